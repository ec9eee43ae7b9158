"""Anchors: constraints that hold part of a solid (thesis Appendix E).

* :class:`RegionAnchor` -- nodes inside a fixed region (a shape in *current* coordinates,
  e.g. the stick's foot) keep zero velocity and their initial reference map.
* :class:`PivotAnchor` -- a pin joint: over a disc of radius ``fit_radius`` round the pivot
  the angular velocity omega = sum(x v - y u) / sum(x^2 + y^2) and the rotation angle of the
  best-fit rotation of the reference map are measured; inside ``hold_radius`` the velocity is
  replaced by the rigid rotation omega x r and the reference map by that rotation of the
  reference configuration.  The body turns freely about the pivot but cannot translate.

Both act after the velocity and reference-map updates (step 8 of the thesis's Algorithm 1)
and are pure functions of the arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from refmap.grid import Grid


@dataclass(frozen=True)
class RegionAnchor:
    """Hold the solid fixed inside ``region`` (a :class:`refmap.geometry.Shape`, current coords)."""

    region: object

    def mask(self, grid: Grid) -> np.ndarray:
        X, Y = grid.mesh("node")
        with jax.ensure_compile_time_eval():  # a constant mask, even when called under jit
            return np.asarray(self.region(X, Y)) < 0

    def apply(self, grid: Grid, v, xi, xi0):
        m = jnp.asarray(self.mask(grid))
        v = jnp.where(m, 0.0, v)
        xi = jnp.where(m, xi0, xi)
        return v, xi

    def to_dict(self):
        return {"type": "region", "region": self.region.to_dict()}


@dataclass(frozen=True)
class PivotAnchor:
    """A frictionless pin at ``center`` (thesis rotor: fit radius 0.4, hold radius 0.3)."""

    center: tuple[float, float] = (0.0, 0.0)
    fit_radius: float = 0.4
    hold_radius: float = 0.3

    def __post_init__(self):
        if not (self.fit_radius > 0 and self.hold_radius > 0):
            raise ValueError(
                f"pivot radii must be > 0, got fit_radius={self.fit_radius!r}, hold_radius={self.hold_radius!r}"
            )
        object.__setattr__(self, "center", tuple(float(c) for c in self.center))

    def apply(self, grid: Grid, v, xi, xi0):
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
        hold = jnp.asarray(r2n < self.hold_radius**2)
        v = jnp.where(hold, jnp.stack([-omega * y, omega * x]), v)
        xi_rot = jnp.stack([c * x - s * y + self.center[0], s * x + c * y + self.center[1]])
        xi = jnp.where(hold, xi_rot, xi)
        return v, xi

    def to_dict(self):
        return {"type": "pivot", "center": list(self.center), "fit_radius": self.fit_radius,
                "hold_radius": self.hold_radius}
