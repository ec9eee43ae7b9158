"""Solid shapes as signed-distance level sets in reference coordinates, with CSG.

A solid body is described by a level set ``phi0(X, Y)`` of the *reference* coordinates: the
body occupies ``phi0 < 0``, the fluid ``phi0 > 0``, and ``phi0`` is a signed distance (its
gradient has unit length) at least in a band around the zero contour.  The solver evaluates
``phi0(xi_x, xi_y)`` on whole 2D arrays of reference-map values at every time step, inside
``jax.jit``, so every shape here is written as pure ``jax.numpy`` elementwise code: there is
no Python branching on values, any input shape works (the two inputs are broadcast against
each other), and the result has the broadcast shape.

Shapes are frozen dataclasses whose fields are plain floats, tuples of floats, or other
shapes.  They are therefore hashable and can be passed to ``jax.jit`` as static arguments or
simply captured in a closure::

    rotor = Rotor(center=(0.5, 0.5))
    body = Disc((0.0, 0.0), 0.3) | Rectangle((0.4, 0.0), (0.4, 0.05))
    phi0 = jax.jit(lambda X, Y: body(X, Y))

Calling a shape compiles its evaluation (also outside ``jit``, where it fuses the elementwise
operations into one kernel).  Only the *structure* of a shape is static in that compilation;
its float parameters enter as traced scalars, so shapes differing only in their numbers share
one compiled kernel per array shape, and inside a caller's ``jit`` they fold to constants.

Primitives (``Disc``, ``Ellipse``, ``Rectangle``, ``Capsule``, ``Rotor``) are exact signed
distances (``Ellipse`` up to a converged fixed-count iteration, see its docstring).  They are
combined with

* ``a | b`` -> ``Union(a, b)``        (pointwise ``min``),
* ``a & b`` -> ``Intersection(a, b)`` (pointwise ``max``),
* ``a - b`` -> ``Difference(a, b)``   (pointwise ``max(a, -b)``),

and moved with ``shape.translate(dx, dy)`` / ``shape.rotate(angle, about)``.  Translations and
rotations are isometries, so they keep a signed distance exact.  The min/max CSG operations
keep the zero contour and the signs exact, but the result is only *approximately* a distance
where the two operands' contours meet (e.g. outside a concave junction of a union, or inside
an intersection, the value can under- or over-estimate the true distance).  That is harmless
here because the solver re-distances its level set; only the zero contour and the sign matter.

Every shape serialises to a JSON-able dict with ``to_dict()`` (a ``"type"`` key plus the
parameters, nested for CSG and transforms) and is rebuilt by ``shape_from_dict``.

Three dimensions.  A shape has a dimension ``ndim`` and is called with that many coordinate
arrays: ``Disc(...)(X, Y)``, ``Sphere(...)(X, Y, Z)``; the wrong count is refused with an
error naming the shape and both counts.  The 3D primitives are ``Sphere``, ``Ellipsoid``
(an approximate distance, see its docstring), ``Box``, ``Cylinder``, ``Capsule3D`` and
``Torus``; their ``bbox()`` is ``(xmin, xmax, ymin, ymax, zmin, zmax)`` and ``volume()``
replaces ``area()``.  CSG works unchanged on 3D shapes (both operands must have the same
dimension), ``translate(dx, dy, dz)`` moves them, and ``rotate(angle, about)`` turns a 3D
shape about the axis parallel to z through ``about = (x, y)``.  3D primitives are
registered in ``SHAPES_3D`` (``SHAPES`` keeps the 2D primitives and the
dimension-agnostic CSG and transforms); ``shape_from_dict`` reads both.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import partial
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "SHAPES",
    "SHAPES_3D",
    "Box",
    "Capsule",
    "Capsule3D",
    "Cylinder",
    "Difference",
    "Disc",
    "Ellipse",
    "Ellipsoid",
    "Intersection",
    "Rectangle",
    "Rotate",
    "Rotor",
    "Shape",
    "Sphere",
    "Torus",
    "Translate",
    "Union",
    "register_shape",
    "shape_from_dict",
]

BBox = tuple[float, ...]  # (xmin, xmax, ymin, ymax[, zmin, zmax])

#: registry of serialisable shape classes, keyed by the ``"type"`` string of ``to_dict()``:
#: the 2D primitives and the CSG and transform classes (which work in any dimension)
SHAPES: dict[str, type[Shape]] = {}

#: registry of the serialisable 3D primitives (``ndim = 3``), read by ``shape_from_dict`` too
SHAPES_3D: dict[str, type[Shape]] = {}

_AXES = "XYZ"


# --------------------------------------------------------------------------------------------
# parameter normalisation and checks (run once, on plain Python numbers)


def _float(cls: str, name: str, value: Any) -> float:
    """``value`` as a finite Python float, or a ValueError naming the parameter."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(
            f"{cls}: parameter {name!r} must be a number, got {name}={value!r}"
        ) from None
    if not math.isfinite(out):
        raise ValueError(f"{cls}: parameter {name!r} must be finite, got {name}={value!r}")
    return out


def _vector(cls: str, name: str, value: Any, n: int) -> tuple[float, ...]:
    """``value`` as a tuple of ``n`` finite floats, or a ValueError naming the parameter."""
    what = {2: "a pair", 3: "a triple"}.get(n, f"{n}")
    try:
        items = tuple(value)
    except TypeError:
        raise ValueError(
            f"{cls}: parameter {name!r} must be {what} of numbers, got {name}={value!r}"
        ) from None
    if len(items) != n:
        raise ValueError(
            f"{cls}: parameter {name!r} must be {what} of numbers, got {name}={value!r}"
        )
    return tuple(_float(cls, name, v) for v in items)


