"""Reading a run written by :class:`refmap.io.RunWriter` back into Python.

* :func:`read_frame` - one frame file -> ``(time, {name: array}, attrs)``;
* :func:`open_run` - every readable frame of a run folder -> one ``xarray.Dataset``;
* :func:`open_diagnostics` - diagnostics.csv -> ``pandas.DataFrame``;
* :func:`read_metadata` - metadata.json -> dict.

Arrays come back indexed ``[i, j]`` (i along x) like the solver's, ``[i, j, k]`` for a 3D
run, whatever the order on disk (see :mod:`refmap.io.writer`).  A run can be read while it is
still being written: frames are moved into place atomically, and files that cannot be read
(truncated, corrupt) are skipped with a warning rather than failing the whole read.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import xarray as xr

from refmap.grid import Grid, Grid3D
from refmap.io._common import (
    DIAGNOSTICS_FILE,
    DIAGNOSTICS_GROUP,
    FRAME_RE,
    FRAMES_DIR,
    METADATA_FILE,
    TMP_SUFFIX,
    frame_ndim,
    grid_attrs,
    grid_from_attrs,
    to_disk,
    to_json,
)

__all__ = ["read_frame", "open_run", "open_diagnostics", "read_metadata", "list_frames"]


def _py(value: Any) -> Any:
    """h5py attribute value -> plain Python value (scalars unwrapped, bytes decoded)."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray) and value.dtype.kind in "OSU":
        return [_py(v) for v in value.tolist()]
    return value


def read_frame(path: str | os.PathLike) -> tuple[float, dict[str, np.ndarray], dict[str, Any]]:
    """Read one frame file.

    Returns ``(time, fields, attrs)``: ``fields`` maps each field name to a float64 array
    indexed ``[i, j]`` (per-solid fields ``[s, i, j]``; a 3D frame ``[i, j, k]`` and
    ``[s, i, j, k]``); ``attrs`` holds the file attributes (time, index, the grid keys nx,
    ny, ax, bx, ay, by, dx, dy, in 3D also nz, az, bz, dz, and whatever extra attrs the
    writer was given) plus ``"locations"``: ``{name: "node" | "corner"}``, and
    ``"diagnostics"``: ``{name: array}`` with ``"diagnostic_dims"``: ``{name: axis names}``
    for the frame's small diagnostic arrays (both empty if it has none).  Raises OSError
    (or KeyError/ValueError) for a file that is not a complete frame.
    """
    with h5py.File(path, "r") as f:
        attrs = {k: _py(v) for k, v in f.attrs.items()}
        if "time" not in attrs or "nx" not in attrs:
            raise ValueError(f"{path} is not a refmap frame file (no time/grid attributes)")
        ndim = frame_ndim(attrs)
        fields: dict[str, np.ndarray] = {}
        locations: dict[str, str] = {}
        for name, ds in f["fields"].items():
            arr = np.asarray(ds[()], dtype=np.float64)
            fields[name] = to_disk(arr, ndim)  # reversing the reversed axes
            locations[name] = _py(ds.attrs["location"])
        small: dict[str, np.ndarray] = {}
        small_dims: dict[str, tuple[str, ...]] = {}
        if DIAGNOSTICS_GROUP in f:
            for name, ds in f[DIAGNOSTICS_GROUP].items():
                small[name] = np.asarray(ds[()], dtype=np.float64)
                dims = _py(ds.attrs.get("dims", ""))
                small_dims[name] = tuple(dims.split()) if dims else ()
    attrs["locations"] = locations
    attrs["diagnostics"] = small
    attrs["diagnostic_dims"] = small_dims
    return float(attrs["time"]), fields, attrs


def list_frames(run_dir: str | os.PathLike) -> list[tuple[int, Path]]:
    """``(index, path)`` of every ``frames/frame_*.h5`` file, sorted by index (no reading)."""
    frames_dir = Path(run_dir) / FRAMES_DIR
    out = []
    if frames_dir.is_dir():
        for p in frames_dir.iterdir():
            m = FRAME_RE.match(p.name)
            if m and p.is_file():
                out.append((int(m.group(1)), p))
    return sorted(out)


def read_metadata(run_dir: str | os.PathLike) -> dict:
    """The content of ``run_dir/metadata.json`` (an empty dict if the file is missing)."""
    p = Path(run_dir) / METADATA_FILE
    if not p.is_file():
        return {}
    with open(p) as fh:
        return json.load(fh)


def _flat_attrs(meta: dict) -> dict[str, Any]:
    """Scalars stay as they are; everything else (dicts, lists, None) becomes JSON text."""
    out = {}
    for k, v in meta.items():
        if isinstance(v, (str, bool, int, float)):
            out[str(k)] = v
        else:
            out[str(k)] = to_json(v)
    return out


