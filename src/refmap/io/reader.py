"""Reading a run written by :class:`refmap.io.RunWriter` back into Python.

* :func:`read_frame` - one frame file -> ``(time, {name: array}, attrs)``;
* :func:`open_run` - every readable frame of a run folder -> one ``xarray.Dataset``;
* :func:`open_diagnostics` - diagnostics.csv -> ``pandas.DataFrame``;
* :func:`read_metadata` - metadata.json -> dict;
* :func:`per_solid_fields` - each solid's whole-grid ``phi`` and ``xi_*`` of a frame, stored
  or (solids stored in windows) rebuilt from the frame's windows;
* :func:`read_state` - a frame written by :class:`refmap.simulation.Simulation` as the
  :class:`~refmap.state.State` it was written from (to start a run from it).

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
    WINDOWS_GROUP,
    frame_ndim,
    grid_attrs,
    grid_from_attrs,
    to_disk,
    to_json,
)

__all__ = ["read_frame", "open_run", "open_diagnostics", "read_metadata", "list_frames",
           "per_solid_fields", "read_state"]

#: the solids' per-solid grid fields of a frame whose solids are on the grid, which
#: :func:`per_solid_fields` rebuilds from the windows of one whose solids are in windows
SOLID_FIELDS = ("phi", "xi_x", "xi_y", "xi_z")


def _py(value: Any) -> Any:
    """h5py attribute value -> plain Python value (scalars unwrapped, bytes decoded)."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray) and value.dtype.kind in "OSU":
        return [_py(v) for v in value.tolist()]
    return value


