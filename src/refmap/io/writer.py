"""Writing a run to disk: one HDF5 file per saved frame, an XDMF index for ParaView/VisIt,
the run's metadata and a CSV of per-step diagnostics.

Folder layout::

    run_dir/
        metadata.json          caller's metadata + "created" (UTC, ISO 8601) + "grid"
        diagnostics.csv        one row per append_diagnostics() call
        run.xdmf               XDMF 3 temporal collection over every frame written so far
        frames/frame_00000.h5  one file per write_frame() call
        frames/frame_00001.h5
        ...

Frame file layout (HDF5)::

    /            attrs: format, layout, time, index, nx, ny, ax, bx, ay, by, dx, dy,
                        plus the caller's extra attrs
    /x, /y       node (cell-centre) axes, lengths nx and ny
    /xc, /yc     corner axes, lengths nx+1 and ny+1
    /fields/<name>  float64 (int32 for an integer field, e.g. solid_index), attrs location
                    ("node"|"corner"), per_solid (bool), dims
    /diagnostics/<name>  optional small float64 arrays (per-solid, per-pair numbers), attr
                     dims (axis names, space-separated, e.g. "solid other_solid"), stored
                     as given (not transposed)
    /xdmf/zero_<loc>  zeros used only as the third velocity component in run.xdmf
    /windows/<name>  optional: the solids stored in windows (see below)

Solids stored in windows (``Numerics.solid_storage = "window"``; docs/restart.md).  Such a
run cannot write S whole-grid level sets and maps a frame (8 GB a field at 1000 discs on
1024^2), so :class:`refmap.simulation.Simulation` writes, whatever the number of solids,
the grid fields ``phi`` (the union level set, the least of the solids'), ``solid_index``
(int32: the solid giving it, -1 where none is within ``phi_max h``) and ``J`` (the nearest
solid's) in ``/fields``, and the windows themselves in ``/windows``: ``phi_window``
``(S, *W)`` and ``xi_window`` ``(S, d, *W)`` (float64), ``origin`` ``(S, d)`` (int32, each
window's first node; a periodic axis wraps round; -1 for a body that outgrew its window),
with group attrs ``far`` (``phi_max h``, a level set's value outside its window) and
``periodic`` (one flag per axis).  These are stored in the solver's order, *not*
transposed (dims attrs ``"solid wx wy"``, ``"solid xy wx wy"``, ``"solid xy"``; 3D
``wz`` and ``xyz``), as a checkpoint holds them; the group is not in run.xdmf.
:func:`refmap.io.per_solid_fields` rebuilds each solid's whole-grid ``phi`` and ``xi_*``
from them, exactly as ``Model.on_grid`` does, and :func:`refmap.io.read_state` the
State.  A run whose solids are on the grid writes the per-solid fields as before and no
``/windows``.

Axis order on disk.  The solver's arrays are indexed ``[i, j]`` (i along x).  XDMF and
ParaView read a structured block with x varying fastest, i.e. a C-ordered ``[j, i]`` array,
and an XDMF HyperSlab can select but cannot transpose.  So each field is stored *transposed
in its last two axes*: a node field of shape ``(nx, ny)`` is saved as an ``(ny, nx)``
dataset, a per-solid corner field ``(nsolid, nx+1, ny+1)`` as ``(nsolid, ny+1, nx+1)``.  The
dataset attribute ``dims`` spells this out (e.g. ``"solid yc xc"``) and
:func:`refmap.io.read_frame` / :func:`refmap.io.open_run` undo the transpose, so Python users
always get ``[i, j]`` arrays back.  With this layout the XDMF description is direct: the
2DCoRectMesh has ``Dimensions="ny+1 nx+1"``, ``Origin="ay ax"``, ``Spacing="dy dx"`` (XDMF
lists the slowest axis first), corner fields are ``Center="Node"`` attributes of shape
``(ny+1, nx+1)`` and node fields ``Center="Cell"`` attributes of shape ``(ny, nx)``.
Per-solid fields appear in the XDMF as ``name_0``, ``name_1``, ... through HyperSlabs of the
3D dataset.  When scalar fields ``u`` and ``v`` exist at the same location, a 3-component
``velocity`` vector (u, v, 0) is added with an XDMF ``JOIN`` function.

Every file is written under a temporary name in its final folder and then moved into place
with ``os.replace``; killing the process mid-write leaves at most a ``*.tmp`` file, never a
half-written file under a final name.

Three dimensions (a :class:`~refmap.grid.Grid3D`).  The same layout with one more axis.  The
file attributes add ``nz, az, bz, dz`` (a frame holding nz, az and bz is read as 3D) and the
layout string says ``[..., k, j, i]``; the axes add ``/z`` (length nz) and ``/zc`` (nz+1).
Fields are indexed ``[i, j, k]``: node fields ``(nx, ny, nz)``, corner fields
``(nx+1, ny+1, nz+1)``, per-solid fields with a leading solid axis (so a 4D array is
per-solid).  Each field is stored with its *last three axes reversed* (z slowest, x fastest):
a node field ``(nx, ny, nz)`` is saved as ``(nz, ny, nx)``, a per-solid corner field
``(nsolid, nx+1, ny+1, nz+1)`` as ``(nsolid, nz+1, ny+1, nx+1)``, with ``dims`` ``"z y x"``,
``"solid zc yc xc"`` and so on; the reader reverses them back.  run.xdmf describes a
``3DCoRectMesh`` with ``Dimensions="nz+1 ny+1 nx+1"``, ``Origin="az ay ax"``,
``Spacing="dz dy dx"`` (GeometryType ``ORIGIN_DXDYDZ``); corner fields are ``Center="Node"``
attributes of shape ``(nz+1, ny+1, nx+1)``, node fields ``Center="Cell"`` ones of shape
``(nz, ny, nx)``, per-solid fields HyperSlabs of the 4D dataset.  The ``velocity`` vector is
``JOIN(u, v, w)`` when scalar fields ``u``, ``v`` and ``w`` exist at the same location (no
``/xdmf`` zero dataset is written in 3D).  The diagnostics dims ``z`` and ``zc`` are
reserved too, and per-solid vectors use the axis name ``"xyz"`` (``("solid", "xyz")``).
"""

