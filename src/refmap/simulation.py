"""The stateful shell: run a :class:`~refmap.case.Case`, writing frames as it goes.

Python runs only between output frames; between them a jitted ``lax.while_loop`` advances
the pure step.  A run that stops being finite raises :class:`SimulationBlowUp` naming the
step, time and field, and the frames already written stay readable.
"""

from __future__ import annotations

import math
import os
import platform
import subprocess
import sys
import time as _time
from pathlib import Path

import jax
import numpy as np

from refmap.case import Case
from refmap.model import LIMIT_NAMES, check_finite_fields


class SimulationBlowUp(RuntimeError):
    """The solution stopped being finite, grew past what the case can produce (fluid
    mass, energy or speed; see :data:`GROWTH_LIMITS`), or the time step collapsed."""


#: Growth checks, run on every frame *before* it is written (the speed also after every
#: step, inside the jitted loop).  A run that trips one stops with SimulationBlowUp naming
#: the step, time, quantity and likely cause.  The bounds are far outside anything the
#: model can produce, so they flag garbage, not inaccuracy:
#:
#: * ``fluid_mass``: the fluid's mass leaves [1/2, 2] times its initial value.  The fluid is
#:   weakly compressible (density changes of order Mach^2); the mean density doubling or
#:   halving means pressures of the order of lambda_f everywhere.  Measured: the rotor quick
#:   start gains 11.9 %, a stiff disc in an inviscid fluid 5x by t = 0.5 and 1e12x by t = 2.
#: * ``energy`` (kinetic + elastic): more than 10 times the initial energy plus the most the
#:   case can put in (1/2 rho_max U^2 |domain| for the fastest boundary or initial speed U,
#:   rho_max |g| L |domain| for gravity), with a floor of the energy of a flow at 1 % of the
#:   sound speed.  An isolated viscous system only loses energy; the stiff disc had 24x its
#:   initial energy at t = 0.25.
#: * ``speed``: more than 10 times the fastest speed the case sets up
#:   (:meth:`refmap.case.Case.velocity_scales`: sound speed, solid wave speed, boundary and
#:   initial speeds, free fall sqrt(2 |g| L)).  Flows near the sound speed already form
#:   shocks this scheme does not capture; ten times the fastest wave is no flow at all.
GROWTH_LIMITS = {"fluid_mass": (0.5, 2.0), "energy": 10.0, "speed": 10.0, "energy_floor_mach": 0.01}


def versions() -> dict:
    import h5py
    import jaxlib

    import refmap

    out = {
        "refmap": refmap.__version__,
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "numpy": np.__version__,
        "h5py": h5py.__version__,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "jax_backend": jax.default_backend(),
    }
    try:
        here = Path(__file__).resolve().parent
        out["git"] = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5
        ).stdout.strip() or None
    except Exception:  # noqa: BLE001 - no git is fine
        out["git"] = None
    return out


def format_rate(rate: float) -> str:
    """Steps per second for the progress bar and the summary: whole numbers from 10 on, two
    significant digits below (a thousand discs at 1024^2 run 0.12 steps/s, not "0")."""
    return f"{rate:.0f}" if rate >= 10 else f"{rate:.2g}"


def release_memory() -> None:
    """Hand the heap's freed pages back to the system (glibc's ``malloc_trim``; nothing
    elsewhere).  XLA's compilations and each frame's outputs free gigabytes that glibc
    keeps mapped: a thousand discs at 1024^2 held 3 GB between frames and peaked at 4.5 GB
    during a frame's outputs, against 1.7 and 3.4 GB with the pages handed back after each
    frame's steps and after its outputs (docs/benchmarks.md, "A thousand discs")."""
    global _libc
    if _libc is None:
        try:
            import ctypes

            _libc = ctypes.CDLL("libc.so.6")
            _libc.malloc_trim.argtypes = [ctypes.c_size_t]
        except (OSError, AttributeError):
            _libc = False
    if _libc:
        _libc.malloc_trim(0)


_libc = None


def _flatten_diag(t, info, diag, wall):
    row = {
        "t": float(t),
        "step": int(info["step"]),
        "dt": float(info["dt"]),
        "dt_limit": LIMIT_NAMES[int(info["limit"])] if info["steps_in_frame"] else "",
        "steps_in_frame": int(info["steps_in_frame"]),
        "wall_s": round(wall, 3),
    }
    for k, v in diag.items():
        if k == "solids":
            for i, per in enumerate(v):
                for kk, vv in per.items():
                    row[f"solid{i}_{kk}"] = float(vv)
        elif k == "pairs":  # {"i_j": {...}}, in the order (0, 1), (0, 2), ..., (1, 2), ...
            for key in sorted(v, key=lambda s: tuple(int(p) for p in s.split("_"))):
                for kk, vv in v[key].items():
                    row[f"pair{key}_{kk}"] = float(vv)
        else:
            row[k] = float(v)
    return row


