"""refmap.extrapolation in 3D (issue 12), and its 2D results bitwise those of the 2D code.

2D: every output of the dimension-generic :func:`extrapolate_linear`,
:func:`smooth_extrapolated` (while-loop and ``fixed_sweeps``) and :func:`extend` (full
grid and band tiles) is compared with ``np.array_equal`` to the frozen copy of the 2D module
in ``tests/frozen_2d_extrapolation.py``, eagerly and under ``jax.jit``.

3D (``dz=`` given): affine fields are reproduced to round-off in the band of a sphere and
kept by the smoothing; a smooth field converges at more than first order; periodic wrap
along z; the smoothing damps a grid-scale tangential perturbation; :func:`extend` is the two
steps per solid and is reverse-differentiable; a 2D problem embedded as an array invariant
along one axis (any of the three) gives the 2D function's values.
"""

import frozen_2d_extrapolation as old
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap import extrapolation as ext
from refmap.grid import Grid, Grid3D

# ---------------------------------------------------------------- 2D bitwise vs frozen copy

G2A = Grid(36, 30, -1.0, 1.0, -0.8, 0.8)  # dx != dy


def _case_2d(grid, centre, periodic, radius=0.45):
    X, Y = grid.mesh()
    Lx = grid.bx - grid.ax
    dxs = (X - centre[0] + Lx / 2) % Lx - Lx / 2 if periodic[0] else X - centre[0]
    phi = np.hypot(dxs / 1.1, Y - centre[1]) - radius  # an ellipse: not a distance
    f = np.stack([np.sin(2 * X + 1) * np.cos(1.5 * Y), np.exp(0.5 * X) * Y**2 - X * Y])
    return jnp.asarray(phi), jnp.asarray(np.where(phi < 0, f, 0.0))


def _same(a, b):
    if isinstance(a, tuple | list):
        assert isinstance(b, tuple | list) and len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _same(x, y)
        return
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    assert np.array_equal(a, b, equal_nan=True)


def test_2d_bitwise_equal_to_frozen():
    """dx != dy, an ellipse straddling the periodic x edge and touching no y edge."""
    grid, periodic = G2A, (True, False)
    phi, f = _case_2d(grid, (0.85, 0.05), periodic, radius=0.3)
    dx, dy, band = grid.dx, grid.dy, 5 * grid.h
    # extend: two solids (the second the mirror image), C = 2
    phis = jnp.stack([phi, phi[::-1]])
    fs = jnp.stack([f, f[:, ::-1] + 0.3])
    tile = (6, 6)  # divides nx = 36 on the periodic axis
    cap = int(np.max(np.asarray(ext.band_tiles(phis, band, tile, periodic))))
    assert cap < 25  # of 6 x 5 tiles: the tile path really runs
    smooth = dict(coef=0.025, max_sweeps=30, ratio=0.25, atol=1e-3, fixed_sweeps=None)
    fixed = dict(smooth, fixed_sweeps=6)

    def run(mod, f, phi, phis, fs, tiles=False):
        e = mod.extrapolate_linear(f, phi, dx, dy, band, periodic=periodic)
        out = (
            e,
            mod.solid_gradient(f, phi, dx, dy, periodic),
            mod.smooth_extrapolated(e, phi, dx, dy, band, periodic=periodic, return_sweeps=True),
            mod.smooth_extrapolated(e, phi, dx, dy, band, periodic=periodic, fixed_sweeps=9),
            mod.extend(fs, phis, dx, dy, band, periodic=periodic, smooth=smooth),
            mod.extend(fs, phis, dx, dy, band, periodic=periodic, smooth=fixed),
        )
        if tiles:  # the band tiles too (2D only; unchanged but for the generic internals)
            out += (mod.extend(fs, phis, dx, dy, band, capacity=cap, tile=tile,
                               periodic=periodic, smooth=smooth),)
        return out

    _same(run(ext, f, phi, phis, fs), run(old, f, phi, phis, fs))
    _same(jax.jit(lambda *a: run(ext, *a, tiles=True))(f, phi, phis, fs),
          jax.jit(lambda *a: run(old, *a, tiles=True))(f, phi, phis, fs))


# ------------------------------------------------------------------------------- 3D

G3 = Grid3D(24, 24, 24, -0.5, 0.5, -0.5, 0.5, -0.5, 0.5)
CENTRE = (0.02, -0.01, 0.03)


def sphere(grid, centre=CENTRE, radius=0.3):
    X, Y, Z = grid.mesh()
    return np.sqrt((X - centre[0]) ** 2 + (Y - centre[1]) ** 2 + (Z - centre[2]) ** 2) - radius


