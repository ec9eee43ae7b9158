"""Each solid's stress, weights and density on its tiles (refmap.solid_tiles, issue 14):
the mixed fields equal the full-grid computation's."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.special import erf

import refmap  # noqa: F401  (float64)
from refmap import blend, solid_tiles
from refmap.boundary import Boundary
from refmap.case import Case
from refmap.geometry import Disc, Rectangle
from refmap.grid import Grid
from refmap.materials import NeoHookean
from refmap.model import Solid
from refmap.scenarios import get_case
from refmap.scenarios_fssi import suspension as _suspension


def suspension(n, count):
    """The ``suspension`` discs on the whole grid (``solid_storage = "grid"``; the scenario
    stores them in windows by default): the layout whose tiles these tests check."""
    case = _suspension(n, count)
    return case.replace(numerics=dataclasses.replace(case.numerics, solid_storage="grid"))

MIXED = ("sxx", "sxy", "syy", "rho", "wf_c", "wf_n")


def test_fraction_is_exactly_zero_beyond_the_cutoff():
    """The tiles leave out every corner and node at or beyond ``cutoff``: the solid's
    fraction 1 - H must be exactly 0 there, for both kernels (erf rounds to 1 in float64
    from x = 5.9216 on, below the 6 w used)."""
    x = jnp.linspace(5.9216, 40.0, 20001)
    assert bool(jnp.all(erf(x) == 1.0))
    assert float(erf(jnp.asarray(5.92))) < 1.0  # the margin is real: just below, it is not 1
    for kernel in blend.KERNELS:
        w = 0.07
        cut = solid_tiles.cutoff(kernel, w)
        phi = cut * jnp.linspace(1.0, 3.0, 1001)
        assert bool(jnp.all(1.0 - blend.heaviside(phi, kernel, w) == 0.0)), kernel
        # and not zero well inside: the cutoff is not too generous to matter
        assert float(1.0 - blend.heaviside(jnp.asarray(0.8 * cut), kernel, w)) > 0.0


def _compare(case, steps=0, tol=0.0, want_tiles=True):
    """Mixed fields of ``derived`` (and, with ``steps``, the state after them) with
    band_sweeps = "grid" (full grid) and "band" (tiles); returns the models."""
    out, models = {}, {}
    for mode in ("grid", "band"):
        c = case.replace(numerics=dataclasses.replace(case.numerics, band_sweeps=mode))
        model, params = c.build()
        models[mode] = model
        s = model.initial_state(params)
        if steps:
            s = jax.jit(lambda s, model=model, params=params: model.run_steps(s, params, steps))(s)
        d = jax.jit(model.derived)(s, params)
        out[mode] = (s, d)
    assert models["grid"].solid_tiles is None
    assert (models["band"].solid_tiles is not None) == want_tiles
    # both from the grid run's state: the derived fields alone
    s_g = out["grid"][0]
    _, params = case.build()
    d_b = jax.jit(models["band"].derived)(s_g, params)
    for k in MIXED:
        a, b = np.asarray(out["grid"][1][k]), np.asarray(d_b[k])
        scale = max(np.abs(a).max(), 1.0)
        assert np.abs(a - b).max() <= tol * scale, (k, np.abs(a - b).max() / scale)
    if steps:
        for k in ("v", "rho_f", "xi", "phi"):
            a, b = np.asarray(getattr(out["grid"][0], k)), np.asarray(getattr(out["band"][0], k))
            assert np.abs(a - b).max() <= 1e-12 * max(np.abs(a).max(), 1.0), k
    return models


def test_suspension_mixed_fields_bitwise_at_start():
    """16 discs in a closed box at 128^2: at most two fractions overlap anywhere, so the
    tile sums are the full-grid arithmetic operation for operation: bitwise equal."""
    _compare(suspension(128, 16), tol=0.0)


def test_suspension_runs_agree():
    """4 discs at 64^2 after 5 steps: the mixed fields differ by a few ulp (XLA fuses the
    two layouts' arithmetic differently), the states by round-off."""
    _compare(suspension(64, 4), steps=5, tol=1e-14)


def test_overlapping_fractions_to_round_off():
    """Two discs overlapping by a cell: their fractions sum past 1 (the renormalisation
    1 / max(T, 1) then scales them), equal to round-off."""
    law = NeoHookean(G=10.0, kappa=10.0)
    g = Grid(64, 64)
    r = 0.6
    gap = -1.0 * g.h
    solids = tuple(Solid(shape=Disc(center=(sx * (r + gap / 2), 0.1), radius=r), law=law) for sx in (-1, 1))
    case = Case(name="overlap", grid=g, solids=solids)
    models = _compare(case, tol=1e-14)
    model, params = case.build()
    d = jax.jit(model.derived)(model.initial_state(params), params)
    assert float(jnp.max(jnp.sum(1.0 - d["Hc"], axis=0))) > 1.0  # the case does overlap
    assert models["band"].solid_tiles is not None


def _periodic_case(n=48, blend_kernel="erf"):
    P = "periodic"
    law = NeoHookean(G=10.0, kappa=10.0)
    solids = (
        Solid(shape=Disc(center=(1.8, 1.75), radius=0.35), law=law),  # across the corner of [-2, 2]^2
        Solid(shape=Rectangle(center=(0.0, -0.2), half_size=(0.4, 0.15)), law=NeoHookean(G=5.0, kappa=20.0, rho0=2.0)),
    )
    case = Case(name="periodic", grid=Grid(n, n), solids=solids,
                boundary=Boundary(left=P, right=P, bottom=P, top=P))
    return case.replace(numerics=dataclasses.replace(case.numerics, blend=blend_kernel))


@pytest.mark.parametrize("kernel", ["erf", "sine"])
def test_periodic_edges_and_corner(kernel):
    """A disc straddling the corner of a doubly periodic box (its tiles read the wrapped
    padding) and a plate of another material; both blend kernels."""
    _compare(_periodic_case(blend_kernel=kernel), steps=2 if kernel == "erf" else 0, tol=1e-14)


def test_capacity_overflow_falls_back_on_the_full_grid():
    """With a capacity too small for the solids' tiles the step takes the full-grid branch
    (and agrees); the tiles are then really bypassed, not silently truncated."""
    case = suspension(96, 9)
    case = case.replace(numerics=dataclasses.replace(case.numerics, band_sweeps="band"))
    model, params = case.build()
    s = model.initial_state(params)
    ref = jax.jit(model.derived)(s, params)
    tile = model.solid_tiles[0]
    model.solid_tiles = (tile, (1,), (1,))
    small = jax.jit(model.derived)(s, params)
    for k in MIXED:  # the full-grid branch of the cond fuses differently: a few ulp
        a, b = np.asarray(ref[k]), np.asarray(small[k])
        assert np.abs(a - b).max() <= 1e-14 * max(np.abs(a).max(), 1.0), k
    # and a truncated list would have been wrong: the listed tiles are more than one
    from refmap.model import Model  # noqa: F401

    flags = solid_tiles.tile_flags(model.bc.pad_linear(s.phi)[model._core(1)],
                                   solid_tiles.cutoff("erf", 2 * model.h), tile)
    assert int(jnp.max(jnp.sum(flags, axis=(1, 2)))) > 1


def test_auto_takes_tiles_only_for_solids_that_cover_little():
    """band_sweeps = "auto": small discs on a large grid are computed on tiles, the rotor
    (its stress region covers most of the grid) on the full grid."""
    model, _ = suspension(128, 16).build()
    assert model.solid_tiles is not None
    model, _ = get_case("rotor", 64).build()
    assert model.solid_tiles is None


def test_3d_spheres_equal_full_grid():
    case = get_case("spheres_settle", 32)
    out = {}
    for mode in ("grid", "band"):
        c = case.replace(numerics=dataclasses.replace(case.numerics, band_sweeps=mode))
        model, params = c.build()
        if mode == "band":
            assert model.solid_tiles is not None
        s = model.initial_state(params)
        out[mode] = jax.jit(model.derived)(s, params)
    for k in ("sxx", "sxy", "sxz", "syy", "syz", "szz", "rho", "wf_c", "wf_n"):
        a, b = np.asarray(out["grid"][k]), np.asarray(out["band"][k])
        assert np.abs(a - b).max() <= 1e-14 * max(np.abs(a).max(), 1.0), k


def test_gradient_through_tiles_equals_full_grid():
    """Reverse mode through the tiles (gather, scatter-add, the capacity switch): the
    gradient of the mixed fields with respect to the maps is the full grid's."""
    case = suspension(48, 4)
    grads = {}
    for mode in ("grid", "band"):
        c = case.replace(numerics=dataclasses.replace(case.numerics, band_sweeps=mode))
        model, params = c.build()
        s = model.initial_state(params)
        X = jnp.asarray(model.grid.mesh("node"))

        def loss(xi, model=model, params=params, s=s):
            d = model.derived(s.replace(xi=xi), params)
            return jnp.sum(d["sxx"] ** 2 + d["sxy"] ** 2) + jnp.sum(d["rho"] ** 2)

        # a strained map (the initial one is stress-free)
        xi = s.xi + 0.02 * jnp.sin(3.0 * X[0]) * jnp.cos(2.0 * X[1])
        grads[mode] = np.asarray(jax.jit(jax.grad(loss))(xi))
    a, b = grads["grid"], grads["band"]
    assert np.abs(a).max() > 0
    assert np.abs(a - b).max() <= 1e-12 * np.abs(a).max()


def _advected_both_ways(model, s, dt, vel=None):
    """Step 1 (map advection) on the model's tiles and on the full grid, from state ``s``."""
    vel = s.v if vel is None else vel

    def adv():  # a new function each time: jit would reuse the first trace of one
        return jax.jit(lambda xi, vel, phi: model._advect_maps(xi, model.bc.pad_affine(xi), vel, phi, dt))

    tiles = model.solid_tiles
    a = adv()(s.xi, vel, s.phi)
    model.solid_tiles = None
    try:
        b = adv()(s.xi, vel, s.phi)
    finally:
        model.solid_tiles = tiles
    return np.asarray(a), np.asarray(b)


def _swirl(model, amp=0.3):
    """A velocity that varies in sign and size over the grid (every ENO branch is taken)."""
    X = jnp.asarray(model.grid.mesh("node"))
    return amp * jnp.stack([jnp.sin(2.1 * X[1] + 0.3) * jnp.cos(1.3 * X[0]),
                            -jnp.cos(1.7 * X[0] - 0.2) * jnp.sin(0.9 * X[1])] + [
                                jnp.sin(X[0] + X[a]) for a in range(2, X.shape[0])])


@pytest.mark.parametrize("which", ["suspension", "periodic_50", "overflow"])
def test_map_advection_on_tiles_is_the_full_grid_s(which):
    """Step 1 on each solid's node tiles gives the full grid's maps bit for bit: the same
    arithmetic per node.  Discs in a closed box; a disc across the corner of a doubly
    periodic box whose 50 nodes a tile of 16 does not divide (the last tile is moved back
    and overlaps its neighbour); and a capacity too small (the full-grid branch)."""
    if which == "periodic_50":
        case = _periodic_case(n=50)
    else:
        case = suspension(96, 9)
    case = case.replace(numerics=dataclasses.replace(case.numerics, band_sweeps="band"))
    model, params = case.build()
    assert model.solid_tiles is not None
    if which == "overflow":
        model.solid_tiles = (model.solid_tiles[0], (1,), (1,))
    s = model.initial_state(params)
    a, b = _advected_both_ways(model, s, 0.01, _swirl(model))
    moved = np.abs(b - np.asarray(s.xi)).max()
    assert moved > 1e-4  # the maps did move
    assert np.array_equal(a, b), np.abs(a - b).max() / moved
    # and nothing moved beyond the advected region (phi < (band - 3) h)
    out = np.asarray(s.phi >= (model.numerics.band - 3.0) * model.h)[:, None] & np.ones_like(a, bool)
    assert np.array_equal(a[out], np.asarray(s.xi)[out])


def test_map_advection_on_tiles_3d():
    case = get_case("spheres_settle", 32)
    case = case.replace(numerics=dataclasses.replace(case.numerics, band_sweeps="band"))
    model, params = case.build()
    assert model.solid_tiles is not None
    s = model.initial_state(params)
    a, b = _advected_both_ways(model, s, 0.01, _swirl(model))
    assert np.abs(b - np.asarray(s.xi)).max() > 1e-4
    assert np.array_equal(a, b)


def test_gradient_through_tile_advection_equals_full_grid():
    """Reverse mode through step 1 on tiles (window gathers, the scatter of overlapping
    windows, the capacity switch) with respect to the velocity and the maps."""
    case = _periodic_case(n=50)
    case = case.replace(numerics=dataclasses.replace(case.numerics, band_sweeps="band"))
    model, params = case.build()
    s = model.initial_state(params)
    vel = _swirl(model)
    tiles = model.solid_tiles
    grads = {}
    for mode in ("tiles", "grid"):
        model.solid_tiles = tiles if mode == "tiles" else None

        def loss(xi, vel, model=model):
            out = model._advect_maps(xi, model.bc.pad_affine(xi), vel, s.phi, 0.01)
            return jnp.sum(jnp.sin(3.0 * out) ** 2)

        grads[mode] = [np.asarray(g) for g in jax.jit(jax.grad(loss, argnums=(0, 1)))(s.xi, vel)]
    model.solid_tiles = tiles
    for a, b in zip(grads["grid"], grads["tiles"], strict=True):
        assert np.abs(a).max() > 0
        assert np.abs(a - b).max() <= 1e-13 * np.abs(a).max()


def test_auto_keeps_small_2d_grids_on_the_full_grid():
    """band_sweeps = "auto" below AUTO_TILE_MIN_NODES_2D nodes (compile time outweighs the
    gain there): no band tiles, no solid tiles, although the bodies cover little; "band"
    still tiles such a grid."""
    from refmap.model import AUTO_TILE_MIN_NODES_2D

    case = suspension(64, 4)
    assert 64 * 64 < AUTO_TILE_MIN_NODES_2D
    model, _ = case.build()
    assert model.band_capacity is None and model.solid_tiles is None
    forced = case.replace(numerics=dataclasses.replace(case.numerics, band_sweeps="band"))
    model, _ = forced.build()
    assert model.band_capacity is not None and model.solid_tiles is not None
    model, _ = suspension(128, 16).build()  # above the floor: tiles
    assert model.band_capacity is not None and model.solid_tiles is not None
