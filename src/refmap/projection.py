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
holds at every t, unless an ``outflow`` segment takes up the difference), and
``outflow``: on the edge's row of nodes the pressure is zero (Dirichlet) and that row's
divergence is not constrained -- the normal face velocity beyond it is whatever closes the
row's continuity equation, so the fluid leaves at the rate the flow brings it.  Formally
the unknowns and equations of those nodes are removed (``keep = 0``: ``B`` is ``keep *
D``, ``G = -B^T`` reads ``keep * p``, and the operator is the identity there), so ``A``
stays symmetric, and with any outflow node it is definite: no constant null space, no
balance needed.  The velocity on a low outflow row (left, bottom) is then free and not
corrected (its continuity row is gone); the next row's correction reads the zero
pressure.  ``divergence`` reports zero on the outflow rows.

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
    prescribed normal velocities do not balance and no ``outflow`` segment takes up the
    difference (no divergence-free field would meet them)."""
    groups: dict = {}
    scale = 0.0
    for name in ("left", "right", "bottom", "top"):
        edge = getattr(boundary, name)
        if edge == "periodic":
            continue
        axis = _AXIS[name]
        for seg in edge:
            if seg.kind == "outflow":
                return  # the outflow takes up any net flux
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
    s_along = (
        (yn - grid.ay) / (grid.by - grid.ay) if axis == 0 else (xn - grid.ax) / (grid.bx - grid.ax)
    )
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


def _outflow_nodes(name, edge, grid):
    """(n,) bool: the nodes along an edge that lie on an ``outflow`` segment."""
    axis = _AXIS[name]
    xn, yn = grid.axes("node")
    s_along = np.asarray(
        (yn - grid.ay) / (grid.by - grid.ay) if axis == 0 else (xn - grid.ax) / (grid.bx - grid.ax)
    )
    out = np.zeros(s_along.shape, dtype=bool)
    for seg in edge:
        if seg.kind == "outflow":
            m = (s_along >= seg.start) & (s_along < seg.end)
            if seg.end >= 1.0:
                m |= s_along >= 1.0
            out |= m
    return out


class Projection:
    """The pressure projection for one :class:`refmap.model.Model` (built once)."""

    def __init__(
        self, model, rtol: float = 1e-10, maxiter: int = 500, preconditioner: str = "fast"
    ):
        if preconditioner not in ("fast", "jacobi"):
            raise ValueError(
                f"pressure preconditioner must be 'fast' or 'jacobi', got {preconditioner!r}"
            )
        g = model.grid
        check_boundary(model.boundary, g)
        self.grid = g
        self.boundary = model.boundary
        self.periodic = model.bc.periodic
        self.rtol = float(rtol)
        self.maxiter = int(maxiter)
        self.preconditioner_kind = preconditioner
        out = {
            name: _outflow_nodes(name, getattr(model.boundary, name), g)
            for name in _AXIS
            if getattr(model.boundary, name) != "periodic"
        }
        self.outflow = out
        mask = np.ones((2, g.nx, g.ny))
        keep = np.ones((g.nx, g.ny))
        if not self.periodic[0]:
            # the left face's normal velocity: prescribed, except on an outflow (free)
            mask[0, 0, :] = out["left"]
            keep[0, out["left"]] = 0.0
            keep[-1, out["right"]] = 0.0
        if not self.periodic[1]:
            mask[1, :, 0] = out["bottom"]
            keep[out["bottom"], 0] = 0.0
            keep[out["top"], -1] = 0.0
        self.mask = mask
        self.has_outflow = bool(np.any(keep == 0.0))
        self.keep = keep

        # the fast preconditioner: Neumann (even) at an edge, Dirichlet (odd: zero half a
        # cell beyond the row where the operator has it on the row) where the whole edge is
        # an outflow
        def kind(name):
            o = out.get(name)
            return "odd" if o is not None and o.all() else "even"

        kinds = tuple(
            "periodic" if p else (kind(lo), kind(hi))
            for p, (lo, hi) in zip(
                self.periodic, (("left", "right"), ("bottom", "top")), strict=True
            )
        )
        self.fast = SeparableSolver(g.nx, g.ny, g.dx, g.dy, kinds)
        self.fast_definite = any(k != "periodic" and "odd" in k for k in kinds)

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
            face = jnp.where(self.outflow["left"], v[0, 0, :], self._edge("left", t))
            out = out.at[0, 0, :].set(face)
        if not self.periodic[1]:
            face = jnp.where(self.outflow["bottom"], v[1, :, 0], self._edge("bottom", t))
            out = out.at[1, :, 0].set(face)
        return out

    def divergence(self, v, t):
        """The discrete divergence D v (nx, ny) the projection zeroes, edge data at t (zero
        on outflow rows, whose continuity equation the outgoing face velocity closes)."""
        v = self.prescribe(v, t)
        hi_u = None if self.periodic[0] else self._edge("right", t)
        hi_v = None if self.periodic[1] else self._edge("top", t)
        return self._div(v, hi_u, hi_v) * self.keep

    def B(self, w):
        """The linear part of D on the free velocity components (zero edge data)."""
        g = self.grid
        zu = None if self.periodic[0] else jnp.zeros(g.ny)
        zv = None if self.periodic[1] else jnp.zeros(g.nx)
        return self._div(w * self.mask, zu, zv) * self.keep

    def BT(self, p):
        """B^T p (2, nx, ny); ``-B^T`` is the pressure gradient G."""
        tmpl = jax.ShapeDtypeStruct((2,) + p.shape, p.dtype)
        return jax.linear_transpose(self.B, tmpl)(p)[0]

    def gradient(self, p):
        """The discrete pressure gradient G p = -B^T p at the free velocity components."""
        return -self.BT(p)

    def _row_sums(self, weight):
        """Per continuity row (node i, j), the sums of ``weight`` over the free velocity
        components it reads: u at i and i + 1, v at j and j + 1 (zero beyond a wall)."""
        g = self.grid
        wu = weight * self.mask[0]
        wv = weight * self.mask[1]
        if self.periodic[0]:
            ux = wu + jnp.roll(wu, -1, axis=0)
        else:
            ux = wu + jnp.concatenate([wu[1:], jnp.zeros((1, g.ny))], axis=0)
        if self.periodic[1]:
            vy = wv + jnp.roll(wv, -1, axis=1)
        else:
            vy = wv + jnp.concatenate([wv[:, 1:], jnp.zeros((g.nx, 1))], axis=1)
        return ux, vy

    def moving_rows(self, weight):
        """(nx, ny) 0/1: the continuity rows with at least one velocity component that the
        correction moves (``weight > 0`` and not prescribed)."""
        ux, vy = self._row_sums(weight)
        return (ux + vy > 0).astype(jnp.float64)

    def operator(self, rho, weight=None):
        """``A = B W rho^-1 B^T`` plus ``s P0`` on the constants (SPD on the velocities
        it moves); ``W`` (default 1) the weight of the pressure correction per node."""
        inv = 1.0 / rho
        s = jax.lax.stop_gradient(jnp.mean(inv)) * (2.0 / self.grid.dx**2 + 2.0 / self.grid.dy**2)
        if weight is not None:
            inv = inv * weight

        if self.has_outflow:  # definite: the outflow rows' identity instead of s P0
            drop = 1.0 - self.keep

            def A(p):
                return self.B(inv[None] * self.BT(p)) + drop * p

            return A, s

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

            if not self.has_outflow:
                return P
            keep, drop = self.keep, 1.0 - self.keep
            if self.fast_definite:
                return lambda r: keep * self.fast.solve(keep * r, 0.0, c, c) + drop * r
            return lambda r: keep * P(keep * r) + drop * r
        # the diagonal of B rho^-1 B^T: each node sees the free u at i and i + 1, v at j, j + 1
        ux, vy = self._row_sums(inv)
        if self.has_outflow:
            diag = (ux / g.dx**2 + vy / g.dy**2) * self.keep + (1.0 - self.keep)
        else:
            diag = ux / g.dx**2 + vy / g.dy**2 + sg(s) / (g.nx * g.ny)
        return lambda r: r / diag

    # ------------------------------------------------------------------ the projection
    def project(self, v_star, rho, t_new, dt, weight=None, return_info=False, source=None):
        """The divergence-free ``v = v* - dt W rho^-1 G p`` (edge data at t_new).

        ``weight`` (nx, ny), default 1: how much of the correction each node takes; the
        anchors' nodes (:meth:`refmap.model.Model.step`) take ``1 - w_anchor``, so an
        anchor's velocity, applied to v* before, is kept where it holds fully.  ``source``
        (nx, ny), default 0: the divergence to impose instead, ``D v = source`` (the solids'
        volume correction, :meth:`refmap.model.Model.volume_source`); without an outflow
        edge it must sum to zero (its mean is removed).  With ``return_info`` also
        ``(p, info)`` (then not differentiable: plain CG)."""
        v_b = self.prescribe(v_star, t_new)
        b = self.divergence(v_b, t_new)
        if source is not None:
            if weight is not None:
                # no velocity of a fully held row moves (an anchor's interior): its row of A
                # is zero and a source there would make the system inconsistent (CG
                # diverged on the Turek--Hron channel at 4 cells across the flag, where
                # the held body's J is 1 to round-off)
                source = source * self.moving_rows(weight)
            b = b - source * self.keep
        if self.has_outflow:
            rhs = -b / dt  # zero on the outflow rows (b is)
        else:
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
