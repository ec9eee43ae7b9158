"""Frozen verbatim copies of the 2D boundary padding and level-set code as they were before
issue 12's second step (commit 6470f49), to test that the dimension-generic code gives
bitwise the same 2D results.  Not collected by pytest (no ``test_`` prefix).  Do not edit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.scipy.special import erf

import refmap  # noqa: F401  (float64)
from refmap.boundary import EDGES, Boundary, Segment
from refmap.grid import Grid


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


# ---------------------------------------------------------------- levelset (verbatim)
Periodic = tuple[bool, bool]

_TINY = 1e-300  # keeps sqrt and divisions finite (and their derivatives) at zero


def _neighbours(a, axis: int, periodic: bool, edge: str = "linear", fill=0):
    """Values of ``a`` at index ``k - 1`` and ``k + 1`` along ``axis`` (-2: x, -1: y).

    Beyond a non-periodic edge the missing value is ``2 a_0 - a_1`` (``edge="linear"``) or
    the constant ``fill`` (``edge="fill"``, used for masks: ``fill=False`` marks a node
    outside the domain as unknown).  With ``periodic`` the axis wraps.
    """
    if periodic:
        return jnp.roll(a, 1, axis=axis), jnp.roll(a, -1, axis=axis)
    ax = a.ndim + axis if axis < 0 else axis
    n = a.shape[ax]
    if edge == "linear":
        first = lax.slice_in_dim(a, 0, 1, axis=ax)
        last = lax.slice_in_dim(a, n - 1, n, axis=ax)
        lo = 2 * first - lax.slice_in_dim(a, 1, 2, axis=ax)
        hi = 2 * last - lax.slice_in_dim(a, n - 2, n - 1, axis=ax)
        padded = jnp.concatenate([lo, a, hi], axis=ax)
    elif edge == "fill":
        widths = [(0, 0, 0)] * a.ndim
        widths[ax] = (1, 1, 0)
        padded = lax.pad(a, jnp.asarray(fill, dtype=a.dtype), widths)
    else:
        raise ValueError(f"unknown edge treatment {edge!r}; use 'linear' or 'fill'")
    minus = lax.slice_in_dim(padded, 0, n, axis=ax)
    plus = lax.slice_in_dim(padded, 2, n + 2, axis=ax)
    return minus, plus


def _check_shape(phi):
    if phi.ndim < 2 or phi.shape[-1] < 2 or phi.shape[-2] < 2:
        raise ValueError(
            f"expected a node field of shape (..., nx, ny) with nx, ny >= 2, got {phi.shape}"
        )


def unit_normal(phi, dx, dy, periodic: Periodic = (False, False)):
    """Outward unit normal ``grad phi / |grad phi|`` by central differences.

    Returns an array of shape ``(..., 2, nx, ny)`` (components on the axis just before the
    grid axes, as for every vector field of the package).  At a non-periodic edge the ghost
    node is linearly extrapolated, which makes the central difference there the one-sided
    difference into the domain.  Where ``grad phi`` vanishes exactly the normal is 0 (no NaN,
    and finite derivatives).
    """
    phi = jnp.asarray(phi)
    _check_shape(phi)
    xm, xp = _neighbours(phi, -2, periodic[0])
    ym, yp = _neighbours(phi, -1, periodic[1])
    gx = (xp - xm) / (2 * dx)
    gy = (yp - ym) / (2 * dy)
    mag2 = gx * gx + gy * gy
    nonzero = mag2 > 0
    inv = jnp.where(nonzero, 1 / jnp.sqrt(jnp.where(nonzero, mag2, 1.0)), 0.0)
    return jnp.stack([gx * inv, gy * inv], axis=-3)


def heaviside_blur(phi, width):
    """Blurred Heaviside ``H = (1 + erf(phi / width)) / 2``: 0 deep in the solid, 1 outside.

    The thesis uses ``width = 2 dx``.  Works on any array shape (nodes or corners).
    """
    return 0.5 * (1 + erf(jnp.asarray(phi) / width))


def redistance(
    phi, dx, dy, iters: int, periodic: Periodic = (False, False), freeze_interface: bool = False
):
    """Re-distance ``phi`` by ``iters`` pseudo-time steps of ``phi_t + S(phi0)(|grad phi| - 1) = 0``.

    Sussman-Smereka-Osher re-initialisation with the first-order Godunov upwind Hamiltonian
    and forward Euler in pseudo-time, step ``dtau = 0.5 min(dx, dy)`` (the 2D CFL number
    is then at most 0.71).  ``phi0`` is the input ``phi`` and fixes the sign ``S = sign(phi0)``.

    Russo-Smereka sub-cell fix: at the nodes adjacent to the zero contour of ``phi0`` (a
    sign change with one of the four neighbours, or ``phi0 == 0``) the upwind update is
    replaced by the relaxation ``phi <- phi - (dtau/h)(S |phi| - D)`` towards the sub-cell
    distance estimate ``D = phi0 / |grad phi0|``, with ``|grad phi0|`` the largest of the
    central-difference gradient magnitude and the four one-sided slopes (Russo & Smereka,
    J. Comput. Phys. 163, 2000).  Those nodes never look across the interface, so the zero
    contour stays where ``phi0`` puts it (to O(h^2) in the slope estimate): it moves by a
    small fraction of a cell, and not at all for a linear ``phi0``.

    Information travels ``dtau = h/2`` per iteration, so making ``phi`` a distance out to
    ``k`` cells from the interface takes about ``2k`` iterations (a few more when the input
    slope is far from 1).  Nodes farther out keep moving towards a distance; clip
    afterwards if only a band matters.  Cost: one fused 5-point stencil per iteration.

    Args:
        phi: level set, ``(..., nx, ny)``.
        dx, dy: grid spacings.
        iters: number of pseudo-time steps (static).
        periodic: static (x, y) wrap flags; otherwise linear-extrapolation ghost nodes.
        freeze_interface: keep the nodes next to the zero contour exactly as given and
            re-distance only the others from them.  Used when re-distancing every time
            step: applying the sub-cell fix at every step accumulates grid-scale wiggles of
            the interface (measured on the rotor: rms of lap(phi) near the interface 9.1
            with the fix every step, 2.2 without re-distancing, a smooth contour frozen).

    Returns:
        The re-distanced level set, same shape as ``phi``.
    """
    phi0 = jnp.asarray(phi)
    _check_shape(phi0)
    px, py = periodic
    h = jnp.minimum(dx, dy)
    dtau = 0.5 * h

    xm, xp = _neighbours(phi0, -2, px)
    ym, yp = _neighbours(phi0, -1, py)
    near = (phi0 == 0) | (phi0 * xm < 0) | (phi0 * xp < 0) | (phi0 * ym < 0) | (phi0 * yp < 0)
    central = jnp.sqrt(((xp - xm) / (2 * dx)) ** 2 + ((yp - ym) / (2 * dy)) ** 2 + _TINY)
    slope = jnp.maximum(
        jnp.maximum(central, jnp.abs(xp - phi0) / dx),
        jnp.maximum(
            jnp.abs(phi0 - xm) / dx,
            jnp.maximum(jnp.abs(yp - phi0) / dy, jnp.abs(phi0 - ym) / dy),
        ),
    )
    dist = phi0 / jnp.maximum(slope, 1e-12)  # Russo-Smereka distance estimate D
    sign = jnp.sign(phi0)
    positive = phi0 > 0
    relax = dtau / h

    def step(_, p):
        pxm, pxp = _neighbours(p, -2, px)
        pym, pyp = _neighbours(p, -1, py)
        a = (p - pxm) / dx  # backward
        b = (pxp - p) / dx  # forward
        c = (p - pym) / dy
        d = (pyp - p) / dy
        # Godunov: for S > 0 take the upwind slopes pointing away from smaller phi
        gx2_pos = jnp.maximum(jnp.maximum(a, 0.0) ** 2, jnp.minimum(b, 0.0) ** 2)
        gy2_pos = jnp.maximum(jnp.maximum(c, 0.0) ** 2, jnp.minimum(d, 0.0) ** 2)
        gx2_neg = jnp.maximum(jnp.minimum(a, 0.0) ** 2, jnp.maximum(b, 0.0) ** 2)
        gy2_neg = jnp.maximum(jnp.minimum(c, 0.0) ** 2, jnp.maximum(d, 0.0) ** 2)
        g2 = jnp.where(positive, gx2_pos + gy2_pos, gx2_neg + gy2_neg)
        far = p - dtau * sign * (jnp.sqrt(g2 + _TINY) - 1)
        if freeze_interface:
            return jnp.where(near, p, far)
        close = p - relax * (sign * jnp.abs(p) - dist)
        return jnp.where(near, close, far)

    return lax.fori_loop(0, iters, jax.checkpoint(step, prevent_cse=False), phi0)


def pin_levelset(
    phi,
    psi,
    dx,
    dy,
    rate,
    inner,
    outer,
    redistance_iters: int,
    phi_max,
    periodic: Periodic = (False, False),
):
    """Pin ``phi`` to the interface seen by the reference map (thesis Algorithm 2).

    ``phi`` is not advected.  Instead it is relaxed towards ``psi = phi0(xi)`` (the initial
    level set evaluated at the current reference map, computed by the caller):

    1. ``phi <- phi + rate (psi - phi)`` where ``-inner < phi < outer`` (elsewhere unchanged);
       ``rate`` in [0, 1] (a scalar or an array broadcasting to ``phi``); ``rate = 1``
       copies ``psi``, ``rate = k * n_sub * dt`` is the thesis's relaxation (k = 5, 10
       sub-steps, zone ``phi > -5 dx``), whose contour alone trails a body moving at speed U
       by ``U / (k n_sub)``; the model copies at the nodes next to the contour and relaxes
       elsewhere (``Numerics.pin_copy``);
    2. re-distance with ``redistance_iters`` iterations of :func:`redistance`, the nodes
       next to the zero contour frozen (so the contour is exactly that of step 1, smooth
       because psi is), restoring ``|grad phi| = 1`` away from it, since ``psi`` is only a
       distance where the solid is unstrained;
    3. clip to ``[-phi_max, phi_max]`` (values far from any interface are not needed).

    Shapes ``(..., nx, ny)``; ``psi`` must broadcast to ``phi``.  ``rate``, ``inner``,
    ``outer``, ``phi_max`` may be traced; ``redistance_iters`` and ``periodic`` are static.
    """
    phi = jnp.asarray(phi)
    zone = (phi > -inner) & (phi < outer)
    phi = jnp.where(zone, phi + rate * (psi - phi), phi)
    phi = redistance(phi, dx, dy, redistance_iters, periodic, freeze_interface=True)
    return jnp.clip(phi, -phi_max, phi_max)
