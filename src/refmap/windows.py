"""Per-body windows: boxes of the grid that follow a body (issue 14; docs/design_windows.md).

A window is a box of ``W = (Wx, Wy[, Wz])`` nodes whose lower corner ``origin`` (integer node
indices, one per axis) sits on the grid.  This module holds the index work that every
windowed phase shares; it knows nothing of reference maps or stresses:

* :func:`placement`: where each body's window goes, from its level set: centred on the box
  of the nodes with ``phi <= reach``, inside the grid on a non-periodic axis, anywhere
  (wrapping round) on a periodic one, and whether that box with ``margin`` nodes to spare
  fits;
* :func:`gather`: the window's values of a grid field (a periodic axis wraps round);
  :func:`gather_ghosted`: the same with nodes past a wall read as the linear ghosts of
  ``BoundaryConditions.pad_linear`` (a window with ghost layers, no padded grid);
  :func:`coordinates`: the node coordinates of a window, wrapped or continued;
* :func:`put`: a window's values written into a grid field;
* :func:`scatter_add`: windows' values added into a grid field (overlapping windows add;
  the exact transpose of :func:`gather`, tested by the adjoint identity);
* :func:`shift`: a window's values moved to a new origin (a body that travelled), the
  nodes that enter the window taking ``fill``;
* :func:`to_grid`: a window's values on the whole grid, ``fill`` outside (output files);
* :func:`ghosted`: a window's values with linear ghost layers (a window stored on its
  own, without the grid round it); :func:`follow`: :func:`placement` from a window's own
  level set (a window that moves with its body).

Every function works on the last ``d = len(W)`` axes of its arrays and on one window; use
``jax.vmap`` over bodies (the origins ``(S, d)`` with them).  On a non-periodic axis a window
never leaves the grid (:func:`placement` clips its origin to ``[0, n - W]``); on a periodic
axis the indices are taken modulo the node count, so a body may straddle an edge or a
corner.  Gathers and scatters use index arrays (XLA gather and scatter-add): simple and
general; whether a sliced form is faster on a CPU is for the step that uses them to
measure.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

#: nodes kept free between a body's band box and its window's edge by :func:`placement`
MARGIN = 2


def index(origins, size, shape, periodic, offset: int = 0, ghost: int = 0):
    """Open-mesh index arrays (``jnp.ix_``-style, one per axis) of the nodes ``origin +
    offset .. origin + offset + size - 1`` of windows at ``origins`` (``(..., d)``: a leading
    batch of windows gives index arrays with those leading axes), taken modulo the node
    count on a periodic axis, in an array padded with ``ghost`` layers.  On a non-periodic
    axis the caller keeps them on the (padded) grid, or lets a scatter drop the rest."""
    origins = jnp.asarray(origins)
    d = len(size)
    lead = origins.shape[:-1]
    idx = []
    for a in range(d):
        node = origins[..., a, None] + offset + jnp.arange(size[a], dtype=jnp.int32)
        if periodic[a]:
            node = node % shape[a]
        idx.append((node + ghost).reshape(lead + (1,) * a + (size[a],) + (1,) * (d - a - 1)))
    return tuple(idx)


def check(window, shape, periodic):
    """ValueError unless ``window`` has one size in ``[1, n]`` per axis of ``shape``."""
    if len(window) != len(shape) or len(periodic) != len(shape):
        raise ValueError(
            f"window {tuple(window)}, grid {tuple(shape)} and periodic {tuple(periodic)} "
            "must have one entry per axis"
        )
    for a, (w, n) in enumerate(zip(window, shape, strict=True)):
        if not (isinstance(w, int) and 1 <= w <= n):
            raise ValueError(f"window size {w!r} along axis {a} must be an integer in [1, {n}]")


def gather(field, origin, window, periodic):
    """``field[..., window]``: the values of ``field`` (``(..., *grid)``) on the window at
    ``origin`` (``(d,)`` int), shape ``(..., *window)``."""
    window = tuple(window)
    d = len(window)
    shape = field.shape[-d:]
    check(window, shape, periodic)
    return field[(Ellipsis,) + index(origin, window, shape, periodic)]


def gather_ghosted(field, origin, size, periodic, offset: int = 0):
    """The values of ``field`` (``(..., *grid)``) at the nodes ``origin + offset ..
    origin + offset + size - 1`` of each axis, shape ``(..., *size)``: wrapped round on a
    periodic axis; on a walled axis the nodes beyond the grid take the linear extrapolation
    of the two nodes next to the edge, as the ghost layers of
    ``BoundaryConditions.pad_linear`` do (``(1 - u) f_0 + u f_1`` at node ``u < 0``), axis
    after axis like that padding, so a window at a wall reads the same ghosts as the padded
    grid without padding the whole grid."""
    size = tuple(size)
    d = len(size)
    shape = field.shape[-d:]
    out = field
    for a in range(d):
        ax = out.ndim - d + a
        n = shape[a]
        u = origin[a] + offset + jnp.arange(size[a], dtype=jnp.int32)
        if periodic[a]:
            out = jnp.take(out, u % n, axis=ax)
            continue
        out = _take_linear(out, u, ax)
    return out


def _take_linear(a, u, ax: int):
    """The values of ``a`` at the indices ``u`` (int array) along axis ``ax``, an index
    below 0 or past the last node taking the linear extrapolation of the two nodes next to
    that end (``(1 - u) f_0 + u f_1`` below, the mirror form above: ``pad_linear``'s
    ghosts)."""
    n = a.shape[ax]
    inside = jnp.take(a, jnp.clip(u, 0, n - 1), axis=ax)
    f0, f1, e0, e1 = (lax.index_in_dim(a, i, axis=ax) for i in (0, 1, n - 1, n - 2))
    bshape = (1,) * ax + (u.shape[0],) + (1,) * (a.ndim - ax - 1)
    uf = u.astype(a.dtype).reshape(bshape)
    m = uf - (n - 1)
    low = (1 - uf) * f0 + uf * f1
    high = (1 + m) * e0 - m * e1
    return jnp.where((u < 0).reshape(bshape), low, jnp.where((u > n - 1).reshape(bshape), high, inside))


def coordinates(origin, size, lows, spacing, shape, periodic, offset: int = 0, wrap: bool = True):
    """Node coordinates ``(d, *size)`` of the window's nodes ``origin + offset ..`` (the
    grid's ``low + (i + 0.5) h``): with ``wrap``, of the node a periodic axis wraps round to
    (the coordinates :func:`gather` reads); without, continued past the edge (a map made
    continuous across a periodic edge)."""
    d = len(size)
    axes = []
    for a in range(d):
        u = origin[a] + offset + jnp.arange(size[a], dtype=jnp.int32)
        if wrap and periodic[a]:
            u = u % shape[a]
        axes.append(lows[a] + (u.astype(jnp.float64) + 0.5) * spacing[a])
    return jnp.stack(jnp.meshgrid(*axes, indexing="ij"))


def put(grid_field, values, origin, periodic):
    """``grid_field`` with its values on the window at ``origin`` replaced by ``values``
    (``(..., *window)``; a window never overlaps itself: at most ``n`` nodes along a
    periodic axis)."""
    origin = jnp.asarray(origin)
    d = origin.shape[-1]
    window = values.shape[-d:]
    shape = grid_field.shape[-d:]
    check(window, shape, periodic)
    return grid_field.at[(Ellipsis,) + index(origin, window, shape, periodic)].set(values)


def scatter_add(grid_field, values, origin, periodic):
    """``grid_field`` with ``values`` (``(..., *window)``) added on the window at ``origin``
    (``(d,)`` int): the transpose of :func:`gather`."""
    origin = jnp.asarray(origin)
    d = origin.shape[-1]
    window = values.shape[-d:]
    shape = grid_field.shape[-d:]
    check(window, shape, periodic)
    return grid_field.at[(Ellipsis,) + index(origin, window, shape, periodic)].add(values)


def scatter_add_many(grid_field, values, origins, periodic):
    """``grid_field`` (``(..., *grid)``) plus every window of ``values`` (``(S, ...,
    *window)``, the leading axes after ``S`` those of ``grid_field``) at its origin
    (``origins`` ``(S, d)``), overlapping windows adding up: one scatter-add."""
    origins = jnp.asarray(origins)
    d = origins.shape[1]
    window = values.shape[-d:]
    shape = grid_field.shape[-d:]
    check(window, shape, periodic)
    lead = values.ndim - 1 - d
    # advanced indices on the last d axes: the result's axes are (..., S, *window)
    idx = index(origins, window, shape, periodic)
    return grid_field.at[(Ellipsis,) + idx].add(jnp.moveaxis(values, 0, lead))


def blocks(field, origins, size, periodic):
    """Every window's values of ``field`` (``(..., *grid)``): ``(S, ..., *size)`` for the
    ``origins`` ``(S, d)``, wrapping round a periodic axis (a window on a walled axis must lie
    on the grid).  The values of :func:`gather` at each origin, read as one slice per window
    (a block gather: whole rows copied) instead of one index per value; the transpose of
    :func:`accumulate`'s sum."""
    origins = jnp.asarray(origins).astype(jnp.int32)
    d = len(size)
    lead = field.ndim - d
    padded = field
    for a in range(d):
        ax = lead + a
        n = field.shape[ax]
        if periodic[a]:
            if size[a] > n:
                raise ValueError(f"a window of {size[a]} nodes on a periodic axis of {n}")
            padded = jnp.concatenate([padded, lax.slice_in_dim(padded, 0, size[a], axis=ax)], axis=ax)
    shape = field.shape[:lead] + tuple(size)
    zero = (jnp.int32(0),) * lead
    return jax.vmap(lambda o: lax.dynamic_slice(padded, zero + tuple(o[a] for a in range(d)), shape))(origins)


