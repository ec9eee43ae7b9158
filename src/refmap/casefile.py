"""User-defined case files: a whole run described in TOML (see ``docs/casefiles.md``).

A case file mirrors :class:`refmap.case.Case`::

    name = "flap"
    gravity = [0.0, 0.0]
    [grid]      n = 128  (or nx, ny),  ax, bx, ay, by
    [fluid]     rho0, lambda_f, eta, extra_viscosity, bulk_viscosity
    [time]      t_end, frames
    [numerics]  cfl and the other fields of refmap.state.Numerics
    [output]    picture_field, movie, pictures, out
    [boundary]  left / right / bottom / top: "wall" | "slip" | "outflow" | "periodic"
                or a list of segment tables {kind, start, end, velocity, profile, ramp, omega}
    [contact]   optional: the contact body force of refmap.contact.Contact
    [initial_velocity]  optional: u, v (formulas in x, y) or file (.npy / .h5, (2, nx, ny))
    [[solids]]  name, shape (a geometry table, CSG nested), law (a material table),
                strain, strain_center, velocity, anchor (region or pivot)

A 3D case says so in its grid: ``[grid] dim = 3`` (default 2).  Then ``[grid]`` takes
``nz``, ``az``, ``bz`` too (``n`` sets nx, and ny, nz follow for cubic cells), gravity,
velocities and ``strain_center`` have three numbers, ``strain`` is 3x3, ``[boundary]``
has the faces ``back`` (z-low) and ``front`` (z-high), shapes are the 3D types of
``refmap.geometry.SHAPES_3D`` (and CSG / transforms of them), laws get ``dim = 3`` without
writing it, and ``[initial_velocity]`` takes ``u``, ``v``, ``w`` in x, y, z (a file holds
``(3, nx, ny, nz)``); a 3D pivot anchor is an axle (``center`` x, y, z, ``axis``,
``half_length``).  Settings the 3D step does not have yet (``band_force = "solid"``) are
errors naming their key.

Public API
----------
* :func:`load_case` ``(path, overrides=None) -> Case``: parse, apply overrides, validate.
* :func:`load_run` ``(path, overrides=None) -> RunPlan``: the same plus the ``[output]``
  settings (output folder, movie, pictures) a command line needs.
* :func:`case_from_dict` ``(data, base_dir=".", overrides=None) -> RunPlan``: from a parsed
  TOML dict (what ``load_run`` calls).
* :func:`case_to_toml` ``(case, base_dir=None) -> str`` and :func:`dump_case`
  ``(case, path)``: a Case as a case file that loads back to an equal Case.
* :func:`show_scenario` ``(name, n=None) -> str``: a built-in scenario as a case file.
* :class:`ArrayShape`: a shape from a mask or signed-distance array (``.npy``) or a picture
  (``.png``), written ``{type = "mask", file = "shape.npy", extent = [x0, x1, y0, y1]}``.
* :func:`build_shape`, :func:`build_law`, :func:`build_anchor`: a shape / law / anchor from
  its table, errors naming the key path inside it.

Every problem with a case file raises one :class:`CaseFileError` (a
:class:`~refmap.case.CaseError`) whose message starts with the key path and ends with the
offending value, e.g. ``solids[1].law.G: must be > 0 (got -3)``.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import hashlib
import math
import os
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import jax.numpy as jnp
import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    ValidationError,
    ValidationInfo,
    create_model,
    field_validator,
    model_validator,
)

from refmap.anchors import PivotAnchor, RegionAnchor
from refmap.boundary import AXIS_FACES, EDGES, FACES, Boundary, Segment
from refmap.case import Case, CaseError
from refmap.contact import Contact
from refmap.geometry import SHAPES, SHAPES_3D, Shape, Translate
from refmap.grid import Grid, Grid3D
from refmap.initial import (
    InitialVelocityError,
    VelocityExpression,
    VelocityFile,
    as_initial_velocity,
)
from refmap.materials import LAWS, law_from_dict
from refmap.model import Solid, check_3d_support
from refmap.state import FluidParams, Numerics

__all__ = [
    "ArrayShape",
    "CaseFileError",
    "build_anchor",
    "build_law",
    "build_initial_velocity",
    "build_shape",
    "RunPlan",
    "case_from_dict",
    "case_to_toml",
    "dump_case",
    "is_case_file",
    "load_case",
    "load_run",
    "register_array_shape",
    "show_scenario",
    "to_toml",
]

#: largest accepted number of cells along an axis, and of output frames
MAX_CELLS = 16384
MAX_FRAMES = 1_000_000
#: fields that ``Simulation`` can draw (2D node or corner fields)
PICTURE_FIELDS = (
    "pressure",
    "p_fluid",
    "u",
    "v",
    "rho_f",
    "rho",
    "sigma_xx",
    "sigma_xy",
    "sigma_yy",
)
EDGE_WORDS = ("wall", "slip", "outflow", "periodic")

# --------------------------------------------------------------------------------------------
# errors


class CaseFileError(CaseError):
    """A problem in a case file.  ``key`` is the key path (``"solids[1].law.G"``, ``""`` for
    the whole file), ``file`` the case file (or None)."""

    def __init__(self, message: str, key: str = "", file: str | None = None):
        super().__init__(message)
        self.key = key
        self.file = file


class _PathError(ValueError):
    """A problem at ``path`` (relative to where it is raised) with message ``msg``."""

    def __init__(self, path: tuple, msg: str):
        super().__init__(msg)
        self.path = tuple(path)
        self.msg = msg


def _fmt_path(path) -> str:
    out = ""
    for p in path:
        if isinstance(p, int):
            out += f"[{p}]"
        else:
            key = str(p) if re.fullmatch(r"[A-Za-z0-9_-]+", str(p)) else _toml_str(str(p))
            out += ("." if out else "") + key
    return out


def _fmt_value(v: Any) -> str:
    """The offending value as the user wrote it (short)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float, np.integer, np.floating)):
        return repr(v.item() if isinstance(v, np.generic) else v)
    if isinstance(v, str):
        s = repr(v)
    elif v is None:
        return "nothing"
    else:
        try:
            s = _toml_value(v)
        except Exception:  # noqa: BLE001 - best effort for odd objects
            s = repr(v)
    return s if len(s) <= 80 else s[:77] + "..."


def _did_you_mean(word: Any, options) -> str:
    options = [str(o) for o in options]
    if not isinstance(word, str):
        return ""
    low = {o.lower(): o for o in options}
    if word.lower() in low and low[word.lower()] != word:
        return f" (did you mean {low[word.lower()]!r}?)"
    m = difflib.get_close_matches(word, options, n=1, cutoff=0.6)
    return f" (did you mean {m[0]!r}?)" if m else ""


def _unknown_key(key: Any, allowed, where: str = "") -> str:
    allowed = sorted(str(a) for a in allowed)
    hint = _did_you_mean(key, allowed)
    if not hint:
        hint = f"; allowed keys: {', '.join(allowed)}" if allowed else ""
    return f"unknown key {key!r}{where}{hint}"


def _check_keys(data: Mapping, allowed, where: str = "") -> None:
    for k in data:
        if k not in allowed:
            raise _PathError((), _unknown_key(k, allowed, where))


def _describe_pydantic(err: dict) -> tuple[tuple, str]:
    """(path, message) for one pydantic error, the message ending with the offending value."""
    loc = tuple(err.get("loc", ()))
    typ = err.get("type", "")
    ctx = err.get("ctx") or {}
    got = f" (got {_fmt_value(err.get('input'))})"
    if typ in ("value_error", "assertion_error") and isinstance(ctx.get("error"), _PathError):
        e = ctx["error"]
        return loc + e.path, e.msg
    if typ == "missing" and loc and isinstance(loc[-1], int):  # a too short list
        return loc[:-1], f"too few entries, no entry [{loc[-1]}]{got}"
    if typ == "missing":
        return loc[:-1], f"missing required key {loc[-1]!r}" if loc else "missing"
    if typ == "extra_forbidden":
        return loc[:-1], f"unknown key {loc[-1]!r}"
    messages = {
        "float_type": "must be a number",
        "float_parsing": "must be a number",
        "int_type": "must be an integer",
        "int_parsing": "must be an integer",
        "int_from_float": "must be an integer",
        "bool_type": "must be true or false",
        "bool_parsing": "must be true or false",
        "string_type": "must be a string",
        "list_type": "must be a list",
        "tuple_type": "must be a list",
        "dict_type": "must be a table",
        "model_type": "must be a table",
        "model_attributes_type": "must be a table",
        "finite_number": "must be a finite number",
    }
    if typ in messages:
        return loc, messages[typ] + got
    if typ in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        op = {
            "greater_than": ">",
            "greater_than_equal": ">=",
            "less_than": "<",
            "less_than_equal": "<=",
        }[typ]
        bound = next(iter(v for k, v in ctx.items() if k in ("gt", "ge", "lt", "le")), "?")
        if isinstance(bound, float) and bound.is_integer():
            bound = int(bound)
        return loc, f"must be {op} {bound}{got}"
    if typ == "literal_error":
        expected = ctx.get("expected", "")
        options = re.findall(r"'([^']*)'", expected)
        return loc, f"must be one of {expected}{got}{_did_you_mean(err.get('input'), options)}"
    if typ in ("too_short", "too_long"):
        n = ctx.get("max_length") if typ == "too_long" else ctx.get("min_length")
        return loc, f"must have {n} entries{got}"
    if typ in ("value_error", "assertion_error"):
        return loc, f"{ctx.get('error', err.get('msg'))}{got}"
    return loc, f"{err.get('msg', typ)}{got}"


def _from_validation_error(e: ValidationError, prefix: tuple = ()) -> _PathError:
    path, msg = _describe_pydantic(e.errors()[0])
    return _PathError(prefix + path, msg)


# --------------------------------------------------------------------------------------------
# scalar types of the schema

Num = Annotated[float, Strict(), Field(allow_inf_nan=False)]
Pos = Annotated[float, Strict(), Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Strict(), Field(ge=0, allow_inf_nan=False)]
Int = Annotated[int, Strict()]
Bool = Annotated[bool, Strict()]
Str = Annotated[str, Strict()]
Pair = tuple[Num, Num]
Triple = tuple[Num, Num, Num]
#: the hint for a 3D key in a 2D case file
_NEEDS_3D = "is for a 3D case: add dim = 3 to [grid]"