def _pair(cls: str, name: str, value: Any) -> tuple[float, float]:
    """``value`` as a tuple of two finite floats, or a ValueError naming the parameter."""
    try:
        items = tuple(value)
    except TypeError:
        raise ValueError(
            f"{cls}: parameter {name!r} must be a pair of numbers, got {name}={value!r}"
        ) from None
    if len(items) != 2:
        raise ValueError(
            f"{cls}: parameter {name!r} must be a pair of numbers, got {name}={value!r}"
        )
    return (_float(cls, name, items[0]), _float(cls, name, items[1]))


def _check_positive(cls: str, name: str, value: float | tuple[float, ...]) -> None:
    values = value if isinstance(value, tuple) else (value,)
    if not all(v > 0 for v in values):
        raise ValueError(f"{cls}: parameter {name!r} must be positive, got {name}={value!r}")


def _check_nonnegative(cls: str, name: str, value: float) -> None:
    if not value >= 0:
        raise ValueError(f"{cls}: parameter {name!r} must be non-negative, got {name}={value!r}")


def _set(obj: Any, name: str, value: Any) -> None:
    object.__setattr__(obj, name, value)


def _as_float_array(v: Any):
    v = jnp.asarray(v)
    if not jnp.issubdtype(v.dtype, jnp.floating):
        v = v.astype(jnp.result_type(float))
    return v


def _to_local(X, Y, center, angle):
    """Coordinates of (X, Y) in a frame centred at ``center`` and rotated by ``angle``.

    The parameters may be Python floats or traced scalars (see ``_evaluate``).
    """
    dx = X - center[0]
    dy = Y - center[1]
    c, s = jnp.cos(angle), jnp.sin(angle)
    return c * dx + s * dy, -s * dx + c * dy


def _norm(u, v, *more):
    """``sqrt(u^2 + v^2 [+ ...])`` whose derivative is finite (zero) where all vanish.

    The plain square root has an infinite derivative at 0 (a node at a disc's centre, every
    node inside a rectangle or on a capsule's axis), and reverse mode multiplies it by a
    zero cotangent: NaN.  The inner ``where`` keeps the square root away from 0 in the
    derivative; the outer one gives exactly ``sqrt(0) = 0`` (forward values unchanged)."""
    r2 = u * u + v * v
    for w in more:
        r2 = r2 + w * w
    pos = r2 > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, r2, 1.0)), 0.0)


def _rotated_extent(hx: float, hy: float, angle: float) -> tuple[float, float]:
    """Half-extents of the axis-aligned box that contains a box (hx, hy) rotated by angle."""
    c, s = abs(math.cos(angle)), abs(math.sin(angle))
    return hx * c + hy * s, hx * s + hy * c


# --------------------------------------------------------------------------------------------
# base class


