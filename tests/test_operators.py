"""Stencil identities of refmap.operators against naive references."""

import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap.operators import (
    advect,
    advect_lowmem,
    corner_average,
    div_node,
    divergence_centered,
    grad_corner,
    laplacian,
    laplacian_lowmem,
    node_average,
)

rng = np.random.default_rng(0)


def test_grad_is_minus_transpose_of_div():
    """<G f, s> = -<f, D s> exactly for zero ghost values (thesis section 3.8)."""
    nx, ny, dx, dy = 9, 7, 0.3, 0.2
    f = rng.standard_normal((nx, ny))
    fp = np.pad(f, 1)  # zero ghosts
    sxx, sxy, syy = (rng.standard_normal((nx + 1, ny + 1)) for _ in range(3))
    fx, fy = grad_corner(fp, dx, dy)
    lhs = np.sum(fx * sxx + fy * sxy) + np.sum(fx * sxy + fy * syy) * 0  # x-row of tensor
    d = np.asarray(div_node(sxx, sxy, syy, dx, dy))
    # x component: D_x pairs with (fx, fy) contracted with the first row (sxx, sxy)
    assert np.allclose(np.sum(fx * sxx + fy * sxy), -np.sum(f * d[0]), rtol=1e-12, atol=1e-12)
    assert np.allclose(np.sum(fx * sxy + fy * syy), -np.sum(f * d[1]), rtol=1e-12, atol=1e-12)
    del lhs


def test_grad_corner_matches_naive_loop():
    nx, ny, dx, dy = 6, 5, 0.5, 0.25
    fp = rng.standard_normal((nx + 2, ny + 2))
    fx, fy = (np.asarray(a) for a in grad_corner(fp, dx, dy))
    for i in range(nx + 1):
        for j in range(ny + 1):
            bl, br, tl = fp[i, j], fp[i + 1, j], fp[i, j + 1]
            assert fx[i, j] == pytest.approx((br - bl) / dx)
            assert fy[i, j] == pytest.approx((tl - bl) / dy)


def test_div_node_matches_naive_loop():
    nx, ny, dx, dy = 5, 4, 0.5, 0.25
    sxx, sxy, syy = (rng.standard_normal((nx + 1, ny + 1)) for _ in range(3))
    d = np.asarray(div_node(sxx, sxy, syy, dx, dy))
    for i in range(nx):
        for j in range(ny):
            tr, tl, br = (i + 1, j + 1), (i, j + 1), (i + 1, j)
            assert d[0, i, j] == pytest.approx((sxx[tr] - sxx[tl]) / dx + (sxy[tr] - sxy[br]) / dy)
            assert d[1, i, j] == pytest.approx((sxy[tr] - sxy[tl]) / dx + (syy[tr] - syy[br]) / dy)


def test_gradient_exact_on_affine():
    nx, ny, dx, dy = 8, 6, 0.1, 0.3
    x = (np.arange(-1, nx + 1) + 0.5) * dx
    y = (np.arange(-1, ny + 1) + 0.5) * dy
    X, Y = np.meshgrid(x, y, indexing="ij")
    fx, fy = grad_corner(2.5 * X - 1.5 * Y + 3, dx, dy)
    assert np.allclose(fx, 2.5, atol=1e-12) and np.allclose(fy, -1.5, atol=1e-12)


def test_no_checkerboard_null_mode():
    """The checkerboard has a non-zero triangle gradient (it is not a zero-energy mode),
    while the centred 4-point corner average of differences would miss it."""
    nx = ny = 8
    i, j = np.meshgrid(np.arange(nx + 2), np.arange(ny + 2), indexing="ij")
    cb = (-1.0) ** (i + j)
    fx, fy = grad_corner(cb, 1.0, 1.0)
    assert np.min(np.abs(fx)) == 2.0 and np.min(np.abs(fy)) == 2.0
    centred_x = 0.5 * ((cb[1:, :-1] - cb[:-1, :-1]) + (cb[1:, 1:] - cb[:-1, 1:]))
    assert np.allclose(centred_x, 0.0)