from __future__ import annotations

import csv
import operator
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from refmap.grid import Grid, Grid3D
from refmap.io._common import (
    DIAGNOSTICS_FILE,
    DIAGNOSTICS_GROUP,
    FORMAT,
    FRAME_RE,
    FRAMES_DIR,
    METADATA_FILE,
    RESERVED_FRAME_ATTRS,
    RESERVED_FRAME_ATTRS_3D,
    TMP_SUFFIX,
    WINDOWS_GROUP,
    XDMF_FILE,
    atomic_write_bytes,
    frame_name,
    grid_attrs,
    infer_location,
    make_temp,
    to_disk,
    to_json,
)

__all__ = ["RunWriter", "build_xdmf"]

#: files of a run that are not the writer's own but describe the run it replaces; removed
#: with ``overwrite=True`` (names as in refmap.checkpoint and refmap.simulation)
RUN_STATE_FILES = ("checkpoint.h5", "checkpoint.prev.h5", "summary.json")


def _compression_options(compression: str | None, level: int) -> dict:
    if compression is None:
        return {}
    if compression == "gzip":
        return {"compression": "gzip", "compression_opts": int(level), "shuffle": True}
    if compression == "lzf":
        return {"compression": "lzf", "shuffle": True}
    raise ValueError(f"compression must be 'gzip', 'lzf' or None, got {compression!r}")


@dataclass(frozen=True)
class _FieldRecord:
    name: str
    location: str  # "node" | "corner"
    nsolid: int  # 0 for a field without a solid axis
    number: str = "Float"  # XDMF NumberType and Precision of the dataset
    precision: int = 8


def xdmf_number(dtype) -> tuple[str, int]:
    """XDMF ``(NumberType, Precision)`` of a field dataset's dtype: ``("Int", 4)`` for the
    int32 of an integer field, ``("Float", 8)`` for float64."""
    dtype = np.dtype(dtype)
    return ("Int", dtype.itemsize) if dtype.kind in "iu" else ("Float", dtype.itemsize)


def _field_array(name: str, value: Any) -> np.ndarray:
    """A field as stored: int32 for integer or boolean values (a solid index), float64
    otherwise (ValueError for integers outside int32's range)."""
    arr = np.asarray(value)
    if arr.dtype.kind in "biu":
        if arr.size and (arr.min() < np.iinfo(np.int32).min or arr.max() > np.iinfo(np.int32).max):
            raise ValueError(f"integer field {name!r} does not fit int32")
        return arr.astype(np.int32)
    return np.asarray(value, dtype=np.float64)


