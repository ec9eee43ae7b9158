"""What a user reaches for after a run: a picture of one field at one time, a movie, and a
summary of the run (``refmap plot``, ``refmap movie``, ``refmap info``).

The functions return paths, data and strings; the command line only prints them.  A run
whose solids are stored in windows (``numerics.solid_storage = "window"``) stores the union of
their level sets as ``phi``, a ``solid_index`` and the nearest solid's ``J`` on the grid;
one solid's ``phi`` (``--solid``) and its map ``xi_x``, ``xi_y`` are rebuilt from the frame's
windows (:func:`refmap.io.per_solid_fields`).  Bad arguments (no such run folder, an unknown field, a time outside the run, a solid that does
not exist) raise :class:`PostprocessError` with a one-line message naming the value.
"""

from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np

from refmap.io import (
    DERIVED_FIELDS,
    derived_field,
    list_frames,
    per_solid_fields,
    read_frame,
    read_metadata,
)
from refmap.io._common import WINDOWS_GROUP, frame_ndim, grid_from_attrs

__all__ = [
    "PostprocessError",
    "available_fields",
    "field_at",
    "format_info",
    "frame_times",
    "make_run_movie",
    "nearest_frame",
    "plot_frame",
    "run_info",
]


class PostprocessError(ValueError):
    """A bad argument to a post-processing command (the message names the value)."""


# ---------------------------------------------------------------------- the run folder
def _run_dir(run_dir) -> Path:
    p = Path(run_dir)
    if not p.is_dir():
        raise PostprocessError(f"no run folder {str(run_dir)!r}")
    if not list_frames(p):
        raise PostprocessError(f"{str(run_dir)!r} holds no frames (frames/frame_*.h5): not a refmap run folder")
    return p


def frame_times(run_dir) -> list[tuple[int, float, Path]]:
    """``(index, time, path)`` of every readable frame, by index (reads attributes only)."""
    out = []
    for index, path in list_frames(_run_dir(run_dir)):
        try:
            with h5py.File(path, "r") as f:
                out.append((index, float(f.attrs["time"]), path))
        except Exception:  # noqa: BLE001 - a damaged frame is skipped
            continue
    if not out:
        raise PostprocessError(f"{str(run_dir)!r} holds no readable frame")
    return out


def nearest_frame(run_dir, time: float) -> tuple[int, float, Path]:
    """The frame nearest ``time``; a time outside [first, last] frame time is an error."""
    frames = frame_times(run_dir)
    ts = np.array([t for _, t, _ in frames])
    lo, hi = float(ts.min()), float(ts.max())
    tol = 1e-9 * max(1.0, abs(hi))
    if not math.isfinite(time) or time < lo - tol or time > hi + tol:
        raise PostprocessError(
            f"time {time:g} is outside the run's range [{lo:g}, {hi:g}] ({len(frames)} frames)"
        )
    return frames[int(np.argmin(np.abs(ts - time)))]


def available_fields(run_dir) -> tuple[list[str], list[str]]:
    """``(stored, derived)`` field names of a run (from its first readable frame); the
    stored ones include the solids' maps ``xi_*`` of a run whose solids are stored in
    windows (rebuilt from them)."""
    _, _, path = frame_times(run_dir)[0]
    with h5py.File(path, "r") as f:
        stored = set(f["fields"].keys())
        if WINDOWS_GROUP in f:
            stored |= {f"xi_{a}" for a in "xyz"[: frame_ndim(f.attrs)]}
    stored = sorted(stored)
    derived = [d for d in DERIVED_FIELDS if d not in stored]
    return stored, derived


def _from_windows(field: str, source, solid: int | None) -> bool:
    """Whether ``field`` of the frame ``source`` is one solid's level set or map rebuilt
    from the frame's windows: ``xi_*``, or ``phi`` with a solid named (``phi`` alone is the
    stored union)."""
    return bool(source[2].get("windows")) and (field.startswith("xi_") or (field == "phi" and solid is not None))