def accumulate(base, values, origins, periodic, op: str = "add"):
    """``base`` (``(..., *grid)``) with every window of ``values`` (``(S, ..., *size)``, the
    axes after ``S`` those of ``base``) combined into it at its origin (``origins`` ``(S,
    d)``): ``op = "add"`` sums overlapping windows, ``"min"`` keeps the smallest.  A window
    wraps round a periodic axis; past a walled edge its values are dropped.

    The windows are visited one after the other (``lax.fori_loop``), each a
    ``dynamic_slice`` and a ``dynamic_update_slice`` of a box of the grid padded by one
    window's size at the far side of every axis, whose padding is then folded back onto
    the start of a periodic axis (or dropped at a wall).  The same values as
    :func:`scatter_add_many` and ``.at[].min`` (up to the order of additions where windows
    overlap), but an XLA scatter with one index per value costs about ten times more on a
    CPU (100 windows of 60^2 at 300^2: ~10 against ~1 ms)."""
    origins = jnp.asarray(origins).astype(jnp.int32)
    d = origins.shape[1]
    size = values.shape[-d:]
    lead = base.ndim - d
    if values.shape[1:-d] != base.shape[:lead]:
        raise ValueError(f"windows {values.shape} do not fit a field of shape {base.shape}")
    acc = add_windows(padded_for(base, size, op), values, origins, op)
    return fold(acc, base.shape[-d:], size, periodic, op)


