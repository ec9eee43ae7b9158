"""3D boundary padding (issue 12, step two): six faces, the 2D rules per axis, axis after axis.

Checked on an 8 x 9 x 10 grid (``Grid3D`` needs n >= 8; three different sizes and spacings
catch any mix-up of axes): affine fields are continued exactly by ``pad_linear`` and
``pad_affine``; wall, moving wall, slip, velocity (with a parabolic whole-face profile and
a ramp), outflow and periodic ghosts equal their reflection rules computed by hand face by
face; the ghost edges and corners equal an independent numpy padding done axis after
axis, and a triple corner is checked by hand; gluing reflects about the initial face.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap.boundary import EDGES, Boundary, BoundaryConditions, Segment
from refmap.grid import Grid, Grid3D

G = Grid3D(8, 9, 10, ax=-1.0, bx=1.0, ay=0.0, by=1.8, az=-0.5, bz=1.5)
I = slice(2, -2)  # interior (non-ghost) range of a padded axis
U_RIGHT = (0.5, 0.2, -0.1)
W_BACK = (0.3, -0.2, 0.7)
MIXED = Boundary(
    left="wall",
    right=Segment("velocity", velocity=U_RIGHT),
    bottom="slip",
    top="outflow",
    back=Segment("wall", velocity=W_BACK),
    front="slip",
)
TOL = dict(rtol=0, atol=1e-14)


def _rand(*shape, seed=0):
    return np.random.default_rng(seed).normal(size=shape)


def test_padded_coords_and_affine_fields_exact():
    rng = np.random.default_rng(1)
    A, c = rng.normal(size=(3, 3)), rng.normal(size=3)
    X = np.asarray(G.mesh())
    for b in (MIXED, Boundary(back="wall", front="outflow")):
        bc = BoundaryConditions(G, b)
        Xp = bc.padded_coords(2)
        assert Xp.shape == (3, 12, 13, 14)
        for a, (lo, h) in enumerate(zip((G.ax, G.ay, G.az), G.spacing, strict=True)):
            line = np.moveaxis(Xp[a], a, 0)[:, 0, 0]
            np.testing.assert_allclose(line, lo + (np.arange(-2, G.shape()[a] + 2) + 0.5) * h, **TOL)
        f = c[:, None, None, None] + np.einsum("ij,j...->i...", A, X)
        exact = c[:, None, None, None] + np.einsum("ij,j...->i...", A, Xp)
        np.testing.assert_allclose(bc.pad_linear(jnp.asarray(f)), exact, rtol=0, atol=1e-12)
        np.testing.assert_allclose(bc.pad_affine(jnp.asarray(f)), exact, rtol=0, atol=1e-12)
        # leading (solid) axes are free
        assert bc.pad_affine(jnp.asarray(np.stack([f, f]))).shape == (2, 3, 12, 13, 14)
    # periodic z: xi - x periodic in z (here independent of z) is continued exactly too
    bc = BoundaryConditions(G, Boundary(back="periodic", front="periodic"))
    assert bc.periodic == (False, False, True)
    A[:, 2] = 0.0
    xi = X + c[:, None, None, None] + np.einsum("ij,j...->i...", A, X)
    Xp = bc.padded_coords(2)
    exact = Xp + c[:, None, None, None] + np.einsum("ij,j...->i...", A, Xp)
    np.testing.assert_allclose(bc.pad_affine(jnp.asarray(xi)), exact, rtol=0, atol=1e-12)


def test_face_rules_by_hand():
    bc = BoundaryConditions(G, MIXED)
    v = _rand(3, 8, 9, 10)
    P = np.asarray(bc.pad_velocity(jnp.asarray(v), 0.0))
    assert P.shape == (3, 12, 13, 14)
    np.testing.assert_array_equal(P[:, I, I, I], v)
    U, W = np.array(U_RIGHT)[:, None, None], np.array(W_BACK)[:, None, None]
    # left: no-slip wall at rest, odd reflection of every component
    np.testing.assert_allclose(P[:, 1, I, I], -v[:, 0], **TOL)
    np.testing.assert_allclose(P[:, 0, I, I], -v[:, 1], **TOL)
    # right: given velocity U on the face, ghost = 2U - mirror
    np.testing.assert_allclose(P[:, -2, I, I], 2 * U - v[:, -1], **TOL)
    np.testing.assert_allclose(P[:, -1, I, I], 2 * U - v[:, -2], **TOL)
    # bottom: slip, normal (v) odd, tangential (u, w) even
    s = np.array([1.0, -1.0, 1.0])[:, None, None]
    np.testing.assert_allclose(P[:, I, 1, I], s * v[:, :, 0], **TOL)
    np.testing.assert_allclose(P[:, I, 0, I], s * v[:, :, 1], **TOL)
    # top: outflow, zero gradient
    np.testing.assert_allclose(P[:, I, -2, I], v[:, :, -1], **TOL)
    np.testing.assert_allclose(P[:, I, -1, I], v[:, :, -1], **TOL)
    # back: wall moving with W
    np.testing.assert_allclose(P[:, I, I, 1], 2 * W - v[..., 0], **TOL)
    np.testing.assert_allclose(P[:, I, I, 0], 2 * W - v[..., 1], **TOL)
    # front: slip, normal (w) odd
    s = np.array([1.0, 1.0, -1.0])[:, None, None]
    np.testing.assert_allclose(P[:, I, I, -2], s * v[..., -1], **TOL)
    np.testing.assert_allclose(P[:, I, I, -1], s * v[..., -2], **TOL)
    # a triple corner by hand, axis after axis: x (left wall), then y (bottom slip), then
    # z (back moving wall): G_x = -v, G_xy = s_y G_x, G_xyz = 2 W - G_xy(mirror in z)
    sy = np.array([1.0, -1.0, 1.0])
    for c in range(3):
        expect = 2 * W_BACK[c] - sy[c] * (-v[c, 0, 0, 0])
        assert abs(P[c, 1, 1, 1] - expect) < 1e-14
        expect = 2 * W_BACK[c] - sy[c] * (-v[c, 1, 1, 1])  # outermost: mirrors (1, 1, 1)
        assert abs(P[c, 0, 0, 0] - expect) < 1e-14
    # density: walls and slip even, outgoing velocity and outflow linear
    rho = 1 + 0.1 * _rand(8, 9, 10, seed=2)
    R = np.asarray(bc.pad_density(jnp.asarray(rho)))
    np.testing.assert_allclose(R[1, I, I], rho[0], **TOL)
    np.testing.assert_allclose(R[0, I, I], rho[1], **TOL)
    np.testing.assert_allclose(R[-2, I, I], 2 * rho[-1] - rho[-2], **TOL)
    np.testing.assert_allclose(R[-1, I, I], 3 * rho[-1] - 2 * rho[-2], **TOL)
    np.testing.assert_allclose(R[I, -1, I], 3 * rho[:, -1] - 2 * rho[:, -2], **TOL)
    np.testing.assert_allclose(R[I, I, 0], rho[..., 1], **TOL)
    np.testing.assert_allclose(R[I, I, -1], rho[..., -2], **TOL)


def _np_pad(f, rules):
    """Independent reference: pad the last three axes of ``f`` axis after axis.

    ``rules[axis]`` is "periodic" or a pair (low, high) of functions
    ``ghost_k(f_(k-1), f_0, f_1, k)`` applied to the slices of the array padded so far.
    """
    for axis in range(3):
        ax = f.ndim - 3 + axis
        if rules[axis] == "periodic":
            w = [(0, 0)] * f.ndim
            w[ax] = (2, 2)
            f = np.pad(f, w, mode="wrap")
            continue
        n = f.shape[ax]
        lo, hi = rules[axis]
        t = lambda i, f=f, ax=ax: np.take(f, [i], axis=ax)  # noqa: E731
        low = [lo(t(k - 1), t(0), t(1), k) for k in (2, 1)]
        high = [hi(t(n - k), t(n - 1), t(n - 2), k) for k in (1, 2)]
        f = np.concatenate(low + [f] + high, axis=ax)
    return f


def _odd(U=0.0):
    return lambda fm, f0, f1, k: 2 * U - fm


def _even(fm, f0, f1, k):
    return fm


def _outflow(fm, f0, f1, k):
    return f0


def _linear(fm, f0, f1, k):
    return (k + 1) * f0 - k * f1


def _const(c):
    return lambda fm, f0, f1, k: np.full_like(f0, c)


@pytest.mark.parametrize("z_periodic", [False, True])
def test_edges_and_corners_axis_after_axis(z_periodic):
    b = MIXED if not z_periodic else Boundary(
        left=MIXED.left, right=MIXED.right, bottom=MIXED.bottom, top=MIXED.top,
        back="periodic", front="periodic")
    bc = BoundaryConditions(G, b, rho_f0=1.25)
    v = _rand(3, 8, 9, 10, seed=3)
    P = np.asarray(bc.pad_velocity(jnp.asarray(v), 0.0))
    for c in range(3):
        slip = [_odd() if c == a else _even for a in range(3)]
        rules = [
            (_odd(), _odd(U_RIGHT[c])),
            (slip[1], _outflow),
            "periodic" if z_periodic else (_odd(W_BACK[c]), slip[2]),
        ]
        np.testing.assert_allclose(P[c], _np_pad(v[c], rules), **TOL)
    rho = 1 + 0.1 * _rand(8, 9, 10, seed=4)
    R = np.asarray(bc.pad_density(jnp.asarray(rho)))
    rules = [(_even, _linear), (_even, _linear), "periodic" if z_periodic else (_even, _even)]
    np.testing.assert_allclose(R, _np_pad(rho, rules), **TOL)
    # an inflowing face takes the reference density (here the back face, u_z > 0)
    b_in = Boundary(left="outflow", right="outflow", back=Segment("velocity", velocity=(0, 0, 0.4)),
                    front="outflow")
    R = np.asarray(BoundaryConditions(G, b_in, rho_f0=1.25).pad_density(jnp.asarray(rho), rho0=0.9))
    rules = [(_linear, _linear), (_even, _even), (_const(0.9), _linear)]
    np.testing.assert_allclose(R, _np_pad(rho, rules), **TOL)
    # pad_linear: linear extrapolation (or wrap), axis after axis, edges and corners included
    f = _rand(2, 3, 8, 9, 10, seed=5)
    rules = [(_linear, _linear), (_linear, _linear), "periodic" if z_periodic else (_linear, _linear)]
    np.testing.assert_allclose(bc.pad_linear(jnp.asarray(f)), _np_pad(f, rules), rtol=0, atol=1e-13)


def test_periodic_axis_wraps():
    b = Boundary(left="periodic", right="periodic", back="periodic", front="periodic")
    bc = BoundaryConditions(G, b)
    assert bc.periodic == (True, False, True)
    v = _rand(3, 8, 9, 10, seed=6)
    P = np.asarray(bc.pad_velocity(jnp.asarray(v), 0.0))
    np.testing.assert_array_equal(P[:, 0, I, I], v[:, -2])
    np.testing.assert_array_equal(P[:, 1, I, I], v[:, -1])
    np.testing.assert_array_equal(P[:, -2, I, I], v[:, 0])
    np.testing.assert_array_equal(P[:, -1, I, I], v[:, 1])
    np.testing.assert_array_equal(P[:, I, I, 0], v[..., -2])
    np.testing.assert_array_equal(P[:, I, I, -1], v[..., 1])
    # the x-z edge ghosts wrap on both axes
    np.testing.assert_array_equal(P[:, 0, I, 0], v[:, -2, :, -2])
    np.testing.assert_array_equal(P[:, -1, I, -1], v[:, 1, :, 1])


def test_parabolic_profile_and_ramp_on_a_face():
    seg = Segment("velocity", velocity=(1.0, 0.0, 0.5), profile="parabolic", ramp=2.0)
    bc = BoundaryConditions(G, Boundary(left=seg, back="wall", front="wall"))
    v = _rand(3, 8, 9, 10, seed=7)
    t = 0.5
    wave = 0.5 * (1 - np.cos(np.pi * t / 2.0))
    P = np.asarray(jax.jit(bc.pad_velocity)(jnp.asarray(v), t))
    y, z = G.axes()[1], G.axes()[2]
    s, r = (y - G.ay) / (G.by - G.ay), (z - G.az) / (G.bz - G.az)
    prof = (4 * s * (1 - s))[:, None] * (4 * r * (1 - r))[None, :]
    for c, U in enumerate(seg.velocity):
        np.testing.assert_allclose(P[c, 1, I, I], -v[c, 0] + 2 * U * prof * wave, rtol=0, atol=1e-13)
        np.testing.assert_allclose(P[c, 0, I, I], -v[c, 1] + 2 * U * prof * wave, rtol=0, atol=1e-13)


def test_glue_reflects_about_the_initial_face():
    b = Boundary(left="outflow", right="outflow", top="outflow", back="slip", front="outflow")
    bc = BoundaryConditions(G, b)
    X = np.asarray(G.mesh())
    disp0 = 0.05 * _rand(1, 3, 8, 9, 10, seed=8)
    bc.glue(disp0, np.ones((1, 8, 9, 10), bool))
    d = 0.05 * _rand(1, 3, 8, 9, 10, seed=9)
    D = np.asarray(bc.pad_affine(jnp.asarray(X + d))) - bc.padded_coords(2)
    # bottom: wall at rest, every component odd about the initial face value
    face = 1.5 * disp0[:, :, :, 0] - 0.5 * disp0[:, :, :, 1]
    np.testing.assert_allclose(D[:, :, I, 1, I], 2 * face - d[:, :, :, 0], rtol=0, atol=1e-13)
    np.testing.assert_allclose(D[:, :, I, 0, I], 2 * face - d[:, :, :, 1], rtol=0, atol=1e-13)
    # back: slip, normal component (z) odd about the face, tangential (x, y) even
    face = 1.5 * disp0[..., 0] - 0.5 * disp0[..., 1]
    np.testing.assert_allclose(D[:, 2, I, I, 1], 2 * face[:, 2] - d[:, 2, ..., 0], rtol=0, atol=1e-13)
    np.testing.assert_allclose(D[:, :2, I, I, 1], d[:, :2, ..., 0], rtol=0, atol=1e-13)
    np.testing.assert_allclose(D[:, :2, I, I, 0], d[:, :2, ..., 1], rtol=0, atol=1e-13)
    # outflow faces: linear extrapolation as before
    np.testing.assert_allclose(D[:, :, 1, I, I], 2 * d[:, :, 0] - d[:, :, 1], rtol=0, atol=1e-13)


def test_3d_boundary_api_and_errors():
    b = MIXED
    assert b.ndim == 3 and b.faces == EDGES + ("back", "front")
    assert Boundary().ndim == 2 and Boundary().periodic == (False, False)
    d = b.to_dict()
    assert list(d) == list(EDGES) + ["back", "front"]
    assert Boundary.from_dict(d) == b
    assert list(Boundary().to_dict()) == list(EDGES)  # 2D dictionaries unchanged
    assert Boundary.from_dict(Boundary(back="wall", front="wall").to_dict()) == Boundary(
        back="wall", front="wall")
    assert Boundary(back="wall", front="wall").left[0].velocity == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="face 'top' of a 3D boundary.*2 components"):
        Boundary(top=Segment("wall", velocity=(1.0, 0.0)), back="wall", front="wall")
    with pytest.raises(ValueError, match="face 'back' of a 3D boundary.*whole"):
        Boundary(back=(Segment("wall", 0.0, 0.5, (0, 0, 0)), Segment("slip", 0.5, 1.0, (0, 0, 0))),
                 front="wall")
    with pytest.raises(ValueError, match="edge 'left' of a 2D boundary"):
        Boundary(left=Segment("wall", velocity=(0.0, 0.0, 1.0)))
    with pytest.raises(ValueError, match="both z faces"):
        Boundary(back="wall")
    with pytest.raises(ValueError, match="periodic edges come in pairs: back"):
        Boundary(back="periodic", front="wall")
    with pytest.raises(ValueError, match="a 3D grid needs a 3D boundary"):
        BoundaryConditions(G, Boundary())
    with pytest.raises(ValueError, match="a 2D grid needs a 2D boundary"):
        BoundaryConditions(Grid(8, 8), MIXED)
