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
exact for uniform density), the diagonal (``"jacobi"``), or a multigrid V-cycle on ``A``'s
own face coefficients ``W / rho`` (``"multigrid"``, :mod:`refmap.multigrid`): it sees
what the fast one does not, a held anchor (zero coefficients: an obstacle inside the box)
and density jumps, and takes about 10 iterations whatever the grid and the case.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from refmap.boundary import AXIS_FACES, _waveform
from refmap.linsolve import SeparableSolver, cg, solve_spd
from refmap.multigrid import Hierarchy, face_diagonal, vcycle

#: the preconditioners :class:`Projection` takes (``Numerics.pressure_preconditioner`` also
#: takes ``"auto"``, :func:`resolve_preconditioner`)
PRECONDITIONERS = ("fast", "jacobi", "multigrid")


def resolve_preconditioner(choice: str, solids) -> str:
    """The preconditioner for ``Numerics.pressure_preconditioner = choice``: ``"auto"``
    takes ``"multigrid"`` when any solid has an anchor, else ``"fast"``; any other value is
    kept.

    Why (docs/validation_incompressible.md, "Preconditioners"; one core): an anchor's held
    nodes are an obstacle inside the box, which the constant-coefficient fast solve does
    not see, so CG needs 26 (two_balls, one ball held) to 103 (rotor) iterations with it,
    against 10-12 with the cycle (step 1.5x to 6.1x faster at 128^2). Without an anchor the
    fast solve is nearly exact wherever the density is nearly uniform (circle at 128^2: 4
    iterations, 1.2x faster than the cycle's 9; the 3D sphere_cavity: 2 against 12,
    1.5-1.7x faster). Many free bodies of two densities fall in between (the 100-disc
    suspension at 64^2: fast 14 iterations, the cycle 9, the same step time)."""
    if choice != "auto":
        return choice
    return "multigrid" if any(getattr(s, "anchor", None) is not None for s in solids) else "fast"

_HIGH = {"left": False, "right": True, "bottom": False, "top": True, "back": False, "front": True}
_AXIS = {"left": 0, "right": 0, "bottom": 1, "top": 1, "back": 2, "front": 2}


def _faces(ndim):
    """The face names of a ``ndim``-D box, low before high, axis by axis."""
    return [name for pair in AXIS_FACES[:ndim] for name in pair]


def _face_area(grid, axis):
    """The area (2D: length) per node of a face normal to ``axis``."""
    out = 1.0
    for a, h in enumerate(grid.spacing):
        if a != axis:
            out *= h
    return out


def _is_number(x) -> bool:
    return isinstance(x, (int, float, np.floating, np.integer))


def check_boundary(boundary, grid) -> None:
    """Raise ValueError for edge conditions the projection does not support, and when the
    prescribed normal velocities do not balance and no ``outflow`` segment takes up the
    difference (no divergence-free field would meet them)."""
    groups: dict = {}
    scale = 0.0
    for name in _faces(grid.ndim):
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
            flux *= _face_area(grid, axis)
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


def _along(name, grid):
    """The positions s in [0, 1] of the face's nodes along its tangential axes: one (n,)
    array per tangential axis (one in 2D, two in 3D), broadcast to the face's shape."""
    axis = _AXIS[name]
    axes = grid.axes("node")
    lows, highs = grid.lows, grid.highs
    tang = [a for a in range(grid.ndim) if a != axis]
    out = []
    for k, a in enumerate(tang):
        s = (axes[a] - lows[a]) / (highs[a] - lows[a])
        shape = [1] * len(tang)
        shape[k] = -1
        out.append(np.asarray(s).reshape(shape))
    return out


