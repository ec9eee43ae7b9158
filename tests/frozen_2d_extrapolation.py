"""Frozen verbatim copy of ``refmap.extrapolation`` as it was before it became
dimension-generic (issue 12, commit fd793c3), to test that the generic code gives bitwise
the same 2D results (``tests/test_extrapolation_3d.py``).  Only the module docstring is
replaced by this one.  Not collected by pytest (no ``test_`` prefix).  Do not edit.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax import lax

from refmap import narrowband
from refmap.levelset import Periodic, _neighbours, unit_normal


def _nb(a, axis, periodic, fill):
    """Neighbours along ``axis`` with a constant beyond a non-periodic edge."""
    return _neighbours(a, axis, periodic, edge="fill", fill=fill)


def default_sweeps(band, dx, dy) -> int:
    """Default Jacobi sweep count of :func:`extrapolate_linear`: ``ceil(sqrt(2) band / h) + 3``.

    A sweep moves information one node along x or y, so reaching a band node at distance
    ``band`` along a diagonal normal takes ``sqrt(2) band / h`` sweeps (the Manhattan length
    of the path), plus a few for the offset of the first band layer.
    """
    h = min(float(dx), float(dy))
    return int(math.ceil(math.sqrt(2.0) * float(band) / h - 1e-9)) + 3


def solid_gradient(f, phi, dx, dy, periodic: Periodic = (False, False)):
    """Gradient of ``f`` at solid nodes from solid values only.

    Central differences where both neighbours along an axis are solid (``phi < 0``),
    one-sided towards the solid otherwise.  Exact for affine ``f``.

    Returns ``(gx, gy, valid)``: ``valid`` (shape of ``phi``) is True at solid nodes where
    both components could be formed (a node with no solid neighbour along an axis, e.g. in a
    one-cell sliver or against a non-periodic edge, is not valid); ``gx``, ``gy`` are
    meaningless elsewhere.
    """
    f = jnp.asarray(f)
    solid = jnp.asarray(phi) < 0
    nb = _DenseNeighbours(periodic)
    return _solid_gradient_nb(f, nb(f, 0.0), solid, nb(solid, False), dx, dy)


def _solid_gradient_nb(f, f_nb, solid, s_nb, dx, dy):
    """:func:`solid_gradient` from the neighbours (x-, x+, y-, y+) of f and of the solid mask."""
    fxm, fxp, fym, fyp = f_nb
    sxm, sxp, sym, syp = s_nb
    gx = jnp.where(
        sxm & sxp, (fxp - fxm) / (2 * dx), jnp.where(sxp, (fxp - f) / dx, (f - fxm) / dx)
    )
    gy = jnp.where(
        sym & syp, (fyp - fym) / (2 * dy), jnp.where(syp, (fyp - f) / dy, (f - fym) / dy)
    )
    return gx, gy, solid & (sxm | sxp) & (sym | syp)


def _gradient_valid(solid, periodic):
    """Solid nodes with a solid neighbour along each axis (geometry only, shape of phi)."""
    sxm, sxp = _nb(solid, -2, periodic[0], False)
    sym, syp = _nb(solid, -1, periodic[1], False)
    return solid & (sxm | sxp) & (sym | syp)


def extrapolate_linear(
    f,
    phi,
    dx,
    dy,
    band,
    iters: int | None = None,
    periodic: Periodic = (False, False),
):
    """Extend a node scalar from the solid (``phi < 0``) into the band ``0 <= phi <= band``.

    Linear extrapolation along the outward normal ``n = grad phi / |grad phi|`` (Aslam 2004,
    "constant then linear"), with the gradient extrapolated as two independent scalars:

    (a) ``g = (gx, gy)`` at solid nodes from solid values only (:func:`solid_gradient`);
    (b) ``g`` is extended as a constant along ``n``: at each unknown node (band nodes, and
        solid nodes without a valid gradient, all with ``phi <= band``) the upwind
        discretisation of ``n . grad q = 0`` gives ``q = sum_d w_d q_up_d / sum_d w_d``,
        ``w_d = |n_d| / h_d``, ``q_up_d`` the neighbour on the solid side along axis d;
    (c) ``f`` is rebuilt at band nodes from the upwind discretisation of ``n . grad f = n . g``:
        ``f = (sum_d w_d f_up_d + n . g) / sum_d w_d``.

    (b) and (c) are solved together by Jacobi sweeps outward from the solid, using in each
    sweep only neighbours whose values are already known (a node becomes known when one of
    them is; the sums above then run over the known upwind axes, with ``n . g`` restricted
    to the same axes).  A node with no known upwind neighbour (``n = 0``, or an upwind node
    outside the band or the domain) falls back on the mean over its known 4-neighbours
    ``nb`` of ``q_nb`` for the gradient and ``f_nb + (x - x_nb) . g`` for ``f``.

    Exactness: every formula above reproduces an affine ``f = a x + b y + c`` exactly
    (one-sided and central differences of an affine field are exact; the upwind relation is
    exact for it, over any subset of axes), so an affine ``f`` is reproduced to round-off at
    every band node reached, whatever ``phi``.  A smooth ``f`` is extrapolated with error
    O(h^2) at a fixed number of cells from the interface (O(h d) + O(d^2) at distance d).

    Which nodes are known before each sweep depends on ``phi`` only, so it is found first by
    a cheap boolean pre-pass (shared by all components of a batch with one ``phi``); the
    value sweeps then only gather 4-neighbours of ``gx``, ``gy`` and ``f``.

    Cost: ``iters`` boolean pre-pass sweeps plus ``iters`` value sweeps, each a 5-point
    stencil on three arrays per component.  A sweep moves information one node along an
    axis.  The default :func:`default_sweeps` (``ceil(sqrt(2) band / h) + 3``, 12 for
    ``band = 6h``) reaches the whole band along diagonals too and lets the upwind values
    settle (measured: within 1e-5 of the fully converged sweeps for the shapes in the
    tests; ``ceil(band / h) + 3`` = 9 sweeps also reaches every band node but leaves
    differences up to ~1e-2 for ``sin(2x + 1) cos(1.5y)`` at the outer diagonal band nodes).  With
    fewer sweeps the outer band nodes keep their input value (not reached) or an
    off-normal, still affine-exact, estimate.

    Args:
        f: node scalar, ``(..., nx, ny)``; values at ``phi >= 0`` are ignored (may be
            anything finite or not).
        phi: level set broadcastable to ``f`` (negative in the solid).
        dx, dy: spacings.
        band: width of the extrapolation band (a distance, e.g. ``6 * dx``).
        iters: number of Jacobi sweeps (static); default :func:`default_sweeps`.
        periodic: static (x, y) wrap flags.

    Returns:
        ``f`` with its band values replaced; solid nodes and nodes with ``phi > band`` (and any
        band node not reached within ``iters`` sweeps) are returned unchanged.
    """
    f = jnp.asarray(f)
    phi = jnp.asarray(phi)
    if f.ndim < 2:
        raise ValueError(f"f must have shape (..., nx, ny), got {f.shape}")
    if iters is None:
        iters = default_sweeps(band, dx, dy)
    shape = jnp.broadcast_shapes(f.shape, phi.shape)
    f = jnp.broadcast_to(f, shape)

    solid = phi < 0
    in_band = phi <= band
    update_f = in_band & ~solid
    gx, gy, gvalid = solid_gradient(f, phi, dx, dy, periodic)
    update_g = in_band & ~gvalid
    normal = unit_normal(phi, dx, dy, periodic)
    nb = _DenseNeighbours(periodic)
    fixed_g = dict(known=False, arrival=jnp.int32(iters + 1), value=(0.0, 0.0))
    fixed_f = dict(known=False, arrival=jnp.int32(iters + 1), value=0.0)
    # Values that are not known yet are never used (weight 0), but may be NaN: zero them.
    values = (jnp.where(gvalid, gx, 0.0), jnp.where(gvalid, gy, 0.0), jnp.where(solid, f, 0.0))
    f_ext, done = _extrapolate_core(
        values,
        gvalid,
        solid,
        update_g,
        update_f,
        normal[..., 0, :, :],
        normal[..., 1, :, :],
        nb,
        fixed_g,
        fixed_f,
        iters,
        dx,
        dy,
    )
    return jnp.where(done, f_ext, f)


class _DenseNeighbours:
    """The four neighbours (x-, x+, y-, y+) of a grid array, a constant beyond an edge."""

    def __init__(self, periodic):
        self.px, self.py = periodic

    def __call__(self, a, fill):
        am, ap = _nb(a, -2, self.px, fill)
        bm, bp = _nb(a, -1, self.py, fill)
        return am, ap, bm, bp


def _extrapolate_core(
    values, gvalid, solid, update_g, update_f, nrm_x, nrm_y, nb, fixed_g, fixed_f, iters, dx, dy
):
    """The sweeps of :func:`extrapolate_linear` on any layout of the unknowns.

    ``values = (gx, gy, f)`` and the masks are arrays of one layout (the grid, or a
    compacted list of band nodes); ``nb(a, fill)`` returns the four neighbours of a layout
    array, taking ``fill`` (a constant, or per-neighbour arrays) where the neighbour is not
    part of the layout.  ``fixed_g``/``fixed_f`` hold those fills for the gradient's and
    for f's ``known``, ``arrival`` and ``value``.  Returns ``(f, done)``: the swept f and the
    nodes whose f was reached (to be written back).
    """
    never = jnp.int32(iters + 1)

    def any_neighbour(k, fill):
        km, kp, lm, lp = nb(k, fill)
        return km | kp | lm | lp

    # Which values are known before sweep s depends on the geometry only (not on f), so it
    # is computed once (shared by every component using this phi) as an arrival sweep:
    # a node is known before sweep s iff arrival <= s.  A gradient becomes known in the sweep
    # after any 4-neighbour's gradient is; f in the sweep after any 4-neighbour's f is,
    # provided its own gradient is known by the end of that sweep.
    def arrive(s, state):
        gk, fk, ag, af = state
        gk_new = gk | (update_g & any_neighbour(gk, fixed_g["known"]))
        fk_new = fk | (update_f & gk_new & any_neighbour(fk, fixed_f["known"]))
        ag = jnp.where(gk_new & ~gk, s + 1, ag)
        af = jnp.where(fk_new & ~fk, s + 1, af)
        return gk_new, fk_new, ag, af

    ag0 = jnp.where(gvalid, 0, never).astype(jnp.int32)
    af0 = jnp.where(solid, 0, never).astype(jnp.int32)
    _, _, ag, af = lax.fori_loop(0, iters, arrive, (gvalid, solid, ag0, af0))

    # Static neighbour weights, order (x-, x+, y-, y+): |n_d| / h_d on the upwind (solid)
    # side of each axis, 0 on the other.
    wx = jnp.abs(nrm_x) / dx
    wy = jnp.abs(nrm_y) / dy
    zero = jnp.zeros_like(wx)
    w_up = (
        jnp.where(nrm_x > 0, wx, zero),
        jnp.where(nrm_x < 0, wx, zero),
        jnp.where(nrm_y > 0, wy, zero),
        jnp.where(nrm_y < 0, wy, zero),
    )
    g_arr = nb(ag, fixed_g["arrival"])
    f_arr = nb(af, fixed_f["arrival"])

    def weights(arr, s):
        """Upwind weights of the known neighbours, or 1 per known neighbour if none."""
        known = [a <= s for a in arr]
        up = [jnp.where(k, w, 0.0) for k, w in zip(known, w_up, strict=True)]
        has_up = (up[0] + up[1]) + (up[2] + up[3]) > 0
        c = [jnp.where(has_up, u, k.astype(u.dtype)) for u, k in zip(up, known, strict=True)]
        total = (c[0] + c[1]) + (c[2] + c[3])
        return c, 1 / jnp.where(total > 0, total, 1.0)

    gx_fill, gy_fill = fixed_g["value"]
    f_fill = fixed_f["value"]

    def sweep(s, state):
        # Both regimes are one formula over the 4 neighbours nb with weights c_nb:
        #   q = sum c q_nb / sum c,   f = sum c (f_nb + (x - x_nb) . g) / sum c,
        # which is (b)/(c) above when c are the upwind weights (since
        # |n_d| / h_d * (x - x_up)_d = n_d) and the fallback mean when c are 0/1.
        gx, gy, f = state
        c, inv = weights(g_arr, s)
        new = []
        for q, fill in ((gx, gx_fill), (gy, gy_fill)):
            qxm, qxp, qym, qyp = nb(q, fill)
            new.append(((c[0] * qxm + c[1] * qxp) + (c[2] * qym + c[3] * qyp)) * inv)
        g_now = update_g & (ag <= s + 1)
        gx = jnp.where(g_now, new[0], gx)
        gy = jnp.where(g_now, new[1], gy)

        c, inv = weights(f_arr, s)
        fxm, fxp, fym, fyp = nb(f, f_fill)
        sx = dx * gx
        sy = dy * gy
        f_new = (
            (c[0] * (fxm + sx) + c[1] * (fxp - sx)) + (c[2] * (fym + sy) + c[3] * (fyp - sy))
        ) * inv
        f = jnp.where(update_f & (af <= s + 1), f_new, f)
        return gx, gy, f

    _, _, f_ext = _checkpointed_sweeps(sweep, iters, values)
    return f_ext, update_f & (af <= iters)


def _checkpointed_sweeps(sweep, iters: int, values):
    """``lax.fori_loop(0, iters, sweep, values)`` with every sweep rematerialised, in two
    nested loops of about ``sqrt(iters)`` sweeps (blocks rematerialised too): reverse mode
    keeps about ``2 sqrt(iters)`` carries instead of ``iters`` (7 instead of 12 for the
    default 12 sweeps) for one more forward pass of the sweeps.  The forward values are
    those of the plain loop, bit for bit (the same sweeps in the same order)."""
    body = jax.checkpoint(sweep, prevent_cse=False)
    k = math.isqrt(iters - 1) + 1 if iters > 1 else 1  # ceil(sqrt(iters))
    q = iters // k
    if q <= 1:
        return lax.fori_loop(0, iters, body, values)

    def block(b, v):
        return lax.fori_loop(0, k, lambda i, v: body(b * k + i, v), v)

    values = lax.fori_loop(0, q, jax.checkpoint(block, prevent_cse=False), values)
    return lax.fori_loop(q * k, iters, body, values)


def _second_differences(f, okx, oky, dx, dy, nb, fill):
    """``(f_xx, f_yy)`` by 3-point differences, 0 where a stencil node is not valid."""
    fxm, fxp, fym, fyp = nb(f, fill)
    fxx = jnp.where(okx, (fxp - 2 * f + fxm) / (dx * dx), 0.0)
    fyy = jnp.where(oky, (fyp - 2 * f + fym) / (dy * dy), 0.0)
    return fxx, fyy


def smooth_extrapolated(
    f,
    phi,
    dx,
    dy,
    band,
    coef=0.025,
    max_sweeps: int = 80,
    ratio=0.25,
    atol=1e-3,
    periodic: Periodic = (False, False),
    fixed_sweeps: int | None = None,
    return_sweeps: bool = False,
):
    """Diffuse the extrapolated values of ``f`` in pseudo-time (thesis Algorithm 3).

    Each sweep does ``f <- f + coef h^2 (f_xx + f_yy)`` (``h = min(dx, dy)``, 3-point second
    differences, Jacobi) at the extrapolated nodes ``0 <= phi <= band`` only; the solid's own
    values (``phi < 0``) and nodes beyond the band are never changed.  A second difference
    whose stencil reaches a node that is not valid (``phi > band``, or beyond a non-periodic
    edge) is taken as 0 along that axis (as with a linearly extrapolated ghost), so an affine
    ``f`` is a fixed point everywhere; the consequence is that the outermost band layer is
    smoothed only along the axes whose both neighbours lie in the band (to smooth the whole
    band, extrapolate and smooth over a band two cells wider than needed).

    Stopping rule (while-loop): before each sweep the largest ``|f_xx|`` and ``|f_yy|`` over
    the band are compared, per component, with those over the solid interior
    (``phi < -2h``); sweeping stops once ``band_max <= ratio * interior_max + atol`` for
    both, or after ``max_sweeps`` sweeps.  The thesis's values are ``coef = 0.025`` (its
    ``0.000025`` at ``dx = 4/128``), ``ratio = 0.25``, at most 80 sweeps.  With a leading batch
    axis the rule is applied to each element separately (as ``vmap`` of ``while_loop`` would).

    For reverse-mode differentiation pass ``fixed_sweeps=k``: exactly ``k`` sweeps in a
    ``fori_loop``, no stopping rule.

    In practice a first-order normal extrapolation of a curved (non-affine) field already
    has band second differences comparable to the interior's (they grow like 1/h at a fixed
    distance, from the grid-scale variation of the upwind error), so with ``ratio = 0.25``
    the rule is seldom met and the loop runs ``max_sweeps`` sweeps, as the thesis's code
    (whose interior maximum was effectively 0) always did; an affine field stops at once.

    Cost: per sweep one 5-point stencil and, in the while-loop, one masked max reduction
    (about 3x the cost of a ``fixed_sweeps`` sweep on CPU).  Stability: the explicit update
    is stable and monotone for ``coef <= 0.25`` when ``dx == dy``; at the default a
    grid-scale (2h) tangential mode decays by ``1 - 4 coef = 0.9`` per sweep, a 4h mode by
    0.95, so 80 sweeps take them down by 2e-4 and 2e-2 (less next to the outermost layer).

    Args:
        f: node scalar(s) ``(..., nx, ny)``, already extrapolated (:func:`extrapolate_linear`).
        phi: level set broadcastable to ``f``.
        dx, dy, band: spacings and band width (the same band as the extrapolation).
        coef, ratio, atol: diffusion number, stopping ratio and absolute tolerance (units of
            ``f / length^2``).
        max_sweeps: cap on the sweeps of the while-loop (static).
        periodic: static (x, y) wrap flags.
        fixed_sweeps: static; if given, run exactly this many sweeps instead.
        return_sweeps: static; also return the number of sweeps done (per batch element).

    Returns:
        The smoothed ``f`` (and the sweep counts, int32 of the batch shape, if
        ``return_sweeps``).
    """
    f = jnp.asarray(f)
    phi = jnp.asarray(phi)
    shape = jnp.broadcast_shapes(f.shape, phi.shape)
    f = jnp.broadcast_to(f, shape)
    h = jnp.minimum(dx, dy)

    solid = phi < 0
    valid = phi <= band
    ext = valid & ~solid
    nb = _DenseNeighbours(periodic)
    vxm, vxp, vym, vyp = nb(valid, False)
    limits = None
    if fixed_sweeps is None:
        limits = _interior_limits(f, phi < -2 * h, vxm & vxp, vym & vyp, dx, dy, nb, ratio, atol)
    return _smooth_core(
        f,
        ext,
        vxm & vxp,
        vym & vyp,
        limits,
        nb,
        0.0,
        coef * h * h,
        dx,
        dy,
        max_sweeps,
        fixed_sweeps,
        return_sweeps,
        grid_ndim=2,
    )


def _interior_limits(f, interior, okx, oky, dx, dy, nb, ratio, atol):
    """The smoothing's stopping limits ``ratio * max |f_dd| over the interior + atol``."""

    def masked_max(a, mask):
        return jnp.max(jnp.where(mask, jnp.abs(a), 0.0), axis=(-2, -1))

    fxx0, fyy0 = _second_differences(f, okx, oky, dx, dy, nb, 0.0)
    # interior values never change, so neither do these limits
    return ratio * masked_max(fxx0, interior) + atol, ratio * masked_max(fyy0, interior) + atol


