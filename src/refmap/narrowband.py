"""The band of a solid as a list of grid tiles (the band layout of the sweeps).

The band work of a solid (extrapolating its reference map, smoothing the extrapolated
values) updates only the nodes near its interface: a few per cent of the grid for a large
body, far less for a small one.  Sweeping the whole grid for them moves every field through
memory once per sweep.  Here the grid is cut into tiles of ``tx x ty`` nodes (about 16 x 16),
the tiles holding at least one node to update are gathered once into a list of static
length ``capacity`` (JAX needs static shapes), and the sweeps run on the list: a dense
stencil inside each tile, the tile's edge rows read from its listed neighbour tiles, or,
where the neighbour tile is not listed (none of its nodes changes), from values gathered
once.  Gathering whole tiles keeps the sweeps vectorised: on a CPU a gather of single
nodes costs about 15 times a stencil update of one node, which ate the gain of an earlier
list of single band nodes (docs/benchmarks.md).

Layout: a tile array is ``(..., capacity, tx, ty)``; :class:`Tiles` says which tile each
slot holds and where its four neighbour tiles (x-, x+, y-, y+) are.  Slots past ``count``
are empty: their masks must be False (callers AND them with ``slot``), they are nobody's
neighbour, and their values are never written back.  A band of more than ``capacity``
tiles does not fit (``count > capacity``): callers check and fall back on the full-grid
sweeps (:func:`refmap.extrapolation.extend` does).

Edges: on a periodic axis the tile size must divide the node count (:func:`tile_shape`
picks one, or returns None: no tiling); on a non-periodic axis the grid is padded with
nodes beyond the edge, which hold the value a full-grid stencil assumes beyond an edge
(its ``fill``) and are never written back.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from refmap.levelset import Periodic

_OFFSETS = ((-1, 0), (1, 0), (0, -1), (0, 1))  # x-, x+, y-, y+
HALO = 2  # ghost rows gathered round each tile (a solid-only gradient on its edge row)


def _axis_tile(n: int, periodic: bool, target: int) -> int | None:
    if not periodic:
        return min(target, n)
    sizes = [t for t in range(8, 33) if n % t == 0]
    if not sizes:
        return n if n <= 32 else None
    return min(sizes, key=lambda t: (abs(t - target), t))


def tile_shape(shape, periodic: Periodic = (False, False), target: int = 16):
    """Tile size ``(tx, ty)`` for a grid: ``target`` along a non-periodic axis, the divisor
    of the node count in 8..32 closest to it along a periodic one; None if a periodic axis
    has no such divisor (and more than 32 nodes)."""
    tx = _axis_tile(shape[0], periodic[0], target)
    ty = _axis_tile(shape[1], periodic[1], target)
    return None if tx is None or ty is None else (tx, ty)


class Tiles(NamedTuple):
    """The listed tiles of a mask and their neighbours (static: ``tile``, ``periodic``)."""

    ti: jax.Array  # (cap,) tile row of each slot (0 for an empty slot)
    tj: jax.Array  # (cap,) tile column
    slot: jax.Array  # (cap,) True where the slot holds a tile
    listed: jax.Array  # (4, cap) the neighbour tile is itself in the list ...
    ptr: jax.Array  # (4, cap) ... at this slot (0 where it is not)
    count: jax.Array  # () number of tiles holding a node of the mask (may exceed cap)


def n_tiles(shape, tile):
    return -(-shape[0] // tile[0]), -(-shape[1] // tile[1])


def tile_flags(mask, tile):
    """(ntx, nty): which tiles hold a True node of ``mask`` (nx, ny)."""
    ntx, nty = n_tiles(mask.shape, tile)
    m = _pad_to(mask, (ntx * tile[0], nty * tile[1]), False)
    return jnp.any(m.reshape(ntx, tile[0], nty, tile[1]), axis=(1, 3))


def _pad_to(a, shape, fill):
    widths = [(0, 0, 0)] * (a.ndim - 2) + [
        (0, shape[0] - a.shape[-2], 0),
        (0, shape[1] - a.shape[-1], 0),
    ]
    return lax.pad(a, jnp.asarray(fill, dtype=a.dtype), widths)


def build(mask, capacity: int, tile, periodic: Periodic = (False, False)) -> Tiles:
    """The tiles holding a True node of ``mask`` (nx, ny), in index order."""
    return build_from_flags(tile_flags(mask, tile), capacity, periodic)


def build_from_flags(flags, capacity: int, periodic: Periodic = (False, False)) -> Tiles:
    """:func:`build` from the tile flags (ntx, nty) of :func:`tile_flags`."""
    ntx, nty = flags.shape
    m = flags.reshape(-1)
    count = jnp.sum(m, dtype=jnp.int32)
    k = jnp.nonzero(m, size=capacity, fill_value=0)[0].astype(jnp.int32)
    slot = jnp.arange(capacity, dtype=jnp.int32) < count
    rank = jnp.cumsum(m, dtype=jnp.int32) - 1
    ti, tj = k // nty, k % nty
    listed, ptr = [], []
    for di, dj in _OFFSETS:
        ii, jj = ti + di, tj + dj
        ok = slot
        if periodic[0]:
            ii = jnp.mod(ii, ntx)
        else:
            ok = ok & (ii >= 0) & (ii < ntx)
        if periodic[1]:
            jj = jnp.mod(jj, nty)
        else:
            ok = ok & (jj >= 0) & (jj < nty)
        flat = jnp.where(ok, ii * nty + jj, 0)
        is_listed = ok & m[flat]
        listed.append(is_listed)
        ptr.append(jnp.where(is_listed, rank[flat], 0))
    return Tiles(ti, tj, slot, jnp.stack(listed), jnp.stack(ptr), count)


def gather(a, tiles: Tiles, tile, periodic: Periodic, fill, halo: int = HALO):
    """The listed tiles of a node field ``a`` (..., nx, ny) with ``halo`` ghost rows:
    (..., cap, tx + 2 halo, ty + 2 halo).  Beyond a non-periodic edge the value is ``fill``;
    across a periodic one the axis wraps."""
    tx, ty = tile
    ntx, nty = n_tiles(a.shape[-2:], tile)
    a = _pad_to(a, (ntx * tx, nty * ty), fill)
    for axis, p in ((-2, periodic[0]), (-1, periodic[1])):
        if p:
            a = jnp.concatenate(
                [
                    lax.slice_in_dim(a, a.shape[axis] - halo, a.shape[axis], axis=a.ndim + axis),
                    a,
                    lax.slice_in_dim(a, 0, halo, axis=a.ndim + axis),
                ],
                axis=axis,
            )
        else:
            widths = [(0, 0, 0)] * a.ndim
            widths[a.ndim + axis] = (halo, halo, 0)
            a = lax.pad(a, jnp.asarray(fill, dtype=a.dtype), widths)
    lead = a.shape[:-2]
    size = (tx + 2 * halo, ty + 2 * halo)

    def one(i, j):
        start = (jnp.int32(0),) * len(lead) + (i * tx, j * ty)
        return lax.dynamic_slice(a, start, lead + size)

    out = jax.vmap(one)(tiles.ti, tiles.tj)  # (cap, ..., sx, sy)
    return jnp.moveaxis(out, 0, -3)


def node_index(tiles: Tiles, tile, shape):
    """Flat node index (cap, tx, ty) of every tile node; ``nx * ny`` (dropped when
    scattering) for empty slots and padding beyond the grid."""
    tx, ty = tile
    nx, ny = shape
    i = tiles.ti[:, None, None] * tx + jnp.arange(tx)[None, :, None]
    j = tiles.tj[:, None, None] * ty + jnp.arange(ty)[None, None, :]
    ok = tiles.slot[:, None, None] & (i < nx) & (j < ny)
    return jnp.where(ok, i * ny + j, nx * ny)


def scatter(a, index, values):
    """``a`` (..., nx, ny) with the tile nodes ``index`` (cap, tx, ty) set to ``values``."""
    shape = a.shape
    flat = a.reshape(shape[:-2] + (-1,))
    return flat.at[..., index].set(values, mode="drop").reshape(shape)


def halos(r1):
    """Edge rows (x-, x+, y-, y+) of an array with one ghost row (..., tx + 2, ty + 2)."""
    return (r1[..., 0, 1:-1], r1[..., -1, 1:-1], r1[..., 1:-1, 0], r1[..., 1:-1, -1])


def interior(a, halo: int):
    return a[..., halo:-halo, halo:-halo]


def stencil_neighbours(p):
    """The four neighbours of the inner part of ``p`` (..., sx, sy): (..., sx - 2, sy - 2)."""
    return (p[..., :-2, 1:-1], p[..., 2:, 1:-1], p[..., 1:-1, :-2], p[..., 1:-1, 2:])


class Neighbours:
    """The four neighbours of a tile array (..., cap, tx, ty): inside a tile by shifting, on
    a tile's edge from the listed neighbour tile's edge row, or from ``fixed``, the edge
    rows (x-, x+, y-, y+) gathered once, where the neighbour tile is not listed."""

    def __init__(self, tiles: Tiles):
        self.tiles = tiles

    def __call__(self, a, fixed):
        lst, ptr = self.tiles.listed, self.tiles.ptr

        def edge(rows, d):  # the edge rows (..., cap, t) of the neighbour tiles along d
            return jnp.where(lst[d][:, None], jnp.take(rows, ptr[d], axis=-2), fixed[d])

        hxm = edge(a[..., -1, :], 0)
        hxp = edge(a[..., 0, :], 1)
        hym = edge(a[..., :, -1], 2)
        hyp = edge(a[..., :, 0], 3)
        # the tile with one ghost row, built apart (an optimisation barrier keeps XLA from
        # fusing the concatenation into the stencil, which would then not vectorise)
        p = jnp.concatenate([hxm[..., None, :], a, hxp[..., None, :]], axis=-2)
        pad = [(0, 0, 0)] * (hym.ndim - 1) + [(1, 1, 0)]
        hym = lax.pad(hym, jnp.zeros((), hym.dtype), pad)
        hyp = lax.pad(hyp, jnp.zeros((), hyp.dtype), pad)
        p = jnp.concatenate([hym[..., None], p, hyp[..., None]], axis=-1)
        p = lax.optimization_barrier(p)
        return stencil_neighbours(p)


__all__ = [
    "HALO",
    "Neighbours",
    "Tiles",
    "build",
    "build_from_flags",
    "gather",
    "halos",
    "interior",
    "node_index",
    "scatter",
    "stencil_neighbours",
    "tile_flags",
    "tile_shape",
]
