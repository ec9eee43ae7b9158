"""The band layout of the sweeps (refmap.narrowband): same result as the full-grid sweeps."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax

import refmap  # noqa: F401  (float64)
from refmap import narrowband
from refmap.extrapolation import band_tiles, extend
from refmap.grid import Grid
from refmap.scenarios import get_case
from refmap.state import Numerics

SMOOTH = {
    "none": None,
    "adaptive": dict(coef=0.025, max_sweeps=80, ratio=0.25, atol=1e-3, fixed_sweeps=None),
    "fixed": dict(fixed_sweeps=7),
}


def _fields(nx, ny):
    g = Grid(nx, ny)
    X, Y = g.mesh()
    arm = np.minimum(
        np.hypot(np.maximum(abs(X) - 1.1, 0), Y) - 0.4,
        np.hypot(X, np.maximum(abs(Y) - 1.1, 0)) - 0.4,
    )
    # a disc, a cross with concave corners, a disc cut by the top-right corner of the box
    phis = np.stack([np.hypot(X - 0.1, Y + 0.05) - 0.8, arm, np.hypot(X - 1.7, Y - 1.8) - 0.5])
    f = np.stack([np.stack([np.sin(2 * X + 1) * np.cos(1.5 * Y), X * Y]) for _ in range(3)])
    return g, phis, f


@pytest.mark.parametrize(
    "shape, periodic, smooth",
    [
        ((100, 70), (False, False), "adaptive"),  # padded tiles at the far edges
        ((100, 70), (False, False), "fixed"),
        ((96, 72), (True, False), "none"),
        ((96, 72), (True, True), "adaptive"),  # tiles of 16 x 18; the corner disc wraps
        ((96, 72), (False, True), "fixed"),
    ],
)
def test_tiles_equal_full_grid_sweeps(shape, periodic, smooth):
    g, phis, f = _fields(*shape)
    band = 6 * g.h
    tile = narrowband.tile_shape(shape, periodic)
    counts = np.asarray(band_tiles(phis, band, tile, periodic))
    sm = SMOOTH[smooth]

    def run(capacity):
        return np.asarray(
            jax.jit(
                lambda f, p: extend(
                    f, p, g.dx, g.dy, band, capacity, periodic=periodic, smooth=sm, tile=tile
                )
            )(f, phis)
        )

    dense = run(None)
    tiles = run(int(counts.max()) + 1)
    # the same arithmetic node for node; XLA may fuse it differently (last-bit differences)
    scale = np.abs(dense).max()
    assert np.abs(tiles - dense).max() <= 1e-14 * scale
    # a band that does not fit falls back on the full-grid sweeps: bitwise the dense result
    np.testing.assert_array_equal(run(int(counts.max()) - 1), dense)
    # every node outside the bands is untouched
    outside = np.broadcast_to((phis > band)[:, None], f.shape)
    np.testing.assert_array_equal(tiles[outside], f[outside])


def test_capacity_ladder_takes_the_first_that_fits():
    """A tuple of capacities: the smallest that holds every band is swept (same result as
    the full grid), and when none does the full-grid sweeps run (bitwise)."""
    g, phis, f = _fields(100, 70)
    band = 6 * g.h
    tile = narrowband.tile_shape((100, 70))
    most = int(np.asarray(band_tiles(phis, band, tile)).max())
    sm = SMOOTH["fixed"]

    def run(capacity):
        return np.asarray(
            jax.jit(lambda f, p: extend(f, p, g.dx, g.dy, band, capacity, smooth=sm, tile=tile))(
                f, phis
            )
        )

    dense = run(None)
    scale = np.abs(dense).max()
    exact = run(most)
    for ladder in ((most, most + 5), (most - 1, most), (most - 3, most - 1, most + 4)):
        np.testing.assert_array_equal(run(ladder), exact)  # the same tiles, whatever slots
    assert np.abs(exact - dense).max() <= 1e-14 * scale
    np.testing.assert_array_equal(run((most - 2, most - 1)), dense)


def test_tile_shape_on_periodic_axes():
    assert narrowband.tile_shape((100, 70)) == (16, 16)
    assert narrowband.tile_shape((96, 72), (True, True)) == (16, 18)
    assert narrowband.tile_shape((24, 20), (True, True)) == (12, 20)  # divisors nearest 16
    assert narrowband.tile_shape((101, 64), (True, False)) is None  # prime: no tiling


@pytest.mark.parametrize("name", ["rotor", "two_balls"])
def test_model_band_sweeps_equal_grid_sweeps(name):
    """Ten steps with the band sweeps on tiles equal the full-grid sweeps to round-off.
    two_balls runs the explicit viscous step here: its implicit solve (BiCGSTAB, stopped at
    a relative residual) passes the sweeps' round-off differences on amplified, 2.0e-12
    against velocities of 8.6e-4 after ten steps, while the subject is the sweeps."""
    case = get_case(name, 96)
    if name == "two_balls":
        case = case.replace(numerics=dataclasses.replace(case.numerics, viscosity="explicit"))
    out = {}
    for mode in ("grid", "band"):
        c = case.replace(numerics=dataclasses.replace(case.numerics, band_sweeps=mode))
        model, params = c.build()
        if mode == "band":
            assert model.band_capacity is not None  # tiled (144 tiles of 8 x 8)
        s = model.initial_state(params)
        out[mode] = jax.jit(lambda s, model=model, params=params: model.run_steps(s, params, 10))(s)
    for k in ("v", "rho_f", "xi", "phi"):
        a, b = np.asarray(getattr(out["grid"], k)), np.asarray(getattr(out["band"], k))
        assert np.abs(a - b).max() <= 1e-12 * max(np.abs(a).max(), 1.0), k


@pytest.mark.parametrize(
    "kw, msg", [({"band_sweeps": "list"}, "band_sweeps"), ({"band_capacity": 0.5}, "band_capacity")]
)
def test_bad_band_numerics_refused(kw, msg):
    with pytest.raises(ValueError, match=msg):
        Numerics(**kw)


def test_auto_tiles_only_a_band_that_covers_little_of_the_grid():
    """band_sweeps = "auto" (the default) lists tiles only when the capacity is at most
    BAND_TILE_FRACTION of the grid's tiles: a small disc on a large grid is tiled, the
    rotor at 64^2 (its band covers most of the 16 tiles) is swept densely, "band" forces
    tiles and "grid" forbids them."""
    from refmap.geometry import Disc
    from refmap.materials import NeoHookean
    from refmap.model import BAND_TILE_FRACTION, Model, Solid

    assert Numerics().band_sweeps == "auto"
    grid = Grid(256, 256)
    disc = Solid(Disc((0.0, 0.0), 0.1), NeoHookean(G=1.0, kappa=1.0))
    caps = {
        m: Model(grid, (disc,), numerics=Numerics(band_sweeps=m)).band_capacity
        for m in ("auto", "band", "grid")
    }
    assert caps["grid"] is None
    assert caps["auto"] == caps["band"] is not None
    assert caps["auto"] <= BAND_TILE_FRACTION * 16 * 16
    rotor = {}
    for m in ("auto", "band"):
        case = get_case("rotor", 64)
        model, _ = case.replace(numerics=dataclasses.replace(case.numerics, band_sweeps=m)).build()
        rotor[m] = model.band_capacity
    assert rotor["auto"] is None
    assert rotor["band"] > BAND_TILE_FRACTION * 4 * 4


# ------------------------------------------------------------------------------- 3D


def _fields_3d(shape):
    from refmap.grid import Grid3D

    g = Grid3D(*shape, -1.0, 1.0, -1.1, 1.1, -0.95, 0.95)
    X, Y, Z = g.mesh()
    # an ellipsoid (phi not a distance) and a small sphere cut by the box's far corner
    phis = np.stack([
        np.sqrt((X - 0.1) ** 2 / 1.2 + (Y + 0.05) ** 2 + (Z - 0.02) ** 2) - 0.5,
        np.sqrt((X - 0.8) ** 2 + (Y - 0.9) ** 2 + (Z + 0.7) ** 2) - 0.35,
    ])
    one = np.stack([np.sin(2 * X + 1) * np.cos(1.5 * Y) * np.exp(0.3 * Z), X * Y - Z])
    f = np.where(phis[:, None] < 0, np.stack([one, one + 0.5]), 0.0)
    return g, phis, f


@pytest.mark.parametrize(
    "shape, periodic, smooth",
    [
        ((30, 34, 26), (False, False, False), "adaptive"),  # padded tiles at the far faces
        ((30, 34, 26), (False, False, False), "fixed"),
        ((32, 36, 30), (True, False, True), "none"),  # tiles 8 x 8 x 6 (or 10) on the wraps
        ((32, 36, 30), (False, True, False), "adaptive"),
    ],
)
def test_tiles_equal_full_grid_sweeps_3d(shape, periodic, smooth):
    """The 3D tiles (8 x 8 x 8 by default) give the full-grid sweeps' result to round-off;
    a band that does not fit falls back on the full grid (bitwise); nothing outside the
    bands changes."""
    from refmap.extrapolation import TILE_TARGET

    g, phis, f = _fields_3d(shape)
    band = 6 * g.h
    tile = narrowband.tile_shape(shape, periodic, target=TILE_TARGET[3])
    assert tile is not None and all(6 <= t <= 10 for t in tile)
    counts = np.asarray(band_tiles(phis, band, tile, periodic))
    assert counts.max() < np.prod(narrowband.n_tiles(shape, tile))  # some tiles not listed
    sm = SMOOTH[smooth]

    def run(capacity):
        return np.asarray(
            jax.jit(
                lambda f, p: extend(f, p, g.dx, g.dy, band, capacity, periodic=periodic,
                                    smooth=sm, tile=tile, dz=g.dz)
            )(f, phis)
        )

    dense = run(None)
    tiles = run(int(counts.max()) + 1)
    assert np.abs(tiles - dense).max() <= 1e-14 * np.abs(dense).max()
    assert np.any(tiles != f)  # the sweeps did change the bands
    np.testing.assert_array_equal(run(int(counts.max()) - 1), dense)
    outside = np.broadcast_to((phis > band)[:, None], f.shape)
    np.testing.assert_array_equal(tiles[outside], f[outside])


def test_tile_layout_3d_neighbours_and_scatter():
    """The 3D tile list: slots in index order, each face neighbour found (wrapping on a
    periodic axis, absent beyond a wall), and gather then scatter is the identity on the
    listed tiles."""
    shape, tile, periodic = (12, 8, 9), (4, 4, 3), (True, False, False)
    mask = np.zeros(shape, dtype=bool)
    mask[0, 0, 0] = True  # tile (0, 0, 0)
    mask[11, 5, 8] = True  # tile (2, 1, 2)
    mask[9, 1, 1] = True  # tile (2, 0, 0): the x- periodic neighbour of (0, 0, 0)
    t = narrowband.build(jnp.asarray(mask), 4, tile, periodic)
    assert int(t.count) == 3
    pos = np.stack([np.asarray(p) for p in t.pos])[:, :3].T.tolist()
    assert pos == [[0, 0, 0], [2, 0, 0], [2, 1, 2]]
    listed, ptr = np.asarray(t.listed), np.asarray(t.ptr)
    # (0,0,0): x- wraps to (2,0,0) at slot 1; its x+ neighbour (1,0,0) is not listed
    assert listed[0, 0] and ptr[0, 0] == 1 and not listed[1, 0]
    # (2,0,0): x+ wraps to (0,0,0) at slot 0; y- and z- lie beyond the walls
    assert listed[1, 1] and ptr[1, 1] == 0 and not listed[2, 1] and not listed[4, 1]
    assert not np.any(listed[:, 3])  # the empty slot is nobody's neighbour and has none
    a = jnp.asarray(np.random.default_rng(0).standard_normal((2,) + shape))
    G = narrowband.gather(a, t, tile, periodic, 0.0, halo=0)
    assert G.shape == (2, 4) + tile
    np.testing.assert_array_equal(np.asarray(G[:, 2]), np.asarray(a[:, 8:12, 4:8, 6:9]))
    idx = narrowband.node_index(t, tile, shape)
    back = narrowband.scatter(jnp.zeros_like(a), idx, G)
    listed_nodes = np.zeros(shape, dtype=bool)
    for i, j, k in pos:
        listed_nodes[4 * i:4 * i + 4, 4 * j:4 * j + 4, 3 * k:3 * k + 3] = True
    np.testing.assert_array_equal(np.asarray(back)[:, listed_nodes], np.asarray(a)[:, listed_nodes])
    assert not np.any(np.asarray(back)[:, ~listed_nodes])


def test_model_band_tiles_3d_equal_grid_sweeps():
    """A 3D model with band_sweeps = "band" (two spheres thrown at each other, one sheared,
    on 8^3 tiles) runs the full-grid sweeps' steps to round-off; "auto" tiles a band that
    lists little of the grid and not one that lists all of it."""
    from refmap.boundary import Boundary
    from refmap.geometry import Sphere
    from refmap.grid import Grid3D
    from refmap.materials import NeoHookean
    from refmap.model import Model, Solid

    law = NeoHookean(G=5.0, kappa=5.0, dim=3)
    A = ((1.0, 0.2, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    solids = (
        Solid(Sphere(center=(-0.55, 0.1, 0.0), radius=0.3), law, strain=A,
              strain_center=(-0.55, 0.1, 0.0), velocity=(0.3, 0.0, 0.0)),
        Solid(Sphere(center=(0.55, -0.1, 0.15), radius=0.3), law, velocity=(-0.3, 0.0, 0.0), name="b"),
    )
    walls = {f: "wall" for f in ("left", "right", "bottom", "top", "back", "front")}
    g = Grid3D(32, 32, 32, -1.5, 1.5, -1.5, 1.5, -1.5, 1.5)
    out = {}
    for mode in ("grid", "band"):
        model = Model(g, solids, Boundary(**walls), Numerics(band_sweeps=mode))
        if mode == "band":
            assert model.band_tile == (8, 8, 8) and model.band_capacity is not None
        p = model.default_params()
        s = model.initial_state(p)
        out[mode] = jax.jit(lambda s, model=model, p=p: model.run_steps(s, p, 6))(s)
    for k in ("v", "rho_f", "xi", "phi"):
        a, b = np.asarray(getattr(out["grid"], k)), np.asarray(getattr(out["band"], k))
        assert np.abs(a - b).max() <= 1e-12 * max(np.abs(a).max(), 1.0), k
    auto = Model(Grid3D(48, 48, 48, -1.5, 1.5, -1.5, 1.5, -1.5, 1.5), solids, Boundary(**walls))
    assert auto.band_capacity is not None  # 2 x 27 + 8 of 216 tiles
    case = get_case("sphere_relax", 32)  # its band lists all 64 tiles: full grid
    assert case.build()[0].band_capacity is None


@pytest.mark.parametrize(
    "shape, tile, periodic",
    [((16, 12), (4, 4), (True, False)), ((12, 8, 9), (4, 4, 3), (True, False, True))],
)
@pytest.mark.parametrize("cap_last", [False, True])
def test_neighbours_read_the_grid_in_both_layouts(shape, tile, periodic, cap_last):
    """The tile neighbours (inside a tile by shifting, across a face from the listed
    neighbour tile or from the fixed faces) are the field's own grid neighbours, in the
    tile-major layout and in the sweeps' slot-innermost one: every node of every listed
    tile, against the same tiles gathered from the grid with one ghost row."""
    rng = np.random.default_rng(3)
    nd = len(shape)
    mask = rng.random(shape) < 0.04
    cap = int(narrowband.tile_flags(jnp.asarray(mask), tile).sum()) + 2
    t = narrowband.build(jnp.asarray(mask), cap, tile, periodic)
    a = jnp.asarray(rng.standard_normal((2,) + shape))
    ghosted = narrowband.gather(a, t, tile, periodic, 0.0, halo=1)  # (2, cap, t + 2, ...)
    inner = narrowband.interior(ghosted, 1, nd)
    fixed = narrowband.halos(ghosted, nd)
    expect = narrowband.stencil_neighbours(ghosted, nd)
    if cap_last:
        inner = narrowband.cap_last(inner, nd)
        fixed = tuple(narrowband.cap_last(f, nd - 1) for f in fixed)
        expect = tuple(narrowband.cap_last(e, nd) for e in expect)
    got = narrowband.Neighbours(t, cap_last=cap_last)(inner, fixed)
    slots = int(t.count)
    for g, e in zip(got, expect, strict=True):
        g, e = np.asarray(g), np.asarray(e)
        if cap_last:
            g, e = g[..., :slots], e[..., :slots]
        else:
            g, e = g[:, :slots], e[:, :slots]
        np.testing.assert_array_equal(g, e)
    back = narrowband.cap_first(narrowband.cap_last(ghosted, nd), nd)
    np.testing.assert_array_equal(np.asarray(back), np.asarray(ghosted))


def _switch_branches(n):
    """Three branches whose reverse mode needs intermediates of three different shapes."""
    return [
        lambda x: jnp.sin(jnp.outer(x, x)).sum(axis=0),
        lambda x: jnp.cos(jnp.outer(x, x[: n // 2])).sum(axis=1),
        lambda x: jnp.tanh(jnp.outer(x[: n // 4], x)).sum(axis=0),
    ]


@pytest.mark.parametrize("nbranch", [2, 3])
def test_switch_equals_lax_switch_in_value_and_gradient(nbranch):
    n = 16
    x = jnp.linspace(-1.0, 1.0, n)
    branches = _switch_branches(n)[:nbranch]
    for i in range(nbranch):
        def ours(x, i=i):
            return jnp.sum(narrowband.switch(jnp.asarray(i), branches, x) ** 2)

        def plain(x, i=i):
            return jnp.sum(lax.switch(jnp.asarray(i), branches, x) ** 2)

        assert float(ours(x)) == float(plain(x))
        np.testing.assert_allclose(jax.grad(ours)(x), jax.grad(plain)(x), rtol=1e-14, atol=1e-14)


def test_switch_keeps_only_the_operands_for_the_backward_pass():
    """lax.switch keeps every branch's residuals in reverse mode (JAX joins them; only
    equal shapes share a slot); narrowband.switch keeps the operands: here n values against
    more than three n x n intermediates' worth."""
    n = 64
    x = jnp.linspace(-1.0, 1.0, n)
    branches = _switch_branches(n)

    def kept(switch):
        _, vjp = jax.vjp(lambda x: switch(jnp.asarray(1), branches, x), x)
        return sum(leaf.size for leaf in jax.tree_util.tree_leaves(vjp) if hasattr(leaf, "size"))

    plain, ours = kept(lax.switch), kept(narrowband.switch)
    assert plain > n * n  # the three branches' outer products, or their derivatives
    assert ours <= 4 * n  # the operand (and the index), nothing of n^2 size