#: the arrays of a frame's window group, and its attributes
WINDOW_ARRAYS = ("phi_window", "xi_window", "origin")
WINDOW_ATTRS = ("far", "periodic")


def _prepare_windows(windows: dict, ndim: int) -> tuple[dict, dict]:
    """``({name: (dims, array)}, attrs)`` of a frame's ``windows`` argument, checked."""
    keys = set(windows)
    want = set(WINDOW_ARRAYS) | set(WINDOW_ATTRS)
    if keys != want:
        raise ValueError(f"windows must hold exactly {sorted(want)}, got {sorted(keys)}")
    phi = np.asarray(windows["phi_window"], dtype=np.float64)
    xi = np.asarray(windows["xi_window"], dtype=np.float64)
    origin = np.asarray(windows["origin"])
    if phi.ndim != ndim + 1:
        raise ValueError(f"phi_window must be (S, *W) with {ndim} window axes, got {phi.shape}")
    S, W = phi.shape[0], phi.shape[1:]
    if xi.shape != (S, ndim, *W):
        raise ValueError(f"xi_window must be {(S, ndim, *W)} (phi_window {phi.shape}), got {xi.shape}")
    if origin.shape != (S, ndim) or origin.dtype.kind not in "iu":
        raise ValueError(f"origin must be {(S, ndim)} integers, got {origin.shape} {origin.dtype}")
    periodic = np.asarray(windows["periodic"], dtype=bool)
    if periodic.shape != (ndim,):
        raise ValueError(f"periodic must hold one flag per axis ({ndim}), got {periodic.shape}")
    comp, axes = ("xy", "wx wy") if ndim == 2 else ("xyz", "wx wy wz")
    arrays = {
        "phi_window": (f"solid {axes}", phi),
        "xi_window": (f"solid {comp} {axes}", xi),
        "origin": (f"solid {comp}", origin.astype(np.int32)),
    }
    return arrays, {"far": float(windows["far"]), "periodic": periodic}


@dataclass(frozen=True)
class _FrameRecord:
    index: int
    time: float
    relpath: str  # relative to run_dir, forward slashes
    fields: tuple[_FieldRecord, ...]
    velocity_zero: str | None  # dataset path of the zero component, or None


def _disk_dims(location: str, per_solid: bool, ndim: int = 2) -> str:
    names = "zyx"[3 - ndim :]
    base = " ".join(a if location == "node" else f"{a}c" for a in names)
    return f"solid {base}" if per_solid else base


def _h5_attr_value(value: Any) -> Any:
    """Turn a caller attribute into something h5py stores natively (else a JSON string)."""
    if isinstance(value, (str, bool, int, float, np.generic)):
        return value
    if isinstance(value, np.ndarray) and value.dtype.kind in "biuf":
        return value
    if isinstance(value, (list, tuple)):
        arr = np.asarray(value)
        if arr.dtype.kind in "biuf" and arr.ndim >= 1:
            return arr
    if hasattr(value, "__array__") and not isinstance(value, (dict, list, tuple)):
        arr = np.asarray(value)
        if arr.dtype.kind in "biuf":
            return arr.item() if arr.ndim == 0 else arr
    return to_json(value)


def _csv_value(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, np.generic):
        return value.item()
    if hasattr(value, "__array__") and not isinstance(value, (str, bytes)):
        arr = np.asarray(value)
        if arr.ndim == 0:
            return arr.item()
        return to_json(arr)
    return value


def _prepare_diagnostics(diagnostics: dict, fields: dict, ndim: int = 2) -> dict:
    """``{name: (dims, float64 array)}`` from a frame's ``diagnostics`` argument, checked."""
    out = {}
    for name, value in diagnostics.items():
        if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
            raise ValueError(f"invalid diagnostics name {name!r}")
        if name in fields:
            raise ValueError(f"diagnostics name {name!r} is also a field name")
        dims = None
        if isinstance(value, tuple) and len(value) == 2 and isinstance(value[0], (tuple, list)):
            dims, value = value
        arr = np.asarray(value, dtype=np.float64)
        if dims is None:
            dims = tuple(f"{name}_dim{k}" for k in range(arr.ndim))
        dims = tuple(str(d) for d in dims)
        if len(dims) != arr.ndim or not all(d and d.isidentifier() for d in dims):
            raise ValueError(
                f"diagnostics {name!r}: dims {dims!r} must name each of its {arr.ndim} axes "
                "(identifiers)"
            )
        reserved = {"time", "x", "y", "xc", "yc"}
        if ndim == 3:
            reserved |= {"z", "zc"}
        taken = sorted(reserved.intersection(dims))
        if taken:
            raise ValueError(f"diagnostics {name!r}: dims {taken} are reserved for the grid/time")
        out[name] = (dims, arr)
    return out


