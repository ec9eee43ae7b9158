"""Tests for refmap.extrapolation: affine-exact band extrapolation and smoothing."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import refmap  # noqa: F401  (enables float64 before any array is made)
from refmap.extrapolation import (
    default_sweeps,
    extrapolate_linear,
    smooth_extrapolated,
    solid_gradient,
)
from refmap.grid import Grid

G64 = Grid(64, 64)
H64 = G64.h
BAND = 6 * H64

extrapolate_jit = jax.jit(
    extrapolate_linear, static_argnames=("dx", "dy", "band", "iters", "periodic")
)
smooth_jit = jax.jit(
    smooth_extrapolated,
    static_argnames=("max_sweeps", "periodic", "fixed_sweeps", "return_sweeps", "check_every"),
)


def capsule(x, y, half_length, radius, along_x):
    """Signed distance to a capsule centred at 0 along x (or y)."""
    if along_x:
        return np.hypot(np.maximum(np.abs(x) - half_length, 0.0), y) - radius
    return np.hypot(x, np.maximum(np.abs(y) - half_length, 0.0)) - radius


def shapes(grid):
    X, Y = grid.mesh()
    return {
        "disc": np.hypot(X - 0.1, Y + 0.05) - 0.8,
        "ellipse": np.hypot(X / 1.2, Y / 0.7) - 1.0,  # negative inside, not a distance
        "rotor": np.minimum(
            capsule(X, Y, 1.1, 0.4, True), capsule(X, Y, 1.1, 0.4, False)
        ),  # four arms with concave corners
    }


SHAPES = shapes(G64)


def rotation_map(X, Y, angle, c, X0=(0.0, 0.0)):
    """xi = R^T (x - c) + X0."""
    ca, sa = np.cos(angle), np.sin(angle)
    dxs, dys = X - c[0], Y - c[1]
    return np.stack([ca * dxs + sa * dys + X0[0], -sa * dxs + ca * dys + X0[1]])


def band_mask(phi, band=BAND):
    return (phi >= 0) & (phi <= band)


def check_extension(out, exact, f_in, phi, band=BAND, tol=1e-10):
    out = np.asarray(out)
    m = np.broadcast_to(band_mask(phi, band), out.shape)
    assert np.all(np.isfinite(out[m]))
    assert np.abs(out - exact)[m].max() < tol
    # solid values and values beyond the band are untouched (bitwise, NaN included)
    keep = np.broadcast_to((phi < 0) | (phi > band), out.shape)
    np.testing.assert_array_equal(out[keep], np.asarray(f_in)[keep])


@pytest.mark.parametrize("name", list(SHAPES))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_affine_is_reproduced_exactly(name, seed):
    X, Y = G64.mesh()
    phi = SHAPES[name]
    a, b, c = np.random.default_rng(seed).normal(size=3) * [1.0, 1.0, 3.0]
    f = a * X + b * Y + c
    f_in = np.where(phi < 0, f, np.nan)  # only solid values may be used
    out = extrapolate_jit(f_in, phi, G64.dx, G64.dy, BAND)
    check_extension(out, f, f_in, phi)


@pytest.mark.parametrize("name", list(SHAPES))
def test_rotation_map_is_reproduced_exactly(name):
    X, Y = G64.mesh()
    phi = SHAPES[name]
    xi = rotation_map(X, Y, 0.7, (0.3, -0.2), (1.0, -2.0))
    xi_in = np.where(phi < 0, xi, 0.0)
    out = extrapolate_jit(xi_in, phi, G64.dx, G64.dy, BAND)  # (2, nx, ny) batch
    check_extension(out, xi, xi_in, phi)


@pytest.mark.parametrize(
    "grid, centre",
    [
        (Grid(64, 48, -2.0, 2.0, -1.5, 1.5), (1.9, 0.0)),  # solid cut by the right edge
        (Grid(64, 48, -2.0, 2.0, -1.5, 1.5), (-2.1, -1.6)),  # a corner
        (Grid(64, 40), (0.1, 0.0)),  # dx != dy
    ],
)
def test_affine_at_domain_edges_and_anisotropic_grid(grid, centre):
    X, Y = grid.mesh()
    phi = np.hypot((X - centre[0]) / 1.1, Y - centre[1]) - 0.6
    f = 0.3 * X - 2.0 * Y + 1.0
    f_in = np.where(phi < 0, f, np.nan)
    band = 6 * grid.h
    out = extrapolate_jit(f_in, phi, grid.dx, grid.dy, band)
    check_extension(out, f, f_in, phi, band=band)
    smoothed = smooth_jit(out, phi, grid.dx, grid.dy, band)
    np.testing.assert_array_equal(np.asarray(smoothed), np.asarray(out))


@settings(max_examples=25, deadline=None)
@given(
    coef=st.lists(st.floats(-5, 5), min_size=6, max_size=6),
    shape=st.sampled_from(list(SHAPES)),
)
def test_affine_maps_hypothesis(coef, shape):
    """Any uniform strain (affine map, both components at once) is reproduced exactly."""
    X, Y = G64.mesh()
    phi = SHAPES[shape]
    a, b, c, d, e, f0 = coef
    xi = np.stack([a * X + b * Y + c, d * X + e * Y + f0])
    xi_in = np.where(phi < 0, xi, np.nan)
    out = extrapolate_jit(xi_in, phi, G64.dx, G64.dy, BAND)
    scale = 1 + np.abs(coef).max()
    check_extension(out, xi, xi_in, phi, tol=1e-11 * scale)


def test_corner_gradient_of_rotation_is_exact():
    """Bottom-left-triangle grad xi at corners = R^T wherever its 4 nodes are in the band."""
    X, Y = G64.mesh()
    phi = np.hypot(X, Y) - 0.8
    angle = 0.45
    xi = rotation_map(X, Y, angle, (0.05, -0.1))
    out = np.asarray(extrapolate_jit(np.where(phi < 0, xi, 0.0), phi, G64.dx, G64.dy, BAND))
    ok = phi <= BAND  # solid or extrapolated
    # corner (i, j), 1 <= i, j <= n-1, surrounded by nodes (i-1|i, j-1|j)
    bl, br, tl = out[:, :-1, :-1], out[:, 1:, :-1], out[:, :-1, 1:]
    four = ok[:-1, :-1] & ok[1:, :-1] & ok[:-1, 1:] & ok[1:, 1:]
    d_dx = (br - bl) / G64.dx
    d_dy = (tl - bl) / G64.dy
    RT = np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]])
    outside_any = four & ~((phi[:-1, :-1] < 0) & (phi[1:, :-1] < 0) & (phi[:-1, 1:] < 0))
    assert outside_any.sum() > 500  # the band corners are really tested
    for comp in range(2):
        assert np.abs(d_dx[comp] - RT[comp, 0])[four].max() < 1e-10
        assert np.abs(d_dy[comp] - RT[comp, 1])[four].max() < 1e-10


@pytest.mark.parametrize("name", ["disc", "ellipse"])
def test_smooth_field_second_order(name):
    errs = []
    for n in (32, 64, 128):
        g = Grid(n, n)
        X, Y = g.mesh()
        phi = shapes(g)[name]
        f = np.sin(2 * X + 1) * np.cos(1.5 * Y)
        out = np.asarray(extrapolate_jit(np.where(phi < 0, f, 0.0), phi, g.dx, g.dy, 6 * g.h))
        near = (phi >= 0) & (phi <= 3 * g.h)  # a fixed number of cells out
        errs.append(np.abs(out - f)[near].max())
    ratios = np.array(errs[:-1]) / np.array(errs[1:])
    assert np.all(ratios > 2.5), (errs, ratios)


def test_solid_gradient_one_sided_and_valid():
    g = Grid(16, 12, 0.0, 1.6, 0.0, 1.2)
    X, Y = g.mesh()
    phi = np.abs(Y - 0.6) - 0.1  # stripe two nodes thick
    f = 2.0 * X - 3.0 * Y + 1
    gx, gy, valid = solid_gradient(f, phi, g.dx, g.dy)
    solid = phi < 0
    assert valid.shape == phi.shape
    np.testing.assert_array_equal(np.asarray(valid), solid)
    np.testing.assert_allclose(np.asarray(gx)[solid], 2.0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(gy)[solid], -3.0, atol=1e-12)
    # a one-node-thick sliver has no y gradient: nothing can be extrapolated from it
    thin = np.abs(Y - 0.65) - 0.04
    assert not np.asarray(solid_gradient(f, thin, g.dx, g.dy)[2]).any()
    out = np.asarray(extrapolate_linear(np.where(thin < 0, f, -7.0), thin, g.dx, g.dy, 0.3))
    np.testing.assert_array_equal(out, np.where(thin < 0, f, -7.0))


def test_default_sweeps_and_partial_sweeps():
    assert default_sweeps(6 * 0.1, 0.1, 0.1) == 12
    assert default_sweeps(4.0, 1.0, 2.0) == 9
    X, Y = G64.mesh()
    phi = SHAPES["disc"]
    f = 0.5 * X - Y
    f_in = np.where(phi < 0, f, -99.0)
    out = np.asarray(extrapolate_linear(f_in, phi, G64.dx, G64.dy, BAND, iters=2))
    m = band_mask(phi)
    reached = m & (out != -99.0)
    assert reached.any() and (m & ~reached).any()  # two sweeps reach two layers only
    assert np.abs(out - f)[reached].max() < 1e-12  # what is reached is exact
    assert phi[reached].max() < 2.5 * H64


def test_periodic_wrap_across_edge():
    g = Grid(64, 48, -2.0, 2.0, -1.5, 1.5)
    X, Y = g.mesh()
    cx, cy, R = 1.8, 0.2, 0.6
    dxs = (X - cx + 2.0) % 4.0 - 2.0  # x - cx unwrapped to the nearest image
    phi = np.hypot(dxs, Y - cy) - R
    f = 0.7 * dxs - 1.3 * (Y - cy) + 0.4  # affine in the unwrapped coordinate
    f_in = np.where(phi < 0, f, np.nan)
    band = 6 * g.h
    out = extrapolate_jit(f_in, phi, g.dx, g.dy, band, periodic=(True, False))
    check_extension(out, f, f_in, phi, band=band)
    # the wrapped band really is used: some band nodes sit on the left edge
    assert band_mask(phi, band)[0].any() and band_mask(phi, band)[-1].any()


def test_batch_vmap_and_jit_agree():
    X, Y = G64.mesh()
    phi = SHAPES["rotor"]
    rng = np.random.default_rng(5)
    xi = rotation_map(X, Y, 0.3, (0.0, 0.1)) + 0.05 * np.sin(3 * X + rng.normal()) * np.cos(Y)
    xi_in = jnp.asarray(np.where(phi < 0, xi, 0.0))
    native = extrapolate_jit(xi_in, phi, G64.dx, G64.dy, BAND)
    vm = jax.vmap(lambda f: extrapolate_linear(f, phi, G64.dx, G64.dy, BAND))(xi_in)
    single = [extrapolate_jit(xi_in[k], phi, G64.dx, G64.dy, BAND) for k in range(2)]
    np.testing.assert_allclose(native, vm, rtol=0, atol=1e-14)
    np.testing.assert_allclose(native, np.stack(single), rtol=0, atol=1e-14)
    # one level set per solid, stacked on the leading axis
    phis = np.stack([phi, SHAPES["disc"]])
    two = extrapolate_jit(xi_in, phis, G64.dx, G64.dy, BAND)
    np.testing.assert_allclose(
        two[1], extrapolate_jit(xi_in[1], phis[1], G64.dx, G64.dy, BAND), atol=1e-14
    )

    e = native
    s_native = smooth_jit(e, phi, G64.dx, G64.dy, BAND)
    s_vm = jax.vmap(lambda f: smooth_extrapolated(f, phi, G64.dx, G64.dy, BAND))(e)
    np.testing.assert_allclose(s_native, s_vm, rtol=0, atol=1e-14)


def test_smoothing_keeps_affine_and_solid():
    X, Y = G64.mesh()
    phi = SHAPES["rotor"]
    xi = rotation_map(X, Y, -0.4, (0.2, 0.0))
    e = extrapolate_jit(np.where(phi < 0, xi, 0.0), phi, G64.dx, G64.dy, BAND)
    out, sweeps = smooth_jit(e, phi, G64.dx, G64.dy, BAND, return_sweeps=True)
    np.testing.assert_array_equal(np.asarray(sweeps), 0)  # criterion met at once
    np.testing.assert_allclose(out, xi * (phi <= BAND) + np.asarray(e) * (phi > BAND), atol=1e-10)
    fixed = smooth_jit(e, phi, G64.dx, G64.dy, BAND, fixed_sweeps=50)
    assert np.abs(np.asarray(fixed) - np.asarray(e)).max() < 1e-12  # a fixed point


def striated(grid, phi, f, m_modes, amp):
    """``f`` plus a tangential (angular) oscillation on the extrapolated nodes only."""
    X, Y = grid.mesh()
    theta = np.arctan2(Y, X)
    return np.where(band_mask(phi), f + amp * np.cos(m_modes * theta), f)


@pytest.mark.parametrize("m_modes", [24, 40])
def test_smoothing_removes_striations(m_modes):
    X, Y = G64.mesh()
    phi = np.hypot(X, Y) - 0.8
    f = 0.3 * X - 1.2 * Y + 0.5
    f_in = striated(G64, phi, f, m_modes, 0.05)
    out, sweeps = smooth_jit(f_in, phi, G64.dx, G64.dy, BAND, return_sweeps=True)
    out = np.asarray(out)
    assert int(sweeps) == 80  # the perturbation keeps the band far above the interior
    # solid values and values beyond the band never change
    keep = (phi < 0) | (phi > BAND)
    np.testing.assert_array_equal(out[keep], f_in[keep])
    err_in = np.abs(f_in - f)
    err_out = np.abs(out - f)
    blur = (phi >= 0) & (phi <= 2 * H64)  # where the blend weights use the band values
    assert err_out[blur].max() < 0.1 * err_in[blur].max()
    inner = band_mask(phi, BAND - 1.5 * H64)
    assert np.sqrt(np.mean(err_out[inner] ** 2)) < 0.3 * np.sqrt(np.mean(err_in[inner] ** 2))


def test_smoothing_stops_on_criterion():
    """Sweeping stops once the band's curvature is comparable to the interior's."""
    X, Y = G64.mesh()
    phi = np.hypot(X, Y) - 0.8
    f = np.sin(2 * X) * np.cos(2 * Y)  # interior |f_xx|, |f_yy| up to ~4
    e = extrapolate_jit(np.where(phi < 0, f, 0.0), phi, G64.dx, G64.dy, BAND)
    f_in = striated(G64, phi, np.asarray(e), 30, 0.01)
    # A first-order extrapolation of a curved field already has band second differences
    # comparable to the interior's, so the thesis's ratio 0.25 runs to the cap.
    _, sweeps = smooth_jit(f_in, phi, G64.dx, G64.dy, BAND, return_sweeps=True)
    assert int(sweeps) == 80
    out, sweeps = smooth_jit(f_in, phi, G64.dx, G64.dy, BAND, ratio=1.5, return_sweeps=True)
    k = int(sweeps)
    assert 0 < k < 80
    # the while loop did exactly k plain sweeps
    fixed = smooth_jit(f_in, phi, G64.dx, G64.dy, BAND, fixed_sweeps=k)
    np.testing.assert_allclose(out, fixed, rtol=0, atol=1e-14)
    # a looser ratio stops no later; max_sweeps caps the loop
    _, loose = smooth_jit(f_in, phi, G64.dx, G64.dy, BAND, ratio=2.0, return_sweeps=True)
    assert int(loose) <= k
    _, capped = smooth_jit(
        f_in, phi, G64.dx, G64.dy, BAND, ratio=1.5, max_sweeps=3, return_sweeps=True
    )
    assert int(capped) == 3


def test_smoothing_batch_counts_each_component():
    X, Y = G64.mesh()
    phi = np.hypot(X, Y) - 0.8
    f = 0.3 * X - 1.2 * Y
    both = np.stack([f, striated(G64, phi, f, 24, 0.05)])
    out, sweeps = smooth_jit(both, phi, G64.dx, G64.dy, BAND, return_sweeps=True)
    np.testing.assert_array_equal(np.asarray(sweeps), [0, 80])
    np.testing.assert_array_equal(np.asarray(out[0]), f)


def _criterion_case():
    """A curved field whose smoothing stops part-way at ratio 1.5 (see above)."""
    X, Y = G64.mesh()
    phi = np.hypot(X, Y) - 0.8
    f = np.sin(2 * X) * np.cos(2 * Y)
    e = extrapolate_jit(np.where(phi < 0, f, 0.0), phi, G64.dx, G64.dy, BAND)
    return striated(G64, phi, np.asarray(e), 30, 0.01), phi


@pytest.mark.parametrize("m", [3, 4, 5, 8])
def test_smoothing_tested_every_m_sweeps(m):
    """Testing the rule every m sweeps stops at the first test at or after the sweep where
    testing every sweep stops, and the result is that many plain sweeps."""
    f_in, phi = _criterion_case()
    _, k1 = smooth_jit(f_in, phi, G64.dx, G64.dy, BAND, ratio=1.5, return_sweeps=True)
    k1 = int(k1)
    assert 0 < k1 < 80 and k1 % m  # the block structure is exercised
    out, km = smooth_jit(
        f_in, phi, G64.dx, G64.dy, BAND, ratio=1.5, return_sweeps=True, check_every=m
    )
    km = int(km)
    # the tests before sweeps 0, m, ... below k1 see the same fields as before and fail;
    # the next one sees a field smoothed further, which the rule passes here
    assert km == -(-k1 // m) * m
    fixed = smooth_jit(f_in, phi, G64.dx, G64.dy, BAND, fixed_sweeps=km)
    np.testing.assert_array_equal(np.asarray(out), np.asarray(fixed))


@pytest.mark.parametrize("max_sweeps", [80, 7])
def test_smoothing_tested_every_m_sweeps_to_the_cap_is_unchanged(max_sweeps):
    """Run to max_sweeps (also one that m does not divide), the result is bit for bit the
    rule tested before every sweep; an affine field still stops at once; batch elements
    keep their own counts."""
    X, Y = G64.mesh()
    phi = np.hypot(X, Y) - 0.8
    f = 0.3 * X - 1.2 * Y
    both = np.stack([f, striated(G64, phi, f, 24, 0.05)])
    ref, k_ref = smooth_jit(both, phi, G64.dx, G64.dy, BAND, max_sweeps=max_sweeps, return_sweeps=True)
    out, k4 = smooth_jit(
        both, phi, G64.dx, G64.dy, BAND, max_sweeps=max_sweeps, return_sweeps=True, check_every=4
    )
    np.testing.assert_array_equal(np.asarray(k4), [0, max_sweeps])
    np.testing.assert_array_equal(np.asarray(k4), np.asarray(k_ref))
    np.testing.assert_array_equal(np.asarray(out), np.asarray(ref))


def test_smoothing_check_every_must_be_positive():
    f_in, phi = _criterion_case()
    with pytest.raises(ValueError, match="check_every must be an integer >= 1, got 0"):
        smooth_extrapolated(f_in, phi, G64.dx, G64.dy, BAND, check_every=0)


def test_reverse_mode_gradient():
    X, Y = G64.mesh()
    phi = jnp.asarray(SHAPES["disc"])
    f = jnp.asarray(np.sin(X) * np.cos(Y))

    def loss(f):
        e = extrapolate_linear(f, phi, G64.dx, G64.dy, BAND)
        s = smooth_extrapolated(e, phi, G64.dx, G64.dy, BAND, fixed_sweeps=5)
        return jnp.sum(s**2 * ((phi >= 0) & (phi <= BAND)))

    grad = jax.jit(jax.grad(loss))(f)
    grad = np.asarray(grad)
    assert np.all(np.isfinite(grad))
    assert np.abs(grad[np.asarray(phi) >= 0]).max() == 0  # band inputs are not used
    direction = jnp.asarray(np.cos(2 * X + Y)) * (phi < 0)
    eps = 1e-6
    fd = (loss(f + eps * direction) - loss(f - eps * direction)) / (2 * eps)
    np.testing.assert_allclose(float(jnp.vdot(grad, direction)), float(fd), rtol=1e-6)
