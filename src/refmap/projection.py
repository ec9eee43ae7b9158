"""Incompressible fluid by projection: ``Numerics.fluid_model = "incompressible"``.

The step predicts ``v*`` from every term but the fluid pressure (advection, the blended
stress divergence with the solid stress and the fluid viscosity, extra viscosity, body
forces, gravity; the fluid density is held at ``rho0``, so ``lambda_f (rho_f / rho0 - 1)``
is zero), then projects it:

    v = v* - dt rho^-1 G p,     D v = 0,    i.e.   (D rho^-1 G) p = D v* / dt,

with ``rho`` the blended node density (fluid and solids).

Discretisation.  The pressure ``p`` lives on the nodes; as in the compressible model it is
the pressure of each node's top-right corner (the corner pressure is taken from its
bottom-left node), so the pressure force on a node is ``div_node`` of that corner
pressure, the backward difference ``G p = ((p[i] - p[i-1]) / dx, (p[j] - p[j-1]) / dy)``.
The divergence ``D`` is the one of ``Numerics.compression = "corner"``: ``grad_corner``'s
divergence at the node's top-right corner, the forward difference
``(u[i+1] - u[i]) / dx + (v[j+1] - v[j]) / dy``.  In the interior ``D = -G^T`` exactly, and
the code *builds* ``G`` as ``-B^T`` (``B`` the linear part of ``D``, transposed by
``jax.linear_transpose``), so ``A = B rho^-1 B^T = -D rho^-1 G`` is symmetric positive
semi-definite whatever the edges, and after the solve ``D v = 0`` holds to the solver's
residual.  For uniform rho ``A`` is the five-point Laplacian (compact, the MAC scheme's
in disguise: ``u[i]`` plays the face velocity between ``p[i-1]`` and ``p[i]``), whose null
space is the constants alone: there is no checkerboard mode (tested on a dense matrix).

Edges.  The velocity a divergence needs beyond the grid is a normal component on a face:
at a low edge (left, bottom) the first node's normal velocity is the face's (it is set to
the edge's normal velocity and not corrected); at a high edge (right, top) the ghost face
value is the edge's normal velocity.  Then every pressure condition is homogeneous
Neumann, the null space is the constants, and the solve needs the boundary fluxes to
balance (checked when the model is built).  Supported: periodic pairs, ``wall`` (no-slip,
moving tangentially), ``slip``, ``velocity`` (inflow or prescribed outflow, any profile;
segments whose normal velocity is not zero must share one ramp and omega so the balance
holds at every t).  Refused (ValueError naming the edge): ``outflow`` segments.

Solver.  ``A + s P0`` (P0 the projector onto the constants, s a fixed scale) is SPD with
the same solution for the compatible (mean-free) right-hand side; it is solved by
preconditioned conjugate gradients inside ``lax.custom_linear_solve``
(:func:`refmap.linsolve.solve_spd`), so derivatives are one more solve, not the
iterations.  Preconditioner: the exact fast inverse of the constant-coefficient operator
``mean(1/rho) (-Dxx - Dyy)`` (``"fast"``, FFT on periodic axes, DCT-II on the others:
exact for uniform density), or the diagonal (``"jacobi"``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from refmap.boundary import _waveform
from refmap.linsolve import SeparableSolver, cg, solve_spd

_HIGH = {"left": False, "right": True, "bottom": False, "top": True}
_AXIS = {"left": 0, "right": 0, "bottom": 1, "top": 1}


def _is_number(x) -> bool:
    return isinstance(x, (int, float, np.floating, np.integer))


def check_boundary(boundary, grid) -> None:
    """Raise ValueError for edge conditions the projection does not support, and when the
    prescribed normal velocities do not balance (no divergence-free field would meet them)."""
    groups: dict = {}
    scale = 0.0
    for name in ("left", "right", "bottom", "top"):
        edge = getattr(boundary, name)
        if edge == "periodic":
            continue
        axis = _AXIS[name]
        for seg in edge:
            if seg.kind == "outflow":
                raise ValueError(
                    f"fluid_model 'incompressible' does not support boundary kind 'outflow' "
                    f"(edge {name!r}, segment [{seg.start:g}, {seg.end:g})); use a 'velocity' "
                    "segment with the outflow's velocity (the fluxes must balance), 'wall', "
                    "'slip' or 'periodic', or fluid_model = 'compressible'"
                )
            if seg.kind == "slip":
                continue
            un = seg.velocity[axis]
            if not _is_number(un):
                return  # traced boundary data: nothing to check statically
            if un == 0.0:
                continue
            flux = _face_values(name, (seg,), grid, 0.0, waveform=False).sum()
            flux *= grid.dy if axis == 0 else grid.dx
            sign = -1.0 if _HIGH[name] else 1.0  # inflow positive
            key = (seg.ramp, seg.omega)
            groups[key] = groups.get(key, 0.0) + sign * float(flux)
            scale += abs(float(flux))
    if len(groups) > 1:
        raise ValueError(
            "fluid_model 'incompressible': boundary segments with a normal velocity must share "
            f"one ramp and omega (the fluxes must balance at every t), got {sorted(groups, key=str)}"
        )
    for net in groups.values():
        if abs(net) > 1e-9 * max(scale, 1e-300):
            raise ValueError(
                "fluid_model 'incompressible': the prescribed normal velocities do not balance: "
                f"net inflow {net:.6g} (of {scale:.6g} through the edges); an incompressible "
                "fluid in this box needs a net flux of zero"
            )


def _face_values(name, edge, grid, t, waveform=True):
    """The normal velocity on the edge's faces (one value per node along it) at time t."""
    axis = _AXIS[name]
    xn, yn = grid.axes("node")
    s_along = (yn - grid.ay) / (grid.by - grid.ay) if axis == 0 else (xn - grid.ax) / (grid.bx - grid.ax)
    out = jnp.zeros(s_along.shape)
    for seg in edge:
        if seg.kind not in ("wall", "velocity"):
            continue
        m = (s_along >= seg.start) & (s_along < seg.end)
        if seg.end >= 1.0:
            m |= s_along >= 1.0
        prof = np.ones_like(s_along)
        if seg.profile == "parabolic":
            s = (s_along - seg.start) / (seg.end - seg.start)
            prof = 4.0 * s * (1.0 - s)
        val = jnp.where(jnp.asarray(m), seg.velocity[axis] * prof, 0.0)
        out = out + (val * _waveform(seg, t) if waveform else val)
    return np.asarray(out) if not waveform else out