def band_mask(phi, band):
    return (phi >= 0) & (phi <= band)


def spacing(grid):
    return dict(dx=grid.dx, dy=grid.dy, dz=grid.dz)


def test_default_sweeps_and_flags_3d():
    assert ext.default_sweeps(0.4, 0.1, 0.1) == 9  # ceil(sqrt(2) 4) + 3
    assert ext.default_sweeps(0.4, 0.1, 0.1, dz=0.1) == 10  # ceil(sqrt(3) 4) + 3
    assert ext.default_sweeps(0.4, 0.1, 0.2, dz=0.05) == 17  # h = min spacing
    phi = jnp.asarray(sphere(G3))
    with pytest.raises(ValueError, match="3 periodic flags"):
        ext.extrapolate_linear(phi, phi, 0.1, 0.1, 0.4, periodic=(False, True), dz=0.1)
    with pytest.raises(ValueError, match="nx, ny, nz"):
        ext.extrapolate_linear(phi[0, 0], phi[0, 0], 0.1, 0.1, 0.4, dz=0.1)


def test_affine_3d_exact_and_kept_by_smoothing():
    X, Y, Z = G3.mesh()
    phi = sphere(G3)
    band = 4 * G3.h
    rng = np.random.default_rng(3)
    A, c = rng.normal(size=(3, 3)), rng.normal(size=3)
    xi = np.einsum("ab,bijk->aijk", A, np.stack([X, Y, Z])) + c[:, None, None, None]
    xi_in = np.where(phi < 0, xi, np.nan)  # only solid values may be used
    *g, gvalid = ext.solid_gradient(xi, phi, **spacing(G3))
    assert len(g) == 3
    gvalid = np.asarray(gvalid)
    assert not (gvalid & (phi >= 0)).any()
    assert gvalid.sum() > 0.99 * (phi < 0).sum()  # all but a few single-node bumps
    for a in range(3):
        for b in range(3):
            np.testing.assert_allclose(np.asarray(g[a])[b][gvalid], A[b, a], atol=1e-12)
    out = np.asarray(ext.extrapolate_linear(xi_in, phi, band=band, **spacing(G3)))
    m = np.broadcast_to(band_mask(phi, band), out.shape)
    assert m.sum() > 3 * 3000  # every band node of the sphere, all three components
    scale = np.abs(xi).max()
    assert np.abs(out - xi)[m].max() < 1e-12 * scale
    keep = np.broadcast_to((phi < 0) | (phi > band), out.shape)
    np.testing.assert_array_equal(out[keep], xi_in[keep])  # NaN beyond the band kept
    # the smoothing: the stopping rule is met at once, and fixed sweeps keep it too
    s, sweeps = ext.smooth_extrapolated(out, phi, band=band, return_sweeps=True, **spacing(G3))
    np.testing.assert_array_equal(np.asarray(sweeps), [0, 0, 0])
    np.testing.assert_array_equal(np.asarray(s), out)
    s = np.asarray(ext.smooth_extrapolated(out, phi, band=band, fixed_sweeps=30, **spacing(G3)))
    assert np.abs(s - xi)[m].max() < 1e-12 * scale


def test_smooth_field_3d_converges_faster_than_first_order():
    """Max error over the first two band layers (``0 <= phi <= 2h``, where the blend
    weights read band values): O(h^2) at a fixed number of cells from the interface."""
    errs = []
    for n in (12, 24):
        g = Grid3D(n, n, n, -0.5, 0.5, -0.5, 0.5, -0.5, 0.5)
        X, Y, Z = g.mesh()
        phi = sphere(g)
        f = np.sin(2 * X + 1) * np.cos(1.5 * Y) * np.cos(Z)
        out = np.asarray(ext.extrapolate_linear(np.where(phi < 0, f, 0.0), phi, band=4 * g.h,
                                                **spacing(g)))
        errs.append(np.abs(out - f)[band_mask(phi, 2 * g.h)].max())
    order = np.log2(errs[0] / errs[1])
    assert order > 1.5, (errs, order)  # measured 0.106 -> 0.030, order 1.82
    assert errs[1] < 0.04


G3Z = Grid3D(24, 24, 8, -0.5, 0.5, -0.5, 0.5, 0.0, 0.4)