class Shape:
    """Base class of all shapes: a level set ``phi(X, Y)`` (3D: ``phi(X, Y, Z)``), negative
    inside the solid.

    Subclasses implement ``_sdf(X, Y)`` (elementwise ``jax.numpy`` code on floating arrays of
    a common shape) and ``bbox()``; the base class supplies array conversion and compilation
    in ``__call__``, the CSG operators ``|``, ``&``, ``-``, the ``translate``/``rotate``
    helpers, a sampling estimate of the area, and dict serialisation.  The built-in shapes
    are frozen dataclasses registered with ``register_shape``, which is also the way to add a
    serialisable shape of your own::

        @register_shape
        class Annulus(Shape):
            center: tuple[float, float]
            inner: float
            outer: float

            def _sdf(self, X, Y):
                r = jnp.hypot(X - self.center[0], Y - self.center[1])
                return jnp.maximum(r - self.outer, self.inner - r)

            def bbox(self):
                (cx, cy), R = self.center, self.outer
                return (cx - R, cx + R, cy - R, cy + R)

    ``_sdf`` must only do arithmetic with the float fields (no Python ``if`` on them, no
    ``math`` functions): ``__call__`` passes them in as traced scalars so that shapes that
    differ only in their numbers share one compilation (see ``_evaluate``).

    A 3D shape sets the class attribute ``ndim = 3`` and implements ``_sdf(X, Y, Z)``;
    ``register_shape`` files it in ``SHAPES_3D``.
    """

    #: number of coordinates the shape is a function of (CSG and transforms: their children's)
    ndim: ClassVar[int] = 2

    # ---- evaluation ----------------------------------------------------------------------

    def __call__(self, *coords):
        """Evaluate the level set at points (X, Y) (3D: (X, Y, Z)): arrays (numpy or JAX).

        Pure ``jax.numpy`` code, safe under ``jax.jit``/``vmap``; returns an array of the
        broadcast shape of the inputs.  Integer inputs are promoted to the default float
        dtype.  Raises ValueError unless exactly ``self.ndim`` coordinate arrays are given.
        """
        nd = self.ndim
        if len(coords) != nd:
            names = ", ".join(_AXES[:nd])
            raise ValueError(
                f"{type(self).__name__} is a {nd}D shape: call it with {nd} coordinate "
                f"arrays ({names}), got {len(coords)}"
            )
        coords = tuple(jnp.broadcast_arrays(*(_as_float_array(c) for c in coords)))
        if not dataclasses.is_dataclass(self):  # not flattenable: evaluate directly
            return self._sdf(*coords)
        skeleton, params = _flatten(self)
        return _evaluate(coords, params, skeleton)

    def _sdf(self, *coords):
        """The level set on floating JAX arrays of equal shape; implemented by subclasses."""
        if type(self).__call__ is not Shape.__call__:  # a subclass that overrides __call__
            return self(*coords)
        raise NotImplementedError(f"{type(self).__name__} must implement _sdf(X, Y)")

    def bbox(self) -> BBox:  # pragma: no cover - abstract
        """Axis-aligned box ``(xmin, xmax, ymin, ymax[, zmin, zmax])`` around the inside."""
        raise NotImplementedError(f"{type(self).__name__} must implement bbox()")

    # ---- CSG and transforms --------------------------------------------------------------

    def __or__(self, other: Shape) -> Shape:
        if not isinstance(other, Shape):
            return NotImplemented
        return Union(self, other)

    def __and__(self, other: Shape) -> Shape:
        if not isinstance(other, Shape):
            return NotImplemented
        return Intersection(self, other)

    def __sub__(self, other: Shape) -> Shape:
        if not isinstance(other, Shape):
            return NotImplemented
        return Difference(self, other)

    def translate(self, dx: float, dy: float, dz: float | None = None) -> Shape:
        """This shape moved by (dx, dy) (3D shapes: by (dx, dy, dz))."""
        return Translate(self, (dx, dy) if dz is None else (dx, dy, dz))

    def rotate(self, angle: float, about: tuple[float, float] = (0.0, 0.0)) -> Shape:
        """This shape rotated counter-clockwise by ``angle`` radians about the point ``about``
        (3D shapes: about the axis parallel to z through ``about = (x, y)``)."""
        return Rotate(self, angle, about)

    # ---- diagnostics ---------------------------------------------------------------------

    def area(self, n: int = 400) -> float:
        """Estimate the inside area by sampling ``phi < 0`` at n x n cell centres of ``bbox()``.

        Each cell counts as inside or outside according to its centre.  A misclassified point
        lies within half a cell diagonal (``h/sqrt(2)`` for square cells of side h) of the
        contour, so for a contour of length P the error is at most the area of that tube,
        about ``sqrt(2) * P * h``; in practice the errors largely cancel and the estimate is
        much better.
        """
        n = int(n)
        if n < 1:
            raise ValueError(f"area: parameter 'n' must be positive, got n={n!r}")
        if self.ndim != 2:
            raise ValueError(f"{type(self).__name__} is a {self.ndim}D shape: use volume()")
        xmin, xmax, ymin, ymax = self.bbox()
        wx, wy = xmax - xmin, ymax - ymin
        if not (wx > 0 and wy > 0):
            return 0.0
        hx, hy = wx / n, wy / n
        x = xmin + hx * (np.arange(n) + 0.5)
        y = ymin + hy * (np.arange(n) + 0.5)
        X, Y = np.meshgrid(x, y, indexing="ij")
        inside = np.asarray(self(X, Y)) < 0
        return float(np.count_nonzero(inside)) * hx * hy

    def volume(self, n: int = 100) -> float:
        """Estimate the inside volume of a 3D shape from ``phi < 0`` at n^3 cell centres of
        ``bbox()`` (the 3D analogue of ``area``; error at most the volume of the tube of
        half a cell diagonal around the surface, in practice much less)."""
        n = int(n)
        if n < 1:
            raise ValueError(f"volume: parameter 'n' must be positive, got n={n!r}")
        if self.ndim != 3:
            raise ValueError(f"{type(self).__name__} is a {self.ndim}D shape: use area()")
        b = self.bbox()
        widths = [b[2 * a + 1] - b[2 * a] for a in range(3)]
        if not all(w > 0 for w in widths):
            return 0.0
        hs = [w / n for w in widths]
        axes = [b[2 * a] + hs[a] * (np.arange(n) + 0.5) for a in range(3)]
        X, Y = np.meshgrid(axes[0], axes[1], indexing="ij")
        count = 0
        for z in axes[2]:  # slab by slab: n^2 points at a time
            count += int(np.count_nonzero(np.asarray(self(X, Y, np.full_like(X, z))) < 0))
        return float(count) * hs[0] * hs[1] * hs[2]

    # ---- serialisation -------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict: ``{"type": <name>, <field>: <value>, ...}``, nested for CSG."""
        name = type(self).__name__
        if SHAPES.get(name) is not type(self) and SHAPES_3D.get(name) is not type(self):
            raise TypeError(f"{name} is not registered (decorate it with register_shape)")
        out: dict[str, Any] = {"type": name}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            v = getattr(self, f.name)
            if isinstance(v, Shape):
                out[f.name] = v.to_dict()
            elif isinstance(v, tuple):
                out[f.name] = list(v)
            else:
                out[f.name] = v
        return out


def _is_param(v: Any) -> bool:
    return isinstance(v, float)


def _flatten(shape: Shape) -> tuple[tuple, tuple[float, ...]]:
    """Split a shape tree into a hashable skeleton and its float parameters.

    The skeleton records the classes, field names, nesting and any non-float field values
    (ints, strings: these stay static); the floats (alone or in tuples of floats) are
    returned separately, in a fixed order, so that ``_evaluate`` can trace them.
    """
    params: list[float] = []

    def rec(s: Shape) -> tuple:
        if not dataclasses.is_dataclass(s):
            return ("opaque", s)  # evaluated through its own __call__, static as a whole
        spec = []
        for f in dataclasses.fields(s):
            v = getattr(s, f.name)
            if isinstance(v, Shape):
                spec.append((f.name, "shape", rec(v)))
            elif isinstance(v, tuple) and v and all(_is_param(x) for x in v):
                params.extend(v)
                spec.append((f.name, "tuple", len(v)))
            elif _is_param(v):
                params.append(v)
                spec.append((f.name, "float", None))
            else:
                spec.append((f.name, "static", v))
        return (type(s), tuple(spec))

    skeleton = rec(shape)
    return skeleton, tuple(params)


def _unflatten(skeleton: tuple, params) -> Shape:
    """Inverse of ``_flatten`` for (possibly traced) floats; bypasses ``__init__`` checks."""
    it = iter(params)

    def rec(skel: tuple) -> Shape:
        if skel[0] == "opaque":
            return _Opaque(skel[1])
        cls, spec = skel
        obj = object.__new__(cls)
        for name, kind, sub in spec:
            if kind == "shape":
                v = rec(sub)
            elif kind == "tuple":
                v = tuple(next(it) for _ in range(sub))
            elif kind == "float":
                v = next(it)
            else:
                v = sub
            object.__setattr__(obj, name, v)
        return obj

    return rec(skeleton)