def _smooth_core(
    f,
    ext,
    okx,
    oky,
    limits,
    nb,
    fill,
    step,
    dx,
    dy,
    max_sweeps,
    fixed_sweeps,
    return_sweeps,
    grid_ndim,
):
    """The sweeps of :func:`smooth_extrapolated` on any layout (see :func:`_extrapolate_core`):
    ``f`` and the masks are layout arrays whose last ``grid_ndim`` axes are the layout's,
    ``limits`` the per-batch stopping limits (None with ``fixed_sweeps``)."""
    axes = tuple(range(-grid_ndim, 0))
    batch = f.shape[:-grid_ndim]

    def expand(a):
        return a.reshape(a.shape + (1,) * grid_ndim)

    def sweep_with(f, fxx, fyy, active):
        return jnp.where(ext & active, f + step * (fxx + fyy), f)

    if fixed_sweeps is not None:

        def body(_, f):
            fxx, fyy = _second_differences(f, okx, oky, dx, dy, nb, fill)
            return sweep_with(f, fxx, fyy, True)

        f = lax.fori_loop(0, fixed_sweeps, body, f)
        if return_sweeps:
            return f, jnp.full(batch, fixed_sweeps, dtype=jnp.int32)
        return f

    lim_xx, lim_yy = (expand(lim) for lim in limits)

    def cond(state):
        k, _, active, _ = state
        return (k < max_sweeps) & jnp.any(active)

    def body(state):
        k, f, _, count = state
        fxx, fyy = _second_differences(f, okx, oky, dx, dy, nb, fill)
        # one reduction: is any band node above its limit in either component?
        excess = jnp.maximum(jnp.abs(fxx) - lim_xx, jnp.abs(fyy) - lim_yy)
        active = jnp.max(jnp.where(ext, excess, -1.0), axis=axes) > 0
        f = sweep_with(f, fxx, fyy, expand(active))
        return k + 1, f, active, count + active.astype(jnp.int32)

    state = (jnp.int32(0), f, jnp.ones(batch, dtype=bool), jnp.zeros(batch, dtype=jnp.int32))
    _, f, _, count = lax.while_loop(cond, body, state)
    if return_sweeps:
        return f, count
    return f