def test_cylinder_along_periodic_z_same_in_every_slice():
    X, Y, Z = G3Z.mesh()
    phi = np.hypot(X - 0.03, Y + 0.02) - 0.3
    f = np.sin(2 * X + 1) * np.cos(1.5 * Y) + 0.0 * Z
    band = 4 * G3Z.h
    kw = dict(periodic=(False, False, True), **spacing(G3Z))
    out = np.asarray(ext.extrapolate_linear(np.where(phi < 0, f, 0.0), phi, band=band, **kw))
    sm = np.asarray(ext.smooth_extrapolated(out, phi, band=band, **kw))
    for a in (out, sm):
        for k in range(1, G3Z.nz):
            np.testing.assert_array_equal(a[..., k], a[..., 0])
    m = band_mask(phi, 2 * G3Z.h)
    assert np.abs(out - f)[m].max() < 0.05


def test_sphere_across_periodic_z_edge():
    X, Y, Z = G3.mesh()
    band = 4 * G3.h
    kw = dict(periodic=(False, False, True), **spacing(G3))
    # a sphere centred on the z edge: affine in the unwrapped z is reproduced exactly
    cz = 0.5
    dzs = (Z - cz + 0.5) % 1.0 - 0.5
    phi = np.sqrt((X - 0.02) ** 2 + (Y + 0.01) ** 2 + dzs**2) - 0.3
    f = 0.7 * X - 1.3 * Y + 2.1 * dzs + 0.4
    out = np.asarray(ext.extrapolate_linear(np.where(phi < 0, f, np.nan), phi, band=band, **kw))
    m = band_mask(phi, band)
    assert m[..., 0].any() and m[..., -1].any()  # the band really straddles the edge
    assert np.abs(out - f)[m].max() < 1e-12 * np.abs(f).max()
    # a non-affine, z-periodic field: the sphere shifted across the edge gives the
    # unshifted result shifted (rolled by half the period)
    phi0 = sphere(G3, centre=(0.02, -0.01, 0.0))
    f0 = np.sin(2 * X + 1) * np.cos(1.5 * Y) * np.cos(2 * np.pi * Z) * (phi0 < 0)
    half = G3.nz // 2

    def run(phi, f):
        e = ext.extrapolate_linear(f, phi, band=band, **kw)
        return np.asarray(ext.smooth_extrapolated(e, phi, band=band, fixed_sweeps=20, **kw))

    shifted = run(np.roll(phi0, half, axis=-1), np.roll(f0, half, axis=-1))
    np.testing.assert_allclose(shifted, np.roll(run(phi0, f0), half, axis=-1), rtol=0,
                               atol=1e-14)
    # without the wrap the straddling sphere is cut at the edge: different band values
    cut = ext.extrapolate_linear(np.roll(f0, half, -1), np.roll(phi0, half, -1), band=band,
                                 **spacing(G3))
    assert np.abs(np.asarray(cut) - shifted).max() > 1e-3


def test_smoothing_damps_tangential_perturbation_3d():
    X, Y, Z = G3.mesh()
    phi = sphere(G3, centre=(0.0, 0.0, 0.0))
    band = 5 * G3.h  # extrapolate and smooth over a band wider than the blend zone
    f = 0.3 * X - 1.2 * Y + 0.5 * Z + 0.5
    rho2 = X**2 + Y**2
    wave = np.cos(12 * np.arctan2(Y, X)) * rho2 / (rho2 + Z**2 + 1e-30)  # ~4h wavelength
    f_in = np.where(band_mask(phi, band), f + 0.05 * wave, f)
    out, sweeps = ext.smooth_extrapolated(f_in, phi, band=band, return_sweeps=True,
                                          **spacing(G3))
    out = np.asarray(out)
    assert int(sweeps) == 80  # the perturbation keeps the band far above the interior
    keep = (phi < 0) | (phi > band)
    np.testing.assert_array_equal(out[keep], f_in[keep])
    err_in, err_out = np.abs(f_in - f), np.abs(out - f)
    blur = band_mask(phi, 2 * G3.h)
    assert err_out[blur].max() < 0.1 * err_in[blur].max()  # measured 0.05
    inner = band_mask(phi, band - 1.5 * G3.h)
    assert np.sqrt(np.mean(err_out[inner] ** 2)) < 0.2 * np.sqrt(np.mean(err_in[inner] ** 2))  # 0.09


G3S = Grid3D(16, 16, 16, -0.5, 0.5, -0.5, 0.5, -0.5, 0.5)