def _rebuilt(field: str, source, solid: int | None):
    """``(data, solid)``: one solid's ``field`` rebuilt from the frame's windows."""
    n = source[2]["windows"]["phi_window"].shape[0]
    if solid is None:
        if n != 1:
            raise PostprocessError(f"field {field!r} is per solid ({n} solids); pass --solid 0..{n - 1}")
        solid = 0
    if not (isinstance(solid, int) and 0 <= solid < n):
        raise PostprocessError(f"solid {solid} does not exist; field {field!r} has solids 0..{n - 1}")
    return per_solid_fields(source, solid)[field], solid


def _check_field(run_dir, field: str) -> None:
    stored, derived = available_fields(run_dir)
    if field not in stored and field not in derived:
        raise PostprocessError(
            f"unknown field {field!r}; available: {', '.join(derived + stored)}"
        )


def _pick_solid(field: str, data: np.ndarray, solid: int | None, ndim: int = 2):
    """``data`` of one solid: a per-solid field has one more axis than the grid's ``ndim``."""
    if data.ndim != ndim + 1:
        if solid is not None:
            raise PostprocessError(f"field {field!r} is not per solid; drop --solid {solid}")
        return data, None
    n = data.shape[0]
    if solid is None:
        if n != 1:
            raise PostprocessError(f"field {field!r} is per solid ({n} solids); pass --solid 0..{n - 1}")
        solid = 0
    if not 0 <= solid < n:
        raise PostprocessError(f"solid {solid} does not exist; field {field!r} has solids 0..{n - 1}")
    return data[solid], solid


def field_at(run_dir, field: str, time: float, solid: int | None = None) -> dict:
    """One field (stored or derived) at the frame nearest ``time``.

    Returns a dict: ``grid``, ``time`` (the frame's), ``index``, ``data`` (``[i, j]`` array;
    a per-solid field reduced to ``solid``), ``solid``, ``phis`` (the level sets, or None).
    """
    _check_field(run_dir, field)
    index, t, path = nearest_frame(run_dir, time)
    source = read_frame(path)
    _, fields, attrs = source
    grid = grid_from_attrs(attrs)
    if _from_windows(field, source, solid):
        data, solid = _rebuilt(field, source, solid)
    else:
        try:
            data = derived_field(source, field)
        except ValueError as exc:
            raise PostprocessError(str(exc).splitlines()[0]) from None
        data, solid = _pick_solid(field, np.asarray(data, dtype=np.float64), solid, grid.ndim)
    return {
        "grid": grid,
        "time": t,
        "index": index,
        "data": data,
        "solid": solid,
        "phis": fields.get("phi"),
    }


def _label(field: str, solid: int | None) -> str:
    return field if solid is None else f"{field}_{solid}"


def plot_frame(run_dir, field: str, time: float, out=None, solid: int | None = None,
               dpi: int = 120) -> Path:
    """PNG of ``field`` at the frame nearest ``time``, interfaces drawn; returns its path.

    Default file: ``RUN/plots/<field>_t<time>.png``.  The colour map is diverging (symmetric
    about 0) for a field that changes sign, sequential otherwise.
    """
    from refmap.io import save_frame_png

    run_dir = _run_dir(run_dir)
    fa = field_at(run_dir, field, time, solid)
    data = fa["data"]
    finite = data[np.isfinite(data)]
    signed = finite.size and finite.min() < 0 < finite.max()
    label = _label(field, fa["solid"])
    if out is None:
        out = run_dir / "plots" / f"{label}_t{fa['time']:.6g}.png"
    return save_frame_png(out, fa["grid"], fa["time"], label, data, None, fa["phis"],
                          cmap="RdBu_r" if signed else "viridis", dpi=dpi)


