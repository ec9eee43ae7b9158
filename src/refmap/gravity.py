"""Gravity relative to the mean density: a body force for periodic boxes.

``Params.gravity`` accelerates everything, fluid and solids alike; in a closed box the
fluid's pressure then builds a hydrostatic gradient and the buoyancy of the solids follows.
In a box periodic along gravity no such gradient can form (the pressure is periodic), so
everything would fall together.  :class:`RelativeGravity` is the usual cure for periodic
suspensions (Hasimoto 1959; Zick & Homsy 1982): the force density

    f = (rho - <rho>) g,

with ``<rho>`` the mean of the mixed density over the grid, i.e. gravity minus the uniform
pressure gradient ``<rho> g`` that holds up the mixture's mean weight.  Its total is zero
(momentum is conserved), a solid of density rho_s feels ``(rho_s - <rho>) g`` per unit
volume and the fluid the uniform back-force ``(rho_f - <rho>) g``; for one body of volume
V in a cell of volume L^d the back-force is ``-F / L^d`` with ``F = (rho_s - rho_f) V g``,
the set-up of Hasimoto's periodic array.  Use it instead of ``Params.gravity`` (leave that
zero): ``Model(..., body_forces=(RelativeGravity((0, 0, -9.81)),))``.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp


@dataclass(frozen=True)
class RelativeGravity:
    """The body force ``(rho - mean(rho)) g`` (one component of ``g`` per axis)."""

    g: tuple

    supports_3d = True

    def __post_init__(self):
        object.__setattr__(self, "g", tuple(float(c) for c in self.g))

    def __call__(self, ctx):
        model = ctx["model"]
        if len(self.g) != model.ndim:
            raise ValueError(f"RelativeGravity g has {len(self.g)} components, the grid is {model.ndim}D")
        rho = ctx["derived"]["rho"]
        excess = rho - jnp.mean(rho)
        return jnp.stack([excess * gc for gc in self.g])


__all__ = ["RelativeGravity"]