def _face_values(name, edge, grid, t, waveform=True):
    """The normal velocity on the edge's faces (one value per node along it, 2D; per node
    of the face, 3D) at time t."""
    axis = _AXIS[name]
    if grid.ndim == 2:
        (s_along,) = _along(name, grid)
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
    # 3D: whole-face segments (Boundary refuses others); "parabolic" is the product of the
    # parabolas across the two tangential axes, as in refmap.boundary
    s1, s2 = _along(name, grid)
    shape = np.broadcast_shapes(s1.shape, s2.shape)
    out = jnp.zeros(shape)
    for seg in edge:
        if seg.kind not in ("wall", "velocity"):
            continue
        prof = np.ones(shape)
        if seg.profile == "parabolic":
            prof = 16.0 * s1 * (1.0 - s1) * s2 * (1.0 - s2)
        val = jnp.asarray(seg.velocity[axis] * prof)
        out = out + (val * _waveform(seg, t) if waveform else val)
    return np.asarray(out) if not waveform else out


def _outflow_nodes(name, edge, grid):
    """(n,) bool (2D) or the face's shape (3D): the nodes of a face on an ``outflow``
    segment."""
    if grid.ndim == 3:  # whole-face segments
        s1, s2 = _along(name, grid)
        shape = np.broadcast_shapes(s1.shape, s2.shape)
        return np.full(shape, any(seg.kind == "outflow" for seg in edge))
    (s_along,) = _along(name, grid)
    out = np.zeros(s_along.shape, dtype=bool)
    for seg in edge:
        if seg.kind == "outflow":
            m = (s_along >= seg.start) & (s_along < seg.end)
            if seg.end >= 1.0:
                m |= s_along >= 1.0
            out |= m
    return out


def _index(ndim, axis, i):
    """The index tuple taking ``i`` (an int or a slice) along ``axis`` of an ``ndim``-D
    array and everything along the others."""
    idx = [slice(None)] * ndim
    idx[axis] = i
    return tuple(idx)


