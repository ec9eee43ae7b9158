"""Anchors: constraints that hold part of a solid (thesis Appendix E).

* :class:`RegionAnchor` -- nodes inside a fixed region (a shape in *current* coordinates,
  e.g. the stick's foot) keep zero velocity and their initial reference map.
* :class:`PivotAnchor` -- a pin joint: over a disc of radius ``fit_radius`` round the pivot
  the angular velocity omega = sum(x v - y u) / sum(x^2 + y^2) and the rotation angle of the
  best-fit rotation of the reference map are measured; inside ``hold_radius`` the velocity is
  replaced by the rigid rotation omega x r and the reference map by that rotation of the
  reference configuration.  The body turns freely about the pivot but cannot translate.

Unlike the thesis's code, the pivot imposes the rigid rotation on the velocity only, with
a weight that ramps from 1 to 0 over two cells across the held disc's edge (see
:func:`_ramp`), and leaves the reference map to the advection by that rigid velocity
(``hold_map=True`` also overwrites it with the best-fit rotation, as the thesis does).  On
the rotor at 96^2, t = 3, the largest mixed second difference of the pressure round the
pivot (single-cell spots) is 0.40 with the thesis's hard mask on both, 0.33 with the ramp,
0.24 with the ramp on the velocity only, against a pressure range of 1.25 there.

Both act after the velocity and reference-map updates (step 8 of the thesis's Algorithm 1)
and are pure functions of the arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from refmap.grid import Grid


def _ramp(d, h):
    """Constraint weight from a signed distance d to the held region's edge (d < 0 inside).

    A hard on/off mask makes the held region's edge a staircase that shows up as
    single-cell spots in the stress; a ramp over two cells smooths it.
    """
    return np.clip(0.5 - d / (2.0 * h), 0.0, 1.0)


@dataclass(frozen=True)
class RegionAnchor:
    """Hold the solid fixed inside ``region`` (a :class:`refmap.geometry.Shape`, current coords)."""

    region: object
    #: also hold the map, to ``xi0``, on a free node (outside the region) whose map points
    #: into the region: the held material is at rest, so no node outside the region can
    #: carry it (assumes the region's material has ``xi0 = x``, a body built in place).
    #: For an anchor that holds a whole body (the rigid Turek--Hron flag): the free nodes
    #: next to its contour have the fluid's velocity, their advected map is ``x - dt v``
    #: and the level set pinned to it, ``phi0(x - dt v)``, turns negative where ``dt v``
    #: reaches past the node's distance to the contour.  That node was then a solid node
    #: the anchor does not hold, a source of the map's extrapolation with strain against
    #: its held neighbours, and the solid's stress on it is explicit (CFD1 at 8 cells
    #: across the flag: a node 0.012 h outside the cylinder crossed at t = 1.175 and the
    #: step, 45x the solid's wave limit, blew up within three steps).  Where no map
    #: enters the region the step is unchanged, bit for bit.
    hold_entering: bool = False

    supports_3d = True

    def mask(self, grid: Grid) -> np.ndarray:
        return self.weight(grid) > 0.5

    def weight(self, grid: Grid) -> np.ndarray:
        """1 inside the region, 0 outside (a hard clamp, as the thesis's code).

        (A ramp over two cells, tried as for the pivot, left single-cell velocity spots
        round the stick's foot: 0.71 against 0.56 for the hard clamp at 64^2, t = 8.)"""
        with jax.ensure_compile_time_eval():  # a constant, even when called under jit
            d = np.asarray(self.region(*grid.mesh("node")))
        return (d < 0).astype(float)

    def check(self, grid: Grid, inside) -> None:
        """ValueError unless the region holds at least one grid node of the solid
        (``inside``: the solid's nodes at t = 0); a region beside the solid would hold
        nothing and the solid would float free without a word."""
        held = self.mask(grid)
        if not (held & np.asarray(inside)).any():
            Xn = grid.mesh("node")
            where = (
                f"it holds {int(held.sum())} grid nodes, none inside the solid"
                if held.any()
                else "it holds no grid node at all"
            )
            spans = ", ".join(f"{'xyz'[c]} in [{Xc[inside].min():.3g}, {Xc[inside].max():.3g}]"
                              for c, Xc in enumerate(Xn))
            raise ValueError(
                f"anchor region {self.region!r} holds no node of the solid ({where}; the "
                f"solid spans {spans}, h = {grid.h:.3g})"
            )

    def velocity_weight(self, grid: Grid) -> np.ndarray:
        """Node weight of the anchor's velocity in :meth:`apply` (v -> w v_a + (1 - w) v)."""
        return self.weight(grid)

    def apply(self, grid: Grid, v, xi, xi0):
        w = jnp.asarray(self.weight(grid))
        v = (1.0 - w) * v
        xi = w * xi0 + (1.0 - w) * xi
        if self.hold_entering:
            entering = (w == 0.0) & (self.region(*xi) < 0.0)
            xi = jnp.where(entering[None], xi0, xi)
        return v, xi

    def to_dict(self):
        out = {"type": "region", "region": self.region.to_dict()}
        if self.hold_entering:
            out["hold_entering"] = True
        return out


@dataclass(frozen=True)
class PivotAnchor:
    """A frictionless pin at ``center`` (thesis rotor: fit radius 0.4, hold radius 0.3).

    In 3D it is an axle: ``center`` has three coordinates and the axle runs through it
    along ``axis`` (default z) over ``half_length`` either side (None: through the whole
    box).  The body turns freely about the axle (the rate omega is fitted over the nodes
    within ``fit_radius`` of the axle's line and of its length) and cannot translate; held
    nodes get the rigid rotation ``omega axis x r``.  ``hold_map`` is 2D only.
    """

    center: tuple[float, float] = (0.0, 0.0)  # (x, y, z) in 3D
    fit_radius: float = 0.4
    hold_radius: float = 0.3
    hold_map: bool = False
    axis: tuple[float, float, float] | None = None  # 3D only
    half_length: float | None = None  # 3D only

    supports_3d = True

    def __post_init__(self):
        if not (self.fit_radius > 0 and self.hold_radius > 0):
            raise ValueError(
                f"pivot radii must be > 0, got fit_radius={self.fit_radius!r}, hold_radius={self.hold_radius!r}"
            )
        center = tuple(float(c) for c in self.center)
        if len(center) not in (2, 3):
            raise ValueError(f"pivot center must have 2 (2D) or 3 (3D) coordinates, got {self.center!r}")
        object.__setattr__(self, "center", center)
        if len(center) == 2:
            if self.axis is not None or self.half_length is not None:
                raise ValueError("a 2D pivot takes no axis or half_length (a 3D pivot has a 3D center)")
            return
        if self.hold_map:
            raise ValueError("pivot hold_map is 2D only (a 3D pivot leaves the map to the advection)")
        a = np.asarray((0.0, 0.0, 1.0) if self.axis is None else self.axis, dtype=float)
        if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) == 0:
            raise ValueError(f"pivot axis must be a non-zero 3-vector, got {self.axis!r}")
        object.__setattr__(self, "axis", tuple(float(c) for c in a / np.linalg.norm(a)))
        if self.half_length is not None and not self.half_length > 0:
            raise ValueError(f"pivot half_length must be > 0 or None, got {self.half_length!r}")

    def _check_dim(self, grid):
        if len(self.center) != grid.ndim:
            raise ValueError(f"pivot center {self.center} has {len(self.center)} coordinates, the grid is "
                             f"{grid.ndim}D")

    def _axle(self, grid):
        """3D: (r_perp (3, ...), |r_perp|, along-axle mask) of the node coordinates."""
        Xn = np.stack(grid.mesh("node"))
        r = Xn - np.asarray(self.center).reshape(3, 1, 1, 1)
        a = np.asarray(self.axis).reshape(3, 1, 1, 1)
        along = np.sum(r * a, axis=0)
        rp = r - along[None] * a
        within = np.ones(along.shape, bool) if self.half_length is None else np.abs(along) <= self.half_length
        return rp, np.sqrt(np.sum(rp * rp, axis=0)), within

    def velocity_weight(self, grid: Grid) -> np.ndarray:
        """Node weight of the rigid rotation in :meth:`apply` (v -> w v_rot + (1 - w) v)."""
        self._check_dim(grid)
        if grid.ndim == 3:
            _, dist, within = self._axle(grid)
            return _ramp(dist - self.hold_radius, grid.h) * within
        X, Y = grid.mesh("node")
        r = np.hypot(X - self.center[0], Y - self.center[1])
        return _ramp(r - self.hold_radius, grid.h)

    def apply(self, grid: Grid, v, xi, xi0):
        self._check_dim(grid)
        if grid.ndim == 3:
            return self._apply_3d(grid, v, xi)
        X, Y = grid.mesh("node")
        xn, yn = X - self.center[0], Y - self.center[1]
        r2n = xn * xn + yn * yn
        if not np.any(r2n < self.fit_radius**2):
            raise ValueError(f"pivot fit_radius {self.fit_radius} holds no grid node; refine the grid")
        x, y, r2 = jnp.asarray(xn), jnp.asarray(yn), jnp.asarray(r2n)
        fit = jnp.asarray(r2n < self.fit_radius**2)
        u, w = v[0], v[1]
        omega = jnp.sum(jnp.where(fit, x * w - y * u, 0.0)) / jnp.sum(jnp.where(fit, r2, 0.0))
        Xr = xi[0] - self.center[0]
        Yr = xi[1] - self.center[1]
        cxx = jnp.sum(jnp.where(fit, Xr * x + Yr * y, 0.0))
        cyx = jnp.sum(jnp.where(fit, Yr * x - Xr * y, 0.0))
        theta = jnp.arctan2(cyx, cxx)
        c, s = jnp.cos(theta), jnp.sin(theta)
        w = jnp.asarray(_ramp(np.sqrt(r2n) - self.hold_radius, grid.h))
        v = w * jnp.stack([-omega * y, omega * x]) + (1.0 - w) * v
        if self.hold_map:
            xi_rot = jnp.stack([c * x - s * y + self.center[0], s * x + c * y + self.center[1]])
            xi = w * xi_rot + (1.0 - w) * xi
        return v, xi

    def _apply_3d(self, grid, v, xi):
        rp, dist, within = self._axle(grid)
        fit_n = (dist < self.fit_radius) & within
        if not fit_n.any():
            raise ValueError(f"pivot fit_radius {self.fit_radius} holds no grid node; refine the grid")
        a = np.asarray(self.axis).reshape(3, 1, 1, 1)
        t = np.cross(a, rp, axis=0)  # a x r_perp: the rigid rotation's velocity per unit omega
        fit = jnp.asarray(fit_n)
        tj = jnp.asarray(t)
        omega = jnp.sum(jnp.where(fit, jnp.sum(tj * v, axis=0), 0.0)) / jnp.sum(
            jnp.where(fit, jnp.asarray(dist * dist), 0.0))
        w = jnp.asarray(_ramp(dist - self.hold_radius, grid.h) * within)
        return w * omega * tj + (1.0 - w) * v, xi

    def to_dict(self):
        out = {"type": "pivot", "center": list(self.center), "fit_radius": self.fit_radius,
               "hold_radius": self.hold_radius, "hold_map": self.hold_map}
        if len(self.center) == 3:
            out.update(axis=list(self.axis), half_length=self.half_length)
        return out