class Projection:
    """The pressure projection for one :class:`refmap.model.Model` (built once)."""

    def __init__(self, model, rtol: float = 1e-10, maxiter: int = 500, preconditioner: str = "fast"):
        if preconditioner not in ("fast", "jacobi"):
            raise ValueError(f"pressure preconditioner must be 'fast' or 'jacobi', got {preconditioner!r}")
        g = model.grid
        check_boundary(model.boundary, g)
        self.grid = g
        self.boundary = model.boundary
        self.periodic = model.bc.periodic
        self.rtol = float(rtol)
        self.maxiter = int(maxiter)
        self.preconditioner_kind = preconditioner
        mask = np.ones((2, g.nx, g.ny))
        if not self.periodic[0]:
            mask[0, 0, :] = 0.0  # the left face's normal velocity: prescribed
        if not self.periodic[1]:
            mask[1, :, 0] = 0.0
        self.mask = mask
        kinds = tuple("periodic" if p else ("even", "even") for p in self.periodic)
        self.fast = SeparableSolver(g.nx, g.ny, g.dx, g.dy, kinds)

    # ------------------------------------------------------------------ operators
    def _edge(self, name, t):
        return _face_values(name, getattr(self.boundary, name), self.grid, t)

    def _div(self, v, hi_u, hi_v):
        """Forward-difference divergence with the given high-edge face values (None: wrap)."""
        g = self.grid
        u, w = v[0], v[1]
        up = jnp.concatenate([u[1:], u[:1] if hi_u is None else hi_u[None, :]], axis=0)
        wp = jnp.concatenate([w[:, 1:], w[:, :1] if hi_v is None else hi_v[:, None]], axis=1)
        return (up - u) / g.dx + (wp - w) / g.dy

    def prescribe(self, v, t):
        """``v`` with the low edges' normal components set to the edges' normal velocity."""
        out = v
        if not self.periodic[0]:
            out = out.at[0, 0, :].set(self._edge("left", t))
        if not self.periodic[1]:
            out = out.at[1, :, 0].set(self._edge("bottom", t))
        return out

    def divergence(self, v, t):
        """The discrete divergence D v (nx, ny) the projection zeroes, edge data at t."""
        v = self.prescribe(v, t)
        hi_u = None if self.periodic[0] else self._edge("right", t)
        hi_v = None if self.periodic[1] else self._edge("top", t)
        return self._div(v, hi_u, hi_v)

    def B(self, w):
        """The linear part of D on the free velocity components (zero edge data)."""
        g = self.grid
        zu = None if self.periodic[0] else jnp.zeros(g.ny)
        zv = None if self.periodic[1] else jnp.zeros(g.nx)
        return self._div(w * self.mask, zu, zv)

    def BT(self, p):
        """B^T p (2, nx, ny); ``-B^T`` is the pressure gradient G."""
        tmpl = jax.ShapeDtypeStruct((2,) + p.shape, p.dtype)
        return jax.linear_transpose(self.B, tmpl)(p)[0]

    def gradient(self, p):
        """The discrete pressure gradient G p = -B^T p at the free velocity components."""
        return -self.BT(p)

    def operator(self, rho, weight=None):
        """``A = B W rho^-1 B^T`` plus ``s P0`` on the constants (SPD on the velocities
        it moves); ``W`` (default 1) the weight of the pressure correction per node."""
        inv = 1.0 / rho
        s = jax.lax.stop_gradient(jnp.mean(inv)) * (2.0 / self.grid.dx**2 + 2.0 / self.grid.dy**2)
        if weight is not None:
            inv = inv * weight

        def A(p):
            return self.B(inv[None] * self.BT(p)) + s * jnp.mean(p)

        return A, s

    def preconditioner(self, rho, s, weight=None):
        sg = jax.lax.stop_gradient
        g = self.grid
        inv = sg(1.0 / rho)
        if weight is not None:
            inv = inv * weight
        if self.preconditioner_kind == "fast":
            c = jnp.mean(inv)
            s0 = sg(s)

            def P(r):
                # the constants are A's eigenvector with eigenvalue s; the rest is the
                # constant-coefficient Laplacian's pseudo-inverse
                mean = jnp.mean(r)
                return self.fast.solve_semidefinite(r - mean, c, c) + mean / s0

            return P
        # the diagonal of B rho^-1 B^T: each node sees the free u at i and i + 1, v at j, j + 1
        wu = inv * self.mask[0]
        wv = inv * self.mask[1]
        if self.periodic[0]:
            ux = wu + jnp.roll(wu, -1, axis=0)
        else:
            ux = wu + jnp.concatenate([wu[1:], jnp.zeros((1, g.ny))], axis=0)
        if self.periodic[1]:
            vy = wv + jnp.roll(wv, -1, axis=1)
        else:
            vy = wv + jnp.concatenate([wv[:, 1:], jnp.zeros((g.nx, 1))], axis=1)
        diag = ux / g.dx**2 + vy / g.dy**2 + sg(s) / (g.nx * g.ny)
        return lambda r: r / diag

    # ------------------------------------------------------------------ the projection
    def project(self, v_star, rho, t_new, dt, weight=None, return_info=False):
        """The divergence-free ``v = v* - dt W rho^-1 G p`` (edge data at t_new).

        ``weight`` (nx, ny), default 1: how much of the correction each node takes; the
        anchors' nodes (:meth:`refmap.model.Model.step`) take ``1 - w_anchor``, so an
        anchor's velocity, applied to v* before, is kept where it holds fully.  With
        ``return_info`` also ``(p, info)`` (then not differentiable: plain CG)."""
        v_b = self.prescribe(v_star, t_new)
        b = self.divergence(v_b, t_new)
        rhs = -(b - jnp.mean(b)) / dt  # compatible: the fluxes balance (checked), round-off
        A, s = self.operator(rho, weight)
        P = self.preconditioner(rho, s, weight)
        atol = 1e-14 * jax.lax.stop_gradient(jnp.sqrt(jnp.sum(v_b**2)) / (dt * self.grid.h))
        kw = dict(precond=P, rtol=self.rtol, atol=atol, maxiter=self.maxiter)
        if return_info:
            p, info = cg(A, rhs, **kw)
        else:
            p = solve_spd(A, rhs, **kw)
        inv = 1.0 / rho if weight is None else weight / rho
        v = v_b + dt * self.BT(p) * inv[None]
        if return_info:
            return v, p, info
        return v


__all__ = ["Projection", "check_boundary"]
