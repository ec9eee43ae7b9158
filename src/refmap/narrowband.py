"""The band of a solid as a list of grid tiles (the band layout of the sweeps).

The band work of a solid (extrapolating its reference map, smoothing the extrapolated
values) updates only the nodes near its interface: a few per cent of the grid for a large
body, far less for a small one.  Sweeping the whole grid for them moves every field through
memory once per sweep.  Here the grid is cut into tiles of ``tx x ty`` nodes (about 8 x 8;
``tx x ty x tz``, about 8 x 8 x 8, in 3D),
the tiles holding at least one node to update are gathered once into a list of static
length ``capacity`` (JAX needs static shapes), and the sweeps run on the list: a dense
stencil inside each tile, the tile's edge rows read from its listed neighbour tiles, or,
where the neighbour tile is not listed (none of its nodes changes), from values gathered
once.  Gathering whole tiles keeps the sweeps vectorised: on a CPU a gather of single
nodes costs about 15 times a stencil update of one node, which ate the gain of an earlier
list of single band nodes (docs/benchmarks.md).

Layout: a tile array is ``(..., capacity, tx, ty)`` (``tx, ty, tz`` on a 3D grid: the module
works on the last ``len(tile)`` axes); :class:`Tiles` says which tile each slot holds and
where its ``2 d`` face-neighbour tiles (x-, x+, y-, y+[, z-, z+]) are.  Slots past ``count``
are empty: their masks must be False (callers AND them with ``slot``), they are nobody's
neighbour, and their values are never written back.  A band of more than ``capacity``
tiles does not fit (``count > capacity``): callers check and fall back on the full-grid
sweeps (:func:`refmap.extrapolation.extend` does).  The sweeps themselves run on the same
tiles with the slot axis moved innermost, ``(..., tx, ty[, tz], capacity)``
(:func:`cap_last`): a stencil shift is then a shift along an outer axis and each inner loop
runs over every listed tile at once, where with 8-node rows it ran over 8 values (1.5-2
times faster on a CPU core, docs/benchmarks.md).

Edges: on a periodic axis the tile size must divide the node count (:func:`tile_shape`
picks one, or returns None: no tiling); on a non-periodic axis the grid is padded with
nodes beyond the edge, which hold the value a full-grid stencil assumes beyond an edge
(its ``fill``) and are never written back.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from refmap.levelset import Periodic

HALO = 2  # ghost rows gathered round each tile (a solid-only gradient on its edge row)


def _offsets(nd: int):
    """The unit offsets to the ``2 nd`` face neighbours, order (x-, x+, y-, y+[, z-, z+])."""
    out = []
    for a in range(nd):
        for s in (-1, 1):
            e = [0] * nd
            e[a] = s
            out.append(tuple(e))
    return tuple(out)


def _axis_tile(n: int, periodic: bool, target: int) -> int | None:
    if not periodic:
        return min(target, n)
    lo, hi = max(2, target // 2), 2 * target
    sizes = [t for t in range(lo, hi + 1) if n % t == 0]
    if not sizes:
        return n if n <= hi else None
    return min(sizes, key=lambda t: (abs(t - target), t))


def tile_shape(shape, periodic: Periodic | None = None, target: int = 16):
    """Tile size ``(tx, ty[, tz])`` for a grid: ``target`` along a non-periodic axis, the
    divisor of the node count in ``target/2 .. 2 target`` closest to it along a periodic one;
    None if a periodic axis has no such divisor (and more than ``2 target`` nodes)."""
    periodic = (False,) * len(shape) if periodic is None else tuple(periodic)
    t = tuple(_axis_tile(n, p, target) for n, p in zip(shape, periodic, strict=True))
    return None if any(x is None for x in t) else t


class Tiles(NamedTuple):
    """The listed tiles of a mask and their neighbours (static: ``tile``, ``periodic``)."""

    pos: tuple  # per axis (cap,) the tile index of each slot along it (0 for an empty slot)
    slot: jax.Array  # (cap,) True where the slot holds a tile
    listed: jax.Array  # (2 nd, cap) the neighbour tile is itself in the list ...
    ptr: jax.Array  # (2 nd, cap) ... at this slot (0 where it is not)
    count: jax.Array  # () number of tiles holding a node of the mask (may exceed cap)


def n_tiles(shape, tile):
    """Tiles per axis of a grid of ``shape`` nodes (the last tile may be partly outside)."""
    return tuple(-(-n // t) for n, t in zip(shape, tile, strict=True))


def capacity_for(counts, factor: float, total: int) -> int:
    """Static slots of a tile list: ``factor`` times the most tiles a solid holds
    (``counts``, one per solid), plus 8, at most every tile of the grid (``total``)."""
    return min(int(math.ceil(factor * int(max(counts, default=0)))) + 8, total)


def ladder_level(flags, ladder):
    """Which rung of a capacity ``ladder`` (ascending) holds every solid's listed tiles
    (``flags`` (S, nt...)): the index of the first capacity at least the largest count,
    ``len(ladder)`` (past the last: the full grid) when none is."""
    nd = flags.ndim - 1
    most = jnp.max(jnp.sum(flags, axis=tuple(range(1, nd + 1)), dtype=jnp.int32))
    return jnp.sum(jnp.asarray(ladder, dtype=jnp.int32) < most, dtype=jnp.int32)


def tile_flags(mask, tile):
    """(ntx, nty[, ntz]): which tiles hold a True node of ``mask`` (nx, ny[, nz])."""
    nd = len(tile)
    nt = n_tiles(mask.shape, tile)
    m = pad_high(mask, tuple(n * t for n, t in zip(nt, tile, strict=True)), False)
    split = sum(((n, t) for n, t in zip(nt, tile, strict=True)), ())
    return jnp.any(m.reshape(split), axis=tuple(range(1, 2 * nd, 2)))


def switch(index, branches, *operands):
    """``lax.switch(index, branches, *operands)`` with every branch under ``jax.checkpoint``.

    For the capacity ladders (each rung a branch, the full grid the last).  In reverse
    mode ``lax.switch`` keeps the residuals of *every* branch, not only the taken one's
    (JAX joins the branches' residual lists, and only residuals of the same shape share a
    slot), so a ladder of two tile capacities and the full grid held all three branches'
    intermediates through a step's backward pass.  Under ``jax.checkpoint`` a branch keeps
    only its operands, shared by all, and the taken branch is run again in the backward
    pass.  Measured (circle, 128^2, binomial checkpointing with 4 snapshots): the gradient's
    memory 24.31 -> 21.56 MiB (4.48x -> 3.98x the forward run), its time +1.4 %.  The
    forward pass is unchanged: without a derivative the checkpoint is inlined as it
    stands (``prevent_cse=False`` puts no barrier in)."""
    return lax.switch(index, [jax.checkpoint(b, prevent_cse=False) for b in branches], *operands)


def pad_high(a, shape, fill, crop: int = 0):
    """``a`` without its first ``crop`` entries along each of its last ``len(shape)`` axes,
    then padded with ``fill`` (or cut) at their high end to ``shape``: one pass."""
    nd = len(shape)
    lead = a.ndim - nd
    widths = [(0, 0, 0)] * lead + [
        (-crop, s - (a.shape[lead + i] - crop), 0) for i, s in enumerate(shape)
    ]
    return lax.pad(a, jnp.asarray(fill, dtype=a.dtype), widths)


def build(mask, capacity: int, tile, periodic: Periodic | None = None) -> Tiles:
    """The tiles holding a True node of ``mask`` (nx, ny[, nz]), in index order."""
    return build_from_flags(tile_flags(mask, tile), capacity, periodic)


def build_from_flags(flags, capacity: int, periodic: Periodic | None = None) -> Tiles:
    """:func:`build` from the tile flags (ntx, nty[, ntz]) of :func:`tile_flags`."""
    nt = flags.shape
    nd = len(nt)
    periodic = (False,) * nd if periodic is None else tuple(periodic)
    stride = [math.prod(nt[a + 1:]) for a in range(nd)]
    m = flags.reshape(-1)
    count = jnp.sum(m, dtype=jnp.int32)
    k = jnp.nonzero(m, size=capacity, fill_value=0)[0].astype(jnp.int32)
    slot = jnp.arange(capacity, dtype=jnp.int32) < count
    rank = jnp.cumsum(m, dtype=jnp.int32) - 1
    pos = tuple((k // stride[a]) % nt[a] for a in range(nd))
    listed, ptr = [], []
    for off in _offsets(nd):
        ok = slot
        flat = 0
        for a in range(nd):
            i = pos[a] + off[a]
            if periodic[a]:
                i = jnp.mod(i, nt[a])
            else:
                ok = ok & (i >= 0) & (i < nt[a])
            flat = flat * nt[a] + i
        flat = jnp.where(ok, flat, 0)
        is_listed = ok & m[flat]
        listed.append(is_listed)
        ptr.append(jnp.where(is_listed, rank[flat], 0))
    return Tiles(pos, slot, jnp.stack(listed), jnp.stack(ptr), count)


def gather(a, tiles: Tiles, tile, periodic: Periodic, fill, halo: int = HALO):
    """The listed tiles of a node field ``a`` (..., nx, ny[, nz]) with ``halo`` ghost rows:
    (..., cap, tx + 2 halo, ty + 2 halo[, tz + 2 halo]).  Beyond a non-periodic edge the
    value is ``fill``; across a periodic one the axis wraps."""
    nd = len(tile)
    nt = n_tiles(a.shape[-nd:], tile)
    a = pad_high(a, tuple(n * t for n, t in zip(nt, tile, strict=True)), fill)
    for i in range(nd):
        axis = a.ndim - nd + i
        if periodic[i]:
            a = jnp.concatenate(
                [
                    lax.slice_in_dim(a, a.shape[axis] - halo, a.shape[axis], axis=axis),
                    a,
                    lax.slice_in_dim(a, 0, halo, axis=axis),
                ],
                axis=axis,
            )
        else:
            widths = [(0, 0, 0)] * a.ndim
            widths[axis] = (halo, halo, 0)
            a = lax.pad(a, jnp.asarray(fill, dtype=a.dtype), widths)
    lead = a.shape[:-nd]
    size = tuple(t + 2 * halo for t in tile)

    def one(*p):
        start = (jnp.int32(0),) * len(lead) + tuple(q * t for q, t in zip(p, tile, strict=True))
        return lax.dynamic_slice(a, start, lead + size)

    out = jax.vmap(one)(*tiles.pos)  # (cap, ..., sx, sy[, sz])
    return jnp.moveaxis(out, 0, -(nd + 1))


def node_index(tiles: Tiles, tile, shape):
    """Flat node index (cap, tx, ty[, tz]) of every tile node; ``prod(shape)`` (dropped when
    scattering) for empty slots and padding beyond the grid."""
    nd = len(tile)
    ok = tiles.slot.reshape((-1,) + (1,) * nd)
    flat = 0
    for a in range(nd):
        along = [1] * nd
        along[a] = tile[a]
        i = tiles.pos[a].reshape((-1,) + (1,) * nd) * tile[a] + jnp.arange(tile[a]).reshape(along)
        ok = ok & (i < shape[a])
        flat = flat * shape[a] + i
    return jnp.where(ok, flat, math.prod(shape))


def scatter(a, index, values):
    """``a`` (..., nx, ny[, nz]) with the tile nodes ``index`` (cap, tx, ty[, tz]) set to
    ``values``."""
    nd = index.ndim - 1
    shape = a.shape
    flat = a.reshape(shape[:-nd] + (-1,))
    return flat.at[..., index].set(values, mode="drop").reshape(shape)


def _face(a, axis: int, k: int, nd: int, inner: bool, tail: int = 0):
    """The layer ``k`` of ``a`` across tile axis ``axis`` (one of the ``nd`` tile axes, which
    are followed by ``tail`` more axes), with the other tile axes cut to their inner part
    (``inner``: drop one node at each end)."""
    idx = [slice(1, -1) if inner else slice(None)] * nd
    idx[axis] = k
    return a[(Ellipsis, *idx) + (slice(None),) * tail]


def halos(r1, nd: int = 2, tail: int = 0):
    """Edge rows (x-, x+, y-, y+[, z-, z+]) of an array with one ghost row
    (..., tx + 2, ty + 2[, tz + 2], *tail axes)."""
    out = ()
    for a in range(nd):
        out += (_face(r1, a, 0, nd, True, tail), _face(r1, a, -1, nd, True, tail))
    return out


def interior(a, halo: int, nd: int = 2, tail: int = 0):
    return a[(Ellipsis,) + (slice(halo, -halo),) * nd + (slice(None),) * tail]


def stencil_neighbours(p, nd: int = 2, tail: int = 0):
    """The ``2 nd`` neighbours of the inner part of ``p`` (..., sx, sy[, sz], *tail axes):
    (..., sx - 2, sy - 2[, sz - 2], *tail axes)."""
    out = ()
    for a in range(nd):
        for lo in (0, 2):
            idx = [slice(1, -1)] * nd
            idx[a] = slice(lo, lo - 2 if lo < 2 else None)
            out += (p[(Ellipsis, *idx) + (slice(None),) * tail],)
    return out


def cap_last(a, nd: int = 2):
    """A tile array (..., cap, tx, ty[, tz]) in the sweeps' layout (..., tx, ty[, tz], cap)
    (a tile face, with ``nd - 1`` tile axes: ``cap_last(face, nd - 1)``): the slot axis
    innermost, so that every stencil shift moves along an outer axis and the
    inner loops run over all the tiles at once."""
    return jnp.moveaxis(a, -(nd + 1), -1)


def cap_first(a, nd: int = 2):
    """The inverse of :func:`cap_last`."""
    return jnp.moveaxis(a, -1, -(nd + 1))


class Neighbours:
    """The ``2 nd`` neighbours of a tile array, inside a tile by shifting, on a tile's face
    from the listed neighbour tile's face, or from ``fixed``, the faces (x-, x+, y-, y+[,
    z-, z+]) gathered once, where the neighbour tile is not listed.  Layout: (..., cap, tx,
    ty[, tz]), or with ``cap_last`` (..., tx, ty[, tz], cap) (:func:`cap_last`; ``fixed``
    in the same layout), which the sweeps use: on a CPU their stencils run about 1.5 times
    faster with the slots innermost (docs/benchmarks.md)."""

    def __init__(self, tiles: Tiles, cap_last: bool = False):
        self.tiles = tiles
        self.nd = len(tiles.pos)
        self.cap_last = cap_last

    def __call__(self, a, fixed):
        nd = self.nd
        lst, ptr = self.tiles.listed, self.tiles.ptr
        tail = 1 if self.cap_last else 0
        first = a.ndim - nd - tail  # the first tile axis

        def edge(rows, d):  # the faces of the neighbour tiles along d
            if self.cap_last:
                keep, cap_axis = lst[d], rows.ndim - 1
            else:
                keep, cap_axis = lst[d].reshape((-1,) + (1,) * (nd - 1)), rows.ndim - nd
            return jnp.where(keep, jnp.take(rows, ptr[d], axis=cap_axis), fixed[d])

        # the tile with one ghost layer, built apart (an optimisation barrier keeps XLA
        # from fusing the concatenations into the stencil, which would then not vectorise);
        # the corners and edges of the ghost layer are zeros that no stencil reads
        p = a
        for ax in range(nd):
            axis = first + ax
            lo = edge(_face(a, ax, -1, nd, False, tail), 2 * ax)
            hi = edge(_face(a, ax, 0, nd, False, tail), 2 * ax + 1)
            if ax:  # widen the faces over the axes already given their ghost layer
                face_first = first  # the faces' tile axes start where the array's do
                pad = [(0, 0, 0)] * lo.ndim
                for b in range(ax):
                    pad[face_first + b] = (1, 1, 0)
                lo = lax.pad(lo, jnp.zeros((), lo.dtype), pad)
                hi = lax.pad(hi, jnp.zeros((), hi.dtype), pad)
            p = jnp.concatenate([jnp.expand_dims(lo, axis), p, jnp.expand_dims(hi, axis)], axis=axis)
        p = lax.optimization_barrier(p)
        return stencil_neighbours(p, nd, tail)


__all__ = [
    "HALO",
    "Neighbours",
    "Tiles",
    "build",
    "build_from_flags",
    "cap_first",
    "cap_last",
    "capacity_for",
    "ladder_level",
    "gather",
    "halos",
    "interior",
    "node_index",
    "scatter",
    "stencil_neighbours",
    "tile_flags",
    "tile_shape",
]
