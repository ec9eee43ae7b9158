"""refmap.windows: the index work of per-body windows (docs/design_windows.md), against
numpy's own slicing with wrapped indices, in 2D and 3D, on periodic and walled axes."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap import windows


def _np_index(origin, window, shape, periodic):
    idx = []
    for a, (o, w, n) in enumerate(zip(origin, window, shape, strict=True)):
        i = np.arange(o, o + w)
        if not periodic[a]:
            assert i[-1] < n  # a walled axis's window stays on the grid
        idx.append(i % n)
    return np.ix_(*idx)


CASES = [
    ((12, 10), (5, 4), (True, True), [(0, 0), (9, 8), (11, 9), (3, 2)]),  # wraps x, y, corner
    ((12, 10), (5, 4), (False, False), [(0, 0), (7, 6), (3, 2)]),  # walls: on the grid
    ((12, 10), (12, 3), (True, False), [(5, 7), (0, 0)]),  # a window the whole period long
    ((6, 7, 5), (3, 4, 2), (True, False, True), [(5, 3, 4), (0, 0, 0), (2, 1, 3)]),
]


@pytest.mark.parametrize(("shape", "window", "periodic", "origins"), CASES)
def test_gather_and_to_grid_match_numpy(shape, window, periodic, origins):
    rng = np.random.default_rng(1)
    f = rng.normal(size=(2, *shape))
    for o in origins:
        got = windows.gather(jnp.asarray(f), jnp.asarray(o, jnp.int32), window, periodic)
        want = f[(Ellipsis,) + _np_index(o, window, shape, periodic)]
        np.testing.assert_array_equal(np.asarray(got), want)
        full = windows.to_grid(got, jnp.asarray(o, jnp.int32), shape, periodic, -7.0)
        ref = np.full_like(f, -7.0)
        ref[(Ellipsis,) + _np_index(o, window, shape, periodic)] = want
        np.testing.assert_array_equal(np.asarray(full), ref)


@pytest.mark.parametrize(("shape", "window", "periodic", "origins"), CASES)
def test_scatter_add_is_the_transpose_of_gather(shape, window, periodic, origins):
    """<gather(f), w> = <f, scatter_add(0, w)> for every origin (the adjoint identity), and
    several windows added at once equal adding them one by one (overlaps accumulate)."""
    rng = np.random.default_rng(2)
    f = jnp.asarray(rng.normal(size=(3, *shape)))
    ws = jnp.asarray(rng.normal(size=(len(origins), 3, *window)))
    o = jnp.asarray(origins, jnp.int32)
    total = jnp.zeros_like(f)
    for k in range(len(origins)):
        lhs = jnp.vdot(windows.gather(f, o[k], window, periodic), ws[k])
        placed = windows.scatter_add(jnp.zeros_like(f), ws[k], o[k], periodic)
        assert float(lhs) == pytest.approx(float(jnp.vdot(f, placed)), rel=1e-13)
        total = total + placed
    many = windows.scatter_add_many(jnp.zeros_like(f), ws, o, periodic)
    np.testing.assert_allclose(np.asarray(many), np.asarray(total), rtol=1e-14, atol=1e-14)
    # and it is what jax.vjp of the gather gives
    _, vjp = jax.vjp(lambda g: windows.gather(g, o[0], window, periodic), f)
    np.testing.assert_allclose(np.asarray(vjp(ws[0])[0]),
                               np.asarray(windows.scatter_add(jnp.zeros_like(f), ws[0], o[0], periodic)),
                               rtol=0, atol=0)


def _disc_phi(shape, h, center, r, periodic):
    """Signed distance to a disc on a node grid of spacing h (periodic images on periodic
    axes)."""
    axes = [np.arange(n) * h for n in shape]
    X = np.meshgrid(*axes, indexing="ij")
    d2 = 0.0
    for a, (x, c) in enumerate(zip(X, center, strict=True)):
        dx = x - c
        if periodic[a]:
            L = shape[a] * h
            dx = (dx + L / 2) % L - L / 2
        d2 = d2 + dx * dx
    return np.sqrt(d2) - r


@pytest.mark.parametrize("periodic", [(True, True), (False, False), (True, False)])
@pytest.mark.parametrize("center", [(0.5, 0.5), (0.02, 0.5), (0.98, 0.03), (0.6, 0.97)])
def test_placement_holds_the_band_with_its_margin(periodic, center):
    """A disc of radius 0.1 (reach 0.05) on a 50^2 grid of the unit box, anywhere,
    straddling periodic edges and corners or touching walls: the window of 24 nodes holds
    every node with phi <= reach, with the margin to spare except at a wall the window
    shares; on a walled axis the window stays on the grid."""
    shape, h, reach, window = (50, 50), 1.0 / 50, 0.05, (24, 24)
    phi = _disc_phi(shape, h, center, 0.1, periodic)
    origin, fits = windows.placement(jnp.asarray(phi), reach, window, periodic)
    origin = np.asarray(origin)
    assert bool(fits)
    inside = np.zeros(shape, bool)
    inside[_np_index(origin, window, shape, periodic)] = True
    band = phi <= reach
    assert not (band & ~inside).any()
    for a in range(2):
        if not periodic[a]:
            assert 0 <= origin[a] <= shape[a] - window[a]
    # the margin: the band's nodes shifted by +-MARGIN along each axis are still inside,
    # unless that crosses a wall
    m = windows.MARGIN
    for a, s in itertools.product(range(2), (-m, m)):
        moved = np.roll(band, s, axis=a)
        if not periodic[a]:  # np.roll wraps: drop what crossed a wall
            sl = [slice(None)] * 2
            sl[a] = slice(0, s) if s > 0 else slice(s, None)
            moved[tuple(sl)] = False
        assert not (moved & ~inside).any(), (a, s)


def test_placement_reports_a_body_too_large_or_absent():
    shape, h = (40, 40), 1.0 / 40
    phi = _disc_phi(shape, h, (0.5, 0.5), 0.3, (True, True))  # 24+ nodes across
    _, fits = windows.placement(jnp.asarray(phi), 0.05, (20, 20), (True, True))
    assert not bool(fits)
    _, fits = windows.placement(jnp.full(shape, 1.0), 0.05, (20, 20), (True, True))
    assert not bool(fits)  # no node within reach: nothing to hold
    # vmapped over bodies, under jit
    phis = jnp.stack([jnp.asarray(_disc_phi(shape, h, c, 0.1, (True, False)))
                      for c in ((0.1, 0.5), (0.9, 0.9))])
    o, f = jax.jit(jax.vmap(lambda p: windows.placement(p, 0.05, (20, 20), (True, False))))(phis)
    assert o.shape == (2, 2) and bool(jnp.all(f))


@pytest.mark.parametrize("periodic", [(True, True), (False, False)])
def test_shift_keeps_the_overlap_and_fills_the_rest(periodic):
    """Moving a window's values to a new origin equals gathering at the new origin where
    the two windows overlap, and gives ``fill`` where the new window reaches nodes the old
    one did not hold (periodic: the shortest way round, across the edge)."""
    shape, window = (16, 14), (6, 5)
    rng = np.random.default_rng(3)
    f = jnp.asarray(rng.normal(size=(2, *shape)))
    pairs = [((2, 3), (4, 2)), ((5, 5), (5, 5)), ((2, 3), (10, 9))]
    if periodic[0]:
        pairs.append(((14, 12), (1, 0)))  # across the corner
    for old, new in pairs:
        o, n = jnp.asarray(old, jnp.int32), jnp.asarray(new, jnp.int32)
        moved = windows.shift(windows.gather(f, o, window, periodic), o, n, shape, periodic, 9.0)
        direct = np.asarray(windows.gather(f, n, window, periodic))
        held = np.zeros(shape, bool)
        held[_np_index(old, window, shape, periodic)] = True
        held_new = held[_np_index(new, window, shape, periodic)]
        moved = np.asarray(moved)
        np.testing.assert_array_equal(moved[:, held_new], direct[:, held_new])
        assert np.all(moved[:, ~held_new] == 9.0)


def test_bad_windows_are_refused():
    f = jnp.zeros((8, 8))
    with pytest.raises(ValueError, match="window size 9 along axis 0"):
        windows.gather(f, jnp.zeros(2, jnp.int32), (9, 4), (False, False))
    with pytest.raises(ValueError, match="one entry per axis"):
        windows.gather(f, jnp.zeros(2, jnp.int32), (4, 4), (False,))


def _brute_circular_box(line):
    """The shortest circular interval [s, s + L) holding every True (smallest L, then
    smallest s), by trying them all."""
    n = len(line)
    if not line.any():
        return 0, 0
    for L in range(1, n + 1):
        for s in range(n):
            covered = np.zeros(n, bool)
            covered[(s + np.arange(L)) % n] = True
            if not (line & ~covered).any():
                return s, L
    raise AssertionError


def test_circular_box_is_the_shortest_covering_interval():
    rng = np.random.default_rng(4)
    lines = [np.zeros(9, bool), np.ones(9, bool)]
    for n in (1, 2, 7, 12):
        for p in (0.15, 0.4):
            lines += [rng.random(n) < p for _ in range(20)]
    for line in lines:
        s, L = (int(x) for x in windows._circular_box(jnp.asarray(line)))
        bs, bL = _brute_circular_box(line)
        assert L == bL, (line, s, L, bs, bL)
        covered = np.zeros(len(line), bool)
        covered[(s + np.arange(L)) % len(line)] = True
        assert not (line & ~covered).any(), (line, s, L)


@pytest.mark.parametrize("periodic", [(True, True), (False, False)])
def test_placement_with_a_tight_window(periodic):
    """A window exactly the band's box plus the margin on each side fits, one node
    smaller does not (a disc away from the walls; on periodic axes across the corner)."""
    shape, h, reach = (50, 50), 1.0 / 50, 0.03
    center = (0.99, 0.01) if periodic[0] else (0.5, 0.5)
    phi = _disc_phi(shape, h, center, 0.1, periodic)
    band = phi <= reach
    extent = max(int(windows._circular_box(jnp.asarray(band.any(axis=1 - a)))[1]) for a in range(2))
    tight = extent + 2 * windows.MARGIN
    _, fits = windows.placement(jnp.asarray(phi), reach, (tight, tight), periodic)
    assert bool(fits)
    _, fits = windows.placement(jnp.asarray(phi), reach, (tight - 1, tight - 1), periodic)
    assert not bool(fits)


@pytest.mark.parametrize("periodic", [(False, False), (True, False), (True, True)])
def test_gather_ghosted_reads_the_padded_grid(periodic):
    """A window with two ghost layers read by ``gather_ghosted`` from the unpadded field is,
    bit for bit, the same box of ``BoundaryConditions.pad_linear``'s padded field: wrapped
    round a periodic edge, linearly extrapolated past a wall (edges and corners)."""
    from refmap.boundary import Boundary, BoundaryConditions
    from refmap.grid import Grid

    edge = {False: "wall", True: "periodic"}
    bc = BoundaryConditions(Grid(20, 17), Boundary(left=edge[periodic[0]], right=edge[periodic[0]],
                                                   bottom=edge[periodic[1]], top=edge[periodic[1]]))
    rng = np.random.default_rng(3)
    f = jnp.asarray(rng.normal(size=(3, 20, 17)))
    padded = np.asarray(bc.pad_linear(f))
    W = (8, 7)
    for o in [(0, 0), (12, 10), (5, 3), (19, 16), (13, 0)]:
        o = tuple(min(o[a], f.shape[1 + a] - W[a]) if not periodic[a] else o[a] for a in range(2))
        got = windows.gather_ghosted(f, jnp.asarray(o), (W[0] + 4, W[1] + 4), periodic, offset=-2)
        # padded index of node u is u + 2; a periodic axis wraps u first
        ix = [((np.arange(W[a] + 4) + o[a] - 2) % f.shape[1 + a] if periodic[a] else
               np.arange(W[a] + 4) + o[a] - 2) + 2 for a in range(2)]
        np.testing.assert_array_equal(np.asarray(got), padded[:, ix[0]][:, :, ix[1]])
    # coordinates: wrapped ones are the grid's node coordinates, unwrapped ones continue
    grid = Grid(20, 17)
    X = windows.coordinates(jnp.asarray((18, 15)), (4, 4), grid.lows, grid.spacing, (20, 17), (True, True))
    Xu = windows.coordinates(jnp.asarray((18, 15)), (4, 4), grid.lows, grid.spacing, (20, 17), (True, True),
                             wrap=False)
    mesh = np.stack(grid.mesh("node"))
    np.testing.assert_array_equal(np.asarray(X), mesh[:, [18, 19, 0, 1]][:, :, [15, 16, 0, 1]])
    np.testing.assert_allclose(np.asarray(Xu)[0, 2:] - np.asarray(X)[0, 2:], grid.bx - grid.ax, rtol=1e-14)


def test_put_writes_only_the_window():
    f = jnp.zeros((2, 10, 9))
    vals = jnp.ones((2, 4, 3))
    out = np.asarray(windows.put(f, vals, jnp.asarray((8, 7)), (True, True)))
    assert out.sum() == 24
    assert out[:, [8, 9, 0, 1]][:, :, [7, 8, 0]].min() == 1.0


@pytest.mark.parametrize("o", [(0, 0), (12, 10), (0, 5), (12, 3), (4, 10)])
def test_ghosted_window_reads_the_walls_ghosts(o):
    """A window stored on its own, given ghost layers by ``ghosted``, holds at a side it
    shares with a wall the ghosts ``gather_ghosted`` reads from the grid (those of
    ``pad_linear``), bit for bit, edges and corners; inside it the window's values."""
    rng = np.random.default_rng(5)
    f = jnp.asarray(rng.normal(size=(2, 20, 17)))
    W = (8, 7)
    per = (False, False)
    o = jnp.asarray(o)
    w = windows.gather(f, o, W, per)
    got = np.asarray(windows.ghosted(w, 1, 2, 2))
    ref = np.asarray(windows.gather_ghosted(f, o, (W[0] + 3, W[1] + 3), per, offset=-1))
    assert got.shape == ref.shape == (2, 11, 10)
    np.testing.assert_array_equal(got[:, 1:-2, 1:-2], np.asarray(w))
    # the nodes whose every index lies in the window or past a wall it shares
    trusted = []
    for a, (n, w) in enumerate(((20, 8), (17, 7))):
        u = np.arange(-1, w + 2)
        lo_wall, hi_wall = int(o[a]) == 0, int(o[a]) + w == n
        trusted.append(((u >= 0) | lo_wall) & ((u < w) | hi_wall))
    mask = np.broadcast_to((trusted[0][:, None] & trusted[1][None, :])[None], got.shape)
    np.testing.assert_array_equal(got[mask], ref[mask])
    assert mask.sum() > 2 * 8 * 7 or not any(int(c) in (0, 12, 10) for c in o)  # some ghosts compared
    # a window's affine field stays affine in its ghosts (any side)
    X, Y = np.meshgrid(np.arange(8.0), np.arange(7.0), indexing="ij")
    aff = jnp.asarray(2.0 * X - 0.5 * Y + 1.0)
    u = np.arange(-1, 10.0)
    v = np.arange(-1, 9.0)
    U, V = np.meshgrid(u, v, indexing="ij")
    np.testing.assert_allclose(np.asarray(windows.ghosted(aff, 1, 2, 2)), 2.0 * U - 0.5 * V + 1.0, atol=1e-13)