def make_run_movie(run_dir, field: str, out=None, fps: int = 15, solid: int | None = None) -> Path:
    """MP4 of ``field`` over all frames (``refmap.io.make_movie``: interfaces drawn, colour
    range fixed over time); default file ``RUN/<field>.mp4``.  Returns its path."""
    from refmap.io import make_movie

    run_dir = _run_dir(run_dir)
    _check_field(run_dir, field)
    if not (isinstance(fps, int) and fps >= 1):
        raise PostprocessError(f"fps must be an integer >= 1, got {fps!r}")
    # resolve a per-solid field's solid now, for a clear message
    _, _, path = frame_times(run_dir)[0]
    try:
        source = read_frame(path)
        first = None if _from_windows(field, source, solid) else np.asarray(derived_field(source, field))
    except ValueError as exc:
        raise PostprocessError(str(exc).splitlines()[0]) from None
    if first is None:
        _, solid = _rebuilt(field, source, solid)
    else:
        _, solid = _pick_solid(field, first, solid, grid_from_attrs(source[2]).ndim)
    if out is None:
        out = run_dir / f"{_label(field, solid)}.mp4"
    return make_movie(run_dir, field, out, fps=fps, solid=solid)


# ---------------------------------------------------------------------- info
def _rel_change(col) -> dict | None:
    vals = np.asarray(col, dtype=np.float64)
    vals = vals[np.isfinite(vals)]
    if vals.size == 0:
        return None
    first, last = float(vals[0]), float(vals[-1])
    rel = (last - first) / abs(first) if first != 0 else float("nan")
    return {"first": first, "last": last, "relative_change": rel}


def run_info(run_dir) -> dict:
    """Key facts of a run folder as a dict (see :func:`format_info` for the text)."""
    from refmap.checkpoint import read_checkpoint_info

    run_dir = _run_dir(run_dir)
    meta = read_metadata(run_dir)
    case = meta.get("case", {})
    frames = frame_times(run_dir)
    info: dict = {
        "run_dir": str(run_dir),
        "case": case,
        "versions": meta.get("versions", {}),
        "command": meta.get("command"),
        "created": meta.get("created"),
        "resumes": len(meta.get("resumes", [])),
        "frames_written": len(frames),
        "t_first": frames[0][1],
        "t_last": frames[-1][1],
        "checkpoint": None,
    }
    ck = read_checkpoint_info(run_dir)
    if ck is not None:
        info["checkpoint"] = {k: ck.get(k) for k in ("frame_index", "t", "step", "checkpoint_file",
                                                   "dt_min", "dt_max", "total_steps")}
    diag = None
    try:
        from refmap.io import open_diagnostics

        diag = open_diagnostics(run_dir)
    except (FileNotFoundError, ValueError):
        pass
    if diag is not None and len(diag):
        last = diag.iloc[-1]
        info["steps"] = int(last["step"]) if "step" in diag else None
        info["wall_time_s"] = float(last["wall_s"]) if "wall_s" in diag else None
        if "steps_in_frame" in diag and "dt" in diag:
            active = diag[diag["steps_in_frame"] > 0]
            if len(active):
                dts = active["dt"].astype(float)
                info["dt"] = {"min": float(dts.min()), "mean": float(dts.mean()), "max": float(dts.max()),
                              "intervals": len(active)}
                steps = info.get("steps") or 0
                if steps:
                    info["dt"]["mean_all_steps"] = (float(diag["t"].iloc[-1]) - float(diag["t"].iloc[0])) / steps
                if "dt_limit" in active:
                    share = active["dt_limit"].fillna("").value_counts(normalize=True)
                    info["dt_limits"] = {str(k): float(v) for k, v in share.items()}
        cons = {}
        for name in ("fluid_mass", "solid_area"):
            if name in diag:
                rc = _rel_change(diag[name])
                if rc is not None:
                    cons[name] = rc
        info["conservation"] = cons
        if "pressure_cg_iterations" in diag:
            # incompressible fluid: each frame's pressure solve (refmap.model.Model.diagnostics)
            it = diag["pressure_cg_iterations"].astype(float)
            ok = diag["pressure_cg_converged"].astype(float) > 0.5
            info["pressure_solve"] = {
                "frames": len(diag), "iterations_mean": float(it.mean()),
                "iterations_max": int(it.max()), "not_converged": int((~ok).sum()),
                "residual_max": float(diag["pressure_cg_residual"].astype(float).max()),
            }
    return info


def _num(x) -> str:
    return "-" if x is None else f"{x:g}" if isinstance(x, (int, float)) else str(x)


