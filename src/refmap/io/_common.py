"""Small pieces shared by the writer, the reader and the pictures: file names, the on-disk
layout of a frame (2D :class:`~refmap.grid.Grid` or 3D :class:`~refmap.grid.Grid3D`), atomic
replacement of a file and JSON conversion of odd values."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from refmap.grid import Grid, Grid3D

FORMAT = "refmap-frame-1"
FRAMES_DIR = "frames"
METADATA_FILE = "metadata.json"
XDMF_FILE = "run.xdmf"
DIAGNOSTICS_FILE = "diagnostics.csv"
TMP_SUFFIX = ".tmp"

GRID_KEYS = ("nx", "ny", "ax", "bx", "ay", "by", "dx", "dy")
#: the grid keys a 3D frame adds (attributes holding nz, az and bz describe a 3D grid)
GRID_KEYS_3D = ("nz", "az", "bz", "dz")
RESERVED_FRAME_ATTRS = frozenset(
    ("time", "index", "format", "layout", "locations", "diagnostics", "diagnostic_dims", "windows",
     *GRID_KEYS)
)
#: reserved attribute names of a 3D frame (the 2D set is left as it was)
RESERVED_FRAME_ATTRS_3D = RESERVED_FRAME_ATTRS | frozenset(GRID_KEYS_3D)
#: HDF5 group of a frame's small per-solid / per-pair arrays
DIAGNOSTICS_GROUP = "diagnostics"
#: HDF5 group of a frame's solid windows (solids stored in windows; refmap.io.writer)
WINDOWS_GROUP = "windows"

FRAME_RE = re.compile(r"^frame_(\d+)\.h5$")


def frame_name(index: int) -> str:
    return f"frame_{index:05d}.h5"


def grid_attrs(grid: Grid | Grid3D) -> dict[str, float | int]:
    """The grid as plain numbers: nx, ny, ax, bx, ay, by, dx, dy, and for a 3D grid also
    nz, az, bz, dz (the 2D dict is exactly as it always was)."""
    out = {
        "nx": int(grid.nx),
        "ny": int(grid.ny),
        "ax": float(grid.ax),
        "bx": float(grid.bx),
        "ay": float(grid.ay),
        "by": float(grid.by),
        "dx": float(grid.dx),
        "dy": float(grid.dy),
    }
    if grid.ndim == 3:
        out.update(nz=int(grid.nz), az=float(grid.az), bz=float(grid.bz), dz=float(grid.dz))
    return out


def grid_from_attrs(attrs: Any) -> Grid | Grid3D:
    """Rebuild the grid from a mapping holding nx, ny, ax, bx, ay, by (frame attributes,
    ``open_run(...).attrs`` or the ``"grid"`` entry of metadata.json): a
    :class:`~refmap.grid.Grid3D` when it also holds nz, az and bz, else a
    :class:`~refmap.grid.Grid`."""
    try:
        if frame_ndim(attrs) == 3:
            return Grid3D(
                int(attrs["nx"]),
                int(attrs["ny"]),
                int(attrs["nz"]),
                float(attrs["ax"]),
                float(attrs["bx"]),
                float(attrs["ay"]),
                float(attrs["by"]),
                float(attrs["az"]),
                float(attrs["bz"]),
            )
        return Grid(
            int(attrs["nx"]),
            int(attrs["ny"]),
            float(attrs["ax"]),
            float(attrs["bx"]),
            float(attrs["ay"]),
            float(attrs["by"]),
        )
    except KeyError as exc:
        raise ValueError(f"no grid description in these attributes (missing {exc})") from None


def frame_ndim(attrs: Any) -> int:
    """2 or 3: the dimension of the grid a mapping of grid keys describes.  3 needs all of
    nz, az and bz, so a 2D frame whose caller attributes (or a 2D run whose metadata) happen
    to use one of those names still reads as 2D, as it did before 3D output existed."""
    return 3 if all(k in attrs for k in ("nz", "az", "bz")) else 2


def to_disk(arr: np.ndarray, ndim: int) -> np.ndarray:
    """Reverse the last ``ndim`` axes (``[..., i, j]`` -> ``[..., j, i]``, ``[..., i, j, k]``
    -> ``[..., k, j, i]``), C-contiguous.  Its own inverse: the reader undoes it with the
    same call."""
    lead = arr.ndim - ndim
    order = (*range(lead), *range(arr.ndim - 1, lead - 1, -1))
    return np.ascontiguousarray(np.transpose(arr, order))


def infer_location(grid: Grid | Grid3D, name: str, shape: tuple[int, ...]) -> tuple[str, bool]:
    """Return (location, per_solid) of an array of the given shape, or raise ValueError."""
    d = grid.ndim
    if len(shape) in (d, d + 1):
        tail = tuple(shape[-d:])
        per_solid = len(shape) == d + 1
        if tail == tuple(grid.shape("node")):
            return "node", per_solid
        if tail == tuple(grid.shape("corner")):
            return "corner", per_solid
    if d == 3:
        raise ValueError(
            f"field {name!r} has shape {tuple(shape)}; expected a node field (nx, ny, nz) = "
            f"{tuple(grid.shape('node'))} or corner field (nx+1, ny+1, nz+1) = "
            f"{tuple(grid.shape('corner'))}, optionally with one leading solid axis"
        )
    raise ValueError(
        f"field {name!r} has shape {tuple(shape)}; expected a node field (nx, ny) = "
        f"({grid.nx}, {grid.ny}) or corner field (nx+1, ny+1) = ({grid.nx + 1}, {grid.ny + 1}), "
        "optionally with one leading solid axis"
    )


def json_default(obj: Any) -> Any:
    """``json.dumps`` fallback for numpy values, paths, dataclasses and the like."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.asdict(obj)
    if isinstance(obj, (set, frozenset)):
        return sorted(obj, key=repr)
    if hasattr(obj, "model_dump"):  # pydantic models
        return obj.model_dump()
    if hasattr(obj, "__array__"):  # jax arrays and friends
        return np.asarray(obj).tolist()
    return str(obj)


def to_json(obj: Any, **kw) -> str:
    return json.dumps(obj, default=json_default, **kw)


def file_mode() -> int:
    """The mode a plainly created file gets under the current umask (0644 under the usual
    022).  ``tempfile.mkstemp`` creates its files 0600 and ``os.replace`` keeps that mode,
    so every file written through a temporary name is given this mode before it is moved
    into place (data files readable by the owner only surprised users sharing a run)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def make_temp(final: Path, suffix: str = TMP_SUFFIX) -> str:
    """A closed, empty temporary file next to ``final`` with the umask's mode; its path."""
    final = Path(final)
    fd, tmp = tempfile.mkstemp(prefix=f".{final.name}.", suffix=suffix, dir=final.parent)
    try:
        os.fchmod(fd, file_mode())
    finally:
        os.close(fd)
    return tmp


def atomic_write_bytes(path: Path, data: bytes, fsync: bool = False) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and
    ``os.replace``, so readers see either the old file or the complete new one."""
    path = Path(path)
    tmp = make_temp(path)
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            if fsync:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