class _Opaque(Shape):
    """Wraps a non-dataclass shape found inside a tree: its ``_sdf`` is its ``__call__``."""

    def __init__(self, shape: Shape) -> None:
        self.shape = shape

    @property
    def ndim(self) -> int:
        return self.shape.ndim

    def _sdf(self, *coords):
        return self.shape(*coords)


@partial(jax.jit, static_argnums=2)
def _evaluate(coords, params, skeleton):
    """Evaluate the shape ``_unflatten(skeleton, params)`` at ``coords = (X, Y[, Z])``.

    Only the skeleton (which classes, nested how) is static: the numeric parameters are
    traced scalars, so shapes that differ only in their numbers (a moved or resized disc)
    share one compilation per array shape.  Outside ``jit`` this turns the many small
    elementwise operations (the ellipse alone has ~200) into one fused kernel; inside a
    caller's ``jit`` the parameters are constants and the call is inlined.
    """
    return _unflatten(skeleton, params)._sdf(*coords)


def register_shape(cls: type) -> type:
    """Class decorator: make ``cls`` a frozen dataclass and add it to ``SHAPES``.

    The class name is the ``"type"`` key of its ``to_dict()`` output.  Classes with the
    class attribute ``ndim = 3`` go to ``SHAPES_3D``, the others to ``SHAPES``.
    """
    cls = dataclass(frozen=True)(cls)
    nd = getattr(cls, "ndim", 2)  # a property (CSG, transforms) is not an int
    registry = SHAPES_3D if isinstance(nd, int) and nd == 3 else SHAPES
    registry[cls.__name__] = cls
    return cls