class Projection:
    """The pressure projection for one :class:`refmap.model.Model` (built once)."""

    def __init__(
        self, model, rtol: float = 1e-10, maxiter: int = 500, preconditioner: str = "fast"
    ):
        if preconditioner not in PRECONDITIONERS:
            raise ValueError(
                "pressure preconditioner must be one of "
                f"{', '.join(map(repr, PRECONDITIONERS))}, got {preconditioner!r}"
            )
        g = model.grid
        check_boundary(model.boundary, g)
        self.grid = g
        self.boundary = model.boundary
        self.periodic = model.bc.periodic
        self.rtol = float(rtol)
        self.maxiter = int(maxiter)
        self.preconditioner_kind = preconditioner
        nd = g.ndim
        self.ndim = nd
        self.spacing = tuple(g.spacing)
        faces = _faces(nd)
        out = {
            name: _outflow_nodes(name, getattr(model.boundary, name), g)
            for name in faces
            if getattr(model.boundary, name) != "periodic"
        }
        self.outflow = out
        mask = np.ones((nd,) + tuple(g.shape()))
        keep = np.ones(tuple(g.shape()))
        for a, (lo, hi) in enumerate(AXIS_FACES[:nd]):
            if self.periodic[a]:
                continue
            # the low face's normal velocity: prescribed, except on an outflow (free)
            first = _index(nd, a, 0)
            last = _index(nd, a, -1)
            mask[(a,) + first] = out[lo]
            keep[first][out[lo]] = 0.0
            keep[last][out[hi]] = 0.0
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
            for p, (lo, hi) in zip(self.periodic, AXIS_FACES[:nd], strict=True)
        )
        self.fast = SeparableSolver.on_grid(g, kinds)
        self.fast_definite = any(k != "periodic" and "odd" in k for k in kinds)
        # the multigrid cycle's levels (static sizes), only where it is used
        self.hierarchy = (Hierarchy.build(g.shape(), self.periodic)
                          if preconditioner == "multigrid" else None)

    # ------------------------------------------------------------------ operators
    def _edge(self, name, t):
        return _face_values(name, getattr(self.boundary, name), self.grid, t)

    def _div(self, v, *his):
        """Forward-difference divergence with the given high-edge face values, one per axis
        (None: wrap)."""
        out = None
        for a, (h, hi) in enumerate(zip(self.spacing, his, strict=True)):
            c = v[a]
            nxt = c[_index(self.ndim, a, slice(1, None))]
            beyond = c[_index(self.ndim, a, slice(0, 1))] if hi is None else jnp.expand_dims(hi, a)
            term = (jnp.concatenate([nxt, beyond], axis=a) - c) / h
            out = term if out is None else out + term
        return out

    def _his(self, t):
        """Per axis the high face's normal velocity at t (None where periodic)."""
        return [
            None if self.periodic[a] else self._edge(hi, t)
            for a, (_, hi) in enumerate(AXIS_FACES[: self.ndim])
        ]

    def prescribe(self, v, t):
        """``v`` with the low edges' normal components set to the edges' normal velocity."""
        out = v
        for a, (lo, _) in enumerate(AXIS_FACES[: self.ndim]):
            if self.periodic[a]:
                continue
            idx = (a,) + _index(self.ndim, a, 0)
            face = jnp.where(self.outflow[lo], v[idx], self._edge(lo, t))
            out = out.at[idx].set(face)
        return out

    def divergence(self, v, t):
        """The discrete divergence D v (the grid's shape) the projection zeroes, edge data
        at t (zero on outflow rows, whose continuity equation the outgoing face velocity
        closes)."""
        v = self.prescribe(v, t)
        return self._div(v, *self._his(t)) * self.keep

    def B(self, w):
        """The linear part of D on the free velocity components (zero edge data)."""
        g = self.grid
        shape = tuple(g.shape())
        zeros = [
            None if self.periodic[a] else jnp.zeros(shape[:a] + shape[a + 1:])
            for a in range(self.ndim)
        ]
        return self._div(w * self.mask, *zeros) * self.keep

    def BT(self, p):
        """B^T p (ndim, *shape); ``-B^T`` is the pressure gradient G."""
        tmpl = jax.ShapeDtypeStruct((self.ndim,) + p.shape, p.dtype)
        return jax.linear_transpose(self.B, tmpl)(p)[0]

    def gradient(self, p):
        """The discrete pressure gradient G p = -B^T p at the free velocity components."""
        return -self.BT(p)

    def _row_sums(self, weight):
        """Per continuity row (node), per axis the sums of ``weight`` over the free velocity
        components it reads: u at i and i + 1, v at j and j + 1, ... (zero beyond a wall)."""
        out = []
        for a in range(self.ndim):
            wa = weight * self.mask[a]
            if self.periodic[a]:
                out.append(wa + jnp.roll(wa, -1, axis=a))
            else:
                pad = jnp.zeros_like(wa[_index(self.ndim, a, slice(0, 1))])
                out.append(wa + jnp.concatenate([wa[_index(self.ndim, a, slice(1, None))], pad], axis=a))
        return out

    def moving_rows(self, weight):
        """(the grid's shape) 0/1: the continuity rows with at least one velocity component
        that the correction moves (``weight > 0`` and not prescribed)."""
        sums = self._row_sums(weight)
        total = sums[0]
        for r in sums[1:]:
            total = total + r
        return (total > 0).astype(jnp.float64)

    def operator(self, rho, weight=None):
        """``A = B W rho^-1 B^T`` plus ``s P0`` on the constants (SPD on the velocities
        it moves); ``W`` (default 1) the weight of the pressure correction per node."""
        inv = 1.0 / rho
        s = jax.lax.stop_gradient(jnp.mean(inv)) * sum(2.0 / h**2 for h in self.spacing)
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
            cs = (c,) * self.ndim
            s0 = sg(s)

            def P(r):
                # the constants are A's eigenvector with eigenvalue s; the rest is the
                # constant-coefficient Laplacian's pseudo-inverse
                mean = jnp.mean(r)
                return self.fast.solve_semidefinite(r - mean, *cs) + mean / s0

            if not self.has_outflow:
                return P
            keep, drop = self.keep, 1.0 - self.keep
            if self.fast_definite:
                return lambda r: keep * self.fast.solve(keep * r, 0.0, *cs) + drop * r
            return lambda r: keep * P(keep * r) + drop * r
        if self.preconditioner_kind == "multigrid":
            return self._multigrid(inv, sg(s))
        # the diagonal of B rho^-1 B^T: each node sees the free u at i and i + 1, v at j, j + 1
        sums = self._row_sums(inv)
        diag = sums[0] / self.spacing[0] ** 2
        for r, h in zip(sums[1:], self.spacing[1:], strict=True):
            diag = diag + r / h**2
        if self.has_outflow:
            diag = diag * self.keep + (1.0 - self.keep)
        else:
            diag = diag + sg(s) / int(np.prod(g.shape()))
        return lambda r: r / diag

    def faces(self, inv):
        """The operator ``B diag(inv) B^T`` without its ``s P0`` term, as the face
        coefficients and extra diagonal of :mod:`refmap.multigrid` (its outflow rows are
        zero there: the identity rows of ``A`` are the cycle's identity rows)."""
        nd = self.ndim
        keep = jnp.asarray(self.keep)
        faces = []
        extra = jnp.zeros_like(inv)
        for a, h in enumerate(self.spacing):
            # the face at node j (the free velocity component there) couples j - 1 and j
            c = self.mask[a] * inv / h**2
            if not self.periodic[a]:
                c = c.at[_index(nd, a, 0)].set(0.0)  # no node before the first
            before = jnp.roll(keep, 1, axis=a)
            faces.append(c * keep * before)
            # a face between a kept and a removed (outflow) node: a Dirichlet term on the kept
            extra = extra + c * keep * (1.0 - before) + jnp.roll(c * (1.0 - keep) * before, -1, axis=a)
        return tuple(faces), extra

    def _multigrid(self, inv, s):
        faces, extra = self.faces(inv)
        V = vcycle(self.hierarchy, faces, extra)
        moving = (face_diagonal(faces, extra) > 0).astype(inv.dtype)
        fixed = 1.0 - moving

        def P0(r):
            # exactly the identity on the rows that nothing moves (held, outflow)
            return moving * V(moving * r) + fixed * r

        if self.has_outflow:
            return P0

        def P(r):
            # the constants are A's eigenvector with eigenvalue s; the cycle on the rest
            mean = jnp.mean(r)
            z = P0(r - mean)
            return z - jnp.mean(z) + mean / s

        return P

    # ------------------------------------------------------------------ the projection
    def correct(self, v, p, rho, dt, weight=None):
        """``v - dt W rho^-1 G p``: the pressure ``p``'s correction, weighted per node as in
        :meth:`project` (the incremental step applies the last pressure's with it)."""
        inv = 1.0 / rho if weight is None else weight / rho
        return v + dt * self.BT(p) * inv[None]

    def project(self, v_star, rho, t_new, dt, weight=None, return_info=False, source=None,
                guess=None, return_solution=False):
        """The divergence-free ``v = v* - dt W rho^-1 G p`` (edge data at t_new).

        ``weight`` (nx, ny), default 1: how much of the correction each node takes; the
        anchors' nodes (:meth:`refmap.model.Model.step`) take ``1 - w_anchor``, so an
        anchor's velocity, applied to v* before, is kept where it holds fully.  ``source``
        (nx, ny), default 0: the divergence to impose instead, ``D v = source`` (the solids'
        volume correction, :meth:`refmap.model.Model.volume_source`); without an outflow
        edge it must sum to zero (its mean is removed).  With ``return_info`` also
        ``(p, info)`` (then not differentiable: plain CG).  ``guess`` (nx, ny): a first
        iterate for p (:meth:`refmap.model.Model.advance` extrapolates it from the last two
        steps; the solve stops at the same residual, so the answer changes only within
        ``rtol``); ``return_solution``: return ``(v, p)``."""
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
            p, info = cg(A, rhs, x0=guess, **kw)
        else:
            p = solve_spd(A, rhs, x0=guess, **kw)
        v = self.correct(v_b, p, rho, dt, weight)
        if return_info:
            return v, p, info
        if return_solution:
            return v, p
        return v


__all__ = ["PRECONDITIONERS", "Projection", "check_boundary", "resolve_preconditioner"]