def _number(v: Any, path: tuple = ()) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _PathError(path, f"must be a number (got {_fmt_value(v)})")
    try:
        f = float(v)
    except OverflowError:
        f = math.inf
    if not math.isfinite(f):
        raise _PathError(path, f"must be a finite number (got {_fmt_value(v)})")
    return f


class _Table(BaseModel):
    """A TOML table: unknown keys are errors (with a suggestion, or the hint of
    ``key_hints`` for keys that belong to the other dimension)."""

    model_config = ConfigDict(extra="forbid", frozen=True, arbitrary_types_allowed=True)
    #: key -> why it is not accepted here (e.g. a 3D key in a 2D file)
    key_hints: ClassVar[dict[str, str]] = {}

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        if not isinstance(data, Mapping):
            raise _PathError((), f"must be a table (got {_fmt_value(data)})")
        for k in data:
            if k not in cls.model_fields and k in cls.key_hints:
                raise _PathError((k,), f"{cls.key_hints[k]} (got {_fmt_value(data[k])})")
        _check_keys(data, cls.model_fields)
        return data


def _spec_from_dataclass(
    name: str, cls: type, constraints: dict[str, dict], only: list[str] | None = None,
    types: dict[str, Any] | None = None,
) -> type[_Table]:
    """A table model with one key per field of the dataclass ``cls`` (optional with the
    dataclass default where it has one); scalar and pair fields are typed, others Any;
    ``types`` overrides the type of the fields it names."""
    scalar = {
        "float": lambda c: Annotated[float, Strict(), Field(allow_inf_nan=False, **c)],
        "int": lambda c: Annotated[int, Strict(), Field(**c)],
        "bool": lambda c: Bool,
        "str": lambda c: Str,
        "tuple[float,float]": lambda c: Pair,
    }
    fields = {}
    for f in dataclasses.fields(cls):
        if only is not None and f.name not in only:
            continue
        ann = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
        ann = ann.replace(" ", "")
        if ann.startswith("Optional[") and ann.endswith("]"):
            ann = ann[9:-1] + "|None"
        optional = ann.endswith("|None")
        base = ann.removesuffix("|None")
        c = constraints.get(f.name, {})
        typ = scalar[base](c) if base in scalar else Any
        if types and f.name in types:
            typ = types[f.name]
        if optional:
            typ = typ | None
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = ...
        fields[f.name] = (typ, default)
    return create_model(name, __base__=_Table, **fields)


FluidSpec = _spec_from_dataclass(
    "FluidSpec",
    FluidParams,
    {
        "rho0": {"gt": 0},
        "lambda_f": {"gt": 0},
        "eta": {"ge": 0},
        "extra_viscosity": {"ge": 0},
        "bulk_viscosity": {"ge": 0},
    },
)
NumericsSpec = _spec_from_dataclass(
    "NumericsSpec",
    Numerics,
    {
        "blur_width": {"gt": 0},
        "band": {"gt": 0},
        "stress_band": {"gt": 0},
        "advected_band": {"ge": 0},
        "pin_rate": {"ge": 0},
        "pin_substeps": {"ge": 0},
        "pin_inner": {"ge": 0},
        "pin_copy": {"gt": 0},
        "redistance_iters": {"ge": 0},
        "smooth_coef": {"ge": 0},
        "smooth_max_sweeps": {"ge": 0},
        "smooth_ratio": {"ge": 0},
        "smooth_atol": {"ge": 0},
        "smooth_check_every": {"ge": 1},
        "fixed_smooth_sweeps": {"ge": 0},
        "cfl": {"gt": 0, "le": 1},
        "dt_max": {"gt": 0},
        "dt_fixed": {"gt": 0},
        "phi_max": {"gt": 0},
        "band_capacity": {"ge": 1},
        "volume_correction": {"ge": 0},
    },
)


ContactSpec = _spec_from_dataclass(
    "ContactSpec",
    Contact,
    {"width": {"gt": 0}, "cutoff": {"ge": 0, "lt": 1}, "strength": {"gt": 0}, "reach": {"gt": 0}},
)


Cells = Annotated[int, Strict(), Field(ge=8, le=MAX_CELLS)]


def _dim_value(v: Any) -> int:
    """``[grid] dim``: 2 or 3 (an integer)."""
    if isinstance(v, bool) or not isinstance(v, int) or v not in (2, 3):
        raise _PathError((), f"must be 2 or 3 (got {_fmt_value(v)})")
    return v


class GridSpec(_Table):
    key_hints: ClassVar[dict[str, str]] = {}
    #: 2 (default) or 3: a 3D case file says so here
    dim: Any = 2
    n: Cells | None = None
    nx: Cells | None = None
    ny: Cells | None = None
    nz: Cells | None = None
    ax: Num = -2.0
    bx: Num = 2.0
    ay: Num = -2.0
    by: Num = 2.0
    az: Num | None = None  # 3D only; -2 when left out
    bz: Num | None = None  # 3D only; 2 when left out

    @field_validator("dim", mode="before")
    @classmethod
    def _dim(cls, v):
        return _dim_value(v)

    @model_validator(mode="after")
    def _consistent(self):
        if self.dim == 3:
            return self._consistent_3d()
        for key in ("nz", "az", "bz"):
            if getattr(self, key) is not None:
                raise _PathError((key,), f"{_NEEDS_3D} (got {_fmt_value(getattr(self, key))})")
        if self.n is not None and (self.nx is not None or self.ny is not None):
            key = "nx" if self.nx is not None else "ny"
            raise _PathError(
                (key,),
                f"give either n or nx and ny, not both (got n = {self.n}, "
                f"{key} = {getattr(self, key)})",
            )
        if self.n is None and (self.nx is None or self.ny is None):
            missing = "ny" if self.nx is not None else "nx" if self.ny is not None else "n"
            raise _PathError((), f"missing required key {missing!r} (give n, or nx and ny)")
        if not self.bx > self.ax:
            raise _PathError(("bx",), f"must be > ax = {self.ax!r} (got {self.bx!r})")
        if not self.by > self.ay:
            raise _PathError(("by",), f"must be > ay = {self.ay!r} (got {self.by!r})")
        lx, ly = self.bx - self.ax, self.by - self.ay
        if not (math.isfinite(lx) and math.isfinite(ly)):
            raise _PathError((), "the domain is too large to represent")
        if self.n is not None:
            ratio = ly / lx
            if not (8 <= self.n * ratio <= MAX_CELLS):
                raise _PathError(
                    ("n",),
                    f"gives ny = n * (by - ay) / (bx - ax) = {self.n * ratio:.4g} "
                    f"cells, outside [8, {MAX_CELLS}]; give nx and ny (got {self.n})",
                )
        return self

    def z_bounds(self) -> tuple[float, float]:
        """(az, bz) of a 3D grid, with their defaults."""
        return (-2.0 if self.az is None else self.az, 2.0 if self.bz is None else self.bz)

    def _consistent_3d(self):
        names = ("nx", "ny", "nz")
        given = [k for k in names if getattr(self, k) is not None]
        if self.n is not None and given:
            key = given[0]
            raise _PathError(
                (key,),
                f"give either n or nx, ny and nz, not both (got n = {self.n}, "
                f"{key} = {getattr(self, key)})",
            )
        if self.n is None and len(given) < 3:
            missing = next(k for k in names if k not in given) if given else "n"
            raise _PathError((), f"missing required key {missing!r} (give n, or nx, ny and nz)")
        az, bz = self.z_bounds()
        for a, lo, hi in (("x", self.ax, self.bx), ("y", self.ay, self.by), ("z", az, bz)):
            if not hi > lo:
                raise _PathError((f"b{a}",), f"must be > a{a} = {lo!r} (got {hi!r})")
        lengths = (self.bx - self.ax, self.by - self.ay, bz - az)
        if not all(math.isfinite(v) for v in lengths):
            raise _PathError((), "the domain is too large to represent")
        if self.n is not None:
            for a, length in (("y", lengths[1]), ("z", lengths[2])):
                cells = self.n * length / lengths[0]
                if not (8 <= cells <= MAX_CELLS):
                    raise _PathError(
                        ("n",),
                        f"gives n{a} = n * (b{a} - a{a}) / (bx - ax) = {cells:.4g} cells, "
                        f"outside [8, {MAX_CELLS}]; give nx, ny and nz (got {self.n})",
                    )
        return self

    def cells(self) -> tuple[int, ...]:
        if self.dim == 3:
            if self.n is None:
                return self.nx, self.ny, self.nz
            az, bz = self.z_bounds()
            return (self.n, _derived_ny(self.n, self.ax, self.bx, self.ay, self.by),
                    _derived_ny(self.n, self.ax, self.bx, az, bz))
        if self.n is None:
            return self.nx, self.ny
        return self.n, _derived_ny(self.n, self.ax, self.bx, self.ay, self.by)

    def grid(self):
        """The :class:`~refmap.grid.Grid` (or :class:`~refmap.grid.Grid3D`) of the table."""
        if self.dim == 3:
            nx, ny, nz = self.cells()
            return Grid3D(nx, ny, nz, self.ax, self.bx, self.ay, self.by, *self.z_bounds())
        nx, ny = self.cells()
        return Grid(nx, ny, self.ax, self.bx, self.ay, self.by)


def _derived_ny(n, ax, bx, ay, by) -> int:
    """Cells along y (or z, given az, bz) for ``n`` along x: square cells (as close as the
    grid allows)."""
    return max(8, int(round(n * (by - ay) / (bx - ax))))


class TimeSpec(_Table):
    t_end: Pos = Case.__dataclass_fields__["t_end"].default
    frames: Annotated[int, Strict(), Field(ge=1, le=MAX_FRAMES)] = Case.__dataclass_fields__[
        "frames"
    ].default


class OutputSpec(_Table):
    picture_field: Literal[PICTURE_FIELDS] = Case.__dataclass_fields__["picture_field"].default  # type: ignore[valid-type]
    movie: Bool = False
    pictures: Bool = True
    out: Str | None = None