def shape_from_dict(d: Mapping[str, Any]) -> Shape:
    """Rebuild a shape from the output of ``Shape.to_dict()`` (nested dicts for CSG).

    Parameters left out take the class defaults.  Raises ValueError for a missing or unknown
    ``"type"``, an unknown parameter key, a missing required parameter, or a bad value.
    """
    if not isinstance(d, Mapping):
        raise ValueError(f"shape_from_dict: expected a dict, got {type(d).__name__}: {d!r}")
    if "type" not in d:
        raise ValueError(f"shape_from_dict: missing 'type' key in {dict(d)!r}")
    name = d["type"]
    known = {**SHAPES, **SHAPES_3D}
    cls = known.get(name) if isinstance(name, str) else None
    if cls is None:
        raise ValueError(
            f"shape_from_dict: unknown shape type {name!r}; known types: {sorted(known)}"
        )
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in d.items():
        if key == "type":
            continue
        if key not in fields:
            raise ValueError(
                f"shape_from_dict: unknown key {key!r} for shape type {name!r}; "
                f"valid keys: {sorted(fields)}"
            )
        if isinstance(value, Mapping):
            value = shape_from_dict(value)
        elif isinstance(value, list):  # JSON arrays back to (hashable) tuples
            value = tuple(value)
        kwargs[key] = value
    missing = [
        k
        for k, f in fields.items()
        if k not in kwargs
        and f.default is dataclasses.MISSING
        and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise ValueError(f"shape_from_dict: shape type {name!r} is missing key(s) {missing}")
    try:
        return cls(**kwargs)
    except TypeError as err:
        raise ValueError(f"shape_from_dict: bad parameters for {name!r}: {err}") from None


# --------------------------------------------------------------------------------------------
# primitives


@register_shape
class Disc(Shape):
    """Disc of radius ``radius`` centred at ``center``; exact signed distance ``|p - c| - r``."""

    center: tuple[float, float] = (0.0, 0.0)
    radius: float = 1.0

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _set(self, "center", _pair(cls, "center", self.center))
        _set(self, "radius", _float(cls, "radius", self.radius))
        _check_positive(cls, "radius", self.radius)

    def _sdf(self, X, Y):
        return _norm(X - self.center[0], Y - self.center[1]) - self.radius

    def bbox(self) -> BBox:
        (cx, cy), r = self.center, self.radius
        return (cx - r, cx + r, cy - r, cy + r)


@register_shape
class Ellipse(Shape):
    """Ellipse with semi-axes ``(a, b)``, the first along the direction ``angle`` (radians).

    The value is ``sign(k) * |p - q|`` where ``k = (x/a)^2 + (y/b)^2 - 1`` in the ellipse's own
    frame (so the zero contour and the sign are exact) and ``q`` is the closest point of the
    ellipse, found by a fixed number (``iterations = 8``) of the curvature-circle iteration of
    C. Chatfield ("0xfaded", 2017): in the first quadrant, the current guess on the ellipse is
    replaced by the point where the ray from the local centre of curvature towards ``p`` meets
    the osculating circle, re-projected onto the ellipse.  It converges for every point (also
    inside, near the medial axis) without branching; 8 iterations reach round-off for aspect
    ratios up to about 20 (errors of order 1e-9 remain at aspect 50).  The result is then an exact
    signed distance for practical purposes (|grad| = 1 away from the medial axis segment
    inside the ellipse).
    """

    center: tuple[float, float]
    semi_axes: tuple[float, float]
    angle: float = 0.0

    iterations: ClassVar[int] = 8

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _set(self, "center", _pair(cls, "center", self.center))
        _set(self, "semi_axes", _pair(cls, "semi_axes", self.semi_axes))
        _set(self, "angle", _float(cls, "angle", self.angle))
        _check_positive(cls, "semi_axes", self.semi_axes)

    def _sdf(self, X, Y):
        a, b = self.semi_axes
        x, y = _to_local(X, Y, self.center, self.angle)
        px, py = jnp.abs(x), jnp.abs(y)
        tiny = 1e-300
        tx = jnp.full_like(px, math.sqrt(0.5))
        ty = tx
        for _ in range(self.iterations):
            ex = (a * a - b * b) * tx**3 / a  # centre of curvature at (a tx, b ty)
            ey = (b * b - a * a) * ty**3 / b
            r = _norm(a * tx - ex, b * ty - ey)  # radius of curvature
            qx, qy = px - ex, py - ey
            q = jnp.maximum(_norm(qx, qy), tiny)
            ux = jnp.clip((qx * r / q + ex) / a, 0.0, 1.0)
            uy = jnp.clip((qy * r / q + ey) / b, 0.0, 1.0)
            t = _norm(ux, uy)
            ok = t > tiny  # only a disc's centre gives t = 0; keep the old guess there
            t = jnp.where(ok, t, 1.0)
            tx = jnp.where(ok, ux / t, tx)
            ty = jnp.where(ok, uy / t, ty)
        dist = _norm(px - a * tx, py - b * ty)
        k = (x / a) ** 2 + (y / b) ** 2 - 1.0
        return jnp.where(k < 0, -dist, dist)

    def bbox(self) -> BBox:
        a, b = self.semi_axes
        c, s = math.cos(self.angle), math.sin(self.angle)
        ex, ey = math.hypot(a * c, b * s), math.hypot(a * s, b * c)
        cx, cy = self.center
        return (cx - ex, cx + ex, cy - ey, cy + ey)


@register_shape
class Rectangle(Shape):
    """Rectangle with half-sizes ``(hx, hy)`` along its own axes, rotated by ``angle``.

    With ``corner_radius = r > 0`` the corners are rounded with radius r while the outer
    half-sizes stay ``(hx, hy)`` (``r <= min(hx, hy)``).  Exact signed distance:
    ``|max(q, 0)| + min(max(qx, qy), 0) - r`` with ``q = |p_local| - (h - r)``.
    """

    center: tuple[float, float]
    half_size: tuple[float, float]
    angle: float = 0.0
    corner_radius: float = 0.0

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _set(self, "center", _pair(cls, "center", self.center))
        _set(self, "half_size", _pair(cls, "half_size", self.half_size))
        _set(self, "angle", _float(cls, "angle", self.angle))
        _set(self, "corner_radius", _float(cls, "corner_radius", self.corner_radius))
        _check_positive(cls, "half_size", self.half_size)
        _check_nonnegative(cls, "corner_radius", self.corner_radius)
        if self.corner_radius > min(self.half_size):
            raise ValueError(
                f"{cls}: parameter 'corner_radius' must not exceed min(half_size)="
                f"{min(self.half_size)!r}, got corner_radius={self.corner_radius!r}"
            )

    def _sdf(self, X, Y):
        r = self.corner_radius
        x, y = _to_local(X, Y, self.center, self.angle)
        qx = jnp.abs(x) - (self.half_size[0] - r)
        qy = jnp.abs(y) - (self.half_size[1] - r)
        outside = _norm(jnp.maximum(qx, 0.0), jnp.maximum(qy, 0.0))
        inside = jnp.minimum(jnp.maximum(qx, qy), 0.0)
        return outside + inside - r

    def bbox(self) -> BBox:
        ex, ey = _rotated_extent(*self.half_size, self.angle)
        cx, cy = self.center
        return (cx - ex, cx + ex, cy - ey, cy + ey)


@register_shape
class Capsule(Shape):
    """Segment of half-length ``half_length`` through ``center`` along ``angle``, thickened.

    ``angle = 0`` lays the segment along x, ``angle = pi/2`` along y; every point within
    ``radius`` of the segment is inside.  ``half_length = 0`` gives a disc.  Exact signed
    distance ``dist(p, segment) - radius``.  Area ``4 L r + pi r^2``.
    """

    center: tuple[float, float]
    half_length: float
    radius: float
    angle: float = 0.0

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _set(self, "center", _pair(cls, "center", self.center))
        _set(self, "half_length", _float(cls, "half_length", self.half_length))
        _set(self, "radius", _float(cls, "radius", self.radius))
        _set(self, "angle", _float(cls, "angle", self.angle))
        _check_nonnegative(cls, "half_length", self.half_length)
        _check_positive(cls, "radius", self.radius)

    def _sdf(self, X, Y):
        u, v = _to_local(X, Y, self.center, self.angle)
        u = jnp.maximum(jnp.abs(u) - self.half_length, 0.0)
        return _norm(u, v) - self.radius

    def bbox(self) -> BBox:
        L, r = self.half_length, self.radius
        ex = L * abs(math.cos(self.angle)) + r
        ey = L * abs(math.sin(self.angle)) + r
        cx, cy = self.center
        return (cx - ex, cx + ex, cy - ey, cy + ey)


@register_shape
class Rotor(Shape):
    """Four-armed rotor (a plus sign with filleted inner corners and rounded arm ends).

    The shape of Valkov's thesis.  With ``xx = |X - cx|``, ``yy = |Y - cy|``,
    ``L = arm_half_length``, ``w = half_width``, ``b = fillet_center``::

        if xx < b and yy < b:  phi = (b - w) - sqrt((xx - b)^2 + (yy - b)^2)  # inner fillet
        else:
            (xx, yy) = (max, min) of (xx, yy)
            phi = yy - w                    if xx < L                          # arm side
            phi = sqrt((xx - L)^2 + yy^2) - w   otherwise                        # arm end

    evaluated branch-free with ``jnp.where``.  The arms are 2w wide and reach ``L + w`` from
    the centre; the fillets have radius ``b - w`` (so ``w < b < L`` is required).  Each piece
    is a distance to a line or a circle and the pieces join with continuous gradients on the
    contour, so the function is a signed distance near the zero contour.
    """

    center: tuple[float, float] = (0.0, 0.0)
    arm_half_length: float = 1.1
    half_width: float = 0.4
    fillet_center: float = 0.8

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _set(self, "center", _pair(cls, "center", self.center))
        for name in ("arm_half_length", "half_width", "fillet_center"):
            _set(self, name, _float(cls, name, getattr(self, name)))
            _check_positive(cls, name, getattr(self, name))
        L, w, b = self.arm_half_length, self.half_width, self.fillet_center
        if not w < b:
            raise ValueError(
                f"{cls}: parameter 'fillet_center' must exceed half_width={w!r} "
                f"(fillet radius fillet_center - half_width > 0), got fillet_center={b!r}"
            )
        if not b < L:
            raise ValueError(
                f"{cls}: parameter 'fillet_center' must be less than arm_half_length={L!r}, "
                f"got fillet_center={b!r}"
            )

    def _sdf(self, X, Y):
        L, w, b = self.arm_half_length, self.half_width, self.fillet_center
        xx = jnp.abs(X - self.center[0])
        yy = jnp.abs(Y - self.center[1])
        fillet = (b - w) - _norm(xx - b, yy - b)
        hi = jnp.maximum(xx, yy)
        lo = jnp.minimum(xx, yy)
        arm = jnp.where(hi < L, lo - w, _norm(hi - L, lo) - w)
        return jnp.where((xx < b) & (yy < b), fillet, arm)

    def bbox(self) -> BBox:
        e = self.arm_half_length + self.half_width
        cx, cy = self.center
        return (cx - e, cx + e, cy - e, cy + e)


# --------------------------------------------------------------------------------------------
# 3D primitives


def _unit(d):
    """``d / |d|`` for a triple of (possibly traced) floats."""
    n = jnp.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    return d[0] / n, d[1] / n, d[2] / n


def _axial_radial(X, Y, Z, center, direction):
    """Axial coordinate ``a = w . d`` and the components of ``w x d`` (norm: the distance
    to the axis) of ``w = p - center`` for the unit vector ``d`` along ``direction``."""
    d = _unit(direction)
    wx, wy, wz = X - center[0], Y - center[1], Z - center[2]
    a = wx * d[0] + wy * d[1] + wz * d[2]
    cross = (wy * d[2] - wz * d[1], wz * d[0] - wx * d[2], wx * d[1] - wy * d[0])
    return a, cross


def _direction(cls: str, value: Any) -> tuple[float, float, float]:
    d = _vector(cls, "direction", value, 3)
    if not math.hypot(*d) > 0:
        raise ValueError(f"{cls}: parameter 'direction' must be non-zero, got direction={value!r}")
    return d


def _axis_extent(direction, half_length: float, radius: float, rounded: bool):
    """Half-extents along x, y, z of a segment of half-length L along ``direction``
    thickened by ``radius``: spherically (capsule) or as a disc normal to it (cylinder)."""
    n = math.hypot(*direction)
    out = []
    for di in direction:
        c = abs(di) / n
        out.append(
            half_length * c + (radius if rounded else radius * math.sqrt(max(0.0, 1 - c * c)))
        )
    return out


@register_shape
class Sphere(Shape):
    """Ball of radius ``radius`` centred at ``center``; exact signed distance ``|p - c| - r``.

    Volume ``4/3 pi r^3``.
    """

    ndim: ClassVar[int] = 3

    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 1.0

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _set(self, "center", _vector(cls, "center", self.center, 3))
        _set(self, "radius", _float(cls, "radius", self.radius))
        _check_positive(cls, "radius", self.radius)

    def _sdf(self, X, Y, Z):
        c = self.center
        return _norm(X - c[0], Y - c[1], Z - c[2]) - self.radius

    def bbox(self) -> BBox:
        (cx, cy, cz), r = self.center, self.radius
        return (cx - r, cx + r, cy - r, cy + r, cz - r, cz + r)


@register_shape
class Ellipsoid(Shape):
    """Ellipsoid with semi-axes ``(a, b, c)`` along its own axes, turned by ``angle`` about z.

    An approximate signed distance (I. Quilez's "bound" form): with ``q`` the local
    coordinates, ``k0 = |q / r|`` and ``k1 = |q / r^2|`` (componentwise by the semi-axes r),

        phi = k0 (k0 - 1) / k1.

    Its zero set and its sign are exact (``k0 = 1`` on the surface), and on the surface
    ``grad phi = grad k0 / k1`` is exactly the unit normal, so phi agrees with the true
    signed distance to first order: the error is O(d^2) at true distance d (tested: below
    ``d^2 / min(r)`` for ``|d| <= 0.1 min(r)`` and aspect ratios up to 3; measured 0.2 and
    0.45 times that), which is what the solver needs (it re-distances its level set).  It is exact for a sphere
    (equal semi-axes).  Far from the surface it is only a rough distance; at the centre it
    is ``-min(r)``.  An exact distance would need a root solve per point (Eberly 2013).
    """

    ndim: ClassVar[int] = 3

    center: tuple[float, float, float]
    semi_axes: tuple[float, float, float]
    angle: float = 0.0

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _set(self, "center", _vector(cls, "center", self.center, 3))
        _set(self, "semi_axes", _vector(cls, "semi_axes", self.semi_axes, 3))
        _set(self, "angle", _float(cls, "angle", self.angle))
        _check_positive(cls, "semi_axes", self.semi_axes)

    def _sdf(self, X, Y, Z):
        a, b, c = self.semi_axes
        x, y = _to_local(X, Y, self.center[:2], self.angle)
        z = Z - self.center[2]
        k0 = _norm(x / a, y / b, z / c)
        k1 = _norm(x / (a * a), y / (b * b), z / (c * c))
        pos = k1 > 0
        centre = -jnp.minimum(jnp.minimum(a, b), c)  # the limit value at q = 0
        return jnp.where(pos, k0 * (k0 - 1.0) / jnp.where(pos, k1, 1.0), centre)

    def bbox(self) -> BBox:
        a, b, c = self.semi_axes
        co, si = math.cos(self.angle), math.sin(self.angle)
        ex, ey = math.hypot(a * co, b * si), math.hypot(a * si, b * co)
        cx, cy, cz = self.center
        return (cx - ex, cx + ex, cy - ey, cy + ey, cz - c, cz + c)


@register_shape
class Box(Shape):
    """Box with half-sizes ``(hx, hy, hz)`` along its own axes, turned by ``angle`` about z.

    With ``corner_radius = r > 0`` the edges and corners are rounded with radius r while
    the outer half-sizes stay ``h`` (``r <= min(h)``).  Exact signed distance:
    ``|max(q, 0)| + min(max(qx, qy, qz), 0) - r`` with ``q = |p_local| - (h - r)``.
    Volume ``8 hx hy hz`` (sharp).
    """

    ndim: ClassVar[int] = 3

    center: tuple[float, float, float]
    half_size: tuple[float, float, float]
    angle: float = 0.0
    corner_radius: float = 0.0

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _set(self, "center", _vector(cls, "center", self.center, 3))
        _set(self, "half_size", _vector(cls, "half_size", self.half_size, 3))
        _set(self, "angle", _float(cls, "angle", self.angle))
        _set(self, "corner_radius", _float(cls, "corner_radius", self.corner_radius))
        _check_positive(cls, "half_size", self.half_size)
        _check_nonnegative(cls, "corner_radius", self.corner_radius)
        if self.corner_radius > min(self.half_size):
            raise ValueError(
                f"{cls}: parameter 'corner_radius' must not exceed min(half_size)="
                f"{min(self.half_size)!r}, got corner_radius={self.corner_radius!r}"
            )

    def _sdf(self, X, Y, Z):
        r = self.corner_radius
        x, y = _to_local(X, Y, self.center[:2], self.angle)
        z = Z - self.center[2]
        q = [jnp.abs(v) - (h - r) for v, h in zip((x, y, z), self.half_size, strict=True)]
        outside = _norm(*(jnp.maximum(v, 0.0) for v in q))
        inside = jnp.minimum(jnp.maximum(jnp.maximum(q[0], q[1]), q[2]), 0.0)
        return outside + inside - r

    def bbox(self) -> BBox:
        hx, hy, hz = self.half_size
        ex, ey = _rotated_extent(hx, hy, self.angle)
        cx, cy, cz = self.center
        return (cx - ex, cx + ex, cy - ey, cy + ey, cz - hz, cz + hz)


@register_shape
class Cylinder(Shape):
    """Solid circular cylinder with flat caps: radius ``radius``, axis through ``center``
    along ``direction`` (any non-zero vector, default z), reaching ``half_length`` either
    side of the centre.  Exact signed distance: with ``rho`` the distance to the axis and
    ``a`` the axial coordinate, ``q = (rho - r, |a| - L)``,
    ``phi = |max(q, 0)| + min(max(q), 0)``.  Volume ``2 pi r^2 L``.
    """

    ndim: ClassVar[int] = 3

    center: tuple[float, float, float]
    radius: float
    half_length: float
    direction: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _set(self, "center", _vector(cls, "center", self.center, 3))
        _set(self, "radius", _float(cls, "radius", self.radius))
        _set(self, "half_length", _float(cls, "half_length", self.half_length))
        _set(self, "direction", _direction(cls, self.direction))
        _check_positive(cls, "radius", self.radius)
        _check_positive(cls, "half_length", self.half_length)

    def _sdf(self, X, Y, Z):
        a, cross = _axial_radial(X, Y, Z, self.center, self.direction)
        q0 = _norm(*cross) - self.radius
        q1 = jnp.abs(a) - self.half_length
        outside = _norm(jnp.maximum(q0, 0.0), jnp.maximum(q1, 0.0))
        return outside + jnp.minimum(jnp.maximum(q0, q1), 0.0)

    def bbox(self) -> BBox:
        e = _axis_extent(self.direction, self.half_length, self.radius, rounded=False)
        return tuple(v for c, h in zip(self.center, e, strict=True) for v in (c - h, c + h))


@register_shape
class Capsule3D(Shape):
    """Segment of half-length ``half_length`` through ``center`` along ``direction``
    (default x, like ``Capsule`` at angle 0), thickened by ``radius``: a cylinder with
    hemispherical caps.  ``half_length = 0`` gives a sphere.  Exact signed distance
    ``dist(p, segment) - radius``.  Volume ``2 pi r^2 L + 4/3 pi r^3``.
    """

    ndim: ClassVar[int] = 3

    center: tuple[float, float, float]
    half_length: float
    radius: float
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _set(self, "center", _vector(cls, "center", self.center, 3))
        _set(self, "half_length", _float(cls, "half_length", self.half_length))
        _set(self, "radius", _float(cls, "radius", self.radius))
        _set(self, "direction", _direction(cls, self.direction))
        _check_nonnegative(cls, "half_length", self.half_length)
        _check_positive(cls, "radius", self.radius)

    def _sdf(self, X, Y, Z):
        a, cross = _axial_radial(X, Y, Z, self.center, self.direction)
        beyond = jnp.maximum(jnp.abs(a) - self.half_length, 0.0)
        return _norm(*cross, beyond) - self.radius

    def bbox(self) -> BBox:
        e = _axis_extent(self.direction, self.half_length, self.radius, rounded=True)
        return tuple(v for c, h in zip(self.center, e, strict=True) for v in (c - h, c + h))


@register_shape
class Torus(Shape):
    """Ring torus about the axis parallel to z through ``center``: the tube of radius
    ``minor_radius`` around the circle of radius ``major_radius`` in the plane z = cz
    (``0 < minor_radius < major_radius``).  Exact signed distance
    ``|(sqrt(x^2 + y^2) - R, z)| - r``.  Volume ``2 pi^2 R r^2``.
    """

    ndim: ClassVar[int] = 3

    center: tuple[float, float, float]
    major_radius: float
    minor_radius: float

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _set(self, "center", _vector(cls, "center", self.center, 3))
        _set(self, "major_radius", _float(cls, "major_radius", self.major_radius))
        _set(self, "minor_radius", _float(cls, "minor_radius", self.minor_radius))
        _check_positive(cls, "minor_radius", self.minor_radius)
        if not self.major_radius > self.minor_radius:
            raise ValueError(
                f"{cls}: parameter 'major_radius' must exceed minor_radius="
                f"{self.minor_radius!r}, got major_radius={self.major_radius!r}"
            )

    def _sdf(self, X, Y, Z):
        c = self.center
        rho = _norm(X - c[0], Y - c[1])
        return _norm(rho - self.major_radius, Z - c[2]) - self.minor_radius

    def bbox(self) -> BBox:
        (cx, cy, cz), R, r = self.center, self.major_radius, self.minor_radius
        e = R + r
        return (cx - e, cx + e, cy - e, cy + e, cz - r, cz + r)


# --------------------------------------------------------------------------------------------
# CSG and rigid transforms


def _check_child(cls: str, name: str, value: Any) -> None:
    if not isinstance(value, Shape):
        raise TypeError(f"{cls}: {name!r} must be a Shape, got {type(value).__name__}")


def _check_same_ndim(cls: str, a: Shape, b: Shape) -> None:
    if a.ndim != b.ndim:
        raise ValueError(
            f"{cls}: cannot combine a {a.ndim}D shape ({type(a).__name__}) with a "
            f"{b.ndim}D shape ({type(b).__name__})"
        )


def _bbox_hull(a: BBox, b: BBox) -> BBox:
    out = []
    for k in range(0, len(a), 2):
        out += [min(a[k], b[k]), max(a[k + 1], b[k + 1])]
    return tuple(out)


def _bbox_overlap(a: BBox, b: BBox) -> BBox:
    """Overlap of two boxes; a zero-size box along an axis where they do not overlap."""
    out = []
    for k in range(0, len(a), 2):
        lo, hi = max(a[k], b[k]), min(a[k + 1], b[k + 1])
        if hi < lo:
            lo = hi = 0.5 * (lo + hi)
        out += [lo, hi]
    return tuple(out)


class _Binary(Shape):
    """Common parts of the CSG operations: two children of one dimension."""

    @property
    def ndim(self) -> int:
        return self.a.ndim

    def __post_init__(self) -> None:
        cls = type(self).__name__
        _check_child(cls, "a", self.a)
        _check_child(cls, "b", self.b)
        _check_same_ndim(cls, self.a, self.b)


@register_shape
class Union(_Binary):
    """Inside either ``a`` or ``b``: ``min(a, b)`` (a distance only away from junctions)."""

    a: Shape
    b: Shape

    def _sdf(self, *c):
        return jnp.minimum(self.a._sdf(*c), self.b._sdf(*c))

    def bbox(self) -> BBox:
        return _bbox_hull(self.a.bbox(), self.b.bbox())


@register_shape
class Intersection(_Binary):
    """Inside both ``a`` and ``b``: ``max(a, b)`` (a distance only away from junctions)."""

    a: Shape
    b: Shape

    def _sdf(self, *c):
        return jnp.maximum(self.a._sdf(*c), self.b._sdf(*c))

    def bbox(self) -> BBox:
        """Overlap of the two boxes; a zero-size box when they do not overlap."""
        return _bbox_overlap(self.a.bbox(), self.b.bbox())


@register_shape
class Difference(_Binary):
    """Inside ``a`` but not inside ``b``: ``max(a, -b)`` (a distance only away from junctions)."""

    a: Shape
    b: Shape

    def _sdf(self, *c):
        return jnp.maximum(self.a._sdf(*c), -self.b._sdf(*c))

    def bbox(self) -> BBox:
        return self.a.bbox()


@register_shape
class Translate(Shape):
    """``shape`` moved by ``offset = (dx, dy)``: evaluates ``shape(X - dx, Y - dy)``.

    For a 3D shape the offset is ``(dx, dy, dz)``.
    """

    shape: Shape
    offset: tuple[float, float]  # three numbers for a 3D shape

    @property
    def ndim(self) -> int:
        return self.shape.ndim

    def __post_init__(self) -> None:
        _check_child("Translate", "shape", self.shape)
        _set(self, "offset", _vector("Translate", "offset", self.offset, self.shape.ndim))

    def _sdf(self, *c):
        return self.shape._sdf(*(x - o for x, o in zip(c, self.offset, strict=True)))

    def bbox(self) -> BBox:
        b = self.shape.bbox()
        return tuple(v + self.offset[k // 2] for k, v in enumerate(b))


@register_shape
class Rotate(Shape):
    """``shape`` rotated counter-clockwise by ``angle`` radians about the point ``about``.

    Evaluates the child at the inversely rotated point ``R(-angle) (p - about) + about``.
    A 3D shape turns about the axis parallel to z through ``about = (x, y)``; Z passes
    through unchanged.
    """

    shape: Shape
    angle: float
    about: tuple[float, float] = (0.0, 0.0)

    @property
    def ndim(self) -> int:
        return self.shape.ndim

    def __post_init__(self) -> None:
        _check_child("Rotate", "shape", self.shape)
        _set(self, "angle", _float("Rotate", "angle", self.angle))
        _set(self, "about", _pair("Rotate", "about", self.about))

    def _sdf(self, X, Y, *rest):
        u, v = _to_local(X, Y, self.about, self.angle)
        return self.shape._sdf(u + self.about[0], v + self.about[1], *rest)

    def bbox(self) -> BBox:
        """Box around the rotated corners of the child's box (conservative)."""
        x0, x1, y0, y1, *rest = self.shape.bbox()
        ox, oy = self.about
        c, s = math.cos(self.angle), math.sin(self.angle)
        xs, ys = [], []
        for x in (x0, x1):
            for y in (y0, y1):
                xs.append(ox + c * (x - ox) - s * (y - oy))
                ys.append(oy + s * (x - ox) + c * (y - oy))
        return (min(xs), max(xs), min(ys), max(ys), *rest)
