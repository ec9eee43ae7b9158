"""Domain-edge conditions, imposed through ghost nodes.

Each of the four edges is either ``"periodic"`` (then its opposite edge must be too) or a
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
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import jax.numpy as jnp
import numpy as np

from refmap.grid import Grid

SegmentKind = Literal["wall", "slip", "velocity", "outflow"]
EDGES = ("left", "right", "bottom", "top")
_KINDS = ("wall", "slip", "velocity", "outflow")


@dataclass(frozen=True)
class Segment:
    """A stretch ``[start, end)`` of an edge (fractions of its length, from its low end)."""

    kind: SegmentKind = "wall"
    start: float = 0.0
    end: float = 1.0
    velocity: tuple[float, float] = (0.0, 0.0)
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


def _as_edge(e) -> Edge:
    if isinstance(e, str):
        if e == "periodic":
            return "periodic"
        return (Segment(kind=e),)
    if isinstance(e, Segment):
        return (e,)
    return tuple(e)


@dataclass(frozen=True)
class Boundary:
    """Conditions on the four edges (default: no-slip walls all round)."""

    left: Edge = (Segment("wall"),)
    right: Edge = (Segment("wall"),)
    bottom: Edge = (Segment("wall"),)
    top: Edge = (Segment("wall"),)

    def __post_init__(self):
        for name in EDGES:
            object.__setattr__(self, name, _as_edge(getattr(self, name)))
        for a, b in (("left", "right"), ("bottom", "top")):
            pa, pb = getattr(self, a) == "periodic", getattr(self, b) == "periodic"
            if pa != pb:
                raise ValueError(f"periodic edges come in pairs: {a} is {getattr(self, a)!r} but {b} is not")
        for name in EDGES:
            e = getattr(self, name)
            if e == "periodic":
                continue
            if len(e) == 0:
                raise ValueError(f"boundary edge {name!r} has no segments")
            cover = sorted((s.start, s.end) for s in e)
            pos = 0.0
            for s0, s1 in cover:
                if abs(s0 - pos) > 1e-12:
                    raise ValueError(f"segments of edge {name!r} must tile [0, 1] without gaps or overlaps; got {cover}")
                pos = s1
            if abs(pos - 1.0) > 1e-12:
                raise ValueError(f"segments of edge {name!r} must reach 1.0; got {cover}")

    @property
    def periodic(self) -> tuple[bool, bool]:
        return (self.left == "periodic", self.bottom == "periodic")

    def to_dict(self):
        return {
            n: ("periodic" if getattr(self, n) == "periodic" else [s.to_dict() for s in getattr(self, n)])
            for n in EDGES
        }

    @classmethod
    def from_dict(cls, d):
        kw = {}
        for n in EDGES:
            if n in d:
                e = d[n]
                kw[n] = e if isinstance(e, str) else tuple(
                    Segment(**{**s, "velocity": tuple(s.get("velocity", (0.0, 0.0)))}) for s in e
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
    alpha: np.ndarray  # (2, L): ghost layers k = 1, 2
    beta: np.ndarray
    gamma: np.ndarray
    dirichlet: list = field(default_factory=list)  # (segment, mask(L), profile(L), component)


class BoundaryConditions:
    """Ghost-node padding for one grid and one :class:`Boundary` (built once per case)."""

    G = 2  # ghost layers provided

    def __init__(self, grid: Grid, boundary: Boundary, rho_f0: float = 1.0):
        self.grid = grid
        self.boundary = boundary
        self.rho_f0 = float(rho_f0)
        self.periodic = boundary.periodic
        self._glue = ()
        xn, yn = grid.axes("node")
        self._frac = {
            "left": (yn - grid.ay) / (grid.by - grid.ay),
            "right": (yn - grid.ay) / (grid.by - grid.ay),
            "bottom": (xn - grid.ax) / (grid.bx - grid.ax),
            "top": (xn - grid.ax) / (grid.bx - grid.ax),
        }
        self._rules = {}
        for name in EDGES:
            edge = getattr(boundary, name)
            if edge == "periodic":
                continue
            normal_axis = 0 if name in ("left", "right") else 1
            inward = 1.0 if name in ("left", "bottom") else -1.0
            for comp in ("u", "v", "rho"):
                self._rules[(name, comp)] = self._build(name, edge, comp, normal_axis, inward)

    # ------------------------------------------------------------------ construction
    def _build(self, name, edge, comp, normal_axis, inward):
        frac = self._frac[name]
        L = frac.size
        alpha = np.zeros((2, L))
        beta = np.zeros((2, L))
        gamma = np.zeros((2, L))
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
                    rule.dirichlet.append((seg, m, np.ones(L), None))  # ghost = rho_f0
                else:  # outflow or outgoing prescribed velocity: linear extrapolation
                    beta[:, m] = (k + 1) * np.ones((2, m.sum()))
                    gamma[:, m] = -k * np.ones((2, m.sum()))
                continue
            ci = 0 if comp == "u" else 1
            if seg.kind in ("wall", "velocity"):
                alpha[:, m] = -1.0
                prof = np.ones(L)
                if seg.profile == "parabolic":
                    s = (frac - seg.start) / (seg.end - seg.start)
                    prof = 4.0 * s * (1.0 - s)
                if seg.velocity[ci] != 0.0:
                    rule.dirichlet.append((seg, m, 2.0 * seg.velocity[ci] * prof, "odd"))
            elif seg.kind == "slip":
                alpha[:, m] = -1.0 if ci == normal_axis else 1.0
            elif seg.kind == "outflow":
                beta[:, m] = 1.0
        return rule

    # ------------------------------------------------------------------ padding
    def _ghosts(self, f, rule: _EdgeRule, low: bool, axis: int, t, rho0=None):
        """Two ghost layers (k = 2, 1 order outwards-in) for one edge of ``f``."""
        rho0 = self.rho_f0 if rho0 is None else rho0
        n = f.shape[axis - 2]

        def take(i):
            i = i if low else n - 1 - i
            return jnp.take(f, i, axis=axis - 2 + f.ndim if axis - 2 < 0 else axis)

        f0, f1 = take(0), take(1)
        ghosts = []
        for kk in (0, 1):
            fm = take(kk)
            a, b, c = (jnp.asarray(arr[kk]) for arr in (rule.alpha, rule.beta, rule.gamma))
            if axis == 1:  # bottom/top edges: coefficient arrays run along x; f0 is (..., nx')
                a, b, c = (self._extend(arr, f0.shape[-1]) for arr in (a, b, c))
            g = a * fm + b * f0 + c * f1
            for seg, m, val, how in rule.dirichlet:
                # jnp.where: the values may be traced (refmap.differentiable.with_traced)
                d = jnp.where(jnp.asarray(m), val, 0.0)
                if axis == 1:
                    d = self._extend(d, f0.shape[-1])
                if how is None:
                    mm = jnp.asarray(m)
                    g = jnp.where(self._extend(mm, f0.shape[-1]) if axis == 1 else mm, rho0, g)
                else:
                    g = g + d * _waveform(seg, t)
            ghosts.append(g)
        g1, g2 = ghosts
        return (g2, g1) if low else (g1, g2)

    @staticmethod
    def _extend(a, length):
        """Extend an edge coefficient array to cover the corner ghosts (edge replication)."""
        pad = (length - a.shape[-1]) // 2
        if pad == 0:
            return a
        return jnp.pad(a, (pad, pad), mode="edge")

    def _pad_axis(self, f, axis, comp, t, rho0=None):
        lo, hi = ("left", "right") if axis == 0 else ("bottom", "top")
        ax = f.ndim - 2 + axis
        if self.periodic[axis]:
            widths = [(0, 0)] * f.ndim
            widths[ax] = (2, 2)
            return jnp.pad(f, widths, mode="wrap")
        gl2, gl1 = self._ghosts(f, self._rules[(lo, comp)], True, axis, t, rho0)
        gh1, gh2 = self._ghosts(f, self._rules[(hi, comp)], False, axis, t, rho0)
        return jnp.concatenate(
            [jnp.expand_dims(x, ax) if x.ndim < f.ndim else x for x in (gl2, gl1)]
            + [f]
            + [jnp.expand_dims(x, ax) for x in (gh1, gh2)],
            axis=ax,
        )

    def _pad(self, f, comp, t, rho0=None):
        return self._pad_axis(self._pad_axis(f, 0, comp, t, rho0), 1, comp, t, rho0)

    def pad_velocity(self, vel, t):
        """(2, nx, ny) -> (2, nx + 4, ny + 4) with two ghost layers."""
        return jnp.stack([self._pad(vel[0], "u", t), self._pad(vel[1], "v", t)])

    def pad_density(self, rho, t=0.0, rho0=None):
        """(nx, ny) -> (nx + 4, ny + 4).  Ghosts at flow-through edges take the fluid's
        reference density ``rho0`` (the fluid's own ``FluidParams.rho0``; the constructor's
        ``rho_f0`` when not given)."""
        return self._pad(rho, "rho", t, rho0)

    def pad_linear(self, f):
        """Linear extrapolation (affine-exact) into two ghost layers, or wrap if periodic."""
        widths_x = [(0, 0)] * (f.ndim - 2) + [(2, 2), (0, 0)]
        widths_y = [(0, 0)] * (f.ndim - 2) + [(0, 0), (2, 2)]
        out = f
        for axis, widths in ((0, widths_x), (1, widths_y)):
            ax = out.ndim - 2 + axis
            if self.periodic[axis]:
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
        """Node coordinates extended by ``g`` ghost layers (affine continuation)."""
        gr = self.grid
        x = gr.ax + (np.arange(-g, gr.nx + g) + 0.5) * gr.dx
        y = gr.ay + (np.arange(-g, gr.ny + g) + 0.5) * gr.dy
        return np.stack(np.meshgrid(x, y, indexing="ij"))

    def pad_affine(self, xi):
        """Pad reference maps (..., 2, nx, ny) so that affine maps stay affine in the ghosts.

        The map minus the identity is extended (linearly, or by wrapping on periodic edges,
        where a body crossing the edge carries a map that jumps by the period) and the
        identity is added back.
        """
        Xn = jnp.asarray(self.grid.mesh("node"))
        Xp = jnp.asarray(self.padded_coords(2))
        d = self.pad_linear(xi - Xn)
        for axis, low, odd, even, face in self._glue:
            ax = d.ndim - 2 + axis
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

        ``disp0``: the initial displacement-like maps ``xi - x`` (N, 2, nx, ny); ``solid0``:
        where each solid is at t = 0 (N, nx, ny) bool.  Where a solid covers the first node
        in from a no-slip ``wall`` segment at rest, its material on the wall face never moves,
        so the face keeps its initial map: the ghosts of ``xi - x`` become the odd reflection
        ``2 d_face - d_mirror`` about the initial face value (both components); at a ``slip``
        segment the normal component is held so and the tangential one reflected evenly
        (no shear strain at a frictionless face).  Linear extrapolation (the default)
        leaves the first node row with no elastic restoring force normal to the edge (the
        wall-face strain is a copy of the next one), a zero-energy mode that a body load
        drives: a solid resting in a corner under gravity collapsed (J -> 0.17 by t = 4 at
        32^2).  Solids that do not touch such an edge at t = 0 are padded as before.
        """
        disp0 = np.asarray(disp0, dtype=float)
        solid0 = np.asarray(solid0, dtype=bool)
        rules = []
        for name in EDGES:
            edge = getattr(self.boundary, name)
            if edge == "periodic":
                continue
            axis = 0 if name in ("left", "right") else 1
            low = name in ("left", "bottom")
            frac = self._frac[name]
            held = np.zeros((2, frac.size), dtype=bool)  # per component: odd reflection
            free = np.zeros((2, frac.size), dtype=bool)  # per component: even reflection
            for seg in edge:
                m = (frac >= seg.start) & (frac < seg.end)
                if seg.end >= 1.0:
                    m |= frac >= 1.0
                if seg.kind == "wall" and seg.velocity == (0.0, 0.0):
                    held[:, m] = True
                elif seg.kind == "slip":
                    held[axis, m] = True
                    free[1 - axis, m] = True
            i0, i1 = (0, 1) if low else (-1, -2)
            at = np.take(solid0, i0, axis=solid0.ndim - 2 + axis)  # (N, L)
            odd = at[:, None, :] & held[None]  # (N, 2, L)
            even = at[:, None, :] & free[None]
            if not (odd.any() or even.any()):
                continue
            d0 = np.take(disp0, i0, axis=disp0.ndim - 2 + axis)
            d1 = np.take(disp0, i1, axis=disp0.ndim - 2 + axis)
            face = 1.5 * d0 - 0.5 * d1  # initial face value (exact for affine maps)
            # cover the ghost corners along the edge: wrap if that axis is periodic
            mode = "wrap" if self.periodic[1 - axis] else "edge"
            pad = ((0, 0), (0, 0), (2, 2))
            odd, even, face = (np.pad(a, pad, mode=mode) for a in (odd, even, face))
            rules.append((axis, low, odd, even, face))
        self._glue = tuple(rules)


def _set_slice(a, ax, i, value):
    """``a`` with index ``i`` along axis ``ax`` replaced by ``value``."""
    idx = [slice(None)] * a.ndim
    idx[ax] = i
    return a.at[tuple(idx)].set(value)