def _kv(d: dict, keys=None) -> str:
    keys = keys or list(d)
    return ", ".join(f"{k}={_num(d[k])}" for k in keys if k in d)


def format_info(info: dict) -> str:
    """The text ``refmap info`` prints."""
    c = info["case"]
    g = c.get("grid", {})
    lines = [f"run         {info['run_dir']}"]
    if c:
        h = min((g["bx"] - g["ax"]) / g["nx"], (g["by"] - g["ay"]) / g["ny"]) if g else None
        lines.append(
            f"case        {c.get('name')} on {g.get('nx')} x {g.get('ny')} cells, "
            f"[{_num(g.get('ax'))}, {_num(g.get('bx'))}] x [{_num(g.get('ay'))}, {_num(g.get('by'))}], h = {_num(h)}"
        )
        for s in c.get("solids", []):
            law = dict(s.get("law", {}))
            lname = law.pop("law", "?")
            shape = s.get("shape", {}).get("type", "?")
            anchor = s.get("anchor")
            anchor = f", anchored ({anchor.get('type', 'yes')})" if isinstance(anchor, dict) else ""
            lines.append(f"solid       {s.get('name')}: {shape}, {lname} ({_kv(law)}){anchor}")
        lines.append(f"fluid       {_kv(c.get('fluid', {}))}; gravity {tuple(c.get('gravity', ()))}")
        lines.append("numerics    " + _kv(c.get("numerics", {}), ["cfl", "dt_fixed", "dt_max", "blur_width", "band"]))
        lines.append(f"schedule    t_end = {_num(c.get('t_end'))}, {c.get('frames')} frame intervals")
    lines.append(
        f"written     {info['frames_written']} frames, t = {_num(info['t_first'])} .. {_num(info['t_last'])}"
        + (f", {info['steps']} steps" if info.get("steps") is not None else "")
    )
    wall = info.get("wall_time_s")
    if wall is not None:
        rate = (info.get("steps") or 0) / wall if wall > 0 else float("nan")
        lines.append(f"wall time   {wall:.1f} s ({rate:.0f} steps/s)")
    dt = info.get("dt")
    if dt:
        extra = f"; mean over all steps {dt['mean_all_steps']:.4g}" if "mean_all_steps" in dt else ""
        lines.append(
            f"dt          min {dt['min']:.4g}, mean {dt['mean']:.4g}, max {dt['max']:.4g} "
            f"(last full step of each of {dt['intervals']} output intervals{extra})"
        )
    lim = info.get("dt_limits")
    if lim:
        lines.append("dt limit    " + ", ".join(f"{k or '(none)'} {100 * v:.0f}%" for k, v in lim.items())
                     + " of output intervals")
    for name, rc in (info.get("conservation") or {}).items():
        lines.append(
            f"{name:<11s} relative change {rc['relative_change']:+.3e} "
            f"({100 * rc['relative_change']:+.3g} %; {rc['first']:.10g} -> {rc['last']:.10g})"
        )
    ps = info.get("pressure_solve")
    if ps:
        bad = (f"; NOT converged in {ps['not_converged']} of {ps['frames']} frames"
               if ps["not_converged"] else "")
        lines.append(f"pressure    CG iterations mean {ps['iterations_mean']:.3g}, max "
                     f"{ps['iterations_max']}, largest relative residual {ps['residual_max']:.2g} "
                     f"(the frames' solves){bad}")
    ck = info.get("checkpoint")
    if ck:
        lines.append(f"checkpoint  frame {ck['frame_index']}, t = {_num(ck['t'])}, step {ck['step']} "
                     f"({ck['checkpoint_file']})" + (f"; resumed {info['resumes']}x" if info["resumes"] else ""))
    else:
        lines.append("checkpoint  none")
    v = info.get("versions") or {}
    if v:
        keys = ["refmap", "jax", "jaxlib", "numpy", "h5py", "python", "jax_backend"]
        git = v.get("git")
        lines.append("versions    " + ", ".join(f"{k} {v[k]}" for k in keys if k in v)
                     + (f", git {git[:12]}" if git else ""))
    return "\n".join(lines)