class SegmentSpec(_Table):
    DIM: ClassVar[int] = 2
    kind: Literal["wall", "slip", "velocity", "outflow"] = "wall"
    start: Annotated[float, Strict(), Field(ge=0, le=1, allow_inf_nan=False)] = 0.0
    end: Annotated[float, Strict(), Field(ge=0, le=1, allow_inf_nan=False)] = 1.0
    velocity: Pair = (0.0, 0.0)
    profile: Literal["uniform", "parabolic"] = "uniform"
    ramp: NonNeg = 0.0
    omega: Num | None = None

    @field_validator("kind", mode="before")
    @classmethod
    def _kind(cls, v):
        if v == "periodic":
            raise _PathError(
                (),
                "'periodic' applies to a whole edge: write the edge as "
                "\"periodic\" instead of a list of segments (got 'periodic')",
            )
        return v

    @model_validator(mode="after")
    def _order(self):
        if not self.start < self.end:
            raise _PathError(("end",), f"must be > start = {self.start!r} (got {self.end!r})")
        return self

    def segment(self) -> Segment:
        return Segment(
            kind=self.kind,
            start=self.start,
            end=self.end,
            velocity=self.velocity,
            profile=self.profile,
            ramp=self.ramp,
            omega=self.omega,
        )


class SegmentSpec3(SegmentSpec):
    """A segment of a 3D face: three velocity components, the whole face only."""

    DIM: ClassVar[int] = 3
    velocity: Triple = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _whole_face(self):
        for key, whole in (("start", 0.0), ("end", 1.0)):
            if getattr(self, key) != whole:
                raise _PathError(
                    (key,),
                    f"must be {whole:g}: a 3D face takes whole-face segments only (partial "
                    f"faces are not supported in 3D yet) (got {_fmt_value(getattr(self, key))})",
                )
        return self


def _edge(v: Any, seg_spec: type[SegmentSpec] = SegmentSpec):
    """An edge: one of EDGE_WORDS, a segment table, or a list of segment tables."""
    if isinstance(v, str):
        if v not in EDGE_WORDS:
            hint = _did_you_mean(v, EDGE_WORDS)
            if v in ("velocity", "inflow"):
                example = "[0.1, 0.0]" if seg_spec.DIM == 2 else "[0.1, 0.0, 0.0]"
                hint = (
                    "; a prescribed velocity needs a segment table, e.g. "
                    f'[{{kind = "velocity", velocity = {example}}}]'
                )
            raise _PathError(
                (),
                f"must be one of {', '.join(map(repr, EDGE_WORDS))} or a list of "
                f"segment tables (got {v!r}){hint}",
            )
        return v
    if isinstance(v, Mapping):
        v = [v]
    if not isinstance(v, (list, tuple)):
        raise _PathError(
            (),
            f"must be one of {', '.join(map(repr, EDGE_WORDS))} or a list of "
            f"segment tables (got {_fmt_value(v)})",
        )
    if not v:
        raise _PathError((), "needs at least one segment (got [])")
    segs = []
    for i, s in enumerate(v):
        try:
            segs.append(seg_spec.model_validate(s))
        except ValidationError as e:
            raise _from_validation_error(e, (i,)) from None
    cover = sorted((s.start, s.end) for s in segs)
    pos, tiled = 0.0, True
    for s0, s1 in cover:
        if abs(s0 - pos) > 1e-12:
            tiled = False
            break
        pos = s1
    if not tiled or abs(pos - 1.0) > 1e-12:
        spans = ", ".join(f"[{a:g}, {b:g}]" for a, b in cover)
        raise _PathError((), f"segments must tile [0, 1] without gaps or overlaps (got {spans})")
    return tuple(segs)


class BoundarySpec(_Table):
    DIM: ClassVar[int] = 2
    key_hints: ClassVar[dict[str, str]] = {
        "back": "is the z-low face of a 3D box: add dim = 3 to [grid] for a 3D case",
        "front": "is the z-high face of a 3D box: add dim = 3 to [grid] for a 3D case",
    }
    left: Any = "wall"
    right: Any = "wall"
    bottom: Any = "wall"
    top: Any = "wall"

    @field_validator("left", "right", "bottom", "top", mode="before")
    @classmethod
    def _edges(cls, v):
        return _edge(v)

    @model_validator(mode="after")
    def _pairs(self):
        for a, b in AXIS_FACES[: self.DIM]:
            ea, eb = getattr(self, a), getattr(self, b)
            if (ea == "periodic") == (eb == "periodic"):
                continue
            other, this, e = (a, b, eb) if ea == "periodic" else (b, a, ea)
            inflow = not isinstance(e, str) and any(s.kind == "velocity" for s in e)
            what = "inflow segment on a periodic edge" if inflow else 'must be "periodic"'
            raise _PathError(
                (this,),
                f'{what}: {other} is "periodic" and periodic edges come in '
                f"pairs (got {_fmt_value(_edge_dict(e))})",
            )
        return self

    def boundary(self) -> Boundary:
        kw = {}
        for name in EDGES if self.DIM == 2 else FACES:
            e = getattr(self, name)
            kw[name] = e if isinstance(e, str) else tuple(s.segment() for s in e)
        return Boundary(**kw)


class BoundarySpec3(BoundarySpec):
    """The six faces of a 3D box: the four edges of 2D, then back (z-low), front (z-high)."""

    DIM: ClassVar[int] = 3
    back: Any = "wall"
    front: Any = "wall"

    @field_validator("left", "right", "bottom", "top", "back", "front", mode="before")
    @classmethod
    def _edges(cls, v):
        return _edge(v, SegmentSpec3)


def _edge_dict(e):
    if isinstance(e, str):
        return e
    return [s.model_dump(exclude_defaults=True) for s in e]


# --------------------------------------------------------------------------------------------
# shapes and laws (registry driven, so user-registered shapes and laws work too)

_SHAPE_ALIASES = {"mask": "mask", "sdf": "sdf"}


def _shape_kind(annotation: Any) -> tuple[str, int]:
    ann = annotation if isinstance(annotation, str) else str(annotation)
    ann = ann.replace(" ", "")
    if "Shape" in ann:
        return "shape", 0
    if ann.startswith("tuple[") and set(ann[6:-1].split(",")) == {"float"}:
        return "floats", len(ann[6:-1].split(","))
    if ann == "float":
        return "float", 0
    if ann == "bool":
        return "bool", 0
    if ann == "str":
        return "str", 0
    return "any", 0


def _exc_param(e: Exception) -> str | None:
    m = re.search(r"parameter '(\w+)'", str(e))
    return m.group(1) if m else None


def _shape_dim(cls: type) -> int | None:
    """The dimension of a shape class: 2 or 3 for a primitive, None for the CSG operations
    and transforms (their ``ndim`` is their children's)."""
    nd = getattr(cls, "ndim", 2)
    return nd if isinstance(nd, int) else None


def _lookup(registry: Mapping, name: str):
    return registry.get(name) or {k.lower(): v for k, v in registry.items()}.get(name.lower())


