"""Each solid's stress, blend weights and density on the tiles that hold it (issue 14).

:meth:`refmap.model.Model.derived` mixes the fluid's stress with every solid's: at each
corner ``sigma = w_f sigma_f + sum_k w_k sigma_k`` with the solid fractions ``w_k = 1 - H_k``
of the blend (renormalised where they sum past 1), and at each node the density likewise.
Computed on the whole grid, every solid costs a full grid of erf weights, map gradients,
deformation gradients and constitutive stresses, although a small disc touches a few per
cent of it: in the suspension at 256^2 this was the largest cost of an added disc
(docs/benchmarks.md, "Where a many-disc step goes now").

A solid's fraction ``1 - H(phi)`` is exactly zero beyond a distance :func:`cutoff` of its
interface (erf: ``erf(x)`` rounds to 1 for ``x > 5.93`` in float64, so ``6 w``; the sine
kernel: its half-width), and its stress is zero where its fraction is.  So each solid's
contributions are computed only on the tiles (``T`` nodes a side, as the band sweeps'
:data:`refmap.extrapolation.TILE_TARGET`) whose corners or nodes lie within that distance,
and added into the grid: per corner the sums ``A_ab = sum_k (1 - H_k) sigma_k,ab`` and
``T_c = sum_k (1 - H_k)``, per node ``B = sum_k (1 - H_k) avg(rho_k)`` and ``T_n``.  The
renormalisation ``1 / max(T, 1)`` is common to all solids at a point, so the mixed fields
follow from these sums (:func:`mix`): where at most two solids overlap and their fractions
sum below 1 (everywhere but deep overlaps), the arithmetic is the full-grid one, operation
for operation, and the results agree to round-off (tested in ``tests/test_solid_tiles.py``).

Layout.  Everything works in the index space of the fields padded with one ghost layer
(``(nx + 2, ny + 2)``; periodic axes already wrapped by the padding): corner ``i`` lies between
padded nodes ``i`` and ``i + 1``, node ``i`` is padded node ``i + 1``.  Tile ``p`` (per axis)
computes the corners and nodes ``p T .. p T + T - 1`` from the padded nodes
``p T .. p T + T + 1`` (a window of ``T + 2``), so tiles do not depend on each other and need
no halo exchange.  A solid's tiles are listed in a static number of slots, ``capacity``;
when a solid's region outgrows it, the caller falls back on the full-grid computation for
that step (same result).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
from jax import lax

from refmap import blend, narrowband, windows
from refmap.operators import corner_average, grad_corner, node_average

#: erf(x) is exactly 1.0 in float64 for x >= 5.9216 (checked in the tests): 1 - H = 0 there
ERF_ZERO = 6.0


def cutoff(kernel: str, width):
    """Distance from the interface beyond which a solid's fraction ``1 - H`` is exactly 0."""
    return (ERF_ZERO if blend.check_kernel(kernel) == "erf" else 1.0) * width