def extend(
    f,
    phi,
    dx,
    dy,
    band,
    capacity: int | tuple[int, ...] | None = None,
    iters: int | None = None,
    periodic: Periodic = (False, False),
    smooth: dict | None = None,
    tile: tuple[int, int] | None = None,
):
    """:func:`extrapolate_linear` then :func:`smooth_extrapolated`, for several solids at once.

    ``f`` is ``(S, C, nx, ny)`` (C components per solid sharing its level set), ``phi``
    ``(S, nx, ny)``; ``smooth`` holds the keyword arguments of the smoothing (``coef``,
    ``max_sweeps``, ``ratio``, ``atol``, ``fixed_sweeps``; None: no smoothing).

    With ``capacity=None`` every sweep runs over the whole grid.  With an integer
    ``capacity`` (a number of tiles) the sweeps run on each solid's band only
    (:mod:`refmap.narrowband`): the tiles (``tile`` nodes, default
    :func:`refmap.narrowband.tile_shape`) that hold a node to update (``phi <= band``
    outside the solid's valid-gradient interior), at most ``capacity`` per solid, are
    gathered once, the extrapolation and smoothing sweep them, and the result is scattered
    back; the arithmetic is the same node for node, so the result is that of the
    full-grid sweeps (to the last bit or so: XLA may fuse the two layouts differently).  If
    any solid's band covers more than ``capacity`` tiles, this call falls back on the
    full-grid sweeps (same result, full cost).  A tuple of capacities is a ladder: the
    smallest one that holds every solid's band is used (the work is proportional to it),
    the full grid when none does.
    """
    f = jnp.asarray(f)
    phi = jnp.asarray(phi)
    if iters is None:
        iters = default_sweeps(band, dx, dy)
    if tile is None and capacity is not None:
        tile = narrowband.tile_shape(phi.shape[-2:], periodic)

    def dense(f, phi):
        def one(f_k, phi_k):
            out = extrapolate_linear(f_k, phi_k[None], dx, dy, band, iters, periodic)
            if smooth is None:
                return out
            return smooth_extrapolated(out, phi_k[None], dx, dy, band, periodic=periodic, **smooth)

        if smooth is not None and smooth.get("fixed_sweeps") is not None and f.shape[1] > 1:
            # fixed sweeps (reverse-differentiable runs): one component at a time, each
            # rematerialised, so that the backward pass holds one component's sweeps (the
            # peak of a step's backward: 16 of its 23 MiB at 128^2, halved).  Same values
            # (the same arithmetic per node), one more forward pass of the sweeps in reverse
            # mode, and the geometric pre-pass is repeated per component.
            def per_solid(f_k, phi_k):
                def comp(fc):
                    return one(fc[None], phi_k)[0]

                return lax.map(jax.checkpoint(comp, prevent_cse=False), f_k)

            return jax.vmap(per_solid)(f, phi)
        return jax.vmap(one)(f, phi)

    if capacity is None or tile is None or f.shape[0] == 0:
        return dense(f, phi)
    ntx, nty = narrowband.n_tiles(phi.shape[-2:], tile)
    ladder = capacity if isinstance(capacity, (tuple, list)) else (capacity,)
    ladder = sorted({int(min(c, ntx * nty)) for c in ladder})

    # the tiles holding a node to update, found once for the choice of layout and the list
    flags = jax.vmap(lambda p: narrowband.tile_flags(_unknown(p, band, periodic), tile))(phi)

    def compact(cap):
        def run(f, phi):
            return jax.vmap(
                lambda f_k, phi_k, fl_k: _extend_tiles(
                    f_k, phi_k, fl_k, dx, dy, band, cap, tile, iters, periodic, smooth
                )
            )(f, phi, flags)

        return run

    most = jnp.max(jnp.sum(flags, axis=(-2, -1), dtype=jnp.int32))
    if len(ladder) == 1:
        return lax.cond(most <= ladder[0], compact(ladder[0]), dense, f, phi)
    # the first capacity that holds the largest band; past the last one, the full grid
    level = jnp.sum(jnp.asarray(ladder, dtype=jnp.int32) < most, dtype=jnp.int32)
    return lax.switch(level, [compact(c) for c in ladder] + [dense], f, phi)