def test_averages():
    fp = rng.standard_normal((6, 5))
    c = np.asarray(corner_average(fp))
    assert c.shape == (5, 4)
    assert c[2, 1] == pytest.approx(fp[2:4, 1:3].mean())
    n = np.asarray(node_average(fp))
    assert n[1, 1] == pytest.approx(fp[1:3, 1:3].mean())


def _padded_mesh(nx, ny, dx, dy, g):
    x = (np.arange(-g, nx + g) + 0.5) * dx
    y = (np.arange(-g, ny + g) + 0.5) * dy
    return np.meshgrid(x, y, indexing="ij")


def test_eno_advection_exact_on_quadratics():
    """Second-order ENO differences are exact on quadratics, whichever stencil is picked."""
    nx, ny, dx, dy = 10, 9, 0.1, 0.15
    X, Y = _padded_mesh(nx, ny, dx, dy, 2)
    f = 0.7 * X**2 - 0.3 * X * Y + 2 * Y**2 + X
    vel = rng.standard_normal((2, nx, ny))
    Xi, Yi = X[2:-2, 2:-2], Y[2:-2, 2:-2]
    exact = -(vel[0] * (1.4 * Xi - 0.3 * Yi + 1) + vel[1] * (-0.3 * Xi + 4 * Yi))
    assert np.allclose(advect(f, vel, dx, dy), exact, atol=1e-10)


def test_laplacian_and_divergence_on_polynomials():
    nx, ny, dx, dy = 7, 8, 0.2, 0.1
    X, Y = _padded_mesh(nx, ny, dx, dy, 1)
    assert np.allclose(laplacian(X**2 + 3 * Y**2, dx, dy, g=1), 8.0, atol=1e-9)
    assert np.allclose(divergence_centered(X**2, X * Y, dx, dy, g=1), 3 * X[1:-1, 1:-1], atol=1e-10)


@pytest.mark.parametrize(
    "fshape, vshape, h",
    [
        ((2, 14, 16), (2, 10, 12), (0.3, 0.2)),  # a velocity field
        ((1, 2, 14, 16), (2, 10, 12), (0.3, 0.2)),  # maps (S, d, ...)
        ((2, 3, 2, 12, 12), (2, 2, 3, 1, 8, 8), (0.3, 0.3)),  # tile windows
        ((12, 14), (2, 3, 8, 10), (0.3, 0.2)),  # velocity broadcast over more axes
        ((2, 10, 12, 9), (3, 6, 8, 5), (0.3, 0.2, 0.25)),  # 3D
    ],
)
def test_lowmem_transposes_match_autodiff(fshape, vshape, h):
    """advect_lowmem and laplacian_lowmem: the same values as advect and laplacian, and
    their hand-written reverse modes equal JAX's own to round-off."""
    import jax

    fp = rng.standard_normal(fshape)
    fp[..., 3, :] = fp[..., 4, :]  # some ties of the ENO indicators
    vel = rng.standard_normal(vshape)
    out = advect(fp, vel, *h)
    assert np.array_equal(np.asarray(out), np.asarray(advect_lowmem(fp, vel, *h)))
    ct = rng.standard_normal(out.shape)
    want = jax.vjp(lambda f, v: advect(f, v, *h), fp, vel)[1](ct)
    got = jax.vjp(lambda f, v: advect_lowmem(f, v, *h), fp, vel)[1](ct)
    for w, g in zip(want, got, strict=True):
        assert w.shape == g.shape
        np.testing.assert_allclose(g, w, rtol=0, atol=1e-13 * np.max(np.abs(w)))
    if len(fshape) == len(vshape):  # one field per velocity: the Laplacian too
        lap = laplacian(fp, *h, g=2)
        assert np.array_equal(np.asarray(lap), np.asarray(laplacian_lowmem(fp, *h, g=2)))
        ct = rng.standard_normal(lap.shape)
        w = jax.vjp(lambda f: laplacian(f, *h, g=2), fp)[1](ct)[0]
        g = jax.vjp(lambda f: laplacian_lowmem(f, *h, g=2), fp)[1](ct)[0]
        np.testing.assert_allclose(g, w, rtol=0, atol=1e-13 * np.max(np.abs(w)))