class RunWriter:
    """Writes the output of one simulation run into ``run_dir``.

    Parameters
    ----------
    run_dir:
        Output folder.  Created if missing.  If it exists and is not empty a
        ``FileExistsError`` is raised, unless ``overwrite=True``, in which case the files
        this class owns (metadata.json, run.xdmf, diagnostics.csv, frames/frame_*.h5 and
        leftover ``*.tmp`` files) and those that describe the old run (checkpoint.h5,
        checkpoint.prev.h5, summary.json) are deleted first; anything else in the folder is
        kept.  A path that exists and is not a folder raises ``FileExistsError`` either way.
    grid:
        The :class:`~refmap.grid.Grid` (2D) or :class:`~refmap.grid.Grid3D` every frame
        lives on.
    metadata:
        Anything JSON-able that describes the run (input parameters, package versions,
        command line, ...).  Saved as metadata.json together with the creation time
        (``"created"``) and the grid (``"grid"``, unless the caller already supplied one).
        numpy values, paths, dataclasses and pydantic models are converted.
    compression, compression_level:
        HDF5 filter for the field datasets: ``"gzip"`` (default, level 1, with byte
        shuffling; readable by ParaView/VisIt), ``"lzf"`` (faster, but only h5py reads it)
        or None (fastest, largest).  Full-precision float64 data shrink little, smooth or
        mostly constant fields (level sets far away, stresses outside the solids) a lot.

    The writer is also a context manager; leaving the ``with`` block calls :meth:`close`.
    See the module docstring for the file layout and the axis order on disk.
    """

    def __init__(
        self,
        run_dir: str | os.PathLike,
        grid: Grid | Grid3D,
        metadata: dict | None = None,
        *,
        overwrite: bool = False,
        compression: str | None = "gzip",
        compression_level: int = 1,
    ):
        self.run_dir = Path(run_dir)
        self.grid = grid
        self.frames_dir = self.run_dir / FRAMES_DIR
        self._compression = _compression_options(compression, compression_level)
        self._frames: dict[int, _FrameRecord] = {}
        self._diag_file = None
        self._diag_writer = None
        self._diag_header: list[str] | None = None
        self._closed = False

        if self.run_dir.exists():
            if not self.run_dir.is_dir():
                raise FileExistsError(f"{self.run_dir} exists and is not a folder")
            if any(self.run_dir.iterdir()):
                if not overwrite:
                    raise FileExistsError(
                        f"run folder {self.run_dir} is not empty; pass overwrite=True to replace "
                        "its run files"
                    )
                self._remove_own_files()
        self.frames_dir.mkdir(parents=True, exist_ok=True)

        meta = dict(metadata or {})
        meta["created"] = datetime.now(UTC).isoformat(timespec="seconds")
        meta.setdefault("grid", grid_attrs(grid))
        self.metadata = meta
        atomic_write_bytes(
            self.run_dir / METADATA_FILE,
            (to_json(meta, indent=2, sort_keys=False) + "\n").encode(),
            fsync=True,
        )

    # ------------------------------------------------------------------ housekeeping
    def _remove_own_files(self) -> None:
        # the run's checkpoints and summary go with its frames: a checkpoint left behind
        # would let `refmap resume` continue the old run in the new run's folder
        for name in (METADATA_FILE, XDMF_FILE, DIAGNOSTICS_FILE, *RUN_STATE_FILES):
            p = self.run_dir / name
            if p.is_file():
                p.unlink()
        for p in self.run_dir.glob(f".*{TMP_SUFFIX}"):
            if p.is_file():
                p.unlink()
        if self.frames_dir.is_dir():
            for p in self.frames_dir.iterdir():
                if p.is_file() and (FRAME_RE.match(p.name) or p.name.endswith(TMP_SUFFIX)):
                    p.unlink()

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"RunWriter for {self.run_dir} is closed")

    @property
    def frame_indices(self) -> list[int]:
        """Indices of the frames written by this writer, in increasing order."""
        return sorted(self._frames)

    # ------------------------------------------------------------------ frames
    def write_frame(
        self,
        index: int,
        time: float,
        fields: dict[str, Any],
        attrs: dict | None = None,
        diagnostics: dict[str, Any] | None = None,
        windows: dict[str, Any] | None = None,
    ) -> Path:
        """Save one snapshot as ``frames/frame_{index:05d}.h5`` and refresh run.xdmf.

        ``fields`` maps names to arrays indexed ``[i, j]``: node fields ``(nx, ny)``, corner
        fields ``(nx+1, ny+1)``, per-solid fields with a leading solid axis.  A 3D array is
        always taken as per-solid, so vector fields must be split into components (``u``,
        ``v``) first.  On a 3D grid the arrays are indexed ``[i, j, k]``: ``(nx, ny, nz)``,
        ``(nx+1, ny+1, nz+1)``, a 4D array is per-solid and velocity comes as ``u``, ``v``,
        ``w``.  Values are stored as float64, integer (and boolean) ones as int32 (run.xdmf
        then says ``NumberType="Int"``).  Any other shape raises ValueError naming the
        field.  ``attrs`` are extra scalar/array/string attributes for the file (other
        values are stored as JSON strings); they may not reuse the reserved names time,
        index, format, layout, locations, diagnostics, diagnostic_dims, windows or the grid
        keys (in 3D also nz, az, bz, dz).

        ``diagnostics`` maps names to small arrays of numbers that belong to the frame but
        live on no grid (per-solid centroids, contact forces, per-pair gaps...): each value
        is an array, or a pair ``(dims, array)`` naming its axes (``("solid", "xy")``, in
        3D ``("solid", "xyz")``; default ``NAME_dim0``, ...).  They are stored in
        ``/diagnostics`` as float64 and come back from :func:`refmap.io.read_frame`
        (``attrs["diagnostics"]``) and :func:`refmap.io.open_run` (variables with dims
        ``("time", *dims)``).  A name may not also be a field name.

        ``windows`` (solids stored in windows, see the module docstring): a dict with the
        arrays ``phi_window`` ``(S, *W)``, ``xi_window`` ``(S, d, *W)``, ``origin`` ``(S, d)``
        (integers) in the solver's order, and ``far`` (a float) and ``periodic`` (one bool
        per axis); written to the group ``/windows``, not listed in run.xdmf.

        Writing an index again replaces that frame.  Returns the path of the frame file.
        """
        self._check_open()
        index = operator.index(index)
        if index < 0:
            raise ValueError(f"frame index must be >= 0, got {index}")
        time = float(time)
        attrs = dict(attrs or {})
        ndim = self.grid.ndim
        reserved = RESERVED_FRAME_ATTRS_3D if ndim == 3 else RESERVED_FRAME_ATTRS
        clash = sorted(reserved.intersection(attrs))
        if clash:
            raise ValueError(f"frame attrs use reserved names: {clash}")

        prepared: list[tuple[_FieldRecord, np.ndarray]] = []
        for name, value in fields.items():
            if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
                raise ValueError(f"invalid field name {name!r}")
            arr = _field_array(name, value)
            location, per_solid = infer_location(self.grid, name, arr.shape)
            disk = to_disk(arr, ndim)
            rec = _FieldRecord(name, location, arr.shape[0] if per_solid else 0, *xdmf_number(disk.dtype))
            prepared.append((rec, disk))

        by_name = {rec.name: rec for rec, _ in prepared}
        small = _prepare_diagnostics(diagnostics or {}, by_name, ndim)
        win = None if windows is None else _prepare_windows(windows, ndim)
        zero_loc = None  # 2D only: the velocity vector's zero third component
        u, v = by_name.get("u"), by_name.get("v")
        if ndim == 2 and u and v and u.nsolid == 0 and v.nsolid == 0 and u.location == v.location:
            zero_loc = u.location

        final = self.frames_dir / frame_name(index)
        tmp = make_temp(final)
        try:
            with h5py.File(tmp, "w") as f:
                f.attrs["format"] = FORMAT
                f.attrs["layout"] = (
                    "fields stored transposed in the last two axes: [..., j, i]"
                    if ndim == 2
                    else "fields stored with the last three axes reversed: [..., k, j, i]"
                )
                f.attrs["time"] = time
                f.attrs["index"] = index
                for k, val in grid_attrs(self.grid).items():
                    f.attrs[k] = val
                for k, val in attrs.items():
                    f.attrs[str(k)] = _h5_attr_value(val)
                names = "xyz"[:ndim]
                axes = [*zip(names, self.grid.axes("node"), strict=True)]
                axes += [(f"{a}c", c) for a, c in zip(names, self.grid.axes("corner"), strict=True)]
                for k, val in axes:
                    f.create_dataset(k, data=val)
                g = f.create_group("fields")
                for rec, disk in prepared:
                    ds = g.create_dataset(rec.name, data=disk, **self._compression)
                    ds.attrs["location"] = rec.location
                    ds.attrs["per_solid"] = bool(rec.nsolid)
                    ds.attrs["dims"] = _disk_dims(rec.location, bool(rec.nsolid), ndim)
                if small:
                    dg = f.create_group(DIAGNOSTICS_GROUP)
                    for name, (dims, arr) in small.items():
                        ds = dg.create_dataset(name, data=arr)
                        ds.attrs["dims"] = " ".join(dims)
                if win is not None:
                    wg = f.create_group(WINDOWS_GROUP)
                    for name, (dims, arr) in win[0].items():
                        ds = wg.create_dataset(name, data=arr, **self._compression)
                        ds.attrs["dims"] = dims
                    for k, val in win[1].items():
                        wg.attrs[k] = val
                if zero_loc is not None:
                    shape = self.grid.shape(zero_loc)[::-1]
                    f.create_group("xdmf").create_dataset(
                        f"zero_{zero_loc}", data=np.zeros(shape), **self._compression
                    )
            os.replace(tmp, final)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise

        self._frames[index] = _FrameRecord(
            index=index,
            time=time,
            relpath=f"{FRAMES_DIR}/{final.name}",
            fields=tuple(rec for rec, _ in prepared),
            velocity_zero=f"/xdmf/zero_{zero_loc}" if zero_loc else None,
        )
        self._write_xdmf()
        return final

    def _write_xdmf(self) -> None:
        records = [self._frames[i] for i in sorted(self._frames)]
        atomic_write_bytes(self.run_dir / XDMF_FILE, build_xdmf(self.grid, records).encode())

    # ------------------------------------------------------------------ diagnostics
    def append_diagnostics(self, row: dict) -> None:
        """Append one row to diagnostics.csv and flush it to the OS right away.

        The first row fixes the columns (its keys, in order).  Later rows may leave columns
        out (written empty) but may not add new ones (ValueError).  numpy/JAX scalars are
        converted to Python numbers; floats are written with full precision.
        """
        self._check_open()
        if self._diag_writer is None:
            self._diag_header = [str(k) for k in row]
            self._diag_file = open(self.run_dir / DIAGNOSTICS_FILE, "w", newline="")
            self._diag_writer = csv.writer(self._diag_file)
            self._diag_writer.writerow(self._diag_header)
        extra = [k for k in row if str(k) not in self._diag_header]
        if extra:
            raise ValueError(
                f"diagnostics row has columns {extra} that the first row did not have "
                f"(columns: {self._diag_header})"
            )
        values = {str(k): v for k, v in row.items()}
        self._diag_writer.writerow([_csv_value(values.get(k)) for k in self._diag_header])
        self._diag_file.flush()

    # ------------------------------------------------------------------ closing
    def close(self) -> None:
        """Close the diagnostics file.  Safe to call more than once."""
        if self._diag_file is not None:
            self._diag_file.close()
            self._diag_file = None
            self._diag_writer = None
        self._closed = True

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"RunWriter({str(self.run_dir)!r}, frames={len(self._frames)})"