def _combine(op: str, dtype):
    if op == "add":
        return jnp.add, 0
    if op == "min":
        return jnp.minimum, (jnp.inf if jnp.issubdtype(dtype, jnp.floating) else jnp.iinfo(dtype).max)
    raise ValueError(f"op must be 'add' or 'min', got {op!r}")


def padded_for(base, size, op: str = "add"):
    """:func:`accumulate`'s accumulator: ``base`` padded by one window's ``size`` at the far
    side of every grid axis with ``op``'s neutral value.  Windows are added into it by
    :func:`add_windows` (in as many batches as wanted) and :func:`fold` makes the field."""
    d = len(size)
    lead = base.ndim - d
    neutral = _combine(op, base.dtype)[1]
    return jnp.pad(base, [(0, 0)] * lead + [(0, w) for w in size], constant_values=neutral)


def add_windows(acc, values, origins, op: str = "add"):
    """The windows ``values`` (S, ..., *size) combined into the padded accumulator ``acc``
    (:func:`padded_for`) at ``origins`` (S, d), one after the other."""
    combine = _combine(op, acc.dtype)[0]
    origins = jnp.asarray(origins).astype(jnp.int32)
    S, d = origins.shape
    lead = acc.ndim - d

    def body(k, acc):
        start = (jnp.int32(0),) * lead + tuple(origins[k, a] for a in range(d))
        cur = lax.dynamic_slice(acc, start, values.shape[1:])
        return lax.dynamic_update_slice(acc, combine(cur, values[k]), start)

    return lax.fori_loop(0, S, body, acc)


