"""Extrapolation of a solid's reference map into a narrow band outside it, and smoothing.

Each solid's reference map ``xi = (X, Y[, Z])`` is known where its level set ``phi < 0``
and is needed in the band ``0 <= phi <= band`` outside (thesis 3.5 and 4.8; ``METHOD.md``,
"Reference map extrapolation").  Two steps, both on node scalars:

* :func:`extrapolate_linear` continues a scalar along the outward normal so that any
  affine field (rigid motion, uniform strain) is reproduced exactly in the band: a rigidly
  moved body has zero stress there.
* :func:`smooth_extrapolated` diffuses the extrapolated values only (thesis Algorithm 3),
  removing the tangential "striations" a purely normal extrapolation leaves.

Apply both to each component of ``xi`` (they are independent scalars).  Conventions: node
arrays ``(..., nx, ny)`` indexed ``[..., i, j]``, i along x; "solid" means ``phi < 0`` and
the "band" (the extrapolated nodes) means ``0 <= phi <= band``; nodes with ``phi > band``
are never touched.  Leading batch axes are supported natively (``f`` of shape
``(..., nx, ny)`` with ``phi`` broadcastable to it: one level set for the components of
``xi``, or one per solid), and both functions are also ``jax.vmap``-friendly (pure ``jnp``,
no Python control flow on values).  Static arguments: ``iters``, ``max_sweeps``,
``fixed_sweeps``, ``periodic``, ``return_sweeps``, and ``band``, ``dx``, ``dy`` (``dz``)
when ``iters`` is left to its default (the default sweep count is computed from them in
Python).

Two or three dimensions, as in :mod:`refmap.levelset`: the keyword ``dz=`` makes a call
3D (``extrapolate_linear(f, phi, dx, dy, band, dz=dz)``); the arrays are then
``(..., nx, ny, nz)``, ``periodic`` has three flags (default none), gradients have three
components and the stencils six neighbours (x-, x+, y-, y+, z-, z+).  One code path: the
stencils loop over the axes, and in 2D they perform the original arithmetic in the
original order, so 2D results are bitwise unchanged (tested against a frozen copy).  The
band-tile layout of :func:`extend` (``capacity``, :mod:`refmap.narrowband`) works in both:
squares of about 8 nodes a side in 2D, cubes of about 8 in 3D.

Domain edges: without ``periodic`` nothing beyond the edge is known, so extrapolation and
one-sided differences use in-domain nodes only, and a second difference across the edge is
taken as 0 (the linear-extrapolation ghost ``2 f_0 - f_1`` gives exactly that); the normal
``grad phi / |grad phi|`` uses the linear ghost of ``phi`` (:func:`refmap.levelset.unit_normal`).
With ``periodic=(px, py[, pz])`` the axis wraps.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from refmap import narrowband
from refmap.levelset import Periodic, _dims, _neighbours, _sum, normalised, unit_normal


def _nb(a, axis, periodic, fill):
    """Neighbours along ``axis`` with a constant beyond a non-periodic edge."""
    return _neighbours(a, axis, periodic, edge="fill", fill=fill)


def _pairs(t):
    """The per-axis pairs ``(t[0], t[1]), (t[2], t[3]), ...`` of a neighbour list."""
    return [(t[2 * a], t[2 * a + 1]) for a in range(len(t) // 2)]


def default_sweeps(band, dx, dy, *, dz=None) -> int:
    """Default Jacobi sweep count of :func:`extrapolate_linear`: ``ceil(sqrt(d) band / h) + 3``.

    A sweep moves information one node along one axis, so reaching a band node at distance
    ``band`` along a diagonal normal takes ``sqrt(2) band / h`` sweeps in 2D,
    ``sqrt(3) band / h`` in 3D (``dz`` given; the Manhattan length of the path), plus a few
    for the offset of the first band layer.
    """
    if dz is None:
        h = min(float(dx), float(dy))
        return int(math.ceil(math.sqrt(2.0) * float(band) / h - 1e-9)) + 3
    h = min(float(dx), float(dy), float(dz))
    return int(math.ceil(math.sqrt(3.0) * float(band) / h - 1e-9)) + 3


def solid_gradient(f, phi, dx, dy, periodic: Periodic | None = None, *, dz=None):
    """Gradient of ``f`` at solid nodes from solid values only.

    Central differences where both neighbours along an axis are solid (``phi < 0``),
    one-sided towards the solid otherwise.  Exact for affine ``f``.

    Returns ``(gx, gy, valid)`` (``(gx, gy, gz, valid)`` with ``dz``): ``valid`` (shape of
    ``phi``) is True at solid nodes where every component could be formed (a node with no
    solid neighbour along an axis, e.g. in a one-cell sliver or against a non-periodic edge,
    is not valid); the components are meaningless elsewhere.
    """
    h, periodic = _dims(dx, dy, dz, periodic, "solid_gradient")
    f = jnp.asarray(f)
    solid = jnp.asarray(phi) < 0
    nb = _DenseNeighbours(periodic)
    return _solid_gradient_nb(f, nb(f, 0.0), solid, nb(solid, False), h)


def _solid_gradient_nb(f, f_nb, solid, s_nb, h):
    """:func:`solid_gradient` from the neighbours (x-, x+, y-, y+[, z-, z+]) of f and of the
    solid mask, ``h`` the spacings: ``(*g, valid)``."""
    g = []
    valid = solid
    for ha, (fm, fp), (sm, sp) in zip(h, _pairs(f_nb), _pairs(s_nb), strict=True):
        g.append(
            jnp.where(sm & sp, (fp - fm) / (2 * ha), jnp.where(sp, (fp - f) / ha, (f - fm) / ha))
        )
        valid = valid & (sm | sp)
    return (*g, valid)


def _gradient_valid(solid, periodic):
    """Solid nodes with a solid neighbour along each axis (geometry only, shape of phi)."""
    d = len(periodic)
    valid = solid
    for a in range(d):
        sm, sp = _nb(solid, a - d, periodic[a], False)
        valid = valid & (sm | sp)
    return valid


def extrapolate_linear(
    f,
    phi,
    dx,
    dy,
    band,
    iters: int | None = None,
    periodic: Periodic | None = None,
    *,
    dz=None,
):
    """Extend a node scalar from the solid (``phi < 0``) into the band ``0 <= phi <= band``.

    Linear extrapolation along the outward normal ``n = grad phi / |grad phi|`` (Aslam 2004,
    "constant then linear"), with the gradient extrapolated as ``d`` independent scalars:

    (a) ``g = (gx, gy[, gz])`` at solid nodes from solid values only (:func:`solid_gradient`);
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
    outside the band or the domain) falls back on the mean over its known ``2d`` neighbours
    ``nb`` of ``q_nb`` for the gradient and ``f_nb + (x - x_nb) . g`` for ``f``.

    Exactness: every formula above reproduces an affine ``f = a . x + c`` exactly
    (one-sided and central differences of an affine field are exact; the upwind relation is
    exact for it, over any subset of axes), so an affine ``f`` is reproduced to round-off at
    every band node reached, whatever ``phi``.  A smooth ``f`` is extrapolated with error
    O(h^2) at a fixed number of cells from the interface (O(h d) + O(d^2) at distance d).

    Which nodes are known before each sweep depends on ``phi`` only, so it is found first by
    a cheap boolean pre-pass (shared by all components of a batch with one ``phi``); the
    value sweeps then only gather the ``2d`` neighbours of ``g`` and ``f``.

    Cost: ``iters`` boolean pre-pass sweeps plus ``iters`` value sweeps, each a
    ``(2d+1)``-point stencil on ``d + 1`` arrays per component.  A sweep moves information
    one node along an axis.  The default :func:`default_sweeps` (``ceil(sqrt(2) band / h) +
    3``, 12 for ``band = 6h``; ``sqrt(3)`` in 3D) reaches the whole band along diagonals
    too and lets the upwind values settle (measured in 2D: within 1e-5 of the fully
    converged sweeps for the shapes in the tests; ``ceil(band / h) + 3`` = 9 sweeps also
    reaches every band node but leaves differences up to ~1e-2 for
    ``sin(2x + 1) cos(1.5y)`` at the outer diagonal band nodes).  With fewer sweeps the
    outer band nodes keep their input value (not reached) or an off-normal, still
    affine-exact, estimate.

    Args:
        f: node scalar, ``(..., nx, ny)`` (``(..., nx, ny, nz)`` with ``dz``); values at
            ``phi >= 0`` are ignored (may be anything finite or not).
        phi: level set broadcastable to ``f`` (negative in the solid).
        dx, dy: spacings.
        band: width of the extrapolation band (a distance, e.g. ``6 * dx``).
        iters: number of Jacobi sweeps (static); default :func:`default_sweeps`.
        periodic: static (x, y[, z]) wrap flags (default none).
        dz: the z spacing: given, the arrays are 3D.

    Returns:
        ``f`` with its band values replaced; solid nodes and nodes with ``phi > band`` (and any
        band node not reached within ``iters`` sweeps) are returned unchanged.
    """
    h, periodic = _dims(dx, dy, dz, periodic, "extrapolate_linear")
    d = len(h)
    f = jnp.asarray(f)
    phi = jnp.asarray(phi)
    if f.ndim < d:
        names = ", ".join(("nx", "ny", "nz")[:d])
        raise ValueError(f"f must have shape (..., {names}), got {f.shape}")
    if iters is None:
        iters = default_sweeps(band, dx, dy, dz=dz)
    shape = jnp.broadcast_shapes(f.shape, phi.shape)
    f = jnp.broadcast_to(f, shape)

    solid = phi < 0
    in_band = phi <= band
    update_f = in_band & ~solid
    *g, gvalid = solid_gradient(f, phi, dx, dy, periodic, dz=dz)
    update_g = in_band & ~gvalid
    normal = unit_normal(phi, dx, dy, periodic, dz=dz)
    nb = _DenseNeighbours(periodic)
    fixed_g = dict(known=False, arrival=jnp.int32(iters + 1), value=(0.0,) * d)
    fixed_f = dict(known=False, arrival=jnp.int32(iters + 1), value=0.0)
    # Values that are not known yet are never used (weight 0), but may be NaN: zero them.
    values = tuple(jnp.where(gvalid, ga, 0.0) for ga in g) + (jnp.where(solid, f, 0.0),)
    f_ext, done = _extrapolate_core(
        values,
        gvalid,
        solid,
        update_g,
        update_f,
        tuple(normal[(Ellipsis, a) + (slice(None),) * d] for a in range(d)),
        nb,
        fixed_g,
        fixed_f,
        iters,
        h,
    )
    return jnp.where(done, f_ext, f)


class _DenseNeighbours:
    """The ``2d`` neighbours (x-, x+, y-, y+[, z-, z+]) of a grid array, a constant beyond
    an edge (``d = len(periodic)``)."""

    def __init__(self, periodic):
        self.periodic = tuple(periodic)

    def __call__(self, a, fill):
        d = len(self.periodic)
        out = ()
        for ax in range(d):
            out += _nb(a, ax - d, self.periodic[ax], fill)
        return out


def _extrapolate_core(
    values, gvalid, solid, update_g, update_f, nrm, nb, fixed_g, fixed_f, iters, h
):
    """The sweeps of :func:`extrapolate_linear` on any layout of the unknowns.

    ``values = (*g, f)`` (``d`` gradient components then f) and the masks are arrays of one
    layout (the grid, or a compacted list of band nodes); ``nrm`` the ``d`` normal
    components and ``h`` the spacings; ``nb(a, fill)`` returns the ``2d`` neighbours of a
    layout array, taking ``fill`` (a constant, or per-neighbour arrays) where the neighbour
    is not part of the layout.  ``fixed_g``/``fixed_f`` hold those fills for the gradient's
    and for f's ``known``, ``arrival`` and ``value`` (``fixed_g["value"]`` one per
    component).  Returns ``(f, done)``: the swept f and the nodes whose f was reached (to be
    written back).
    """
    d = len(h)
    never = jnp.int32(iters + 1)

    def any_neighbour(k, fill):
        ks = nb(k, fill)
        out = ks[0]
        for kk in ks[1:]:
            out = out | kk
        return out

    # Which values are known before sweep s depends on the geometry only (not on f), so it
    # is computed once (shared by every component using this phi) as an arrival sweep:
    # a node is known before sweep s iff arrival <= s.  A gradient becomes known in the sweep
    # after any neighbour's gradient is; f in the sweep after any neighbour's f is,
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

    # Static neighbour weights, order (x-, x+, y-, y+[, z-, z+]): |n_d| / h_d on the upwind
    # (solid) side of each axis, 0 on the other.
    w = [jnp.abs(n) / ha for n, ha in zip(nrm, h, strict=True)]
    zero = jnp.zeros_like(w[0])
    w_up = ()
    for n, wa in zip(nrm, w, strict=True):
        w_up += (jnp.where(n > 0, wa, zero), jnp.where(n < 0, wa, zero))
    g_arr = nb(ag, fixed_g["arrival"])
    f_arr = nb(af, fixed_f["arrival"])

    def pair_sum(terms):
        """``(t0 + t1) + (t2 + t3) [+ (t4 + t5)]``: the 2D expression tree, extended."""
        return _sum([m + p for m, p in _pairs(terms)])

    def weights(arr, s):
        """Upwind weights of the known neighbours, or 1 per known neighbour if none."""
        known = [a <= s for a in arr]
        up = [jnp.where(k, wu, 0.0) for k, wu in zip(known, w_up, strict=True)]
        has_up = pair_sum(up) > 0
        c = [jnp.where(has_up, u, k.astype(u.dtype)) for u, k in zip(up, known, strict=True)]
        total = pair_sum(c)
        return c, 1 / jnp.where(total > 0, total, 1.0)

    g_fill = fixed_g["value"]
    f_fill = fixed_f["value"]

    def sweep(s, state):
        # Both regimes are one formula over the 2d neighbours nb with weights c_nb:
        #   q = sum c q_nb / sum c,   f = sum c (f_nb + (x - x_nb) . g) / sum c,
        # which is (b)/(c) above when c are the upwind weights (since
        # |n_d| / h_d * (x - x_up)_d = n_d) and the fallback mean when c are 0/1.
        *g, f = state
        c, inv = weights(g_arr, s)
        cp = _pairs(c)
        new = []
        for q, fill in zip(g, g_fill, strict=True):
            qn = _pairs(nb(q, fill))
            new.append(
                _sum([cm * qm + cq * qp for (cm, cq), (qm, qp) in zip(cp, qn, strict=True)]) * inv
            )
        g_now = update_g & (ag <= s + 1)
        g = [jnp.where(g_now, nq, q) for nq, q in zip(new, g, strict=True)]

        c, inv = weights(f_arr, s)
        fn = _pairs(nb(f, f_fill))
        sh = [ha * ga for ha, ga in zip(h, g, strict=True)]
        f_new = (
            _sum(
                [
                    cm * (fm + sa) + cq * (fp - sa)
                    for (cm, cq), (fm, fp), sa in zip(_pairs(c), fn, sh, strict=True)
                ]
            )
            * inv
        )
        f = jnp.where(update_f & (af <= s + 1), f_new, f)
        return (*g, f)

    assert len(values) == d + 1
    f_ext = _checkpointed_sweeps(sweep, iters, tuple(values))[-1]
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


def _second_differences(f, ok, h, nb, fill):
    """``(f_xx, f_yy[, f_zz])`` by 3-point differences, 0 where a stencil node is not valid
    (``ok`` one mask per axis, ``h`` the spacings)."""
    out = []
    for oka, ha, (fm, fp) in zip(ok, h, _pairs(nb(f, fill)), strict=True):
        out.append(jnp.where(oka, (fp - 2 * f + fm) / (ha * ha), 0.0))
    return tuple(out)


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
    periodic: Periodic | None = None,
    fixed_sweeps: int | None = None,
    return_sweeps: bool = False,
    check_every: int = 1,
    *,
    dz=None,
):
    """Diffuse the extrapolated values of ``f`` in pseudo-time (thesis Algorithm 3).

    Each sweep does ``f <- f + coef h^2 (f_xx + f_yy)`` (``+ f_zz`` in 3D; ``h`` the
    smallest spacing, 3-point second differences, Jacobi) at the extrapolated nodes
    ``0 <= phi <= band`` only; the solid's own values (``phi < 0``) and nodes beyond the
    band are never changed.  A second difference whose stencil reaches a node that is not
    valid (``phi > band``, or beyond a non-periodic edge) is taken as 0 along that axis (as
    with a linearly extrapolated ghost), so an affine ``f`` is a fixed point everywhere; the
    consequence is that the outermost band layer is smoothed only along the axes whose both
    neighbours lie in the band (to smooth the whole band, extrapolate and smooth over a band
    two cells wider than needed).

    Stopping rule (while-loop): before each sweep the largest ``|f_dd|`` over the band is
    compared, per axis d and per component, with that over the solid interior
    (``phi < -2h``); sweeping stops once ``band_max <= ratio * interior_max + atol`` on
    every axis, or after ``max_sweeps`` sweeps.  The thesis's values are ``coef = 0.025``
    (its ``0.000025`` at ``dx = 4/128``), ``ratio = 0.25``, at most 80 sweeps.  With a
    leading batch axis the rule is applied to each element separately (as ``vmap`` of
    ``while_loop`` would).  With ``check_every = m > 1`` the rule is tested only before
    sweeps 0, m, 2m, ...: a test passed there stops at once, a test failed there is
    followed by m sweeps (fewer where ``max_sweeps`` ends first), so the loop does up to
    ``m - 1`` sweeps more than the test before every sweep would, and the same when it runs
    to ``max_sweeps`` or stops at once (an affine field).  The test costs as much as a
    sweep (a second pass over the stencil that XLA does not fuse with the update), so
    ``m = 4`` makes a run of the full 80 sweeps about 1.7x cheaper.

    For reverse-mode differentiation pass ``fixed_sweeps=k``: exactly ``k`` sweeps in a
    ``fori_loop``, no stopping rule.

    In practice a first-order normal extrapolation of a curved (non-affine) field already
    has band second differences comparable to the interior's (they grow like 1/h at a fixed
    distance, from the grid-scale variation of the upwind error), so with ``ratio = 0.25``
    the rule is seldom met and the loop runs ``max_sweeps`` sweeps, as the thesis's code
    (whose interior maximum was effectively 0) always did; an affine field stops at once.

    Cost: per sweep one ``(2d+1)``-point stencil and, in the while-loop, one masked max
    reduction (about 3x the cost of a ``fixed_sweeps`` sweep on CPU).  Stability: the
    explicit update is stable and monotone for ``coef <= 1 / (2d)`` on a uniform grid; at
    the default a grid-scale (2h) tangential mode decays by ``1 - 4 coef = 0.9`` per sweep
    (along one axis), a 4h mode by 0.95, so 80 sweeps take them down by 2e-4 and 2e-2 (less
    next to the outermost layer).

    Args:
        f: node scalar(s) ``(..., nx, ny)`` (``(..., nx, ny, nz)`` with ``dz``), already
            extrapolated (:func:`extrapolate_linear`).
        phi: level set broadcastable to ``f``.
        dx, dy, band: spacings and band width (the same band as the extrapolation).
        coef, ratio, atol: diffusion number, stopping ratio and absolute tolerance (units of
            ``f / length^2``).
        max_sweeps: cap on the sweeps of the while-loop (static).
        periodic: static (x, y[, z]) wrap flags (default none).
        fixed_sweeps: static; if given, run exactly this many sweeps instead.
        check_every: static; sweeps per test of the stopping rule (1: before every sweep).
        return_sweeps: static; also return the number of sweeps done (per batch element).
        dz: the z spacing: given, the arrays are 3D.

    Returns:
        The smoothed ``f`` (and the sweep counts, int32 of the batch shape, if
        ``return_sweeps``).
    """
    h_ax, periodic = _dims(dx, dy, dz, periodic, "smooth_extrapolated")
    d = len(h_ax)
    f = jnp.asarray(f)
    phi = jnp.asarray(phi)
    shape = jnp.broadcast_shapes(f.shape, phi.shape)
    f = jnp.broadcast_to(f, shape)
    h = jnp.minimum(dx, dy)
    if d == 3:
        h = jnp.minimum(h, dz)

    solid = phi < 0
    valid = phi <= band
    ext = valid & ~solid
    nb = _DenseNeighbours(periodic)
    ok = tuple(vm & vp for vm, vp in _pairs(nb(valid, False)))
    limits = None
    if fixed_sweeps is None:
        limits = _interior_limits(f, phi < -2 * h, ok, h_ax, nb, ratio, atol)
    return _smooth_core(
        f,
        ext,
        ok,
        limits,
        nb,
        0.0,
        coef * h * h,
        h_ax,
        max_sweeps,
        fixed_sweeps,
        return_sweeps,
        grid_ndim=d,
        check_every=check_every,
    )


def _interior_limits(f, interior, ok, h, nb, ratio, atol):
    """The smoothing's stopping limits ``ratio * max |f_dd| over the interior + atol``, one
    per axis (``ok`` one mask per axis, ``h`` the spacings)."""
    axes = tuple(range(-len(h), 0))

    def masked_max(a, mask):
        return jnp.max(jnp.where(mask, jnp.abs(a), 0.0), axis=axes)

    d2 = _second_differences(f, ok, h, nb, 0.0)
    # interior values never change, so neither do these limits
    return tuple(ratio * masked_max(dd, interior) + atol for dd in d2)


def _smooth_core(
    f,
    ext,
    ok,
    limits,
    nb,
    fill,
    step,
    h,
    max_sweeps,
    fixed_sweeps,
    return_sweeps,
    grid_ndim,
    check_every=1,
):
    """The sweeps of :func:`smooth_extrapolated` on any layout (see :func:`_extrapolate_core`):
    ``f`` and the masks are layout arrays whose last ``grid_ndim`` axes are the layout's,
    ``ok`` one second-difference mask per axis, ``h`` the spacings, ``limits`` the per-batch
    stopping limits, one per axis (None with ``fixed_sweeps``), ``check_every`` the sweeps
    per test of the stopping rule."""
    if not (isinstance(check_every, int) and check_every >= 1):
        raise ValueError(f"smoothing check_every must be an integer >= 1, got {check_every!r}")
    axes = tuple(range(-grid_ndim, 0))
    batch = f.shape[:-grid_ndim]

    def expand(a):
        return a.reshape(a.shape + (1,) * grid_ndim)

    def sweep_with(f, d2, active):
        return jnp.where(ext & active, f + step * _sum(list(d2)), f)

    if fixed_sweeps is not None:

        def body(_, f):
            return sweep_with(f, _second_differences(f, ok, h, nb, fill), True)

        f = lax.fori_loop(0, fixed_sweeps, body, f)
        if return_sweeps:
            return f, jnp.full(batch, fixed_sweeps, dtype=jnp.int32)
        return f

    lims = [expand(lim) for lim in limits]

    def cond(state):
        k, _, active, _ = state
        return (k < max_sweeps) & jnp.any(active)

    def body(state):
        k, f, _, count = state
        d2 = _second_differences(f, ok, h, nb, fill)
        # one reduction: is any band node above its limit along any axis?
        excess = jnp.abs(d2[0]) - lims[0]
        for dd, lim in zip(d2[1:], lims[1:], strict=True):
            excess = jnp.maximum(excess, jnp.abs(dd) - lim)
        active = jnp.max(jnp.where(ext, excess, -1.0), axis=axes) > 0
        f = sweep_with(f, d2, expand(active))

        # the block's other sweeps, untested (none past max_sweeps; none when m = 1)
        def untested(j, f):
            on = expand(active & (k + j < max_sweeps))
            return sweep_with(f, _second_differences(f, ok, h, nb, fill), on)

        f = lax.fori_loop(1, check_every, untested, f)
        done = jnp.minimum(check_every, max_sweeps - k)
        return k + check_every, f, active, count + done * active.astype(jnp.int32)

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
    periodic: Periodic | None = None,
    smooth: dict | None = None,
    tile: tuple[int, int] | None = None,
    *,
    dz=None,
    window: tuple[int, ...] | None = None,
):
    """:func:`extrapolate_linear` then :func:`smooth_extrapolated`, for several solids at once.

    ``f`` is ``(S, C, nx, ny)`` (C components per solid sharing its level set), ``phi``
    ``(S, nx, ny)``; in 3D (``dz`` given) ``(S, C, nx, ny, nz)`` and ``(S, nx, ny, nz)``.
    ``smooth`` holds the keyword arguments of the smoothing (``coef``, ``max_sweeps``,
    ``ratio``, ``atol``, ``check_every``, ``fixed_sweeps``; None: no smoothing).

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
    the full grid when none does.  The tiles are squares (cubes in 3D) of about
    :data:`TILE_TARGET` nodes a side.

    ``window`` (3D): a static box size (one number of nodes per axis; the full length on a
    periodic axis).  Each solid's sweeps then run on a box of that size placed round its
    band (``phi <= band``) with :data:`WINDOW_MARGIN` nodes to spare on every side, cut
    out with ``lax.dynamic_slice`` and written back: every node the sweeps change and every
    node they read lies inside, so the result is the full grid's (the arithmetic per node
    is the same).  When a band does not fit (a body grown or deformed beyond it, a body
    across a periodic edge), the call falls back on the full grid.
    """
    h, periodic = _dims(dx, dy, dz, periodic, "extend")
    nd = len(h)
    f = jnp.asarray(f)
    phi = jnp.asarray(phi)
    if iters is None:
        iters = default_sweeps(band, dx, dy, dz=dz)
    if tile is None and capacity is not None:
        tile = narrowband.tile_shape(phi.shape[-nd:], periodic, target=TILE_TARGET[nd])

    def dense(f, phi):
        def one(f_k, phi_k):
            out = extrapolate_linear(f_k, phi_k[None], dx, dy, band, iters, periodic, dz=dz)
            if smooth is None:
                return out
            return smooth_extrapolated(
                out, phi_k[None], dx, dy, band, periodic=periodic, dz=dz, **smooth
            )

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

    if window is not None and dz is not None and f.shape[0] > 0:
        return _extend_window(f, phi, band, tuple(int(w) for w in window), dense, periodic)
    if capacity is None or tile is None or f.shape[0] == 0:
        return dense(f, phi)
    total = math.prod(narrowband.n_tiles(phi.shape[-nd:], tile))
    ladder = capacity if isinstance(capacity, (tuple, list)) else (capacity,)
    ladder = sorted({int(min(c, total)) for c in ladder})

    # the tiles holding a node to update, found once for the choice of layout and the list
    flags = jax.vmap(lambda p: narrowband.tile_flags(_unknown(p, band, periodic), tile))(phi)

    def compact(cap):
        def run(f, phi):
            return jax.vmap(
                lambda f_k, phi_k, fl_k: _extend_tiles(
                    f_k, phi_k, fl_k, h, band, cap, tile, iters, periodic, smooth
                )
            )(f, phi, flags)

        return run

    # the first capacity that holds the largest band; past the last one, the full grid
    level = narrowband.ladder_level(flags, ladder)
    return narrowband.switch(level, [compact(c) for c in ladder] + [dense], f, phi)


#: default tile side of :func:`extend`'s band tiles, by grid dimension: 8 x 8 in 2D, 8 x 8 x 8
#: in 3D.  A larger tile lists more of the grid round a thin band (a 16^3 tile holds 4096
#: nodes; docs/benchmarks.md, "Band tiles in 3D").  In 2D 16 x 16 was the first choice; 8 x 8
#: made whole steps 14-30 % faster at 128^2-256^2 (rotor, 1-64 discs; "Smaller tiles in 2D")
TILE_TARGET = {2: 8, 3: 8}

#: nodes kept between a band and the edge of its window (:func:`extend`'s ``window``): the
#: band's nodes then read only nodes inside (the normal of phi, the neighbours of the sweeps)
WINDOW_MARGIN = 2


def band_window_extent(phi, band, margin: int = WINDOW_MARGIN) -> tuple[int, ...]:
    """The largest extent (nodes per axis, over the solids) of the boxes round each band
    (``phi (S, ...)`` with ``phi <= band``) plus ``margin`` on each side: host-side, for
    choosing a static ``window``."""
    phi = np.asarray(phi)
    nd = phi.ndim - 1
    ext = [0] * nd
    for k in range(phi.shape[0]):
        m = phi[k] <= band
        if not m.any():
            continue
        for a in range(nd):
            line = m.any(axis=tuple(b for b in range(nd) if b != a))
            idx = np.nonzero(line)[0]
            ext[a] = max(ext[a], int(idx[-1] - idx[0] + 1 + 2 * margin))
    return tuple(ext)


def window_placement(phi, band, window, periodic):
    """Where :func:`extend`'s ``window`` boxes go: ``(starts (S, d) int32, fits (S,) bool,
    W)`` for level sets ``phi (S, ...)``: each box (size ``W``, the window with the whole
    length of periodic axes) centred on its band's box, moved inside the grid; ``fits``
    where the band with ``WINDOW_MARGIN`` nodes to spare lies inside (or reaches a grid
    edge that the box shares)."""
    shape = phi.shape[1:]
    nd = len(shape)
    W = tuple(n if p else min(w, n) for w, n, p in zip(window, shape, periodic, strict=True))

    def placement(phi_k):
        m = phi_k <= band
        starts, fits = [], jnp.asarray(True)
        for a in range(nd):
            line = jnp.any(m, axis=tuple(b for b in range(nd) if b != a))
            n = shape[a]
            idx = jnp.arange(n)
            lo = jnp.min(jnp.where(line, idx, n))
            hi = jnp.max(jnp.where(line, idx, -1))
            start = jnp.clip((lo + hi + 1) // 2 - W[a] // 2, 0, n - W[a])
            ok_lo = (lo - WINDOW_MARGIN >= start) | (start == 0)
            ok_hi = (hi + WINDOW_MARGIN <= start + W[a] - 1) | (start + W[a] == n)
            fits = fits & ok_lo & ok_hi & (hi >= lo)
            starts.append(start.astype(jnp.int32))
        return jnp.stack(starts), fits

    starts, fits = jax.vmap(placement)(phi)
    return starts, fits, W


def _extend_window(f, phi, band, window, dense, periodic):
    """:func:`extend`'s ``window`` path: each solid's sweeps on a box round its band (the
    whole length of a periodic axis, whose wrap the box must keep)."""
    starts, fits, W = window_placement(phi, band, window, periodic)

    def windowed(f, phi):
        zero = jnp.zeros((), jnp.int32)

        def cut(a, st, lead):
            return lax.dynamic_slice(a, (zero,) * lead + tuple(st), a.shape[:lead] + W)

        fw = jax.vmap(lambda a, st: cut(a, st, 1))(f, starts)
        pw = jax.vmap(lambda a, st: cut(a, st, 0))(phi, starts)
        out = dense(fw, pw)
        return jax.vmap(lambda a, o, st: lax.dynamic_update_slice(a, o, (zero, *st)))(f, out, starts)

    return narrowband.switch(jnp.where(jnp.all(fits), 0, 1), [windowed, dense], f, phi)


def _unknown(phi, band, periodic):
    """The nodes the extrapolation updates: in the band and without a solid-only gradient."""
    return (phi <= band) & ~_gradient_valid(phi < 0, periodic)


def band_tiles(phi, band, tile, periodic: Periodic | None = None):
    """Number of tiles per solid that :func:`extend` lists (``phi`` (S, nx, ny[, nz]))."""
    periodic = (False,) * len(tile) if periodic is None else tuple(periodic)
    return jax.vmap(
        lambda p: jnp.sum(narrowband.tile_flags(_unknown(p, band, periodic), tile), dtype=jnp.int32)
    )(phi)


def _tile_normal(P, h, periodic):
    """:func:`refmap.levelset.unit_normal` at the inner nodes of tiles gathered with two
    ghost rows and +inf beyond a non-periodic edge (P (cap, tx + 4, ty + 4[, tz + 4])):
    (d, cap, tx, ty[, tz]), 0 at nodes beyond the grid, as the gathered full-grid normal."""
    nd = len(h)
    P1 = narrowband.interior(P, 1, nd)
    out1 = jnp.isinf(P1)
    Ps = jnp.where(out1, 0.0, P1)  # finite everywhere (no NaN in reverse mode)
    c = narrowband.interior(Ps, 1, nd)
    nbs = narrowband.stencil_neighbours(Ps, nd)
    onb = narrowband.stencil_neighbours(out1, nd)
    pairs = []
    for a in range(nd):
        m, p = nbs[2 * a], nbs[2 * a + 1]
        if not periodic[a]:  # the linear ghost 2 a_0 - a_1 beyond the edge
            m, p = jnp.where(onb[2 * a], 2 * c - p, m), jnp.where(onb[2 * a + 1], 2 * c - m, p)
        pairs.append((m, p))
    g = [(p - m) / (2 * h[a]) for a, (m, p) in enumerate(pairs)]
    beyond = narrowband.interior(out1, 1, nd)
    return jnp.stack([jnp.where(beyond, 0.0, n) for n in normalised(g)])


def _extend_tiles(f, phi, flags, h, band, capacity, tile, iters, periodic, smooth):
    """:func:`extend` for one solid on its listed tiles (f (C, nx, ny[, nz]), phi (nx, ny[,
    nz]), the flags (ntx, nty[, ntz]) of the tiles holding a node to update, ``h`` the
    spacings)."""
    nbm = narrowband
    nd = len(h)
    tiles = nbm.build_from_flags(flags, capacity, periodic)
    nb = nbm.Neighbours(tiles, cap_last=True)
    never = jnp.int32(iters + 1)
    slot = tiles.slot  # the sweeps run with the slot axis innermost (nbm.cap_last)

    # tiles with two ghost rows; everything the sweeps need is formed on them, the first
    # ghost row giving the fixed edge values next to tiles that are not listed
    P = nbm.gather(phi, tiles, tile, periodic, jnp.inf)  # beyond an edge: neither solid nor band
    F = nbm.gather(f, tiles, tile, periodic, 0.0)
    solid2, valid2 = P < 0, P <= band
    solid1, valid1, f1 = (nbm.interior(a, 1, nd) for a in (solid2, valid2, F))
    *g1, gvalid1 = _solid_gradient_nb(
        f1, nbm.stencil_neighbours(F, nd), solid1, nbm.stencil_neighbours(solid2, nd), h
    )
    ag1 = jnp.where(gvalid1, 0, never).astype(jnp.int32)
    af1 = jnp.where(solid1, 0, never).astype(jnp.int32)
    g1 = [jnp.where(gvalid1, g, 0.0) for g in g1]
    f1z = jnp.where(solid1, f1, 0.0)
    # from here on in the sweeps' layout (..., tx + 2, ty + 2[, tz + 2], cap)
    g1 = [nbm.cap_last(g, nd) for g in g1]
    gvalid1, ag1, af1, f1z, f1, solid1, valid1 = (
        nbm.cap_last(a, nd) for a in (gvalid1, ag1, af1, f1z, f1, solid1, valid1)
    )

    def inner(a):
        return nbm.interior(a, 1, nd, tail=1)

    def halos(a):
        return nbm.halos(a, nd, tail=1)

    gvalid, solid, valid = inner(gvalid1), inner(solid1), inner(valid1)
    update_g = valid & ~gvalid & slot
    update_f = valid & ~solid & slot
    normal = _tile_normal(P, h, periodic)
    normal = nbm.cap_last(normal, nd)
    fixed_g = dict(known=halos(gvalid1), arrival=halos(ag1), value=tuple(halos(g) for g in g1))
    fixed_f = dict(known=halos(solid1), arrival=halos(af1), value=halos(f1z))
    f_ext, done = _extrapolate_core(
        tuple(inner(g) for g in g1) + (inner(f1z),),
        gvalid,
        solid,
        update_g,
        update_f,
        tuple(normal[a] for a in range(nd)),
        nb,
        fixed_g,
        fixed_f,
        iters,
        h,
    )
    f_t = jnp.where(done, f_ext, inner(f1))
    index = nbm.node_index(tiles, tile, phi.shape)
    if smooth is None:
        return nbm.scatter(f, index, nbm.cap_first(f_t, nd))

    fixed_sweeps = smooth.get("fixed_sweeps")
    hmin = jnp.minimum(h[0], h[1])
    if nd == 3:
        hmin = jnp.minimum(hmin, h[2])
    limits = None
    if fixed_sweeps is None:
        # the interior's second differences (phi < -2h), read from the extrapolated field
        f = nbm.scatter(f, index, nbm.cap_first(f_t, nd))
        dnb = _DenseNeighbours(periodic)
        limits = _interior_limits(
            f,
            phi < -2 * hmin,
            tuple(vm & vp for vm, vp in _pairs(dnb(phi <= band, False))),
            h,
            dnb,
            smooth.get("ratio", 0.25),
            smooth.get("atol", 1e-3),
        )
    f_s = _smooth_core(
        f_t,
        update_f,
        tuple(vm & vp for vm, vp in _pairs(nbm.stencil_neighbours(valid1, nd, tail=1))),
        limits,
        nb,
        halos(f1),
        smooth.get("coef", 0.025) * hmin * hmin,
        h,
        smooth.get("max_sweeps", 80),
        fixed_sweeps,
        False,
        grid_ndim=nd + 1,
        check_every=smooth.get("check_every", 1),
    )
    return nbm.scatter(f, index, nbm.cap_first(f_s, nd))


__all__ = [
    "band_tiles",
    "default_sweeps",
    "extend",
    "extrapolate_linear",
    "smooth_extrapolated",
    "solid_gradient",
]