def _warn_pressure_solve(sim, row) -> None:
    """Warn (once per run) when a frame's pressure solve stopped at its iteration limit
    before reaching ``pressure_rtol``: the velocity is then divergence-free only to the
    residual it reached (diagnostics.csv has ``pressure_cg_*`` for every frame)."""
    if row.get("pressure_cg_converged", 1.0) or sim._warned_pressure:
        return
    import warnings

    sim._warned_pressure = True
    n = sim.case.numerics
    warnings.warn(
        f"case {sim.case.name!r}: the pressure solve did not converge at t = {row['t']:.6g}: "
        f"CG stopped after {int(row['pressure_cg_iterations'])} iterations at relative "
        f"residual {row['pressure_cg_residual']:.3g} > pressure_rtol = {n.pressure_rtol:g} "
        f"(pressure_preconditioner = {n.pressure_preconditioner!r}), so the velocity is "
        "divergence-free only to that residual.  Use pressure_preconditioner = 'multigrid' "
        "(or the default 'auto' where a solid has an anchor), or raise numerics.pressure_rtol",
        RuntimeWarning,
        stacklevel=3,
    )


class Simulation:
    """Run a case: ``Simulation(case, out_dir).run()``.

    ``progress`` shows a tqdm bar in simulated time (steps/s, ETA); ``pictures`` writes PNG
    snapshots in the thesis's style at the end; ``movie`` an MP4 of the picture field.

    ``checkpoint_every`` (frames, default 1; None: only at the end and on Ctrl-C) writes
    ``checkpoint.h5`` into the run folder (see :mod:`refmap.checkpoint`); a run stopped by
    Ctrl-C checkpoints its last completed frame.  :meth:`resume` continues a run folder from
    its checkpoint, bit for bit as if it had never stopped.

    ``state`` (a :class:`~refmap.state.State`) starts the run from that state instead of
    ``model.initial_state``: a state made by hand (``model.initial_state(params)`` with a
    changed ``v``), the end of another run (``Simulation.state``) or a checkpoint
    (``refmap.checkpoint.load_checkpoint``).  It must fit the case (grid shape, number of
    solids; finite values, a positive density) and lie before ``case.t_end``; frame 0 is that
    state at its own time t0 and the ``case.frames`` further frames are spread evenly over
    (t0, t_end].  ``case.initial_velocity`` is not used then (a warning says so).

    ``devices`` (an integer, default None: one device) splits the grid fields along x over
    that many devices (:mod:`refmap.sharding`; the grid's nx must be divisible by it).  The
    results equal the one-device run's to round-off (docs/parallel.md).
    """

    def __init__(self, case: Case, out_dir=None, progress: bool = True, pictures: bool = True,
                 movie: bool = False, overwrite: bool = False, command: str | None = None,
                 checkpoint_every: int | None = 1, state=None, devices: int | None = None):
        if checkpoint_every is not None and (isinstance(checkpoint_every, bool)
                                             or not isinstance(checkpoint_every, int)
                                             or checkpoint_every < 1):
            raise ValueError(f"checkpoint_every must be an integer >= 1 or None, got {checkpoint_every!r}")
        self.checkpoint_every = checkpoint_every
        self._resume_from = None  # set by Simulation.resume
        self._done = None  # counters of the last completed frame (for checkpoints)
        self.case = case.validate()
        self.devices = None
        if devices is not None:
            from refmap.sharding import check_devices

            self.devices = check_devices(devices, case.grid.nx)
        self.model, self.params = case.build()
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self.progress = progress
        self.pictures = pictures
        self.movie = movie
        self.overwrite = overwrite
        self.command = command if command is not None else " ".join(sys.argv)
        if self.devices is None:
            self._advance = jax.jit(self.model.advance, static_argnames=("max_steps",))
        else:
            from refmap.sharding import sharded_advance

            self._advance = sharded_advance(self.model, self.devices)
        model = self.model

        def outputs(state, params):  # one compilation for everything a frame writes
            # the incompressible fluid's pressure solve, once for the fields and diagnostics
            solve = model.frame_pressure(state, params) if model.projection is not None else None
            return (
                model.output_fields(state, params, solve),
                model.diagnostics(state, params, solve),
                model.frame_arrays(state, params),
            )

        self._outputs = jax.jit(outputs)
        self._warned_pressure = False  # a non-converged pressure solve is reported once
        self._array_dims = model.frame_array_dims()
        self.state = None
        self.rows: list[dict] = []
        self.start_state = None if state is None else _check_start_state(state, self.case, model)

    def _write(self, writer, index, state, info, wall, outs=None):
        if outs is None:
            outs = jax.device_get(self._outputs(state, self.params))
        fields, diag, arrays = outs
        row = _flatten_diag(state.t, info, diag, wall)
        self.rows.append(row)
        _warn_pressure_solve(self, row)
        if writer is not None:
            from refmap.io.writer import WINDOW_ARRAYS

            fields = {k: np.asarray(v) for k, v in fields.items()}
            small = {k: (self._array_dims[k], np.asarray(a)) for k, a in arrays.items()}
            win = None
            if "origin" in fields:
                # solids stored in windows (Model.output_fields): the windows go to a
                # group of their own, with what rebuilding the per-solid fields needs
                m = self.model
                win = {k: fields.pop(k) for k in WINDOW_ARRAYS}
                win.update(far=m.numerics.phi_max * m.h, periodic=tuple(m.bc.periodic))
            writer.write_frame(
                index, float(state.t), fields, attrs={"step": int(state.step)}, diagnostics=small,
                windows=win,
            )
            writer.append_diagnostics(row)
        release_memory()
        return row

    def run(self, on_frame=None):
        """Run to ``case.t_end``, or from the checkpoint to the end after :meth:`resume`.

        ``on_frame(index, state)``, if given, is called after each frame is written (and
        checkpointed).  Returns the final State.
        """
        case = self.case
        writer = None
        resumed = self._resume_from
        if self.out_dir is not None and resumed is None:
            from refmap.io import RunWriter

            meta = {"case": case.to_dict(), "versions": versions(), "command": self.command}
            if self.start_state is not None:
                meta["start"] = {"t": float(self.start_state.t), "step": int(self.start_state.step)}
            writer = RunWriter(self.out_dir, case.grid, meta, overwrite=self.overwrite)
        elif self.out_dir is not None:
            writer = self._reopen_for_resume(resumed)
        if resumed is None:
            state = self.start_state
            if state is None:
                state = self.model.initial_state(self.params)
            t0 = _time.perf_counter()
            info0 = {"step": int(state.step), "dt": 0.0, "limit": 0, "steps_in_frame": 0}
            try:
                self._write(writer, 0, state, info0, 0.0)
            except KeyboardInterrupt:
                if writer is not None:
                    writer.close()
                    print(f"\ninterrupted before the first frame was written: {self.out_dir} "
                          "holds no checkpoint and cannot be resumed; run again with "
                          "--overwrite (overwrite=True)", file=sys.stderr)
                raise
            self._growth_reference(self.rows[-1])
            times = np.linspace(float(state.t), case.t_end, case.frames + 1)[1:]
            first, total_steps = 1, 0
            self._dt_stats = (float("inf"), 0.0)
            self._diag_rows_base = -len(self.rows) + 1
        else:
            state = resumed["state"]
            t0 = _time.perf_counter() - float(resumed["wall_time_s"])
            times = np.asarray(resumed["frame_times"], dtype=np.float64)
            first, total_steps = int(resumed["next_frame"]), int(resumed["total_steps"])
            dmin, dmax = resumed.get("dt_min"), resumed.get("dt_max")
            self._dt_stats = (float("inf") if dmin is None else float(dmin), 0.0 if dmax is None else float(dmax))
            self._diag_rows_base = int(resumed["diag_rows"]) - len(self.rows)
            self._growth_reference(self._first_diagnostics_row(state))
        if self.devices is not None:
            from refmap.sharding import shard_state

            state = shard_state(state, self._advance.mesh)
        self._frame_times = [float(x) for x in times]
        last = (resumed["last_dt"], resumed["last_limit"]) if resumed is not None else (0.0, "")
        self._mark_done(first - 1, state, total_steps, t0, *last)
        if writer is not None and resumed is None and self._checkpoint_due(0, len(times)):
            self.save_checkpoint()
        bar = None
        if self.progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=float(case.t_end), unit="t", desc=f"{case.name} {'x'.join(str(m) for m in case.grid.shape())}",
                       bar_format="{l_bar}{bar}| t={n:.3f}/{total:.3f} [{elapsed}<{remaining}{postfix}]",
                       initial=float(state.t))
        try:
            for i, tf in enumerate(times, start=1):
                if i < first:
                    continue
                ts = _time.perf_counter()
                new, info = self._advance(state, self.params, float(tf),
                                          speed_limit=self._speed_limit)
                info = jax.device_get(info)
                release_memory()  # the steps' temporaries (and a first compile's), before the outputs'
                steps = int(info["steps"])
                total_steps += steps
                if not bool(info["ok"]):
                    self._blow_up(new, state, info, writer)
                state = new
                rinfo = {"step": int(state.step), "dt": float(info["dt"]), "limit": int(info["limit"]),
                         "steps_in_frame": steps}
                outs = jax.device_get(self._outputs(state, self.params))
                self._check_growth(_flatten_diag(state.t, rinfo, outs[1], 0.0), state, writer)
                self._write(writer, i, state, rinfo, _time.perf_counter() - t0, outs=outs)
                self._dt_stats = (min(self._dt_stats[0], float(info["dt_min"])),
                                  max(self._dt_stats[1], float(info["dt_max"])))
                self._mark_done(i, state, total_steps, t0, rinfo["dt"], LIMIT_NAMES[rinfo["limit"]])
                if writer is not None and self._checkpoint_due(i, len(times)):
                    self.save_checkpoint()
                if on_frame is not None:
                    on_frame(i, state)
                if bar is not None:
                    el = _time.perf_counter() - ts
                    bar.set_postfix_str(
                        f"{format_rate(steps / max(el, 1e-9))} steps/s, dt={float(info['dt']):.2e} "
                        f"({LIMIT_NAMES[int(info['limit'])]})"
                    )
                    bar.update(float(tf) - bar.n)
        except KeyboardInterrupt:
            if writer is not None and self._done is not None:
                path = self.save_checkpoint()
                d = self._done
                print(f"\ninterrupted: checkpoint of frame {d['frame_index']} (t = {d['t']:.6g}) written "
                      f"to {path}; continue with `refmap resume {self.out_dir}`", file=sys.stderr)
            raise
        finally:
            if bar is not None:
                bar.close()
            if writer is not None:
                writer.close()
        self.state = state
        self.wall_time = _time.perf_counter() - t0
        self.total_steps = total_steps
        self.conservation = self._conservation()
        if writer is not None:
            self._write_summary()
        if writer is not None and self.pictures:
            self.make_pictures()
        if writer is not None and self.movie:
            from refmap.io import make_movie

            make_movie(self.out_dir, case.picture_field, self.out_dir / f"{case.picture_field}.mp4")
        return state

    # ------------------------------------------------------------------ checkpoint / restart
    def _mark_done(self, index, state, total_steps, t0, last_dt, last_limit):
        """Remember the counters of the last completed frame (one assignment, so a Ctrl-C
        never sees half of them)."""
        dmin, dmax = self._dt_stats
        self._done = {
            "frame_index": int(index),
            "next_frame": int(index) + 1,
            "t": float(state.t),
            "step": int(state.step),
            "total_steps": int(total_steps),
            "diag_rows": len(self.rows) + self._diag_rows_base,
            "wall_time_s": _time.perf_counter() - t0,
            "last_dt": float(last_dt),
            "last_limit": str(last_limit),
            "dt_min": dmin if np.isfinite(dmin) else None,
            "dt_max": dmax if dmax > 0 else None,
            "state": state,
        }

    def _checkpoint_due(self, index, n_frames):
        every = self.checkpoint_every
        return index == n_frames or (every is not None and index % every == 0)

    def save_checkpoint(self):
        """Write ``checkpoint.h5`` for the last completed frame; returns its path."""
        from refmap.checkpoint import save_checkpoint

        if self.out_dir is None or self._done is None:
            raise RuntimeError("nothing to checkpoint (no run folder, or no frame completed yet)")
        if getattr(self, "_versions", None) is None:
            from refmap.checkpoint import case_toml

            self._versions = versions()
            self._case_toml = case_toml(self.case)
        d = dict(self._done)
        state = d.pop("state")
        d.update(
            frame_times=list(self._frame_times),
            t_end=float(self.case.t_end),
            frames=int(self.case.frames),
            checkpoint_every=self.checkpoint_every,
            case=self.case.to_dict(),
            case_toml=self._case_toml,
            scenario={"name": self.case.name, "n": int(self.case.grid.nx)},
            versions=self._versions,
            command=self.command,
        )
        return save_checkpoint(self.out_dir, state, d)

    def _reopen_for_resume(self, resumed):
        from datetime import UTC, datetime

        from refmap.checkpoint import note_resume, reopen_run_writer

        writer = reopen_run_writer(self.out_dir, self.case.grid, int(resumed["next_frame"]),
                                   int(resumed["diag_rows"]))
        note_resume(self.out_dir, self.case.to_dict(), {
            "resumed": datetime.now(UTC).isoformat(timespec="seconds"),
            "from_frame": int(resumed["next_frame"]) - 1,
            "from_t": float(resumed["t"]),
            "checkpoint_file": resumed.get("checkpoint_file"),
            "command": self.command,
            "versions": versions(),
        })
        return writer

    @classmethod
    def resume(cls, run_dir, *, case: Case | None = None, t_end: float | None = None,
               frames: int | None = None, progress: bool = True, pictures: bool = True,
               movie: bool = False, command: str | None = None,
               checkpoint_every: int | None = 1, devices: int | None = None) -> Simulation:
        """A Simulation that continues ``run_dir`` from its checkpoint; call ``.run()``.

        The case is rebuilt from the checkpoint (see :func:`refmap.checkpoint.rebuild_case`;
        pass ``case=`` for a user-defined case built in Python).  Without ``t_end``/``frames``
        the run continues on its original output schedule and ends exactly as an
        uninterrupted run would, bit for bit.  ``t_end`` (and optionally ``frames``, the
        number of intervals from 0 to ``t_end``; default: the same frame spacing) extends
        the run: frames already written are kept, the remaining ones follow the new
        schedule.  Frames written after the checkpoint are recomputed.  ``devices``: see
        :class:`Simulation` (a run may be resumed on another number of devices).
        """
        from refmap.case import CaseError
        from refmap.checkpoint import CheckpointError, load_checkpoint, rebuild_case
        from refmap.io import read_metadata

        run_dir = Path(run_dir)
        state, info = load_checkpoint(run_dir)
        case = rebuild_case(info, read_metadata(run_dir), case)
        schedule = [float(x) for x in info["frame_times"]]
        nxt = int(info["next_frame"])
        t_now = float(state.t)
        if t_end is not None or frames is not None:
            new_t_end = float(case.t_end if t_end is None else t_end)
            if frames is None:
                frames = max(1, int(round(new_t_end * case.frames / case.t_end)))
            case.replace(t_end=new_t_end, frames=frames).validate()
            if not new_t_end > t_now:
                raise CaseError(f"t_end {new_t_end:g} is not after the checkpoint time t = {t_now:.6g}")
            tol = 1e-9 * max(1.0, abs(new_t_end))
            new = np.linspace(0.0, new_t_end, int(frames) + 1)[1:]
            schedule = schedule[: nxt - 1] + [float(x) for x in new if x > t_now + tol]
            case = case.replace(t_end=new_t_end, frames=len(schedule))
        sim = cls(case, run_dir, progress=progress, pictures=pictures, movie=movie,
                  command=command, checkpoint_every=checkpoint_every, devices=devices)
        try:
            want = _state_shapes(state, case, sim.model)
        except ValueError as e:
            raise CheckpointError(f"checkpoint state: {e}") from None
        for name, shape in want.items():
            if tuple(np.shape(getattr(state, name))) != shape:
                raise CheckpointError(
                    f"checkpoint field {name} has shape {tuple(np.shape(getattr(state, name)))}, the case "
                    f"needs {shape}")
        from refmap.checkpoint import case_toml

        now, then = versions(), info.get("versions") or {}
        changed = [f"{k} {then.get(k)} -> {now.get(k)}" for k in ("refmap", "git", "jax", "jaxlib")
                   if then.get(k) != now.get(k)]
        if changed:
            import warnings

            warnings.warn(f"resuming {run_dir} with other versions than it was checkpointed with "
                          f"({'; '.join(changed)}): the continuation may differ from an uninterrupted run",
                          UserWarning, stacklevel=2)
        state = sim.model.adopt(_with_pressure(state, sim.model))
        sim._versions, sim._case_toml = now, case_toml(case)
        sim._resume_from = dict(info, state=state, frame_times=schedule)
        return sim

    @property
    def complete(self) -> bool:
        """True when a resumed simulation has no frame left to compute."""
        r = self._resume_from
        return r is not None and int(r["next_frame"]) > len(r["frame_times"])

    # ------------------------------------------------------------------ growth checks
    def _first_diagnostics_row(self, state) -> dict:
        """Frame 0's diagnostics of a resumed run (from diagnostics.csv), else the current
        state's."""
        import csv

        try:
            with open(self.out_dir / "diagnostics.csv", newline="") as f:
                row = next(csv.DictReader(f))
            return {k: float(v) for k, v in row.items()
                    if k in ("fluid_mass", "kinetic_energy", "elastic_energy", "max_speed", "solid_area")
                    and v not in ("", None)}
        except (OSError, StopIteration, ValueError, TypeError):
            diag = jax.device_get(self._outputs(state, self.params))[1]
            return _flatten_diag(state.t, {"step": 0, "dt": 0.0, "limit": 0, "steps_in_frame": 0},
                                 diag, 0.0)

    def _growth_reference(self, row: dict) -> None:
        """Set the bounds of :data:`GROWTH_LIMITS` from frame 0 (its diagnostics row)."""
        case = self.case
        scales = case.velocity_scales()
        v0 = float(row.get("max_speed", 0.0))
        if v0 > 0:
            scales["initial speed"] = v0
        self._scales = scales
        self._speed_limit = GROWTH_LIMITS["speed"] * max(scales.values())
        extents = case._extents()
        area = math.prod(extents)  # the domain's area (2D) or volume (3D)
        rho_max = max([float(case.fluid.rho0)] + [float(s.law.rho0) for s in case.solids])
        drive_u = max(scales.get(k, 0.0) for k in ("boundary speed", "initial solid speed", "initial speed"))
        gmag = math.hypot(*(float(x) for x in case.gravity))
        drive = 0.5 * rho_max * drive_u**2 * area + rho_max * gmag * max(extents) * area
        # the floor's speed: the fluid's sound speed, or (incompressible: no sound) the
        # fastest speed the case sets up
        c_floor = scales.get("sound speed", max(scales.values()))
        floor = 0.5 * float(case.fluid.rho0) * (GROWTH_LIMITS["energy_floor_mach"] * c_floor) ** 2 * area
        e0 = float(row.get("kinetic_energy", 0.0)) + float(row.get("elastic_energy", 0.0))
        self._energy0 = e0
        self._energy_limit = GROWTH_LIMITS["energy"] * max(e0 + drive, floor)
        self._mass0 = float(row.get("fluid_mass", float("nan")))
        self._area0 = float(row["solid_area"]) if "solid_area" in row else None

    def _check_growth(self, row: dict, state, writer) -> None:
        """Stop (SimulationBlowUp) before writing a frame whose fluid mass, energy or speed
        is past :data:`GROWTH_LIMITS`."""
        lo, hi = GROWTH_LIMITS["fluid_mass"]
        m, m0 = row.get("fluid_mass"), self._mass0
        what = None
        if m is not None and m0 > 0 and not (lo <= m / m0 <= hi):
            what = (f"the fluid mass is {m / m0:.3g} times its initial value ({m:.4g} against "
                    f"{m0:.4g}; the check stops outside [{lo:g}, {hi:g}])")
        e = float(row.get("kinetic_energy", 0.0)) + float(row.get("elastic_energy", 0.0))
        if what is None and e > self._energy_limit:
            what = (f"the energy (kinetic + elastic) is {e:.4g}, more than {self._energy_limit:.4g} "
                    f"= {GROWTH_LIMITS['energy']:g} x (initial energy {self._energy0:.4g} + the "
                    "most the boundaries, initial velocities and gravity can put in)")
        v = float(row.get("max_speed", 0.0))
        if what is None and v > self._speed_limit:
            what = self._speed_text(v)
        if what is not None:
            self._stop(state, what, writer, written_note=True)

    def _speed_text(self, v) -> str:
        name, top = max(self._scales.items(), key=lambda kv: kv[1])
        return (f"the speed reached |v| = {v:.3g}, more than {GROWTH_LIMITS['speed']:g} times the "
                f"fastest speed of the case ({name} {top:.3g})")

    def _advice(self) -> list[str]:
        """Likely causes of a blow-up for this case, most specific first."""
        case, fl, nm = self.case, self.case.fluid, self.case.numerics
        out = []
        if nm.dt_fixed is not None:
            out.append(f"numerics.dt_fixed = {nm.dt_fixed:g} too large (leave it out for the "
                       "adaptive step, or lower it below the limit the CaseWarning named)")
        hm = case.hydrostatic_mach()
        if hm is not None and hm[0] > 1:
            mach, rho0, gmag, L, _ = hm
            out.append(f"gravity compressing a too soft fluid (rho0 |g| L / lambda_f = {mach:.3g} "
                       f"> 1: raise fluid.lambda_f to >= {10 * rho0 * gmag * L:.3g} or "
                       "lower the gravity)")
        if float(fl.eta) + float(fl.extra_viscosity) + float(fl.bulk_viscosity) == 0:
            out.append("an inviscid fluid: forward Euler amplifies undamped waves at any time step "
                       "(give it viscosity, e.g. fluid.extra_viscosity = 0.02)")
        elif case.solids and float(fl.extra_viscosity) == 0:
            out.append("no extra viscosity: the solid's waves are undamped and forward Euler "
                       "amplifies them at any time step (fluid.extra_viscosity = 0.02)")
        if case.sound_damping_shortfall() is not None:
            out.append("under-damped sound (see the CaseWarning: fluid.bulk_viscosity or "
                       "numerics.compression = 'corner')")
        if out:  # a specific cause: lowering cfl or refining would not cure it
            return out
        out.append(f"a time step too large (lower numerics.cfl, now {nm.cfl:g}; a finer grid also "
                   "shortens the step but does not cure a time-step instability: raise n, now "
                   f"{case.grid.nx}, only for a solid whose deformation is under-resolved)")
        return out

    def _stop(self, bad, what, writer, written_note=False, info=None, advice=True):
        step, t = int(bad.step), float(bad.t)
        msg = f"simulation '{self.case.name}' {'blew up' if advice else 'stopped'} at step {step}, t = {t:.6g}: {what}"
        if info is not None:
            msg += (f" (last dt = {float(info['dt']):.3e}, limited by "
                    f"{LIMIT_NAMES[int(info['limit'])]})")
        if advice:
            msg += ". Likely causes: " + "; or ".join(self._advice()) + "."
        else:
            msg += "."
        if writer is not None:
            writer.close()
            done = self._done
            last = f" (up to t = {done['t']:.6g})" if done is not None else ""
            msg += f" Frames written so far{last} are in {self.out_dir}"
            msg += "; this state was not written." if written_note else "."
        raise SimulationBlowUp(msg)

    def _blow_up(self, bad, good, info, writer):
        fields = check_finite_fields(bad)
        if "origin" in fields:
            # a body outgrew the window its map and level set are stored in
            lost = np.flatnonzero(np.any(np.asarray(bad.origin) < 0, axis=1))
            names = ", ".join(repr(self.model.solids[k].name) for k in lost)
            self._stop(bad, f"the band of solid {names} no longer fits the window of "
                       f"{' x '.join(str(w) for w in self.model.state_window)} nodes it is stored in "
                       "(numerics solid_storage = 'window' sizes the windows from the bodies at "
                       "t = 0, with room for moving but little for growing); run it with "
                       "solid_storage = 'grid'", writer, info=info, advice=False)
        if fields:
            what = f"non-finite {', '.join(fields)}"
        else:
            v = float(np.sqrt(np.max(np.sum(np.asarray(bad.v) ** 2, axis=0))))
            if v > self._speed_limit:
                what = self._speed_text(v)
            else:
                what = "the time step collapsed to zero"
        self._stop(bad, what, writer, info=info)

    # ------------------------------------------------------------------ summary
    def _conservation(self) -> dict:
        """Fluid mass, solid area and energy at the start and end of the run (from
        diagnostics.csv when there is a run folder, so a resumed run counts from t = 0)."""
        rows = self.rows
        if self.out_dir is not None:
            try:
                from refmap.io import open_diagnostics

                d = open_diagnostics(self.out_dir)
                rows = [d.iloc[0].to_dict(), d.iloc[-1].to_dict()]
            except (FileNotFoundError, ValueError, IndexError):
                pass
        if not rows:
            return {}
        first, last = rows[0], rows[-1]
        out = {}
        for key, name in (("fluid_mass", "fluid_mass_change"), ("solid_area", "solid_area_change")):
            a, b = first.get(key), last.get(key)
            if a is not None and b is not None and np.isfinite(a) and a != 0:
                out[name] = {"first": float(a), "last": float(b), "relative": float(b) / float(a) - 1.0}
        e0 = float(first.get("kinetic_energy", 0.0)) + float(first.get("elastic_energy", 0.0))
        e1 = float(last.get("kinetic_energy", 0.0)) + float(last.get("elastic_energy", 0.0))
        out["energy"] = {"first": e0, "last": e1}
        b = self.case.boundary
        out["open_boundary"] = any(
            seg.kind == "outflow" or (seg.kind == "velocity" and any(seg.velocity))
            for name in ("left", "right", "bottom", "top")
            if not isinstance(getattr(b, name), str) for seg in getattr(b, name))
        return out

    def conservation_text(self) -> str:
        """One line for the end of a run: fluid mass and solid area changes in %."""
        c = getattr(self, "conservation", None) or {}
        parts = []
        if "fluid_mass_change" in c:
            m = c["fluid_mass_change"]
            note = " (includes the flow through the open edges)" if c.get("open_boundary") else ""
            parts.append(f"fluid mass {100 * m['relative']:+.3g} %{note}")
        if "solid_area_change" in c:
            parts.append(f"solid area {100 * c['solid_area_change']['relative']:+.3g} %")
        if "energy" in c:
            parts.append(f"energy (kinetic + elastic) {c['energy']['first']:.4g} -> {c['energy']['last']:.4g}")
        return ("conservation: " + ", ".join(parts)) if parts else ""

    def _write_summary(self):
        from refmap.io._common import atomic_write_bytes, to_json

        summary = {"steps": self.total_steps, "wall_time_s": self.wall_time,
                   "steps_per_s": self.total_steps / max(self.wall_time, 1e-9),
                   "final_time": float(self.state.t), "conservation": self.conservation}
        atomic_write_bytes(self.out_dir / "summary.json", (to_json(summary, indent=2) + "\n").encode())

    def make_pictures(self):
        from refmap.io import open_run, save_frame_png, save_panel_png

        ds = open_run(self.out_dir)
        name = self.case.picture_field
        loc = "corner" if ds[name].dims[-1] in ("yc", "zc") else "node"
        grid = self.case.grid
        nt = ds.sizes["time"]
        picks = sorted(set(np.linspace(0, nt - 1, min(4, nt)).round().astype(int).tolist()))
        panels = []
        for i in picks:
            phis = ds["phi"].isel(time=i).values if "phi" in ds else None
            panels.append((float(ds.time[i]), ds[name].isel(time=i).values, phis))
        save_panel_png(self.out_dir / f"{name}_panels.png", grid, panels, name, loc, ncols=2)
        pics = self.out_dir / "pictures"
        pics.mkdir(exist_ok=True)
        for i in picks:
            phis = ds["phi"].isel(time=i).values if "phi" in ds else None
            save_frame_png(pics / f"{name}_{i:05d}.png", grid, float(ds.time[i]), name,
                           ds[name].isel(time=i).values, loc, phis)


