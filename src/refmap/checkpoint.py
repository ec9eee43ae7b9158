"""Checkpoint and restart: the whole simulation in one HDF5 file, written atomically.

A run folder holds ``checkpoint.h5`` (the latest) and ``checkpoint.prev.h5`` (the one
before).  A checkpoint holds

* every :class:`~refmap.state.State` array at full precision and in its own dtype
  (``/state/t``, ``/state/step``, ``/state/v``, ``/state/rho_f``, ``/state/xi``,
  ``/state/phi``; Fletcher-32 checksums on the non-empty ones);
* ``sim_info`` (a JSON attribute): the output schedule (``frame_times``: the target time of
  frames 1, 2, ...; ``frame_index``: the last frame written, ``next_frame``), the clock and
  step, the last dt and its limit, the run-wide dt minimum and maximum, the total number of
  steps, the number of rows in diagnostics.csv, the wall time so far, the case
  (``Case.to_dict()``), the package versions and the time it was written.

:func:`save_checkpoint` writes the new file under a temporary name in the run folder,
fsyncs it, keeps the current ``checkpoint.h5`` as ``checkpoint.prev.h5`` (a hard link, so
``checkpoint.h5`` never disappears) and only then moves the new file into place.  Killing
the process at any moment leaves the previous checkpoint intact.  :func:`load_checkpoint`
falls back to ``checkpoint.prev.h5`` (with a warning) when ``checkpoint.h5`` is missing or
unreadable.

:func:`reopen_run_writer` reopens a run folder for appending after a restart (frames after
the checkpoint are dropped, diagnostics.csv is cut back to the checkpoint's row count) and
:func:`rebuild_case` recreates the :class:`~refmap.case.Case` of a run.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import tempfile
import warnings
from datetime import UTC, datetime
from pathlib import Path

import h5py
import numpy as np

CHECKPOINT_FILE = "checkpoint.h5"
PREV_CHECKPOINT_FILE = "checkpoint.prev.h5"
FORMAT = "refmap-checkpoint-1"
STATE_FIELDS = ("t", "step", "v", "rho_f", "xi", "phi")

__all__ = [
    "CHECKPOINT_FILE",
    "PREV_CHECKPOINT_FILE",
    "CheckpointError",
    "load_checkpoint",
    "read_checkpoint_info",
    "rebuild_case",
    "reopen_run_writer",
    "save_checkpoint",
]


class CheckpointError(RuntimeError):
    """No usable checkpoint, or one that does not fit the run it is resumed into."""


def _json(obj) -> str:
    from refmap.io._common import to_json

    return to_json(obj)


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _write_h5(path: Path, arrays: dict[str, np.ndarray], sim_info: dict) -> None:
    with h5py.File(path, "w") as f:
        f.attrs["format"] = FORMAT
        f.attrs["sim_info"] = _json(sim_info)
        g = f.create_group("state")
        for name, arr in arrays.items():
            kw = {"fletcher32": True, "chunks": arr.shape} if arr.ndim and arr.size else {}
            g.create_dataset(name, data=arr, **kw)
        f.flush()


def save_checkpoint(run_dir, state, sim_info: dict) -> Path:
    """Write ``run_dir/checkpoint.h5`` holding ``state`` and ``sim_info``; return its path.

    ``state`` is a :class:`~refmap.state.State` (JAX or numpy arrays); ``sim_info`` any
    JSON-able dict (the :class:`~refmap.simulation.Simulation` puts its output schedule,
    counters, case and versions there; ``format`` and ``saved`` are added).  The write is
    atomic: temporary file, fsync, previous checkpoint kept as ``checkpoint.prev.h5``, then
    ``os.replace``.  On any failure the temporary file is removed and the exception
    re-raised; the checkpoint that was there before is untouched.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"no run folder {str(run_dir)!r}")
    arrays = {}
    for name in STATE_FIELDS:
        arrays[name] = np.asarray(getattr(state, name))
    if getattr(state, "p", None) is not None:  # the incompressible fluid's pressure
        arrays["p"] = np.asarray(state.p)
    if getattr(state, "origin", None) is not None:  # solids stored in windows
        arrays["origin"] = np.asarray(state.origin)
    info = dict(sim_info)
    info["format"] = FORMAT
    info["saved"] = datetime.now(UTC).isoformat(timespec="seconds")
    final = run_dir / CHECKPOINT_FILE
    prev = run_dir / PREV_CHECKPOINT_FILE
    from refmap.io._common import make_temp

    tmp = Path(make_temp(final, suffix=".tmp"))
    prev_tmp = None
    try:
        _write_h5(tmp, arrays, info)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        if final.is_file():
            # keep the current checkpoint as checkpoint.prev.h5; a hard link means
            # checkpoint.h5 stays in place until the new one replaces it
            fd2, prev_tmp = tempfile.mkstemp(prefix=f".{PREV_CHECKPOINT_FILE}.", suffix=".tmp", dir=run_dir)
            os.close(fd2)
            os.unlink(prev_tmp)
            try:
                os.link(final, prev_tmp)
            except OSError:  # no hard links on this file system
                shutil.copy2(final, prev_tmp)
            os.replace(prev_tmp, prev)
            prev_tmp = None
        os.replace(tmp, final)
        _fsync_dir(run_dir)
    except BaseException:
        for p in (tmp, prev_tmp):
            if p is not None:
                try:
                    os.unlink(p)
                except OSError:
                    pass
        raise
    return final