@pytest.mark.parametrize("periodic", [(True, True), (False, False), (True, False)])
@pytest.mark.parametrize("center", [(0.5, 0.5), (0.02, 0.5), (0.98, 0.03), (0.6, 0.97)])
def test_follow_places_a_window_as_placement_does(periodic, center):
    """``follow`` finds from a body's window alone the origin ``placement`` finds from the
    whole grid, for a disc anywhere (periodic edges and corners, walls), starting from a
    window that holds it a few nodes off centre; it reports a band that touches a side of
    the old window inside the grid (it may reach past it) or does not fit the new one."""
    shape, h, reach, window = (50, 50), 1.0 / 50, 0.05, (24, 24)
    phi = jnp.asarray(_disc_phi(shape, h, center, 0.1, periodic))
    origin, fits = windows.placement(phi, reach, window, periodic, margin=2)
    assert bool(fits)
    for shift in ((0, 0), (2, -1), (-2, 2)):
        old = origin + jnp.asarray(shift)
        old = jnp.asarray([o % n if p else min(max(int(o), 0), n - w)
                           for o, n, w, p in zip(old, shape, window, periodic, strict=True)])
        phi_w = windows.gather(phi, old, window, periodic)
        new, ok = windows.follow(phi_w, old, reach, shape, periodic, margin=2)
        # the old window holds the whole band, off its sides inside the grid (else the
        # band may go on past it, which follow must report)
        inside = np.zeros(shape, bool)
        inside[_np_index(np.asarray(old), window, shape, periodic)] = True
        band = np.asarray(phi) <= reach
        held = not (band & ~inside).any()
        w_band = np.asarray(phi_w) <= reach
        for a in range(2):
            line = w_band.any(axis=1 - a)
            lo_inner = periodic[a] or int(old[a]) > 0
            hi_inner = periodic[a] or int(old[a]) + window[a] < shape[a]
            held &= not ((lo_inner and line[0]) or (hi_inner and line[-1]))
        assert bool(ok) == held
        if held:
            np.testing.assert_array_equal(np.asarray(new), np.asarray(origin))
    # a window that cuts the band on a side inside the grid: not fit (the body may reach past it)
    big = jnp.asarray(_disc_phi(shape, h, (0.5, 0.5), 0.15, periodic))
    old = jnp.asarray((20, 13))
    _, ok = windows.follow(windows.gather(big, old, window, periodic), old, reach, shape, periodic, margin=2)
    assert not bool(ok)
    # no node within reach: nothing to follow
    _, ok = windows.follow(jnp.ones(window), old, reach, shape, periodic)
    assert not bool(ok)