def build_shape(d: Any, base_dir: str | os.PathLike | None = None, dim: int | None = None) -> Shape:
    """A shape from its table (``Shape.to_dict`` format, or a ``mask``/``sdf`` file table).

    ``dim`` (2 or 3, the grid's dimension) accepts the primitives of that dimension only
    (with the CSG operations and transforms), and names the type, its dimension and the
    grid's for a primitive of the other one; None accepts both (as
    ``geometry.shape_from_dict``).  Raises ``_PathError`` naming the key path inside the
    table.
    """
    if isinstance(d, Shape):
        return d
    if not isinstance(d, Mapping):
        raise _PathError((), f"must be a shape table with a 'type' key (got {_fmt_value(d)})")
    every = {**SHAPES, **SHAPES_3D, "ArrayShape": ArrayShape}
    if dim is None:
        registry = every
        known = sorted({**SHAPES, **SHAPES_3D}) + ["mask", "sdf"]
    else:
        registry = {k: c for k, c in every.items() if _shape_dim(c) in (None, dim)}
        known = sorted(k for k, c in {**SHAPES, **SHAPES_3D}.items() if _shape_dim(c) in (None, dim))
        known += ["mask", "sdf"] if dim == 2 else []
    if "type" not in d:
        raise _PathError((), f"missing required key 'type' (one of {', '.join(known)})")
    name = d["type"]
    if not isinstance(name, str):
        raise _PathError(("type",), f"must be a string (got {_fmt_value(name)})")
    if name.lower() in _SHAPE_ALIASES:
        if dim == 3:
            raise _PathError(
                ("type",),
                f"a {name.lower()!r} shape is 2D (read from a 2D array or a picture) but the "
                f"grid is 3D; use the 3D types: {', '.join(known)} (got {name!r})",
            )
        _check_keys(d, ("type", "file", "extent", "invert"), f" for shape type {name!r}")
        d = {**d, "type": "ArrayShape", "mode": name.lower()}
        name = "ArrayShape"
    cls = _lookup(registry, name)
    if cls is None:
        other = _lookup(every, name)
        if other is not None:
            nd = _shape_dim(other)
            raise _PathError(
                ("type",),
                f"shape type {other.__name__!r} is {nd}D but the grid is {dim}D"
                + (" (3D case files say dim = 3 in [grid])" if nd == 3 else "")
                + f"; {dim}D types: {', '.join(known)} (got {name!r})",
            )
        raise _PathError(
            ("type",),
            f"unknown shape type {name!r}{_did_you_mean(name, known)}; "
            f"known types: {', '.join(known)}",
        )
    if cls is ArrayShape and isinstance(d.get("file"), str) and base_dir is not None:
        d = {**d, "file": str(Path(base_dir, d["file"]))}  # relative to the case file
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init and not f.name.startswith("_")}
    _check_keys(
        {k: v for k, v in d.items() if k != "type"}, fields, f" for shape type {cls.__name__!r}"
    )
    kwargs: dict[str, Any] = {}
    for key, value in d.items():
        if key == "type":
            continue
        kind, n = _shape_kind(fields[key].type)
        if cls is Translate and key == "offset":
            # one number per axis of the child: the grid's; without a grid, 2 or 3 (the
            # constructor checks it against the child)
            given = len(value) if isinstance(value, (list, tuple)) else 0
            n = dim if dim is not None else given if given in (2, 3) else 2
        if kind == "shape":
            try:
                kwargs[key] = build_shape(value, base_dir, dim)
            except _PathError as e:
                raise _PathError((key,) + e.path, e.msg) from None
        elif kind == "float":
            kwargs[key] = _number(value, (key,))
        elif kind == "floats":
            if not isinstance(value, (list, tuple)) or len(value) != n:
                raise _PathError((key,), f"must be a list of {n} numbers (got {_fmt_value(value)})")
            kwargs[key] = tuple(_number(x, (key, i)) for i, x in enumerate(value))
        elif kind == "bool":
            if not isinstance(value, bool):
                raise _PathError((key,), f"must be true or false (got {_fmt_value(value)})")
            kwargs[key] = value
        elif kind == "str":
            if not isinstance(value, str):
                raise _PathError((key,), f"must be a string (got {_fmt_value(value)})")
            kwargs[key] = value
        else:
            kwargs[key] = tuple(value) if isinstance(value, list) else value
    missing = [
        k
        for k, f in fields.items()
        if k not in kwargs
        and f.default is dataclasses.MISSING
        and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise _PathError((), f"missing required key {missing[0]!r} for shape type {cls.__name__!r}")
    try:
        return cls(**kwargs)
    except (ValueError, TypeError, ArithmeticError) as e:
        p = _exc_param(e)
        msg = re.sub(r"^\w+: ", "", str(e))
        if p in d:
            msg = re.sub(rf"^parameter '{p}' ", "", msg)
            msg = re.sub(rf",? got {p}=.*$", "", msg)
            raise _PathError((p,), f"{msg} (got {_fmt_value(d[p])})") from None
        raise _PathError((), f"{msg} (got {_fmt_value(dict(d))})") from None


_POSITIVE_LAW_KEYS = ("G", "kappa", "rho0", "mu", "E")


def build_law(d: Any, dim: int | None = None):
    """A material law from ``{law = "neo_hookean", G = 10, kappa = 10, rho0 = 1}``.

    ``dim`` (the grid's dimension) is given to the law: a case file does not write it (a
    ``dim`` key that differs is an error naming it).  None: the table's own ``dim``, else 2.
    """
    if not isinstance(d, Mapping):
        raise _PathError(
            (),
            f'must be a table such as {{law = "neo_hookean", G = 10, kappa = 10}} '
            f"(got {_fmt_value(d)})",
        )
    if "law" not in d:
        raise _PathError(
            (), f"missing required key 'law' (one of {', '.join(map(repr, sorted(LAWS)))})"
        )
    key = d["law"]
    if not isinstance(key, str) or key not in LAWS:
        raise _PathError(
            ("law",),
            f"unknown material law {_fmt_value(key)}"
            f"{_did_you_mean(key, LAWS)}; known laws: {', '.join(sorted(LAWS))}",
        )
    cls = LAWS[key]
    names = [f.name for f in dataclasses.fields(cls) if not f.metadata.get("static", False)]
    required = [
        f.name
        for f in dataclasses.fields(cls)
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    allowed = set(names)
    params = {k: v for k, v in d.items() if k not in ("law", "dim")}
    if "dim" in d:
        given = d["dim"]
        if isinstance(given, bool) or not isinstance(given, int) or given not in (2, 3):
            raise _PathError(("dim",), f"must be 2 or 3 (got {_fmt_value(given)})")
        if dim is not None and given != dim:
            raise _PathError(
                ("dim",),
                f"the law is {given}D but the grid is {dim}D; leave dim out (a law takes the "
                f"grid's dimension) (got {given})",
            )
        dim = given
    alternatives = []
    if key == "svk":
        alternatives = [{"E", "nu"}, {"G", "kappa"}]
        allowed |= {"E", "nu", "G", "kappa"}
    _check_keys(params, allowed, f" for law {key!r}")
    for k, v in params.items():
        _number(v, (k,))
        if k in _POSITIVE_LAW_KEYS and not v > 0:
            raise _PathError((k,), f"must be > 0 (got {_fmt_value(v)})")
        if k == "nu" and not -1 < v < 0.5:
            raise _PathError((k,), f"must lie in (-1, 0.5) (got {_fmt_value(v)})")
    rest = set(params) - {"rho0"}
    if not any(rest == alt for alt in alternatives):
        if rest - set(names):
            choices = " or ".join(
                [" and ".join(required)] + [" and ".join(sorted(a)) for a in alternatives]
            )
            raise _PathError(
                (), f"law {key!r} takes {choices} (got keys {', '.join(sorted(rest))})"
            )
        missing = [n for n in required if n not in params]
        if missing:
            raise _PathError((), f"missing required key {missing[0]!r} for law {key!r}")
    table = {k: v for k, v in d.items() if k != "dim"}
    if dim == 3:
        table["dim"] = 3
    try:
        return law_from_dict(table)
    except (ValueError, TypeError, ArithmeticError) as e:
        p = _exc_param(e)
        msg = re.sub(r"^\w+: ", "", str(e))
        if p in params:
            raise _PathError((p,), f"{msg} (got {_fmt_value(params[p])})") from None
        raise _PathError((), f"{msg} (got {_fmt_value(dict(d))})") from None


def _base_dir(info: ValidationInfo):
    return (info.context or {}).get("base_dir")


#: anchor ``type`` -> class; fields are read from the dataclass, so new options appear here
ANCHORS = {"region": RegionAnchor, "pivot": PivotAnchor}
_ANCHOR_CONSTRAINTS = {"fit_radius": {"gt": 0}, "hold_radius": {"gt": 0}}


def _is_shape_field(f: dataclasses.Field) -> bool:
    ann = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
    return f.name == "region" or "Shape" in ann


def _anchor_spec(kind: str, dim: int = 2) -> type[_Table]:
    """A table model for the non-shape fields of ``ANCHORS[kind]`` (cached per dimension):
    in 3D a pivot's ``center`` and ``axis`` are three numbers; ``axis`` and
    ``half_length`` are 3D keys."""
    if (kind, dim) not in _ANCHOR_SPECS:
        cls = ANCHORS[kind]
        plain = [f.name for f in dataclasses.fields(cls) if not _is_shape_field(f)]
        types = None
        if dim == 3:
            types = {"center": Triple, "axis": Triple}
        else:
            plain = [n for n in plain if n not in ("axis", "half_length")]
        _ANCHOR_SPECS[(kind, dim)] = _spec_from_dataclass(
            f"{kind.title()}AnchorSpec{dim}D", cls, _ANCHOR_CONSTRAINTS, only=plain, types=types
        )
    return _ANCHOR_SPECS[(kind, dim)]


_ANCHOR_SPECS: dict[tuple[str, int], type[_Table]] = {}


def build_anchor(d: Any, base_dir=None, dim: int = 2):
    """An anchor from ``{type = "region", region = SHAPE}`` or ``{type = "pivot", ...}``
    (``dim``: the grid's dimension; a 3D pivot is an axle, see
    :class:`refmap.anchors.PivotAnchor`)."""
    if not isinstance(d, Mapping):
        raise _PathError((), f"must be a table with a 'type' key (got {_fmt_value(d)})")
    if "type" not in d:
        raise _PathError(
            (), f"missing required key 'type' (one of {', '.join(map(repr, ANCHORS))})"
        )
    kind = d["type"]
    if not isinstance(kind, str) or kind not in ANCHORS:
        raise _PathError(
            ("type",),
            f"must be one of {' or '.join(map(repr, ANCHORS))} (got "
            f"{_fmt_value(kind)}){_did_you_mean(kind, ANCHORS)}",
        )
    cls = ANCHORS[kind]
    fields = {f.name: f for f in dataclasses.fields(cls)}
    if dim == 2:
        fields = {k: f for k, f in fields.items() if k not in ("axis", "half_length")}
    rest = {k: v for k, v in d.items() if k != "type"}
    _check_keys(rest, fields, f" for a {kind} anchor")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        if _is_shape_field(f):
            if name not in rest:
                if f.default is dataclasses.MISSING:
                    raise _PathError(
                        (),
                        f"missing required key {name!r} for a {kind} anchor "
                        "(a shape table, in current coordinates)",
                    )
                continue
            try:
                kwargs[name] = build_shape(rest.pop(name), base_dir, dim)
            except _PathError as e:
                raise _PathError((name,) + e.path, e.msg) from None
    try:
        spec = _anchor_spec(kind, dim).model_validate(rest)
    except ValidationError as e:
        raise _from_validation_error(e) from None
    kwargs.update(spec.model_dump(exclude_unset=True))
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as e:
        raise _PathError((), f"{e} (got {_fmt_value(dict(d))})") from None


class SolidSpec(_Table):
    DIM: ClassVar[int] = 2
    name: Str = "solid"
    shape: Any
    law: Any
    strain: tuple[Pair, Pair] = ((1.0, 0.0), (0.0, 1.0))
    strain_center: Pair = (0.0, 0.0)
    velocity: Pair = (0.0, 0.0)
    anchor: Any = None

    @field_validator("anchor", mode="before")
    @classmethod
    def _anchor(cls, v, info: ValidationInfo):
        return build_anchor(v, _base_dir(info))

    @field_validator("shape", mode="before")
    @classmethod
    def _shape(cls, v, info: ValidationInfo):
        return build_shape(v, _base_dir(info), cls.DIM)

    @field_validator("law", mode="before")
    @classmethod
    def _law(cls, v):
        return build_law(v, cls.DIM)

    @model_validator(mode="after")
    def _strain(self):
        if self.DIM == 2:
            (a, b), (c, d) = self.strain
            det = a * d - b * c
        else:
            with np.errstate(all="ignore"):
                det = float(np.linalg.det(np.asarray(self.strain, dtype=float)))
        if not (math.isfinite(det) and det > 0):
            raise _PathError(
                ("strain",),
                f"must have a positive, finite determinant (det = {det:.4g}; "
                f"got {_fmt_value([list(r) for r in self.strain])})",
            )
        return self


class SolidSpec3(SolidSpec):
    """A solid of a 3D case: 3x3 strain, three-number centre and velocity; anchors with 3D
    regions, or a pivot axle."""

    DIM: ClassVar[int] = 3
    strain: tuple[Triple, Triple, Triple] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    strain_center: Triple = (0.0, 0.0, 0.0)
    velocity: Triple = (0.0, 0.0, 0.0)

    @field_validator("anchor", mode="before")
    @classmethod
    def _anchor(cls, v, info: ValidationInfo):
        return None if v is None else build_anchor(v, _base_dir(info), 3)


def build_initial_velocity(d: Any, base_dir: str | os.PathLike | None = None, dim: int = 2):
    """The ``[initial_velocity]`` table: ``{u = FORMULA, v = FORMULA}`` (3D: ``w`` too; a
    left-out component is 0) or ``{file = PATH, dataset = NAME}`` (``.npy`` or ``.h5``,
    relative to the case file).  ``dim`` is the grid's dimension.  Raises ``_PathError``
    naming the key inside the table."""
    if d is None:
        return None
    comps = ("u", "v") if dim == 2 else ("u", "v", "w")
    formulas = ", ".join(f'{k} = "FORMULA"' for k in comps)
    if not isinstance(d, Mapping):
        raise _PathError(
            (),
            f'must be a table: {{{formulas}}} or {{file = "v0.npy"}} '
            f"(got {_fmt_value(d)})",
        )
    if dim == 2 and "w" in d:
        raise _PathError(
            (),
            "unknown key 'w': w is the z component, for a 3D case (add dim = 3 to [grid]); a 2D "
            f"case takes u and v (got w = {_fmt_value(d['w'])})",
        )
    _check_keys(d, comps + ("file", "dataset"))
    formula = [k for k in comps if k in d]
    names = "u, v" if dim == 2 else "u, v, w"
    variables = "x and y" if dim == 2 else "x, y and z"
    if "file" in d and formula:
        raise _PathError(
            (formula[0],), f"give either formulas {names} or a file, not both (got file = {_fmt_value(d['file'])})"
        )
    if "file" not in d and not formula:
        if "dataset" in d:
            raise _PathError((), "missing required key 'file' (dataset names a dataset in it)")
        some = "u and/or v" if dim == 2 else "u, v and/or w"
        raise _PathError((), f"needs {some} (formulas in {variables}), or file")
    for k in comps + ("file", "dataset"):
        if k in d and (isinstance(d[k], bool) or not isinstance(d[k], (str, int, float)) or (
            k in ("file", "dataset") and not isinstance(d[k], str))):
            what = f"a formula in {variables} (a string)" if k in comps else "a string"
            raise _PathError((k,), f"must be {what} (got {_fmt_value(d[k])})")
    try:
        if formula:
            return VelocityExpression(d.get("u", "0"), d.get("v", "0"), d.get("w"), dim)
        f = d["file"]
        if base_dir is not None:
            f = str(Path(base_dir, f))  # relative to the case file
        return VelocityFile(f, d.get("dataset"))
    except InitialVelocityError as e:
        key = e.key or ("file" if "file" in d else "")
        raise _PathError((key,) if key else (), e.msg) from None


def _initial_velocity_validator(cls, v, info: ValidationInfo):
    return build_initial_velocity(v, _base_dir(info))


def _initial_velocity_validator_3d(cls, v, info: ValidationInfo):
    return build_initial_velocity(v, _base_dir(info), 3)


def _case_spec_model(dim: int = 2):
    """The schema of a whole case file of dimension ``dim`` (``[grid] dim``)."""
    fields = dict(
        name=(Str | None, None),
        description=(Str, ""),
        gravity=(Pair, (0.0, 0.0)) if dim == 2 else (Triple, (0.0, 0.0, 0.0)),
        grid=(GridSpec, ...),
        fluid=(FluidSpec, None),
        time=(TimeSpec, None),
        numerics=(NumericsSpec, None),
        output=(OutputSpec, None),
        boundary=(BoundarySpec if dim == 2 else BoundarySpec3, None),
        solids=(list[SolidSpec if dim == 2 else SolidSpec3], []),
    )
    fields["contact"] = (ContactSpec | None, None)
    fields["initial_velocity"] = (Any, None)
    check = _initial_velocity_validator if dim == 2 else _initial_velocity_validator_3d
    validators = {
        "_initial_velocity": field_validator("initial_velocity", mode="before")(
            classmethod(check)
        )
    }
    name = "CaseSpec" if dim == 2 else "CaseSpec3"
    return create_model(name, __base__=_Table, __validators__=validators, **fields)


CaseSpec = _case_spec_model()
#: the schema of a 3D case file (``[grid] dim = 3``)
CaseSpec3 = _case_spec_model(3)


def _file_dim(data: Mapping) -> int:
    """3 when the file's ``[grid]`` says ``dim = 3``, else 2.  A bad ``dim`` is reported
    first (everything else is read by the schema it selects)."""
    grid = data.get("grid")
    if isinstance(grid, Mapping) and "dim" in grid:
        try:
            return _dim_value(grid["dim"])
        except _PathError as e:
            raise CaseFileError(f"grid.dim: {e.msg}", "grid.dim") from None
    return 2


# --------------------------------------------------------------------------------------------
# shapes from data


class _SampledSDF:
    """A signed distance sampled on a pixel grid; hashed by content (a static jit key)."""

    __slots__ = ("values", "extent", "digest")

    def __init__(self, values: np.ndarray, extent: tuple[float, float, float, float]):
        self.values = np.ascontiguousarray(values, dtype=np.float64)
        self.extent = tuple(float(e) for e in extent)
        h = hashlib.sha1(self.values.tobytes())
        h.update(repr((self.values.shape, self.extent)).encode())
        self.digest = h.hexdigest()

    def __hash__(self):
        return hash(self.digest)

    def __eq__(self, other):
        return isinstance(other, _SampledSDF) and other.digest == self.digest

    def __repr__(self):
        return f"<sampled sdf {self.values.shape[0]}x{self.values.shape[1]} {self.digest[:8]}>"


def _read_array(file: str, mode: str, invert: bool) -> tuple[np.ndarray, bool]:
    """(array indexed [i along x, j along y], is_mask) from a .npy file or a picture."""
    p = Path(file)
    if not p.is_file():
        raise ValueError(f"ArrayShape: parameter 'file' names no readable file: {file}")
    suffix = p.suffix.lower()
    try:
        if suffix == ".npy":
            a = np.load(p, allow_pickle=False)
        elif suffix in (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".gif"):
            if mode == "sdf":
                raise ValueError(
                    "ArrayShape: parameter 'file' must be a .npy array for type 'sdf' "
                    f"(a picture can only be a mask), got {file}"
                )
            import matplotlib.image as mpimg

            img = np.asarray(mpimg.imread(p), dtype=float)
            if img.ndim == 3:
                if img.max() > 1.0:
                    img = img / 255.0
                gray = img[..., :3].mean(axis=-1) if img.shape[-1] >= 3 else img[..., 0]
                if img.shape[-1] == 4 and img[..., 3].min() < 1.0:  # transparent = outside
                    gray = np.where(img[..., 3] < 0.5, 1.0, gray)
            else:
                gray = img / 255.0 if img.max() > 1.0 else img
            a = (gray < 0.5)[::-1].T  # dark pixels are solid; rows run down the picture
        else:
            raise ValueError(
                f"ArrayShape: parameter 'file' must be a .npy array or a picture (.png), got {file}"
            )
    except ValueError:
        raise
    except Exception as e:  # noqa: BLE001 - any unreadable file is a bad value
        raise ValueError(
            f"ArrayShape: parameter 'file' could not be read ({type(e).__name__}: {e}): {file}"
        ) from None
    a = np.asarray(a)
    if a.ndim != 2 or min(a.shape) < 2:
        raise ValueError(
            f"ArrayShape: parameter 'file' must hold a 2D array of at least 2 x 2 "
            f"values, got shape {a.shape} in {file}"
        )
    if a.dtype.kind not in "biuf":
        raise ValueError(
            f"ArrayShape: parameter 'file' must hold numbers or booleans, got dtype "
            f"{a.dtype} in {file}"
        )
    return a, mode == "mask"


def _mask_sdf(inside: np.ndarray, dx: float, dy: float) -> np.ndarray:
    try:
        from scipy.ndimage import distance_transform_edt
    except ImportError:  # pragma: no cover - scipy is a test dependency
        raise ValueError(
            "ArrayShape: parameter 'mode' 'mask' needs scipy (pip install scipy) "
            "to build a signed distance; or give a signed-distance array with "
            'type = "sdf"'
        ) from None
    d_out = distance_transform_edt(~inside, sampling=(dx, dy))  # outside: distance to inside
    d_in = distance_transform_edt(inside, sampling=(dx, dy))  # inside: distance to outside
    half = 0.5 * min(dx, dy)
    return np.where(inside, -(d_in - half), d_out - half)


@dataclasses.dataclass(frozen=True)
class ArrayShape(Shape):
    """A shape sampled on a pixel grid covering ``extent = (x0, x1, y0, y1)``.

    ``mode = "mask"``: the file holds a mask (booleans, or numbers with inside > 0.5; in a
    picture, dark pixels are inside), turned into a signed distance with
    ``scipy.ndimage.distance_transform_edt``.  ``mode = "sdf"``: the file holds a signed
    distance (negative inside, in length units).  ``invert`` swaps inside and outside.

    A ``.npy`` array is indexed ``[i, j]`` with i along x and j along y (like refmap's
    fields: ``plt.imshow(a.T, origin="lower")`` shows it the right way up); pixel (i, j)
    is centred at ``(x0 + (i + 1/2) dx, y0 + (j + 1/2) dy)``.  A picture is read as it
    looks (its top row at y1).  The distance is interpolated bilinearly; outside the
    extent it is continued as the value at the nearest edge point plus the distance to it.
    ``file`` is an absolute path in ``to_dict()`` (a case file may give it relative to
    itself).

    The class is not added to ``refmap.geometry.SHAPES`` (whose tests pin it to the built-in
    types): :func:`build_shape` and the case-file loader know it; call
    :func:`register_array_shape` to let ``geometry.shape_from_dict`` rebuild it too.
    """

    file: str
    extent: tuple[float, float, float, float]
    mode: str = "mask"
    invert: bool = False
    _data: Any = dataclasses.field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        cls = "ArrayShape"
        if not isinstance(self.file, (str, os.PathLike)):
            raise ValueError(f"{cls}: parameter 'file' must be a path, got file={self.file!r}")
        object.__setattr__(self, "file", str(Path(self.file).expanduser().resolve()))
        try:
            ext = tuple(float(e) for e in self.extent)
        except (TypeError, ValueError):
            ext = ()
        if len(ext) != 4 or not all(math.isfinite(e) for e in ext):
            raise ValueError(
                f"{cls}: parameter 'extent' must be four finite numbers [x0, x1, y0, y1], "
                f"got extent={self.extent!r}"
            )
        if not (ext[1] > ext[0] and ext[3] > ext[2]):
            raise ValueError(
                f"{cls}: parameter 'extent' needs x1 > x0 and y1 > y0, got extent={ext!r}"
            )
        object.__setattr__(self, "extent", ext)
        if self.mode not in ("mask", "sdf"):
            raise ValueError(
                f"{cls}: parameter 'mode' must be 'mask' or 'sdf', got mode={self.mode!r}"
            )
        if not isinstance(self.invert, (bool, np.bool_)):
            raise ValueError(
                f"{cls}: parameter 'invert' must be true or false, got invert={self.invert!r}"
            )
        object.__setattr__(self, "invert", bool(self.invert))
        a, is_mask = _read_array(self.file, self.mode, self.invert)
        nx, ny = a.shape
        dx, dy = (ext[1] - ext[0]) / nx, (ext[3] - ext[2]) / ny
        if is_mask:
            inside = (a > 0.5) if a.dtype.kind != "b" else a.astype(bool)
            if self.invert:
                inside = ~inside
            if not inside.any() or inside.all():
                what = "no" if not inside.any() else "only"
                raise ValueError(
                    f"{cls}: parameter 'file' must hold a mask with inside and outside "
                    f"pixels, got {what} inside pixels in {self.file}"
                )
            sdf = _mask_sdf(inside, dx, dy)
        else:
            sdf = np.asarray(a, dtype=float)
            if not np.all(np.isfinite(sdf)):
                raise ValueError(f"{cls}: parameter 'file' holds non-finite values in {self.file}")
            if self.invert:
                sdf = -sdf
            if not (sdf < 0).any():
                raise ValueError(
                    f"{cls}: parameter 'file' holds a signed distance with no negative "
                    f"(inside) value in {self.file}"
                )
        object.__setattr__(self, "_data", _SampledSDF(sdf, ext))

    def _sdf(self, X, Y):
        data = self._data
        v = jnp.asarray(data.values)
        x0, x1, y0, y1 = data.extent
        nx, ny = data.values.shape
        dx, dy = (x1 - x0) / nx, (y1 - y0) / ny
        u = (X - x0) / dx - 0.5
        w = (Y - y0) / dy - 0.5
        uc = jnp.clip(u, 0.0, nx - 1.0)
        wc = jnp.clip(w, 0.0, ny - 1.0)
        i0 = jnp.clip(jnp.floor(uc).astype(jnp.int32), 0, nx - 2)
        j0 = jnp.clip(jnp.floor(wc).astype(jnp.int32), 0, ny - 2)
        tu = uc - i0
        tw = wc - j0
        f = (
            (1 - tu) * (1 - tw) * v[i0, j0]
            + tu * (1 - tw) * v[i0 + 1, j0]
            + (1 - tu) * tw * v[i0, j0 + 1]
            + tu * tw * v[i0 + 1, j0 + 1]
        )
        return f + jnp.sqrt(((u - uc) * dx) ** 2 + ((w - wc) * dy) ** 2)

    def bbox(self):
        v = self._data.values
        x0, x1, y0, y1 = self.extent
        nx, ny = v.shape
        dx, dy = (x1 - x0) / nx, (y1 - y0) / ny
        ii, jj = np.nonzero(v < 0)
        return (
            x0 + max(ii.min() - 0.5, 0) * dx,
            x0 + min(ii.max() + 1.5, nx) * dx,
            y0 + max(jj.min() - 0.5, 0) * dy,
            y0 + min(jj.max() + 1.5, ny) * dy,
        )

    def to_dict(self):
        return {
            "type": "ArrayShape",
            "file": self.file,
            "extent": list(self.extent),
            "mode": self.mode,
            "invert": self.invert,
        }


def register_array_shape() -> None:
    """Add :class:`ArrayShape` to ``refmap.geometry.SHAPES`` (for ``shape_from_dict``)."""
    SHAPES["ArrayShape"] = ArrayShape


# --------------------------------------------------------------------------------------------
# loading


_RUN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")


def check_run_name(name) -> str:
    """``name`` if it can name a run folder (``runs/NAME_NX``), else :class:`CaseFileError`.

    A case name becomes part of the default output path, so it must be one plain folder
    name: letters, digits, ``.``, ``_`` and ``-``, starting with a letter or digit (no path
    separators, no ``..``, not empty).  A name that is not is refused, not rewritten, so
    the run lands where the user expects; ``--out`` (or ``output.out``) chooses any folder.
    """
    if not isinstance(name, str) or not _RUN_NAME.fullmatch(name):
        raise CaseFileError(
            f"name: {name!r} cannot name the run folder runs/NAME_N: use letters, digits, "
            "'.', '_' and '-', starting with a letter or digit (no '/', no '..', not empty), "
            "or choose the folder with --out",
            "name",
        )
    return name


@dataclasses.dataclass(frozen=True)
class RunPlan:
    """A loaded case file: the Case and the ``[output]`` settings of the run."""

    case: Case
    out: Path | None = None
    movie: bool = False
    pictures: bool = True
    source: Path | None = None

    @property
    def out_dir(self) -> Path:
        """``out``, or ``runs/NAME_NX`` (as ``refmap run SCENARIO`` uses)."""
        return (
            self.out
            if self.out is not None
            else Path("runs") / f"{self.case.name}_{self.case.grid.nx}"
        )


#: override key -> key path in the case file
OVERRIDES = {
    "n": ("grid", "n"),
    "nx": ("grid", "nx"),
    "ny": ("grid", "ny"),
    "nz": ("grid", "nz"),
    "t_end": ("time", "t_end"),
    "frames": ("time", "frames"),
    "cfl": ("numerics", "cfl"),
    "movie": ("output", "movie"),
    "pictures": ("output", "pictures"),
    "picture_field": ("output", "picture_field"),
    "name": ("name",),
}


def _apply_overrides(data: dict, overrides: Mapping | None) -> tuple[dict, Any]:
    """Overrides in ``data`` (a deep copy); ``out`` is returned separately (relative to the
    working directory, not to the case file)."""
    data = copy.deepcopy(data)
    out = None
    for key, value in (overrides or {}).items():
        if value is None:
            continue
        if key == "out":
            if not isinstance(value, (str, os.PathLike)):
                raise CaseFileError(f"out: must be a folder path (got {_fmt_value(value)})", "out")
            out = Path(value)
            continue
        if key in OVERRIDES:
            path = OVERRIDES[key]
        elif isinstance(key, str) and "." in key:
            path = tuple(key.split("."))
        else:
            raise CaseFileError(
                f"unknown override {key!r}{_did_you_mean(key, list(OVERRIDES) + ['out'])}; use one of "
                f"{', '.join(list(OVERRIDES) + ['out'])} or a dotted key such as 'fluid.eta'",
                str(key),
            )
        if isinstance(value, Path):
            value = str(value)
        if path == ("grid", "n"):
            grid = data.get("grid")
            if isinstance(grid, dict):
                nx, ny = grid.get("nx"), grid.get("ny")
                if (
                    isinstance(nx, int)
                    and isinstance(ny, int)
                    and "n" not in grid
                    and nx > 0
                    and isinstance(value, int)
                    and not isinstance(value, bool)
                ):
                    grid["nx"] = value
                    grid["ny"] = max(8, int(round(ny * value / nx)))
                    nz = grid.get("nz")
                    if isinstance(nz, int) and not isinstance(nz, bool):  # 3D: nz too
                        grid["nz"] = max(8, int(round(nz * value / nx)))
                    continue
        node = data
        for p in path[:-1]:
            if not isinstance(node.get(p), dict):
                if p in node:  # not a table: leave it, validation names the problem
                    break
                node[p] = {}
            node = node[p]
        else:
            node[path[-1]] = value
    return data, out


def _context(e: _PathError) -> CaseFileError:
    key = _fmt_path(e.path)
    return CaseFileError(f"{key}: {e.msg}" if key else e.msg, key)


def case_from_dict(
    data: Any,
    base_dir: str | os.PathLike | None = ".",
    overrides: Mapping | None = None,
    source: str | os.PathLike | None = None,
) -> RunPlan:
    """Validate a parsed case file (a dict as ``tomllib`` returns) into a :class:`RunPlan`.

    ``base_dir`` is where relative paths (mask files, ``output.out``) are resolved.
    Raises :class:`CaseFileError` (one, naming the key path and value) for any problem.
    """
    if not isinstance(data, Mapping):
        raise CaseFileError(f"a case file must be a table of keys (got {_fmt_value(data)})")
    data, out_override = _apply_overrides(dict(data), overrides)
    if "name" not in data and source is not None:
        data["name"] = Path(source).stem
    schema = CaseSpec3 if _file_dim(data) == 3 else CaseSpec
    try:
        spec = schema.model_validate(data, context={"base_dir": base_dir})
    except ValidationError as e:
        lines = []
        for err in e.errors():
            path, msg = _describe_pydantic(err)
            key = _fmt_path(path)
            lines.append((key, f"{key}: {msg}" if key else msg))
        first_key, first = lines[0]
        more = [m for _, m in lines[1:]]
        message = first + "".join(f"\n  also: {m}" for m in more[:9])
        if len(more) > 9:
            message += f"\n  (and {len(more) - 9} more)"
        raise CaseFileError(message, first_key) from None
    except _PathError as e:  # raised outside a validator (should not happen)
        raise _context(e) from None
    try:
        case = _assemble(spec)
        if case.grid.ndim == 3:
            _check_3d(case)
    except _PathError as e:
        raise _context(e) from None
    from refmap.resources import check_memory

    try:
        check_memory(case)  # before the geometry check makes grid-sized arrays
    except CaseError as e:
        raise CaseFileError(f"grid: {e}", "grid") from None
    try:
        _check_geometry(case)
    except _PathError as e:
        raise _context(e) from None
    try:
        case.validate()
    except CaseError as e:
        raise CaseFileError(str(e)) from None
    except ValueError as e:
        raise CaseFileError(f"invalid case: {e}") from None
    o = spec.output or OutputSpec()
    out = out_override
    if out is None and o.out is not None:
        out = Path(o.out) if base_dir is None else Path(base_dir, o.out)
    if out is None:  # the run folder will be runs/NAME_NX: the name must be a plain one
        check_run_name(case.name)
    return RunPlan(
        case=case,
        out=out,
        movie=o.movie,
        pictures=o.pictures,
        source=Path(source) if source is not None else None,
    )


def _assemble(spec) -> Case:
    g = spec.grid
    try:
        grid = g.grid()
    except ValueError as e:
        raise _PathError(("grid",), str(e)) from None
    fluid = FluidParams(**(spec.fluid or FluidSpec()).model_dump())
    try:
        numerics = Numerics(**(spec.numerics or NumericsSpec()).model_dump())
    except ValueError as e:
        m = re.match(r"numerics (\w+)", str(e))
        raise _PathError(("numerics",) + ((m.group(1),) if m else ()), str(e)) from None
    try:
        default = BoundarySpec3() if g.dim == 3 else BoundarySpec()  # walls all round
        boundary = (spec.boundary or default).boundary()
    except ValueError as e:
        raise _PathError(("boundary",), str(e)) from None
    solids = []
    for k, s in enumerate(spec.solids):
        try:
            solids.append(
                Solid(
                    shape=s.shape,
                    law=s.law,
                    strain=s.strain,
                    strain_center=s.strain_center,
                    velocity=s.velocity,
                    anchor=s.anchor,
                    name=s.name,
                )
            )
        except ValueError as e:
            raise _PathError(("solids", k), str(e)) from None
    t = spec.time or TimeSpec()
    o = spec.output or OutputSpec()
    kw = dict(
        name=spec.name if spec.name is not None else "case",
        grid=grid,
        solids=tuple(solids),
        boundary=boundary,
        fluid=fluid,
        numerics=numerics,
        gravity=tuple(spec.gravity),
        t_end=t.t_end,
        frames=t.frames,
        picture_field=o.picture_field,
        description=spec.description,
        initial_velocity=getattr(spec, "initial_velocity", None),
    )
    contact = getattr(spec, "contact", None)
    if contact is None:
        return Case(**kw)
    try:
        contact_obj = Contact(**contact.model_dump())
    except ValueError as e:
        raise _PathError(("contact",), str(e)) from None
    return Case(**kw, contact=contact_obj)


def _check_3d(case: Case) -> None:
    """The settings of a 3D case that the 3D step does not have yet, each named by its key
    (the wording is :func:`refmap.model.check_3d_support`'s)."""
    try:
        check_3d_support(case.numerics, ())
    except ValueError as e:
        m = re.search(r"numerics\.(\w+)", str(e))
        key = ("numerics", m.group(1)) if m else ("numerics",)
        got = f" (got {_fmt_value(getattr(case.numerics, key[1]))})" if m else ""
        raise _PathError(key, f"{e}{got}") from None
    if case.contact is not None:
        try:
            check_3d_support(case.numerics, (), (case.contact,))
        except ValueError as e:
            raise _PathError(("contact",), f"{e}; leave [contact] out") from None


_AXES = "xyz"


def _span(coords, mask) -> str:
    return ", ".join(
        f"{_AXES[a]} in [{X[mask].min():.3g}, {X[mask].max():.3g}]" for a, X in enumerate(coords)
    )


def _current_bbox(solid: Solid):
    """The solid's box in current coordinates, ``(x0, x1, y0, y1[, z0, z1])`` (None if its
    shape has no bbox)."""
    import itertools

    try:
        bb = tuple(solid.shape.bbox())
    except Exception:  # noqa: BLE001 - user shapes may not implement bbox
        return None
    A = np.asarray(solid.strain)
    c = np.asarray(solid.strain_center)
    nd = len(c)
    if len(bb) != 2 * nd:
        return None
    with np.errstate(all="ignore"):
        try:
            Ainv = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            return None
        pts = np.array(list(itertools.product(*(bb[2 * a: 2 * a + 2] for a in range(nd))))) - c
        cur = pts @ Ainv.T + c  # x = A^-1 (xi - c) + c
    if not np.all(np.isfinite(cur)):
        return None
    return tuple(v for a in range(nd) for v in (cur[:, a].min(), cur[:, a].max()))


def _check_geometry(case: Case) -> None:
    """Shapes covering grid nodes, no overlap at t = 0, anchors holding grid nodes; errors
    name the key path.  Which edges a solid may touch is :meth:`refmap.case.Case.validate`'s
    rule (walls, slip and tangential velocity edges, not edges with flow through them), the
    same for a case file as for a case built in Python."""
    g = case.grid
    coords = g.mesh("node")
    nd = len(coords)
    X, Y = coords[0], coords[1]
    lows = g.lows
    highs = g.highs
    dom = " x ".join(f"[{lo:g}, {hi:g}]" for lo, hi in zip(lows, highs, strict=True))
    insides = []
    for k, s in enumerate(case.solids):
        where = ("solids", k, "shape")
        with np.errstate(all="ignore"):
            xi = s.initial_map(*coords)
            phi = np.asarray(s.shape(*xi))
        inside = phi < 0
        if not inside.any():
            bb = _current_bbox(s)
            if bb is None or any(bb[2 * a + 1] < lows[a] or bb[2 * a] > highs[a]
                                 for a in range(nd)):
                spans = (
                    ""
                    if bb is None
                    else "; the shape spans " + ", ".join(
                        f"{_AXES[a]} in [{bb[2 * a]:.3g}, {bb[2 * a + 1]:.3g}]" for a in range(nd))
                )
                raise _PathError(where, f"outside the domain {dom}{spans}")
            raise _PathError(
                where, f"covers no grid node: too small for the grid (nx = {g.nx}, h = {g.h:.3g})"
            )
        if inside.sum() < 4:
            raise _PathError(
                where,
                f"only {int(inside.sum())} grid nodes inside; refine the grid "
                f"(nx = {g.nx}) or enlarge the shape",
            )
        a = s.anchor
        if isinstance(a, PivotAnchor):
            with np.errstate(all="ignore"):
                r2 = (X - a.center[0]) ** 2 + (Y - a.center[1]) ** 2
            if not np.any(r2 < a.fit_radius**2):
                raise _PathError(
                    ("solids", k, "anchor", "fit_radius"),
                    f"holds no grid node; enlarge it or refine the grid (h = {g.h:.3g}) "
                    f"(got {a.fit_radius!r})",
                )
        elif isinstance(a, RegionAnchor):
            with np.errstate(all="ignore"):
                held = a.mask(g)
            if not held.any():
                raise _PathError(
                    ("solids", k, "anchor", "region"),
                    f"covers no grid node of the domain {dom} (h = {g.h:.3g})",
                )
            if not (held & inside).any():
                raise _PathError(
                    ("solids", k, "anchor", "region"),
                    f"holds no node of the solid: its {int(held.sum())} grid nodes lie "
                    f"outside the solid, which spans {_span(coords, inside)}",
                )
        insides.append(inside)
    if case.initial_velocity is not None:  # shape against the grid, finite values
        try:
            case.initial_velocity.sample(g)
        except InitialVelocityError as e:
            raise _PathError(("initial_velocity",) + ((e.key,) if e.key else ()), e.msg) from None
    for j in range(len(insides)):
        for k in range(j + 1, len(insides)):
            both = insides[j] & insides[k]
            if both.any():
                raise _PathError(
                    (),
                    f"solids[{j}] and solids[{k}] overlap at t = 0 "
                    f"({int(both.sum())} grid nodes inside both: {_span(coords, both)})",
                )


def load_run(path: str | os.PathLike, overrides: Mapping | None = None) -> RunPlan:
    """Read a case file into a :class:`RunPlan` (case + output settings).

    ``overrides`` maps keys of :data:`OVERRIDES` (``n``, ``t_end``, ``frames``, ``cfl``,
    ``movie``, ...), ``out`` (a folder, relative to the working directory) or dotted key
    paths (``"fluid.eta"``) to values; None values are ignored.
    """
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise CaseFileError(f"no case file {str(path)!r}", file=str(path)) from None
    except (OSError, UnicodeDecodeError) as e:
        raise CaseFileError(f"cannot read case file {str(path)!r}: {e}", file=str(path)) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise CaseFileError(f"{path.name}: not valid TOML: {e}", file=str(path)) from None
    try:
        return case_from_dict(data, base_dir=path.parent, overrides=overrides, source=path)
    except CaseFileError as e:
        e.file = str(path)
        raise


def load_case(path: str | os.PathLike, overrides: Mapping | None = None) -> Case:
    """Read, override, validate: the :class:`~refmap.case.Case` of a case file."""
    return load_run(path, overrides).case


def is_case_file(target: str | os.PathLike) -> bool:
    """True if ``target`` names a case file (ends in .toml) rather than a scenario."""
    return str(target).lower().endswith(".toml")


# --------------------------------------------------------------------------------------------
# writing TOML (the subset case files use)

_BARE = re.compile(r"[A-Za-z0-9_-]+")


class Inline(dict):
    """A table written inline (``{a = 1, b = 2}``) by :func:`to_toml`."""


def _toml_str(s: str) -> str:
    out = ['"']
    for ch in s:
        o = ord(ch)
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif ch == "\r":
            out.append("\\r")
        elif o < 0x20 or o == 0x7F:
            out.append(f"\\u{o:04X}")
        elif 0xD800 <= o <= 0xDFFF:  # lone surrogate: not representable
            out.append("\\uFFFD")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def _toml_key(k: str) -> str:
    return k if _BARE.fullmatch(k) else _toml_str(k)


def _toml_value(v: Any) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        f = float(v)
        if math.isnan(f):
            return "nan"
        if math.isinf(f):
            return "inf" if f > 0 else "-inf"
        return repr(f)
    if isinstance(v, str):
        return _toml_str(v)
    if isinstance(v, Path):
        return _toml_str(str(v))
    if isinstance(v, Mapping):
        items = [f"{_toml_key(str(k))} = {_toml_value(x)}" for k, x in v.items() if x is not None]
        return "{" + ", ".join(items) + "}" if items else "{}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML: {v!r}")


def _is_table(v) -> bool:
    return isinstance(v, Mapping) and not isinstance(v, Inline)


def _is_table_array(v) -> bool:
    return isinstance(v, (list, tuple)) and bool(v) and all(_is_table(x) for x in v)


def _emit(lines: list, path: tuple, table: Mapping, comments: Mapping | None) -> None:
    comments = comments or {}
    for k, v in table.items():
        if v is None or _is_table(v) or _is_table_array(v):
            continue
        lines.append(f"{_toml_key(str(k))} = {_toml_value(v)}")
    for k, v in table.items():
        sub = path + (str(k),)
        name = ".".join(_toml_key(p) for p in sub)
        if _is_table(v):
            lines.append("")
            if sub in comments:
                lines.extend(f"# {c}" if c else "#" for c in comments[sub].splitlines())
            lines.append(f"[{name}]")
            _emit(lines, sub, v, comments)
        elif _is_table_array(v):
            for i, item in enumerate(v):
                lines.append("")
                if sub in comments and i == 0:
                    lines.extend(f"# {c}" if c else "#" for c in comments[sub].splitlines())
                lines.append(f"[[{name}]]")
                _emit(lines, sub, item, comments)


def to_toml(doc: Mapping, comments: Mapping | None = None) -> str:
    """TOML text of ``doc``: dicts become tables, lists of dicts arrays of tables,
    :class:`Inline` dicts inline tables; None values are left out.  ``comments`` maps key
    paths (tuples) of tables to comment text written above their headers."""
    lines: list[str] = []
    _emit(lines, (), doc, comments)
    return "\n".join(lines).lstrip("\n") + "\n"


# --------------------------------------------------------------------------------------------
# Case -> case file


def _relative_file(f, base_dir):
    """``f`` relative to the case file's folder ``base_dir`` (unchanged when there is none,
    or when no relative path exists, e.g. another drive on Windows)."""
    if base_dir is None:
        return f
    try:
        return os.path.relpath(f, Path(base_dir).resolve())
    except ValueError:
        return f


def _shape_doc(shape: Shape, base_dir) -> dict:
    if isinstance(shape, ArrayShape):
        f = _relative_file(shape.file, base_dir)
        d = {"type": shape.mode, "file": f, "extent": list(shape.extent)}
        if shape.invert:
            d["invert"] = True
        return d
    d = shape.to_dict()
    out = {}
    for k, v in d.items():
        child = getattr(shape, k, None) if k != "type" else None
        out[k] = _shape_doc(child, base_dir) if isinstance(child, Shape) else v
    return out


def _edge_doc(edge, nd: int = 2):
    if edge == "periodic":
        return "periodic"
    zero = {} if nd == 2 else {"velocity": (0.0,) * nd}  # a face's resting velocity
    if (
        len(edge) == 1
        and edge[0].kind in ("wall", "slip", "outflow")
        and edge[0] == Segment(edge[0].kind, **zero)
    ):
        return edge[0].kind
    default = Segment(**zero)
    out = []
    for s in edge:
        d = Inline(kind=s.kind)
        for f in dataclasses.fields(Segment):
            if f.name == "kind":
                continue
            v = getattr(s, f.name)
            if v != getattr(default, f.name):
                d[f.name] = list(v) if isinstance(v, tuple) else v
        out.append(d)
    return out


def _grid_doc(g) -> dict:
    grid: dict[str, Any] = {}
    if getattr(g, "ndim", 2) == 3:
        grid["dim"] = 3
        cubic = all(
            m == _derived_ny(g.nx, g.ax, g.bx, lo, hi) and 8 <= g.nx * (hi - lo) / (g.bx - g.ax)
            for m, lo, hi in ((g.ny, g.ay, g.by), (g.nz, g.az, g.bz))
        )
        if cubic:
            grid["n"] = g.nx
        else:
            grid["nx"], grid["ny"], grid["nz"] = g.nx, g.ny, g.nz
        grid.update(ax=g.ax, bx=g.bx, ay=g.ay, by=g.by, az=g.az, bz=g.bz)
        return grid
    if g.ny == _derived_ny(g.nx, g.ax, g.bx, g.ay, g.by):
        grid["n"] = g.nx
    else:
        grid["nx"], grid["ny"] = g.nx, g.ny
    grid.update(ax=g.ax, bx=g.bx, ay=g.ay, by=g.by)
    return grid


def _case_doc(case: Case, base_dir=None) -> dict:
    nd = getattr(case.grid, "ndim", 2)
    grid = _grid_doc(case.grid)
    doc: dict[str, Any] = {"name": case.name}
    if getattr(case, "description", ""):
        doc["description"] = case.description
    doc["gravity"] = [float(x) for x in case.gravity]
    doc["grid"] = grid
    doc["time"] = {"t_end": case.t_end, "frames": case.frames}
    doc["fluid"] = case.fluid.to_dict()
    doc["numerics"] = {k: v for k, v in case.numerics.to_dict().items() if v is not None}
    doc["output"] = {"picture_field": case.picture_field}
    faces = EDGES if nd == 2 else FACES
    doc["boundary"] = {name: _edge_doc(getattr(case.boundary, name), nd) for name in faces}
    if case.contact is not None:
        doc["contact"] = case.contact.to_dict()
    iv = as_initial_velocity(case.initial_velocity)
    if isinstance(iv, VelocityExpression):
        doc["initial_velocity"] = dict(iv.to_dict())  # u, v (and w in 3D)
    elif isinstance(iv, VelocityFile):
        doc["initial_velocity"] = {"file": _relative_file(iv.file, base_dir)}
        if iv.dataset is not None:
            doc["initial_velocity"]["dataset"] = iv.dataset
    elif iv is not None:
        raise CaseFileError(
            f"initial_velocity: cannot be written to a case file: {iv!r} is not a formula or a "
            "file; save its node values with numpy.save and give "
            '[initial_velocity] file = "v0.npy"',
            "initial_velocity",
        )
    solids = []
    for k, s in enumerate(case.solids):
        try:
            law = Inline(s.law.to_dict())
            if law.get("dim") == nd:  # a case file's laws take the grid's dimension
                del law["dim"]
        except (ValueError, TypeError) as e:
            raise CaseFileError(
                f"solids[{k}].law: cannot be written to a case file: {e}", f"solids[{k}].law"
            ) from None
        try:
            shape = _shape_doc(s.shape, base_dir)
        except (ValueError, TypeError) as e:
            raise CaseFileError(
                f"solids[{k}].shape: cannot be written to a case file: {e}", f"solids[{k}].shape"
            ) from None
        d: dict[str, Any] = {
            "name": s.name,
            "law": law,
            "strain": [list(r) for r in s.strain],
            "strain_center": list(s.strain_center),
            "velocity": list(s.velocity),
            "shape": shape,
        }
        if s.anchor is not None:
            a = dict(s.anchor.to_dict())
            for key in a:
                if isinstance(getattr(s.anchor, key, None), Shape):
                    a[key] = _shape_doc(getattr(s.anchor, key), base_dir)
            d["anchor"] = a
        solids.append(d)
    if solids:
        doc["solids"] = solids
    return doc


_COMMENTS = {
    (
        "grid",
    ): "n cells along x (ny follows for square cells), or nx and ny; the domain [ax, bx] x [ay, by]",
    ("time",): "simulated time span and number of output frames",
    (
        "fluid",
    ): "p = lambda_f (rho_f / rho0 - 1); viscous stress eta sym(grad v) + bulk_viscosity div(v) I;"
    " extra_viscosity lap(v)",
    ("numerics",): "lengths in grid spacings h; cfl scales the adaptive time step",
    ("output",): "picture_field: the field drawn in the PNG snapshots (and the movie)",
    ("boundary",): 'each edge: "wall", "slip", "outflow", "periodic", or a list of segments\n'
    "{kind, start, end, velocity, profile, ramp, omega} tiling [0, 1] from the edge's low end",
    ("contact",): "repulsive contact force between solids and against the walls (refmap.contact)",
    ("initial_velocity",): "velocity at t = 0 of fluid and solids: formulas u, v in x and y, or a"
    " file (2, nx, ny);\neach solid's velocity is added inside it",
    ("solids",): "a solid: shape in reference coordinates, material law, initial map\n"
    "xi = strain (x - strain_center) + strain_center, initial velocity, optional anchor",
}


_COMMENTS_3D = {
    **_COMMENTS,
    ("grid",): "dim = 3: a 3D case; n cells along x (ny, nz follow for cubic cells), or nx, ny "
    "and nz;\nthe domain [ax, bx] x [ay, by] x [az, bz]",
    ("boundary",): 'each face: "wall", "slip", "outflow", "periodic", or one segment\n'
    "{kind, velocity = [u, v, w], profile, ramp, omega} covering the whole face;\n"
    "back and front are the z-low and z-high faces",
    ("initial_velocity",): "velocity at t = 0 of fluid and solids: formulas u, v, w in x, y "
    "and z, or a\nfile (3, nx, ny, nz); each solid's velocity is added inside it",
    ("solids",): "a solid: shape in reference coordinates (a 3D type), material law (3D by "
    "itself),\ninitial map xi = strain (x - strain_center) + strain_center (3x3), initial "
    "velocity",
}


def case_to_toml(
    case: Case, base_dir: str | os.PathLike | None = None, header: str | None = None
) -> str:
    """The case file of ``case``; :func:`load_case` of it gives an equal Case.

    ``base_dir``: the folder the file will be written to (mask files are written relative
    to it; absolute paths otherwise).  ``header``: comment lines for the top of the file.
    Raises :class:`CaseFileError` for a case that cannot be written (a law given only by a
    Python energy function, an unregistered shape).
    """
    doc = _case_doc(case, base_dir)
    text = to_toml(doc, _COMMENTS_3D if getattr(case.grid, "ndim", 2) == 3 else _COMMENTS)
    if header:
        text = (
            "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines()) + "\n" + text
        )
    return text


def dump_case(case: Case, path: str | os.PathLike, header: str | None = None) -> Path:
    """Write ``case`` as a case file at ``path``; returns the path."""
    path = Path(path)
    text = case_to_toml(case, base_dir=path.parent, header=header)
    path.write_text(text, encoding="utf-8")
    return path


def _scenarios():
    from refmap import scenarios

    try:  # registers the contact scenarios
        import refmap.scenarios_fssi  # noqa: F401
    except ImportError:  # pragma: no cover
        pass
    return scenarios


def show_scenario(name: str, n: int | None = None) -> str:
    """The built-in scenario ``name`` (at its default resolution, or ``n``) as a case file."""
    sc = _scenarios()
    case = sc.get_case(name, n)  # n None: the scenario's own default (32 in 3D, 128 in 2D)
    desc = sc.DESCRIPTIONS.get(name, "")
    header = (
        f"refmap case file: the built-in scenario {name!r}"
        + (f" -- {desc}" if desc else "")
        + "\nrun it with:  refmap run "
        + f"{name}.toml"
        + "\n"
        "edit any value; every key is described in docs/casefiles.md"
    )
    return case_to_toml(case, header=header)