def _two_solids(grid, C):
    X, Y, Z = grid.mesh()
    phi = np.stack([
        sphere(grid, centre=(-0.15, 0.0, 0.05), radius=0.22),
        np.sqrt((X - 0.12) ** 2 / 1.2 + (Y + 0.1) ** 2 + (Z / 0.8) ** 2) - 0.25,
    ])
    base = [np.sin(2 * X + 1) * np.cos(1.5 * Y) * np.cos(Z), X * Y - Z, np.exp(0.5 * Z) * X]
    f = np.stack([np.stack(base[:C]), np.stack(base[:C]) + 1.0])
    return jnp.asarray(phi), jnp.asarray(f * (phi[:, None] < 0))


@pytest.mark.parametrize("fixed_sweeps", [None, 6])
def test_extend_3d_is_the_two_steps_per_solid(fixed_sweeps):
    phi, f = _two_solids(G3S, 3)
    band = 4 * G3S.h
    smooth = dict(coef=0.025, max_sweeps=20, ratio=0.25, atol=1e-3, fixed_sweeps=fixed_sweeps)
    kw = dict(periodic=(False, True, False), **spacing(G3S))
    # capacity is ignored in 3D (the sweeps run on the full grid)
    out = ext.extend(f, phi, band=band, smooth=smooth, capacity=4, **kw)
    for s in range(2):
        e = ext.extrapolate_linear(f[s], phi[s], band=band, **kw)
        ref = ext.smooth_extrapolated(e, phi[s], band=band, **smooth, **kw)
        np.testing.assert_allclose(np.asarray(out[s]), np.asarray(ref), rtol=0, atol=1e-13)


def test_extend_3d_fixed_sweeps_reverse_mode():
    phi, f = _two_solids(G3S, 3)
    band = 4 * G3S.h
    smooth = dict(fixed_sweeps=5)

    def loss(f):
        out = ext.extend(f, phi, band=band, smooth=smooth, **spacing(G3S))
        return jnp.sum(out * jnp.cos(jnp.arange(out.size).reshape(out.shape)))

    grad = np.asarray(jax.jit(jax.grad(loss))(f))
    assert grad.shape == f.shape and np.all(np.isfinite(grad))
    solid = np.broadcast_to(np.asarray(phi)[:, None] < 0, f.shape)
    assert np.abs(grad[solid]).max() > 0
    # a band input is overwritten (not read): its gradient is 0 (phi > band: passed through)
    assert np.abs(grad[np.broadcast_to(band_mask(np.asarray(phi), band)[:, None], f.shape)]
                  ).max() == 0
    direction = jnp.asarray(np.cos(np.arange(f.size)).reshape(f.shape)) * solid
    eps = 1e-6
    fd = (loss(f + eps * direction) - loss(f - eps * direction)) / (2 * eps)
    np.testing.assert_allclose(float(jnp.vdot(grad, direction)), float(fd), rtol=1e-6)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_2d_problem_embedded_along_an_axis(axis):
    """A 2D ellipse problem on an anisotropic grid, embedded in 3D invariant along ``axis``
    (periodic there, 8 nodes, a spacing no smaller than the others): the 3D functions give
    the 2D values.  Not bitwise: the 3D weights and second differences add zero terms."""
    grid = G2A
    phi2, f2 = _case_2d(grid, (-0.05, 0.1), (False, False))
    f2 = f2[0]
    band = 5 * grid.h
    iters = ext.default_sweeps(band, grid.dx, grid.dy)
    periodic2 = (False, True)
    e2 = ext.extrapolate_linear(f2, phi2, grid.dx, grid.dy, band, iters, periodic2)
    s2 = ext.smooth_extrapolated(e2, phi2, grid.dx, grid.dy, band, periodic=periodic2)
    k2 = ext.smooth_extrapolated(e2, phi2, grid.dx, grid.dy, band, periodic=periodic2,
                                 fixed_sweeps=15)

    def embed(a):
        return np.moveaxis(np.repeat(np.asarray(a)[..., None], 8, axis=-1), -1, axis)

    h = [grid.dx, grid.dy]
    h.insert(axis, 0.07)
    periodic = list(periodic2)
    periodic.insert(axis, True)
    kw = dict(dx=h[0], dy=h[1], dz=h[2], periodic=tuple(periodic))
    phi3, f3 = embed(phi2), embed(f2)
    e3 = ext.extrapolate_linear(f3, phi3, band=band, iters=iters, **kw)
    s3 = ext.smooth_extrapolated(e3, phi3, band=band, **kw)
    k3 = ext.smooth_extrapolated(e3, phi3, band=band, fixed_sweeps=15, **kw)
    m = band_mask(np.asarray(phi2), band)
    assert m.sum() > 200
    for a2, a3 in ((e2, e3), (s2, s3), (k2, k3)):
        np.testing.assert_allclose(np.asarray(a3), embed(a2), rtol=0, atol=1e-12)