def fold(acc, shape, size, periodic, op: str = "add"):
    """The field of ``shape`` from :func:`accumulate`'s padded accumulator: the part past a
    periodic edge folded back onto the start of the axis, past a wall dropped."""
    combine = _combine(op, acc.dtype)[0]
    d = len(shape)
    lead = acc.ndim - d
    for a in range(d):
        ax = lead + a
        n, w = shape[a], size[a]
        core = lax.slice_in_dim(acc, 0, n, axis=ax)
        if periodic[a]:  # fold the part past the edge back onto the start, w nodes at most
            if w > n:
                raise ValueError(f"a window of {w} nodes on a periodic axis of {n}")
            tail = lax.slice_in_dim(acc, n, n + w, axis=ax)
            head = combine(lax.slice_in_dim(core, 0, w, axis=ax), tail)
            core = lax.dynamic_update_slice_in_dim(core, head, 0, axis=ax)
        acc = core
    return acc


def shift(values, old_origin, new_origin, shape, periodic, fill):
    """The window ``values`` (``(..., *window)``, at ``old_origin``) moved to
    ``new_origin`` on a grid of ``shape``: a node of the new window that the old one held
    keeps its value, the others take ``fill`` (a scalar)."""
    d = len(shape)
    window = values.shape[-d:]
    check(window, shape, periodic)
    out = values
    for a in range(d):
        n, w = shape[a], window[a]
        delta = new_origin[a] - old_origin[a]
        if periodic[a]:  # the shortest way round: delta in [-n/2, n/2)
            delta = (delta + n // 2) % n - n // 2
        src = jnp.arange(w, dtype=jnp.int32) + delta  # index into the old window
        ok = (src >= 0) & (src < w)
        ax = out.ndim - d + a
        taken = jnp.take(out, jnp.clip(src, 0, w - 1), axis=ax)
        mask = ok.reshape((1,) * ax + (w,) + (1,) * (out.ndim - ax - 1))
        out = jnp.where(mask, taken, jnp.asarray(fill, out.dtype))
    return out


def to_grid(values, origin, shape, periodic, fill):
    """The window ``values`` (``(..., *window)`` at ``origin``) on the whole grid of
    ``shape``, ``fill`` elsewhere."""
    d = len(shape)
    window = values.shape[-d:]
    check(window, shape, periodic)
    base = jnp.full(values.shape[:-d] + tuple(shape), fill, values.dtype)
    return base.at[(Ellipsis,) + index(origin, window, shape, periodic)].set(values)


def ghosted(values, before: int, after: int, d: int):
    """A window's values (``(..., *window)``, the last ``d`` axes) with ``before`` and
    ``after`` ghost layers on each axis, the linear extrapolation of the two nodes next to
    each edge, axis after axis (:func:`_take_linear`, as :func:`gather_ghosted`), so that at a
    window's side that lies on a wall the ghosts are the grid's (``pad_linear``'s) bit for
    bit.  At a side inside the grid the nodes past the window are beyond its body's band
    (the windows keep a margin), where no phase reads a value that matters."""
    out = values
    for a in range(d):
        ax = out.ndim - d + a
        out = _take_linear(out, jnp.arange(-before, out.shape[ax] + after, dtype=jnp.int32), ax)
    return out


def follow(phi_w, origin, reach, shape, periodic, margin: int = MARGIN):
    """``(origin (d,) int32, fits bool)``: where :func:`placement` puts a window of the
    size of ``phi_w`` (a body's level set on its window at ``origin``) on the grid of
    ``shape``, found from the window alone: the box of the window's nodes with ``phi <=
    reach``, centred as :func:`placement` centres the grid's box (the same origin when the
    window holds every such node).  ``fits``: that box with ``margin`` nodes to spare lies
    in the new window, and it does not touch a side of the old window that is inside the
    grid (the body might reach past it, unseen)."""
    return place_from(phi_w, origin, reach, phi_w.shape, shape, periodic, margin)


def place_from(phi_b, origin, reach, window, shape, periodic, margin: int = MARGIN):
    """``(origin (d,) int32, fits bool)``: where :func:`placement` puts a window of
    ``window`` nodes for a body whose level set is known on a box only: ``phi_b`` on the
    box at ``origin`` (any size, e.g. the box a shape's level set was evaluated on at
    t = 0).  The box of the nodes with ``phi <= reach`` is found in ``phi_b`` and centred as
    :func:`placement` centres the grid's box (the same origin when ``phi_b`` holds every
    such node).  ``fits``: that box with ``margin`` nodes to spare lies in the new window,
    and it does not touch a side of the box that is inside the grid (the body might reach
    past it, unseen).  :func:`follow` is the case ``window = phi_b.shape``."""
    box = phi_b.shape
    d = len(box)
    m = phi_b <= reach
    new, fits = [], jnp.any(m)
    for a in range(d):
        n, b, w = shape[a], box[a], window[a]
        line = jnp.any(m, axis=tuple(c for c in range(d) if c != a))
        lo_b, length = axis_box(line, False)
        edge_lo = periodic[a] | (origin[a] > 0)  # the box's sides inside the grid
        edge_hi = periodic[a] | (origin[a] + b < n)
        fits = fits & ~(edge_lo & (lo_b == 0)) & ~(edge_hi & (lo_b + length == b))
        o, ok = _centred(origin[a] + lo_b, length, n, w, periodic[a], margin)
        fits = fits & ok
        new.append(jnp.asarray(o, jnp.int32))
    return jnp.stack(new), fits


def _circular_box(line):
    """(start, length) of the smallest circular box holding every True of ``line`` (n,):
    the complement of its longest circular run of False.  (0, 0) when none is True."""
    n = line.shape[0]
    two = jnp.concatenate([line, line])
    pos = jnp.arange(2 * n, dtype=jnp.int32)
    last = lax.cummax(jnp.where(two, pos, -1), axis=0)
    run = pos - last  # length of the run of False ending at pos (0 on a True)
    tail = run[n:]  # runs ending in the second copy: at most n - 1 when any is True
    end = jnp.argmax(tail).astype(jnp.int32)
    gap = tail[end]
    start = (end + 1) % n
    length = n - gap
    any_true = jnp.any(line)
    return jnp.where(any_true, start, 0), jnp.where(any_true, length, 0)


def axis_box(line, periodic: bool):
    """(start, length) of the smallest box holding every True of the boolean ``line``
    (n,): circular on a periodic axis (:func:`_circular_box`), from the first to the last
    True otherwise; (0, 0) when none is True."""
    if periodic:
        return _circular_box(line)
    n = line.shape[0]
    idx = jnp.arange(n, dtype=jnp.int32)
    lo = jnp.min(jnp.where(line, idx, n))
    hi = jnp.max(jnp.where(line, idx, -1))
    any_true = jnp.any(line)
    return jnp.where(any_true, lo, 0), jnp.where(any_true, hi - lo + 1, 0)


def _centred(start, length, n: int, w: int, periodic: bool, margin: int):
    """``(origin, fits)`` along one axis of ``n`` nodes: a window of ``w`` nodes centred on
    the box ``[start, start + length)`` (inside ``[0, n - w]`` on a walled axis), and
    whether the box with ``margin`` nodes to spare lies in it (on a walled axis the spare
    may be cut by a grid edge the window shares)."""
    if periodic:
        o = (start + length // 2 - w // 2) % n
        lo = (start - o) % n  # the box lies in [o + margin, o + w - margin) mod n
        return o, (lo >= margin) & (lo + length <= w - margin)
    lo, hi = start, start + length - 1
    o = jnp.clip((lo + hi + 1) // 2 - w // 2, 0, n - w)
    return o, ((lo - margin >= o) | (o == 0)) & ((hi + margin <= o + w - 1) | (o + w == n))


def placement(phi, reach, window, periodic, margin: int = MARGIN):
    """``(origin (d,) int32, fits bool)`` of a window of size ``window`` for a body whose
    level set is ``phi`` (``(*grid)``): centred on the box of its nodes with
    ``phi <= reach``; on a non-periodic axis moved inside ``[0, n - W]``.  ``fits``: that box
    with ``margin`` nodes to spare on each side lies in the window (on a non-periodic axis
    the spare may be cut by a grid edge the window shares), and the body has such nodes.
    Use ``jax.vmap`` over bodies."""
    window = tuple(window)
    shape = phi.shape
    d = len(shape)
    check(window, shape, periodic)
    m = phi <= reach
    origin, fits = [], jnp.any(m)
    for a in range(d):
        n, w = shape[a], window[a]
        line = jnp.any(m, axis=tuple(b for b in range(d) if b != a))
        start, length = axis_box(line, periodic[a])
        o, ok = _centred(start, length, n, w, periodic[a], margin)
        fits = fits & ok
        origin.append(jnp.asarray(o, jnp.int32))
    return jnp.stack(origin), fits
