"""Small pieces shared by the writer, the reader and the pictures: file names, the on-disk
layout of a frame, atomic replacement of a file and JSON conversion of odd values."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from refmap.grid import Grid

FORMAT = "refmap-frame-1"
FRAMES_DIR = "frames"
METADATA_FILE = "metadata.json"
XDMF_FILE = "run.xdmf"
DIAGNOSTICS_FILE = "diagnostics.csv"
TMP_SUFFIX = ".tmp"

GRID_KEYS = ("nx", "ny", "ax", "bx", "ay", "by", "dx", "dy")
RESERVED_FRAME_ATTRS = frozenset(
    ("time", "index", "format", "layout", "locations", "diagnostics", "diagnostic_dims", *GRID_KEYS)
)
#: HDF5 group of a frame's small per-solid / per-pair arrays
DIAGNOSTICS_GROUP = "diagnostics"

FRAME_RE = re.compile(r"^frame_(\d+)\.h5$")


def frame_name(index: int) -> str:
    return f"frame_{index:05d}.h5"


def grid_attrs(grid: Grid) -> dict[str, float | int]:
    """The grid as plain numbers (nx, ny, ax, bx, ay, by, dx, dy)."""
    return {
        "nx": int(grid.nx),
        "ny": int(grid.ny),
        "ax": float(grid.ax),
        "bx": float(grid.bx),
        "ay": float(grid.ay),
        "by": float(grid.by),
        "dx": float(grid.dx),
        "dy": float(grid.dy),
    }


def grid_from_attrs(attrs: Any) -> Grid:
    """Rebuild a :class:`~refmap.grid.Grid` from a mapping holding nx, ny, ax, bx, ay, by
    (frame attributes, ``open_run(...).attrs`` or the ``"grid"`` entry of metadata.json)."""
    try:
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


def infer_location(grid: Grid, name: str, shape: tuple[int, ...]) -> tuple[str, bool]:
    """Return (location, per_solid) of an array of the given shape, or raise ValueError."""
    if len(shape) in (2, 3):
        tail = tuple(shape[-2:])
        per_solid = len(shape) == 3
        if tail == (grid.nx, grid.ny):
            return "node", per_solid
        if tail == (grid.nx + 1, grid.ny + 1):
            return "corner", per_solid
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