def read_frame(path: str | os.PathLike, windows: bool = True
               ) -> tuple[float, dict[str, np.ndarray], dict[str, Any]]:
    """Read one frame file.

    Returns ``(time, fields, attrs)``: ``fields`` maps each field name to a float64 array
    (int32 for an integer field: ``solid_index``) indexed ``[i, j]`` (per-solid fields
    ``[s, i, j]``; a 3D frame ``[i, j, k]`` and ``[s, i, j, k]``); ``attrs`` holds the file
    attributes (time, index, the grid keys nx, ny, ax, bx, ay, by, dx, dy, in 3D also nz,
    az, bz, dz, and whatever extra attrs the writer was given) plus ``"locations"``:
    ``{name: "node" | "corner"}``, ``"diagnostics"``: ``{name: array}`` with
    ``"diagnostic_dims"``: ``{name: axis names}`` for the frame's small diagnostic arrays
    (both empty if it has none), and ``"windows"``: the frame's solid windows (a run whose
    solids are stored in windows, :mod:`refmap.io.writer`): ``phi_window`` ``(S, *W)``,
    ``xi_window`` ``(S, d, *W)``, ``origin`` ``(S, d)`` int32 in the solver's order, ``far``
    (float) and ``periodic`` (tuple of bools); empty when the frame has none or with
    ``windows=False`` (which skips reading them).  Raises OSError (or KeyError/ValueError)
    for a file that is not a complete frame.
    """
    with h5py.File(path, "r") as f:
        attrs = {k: _py(v) for k, v in f.attrs.items()}
        if "time" not in attrs or "nx" not in attrs:
            raise ValueError(f"{path} is not a refmap frame file (no time/grid attributes)")
        ndim = frame_ndim(attrs)
        fields: dict[str, np.ndarray] = {}
        locations: dict[str, str] = {}
        for name, ds in f["fields"].items():
            arr = ds[()]
            arr = arr.astype(np.int32) if arr.dtype.kind in "iu" else np.asarray(arr, dtype=np.float64)
            fields[name] = to_disk(arr, ndim)  # reversing the reversed axes
            locations[name] = _py(ds.attrs["location"])
        small: dict[str, np.ndarray] = {}
        small_dims: dict[str, tuple[str, ...]] = {}
        if DIAGNOSTICS_GROUP in f:
            for name, ds in f[DIAGNOSTICS_GROUP].items():
                small[name] = np.asarray(ds[()], dtype=np.float64)
                dims = _py(ds.attrs.get("dims", ""))
                small_dims[name] = tuple(dims.split()) if dims else ()
        win: dict[str, Any] = {}
        if windows and WINDOWS_GROUP in f:
            g = f[WINDOWS_GROUP]
            win["phi_window"] = np.asarray(g["phi_window"][()], dtype=np.float64)
            win["xi_window"] = np.asarray(g["xi_window"][()], dtype=np.float64)
            win["origin"] = np.asarray(g["origin"][()], dtype=np.int32)
            win["far"] = float(g.attrs["far"])
            win["periodic"] = tuple(bool(p) for p in np.atleast_1d(g.attrs["periodic"]))
    attrs["locations"] = locations
    attrs["windows"] = win
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
    windows: bool = False,
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

    A run whose solids are stored in windows (:mod:`refmap.io.writer`) has the grid fields
    ``phi`` (the union level set, ``(time, x, y)``), ``solid_index`` (int32, -1 where no
    solid is within reach) and ``J`` (the nearest solid's, ``(time, xc, yc)``) instead of
    the per-solid ``phi``, ``xi_*`` and ``J``; with ``windows=True`` also the windows:
    ``phi_window`` ``(time, solid, wx, wy)``, ``xi_window`` ``(time, solid, xy, wx, wy)``
    and ``origin`` ``(time, solid, xy)`` (int32; in 3D ``wz`` and ``xyz``), attrs ``far``
    and ``periodic`` (:func:`per_solid_fields` rebuilds a frame's per-solid fields from
    them).  They are left out by default: a frame's windows are as large as its grid
    fields together at a thousand solids.

    Frames are ordered by index.  Unreadable frame files, frames on a different grid, and
    leftover ``*.tmp`` files are skipped with a ``UserWarning``.  A field missing from some
    frames is NaN there (an integer field is int32 when every frame has it, else float64
    with NaN).  ``fields`` restricts loading to the given names.
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
            time, data, attrs = read_frame(path, windows=windows)
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
        loaded.append((int(attrs.get("index", index)), time, data, locs, small, small_dims,
                       attrs["windows"]))
    if grid is None:
        raise FileNotFoundError(f"no readable frame in {frames_dir}")
    loaded.sort(key=lambda t: t[0])
    if wanted is not None:
        present = set().union(*(set(e[2]) | set(e[4]) for e in loaded))
        if windows and any(e[6] for e in loaded):
            present |= {"phi_window", "xi_window", "origin"}
        missing = sorted(wanted - present)
        if missing:
            raise KeyError(f"fields {missing} are in no frame of {run_dir}")

    # union of the fields, in order of first appearance
    order: dict[str, tuple[str, int]] = {}  # name -> (location, nsolid or 0)
    integer = {}  # name -> whether every frame holds it as integers
    for _, _, data, locs, *_ in loaded:
        for name, arr in data.items():
            integer[name] = integer.get(name, True) and arr.dtype.kind in "iu"
            nsolid = arr.shape[0] if arr.ndim == grid.ndim + 1 else 0
            loc = locs[name]
            if name in order:
                old_loc, old_n = order[name]
                if old_loc != loc or (old_n == 0) != (nsolid == 0):
                    hint = (" (a run continued with another numerics solid_storage: per-solid "
                            "fields on one side, the union of the solids in windows on the "
                            "other; read its frames one by one with read_frame)"
                            if name in SOLID_FIELDS or name == "J" else "")
                    raise ValueError(f"field {name!r} changes location or rank between frames{hint}")
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
        ints = integer[name] and all(name in e[2] for e in loaded)
        fill, dtype = (-1, np.int32) if ints else (np.nan, np.float64)
        if nsolid:
            dims = ("time", "solid", *sdims)
            buf = np.full((nt, nsolid_all, *shape2), fill, dtype=dtype)
        else:
            dims = ("time", *sdims)
            buf = np.full((nt, *shape2), fill, dtype=dtype)
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
    for *_, small, small_dims, _ in loaded:
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
        for t, (*_, small, _, _) in enumerate(loaded):
            arr = small.get(name)
            if arr is not None:
                buf[(t, *(slice(0, k) for k in arr.shape))] = arr
        data_vars[name] = xr.Variable(("time", *dims), buf, attrs={"diagnostic": True})

    # the solids' windows (windows=True): (time, solid, [component,] window axes), NaN (or
    # -1 for an origin) where a frame lacks them or holds fewer solids
    win_sizes: dict[str, int] = {}
    if windows and any(e[6] for e in loaded):
        comp = ("xy", "xyz")[grid.ndim - 2]
        waxes = tuple(f"w{a}" for a in ("x", "y", "z")[: grid.ndim])
        wins = [e[6] for e in loaded]
        first = next(w for w in wins if w)
        S = max(w["phi_window"].shape[0] for w in wins if w)
        Wmax = tuple(max(w["phi_window"].shape[1 + a] for w in wins if w) for a in range(grid.ndim))
        win_attrs = {"window": True, "far": first["far"], "periodic": np.asarray(first["periodic"], dtype=bool)}
        specs = {
            "phi_window": (("solid", *waxes), (S, *Wmax), np.nan, np.float64),
            "xi_window": (("solid", comp, *waxes), (S, grid.ndim, *Wmax), np.nan, np.float64),
            "origin": (("solid", comp), (S, grid.ndim), -1, np.int32),
        }
        for name, (dims, shape, fill, dtype) in specs.items():
            if wanted is not None and name not in wanted:
                continue
            if name in data_vars:
                raise ValueError(f"{name!r} is both a field or diagnostics array and a window array")
            buf = np.full((nt, *shape), fill, dtype=dtype)
            for t, w in enumerate(wins):
                if w:
                    arr = w[name]
                    buf[(t, *(slice(0, k) for k in arr.shape))] = arr
            data_vars[name] = xr.Variable(("time", *dims), buf, attrs=dict(win_attrs))
        win_sizes = {"solid": S, comp: grid.ndim}
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
    sizes.update(win_sizes)
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


def _frame_source(source) -> tuple[float, dict[str, np.ndarray], dict[str, Any]]:
    """A frame path, or the ``(time, fields, attrs)`` of :func:`read_frame`."""
    if isinstance(source, tuple) and len(source) == 3:
        return source
    return read_frame(source)


def _window_index(origin, size, shape, periodic) -> tuple[np.ndarray, ...]:
    """``np.ix_`` indices of a window's nodes ``origin .. origin + size - 1`` (a periodic
    axis wraps round): :func:`refmap.windows.index` in numpy."""
    idx = []
    for a, (o, w, n) in enumerate(zip(origin, size, shape, strict=True)):
        node = int(o) + np.arange(w)
        idx.append(node % n if periodic[a] else node)
    return np.ix_(*idx)


def per_solid_fields(source, solid: int | None = None) -> dict[str, np.ndarray]:
    """Each solid's whole-grid level set and reference map of one frame: ``{"phi", "xi_x",
    "xi_y"[, "xi_z"]}``, arrays ``(S, *grid)``, or ``(*grid)`` of the one ``solid`` given.

    ``source``: a frame path or the ``(time, fields, attrs)`` of :func:`read_frame`.  A
    frame of solids on the grid stores these fields; one of solids stored in windows holds
    only their union on the grid, and they are rebuilt from its windows exactly as
    ``Model.on_grid`` places them: each window's values where it lies (wrapping round a
    periodic axis), ``far`` (``phi_max h``) and the identity map ``xi = x`` elsewhere, NaN
    for a solid whose origin is -1 (it outgrew its window).  ``solid=`` builds that one
    solid's fields only (``(*grid)`` each: a thousand solids on a large grid do not fit in
    memory at once).  ValueError for a frame without solids or a solid out of range.
    """
    _, fields, attrs = _frame_source(source)
    grid = grid_from_attrs(attrs)
    nd = grid.ndim
    comps = [f"xi_{a}" for a in "xyz"[:nd]]
    win = attrs.get("windows") or {}
    if not win:
        if "phi" not in fields or fields["phi"].ndim != nd + 1:
            raise ValueError("the frame holds no per-solid level sets (a run without solids, or "
                             "a frame of solids in windows read with windows=False)")
        S = fields["phi"].shape[0]
        pick = slice(None) if solid is None else _check_solid(solid, S)
        return {name: fields[name][pick] for name in ("phi", *comps)}
    phi_w, xi_w, origin = win["phi_window"], win["xi_window"], win["origin"]
    S = phi_w.shape[0]
    solids = range(S) if solid is None else [_check_solid(solid, S)]
    shape = tuple(grid.shape())
    X = np.stack(grid.mesh("node"))
    phi = np.empty((len(solids), *shape))
    xi = np.empty((len(solids), nd, *shape))
    for i, k in enumerate(solids):
        phi[i] = win["far"]
        xi[i] = X
        if np.all(origin[k] >= 0):
            idx = _window_index(origin[k], phi_w.shape[1:], shape, win["periodic"])
            phi[i][idx] = phi_w[k]
            for a in range(nd):
                xi[i, a][idx] = xi_w[k, a]
        else:
            phi[i] = np.nan
    out = {"phi": phi, **{c: xi[:, a] for a, c in enumerate(comps)}}
    return out if solid is None else {name: a[0] for name, a in out.items()}


def _check_solid(solid, S: int) -> int:
    if not (isinstance(solid, (int, np.integer)) and 0 <= solid < S):
        raise ValueError(f"solid {solid!r} does not exist; the frame has solids 0..{S - 1}")
    return int(solid)


def read_state(source):
    """The :class:`~refmap.state.State` a frame written by
    :class:`refmap.simulation.Simulation` was made from, to start a run from it
    (``Simulation(case, out_dir, state=read_state(path))``, docs/restart.md).

    ``source``: a frame path or the ``(time, fields, attrs)`` of :func:`read_frame`.  ``t``,
    ``step`` (the frame attribute), ``v`` from ``u``, ``v``[, ``w``], ``rho_f``, and the
    solids: from the per-solid ``xi_*`` and ``phi`` of a frame of solids on the grid, or the
    windows and their origins of one of solids stored in windows (a windowed State, as the
    run held it).  Every value is the state's own, bit for bit; the incompressible fluid's
    pressure of the last step (``State.p``) is not in a frame, so such a run restarts from
    zero there (the first step solves for the whole pressure) and continues close to, not
    bit for bit as, the original.  ValueError for a frame without them.
    """
    import jax.numpy as jnp

    from refmap.state import State

    time, fields, attrs = _frame_source(source)
    grid = grid_from_attrs(attrs)
    nd = grid.ndim
    comps = "xyz"[:nd]
    need = [*"uvw"[:nd], "rho_f"]
    missing = [n for n in need if n not in fields]
    if missing:
        raise ValueError(f"the frame has no {missing}: not a frame written by refmap.simulation")

    def f64(a):
        return jnp.asarray(a, dtype=jnp.float64)

    win = attrs.get("windows") or {}
    origin = None
    if win:
        xi, phi = win["xi_window"], win["phi_window"]
        origin = jnp.asarray(win["origin"], dtype=jnp.int32)
    elif "phi" in fields and fields["phi"].ndim == nd + 1:
        xi = np.stack([fields[f"xi_{a}"] for a in comps], axis=1)
        phi = fields["phi"]
    elif "phi" in fields or "solid_index" in fields:
        raise ValueError("the frame's solids are stored in windows, but it was read with windows=False")
    else:  # no solids
        xi = np.zeros((0, nd, *grid.shape()))
        phi = np.zeros((0, *grid.shape()))
    return State(
        t=jnp.asarray(time, dtype=jnp.float64),
        step=jnp.asarray(int(attrs.get("step", 0)), dtype=jnp.int64),
        v=f64(np.stack([fields[c] for c in "uvw"[:nd]])),
        rho_f=f64(fields["rho_f"]),
        xi=f64(xi),
        phi=f64(phi),
        origin=origin,
    )


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