# ---------------------------------------------------------------------- XDMF
def _data_item(parent: ET.Element, dims: tuple[int, ...], text: str, fmt: str = "HDF",
               number: tuple[str, int] = ("Float", 8)) -> None:
    item = ET.SubElement(
        parent,
        "DataItem",
        Format=fmt,
        NumberType=number[0],
        Precision=str(number[1]),
        Dimensions=" ".join(str(d) for d in dims),
    )
    item.text = text


def _scalar_attribute(parent, name, center, dims, ref, number=("Float", 8)) -> None:
    attr = ET.SubElement(parent, "Attribute", Name=name, AttributeType="Scalar", Center=center)
    _data_item(attr, dims, ref, number=number)


def _hyperslab_attribute(parent, name, center, dims, nsolid, k, ref, number=("Float", 8)) -> None:
    attr = ET.SubElement(parent, "Attribute", Name=name, AttributeType="Scalar", Center=center)
    slab = ET.SubElement(
        attr,
        "DataItem",
        ItemType="HyperSlab",
        Type="HyperSlab",
        Dimensions=" ".join(str(d) for d in dims),
    )
    rank = len(dims) + 1
    sel = ET.SubElement(slab, "DataItem", Format="XML", NumberType="Int", Dimensions=f"3 {rank}")
    start = " ".join([str(k)] + ["0"] * len(dims))
    stride = " ".join(["1"] * rank)
    count = " ".join(["1", *(str(d) for d in dims)])
    sel.text = f"{start}  {stride}  {count}"
    _data_item(slab, (nsolid, *dims), ref, number=number)