def n_tiles(shape, tile) -> tuple[int, ...]:
    """Tiles per axis: enough to hold the ``n + 1`` corners of an axis of ``n`` nodes."""
    return tuple(-(-(n + 1) // t) for n, t in zip(shape, tile, strict=True))


def window_min(phip, tile, extra: int = 0):
    """(S, ntx, nty[, ntz]): the least value of the padded level sets ``phip`` (S, nx + 2,
    ny + 2[, nz + 2]) in each tile's window.  One axis at a time (a separable minimum: a
    window of ``(T + 2)^d`` at once ran 8 times slower on a CPU).  ``extra``: ``phip`` has
    that many more ghost layers on each side (not read)."""
    nd = len(tile)
    shape = tuple(s - 2 - 2 * extra for s in phip.shape[-nd:])
    nt = n_tiles(shape, tile)
    m = narrowband.pad_high(phip, tuple(k * t + 2 for k, t in zip(nt, tile, strict=True)), jnp.inf, extra)
    lead = m.ndim - nd
    for a in range(nd):
        win = [1] * m.ndim
        stride = [1] * m.ndim
        win[lead + a] = tile[a] + 2
        stride[lead + a] = tile[a]
        m = lax.reduce_window(m, jnp.asarray(jnp.inf, m.dtype), lax.min, tuple(win), tuple(stride), "VALID")
    return m


def tile_flags(phip, cut, tile):
    """(S, ntx, nty[, ntz]): the tiles whose window of padded nodes holds one with
    ``phip < cut`` (``phip`` (S, nx + 2, ny + 2[, nz + 2]), the level sets padded with one
    ghost layer)."""
    return window_min(phip, tile) < cut


class Listed:
    """The listed tiles of every solid: ``pos`` per axis (S, cap), ``slot`` (S, cap) True
    where the slot holds a tile, ``count`` (S,) the tiles each solid needs (may exceed cap)."""

    def __init__(self, flags, capacity: int):
        nd = flags.ndim - 1
        nt = flags.shape[1:]
        stride = [math.prod(nt[a + 1:]) for a in range(nd)]
        flat = flags.reshape(flags.shape[0], -1)
        self.count = jnp.sum(flat, axis=1, dtype=jnp.int32)
        k = jax.vmap(lambda m: jnp.nonzero(m, size=capacity, fill_value=0)[0])(flat).astype(jnp.int32)
        self.slot = jnp.arange(capacity, dtype=jnp.int32)[None] < self.count[:, None]
        self.pos = tuple((k // stride[a]) % nt[a] for a in range(nd))
        # flat tile index of each slot; past the last tile for an empty slot (dropped)
        self.flat = jnp.where(self.slot, k, math.prod(nt))
        self.nt = nt


def gather(a, listed: Listed, tile, fill, extra: int = 0):
    """Each solid's windows of a padded field ``a`` (S, ..., nx + 2, ny + 2[, nz + 2]):
    (S, cap, ..., T + 2, T + 2[, T + 2]); beyond the high edge the value is ``fill``.
    ``extra``: ``a`` has that many more ghost layers on each side (not read; padding once
    with two layers for the map advection and the stress saves a copy of every map)."""
    a = narrowband.pad_high(a, tuple(k * t + 2 for k, t in zip(listed.nt, tile, strict=True)), fill, extra)
    starts = tuple(p * t for p, t in zip(listed.pos, tile, strict=True))
    return _windows(a, starts, tuple(t + 2 for t in tile), per_solid=True)


def _windows(a, starts, size, per_solid: bool):
    """Windows of ``size`` (the last ``len(size)`` axes) of ``a`` at ``starts`` (one (S,
    cap) array per axis): (S, cap, ..., *size).  ``per_solid``: ``a`` has a leading solid
    axis (S, ...) and solid k's windows are cut from ``a[k]``; otherwise all from ``a``."""
    nd = len(size)

    def one(a_k, *st):
        lead = a_k.shape[:a_k.ndim - nd]
        return lax.dynamic_slice(a_k, (jnp.int32(0),) * len(lead) + tuple(st), lead + tuple(size))

    if per_solid:
        return jax.vmap(lambda a_k, *p: jax.vmap(lambda *q: one(a_k, *q))(*p))(a, *starts)
    return jax.vmap(lambda *p: jax.vmap(lambda *q: one(a, *q))(*p))(*starts)


def scatter_add(values, listed: Listed, tile, shape):
    """Sum the tile values (S, cap, C, T, T[, T]) of every solid into a grid: (C, *shape),
    ``shape`` at most the tiles' span (the corners or the nodes of the grid)."""
    nd = len(tile)
    nt = listed.nt
    C = values.shape[2]
    buf = jnp.zeros((math.prod(nt), C) + tuple(tile), dtype=values.dtype)
    buf = buf.at[listed.flat.reshape(-1)].add(values.reshape((-1, C) + tuple(tile)), mode="drop")
    buf = buf.reshape(tuple(nt) + (C,) + tuple(tile))
    # (nt0, nt1, C, T0, T1) -> (C, nt0, T0, nt1, T1) -> (C, nt0 T0, nt1 T1)
    perm = (nd,) + tuple(x for a in range(nd) for x in (a, nd + 1 + a))
    buf = jnp.transpose(buf, perm).reshape((C,) + tuple(k * t for k, t in zip(nt, tile, strict=True)))
    return buf[(slice(None),) + tuple(slice(0, s) for s in shape)]


def blend_contributions(phit, rho0, h, numerics):
    """The blend's part of :func:`mix`'s sums on each solid's tiles (every corner and node
    with a fraction): ``phit`` (S, cap, W...) with ``W = T + 2``, ``rho0`` (S,) the
    reference densities.  Returns corner values (S, cap, 1, T...), ``1 - H``, and node
    values (S, cap, 2, T...): ``(1 - H) rho0`` and ``1 - H``."""
    nd = phit.ndim - 2
    n = numerics
    w = n.blur_width * h
    own = (Ellipsis,) + (slice(0, -1),) * nd  # the tile's own T corners of its T + 1
    inner = (Ellipsis,) + (slice(1, -1),) * nd  # its T nodes
    wc = 1.0 - blend.heaviside(corner_average(phit, nd)[own], n.blend, w)
    wn = 1.0 - blend.heaviside(phit[inner], n.blend, w)
    rho0 = jnp.asarray(rho0, dtype=phit.dtype).reshape((-1,) + (1,) * (nd + 1))
    return wc[:, :, None], jnp.stack([wn * rho0, wn], axis=2)


def stress_contributions(phit, xit, laws, stress_fn, h, spacing, numerics):
    """The solids' stresses' part of :func:`mix`'s sums on each solid's tiles (the corners
    and nodes within ``stress_band`` of it, where the stress is taken).

    ``phit`` (S, cap, W...), ``xit`` (S, cap, d, W...) with ``W = T + 2``; ``stress_fn(laws,
    F)`` the stacked constitutive stress (:func:`refmap.model._solid_stresses`).  Returns
    corner values (S, cap, ncomp, T...), the components ``(1 - H) sigma_ab`` in
    ``SYM_PAIRS`` order, and node values (S, cap, 1, T...): ``(1 - H) avg(rho_s - rho0)``,
    the change of the solid's density from its reference one (``rho0 / J``) where its
    stress is taken, which :func:`blend_contributions`' ``(1 - H) rho0`` completes."""
    from refmap.model import _det_adjugate
    from refmap.operators import SYM_PAIRS

    nd = len(spacing)
    n = numerics
    w = n.blur_width * h
    phic = corner_average(phit, nd)  # (S, cap, T + 1, ...)
    wc = 1.0 - blend.heaviside(phic, n.blend, w)
    inner = (Ellipsis,) + (slice(1, -1),) * nd
    wn = 1.0 - blend.heaviside(phit[inner], n.blend, w)  # (S, cap, T, ...)
    dxi = [grad_corner(xit[:, :, a], *spacing) for a in range(nd)]
    det, adj = _det_adjugate(dxi)
    valid = (phic < n.stress_band * h) & (det > 1e-12)
    safe_det = jnp.where(valid, det, 1.0)
    # F = adj / det, entry by entry (a (..., d, d) stack divided at once vectorises poorly on
    # a CPU, its last axes being 2 or 3 long), identity where the stress is not taken
    eye = jnp.eye(nd)
    F = jnp.stack([jnp.stack([jnp.where(valid, adj[..., a, b] / safe_det, eye[a, b]) for b in range(nd)], axis=-1)
                   for a in range(nd)], axis=-2)
    sig, rho0 = stress_fn(laws, F)
    rho0 = rho0.reshape((-1,) + (1,) * (nd + 1))
    drho = jnp.where(valid, rho0 * det - rho0, 0.0)
    own = (Ellipsis,) + (slice(0, -1),) * nd  # the tile's own T corners of its T + 1
    corner = jnp.stack([(wc * jnp.where(valid, sig[..., a, b], 0.0))[own] for a, b in SYM_PAIRS[nd]], axis=2)
    return corner, (wn * node_average(drho, nd))[:, :, None]


def advect_maps(xi, xip, vel, phi, limit, flags, capacity: int, tile, spacing, dt, advect=None):
    """Each solid's reference maps advected on its listed node tiles: ``xi + dt (-(v . grad)
    xi)`` (ENO, :func:`refmap.operators.advect`) where ``phi < limit``, ``xi`` elsewhere,
    the same arithmetic node for node as on the whole grid.

    ``xi`` (S, d, nx, ny[, nz]) the maps, ``xip`` the same padded with two ghost layers
    (:meth:`refmap.boundary.BoundaryConditions.pad_affine`), ``vel`` (d, nx, ny[, nz]) the
    advecting velocity, ``phi`` (S, nx, ny[, nz]), ``flags`` (S, mt...) the node tiles
    holding a node with ``phi < limit`` (:func:`refmap.narrowband.tile_flags`), at most ``capacity`` per
    solid (the caller checks).  A tile's window starts at ``min(p T, n - T)`` per axis: the
    last tile of an axis that ``T`` does not divide is moved back to end on the last node,
    overlapping its neighbour, whose nodes it computes with the same arithmetic, so the
    writes agree.  Every axis must hold at least ``T`` nodes.  ``advect``: the advection
    operator (default :func:`refmap.operators.advect`; :func:`refmap.operators.advect_lowmem`
    gives the same values)."""
    if advect is None:
        from refmap.operators import advect

    nd = len(tile)
    shape = xi.shape[-nd:]
    S, d = xi.shape[0], xi.shape[1]
    listed = Listed(flags, capacity)
    starts = tuple(jnp.minimum(p * t, n - t) for p, t, n in zip(listed.pos, tile, shape, strict=True))
    xw = _windows(xip, starts, tuple(t + 4 for t in tile), True)  # (S, cap, d, T + 4, ...)
    vw = jnp.moveaxis(_windows(vel, starts, tile, False), 2, 0)[:, :, :, None]  # (d, S, cap, 1, T...)
    pw = _windows(phi, starts, tile, True)[:, :, None]  # (S, cap, 1, T...)
    own = xw[(Ellipsis,) + (slice(2, -2),) * nd]
    new = jnp.where(pw < limit, own + dt * advect(xw, vw, *spacing), own)
    # write the windows back; empty slots name solid S, out of bounds, and are dropped
    which = jnp.where(listed.slot, jnp.arange(S, dtype=jnp.int32)[:, None], S)
    index = jnp.stack((which,) + tuple(st.astype(jnp.int32) for st in starts), axis=-1)
    dnums = lax.ScatterDimensionNumbers(
        update_window_dims=tuple(range(1, nd + 2)), inserted_window_dims=(0,),
        scatter_dims_to_operand_dims=(0,) + tuple(range(2, nd + 2)))
    return lax.scatter(xi, index.reshape(-1, nd + 1), new.reshape((-1, d) + tuple(tile)), dnums,
                       mode=lax.GatherScatterMode.FILL_OR_DROP)


def mix(s_f, rho_f, A, Tc, B, Tn):
    """The mixed corner stress components, density and fluid fractions from the sums of
    :func:`blend_contributions` and :func:`stress_contributions` (``A`` the stress
    components, ``Tc``, ``B`` the density, ``Tn`` grids).

    The solid fractions ``(1 - H_k) / max(T, 1)`` (:func:`refmap.model.solid_fractions`)
    share their scale at a point, so ``sum_k w_k sigma_k = A / max(T_c, 1)``."""
    scale_c = 1.0 / jnp.maximum(Tc, 1.0)
    scale_n = 1.0 / jnp.maximum(Tn, 1.0)
    wf_c = jnp.clip(1.0 - Tc * scale_c, 0.0, 1.0)
    wf_n = jnp.clip(1.0 - Tn * scale_n, 0.0, 1.0)
    s_mix = [wf_c * sf + a * scale_c for sf, a in zip(s_f, A, strict=True)]
    rho = wf_n * rho_f + B * scale_n
    return s_mix, rho, wf_c, wf_n



def mixed_on_windows(s_f, rho_f, phip, xip, spacing, origins, window, periodic, laws, rho0,
                     stress_fn, h, numerics, ghost: int = 2):
    """:func:`mix` of the solids' blend and stress contributions computed on one window per
    solid (:mod:`refmap.windows`, docs/design_windows.md, landing 2) instead of on tiles.

    ``phip`` (S, *padded) the level sets and ``xip`` (S, d, *padded) the maps, both padded
    with ``ghost`` layers (``pad_linear``, ``pad_affine``); ``origins`` (S, d) the windows'
    first nodes and ``window`` their node counts: each solid's corners ``origin ..
    origin + W`` and nodes ``origin .. origin + W`` are computed (the window read with one
    node more below and two above), so every corner and node where the solid's fraction is
    not zero must lie in its window: ``refmap.windows.placement`` with ``reach`` just below
    :func:`cutoff` (``1 - H`` is exactly 0 from there on; a corner is computed when one of
    its nodes is in the window).  On a periodic axis the window may wrap (``W + 1 <= n``);
    a map component read across that axis's edge is moved by the period, so that the map
    is continuous in the window (``xi - x`` is what is periodic).  On a walled axis the
    window stays on the grid (``origin <= n - W``)."""
    nd = len(window)
    nshape = tuple(a - 2 * ghost for a in phip.shape[-nd:])
    windows.check(tuple(window), nshape, periodic)
    for a in range(nd):
        if periodic[a] and window[a] + 1 > nshape[a]:
            raise ValueError(f"a window of {window[a]} nodes along periodic axis {a} needs "
                             f"window + 1 <= {nshape[a]} nodes")
    size = tuple(w + 3 for w in window)  # nodes origin - 1 .. origin + W + 1
    read = windows.index(origins, size, nshape, periodic, offset=-1, ghost=ghost)
    unwrapped = windows.index(origins, size, nshape, (False,) * nd, offset=-1, ghost=ghost)

    def cut(f):  # (S, ..., *padded) -> (S, ..., *size), one window per solid
        return jax.vmap(lambda f_k, *i_k: f_k[(Ellipsis,) + i_k])(f, *read)

    # the period crossed by each node read (0 on a walled axis): component a jumps by it
    jump = jnp.stack([jnp.broadcast_to((u - r) * spacing[a], (origins.shape[0],) + size)
                      for a, (u, r) in enumerate(zip(unwrapped, read, strict=True))], axis=1)
    return mixed_from_windows(s_f, rho_f, cut(phip), cut(xip) + jump, spacing, origins, window,
                              periodic, laws, rho0, stress_fn, h, numerics, nshape)


def cut_windows(phi, xi, origins, window, lows, spacing, periodic):
    """The level sets and maps that :func:`mixed_from_windows` reads, cut from the unpadded
    grid fields ``phi`` (S, *grid) and ``xi`` (S, d, *grid) without padding the grid: nodes
    ``origin - 1 .. origin + W + 1`` of each solid's window, ghosts beyond a wall the linear
    ones of ``pad_linear`` / ``pad_affine`` (:func:`refmap.windows.gather_ghosted`), the map
    made continuous across a periodic edge (``xi - x`` is what is periodic)."""
    size = tuple(w + 3 for w in window)

    def one(phi_k, xi_k, o):
        return (windows.gather_ghosted(phi_k, o, size, periodic, offset=-1),
                cut_map(xi_k, o, size, lows, spacing, periodic, offset=-1))

    return jax.vmap(one)(phi, xi, origins)


def cut_map(xi, origin, size, lows, spacing, periodic, offset: int = 0):
    """One solid's map ``xi`` (d, *grid) on the window's nodes ``origin + offset ..``
    (:func:`refmap.windows.gather_ghosted`: linear ghosts past a wall, as ``pad_affine``'s),
    made continuous across a periodic edge: ``xi - x`` is what is periodic, so the wrapped
    node's ``xi - x`` plus the unwrapped coordinates."""
    shape = xi.shape[-len(size):]
    X = functools.partial(windows.coordinates, origin, size, lows, spacing, shape, periodic, offset=offset)
    return (windows.gather_ghosted(xi, origin, size, periodic, offset=offset) - X()) + X(wrap=False)


def mixed_from_windows(s_f, rho_f, phiw, xiw, spacing, origins, window, periodic, laws, rho0,
                       stress_fn, h, numerics, nshape):
    """:func:`mixed_on_windows` from the windows already cut: ``phiw`` (S, *size) and
    ``xiw`` (S, d, *size), ``size = W + 3`` nodes per axis from ``origin - 1``, the map
    continuous in the window; ``nshape`` the grid's node counts."""
    sums = window_sums(window, periodic, nshape, phiw.dtype)
    parts = window_contributions(phiw, xiw, laws, rho0, stress_fn, h, spacing, numerics)
    sums = tuple(windows.add_windows(a, v, origins) for a, v in zip(sums, parts, strict=True))
    return mix_window_sums(s_f, rho_f, sums, window, periodic, nshape)


def window_contributions(phiw, xiw, laws, rho0, stress_fn, h, spacing, numerics):
    """Each window's part of :func:`mix`'s sums (``phiw`` (S, *size), ``xiw`` (S, d, *size)
    as :func:`mixed_from_windows`): the corner sums ``1 - H`` (S, 1, *C) and the stress
    components (S, ncomp, *C), the node sums ``((1 - H) rho0, 1 - H)`` (S, 2, *W) and the
    density change (S, 1, *W), ``C = W + 1``: the order of :func:`window_sums`."""
    wc, wn = blend_contributions(phiw[:, None], rho0, h, numerics)  # (S, 1, C, W + 1, ...)
    sig, drho = stress_contributions(phiw[:, None], xiw[:, None], laws, stress_fn, h, spacing, numerics)
    return wc[:, 0], sig[:, 0], wn[:, 0], drho[:, 0]


def window_sums(window, periodic, nshape, dtype):
    """The padded sums (:func:`refmap.windows.padded_for`) into which
    :func:`window_contributions` are added: corners ``1 - H`` and the stress components,
    nodes ``((1 - H) rho0, 1 - H)`` and the density change.  A periodic axis holds n
    corners (corner n is corner 0's copy, appended by :func:`mix_window_sums`), a walled
    one n + 1."""
    nd = len(window)
    ncomp = nd * (nd + 1) // 2
    corners = tuple(n if p else n + 1 for n, p in zip(nshape, periodic, strict=True))
    C = tuple(w + 1 for w in window)
    return (windows.padded_for(jnp.zeros((1,) + corners, dtype), C),
            windows.padded_for(jnp.zeros((ncomp,) + corners, dtype), C),
            windows.padded_for(jnp.zeros((2,) + tuple(nshape), dtype), window),
            windows.padded_for(jnp.zeros((1,) + tuple(nshape), dtype), window))


def mix_window_sums(s_f, rho_f, sums, window, periodic, nshape):
    """:func:`mix` from the padded sums of all windows (:func:`window_sums`): folded round a
    periodic axis (:func:`refmap.windows.fold`; corner n, corner 0's copy, appended)."""
    nd = len(window)
    corners = tuple(n if p else n + 1 for n, p in zip(nshape, periodic, strict=True))
    C = tuple(w + 1 for w in window)

    def corner_field(acc):
        out = windows.fold(acc, corners, C, periodic)
        for a in range(nd):
            if periodic[a]:
                out = jnp.concatenate([out, lax.slice_in_dim(out, 0, 1, axis=1 + a)], axis=1 + a)
        return out

    Tc = corner_field(sums[0])[0]
    A = corner_field(sums[1])
    Bn, Tn = windows.fold(sums[2], tuple(nshape), window, periodic)
    Bn = Bn + windows.fold(sums[3], tuple(nshape), window, periodic)[0]
    return mix(s_f, rho_f, tuple(A), Tc, Bn, Tn)


__all__ = ["ERF_ZERO", "Listed", "advect_maps", "blend_contributions", "cutoff", "gather",
           "cut_map", "cut_windows", "mix", "mix_window_sums", "mixed_from_windows", "mixed_on_windows", "n_tiles", "scatter_add", "stress_contributions", "tile_flags", "window_contributions", "window_min", "window_sums"]