def _unknown(phi, band, periodic):
    """The nodes the extrapolation updates: in the band and without a solid-only gradient."""
    return (phi <= band) & ~_gradient_valid(phi < 0, periodic)


def band_tiles(phi, band, tile, periodic: Periodic = (False, False)):
    """Number of tiles per solid that :func:`extend` lists (``phi`` (S, nx, ny))."""
    return jax.vmap(
        lambda p: jnp.sum(narrowband.tile_flags(_unknown(p, band, periodic), tile), dtype=jnp.int32)
    )(phi)


def _extend_tiles(f, phi, flags, dx, dy, band, capacity, tile, iters, periodic, smooth):
    """:func:`extend` for one solid on its listed tiles (f (C, nx, ny), phi (nx, ny), the
    flags (ntx, nty) of the tiles holding a node to update)."""
    nbm = narrowband
    tiles = nbm.build_from_flags(flags, capacity, periodic)
    nb = nbm.Neighbours(tiles)
    never = jnp.int32(iters + 1)
    slot = tiles.slot[:, None, None]

    # tiles with two ghost rows; everything the sweeps need is formed on them, the first
    # ghost row giving the fixed edge values next to tiles that are not listed
    P = nbm.gather(phi, tiles, tile, periodic, jnp.inf)  # beyond an edge: neither solid nor band
    F = nbm.gather(f, tiles, tile, periodic, 0.0)
    solid2, valid2 = P < 0, P <= band
    solid1, valid1, f1 = (nbm.interior(a, 1) for a in (solid2, valid2, F))
    gx1, gy1, gvalid1 = _solid_gradient_nb(
        f1, nbm.stencil_neighbours(F), solid1, nbm.stencil_neighbours(solid2), dx, dy
    )
    ag1 = jnp.where(gvalid1, 0, never).astype(jnp.int32)
    af1 = jnp.where(solid1, 0, never).astype(jnp.int32)
    gx1, gy1 = (jnp.where(gvalid1, g, 0.0) for g in (gx1, gy1))
    f1z = jnp.where(solid1, f1, 0.0)

    def inner(a):
        return nbm.interior(a, 1)

    gvalid, solid, valid = inner(gvalid1), inner(solid1), inner(valid1)
    update_g = valid & ~gvalid & slot
    update_f = valid & ~solid & slot
    normal = nbm.gather(unit_normal(phi, dx, dy, periodic), tiles, tile, periodic, 0.0, halo=0)
    fixed_g = dict(
        known=nbm.halos(gvalid1), arrival=nbm.halos(ag1), value=(nbm.halos(gx1), nbm.halos(gy1))
    )
    fixed_f = dict(known=nbm.halos(solid1), arrival=nbm.halos(af1), value=nbm.halos(f1z))
    f_ext, done = _extrapolate_core(
        (inner(gx1), inner(gy1), inner(f1z)),
        gvalid,
        solid,
        update_g,
        update_f,
        normal[0],
        normal[1],
        nb,
        fixed_g,
        fixed_f,
        iters,
        dx,
        dy,
    )
    f_t = jnp.where(done, f_ext, inner(f1))
    index = nbm.node_index(tiles, tile, phi.shape)
    if smooth is None:
        return nbm.scatter(f, index, f_t)

    fixed_sweeps = smooth.get("fixed_sweeps")
    h = jnp.minimum(dx, dy)
    limits = None
    if fixed_sweeps is None:
        # the interior's second differences (phi < -2h), read from the extrapolated field
        f = nbm.scatter(f, index, f_t)
        dnb = _DenseNeighbours(periodic)
        vxm, vxp, vym, vyp = dnb(phi <= band, False)
        limits = _interior_limits(
            f,
            phi < -2 * h,
            vxm & vxp,
            vym & vyp,
            dx,
            dy,
            dnb,
            smooth.get("ratio", 0.25),
            smooth.get("atol", 1e-3),
        )
    vm, vp, wm, wp = nbm.stencil_neighbours(valid1)
    f_s = _smooth_core(
        f_t,
        update_f,
        vm & vp,
        wm & wp,
        limits,
        nb,
        nbm.halos(f1),
        smooth.get("coef", 0.025) * h * h,
        dx,
        dy,
        smooth.get("max_sweeps", 80),
        fixed_sweeps,
        False,
        grid_ndim=3,
    )
    return nbm.scatter(f, index, f_s)


__all__ = [
    "band_tiles",
    "default_sweeps",
    "extend",
    "extrapolate_linear",
    "smooth_extrapolated",
    "solid_gradient",
]