def _velocity_parts(grid: Grid | Grid3D, fr) -> tuple[str, list[str]] | None:
    """(location, dataset paths) of the frame's ``velocity`` vector, or None: (u, v, zero)
    in 2D, (u, v, w) in 3D, all scalar fields at one location."""
    by_name = {r.name: r for r in fr.fields}
    if grid.ndim == 2:
        if fr.velocity_zero is None:
            return None
        return by_name["u"].location, ["/fields/u", "/fields/v", fr.velocity_zero]
    comps = [by_name.get(c) for c in ("u", "v", "w")]
    if not all(comps) or any(c.nsolid for c in comps):
        return None
    if len({c.location for c in comps}) != 1:
        return None
    return comps[0].location, ["/fields/u", "/fields/v", "/fields/w"]


def build_xdmf(grid: Grid | Grid3D, frames) -> str:
    """Return the XDMF 3 text of a temporal collection over ``frames``.

    ``frames`` are the writer's frame records (index, time, relative path, fields).  The
    mesh of every frame is the 2DCoRectMesh (3DCoRectMesh on a 3D grid) of the grid's
    corners; see the module docstring for the axis order.
    """
    root = ET.Element("Xdmf", Version="3.0")
    domain = ET.SubElement(root, "Domain")
    coll = ET.SubElement(
        domain, "Grid", Name="run", GridType="Collection", CollectionType="Temporal"
    )
    ndim = grid.ndim
    cdims = tuple(grid.shape("corner"))[::-1]  # slowest first: (ny+1, nx+1) or (nz+1, ...)
    ndims = tuple(grid.shape("node"))[::-1]
    origin = list(grid.lows)
    spacing = list(grid.spacing)
    for fr in frames:
        g = ET.SubElement(coll, "Grid", Name=f"frame_{fr.index:05d}", GridType="Uniform")
        ET.SubElement(g, "Time", Value=repr(float(fr.time)))
        ET.SubElement(
            g,
            "Topology",
            TopologyType=f"{ndim}DCoRectMesh",
            Dimensions=" ".join(str(d) for d in cdims),
        )
        geo = ET.SubElement(
            g, "Geometry", GeometryType="ORIGIN_DXDY" if ndim == 2 else "ORIGIN_DXDYDZ"
        )
        _data_item(geo, (ndim,), " ".join(repr(float(a)) for a in origin[::-1]), fmt="XML")
        _data_item(geo, (ndim,), " ".join(repr(float(h)) for h in spacing[::-1]), fmt="XML")
        for rec in fr.fields:
            center, dims = ("Node", cdims) if rec.location == "corner" else ("Cell", ndims)
            ref = f"{fr.relpath}:/fields/{rec.name}"
            number = (rec.number, rec.precision)
            if rec.nsolid:
                for k in range(rec.nsolid):
                    _hyperslab_attribute(g, f"{rec.name}_{k}", center, dims, rec.nsolid, k, ref, number)
            else:
                _scalar_attribute(g, rec.name, center, dims, ref, number)
        vel = _velocity_parts(grid, fr)
        if vel is not None:
            loc, parts = vel
            center, dims = ("Node", cdims) if loc == "corner" else ("Cell", ndims)
            attr = ET.SubElement(
                g, "Attribute", Name="velocity", AttributeType="Vector", Center=center
            )
            fun = ET.SubElement(
                attr,
                "DataItem",
                ItemType="Function",
                Function="JOIN($0, $1, $2)",
                Dimensions=" ".join(str(d) for d in (*dims, 3)),
            )
            for part in parts:
                _data_item(fun, dims, f"{fr.relpath}:{part}")
    ET.indent(root, space="  ")
    body = ET.tostring(root, encoding="unicode")
    return '<?xml version="1.0" ?>\n<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>\n' + body + "\n"
