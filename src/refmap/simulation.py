"""The stateful shell: run a :class:`~refmap.case.Case`, writing frames as it goes.

Python runs only between output frames; between them a jitted ``lax.while_loop`` advances
the pure step.  A run that stops being finite raises :class:`SimulationBlowUp` naming the
step, time and field, and the frames already written stay readable.
"""

from __future__ import annotations

import json
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
    """The solution stopped being finite (or the time step collapsed)."""


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
        else:
            row[k] = float(v)
    return row


class Simulation:
    """Run a case: ``Simulation(case, out_dir).run()``.

    ``progress`` shows a tqdm bar in simulated time (steps/s, ETA); ``pictures`` writes PNG
    snapshots in the thesis's style at the end; ``movie`` an MP4 of the picture field.
    """

    def __init__(self, case: Case, out_dir=None, progress: bool = True, pictures: bool = True,
                 movie: bool = False, overwrite: bool = False, command: str | None = None):
        self.case = case.validate()
        self.model, self.params = case.build()
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self.progress = progress
        self.pictures = pictures
        self.movie = movie
        self.overwrite = overwrite
        self.command = command if command is not None else " ".join(sys.argv)
        self._advance = jax.jit(self.model.advance, static_argnames=("max_steps",))
        self._diag = jax.jit(self.model.diagnostics)
        self._fields = jax.jit(self.model.output_fields)
        self.state = None
        self.rows: list[dict] = []

    def _write(self, writer, index, state, info, wall):
        fields = {k: np.asarray(v) for k, v in self._fields(state, self.params).items()}
        diag = jax.device_get(self._diag(state, self.params))
        row = _flatten_diag(state.t, info, diag, wall)
        self.rows.append(row)
        if writer is not None:
            writer.write_frame(index, float(state.t), fields, attrs={"step": int(state.step)})
            writer.append_diagnostics(row)
        return row

    def run(self):
        case = self.case
        writer = None
        if self.out_dir is not None:
            from refmap.io import RunWriter

            meta = {"case": case.to_dict(), "versions": versions(), "command": self.command}
            writer = RunWriter(self.out_dir, case.grid, meta, overwrite=self.overwrite)
        state = self.model.initial_state(self.params)
        t0 = _time.perf_counter()
        info0 = {"step": 0, "dt": 0.0, "limit": 0, "steps_in_frame": 0}
        self._write(writer, 0, state, info0, 0.0)
        times = np.linspace(0.0, case.t_end, case.frames + 1)[1:]
        bar = None
        if self.progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=float(case.t_end), unit="t", desc=f"{case.name} {case.grid.nx}x{case.grid.ny}",
                       bar_format="{l_bar}{bar}| t={n:.3f}/{total:.3f} [{elapsed}<{remaining}{postfix}]")
        total_steps = 0
        try:
            for i, tf in enumerate(times, start=1):
                ts = _time.perf_counter()
                new, info = self._advance(state, self.params, float(tf))
                info = jax.device_get(info)
                steps = int(info["steps"])
                total_steps += steps
                if not bool(info["ok"]):
                    self._blow_up(new, state, info, writer)
                state = new
                rinfo = {"step": int(state.step), "dt": float(info["dt"]), "limit": int(info["limit"]),
                         "steps_in_frame": steps}
                self._write(writer, i, state, rinfo, _time.perf_counter() - t0)
                if bar is not None:
                    el = _time.perf_counter() - ts
                    bar.set_postfix_str(
                        f"{steps / max(el, 1e-9):.0f} steps/s, dt={float(info['dt']):.2e} ({LIMIT_NAMES[int(info['limit'])]})"
                    )
                    bar.update(float(tf) - bar.n)
        finally:
            if bar is not None:
                bar.close()
            if writer is not None:
                writer.close()
        self.state = state
        self.wall_time = _time.perf_counter() - t0
        self.total_steps = total_steps
        if writer is not None and self.pictures:
            self.make_pictures()
        if writer is not None and self.movie:
            from refmap.io import make_movie

            make_movie(self.out_dir, case.picture_field, self.out_dir / f"{case.picture_field}.mp4")
        return state

    def _blow_up(self, bad, good, info, writer):
        fields = check_finite_fields(bad) or ["(time step collapsed to zero)"]
        step = int(bad.step)
        t = float(bad.t)
        msg = (
            f"simulation '{self.case.name}' blew up at step {step}, t = {t:.6g}: non-finite "
            f"{', '.join(fields)} (last dt = {float(info['dt']):.3e}, limited by "
            f"{LIMIT_NAMES[int(info['limit'])]}). Likely causes: a time step too large for the "
            f"stiffness (lower numerics.cfl, now {self.case.numerics.cfl}), too coarse a grid "
            f"for the deformation (raise n, now {self.case.grid.nx}), or non-physical parameters."
        )
        if writer is not None:
            writer.close()
            msg += f" Frames written so far are in {self.out_dir}."
        raise SimulationBlowUp(msg)

    def make_pictures(self):
        from refmap.io import open_run, save_frame_png, save_panel_png

        ds = open_run(self.out_dir)
        name = self.case.picture_field
        loc = "corner" if ds[name].dims[-1] == "yc" else "node"
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
        with open(self.out_dir / "summary.json", "w") as f:
            json.dump({"steps": self.total_steps, "wall_time_s": self.wall_time,
                       "steps_per_s": self.total_steps / max(self.wall_time, 1e-9),
                       "final_time": float(self.state.t)}, f, indent=2)


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