def _read(path: Path):
    from refmap.state import State

    with h5py.File(path, "r") as f:
        if f.attrs.get("format") != FORMAT:
            raise ValueError(f"{path} is not a refmap checkpoint (format {f.attrs.get('format')!r})")
        info = json.loads(f.attrs["sim_info"])
        arrays = {name: np.asarray(f["state"][name][()]) for name in STATE_FIELDS}
        if "p" in f["state"]:  # written since 2026-12-06 for incompressible runs
            arrays["p"] = np.asarray(f["state"]["p"][()])
        if "origin" in f["state"]:  # solids stored in windows (written since 2026-12-07)
            arrays["origin"] = np.asarray(f["state"]["origin"][()])
    import jax.numpy as jnp

    state = State(**{k: jnp.asarray(v) for k, v in arrays.items()})
    return state, info


def _candidates(run_dir: Path) -> list[Path]:
    return [run_dir / CHECKPOINT_FILE, run_dir / PREV_CHECKPOINT_FILE]


def load_checkpoint(run_dir):
    """Read the checkpoint of a run folder: ``(State, sim_info)``.

    The arrays come back as JAX arrays with the dtypes they were saved with.  If
    ``checkpoint.h5`` is missing or unreadable (e.g. damaged on disk), ``checkpoint.prev.h5``
    is used with a ``UserWarning``.  Raises :class:`FileNotFoundError` for a missing folder
    and :class:`CheckpointError` when neither file is usable.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"no run folder {str(run_dir)!r}")
    errors = []
    for k, path in enumerate(_candidates(run_dir)):
        if not path.is_file():
            errors.append(f"{path.name}: missing")
            continue
        try:
            state, info = _read(path)
        except Exception as exc:  # noqa: BLE001 - try the previous one
            errors.append(f"{path.name}: {exc}")
            continue
        if k:
            warnings.warn(
                f"using the previous checkpoint {path} (t = {info.get('t')}); "
                f"{'; '.join(errors)}",
                UserWarning,
                stacklevel=2,
            )
        info["checkpoint_file"] = path.name
        return state, info
    raise CheckpointError(f"no usable checkpoint in {str(run_dir)!r} ({'; '.join(errors)})")


def read_checkpoint_info(run_dir) -> dict | None:
    """``sim_info`` of the newest readable checkpoint, without the arrays (None if none)."""
    for path in _candidates(Path(run_dir)):
        try:
            with h5py.File(path, "r") as f:
                if f.attrs.get("format") == FORMAT:
                    info = json.loads(f.attrs["sim_info"])
                    info["checkpoint_file"] = path.name
                    return info
        except Exception:  # noqa: BLE001
            continue
    return None


# ---------------------------------------------------------------------- the case
def _plain(d):
    return json.loads(_json(d))


def _diff_keys(a: dict, b: dict, prefix="") -> list[str]:
    out = []
    for k in sorted(set(a) | set(b)):
        if k not in a or k not in b:
            out.append(prefix + k)
        elif isinstance(a[k], dict) and isinstance(b[k], dict):
            out += _diff_keys(a[k], b[k], prefix + k + ".")
        elif a[k] != b[k]:
            out.append(prefix + k)
    return out


def _from_scenario(stored: dict):
    """Built-in scenario name + grid size, then the overridable scalars of the stored case."""
    from dataclasses import replace

    from refmap.scenarios import SCENARIOS, get_case
    from refmap.state import FluidParams

    name = stored.get("name")
    if name not in SCENARIOS:
        return None
    n = int(stored["grid"]["nx"])
    case = get_case(name, n)
    have = _plain(case.to_dict())
    if have["numerics"] != stored["numerics"]:
        case = case.replace(numerics=replace(case.numerics, **{
            k: v for k, v in stored["numerics"].items() if have["numerics"].get(k) != v}))
    if have["fluid"] != stored["fluid"]:
        case = case.replace(fluid=FluidParams(**stored["fluid"]))
    if have["gravity"] != stored["gravity"]:
        case = case.replace(gravity=tuple(stored["gravity"]))
    if have["picture_field"] != stored["picture_field"]:
        case = case.replace(picture_field=stored["picture_field"])
    return case


def case_toml(case) -> str | None:
    """The case as case-file text (``refmap.casefile.case_to_toml``), or None when it cannot
    be written as one (a law given by a Python function, an unregistered shape)."""
    try:
        from refmap.casefile import case_to_toml

        return case_to_toml(case)
    except Exception:  # noqa: BLE001 - then only the built-in scenario route is left
        return None


def _from_toml(text: str):
    import tomllib

    from refmap.casefile import case_from_dict

    return case_from_dict(tomllib.loads(text), base_dir=None).case


def rebuild_case(sim_info: dict, metadata: dict | None = None, case=None):
    """Recreate the :class:`~refmap.case.Case` a checkpoint belongs to.

    Sources, in order: ``case`` (a Case the caller built, e.g. in Python with a law that no
    case file can hold); the case-file text stored in the checkpoint (``case_toml``, read
    with :mod:`refmap.casefile`); the built-in scenario of the stored name and grid size
    with the stored fluid, numerics, gravity and picture field.  The result must reproduce
    the stored ``Case.to_dict()`` exactly (t_end and frames are taken from it), else the
    next source is tried; :class:`CheckpointError` names the keys that differ when none
    does (or at once when ``case`` was given).
    """
    stored = _plain(sim_info.get("case") or (metadata or {}).get("case") or {})
    if not stored:
        raise CheckpointError("the checkpoint holds no case description")
    if case is not None:
        sources = [("the case given", lambda: case)]
    else:
        sources = []
        if sim_info.get("case_toml"):
            sources.append(("the stored case file", lambda: _from_toml(sim_info["case_toml"])))
        sources.append((f"built-in scenario {stored.get('name')!r}", lambda: _from_scenario(stored)))
    problems = []
    for label, make in sources:
        try:
            c = make()
        except Exception as exc:  # noqa: BLE001 - try the next source
            problems.append(f"{label}: {str(exc).splitlines()[0]}")
            continue
        if c is None:
            continue
        c = c.replace(t_end=stored["t_end"], frames=int(stored["frames"]))
        diff = _diff_keys(_plain(c.to_dict()), stored)
        if not diff:
            return c
        problems.append(f"{label} does not reproduce the stored case ({', '.join(diff)} differ)")
    if not problems:
        problems.append("it is not a built-in scenario and no case file text is stored")
    hint = "" if case is not None else "; pass the Case (Simulation.resume(run_dir, case=...))"
    raise CheckpointError(f"cannot rebuild case {stored.get('name')!r}: {'; '.join(problems)}{hint}")


# ---------------------------------------------------------------------- the run folder
def truncate_diagnostics(path, rows: int) -> None:
    """Keep the header and the first ``rows`` data rows of a diagnostics CSV (atomically)."""
    from refmap.io._common import atomic_write_bytes

    path = Path(path)
    if not path.is_file():
        return
    lines = path.read_bytes().splitlines(keepends=True)
    keep = lines[: 1 + int(rows)]
    if len(keep) < 1 + int(rows):
        warnings.warn(
            f"{path} has {len(lines) - 1} rows, the checkpoint expected {rows}", UserWarning,
            stacklevel=2,
        )
    if keep and not keep[-1].endswith(b"\n"):
        keep[-1] = keep[-1].rstrip(b"\r") + b"\r\n"
    atomic_write_bytes(path, b"".join(keep), fsync=True)


def reopen_run_writer(run_dir, grid, next_frame: int, diag_rows: int, **kw):
    """A :class:`~refmap.io.RunWriter` on an existing run folder, for a resumed run.

    Frames ``0 .. next_frame - 1`` are kept (and listed again in run.xdmf); later frames
    (written after the checkpoint, about to be recomputed) and leftover ``*.tmp`` files are
    removed; diagnostics.csv is cut back to ``diag_rows`` rows and reopened for appending.
    metadata.json is left as it is.  ``kw``: compression options as for RunWriter.
    """
    from refmap.io.writer import RunWriter

    class _Reopened(RunWriter):
        def __init__(self):  # noqa: D401 - RunWriter.__init__ insists on an empty folder
            pass

    from refmap.io import _common as C
    from refmap.io import writer as W
    from refmap.io.reader import list_frames, read_metadata

    run_dir = Path(run_dir)
    if not (run_dir / C.FRAMES_DIR).is_dir():
        raise CheckpointError(f"{str(run_dir)!r} holds no frames folder")
    w = _Reopened()
    w.run_dir = run_dir
    w.grid = grid
    w.frames_dir = run_dir / C.FRAMES_DIR
    w._compression = W._compression_options(kw.get("compression", "gzip"), kw.get("compression_level", 1))
    w._frames = {}
    w._diag_file = None
    w._diag_writer = None
    w._diag_header = None
    w._closed = False
    w.metadata = read_metadata(run_dir)

    for p in list(w.frames_dir.glob(f"*{C.TMP_SUFFIX}")) + list(run_dir.glob(f".*{C.TMP_SUFFIX}")):
        if p.is_file() and not p.name.startswith(f".{CHECKPOINT_FILE}"):
            p.unlink()
    for index, path in list_frames(run_dir):
        if index >= next_frame:
            path.unlink()
            continue
        try:
            w._frames[index] = _frame_record(run_dir, path, index)
        except Exception as exc:  # noqa: BLE001
            warnings.warn(f"frame {path} is unreadable and left out of run.xdmf: {exc}",
                          UserWarning, stacklevel=2)
    missing = sorted(set(range(next_frame)) - set(w._frames))
    if missing:
        warnings.warn(f"frames {missing} of {run_dir} are missing", UserWarning, stacklevel=2)
    w._write_xdmf()

    diag = run_dir / C.DIAGNOSTICS_FILE
    if diag.is_file():
        truncate_diagnostics(diag, diag_rows)
        with open(diag, newline="") as fh:
            header = next(csv.reader(fh), None)
        if header:
            w._diag_header = header
            w._diag_file = open(diag, "a", newline="")
            w._diag_writer = csv.writer(w._diag_file)
    return w


def _frame_record(run_dir: Path, path: Path, index: int):
    from refmap.io import _common as C
    from refmap.io import writer as W

    with h5py.File(path, "r") as f:
        recs = []
        for name, ds in f["fields"].items():
            loc = ds.attrs["location"]
            loc = loc.decode() if isinstance(loc, bytes) else str(loc)
            per = bool(ds.attrs["per_solid"])
            # the dataset's number type too (an integer field, solid_index, is int32)
            recs.append(W._FieldRecord(name, loc, int(ds.shape[0]) if per else 0,
                                       *W.xdmf_number(ds.dtype)))
        zero = None
        if "xdmf" in f:
            for k in f["xdmf"]:
                zero = f"/xdmf/{k}"
        time = float(f.attrs["time"])
    return W._FrameRecord(index=index, time=time, relpath=f"{C.FRAMES_DIR}/{path.name}",
                          fields=tuple(recs), velocity_zero=zero)


def note_resume(run_dir, case_dict: dict, entry: dict) -> None:
    """Record a restart in metadata.json: the (possibly extended) case and a ``resumes`` entry."""
    from refmap.io._common import METADATA_FILE, atomic_write_bytes
    from refmap.io.reader import read_metadata

    meta = read_metadata(run_dir)
    meta["case"] = case_dict
    meta.setdefault("resumes", []).append(entry)
    atomic_write_bytes(Path(run_dir) / METADATA_FILE, (_json_indent(meta) + "\n").encode(), fsync=True)


def _json_indent(obj) -> str:
    from refmap.io._common import to_json

    return to_json(obj, indent=2, sort_keys=False)
