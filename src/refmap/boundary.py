"""Domain-edge conditions, imposed through ghost nodes, in two or three dimensions.

Each of the four edges (2D; six faces in 3D, see below) is either ``"periodic"`` (then its opposite edge must be too) or a
tuple of :class:`Segment` s covering parts of it.  A segment is one of

* ``wall``     -- no-slip wall moving with ``velocity`` (zero by default); the ghost velocity
  is the odd reflection ``2 U - v`` so the wall sits on the cell face;
* ``slip``     -- impermeable free-slip wall: normal velocity reflected oddly, tangential
  velocity evenly;
* ``velocity`` -- a given velocity on the face (inflow, or a prescribed outflow as in the
  thesis's rotor and stick); optional ``profile="parabolic"`` across the segment, a
  time ``ramp`` ((1 - cos(pi t / ramp)) / 2 for t < ramp) and an ``omega`` for
  ``U sin(omega t)`` forcing;
* ``outflow``  -- zero-gradient velocity, linearly extrapolated density.

Fluid density ghosts: even reflection at walls, the reference density ``rho_f0`` at
inflowing ``velocity`` segments (the thesis's choice), linear extrapolation at outflows.
Reference maps and level sets are extended linearly (exact for affine maps), or wrapped
on periodic edges; see :meth:`BoundaryConditions.pad_affine`.  A solid that touches a
resting wall (or a slip wall) at t = 0 is glued to it instead: its map's ghosts reflect
about the wall face's initial value (:meth:`BoundaryConditions.glue`).

Ghost value k (k = 1 next to the edge, k = 2 beyond) is
``alpha_k f_(k-1) + beta_k f_0 + gamma_k f_1 + delta_k(t)`` with f_m the m-th node in from
the edge; the coefficients are numpy arrays built once per case, so padding is a handful
of fused multiply-adds inside the jitted step.

Three dimensions.  A :class:`Boundary` with ``back`` and ``front`` faces (z-low and
z-high) is a 3D boundary (``Boundary.ndim == 3``); without them it is the 2D one, whose
fields, dictionaries and behaviour are unchanged.  In 3D every face takes whole-face
conditions only (a segment must span ``[0, 1]``: a fraction along one tangential axis
would not say which), velocities have three components ``(u, v, w)`` (a 2-component
velocity on a 3D face is an error naming the face; edges given as words, ``"wall"`` etc.,
get a zero 3-vector), and ``profile="parabolic"`` is the product of the parabolas across
the face's two tangential axes (1 at the face centre, 0 on its rim).
:class:`BoundaryConditions` then pads ``(..., nx, ny, nz)`` arrays with the same rules per
axis, one axis after the other (x, then y, then z), so the ghost edges and corners of the
padded array are filled exactly as the 2D code fills its corners: the later axis's rule
applied to the earlier axis's ghosts, with the coefficients of the nearest face node.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import jax.numpy as jnp
import numpy as np

from refmap.grid import Grid, Grid3D

SegmentKind = Literal["wall", "slip", "velocity", "outflow"]
EDGES = ("left", "right", "bottom", "top")
#: the six faces of a 3D boundary: the four edges of 2D, then z-low (back) and z-high (front)
FACES = EDGES + ("back", "front")
#: (low, high) face of each axis
AXIS_FACES = (("left", "right"), ("bottom", "top"), ("back", "front"))
#: names of the velocity components, per axis
COMPONENTS = ("u", "v", "w")
_KINDS = ("wall", "slip", "velocity", "outflow")


@dataclass(frozen=True)
class Segment:
    """A stretch ``[start, end)`` of an edge (fractions of its length, from its low end)."""

    kind: SegmentKind = "wall"
    start: float = 0.0
    end: float = 1.0
    velocity: tuple[float, ...] = (0.0, 0.0)  # (u, v); (u, v, w) on a 3D face
    profile: Literal["uniform", "parabolic"] = "uniform"
    ramp: float = 0.0
    omega: float | None = None

    def __post_init__(self):
        if self.kind not in _KINDS:
            raise ValueError(f"boundary segment kind {self.kind!r} is unknown; use one of {_KINDS}")
        if not (0.0 <= self.start < self.end <= 1.0):
            raise ValueError(
                f"boundary segment needs 0 <= start < end <= 1, got start={self.start!r}, end={self.end!r}"
            )
        if self.profile not in ("uniform", "parabolic"):
            raise ValueError(f"boundary segment profile {self.profile!r} is unknown")
        if self.ramp < 0:
            raise ValueError(f"boundary segment ramp must be >= 0, got {self.ramp!r}")
        object.__setattr__(self, "velocity", tuple(float(c) for c in self.velocity))

    def to_dict(self):
        return {
            "kind": self.kind,
            "start": self.start,
            "end": self.end,
            "velocity": list(self.velocity),
            "profile": self.profile,
            "ramp": self.ramp,
            "omega": self.omega,
        }


Edge = tuple[Segment, ...] | Literal["periodic"]


def _as_edge(e, ndim: int = 2) -> Edge:
    if isinstance(e, str):
        if e == "periodic":
            return "periodic"
        if ndim == 2:
            return (Segment(kind=e),)
        return (Segment(kind=e, velocity=(0.0,) * ndim),)
    if isinstance(e, Segment):
        return (e,)
    return tuple(e)


@dataclass(frozen=True)
class Boundary:
    """Conditions on the four edges (default: no-slip walls all round).

    Give ``back`` and ``front`` (the z-low and z-high faces) for a 3D boundary:
    ``Boundary(back="wall", front="wall")`` is a closed box.  The 2D boundary leaves them
    ``None`` and never shows them (``to_dict`` writes the four edges only).
    """

    left: Edge | str = "wall"  # a word ("wall", "slip", "outflow", "periodic") or segments
    right: Edge | str = "wall"
    bottom: Edge | str = "wall"
    top: Edge | str = "wall"
    back: Edge | str | None = None
    front: Edge | str | None = None

    def __post_init__(self):
        if (self.back is None) != (self.front is None):
            raise ValueError(
                "a 3D boundary needs both z faces: give back (z-low) and front (z-high), "
                f"got back={self.back!r}, front={self.front!r}"
            )
        ndim = self.ndim
        for name in self.faces:
            object.__setattr__(self, name, _as_edge(getattr(self, name), ndim))
        for a, b in AXIS_FACES[:ndim]:
            pa, pb = getattr(self, a) == "periodic", getattr(self, b) == "periodic"
            if pa != pb:
                raise ValueError(f"periodic edges come in pairs: {a} is {getattr(self, a)!r} but {b} is not")
        for name in self.faces:
            e = getattr(self, name)
            if e == "periodic":
                continue
            if len(e) == 0:
                raise ValueError(f"boundary edge {name!r} has no segments")
            if ndim == 3:
                for seg in e:
                    if len(seg.velocity) != 3:
                        raise ValueError(
                            f"face {name!r} of a 3D boundary: segment velocity {seg.velocity!r} "
                            f"has {len(seg.velocity)} components; give 3 (u, v, w)"
                        )
                    if seg.start != 0.0 or seg.end != 1.0:
                        raise ValueError(
                            f"face {name!r} of a 3D boundary: segments must cover the whole "
                            f"face (start=0, end=1), got start={seg.start!r}, end={seg.end!r}; "
                            "partial faces are not supported in 3D yet"
                        )
            elif any(len(seg.velocity) != 2 for seg in e):
                raise ValueError(
                    f"edge {name!r} of a 2D boundary: segment velocities have 2 components "
                    f"(u, v), got {[seg.velocity for seg in e]}"
                )
            cover = sorted((s.start, s.end) for s in e)
            pos = 0.0
            for s0, s1 in cover:
                if abs(s0 - pos) > 1e-12:
                    raise ValueError(f"segments of edge {name!r} must tile [0, 1] without gaps or overlaps; got {cover}")
                pos = s1
            if abs(pos - 1.0) > 1e-12:
                raise ValueError(f"segments of edge {name!r} must reach 1.0; got {cover}")

    @property
    def ndim(self) -> int:
        """2, or 3 when the z faces (back, front) are given."""
        return 2 if self.back is None else 3

    @property
    def faces(self) -> tuple[str, ...]:
        """The edge names (2D) or face names (3D), low before high, axis by axis."""
        return EDGES if self.back is None else FACES

    @property
    def periodic(self) -> tuple[bool, ...]:
        """Per axis: whether it wraps ((x, y) in 2D, (x, y, z) in 3D)."""
        return tuple(getattr(self, lo) == "periodic" for lo, _ in AXIS_FACES[: self.ndim])

    def to_dict(self):
        return {
            n: ("periodic" if getattr(self, n) == "periodic" else [s.to_dict() for s in getattr(self, n)])
            for n in self.faces
        }

    @classmethod
    def from_dict(cls, d):
        kw = {}
        zero = (0.0, 0.0, 0.0) if ("back" in d or "front" in d) else (0.0, 0.0)
        for n in FACES:
            if n in d:
                e = d[n]
                kw[n] = e if isinstance(e, str) else tuple(
                    Segment(**{**s, "velocity": tuple(s.get("velocity", zero))}) for s in e
                )
        return cls(**kw)


def _waveform(seg: Segment, t):
    s = 1.0
    if seg.ramp > 0:
        s = jnp.where(t < seg.ramp, 0.5 * (1 - jnp.cos(jnp.pi * t / seg.ramp)), 1.0)
    if seg.omega is not None:
        s = s * jnp.sin(seg.omega * t)
    return s


@dataclass
class _EdgeRule:
    alpha: np.ndarray  # (2, *face): ghost layers k = 1, 2; face = (L,) in 2D, (L1, L2) in 3D
    beta: np.ndarray
    gamma: np.ndarray
    dirichlet: list = field(default_factory=list)  # (segment, mask(face), profile(face), component)


def _extend_face(a, shape):
    """Extend a face coefficient array (its last ``len(shape)`` axes) to ``shape`` by edge
    replication: the ghost edges/corners along a face take the nearest face node's rule."""
    lead = a.ndim - len(shape)
    widths = [(0, 0)] * lead
    for n_have, n_want in zip(a.shape[lead:], shape, strict=True):
        pad = (n_want - n_have) // 2
        widths.append((pad, pad))
    if all(w == (0, 0) for w in widths):
        return a
    return jnp.pad(a, widths, mode="edge")


