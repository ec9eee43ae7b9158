"""Implicit (backward Euler) viscous step: ``Numerics.viscosity = "implicit"``.

The explicit step adds ``dt / rho`` times the viscous force

    f(v) = div_node(w_f tau(v)) + e lap(v),
    tau(v) = eta sym(grad_corner v) + zeta (tr grad_corner v) I,

(``eta`` the fluid's viscosity in the thesis's convention, ``zeta`` the bulk viscosity,
``e`` the extra viscosity, ``w_f`` the fluid fraction at the corners) to the velocity; its
stability limit ``h^2 rho / (4 (eta + e + zeta))`` binds on fine grids.  The implicit step
takes the same discrete operator at the new time level instead:

    rho (v^{n+1} - v*) = dt f(v^{n+1}),

with ``v*`` the velocity after every other (explicit) term and ``f``'s ghost values (walls,
moving lids, inflow profiles) taken at ``t + dt``.  The ghosts of every edge condition are
affine in the velocity, the first ghost layer a reflection of the node next to the edge
(``-v_0 + 2 U`` at walls and prescribed velocities, ``+-v_0`` at slip walls, ``v_0`` at
outflows), so ``f(v) = D v + b(t)`` with ``D`` linear (applied as the tangent of f) and
``b`` the boundary data, and

    (rho - dt D) delta = dt f(v*),    v^{n+1} = v* + delta.

``D`` is ``-G^T C G`` (G the corner gradient, C the pointwise stress law ``w_f (eta,
zeta)``) on periodic axes: symmetric negative semi-definite, solved by conjugate
gradients.  At other edges the ghost reflections enter the u-v coupling one-sidedly and
``D`` is not symmetric (tested against a dense Jacobian): BiCGSTAB.  Both are wrapped in
``custom_linear_solve`` (:mod:`refmap.linsolve`; derivatives by implicit
differentiation).  Preconditioner: the operator's diagonal (``"jacobi"``, default) or the
exact fast solve of the constant-coefficient ``rho_m - dt (a_x Dxx + a_y Dyy)`` for each
velocity component (``"fast"``, :class:`refmap.linsolve.SeparableSolver`: FFT / DCT / DST
per the edges' reflections; an edge with several kinds of segment takes the kind that
covers most of it).  docs/method.md, "Implicit viscosity", has the measurements.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from refmap.boundary import AXIS_FACES
from refmap.linsolve import SeparableSolver, bicgstab, cg, solve_general, solve_spd
from refmap.operators import SYM_PAIRS, div_node, grad_corner, laplacian


def viscous_force(model, v, t, fluid, wf_c):
    """The fluid viscous force f(v) (d, nx, ny[, nz]) with ghost values at time ``t``: the
    divergence of ``w_f (eta sym(grad v) + zeta div(v) I)`` plus ``e lap(v)``, exactly the
    viscous part of the explicit step."""
    g = model.grid
    if getattr(model, "ndim", 2) == 3:
        return _viscous_force_3d(model, v, t, fluid, wf_c)
    vp = model.bc.pad_velocity(v, t)
    vp1 = vp[:, 1:-1, 1:-1]
    ux, uy = grad_corner(vp1[0], g.dx, g.dy)
    vx, vy = grad_corner(vp1[1], g.dx, g.dy)
    bulk = fluid.bulk_viscosity * (ux + vy)
    sxx = wf_c * (fluid.eta * ux + bulk)
    sxy = wf_c * (0.5 * fluid.eta * (uy + vx))
    syy = wf_c * (fluid.eta * vy + bulk)
    return div_node(sxx, sxy, syy, g.dx, g.dy) + fluid.extra_viscosity * laplacian(vp, g.dx, g.dy, g=2)


def _viscous_force_3d(model, v, t, fluid, wf_c):
    """:func:`viscous_force` on a 3D grid (the 2D arithmetic with a third axis)."""
    sp = model.spacing
    vp = model.bc.pad_velocity(v, t)
    vp1 = vp[:, 1:-1, 1:-1, 1:-1]
    dv = [grad_corner(vp1[a], *sp) for a in range(3)]  # dv[a][b] = d v_a / d x_b
    bulk = fluid.bulk_viscosity * (dv[0][0] + dv[1][1] + dv[2][2])
    comps = [
        wf_c * (fluid.eta * dv[a][a] + bulk) if a == b else wf_c * (0.5 * fluid.eta * (dv[a][b] + dv[b][a]))
        for a, b in SYM_PAIRS[3]
    ]
    return div_node(*comps, *sp) + fluid.extra_viscosity * laplacian(vp, *sp, g=2)


def _edge_kind(edge, component: int, normal_axis: int) -> str:
    """'odd' or 'even': the first-ghost reflection of one velocity component on one edge
    (the kind covering most of the edge when its segments differ)."""
    odd = 0.0
    for seg in edge:
        if seg.kind in ("wall", "velocity"):
            is_odd = True
        elif seg.kind == "slip":
            is_odd = component == normal_axis
        else:  # outflow: zero gradient
            is_odd = False
        odd += (seg.end - seg.start) if is_odd else 0.0
    return "odd" if odd >= 0.5 else "even"


def axis_kinds(boundary, component: int):
    """Per axis the :class:`SeparableSolver` kind for one velocity component."""
    out = []
    for axis, (lo, hi) in enumerate(AXIS_FACES[: boundary.ndim]):
        e_lo, e_hi = getattr(boundary, lo), getattr(boundary, hi)
        if e_lo == "periodic":
            out.append("periodic")
        else:
            out.append((_edge_kind(e_lo, component, axis), _edge_kind(e_hi, component, axis)))
    return tuple(out)


class ImplicitViscosity:
    """The backward-Euler viscous solve for one :class:`refmap.model.Model` (built once)."""

    def __init__(self, model, rtol: float = 1e-6, maxiter: int = 200, preconditioner: str = "jacobi"):
        g = model.grid
        if preconditioner not in ("jacobi", "fast"):
            raise ValueError(f"preconditioner must be 'jacobi' or 'fast', got {preconditioner!r}")
        self.preconditioner_kind = preconditioner
        self.model = model
        self.rtol = float(rtol)
        self.maxiter = int(maxiter)
        self.ndim = getattr(model, "ndim", 2)
        self.fast = tuple(
            SeparableSolver.on_grid(g, axis_kinds(model.boundary, c)) for c in range(self.ndim)
        )
        # the corner-stress operator is symmetric on periodic axes; at edges the ghost
        # reflections enter its u-v coupling asymmetrically (tested), so BiCGSTAB there
        self.symmetric = all(model.bc.periodic)

    def operator(self, rho, wf_c, fluid, t, dt):
        """The linear map ``x -> rho x - dt D x`` (D the linear part of f, no boundary data)."""
        zero = jnp.zeros((self.ndim,) + rho.shape, dtype=rho.dtype)

        def D(x):
            return jax.jvp(lambda v: viscous_force(self.model, v, t, fluid, wf_c), (zero,), (x,))[1]

        return lambda x: rho[None] * x - dt * D(x)

    def preconditioner(self, rho, wf_c, fluid, dt):
        """An SPD approximation of the operator's inverse (no derivatives flow through it).

        ``"jacobi"``: division by the operator's diagonal away from the edges,
        ``rho + dt (c_x / dx^2 + c_y / dy^2)`` with the corner weights of each node's stencil.
        ``"fast"``: per velocity component the exact inverse of the constant-coefficient
        ``rho_m - dt (a_x Dxx + a_y Dyy [+ a_z Dzz])`` (rho_m the mean density, a's from the mean fluid
        fraction; :class:`refmap.linsolve.SeparableSolver`)."""
        sg = jax.lax.stop_gradient
        g = self.model.grid
        rho, wf_c, dt = sg(rho), sg(wf_c), sg(dt)
        eta, zeta, e = (sg(jnp.asarray(a)) for a in (fluid.eta, fluid.bulk_viscosity, fluid.extra_viscosity))
        if self.preconditioner_kind == "jacobi" and self.ndim == 3:
            return self._jacobi_3d(rho, wf_c, eta, zeta, e, dt)
        if self.preconditioner_kind == "jacobi":
            # node (i, j)'s stencil: d/dx through its top corners TL, TR; d/dy through TR, BR
            wx = wf_c[:-1, 1:] + wf_c[1:, 1:]
            wy = wf_c[1:, :-1] + wf_c[1:, 1:]
            lap = 2.0 * e * (1.0 / g.dx**2 + 1.0 / g.dy**2)
            du = rho + dt * ((eta + zeta) * wx / g.dx**2 + 0.5 * eta * wy / g.dy**2 + lap)
            dv = rho + dt * (0.5 * eta * wx / g.dx**2 + (eta + zeta) * wy / g.dy**2 + lap)
            inv = 1.0 / jnp.stack([du, dv])
            return lambda r: r * inv
        rho_m = jnp.mean(rho)
        wf = jnp.mean(wf_c)
        normal = e + wf * (eta + zeta)  # d/dx of u, d/dy of v
        shear = e + wf * 0.5 * eta

        def P(r):
            # component c: the normal coefficient along its own axis, shear along the others
            return jnp.stack([
                self.fast[c].solve(r[c], rho_m, *(dt * (normal if a == c else shear) for a in range(self.ndim)))
                for c in range(self.ndim)
            ])

        return P

    def _jacobi_3d(self, rho, wf_c, eta, zeta, e, dt):
        """The operator's diagonal in 3D: the x_a-derivatives of a node's own value enter
        through its top corner TR and TR - e_a, so the weight along axis a is
        ``w_f[TR] + w_f[TR - e_a]``; component c has ``eta + zeta`` along its own axis and
        ``eta / 2`` along the others (as the 2D ``wx``, ``wy``)."""
        h = self.model.spacing
        top = (slice(1, None),) * 3
        w = []
        for a in range(3):
            lower = tuple(slice(None, -1) if b == a else slice(1, None) for b in range(3))
            w.append(wf_c[top] + wf_c[lower])
        lap = 2.0 * e * sum(1.0 / ha**2 for ha in h)
        diag = []
        for c in range(3):
            acc = rho + dt * lap
            for a in range(3):
                coef = (eta + zeta) if a == c else 0.5 * eta
                acc = acc + dt * coef * w[a] / h[a] ** 2
            diag.append(acc)
        inv = 1.0 / jnp.stack(diag)
        return lambda r: r * inv

    def solve(self, v_star, rho, wf_c, fluid, t_new, dt, return_info=False, guess=None,
              free=None):
        """``v^{n+1}`` from ``rho (v^{n+1} - v*) = dt f(v^{n+1})``, boundary data at t_new.

        Conjugate gradients where the operator is symmetric (both axes periodic), BiCGSTAB
        otherwise.  With ``return_info`` also the solver's dict(iterations, residual,
        converged) (then not differentiable).  ``guess``: a first iterate for the increment
        ``v^{n+1} - v*`` (:meth:`refmap.model.Model.advance` extrapolates it from the last
        two steps); the solve stops at the same residual whatever the guess, so the answer
        changes only within ``rtol`` and the iterations fall with a good guess.

        ``free``: a node weight (nx, ny[, nz]), or one per component (d, nx, ny[, nz]), 0 where
        the velocity is held (an anchor's region, the normal components that an
        incompressible fluid's projection prescribes on its edges: ``v*`` already holds the
        held value there) and 1 elsewhere.
        The increment is then 0 on the held nodes and the free nodes' viscous force sees the
        held velocity, as the explicit step's does: the system is ``f A (f x) + (1 - f^2)
        rho x = f b`` (symmetric where A is)."""
        A = self.operator(rho, wf_c, fluid, t_new, dt)
        rhs = dt * viscous_force(self.model, v_star, t_new, fluid, wf_c)
        if free is not None:
            f = jnp.asarray(free)
            f = f if f.ndim == v_star.ndim else f[None]
            A_full = A
            rest = (1.0 - f * f) * rho[None]

            def A(x):
                return f * A_full(f * x) + rest * x

            rhs = f * rhs
        P = self.preconditioner(rho, wf_c, fluid, dt)
        # an absolute floor (1e-14 of rho v*): a step whose viscous correction vanishes (a
        # fluid at rest) must not chase round-off
        atol = 1e-14 * jax.lax.stop_gradient(jnp.sqrt(jnp.sum((rho[None] * v_star) ** 2)))
        kw = dict(precond=P, rtol=self.rtol, atol=atol, maxiter=self.maxiter)
        if return_info:
            delta, info = (cg if self.symmetric else bicgstab)(A, rhs, x0=guess, **kw)
            return v_star + delta, info
        delta = (solve_spd if self.symmetric else solve_general)(A, rhs, x0=guess, **kw)
        return v_star + delta


__all__ = ["ImplicitViscosity", "viscous_force", "axis_kinds"]