def _check_start_state(state, case: Case, model):
    """``state`` as a float64/int64 State that fits ``case``, else CaseError naming the
    field and its value (before anything is compiled)."""
    import warnings

    import jax.numpy as jnp

    from refmap.case import CaseError
    from refmap.state import State

    def bad(msg):
        raise CaseError(f"case {case.name!r}: start state: {msg}")

    if not isinstance(state, State):
        bad(f"must be a refmap.state.State, got {type(state).__name__}")
    g = case.grid
    n = model.n_solids
    gshape = g.shape()
    try:
        want = _state_shapes(state, case, model)
    except ValueError as e:
        bad(str(e))
    if getattr(state, "p", None) is not None:  # an incompressible run's pressure
        want["p"] = gshape
    arrays = {}
    for name, shape in want.items():
        try:
            a = np.asarray(getattr(state, name))
        except Exception as e:  # noqa: BLE001 - anything unreadable is a bad value
            bad(f"{name} cannot be read as an array ({type(e).__name__}: {e})")
        if a.dtype.kind not in "iuf":
            bad(f"{name} must hold real numbers, got dtype {a.dtype}")
        if a.shape != shape:
            what = (f" ({a.shape[0]} solid(s) in the state, {n} in the case)"
                    if name in ("xi", "phi", "origin") and a.ndim >= 1 and a.shape[0] != n else "")
            bad(f"{name} has shape {a.shape}, the case needs {shape} (grid {' x '.join(str(m) for m in gshape)}, "
                f"{n} solid(s)){what}")
        if name == "origin":  # solids stored in windows: each window's first node
            if a.dtype.kind not in "iu" or not np.all((a >= 0) & (a < np.asarray(gshape))):
                bad(f"origin must hold each window's first node, integers in [0, n) per axis "
                    f"(-1 marks a body that outgrew its window, no state to start from), "
                    f"got {a.tolist()!r}")
            arrays[name] = a
            continue
        if not np.all(np.isfinite(a)):
            idx = tuple(int(k[0]) for k in np.nonzero(~np.isfinite(a)))
            bad(f"{name} is not finite at {int((~np.isfinite(a)).sum())} value(s), the first "
                f"at index {list(idx)}: {float(a[idx])!r}")
        arrays[name] = a
    if not np.all(arrays["rho_f"] > 0):
        idx = tuple(int(k[0]) for k in np.nonzero(~(arrays["rho_f"] > 0)))
        bad(f"rho_f must be > 0, got {float(arrays['rho_f'][idx])!r} at node {list(idx)}")
    try:
        t = float(np.asarray(state.t))
        step = np.asarray(state.step)
    except Exception as e:  # noqa: BLE001
        bad(f"t and step must be numbers ({type(e).__name__}: {e})")
    if step.shape != () or step.dtype.kind not in "iu" or int(step) < 0:
        bad(f"step must be an integer >= 0, got {state.step!r}")
    if not (math.isfinite(t) and t >= 0):
        bad(f"t must be a finite number >= 0, got {t!r}")
    if not t < case.t_end:
        bad(f"t = {t:.6g} is not before case.t_end = {case.t_end:.6g}; raise t_end")
    if case.initial_velocity is not None:
        warnings.warn(f"case {case.name!r}: the run starts from the given state, so "
                      f"case.initial_velocity ({case.initial_velocity!r}) is not used",
                      UserWarning, stacklevel=3)
    origin = arrays.pop("origin", None)
    return model.adopt(_with_pressure(
        State(t=jnp.asarray(t, dtype=jnp.float64), step=jnp.asarray(int(step), dtype=jnp.int64),
              **{k: jnp.asarray(a, dtype=jnp.float64) for k, a in arrays.items()},
              origin=None if origin is None else jnp.asarray(origin, dtype=jnp.int32)), model))