class BoundaryConditions:
    """Ghost-node padding for one grid and one :class:`Boundary` (built once per case).

    ``grid`` is a :class:`~refmap.grid.Grid` (with a 2D boundary) or a
    :class:`~refmap.grid.Grid3D` (with a boundary that has ``back`` and ``front`` faces).
    Arrays are padded on their last ``ndim`` axes; any leading axes are free.
    """

    G = 2  # ghost layers provided

    def __init__(self, grid: Grid | Grid3D, boundary: Boundary, rho_f0: float = 1.0):
        d = grid.ndim
        if boundary.ndim != d:
            hint = (
                ' (give its z faces, e.g. Boundary(back="wall", front="wall"))'
                if d == 3 else " (leave back and front unset)"
            )
            raise ValueError(
                f"a {d}D grid needs a {d}D boundary, got a {boundary.ndim}D one{hint}"
            )
        self.grid = grid
        self.ndim = d
        self.boundary = boundary
        self.rho_f0 = float(rho_f0)
        self.periodic = boundary.periodic
        self._glue = ()
        lows = grid.lows
        highs = grid.highs
        node_axes = grid.axes("node")
        # fraction along each tangential axis of the face, on the face's nodes (face-shaped)
        along = [(c - lo) / (hi - lo) for c, lo, hi in zip(node_axes, lows, highs, strict=True)]
        self._frac = {}
        for axis, names in enumerate(AXIS_FACES[:d]):
            fr = np.meshgrid(*(along[b] for b in range(d) if b != axis), indexing="ij")
            for name in names:
                self._frac[name] = tuple(fr)
        self._rules = {}
        for axis, (lo, hi) in enumerate(AXIS_FACES[:d]):
            for name, inward in ((lo, 1.0), (hi, -1.0)):
                edge = getattr(boundary, name)
                if edge == "periodic":
                    continue
                for comp in COMPONENTS[:d] + ("rho",):
                    self._rules[(name, comp)] = self._build(name, edge, comp, axis, inward)

    # ------------------------------------------------------------------ construction
    def _build(self, name, edge, comp, normal_axis, inward):
        fracs = self._frac[name]
        frac = fracs[0]  # segments run along the first tangential axis (whole faces in 3D)
        shape = frac.shape
        alpha = np.zeros((2, *shape))
        beta = np.zeros((2, *shape))
        gamma = np.zeros((2, *shape))
        rule = _EdgeRule(alpha, beta, gamma)
        k = np.array([1.0, 2.0])[:, None]
        for seg in edge:
            m = (frac >= seg.start) & (frac < seg.end)
            if seg.end >= 1.0:
                m |= frac >= 1.0
            if comp == "rho":
                if seg.kind in ("wall", "slip"):
                    alpha[:, m] = 1.0  # even
                elif seg.kind == "velocity" and inward * seg.velocity[normal_axis] > 0:
                    rule.dirichlet.append((seg, m, np.ones(shape), None))  # ghost = rho_f0
                else:  # outflow or outgoing prescribed velocity: linear extrapolation
                    beta[:, m] = (k + 1) * np.ones((2, m.sum()))
                    gamma[:, m] = -k * np.ones((2, m.sum()))
                continue
            ci = COMPONENTS.index(comp)
            if seg.kind in ("wall", "velocity"):
                alpha[:, m] = -1.0
                prof = np.ones(shape)
                if seg.profile == "parabolic":
                    prof = None
                    for fr in fracs:  # 2D: one tangential axis; 3D: the product over two
                        s = (fr - seg.start) / (seg.end - seg.start)
                        p = 4.0 * s * (1.0 - s)
                        prof = p if prof is None else prof * p
                if seg.velocity[ci] != 0.0:
                    rule.dirichlet.append((seg, m, 2.0 * seg.velocity[ci] * prof, "odd"))
            elif seg.kind == "slip":
                alpha[:, m] = -1.0 if ci == normal_axis else 1.0
            elif seg.kind == "outflow":
                beta[:, m] = 1.0
        return rule

    # ------------------------------------------------------------------ padding
    def _ghosts(self, f, rule: _EdgeRule, low: bool, axis: int, t, rho0=None):
        """Two ghost layers (k = 2, 1 order outwards-in) for one face of ``f``.

        ``f`` is already padded along the axes before ``axis``; the face coefficients are
        extended over those ghosts by edge replication (:func:`_extend_face`).
        """
        rho0 = self.rho_f0 if rho0 is None else rho0
        ax = f.ndim - self.ndim + axis
        n = f.shape[ax]

        def take(i):
            i = i if low else n - 1 - i
            return jnp.take(f, i, axis=ax)

        f0, f1 = take(0), take(1)
        face = f0.shape[f0.ndim - (self.ndim - 1):]
        ghosts = []
        for kk in (0, 1):
            fm = take(kk)
            a, b, c = (jnp.asarray(arr[kk]) for arr in (rule.alpha, rule.beta, rule.gamma))
            a, b, c = (_extend_face(arr, face) for arr in (a, b, c))
            g = a * fm + b * f0 + c * f1
            for seg, m, val, how in rule.dirichlet:
                # jnp.where: the values may be traced (refmap.differentiable.with_traced)
                d = _extend_face(jnp.where(jnp.asarray(m), val, 0.0), face)
                if how is None:
                    g = jnp.where(_extend_face(jnp.asarray(m), face), rho0, g)
                else:
                    g = g + d * _waveform(seg, t)
            ghosts.append(g)
        g1, g2 = ghosts
        return (g2, g1) if low else (g1, g2)

    def _pad_axis(self, f, axis, comp, t, rho0=None):
        lo, hi = AXIS_FACES[axis]
        ax = f.ndim - self.ndim + axis
        if self.periodic[axis]:
            widths = [(0, 0)] * f.ndim
            widths[ax] = (2, 2)
            return jnp.pad(f, widths, mode="wrap")
        gl2, gl1 = self._ghosts(f, self._rules[(lo, comp)], True, axis, t, rho0)
        gh1, gh2 = self._ghosts(f, self._rules[(hi, comp)], False, axis, t, rho0)
        return jnp.concatenate(
            [jnp.expand_dims(x, ax) for x in (gl2, gl1)]
            + [f]
            + [jnp.expand_dims(x, ax) for x in (gh1, gh2)],
            axis=ax,
        )

    def _pad(self, f, comp, t, rho0=None):
        """Pad the last ``ndim`` axes of ``f``, axis after axis (x, then y[, then z])."""
        for axis in range(self.ndim):
            f = self._pad_axis(f, axis, comp, t, rho0)
        return f

    def pad_velocity(self, vel, t):
        """(d, nx, ny[, nz]) -> (d, nx + 4, ny + 4[, nz + 4]) with two ghost layers."""
        return jnp.stack([self._pad(vel[c], comp, t) for c, comp in enumerate(COMPONENTS[: self.ndim])])

    def pad_density(self, rho, t=0.0, rho0=None):
        """(nx, ny[, nz]) -> (nx + 4, ny + 4[, nz + 4]).  Ghosts at flow-through faces take
        the fluid's reference density ``rho0`` (the fluid's own ``FluidParams.rho0``; the
        constructor's ``rho_f0`` when not given)."""
        return self._pad(rho, "rho", t, rho0)

    def pad_linear(self, f):
        """Linear extrapolation (affine-exact) into two ghost layers, or wrap if periodic;
        axis after axis, so the ghost edges and corners continue an affine field exactly."""
        out = f
        for axis in range(self.ndim):
            ax = out.ndim - self.ndim + axis
            if self.periodic[axis]:
                widths = [(0, 0)] * out.ndim
                widths[ax] = (2, 2)
                out = jnp.pad(out, widths, mode="wrap")
                continue
            n = out.shape[ax]
            f0 = jnp.take(out, jnp.array([0]), axis=ax)
            f1 = jnp.take(out, jnp.array([1]), axis=ax)
            e0 = jnp.take(out, jnp.array([n - 1]), axis=ax)
            e1 = jnp.take(out, jnp.array([n - 2]), axis=ax)
            out = jnp.concatenate([3 * f0 - 2 * f1, 2 * f0 - f1, out, 2 * e0 - e1, 3 * e0 - 2 * e1], axis=ax)
        return out

    def padded_coords(self, g=2):
        """Node coordinates extended by ``g`` ghost layers (affine continuation):
        (d, nx + 2g, ny + 2g[, nz + 2g])."""
        gr = self.grid
        lows = gr.lows
        axes = [
            lo + (np.arange(-g, n + g) + 0.5) * h
            for lo, n, h in zip(lows, gr.shape("node"), gr.spacing, strict=True)
        ]
        return np.stack(np.meshgrid(*axes, indexing="ij"))

    def pad_affine(self, xi):
        """Pad reference maps (..., d, nx, ny[, nz]) so that affine maps stay affine in the ghosts.

        The map minus the identity is extended (linearly, or by wrapping on periodic edges,
        where a body crossing the edge carries a map that jumps by the period) and the
        identity is added back.
        """
        Xn = jnp.asarray(self.grid.mesh("node"))
        Xp = jnp.asarray(self.padded_coords(2))
        d = self.pad_linear(xi - Xn)
        for axis, low, odd, even, face in self._glue:
            ax = d.ndim - self.ndim + axis
            n = d.shape[ax]
            # ghost layers (k = 1, 2) and their mirror nodes (0, 1) in padded indices
            pairs = ((1, 2), (0, 3)) if low else ((n - 2, n - 3), (n - 1, n - 4))
            for gi, mi in pairs:
                ghost = jnp.take(d, gi, axis=ax)
                mirror = jnp.take(d, mi, axis=ax)
                ghost = jnp.where(odd, 2.0 * face - mirror, jnp.where(even, mirror, ghost))
                d = _set_slice(d, ax, gi, ghost)
        return d + Xp

    def glue(self, disp0, solid0):
        """Glue solids to the stationary edges they touch at t = 0 (for :meth:`pad_affine`).

        ``disp0``: the initial displacement-like maps ``xi - x`` (N, d, nx, ny[, nz]);
        ``solid0``: where each solid is at t = 0 (N, nx, ny[, nz]) bool.  Where a solid covers
        the first node in from a no-slip ``wall`` segment at rest, its material on the wall
        face never moves, so the face keeps its initial map: the ghosts of ``xi - x`` become
        the odd reflection ``2 d_face - d_mirror`` about the initial face value (all
        components); at a ``slip`` segment the normal component is held so and the
        tangential ones reflected evenly (no shear strain at a frictionless face).  Linear
        extrapolation (the default) leaves the first node row with no elastic restoring
        force normal to the edge (the wall-face strain is a copy of the next one), a
        zero-energy mode that a body load drives: a solid resting in a corner under gravity
        collapsed (J -> 0.17 by t = 4 at 32^2).  Solids that do not touch such an edge at
        t = 0 are padded as before.
        """
        disp0 = np.asarray(disp0, dtype=float)
        solid0 = np.asarray(solid0, dtype=bool)
        nd = self.ndim
        rules = []
        for axis, names in enumerate(AXIS_FACES[:nd]):
            for name in names:
                edge = getattr(self.boundary, name)
                if edge == "periodic":
                    continue
                low = name == names[0]
                frac = self._frac[name][0]
                held = np.zeros((nd, *frac.shape), dtype=bool)  # per component: odd reflection
                free = np.zeros((nd, *frac.shape), dtype=bool)  # per component: even reflection
                for seg in edge:
                    m = (frac >= seg.start) & (frac < seg.end)
                    if seg.end >= 1.0:
                        m |= frac >= 1.0
                    if seg.kind == "wall" and all(c == 0.0 for c in seg.velocity):
                        held[:, m] = True
                    elif seg.kind == "slip":
                        held[axis, m] = True
                        for c in range(nd):
                            if c != axis:
                                free[c, m] = True
                i0, i1 = (0, 1) if low else (-1, -2)
                at = np.take(solid0, i0, axis=solid0.ndim - nd + axis)  # (N, *face)
                odd = at[:, None] & held[None]  # (N, d, *face)
                even = at[:, None] & free[None]
                if not (odd.any() or even.any()):
                    continue
                d0 = np.take(disp0, i0, axis=disp0.ndim - nd + axis)
                d1 = np.take(disp0, i1, axis=disp0.ndim - nd + axis)
                face = 1.5 * d0 - 0.5 * d1  # initial face value (exact for affine maps)
                # cover the ghost edges/corners along the face: wrap where that axis is
                # periodic, else replicate the face's rim
                for j, b in enumerate(b for b in range(nd) if b != axis):
                    pad = [(0, 0)] * (2 + nd - 1)
                    pad[2 + j] = (2, 2)
                    mode = "wrap" if self.periodic[b] else "edge"
                    odd, even, face = (np.pad(a, pad, mode=mode) for a in (odd, even, face))
                rules.append((axis, low, odd, even, face))
        self._glue = tuple(rules)


def _set_slice(a, ax, i, value):
    """``a`` with index ``i`` along axis ``ax`` replaced by ``value``."""
    idx = [slice(None)] * a.ndim
    idx[ax] = i
    return a.at[tuple(idx)].set(value)