@pytest.mark.parametrize("periodic", [(True, True), (False, False), (True, False)])
def test_accumulate_equals_the_scatters(periodic):
    """``accumulate`` (one window after the other, by dynamic slices) gives the values of
    the XLA scatters it replaces: overlapping windows summed (``scatter_add_many``) or
    their smallest kept, windows wrapping round periodic edges and corners, values past a
    wall dropped; with a leading axis of components; integers for the minimum."""
    rng = np.random.default_rng(11)
    shape, size = (20, 17), (9, 8)
    origins = jnp.asarray([[0, 0], [15, 12], [5, 3], [11, 9], [3, 14]])
    if not periodic[0]:
        origins = origins.at[:, 0].set(jnp.minimum(origins[:, 0], shape[0] - size[0] + 1))
    if not periodic[1]:
        origins = origins.at[:, 1].set(jnp.minimum(origins[:, 1], shape[1] - size[1] + 1))
    vals = jnp.asarray(rng.normal(size=(5, 3) + size))
    base = jnp.asarray(rng.normal(size=(3,) + shape))
    idx = windows.index(origins, size, shape, periodic)
    ref = base.at[(slice(None),) + idx].add(jnp.moveaxis(vals, 0, 1), mode="drop")
    got = windows.accumulate(base, vals, origins, periodic, "add")
    np.testing.assert_allclose(np.asarray(got), np.asarray(ref), rtol=0, atol=1e-14)
    ref = base[0].at[idx].min(vals[:, 0], mode="drop")
    got = windows.accumulate(base[0], vals[:, 0], origins, periodic, "min")
    np.testing.assert_array_equal(np.asarray(got), np.asarray(ref))
    k = jnp.asarray(rng.integers(0, 9, size=(5,) + size), jnp.int32)
    ref = jnp.full(shape, 9, jnp.int32).at[idx].min(k, mode="drop")
    np.testing.assert_array_equal(np.asarray(windows.accumulate(jnp.full(shape, 9, jnp.int32), k, origins,
                                                                periodic, "min")), np.asarray(ref))
    with pytest.raises(ValueError, match="op must be 'add' or 'min', got 'max'"):
        windows.accumulate(base, vals, origins, periodic, "max")


@pytest.mark.parametrize("periodic", [(True, True), (False, False), (True, False)])
def test_blocks_read_what_gather_reads(periodic):
    """``blocks`` (one slice per window) reads every window's values as ``gather`` does
    (one index per value), wrapping round periodic edges and corners, with a leading axis
    of components; a window longer than a periodic axis is refused."""
    rng = np.random.default_rng(13)
    shape, size = (20, 17), (9, 8)
    field = jnp.asarray(rng.normal(size=(3,) + shape))
    origins = [(0, 0), (15, 12), (5, 3), (11, 9), (3, 14)]
    origins = jnp.asarray([[o if p else min(o, n - w) for o, n, w, p in zip(og, shape, size, periodic, strict=True)]
                           for og in origins])
    got = np.asarray(windows.blocks(field, origins, size, periodic))
    ref = np.stack([np.asarray(windows.gather(field, o, size, periodic)) for o in origins])
    np.testing.assert_array_equal(got, ref)
    if periodic[0]:
        with pytest.raises(ValueError, match="a window of 21 nodes on a periodic axis of 20"):
            windows.blocks(field, origins, (21, 8), periodic)