def _state_shapes(state, case: Case, model) -> dict:
    """The shapes a start state or checkpoint of ``case`` must have: ``v``, ``rho_f``, and
    the solids' ``xi`` and ``phi`` on the grid, or for solids stored in windows
    (``state.origin`` set) of the state's window ``W`` (any size up to the grid's:
    ``Model.adopt`` converts another storage or size) with ``origin`` ``(S, d)``.  Checked
    without placing the windows on the grid, which at a thousand solids would not fit in
    memory.  ValueError for a window that is no box of the grid."""
    g = case.grid
    n = model.n_solids
    nd, gshape = g.ndim, tuple(g.shape())
    want = {"v": (nd, *gshape), "rho_f": gshape}
    if getattr(state, "origin", None) is None:
        return {**want, "xi": (n, nd, *gshape), "phi": (n, *gshape)}
    W = tuple(np.shape(state.phi)[1:])
    if len(W) != nd or not all(1 <= w <= m for w, m in zip(W, gshape, strict=True)):
        raise ValueError(f"its solids' windows phi {tuple(np.shape(state.phi))} are no box of the grid "
                         f"{' x '.join(str(m) for m in gshape)} (solids stored in windows: phi (S, *W))")
    return {**want, "xi": (n, nd, *W), "phi": (n, *W), "origin": (n, nd)}


def _with_pressure(state, model):
    """``state`` with the pressure the model's step carries: zeros for an incompressible
    model whose state has none (a state made by hand, or a checkpoint written before
    2026-12-06; the first step then solves for the whole pressure, as from
    ``initial_state``), None for a compressible one."""
    import jax.numpy as jnp

    if model.projection is None:
        return state.replace(p=None)
    if state.p is None:
        return state.replace(p=jnp.zeros(state.rho_f.shape, dtype=jnp.float64))
    return state


def run_scenario(name: str, n: int = 128, t_end: float | None = None, frames: int | None = None,
                 out=None, **kw):
    """Convenience: run a built-in scenario and return the Simulation."""
    from refmap.scenarios import get_case

    case = get_case(name, n)
    if t_end is not None:
        case = case.replace(t_end=t_end)
    if frames is not None:
        case = case.replace(frames=frames)
    sim = Simulation(case, out, **kw)
    sim.run()
    return sim


os.environ.setdefault("MPLBACKEND", "Agg")