def open_run(
    run_dir: str | os.PathLike,
    fields: list[str] | tuple[str, ...] | None = None,
) -> xr.Dataset:
    """Load every readable frame of a run folder into one ``xarray.Dataset``.

    Dimensions: ``time``; ``x``, ``y`` (the nx x ny nodes / cell centres); ``xc``, ``yc``
    (the corners); ``solid`` for per-solid fields.  Node fields have dims ``(time, x, y)``
    or ``(time, solid, x, y)``, corner fields ``(time, xc, yc)`` or
    ``(time, solid, xc, yc)``; each variable has attrs ``location`` and ``per_solid``.  A
    3D run adds ``z`` and ``zc``: node fields ``(time, [solid,] x, y, z)``, corner fields
    ``(time, [solid,] xc, yc, zc)``.
    The frames' small diagnostic arrays (see :meth:`refmap.io.RunWriter.write_frame`;
    written by :class:`refmap.simulation.Simulation`: ``solid_centroid``,
    ``solid_velocity``, ``solid_area``, ``solid_J_min``, ``solid_J_max`` and, with contact,
    ``contact_force``, ``contact_wall_gap``, ``contact_min_gap``,
    ``contact_overlap_area``) are variables with dims ``(time, *their dims)`` and attr
    ``diagnostic``.  Coordinates: ``time``, ``index`` (frame index, along time), ``x``,
    ``y``, ``xc``, ``yc`` (3D: also ``z``, ``zc``), ``solid``, and ``other_solid``, ``xy``
    (``"x"``, ``"y"``) and ``xyz`` (``"x"``, ``"y"``, ``"z"``) where diagnostics use them.
    ``ds.attrs`` holds metadata.json (values that are not str/int/float/bool are stored as
    JSON strings) and the grid keys nx, ny, ax, bx, ay, by, dx, dy, in 3D also nz, az, bz,
    dz (which take precedence over metadata keys of the same name; those are kept as
    ``metadata.<key>``).  Use :func:`refmap.io.grid_from_attrs` to rebuild the Grid (a
    Grid3D for a 3D run).

    Frames are ordered by index.  Unreadable frame files, frames on a different grid, and
    leftover ``*.tmp`` files are skipped with a ``UserWarning``.  A field missing from some
    frames is NaN there.  ``fields`` restricts loading to the given names.
    Raises FileNotFoundError if the folder holds no readable frame.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"no run folder {run_dir}")
    frames_dir = run_dir / FRAMES_DIR
    leftovers = (
        sorted(p.name for p in frames_dir.glob(f"*{TMP_SUFFIX}")) if frames_dir.is_dir() else []
    )
    if leftovers:
        warnings.warn(
            f"ignoring {len(leftovers)} temporary file(s) in {frames_dir} (a frame being "
            f"written, or left by an interrupted run): {leftovers[:5]}",
            UserWarning,
            stacklevel=2,
        )

    wanted = None if fields is None else set(fields)
    loaded: list[tuple] = []  # (index, time, fields, locations, diagnostics, their dims)
    grid: Grid | Grid3D | None = None
    for index, path in list_frames(run_dir):
        try:
            time, data, attrs = read_frame(path)
            g = grid_from_attrs(attrs)
        except Exception as exc:  # a partial or corrupt file must not hide the others
            warnings.warn(f"skipping unreadable frame {path}: {exc}", UserWarning, stacklevel=2)
            continue
        if grid is None:
            grid = g
        elif g != grid:
            warnings.warn(
                f"skipping frame {path}: its grid {g} differs from {grid}",
                UserWarning,
                stacklevel=2,
            )
            continue
        locs = attrs["locations"]
        small, small_dims = attrs["diagnostics"], attrs["diagnostic_dims"]
        if wanted is not None:
            data = {k: v for k, v in data.items() if k in wanted}
            small = {k: v for k, v in small.items() if k in wanted}
        loaded.append((int(attrs.get("index", index)), time, data, locs, small, small_dims))
    if grid is None:
        raise FileNotFoundError(f"no readable frame in {frames_dir}")
    loaded.sort(key=lambda t: t[0])
    if wanted is not None:
        present = set().union(*(set(e[2]) | set(e[4]) for e in loaded))
        missing = sorted(wanted - present)
        if missing:
            raise KeyError(f"fields {missing} are in no frame of {run_dir}")

    # union of the fields, in order of first appearance
    order: dict[str, tuple[str, int]] = {}  # name -> (location, nsolid or 0)
    for _, _, data, locs, _, _ in loaded:
        for name, arr in data.items():
            nsolid = arr.shape[0] if arr.ndim == grid.ndim + 1 else 0
            loc = locs[name]
            if name in order:
                old_loc, old_n = order[name]
                if old_loc != loc or (old_n == 0) != (nsolid == 0):
                    raise ValueError(f"field {name!r} changes location or rank between frames")
                order[name] = (loc, max(old_n, nsolid))
            else:
                order[name] = (loc, nsolid)
    nsolid_all = max([n for _, n in order.values()], default=0)

    nt = len(loaded)
    data_vars = {}
    for name, (loc, nsolid) in order.items():
        names = ("x", "y", "z")[: grid.ndim]
        sdims = names if loc == "node" else tuple(f"{a}c" for a in names)
        shape2 = grid.shape(loc)
        if nsolid:
            dims = ("time", "solid", *sdims)
            buf = np.full((nt, nsolid_all, *shape2), np.nan)
        else:
            dims = ("time", *sdims)
            buf = np.full((nt, *shape2), np.nan)
        for t, (_, _, data, *_) in enumerate(loaded):
            arr = data.get(name)
            if arr is None:
                continue
            if nsolid:
                buf[t, : arr.shape[0]] = arr
            else:
                buf[t] = arr
        data_vars[name] = xr.Variable(dims, buf, attrs={"location": loc, "per_solid": bool(nsolid)})

    # the frames' small diagnostic arrays (per solid, per pair): dims ("time", *dims),
    # NaN where a frame lacks one (or has a smaller one)
    small_order: dict[str, tuple[str, ...]] = {}
    small_shape: dict[str, tuple[int, ...]] = {}
    for *_, small, small_dims in loaded:
        for name, arr in small.items():
            dims = small_dims.get(name) or tuple(f"{name}_dim{k}" for k in range(arr.ndim))
            if name in order:
                raise ValueError(f"{name!r} is both a field and a diagnostics array")
            if name in small_order and small_order[name] != dims:
                raise ValueError(f"diagnostics {name!r} changes its dims between frames")
            small_order[name] = dims
            old = small_shape.get(name, arr.shape)
            small_shape[name] = tuple(max(a, b) for a, b in zip(old, arr.shape, strict=True))
    for name, dims in small_order.items():
        buf = np.full((nt, *small_shape[name]), np.nan)
        for t, (*_, small, _) in enumerate(loaded):
            arr = small.get(name)
            if arr is not None:
                buf[(t, *(slice(0, k) for k in arr.shape))] = arr
        data_vars[name] = xr.Variable(("time", *dims), buf, attrs={"diagnostic": True})

    coords = {
        "time": ("time", np.array([e[1] for e in loaded], dtype=np.float64)),
        "index": ("time", np.array([e[0] for e in loaded], dtype=np.int64)),
    }
    names = ("x", "y", "z")[: grid.ndim]
    for a, c in zip(names, grid.axes("node"), strict=True):
        coords[a] = (a, c, {"long_name": f"{a} of cell centres (nodes)"})
    for a, c in zip(names, grid.axes("corner"), strict=True):
        coords[f"{a}c"] = (f"{a}c", c, {"long_name": f"{a} of cell corners"})
    sizes = {}
    for name, dims in small_order.items():
        sizes.update(zip(dims, small_shape[name], strict=True))
    n_solid = max(nsolid_all, sizes.get("solid", 0))
    if n_solid:
        coords["solid"] = ("solid", np.arange(n_solid))
    if "other_solid" in sizes:
        coords["other_solid"] = ("other_solid", np.arange(sizes["other_solid"]))
    if "xy" in sizes:
        coords["xy"] = ("xy", np.array(["x", "y"][: sizes["xy"]]))
    if "xyz" in sizes:
        coords["xyz"] = ("xyz", np.array(["x", "y", "z"][: sizes["xyz"]]))

    attrs = _flat_attrs(read_metadata(run_dir))
    for k, v in grid_attrs(grid).items():
        if k in attrs and attrs[k] != v:
            attrs[f"metadata.{k}"] = attrs[k]
        attrs[k] = v
    return xr.Dataset(data_vars=data_vars, coords=coords, attrs=attrs)


def open_diagnostics(run_dir: str | os.PathLike):
    """Read ``run_dir/diagnostics.csv`` into a ``pandas.DataFrame`` (one row per step).

    A last line cut short by a crash is tolerated (missing cells become NaN; a malformed
    line is dropped with a warning).
    """
    import pandas as pd

    p = Path(run_dir) / DIAGNOSTICS_FILE
    if not p.is_file():
        raise FileNotFoundError(f"no diagnostics file {p}")
    return pd.read_csv(p, on_bad_lines="warn")
