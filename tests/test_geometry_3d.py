"""3D shapes of refmap.geometry (issue 12): exact distances at constructed points, the
ellipsoid's approximation order, volumes by sampling, CSG, transforms, errors, round trip."""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (enables float64)
from refmap.geometry import (
    SHAPES,
    SHAPES_3D,
    Box,
    Capsule3D,
    Cylinder,
    Disc,
    Ellipsoid,
    Intersection,
    Rotate,
    Sphere,
    Torus,
    Translate,
    Union,
    shape_from_dict,
)

rng = np.random.default_rng(7)


def unit_vectors(n):
    u = rng.standard_normal((n, 3))
    return u / np.linalg.norm(u, axis=1)[:, None]


def ev(shape, p):
    return np.asarray(shape(p[..., 0], p[..., 1], p[..., 2]))


EXAMPLES = {
    "sphere": Sphere((0.1, -0.2, 0.3), 0.7),
    "ellipsoid": Ellipsoid((0.0, 0.1, -0.1), (1.0, 0.7, 0.5), angle=0.3),
    "box": Box((0.1, 0.0, -0.2), (0.5, 0.3, 0.2), angle=0.4),
    "box_rounded": Box((0.0, 0.0, 0.0), (0.5, 0.4, 0.3), corner_radius=0.1),
    "cylinder": Cylinder((0.0, 0.2, 0.0), 0.3, 0.6, direction=(1.0, 1.0, 1.0)),
    "capsule": Capsule3D((0.1, 0.0, 0.0), 0.5, 0.25, direction=(1.0, 2.0, 0.5)),
    "torus": Torus((0.0, 0.0, 0.2), 0.8, 0.25),
}
VOLUMES = {
    "sphere": 4 / 3 * math.pi * 0.7**3,
    "ellipsoid": 4 / 3 * math.pi * 1.0 * 0.7 * 0.5,
    "box": 8 * 0.5 * 0.3 * 0.2,
    # Steiner: core box (a, b, c) = h - r grown by r: V + S r + 2 pi (a + b + c) r^2 + 4/3 pi r^3
    "box_rounded": 8 * 0.4 * 0.3 * 0.2
    + 8 * 0.1 * (0.4 * 0.3 + 0.3 * 0.2 + 0.2 * 0.4)
    + 2 * math.pi * 0.1**2 * (0.4 + 0.3 + 0.2)
    + 4 / 3 * math.pi * 0.1**3,
    "cylinder": 2 * math.pi * 0.3**2 * 0.6,
    "capsule": 2 * math.pi * 0.25**2 * 0.5 + 4 / 3 * math.pi * 0.25**3,
    "torus": 2 * math.pi**2 * 0.8 * 0.25**2,
}


# --------------------------------------------------------------------------------------------
# dimension checks


def test_wrong_number_of_coordinates_is_refused():
    x = np.zeros(4)
    with pytest.raises(
        ValueError, match=r"Disc is a 2D shape: call it with 2 coordinate arrays \(X, Y\), got 3"
    ):
        Disc()(x, x, x)
    with pytest.raises(
        ValueError,
        match=r"Sphere is a 3D shape: call it with 3 coordinate arrays \(X, Y, Z\), got 2",
    ):
        Sphere()(x, x)
    with pytest.raises(ValueError, match="Union is a 3D shape"):
        (Sphere() | Box((0, 0, 0), (1, 1, 1)))(x, x)
    with pytest.raises(
        ValueError, match=r"Union: cannot combine a 2D shape \(Disc\) with a 3D shape \(Sphere\)"
    ):
        Disc() | Sphere()
    with pytest.raises(ValueError, match="'offset' must be a triple"):
        Translate(Sphere(), (1.0, 2.0))
    with pytest.raises(ValueError, match="'center' must be a triple"):
        Sphere((0.0, 0.0), 1.0)
    with pytest.raises(ValueError, match="use volume"):
        Sphere().area()
    with pytest.raises(ValueError, match="use area"):
        Disc().volume()


def test_registries():
    assert set(SHAPES_3D) == {"Sphere", "Ellipsoid", "Box", "Cylinder", "Capsule3D", "Torus"}
    assert not set(SHAPES_3D) & set(SHAPES)
    assert all(SHAPES_3D[k].ndim == 3 for k in SHAPES_3D)
    assert (Sphere() | Sphere((1, 0, 0))).ndim == 3 and Translate(Disc(), (1, 2)).ndim == 2


# --------------------------------------------------------------------------------------------
# exact distances at points whose distance is known by construction


def test_sphere_exact():
    s = EXAMPLES["sphere"]
    c = np.array(s.center)
    u, t = unit_vectors(200), rng.uniform(-0.7, 2.0, 200)
    p = c + (0.7 + t)[:, None] * u  # at signed distance t along the radius
    np.testing.assert_allclose(ev(s, p), t, atol=1e-14)
    assert float(s(*c)) == -0.7


def test_torus_exact():
    R, r = 0.8, 0.25
    tor = EXAMPLES["torus"]
    c = np.array(tor.center)
    th, ph = rng.uniform(0, 2 * np.pi, (2, 300))
    t = rng.uniform(-r, R - r, 300)  # up to the tube's centre line inside, to the axis outside
    e_rho = np.stack([np.cos(th), np.sin(th), 0 * th], axis=1)
    n = np.cos(ph)[:, None] * e_rho + np.sin(ph)[:, None] * np.array([0.0, 0.0, 1.0])
    p = c + R * e_rho + (r + t)[:, None] * n
    np.testing.assert_allclose(ev(tor, p), t, atol=1e-14)
    z = 0.37  # on the axis: every point of the centre circle is at sqrt(R^2 + z^2)
    assert float(tor(c[0], c[1], c[2] + z)) == pytest.approx(math.hypot(R, z) - r, abs=1e-15)


def test_box_exact():
    box = Box((0.0, 0.0, 0.0), (0.5, 0.3, 0.2))
    cases = [
        ((0.9, 0.1, -0.1), 0.4),  # face region
        ((0.0, 0.0, 0.0), -0.2),  # centre: nearest face z
        ((0.45, 0.1, 0.05), -0.05),  # inside, nearest face x
        ((0.8, 0.7, 0.0), math.hypot(0.3, 0.4)),  # edge region
        ((0.8, -0.7, 0.6), math.sqrt(0.3**2 + 0.4**2 + 0.4**2)),  # vertex region
    ]
    for p, d in cases:
        assert float(box(*p)) == pytest.approx(d, abs=1e-15)
    # rounded: a vertex region point is at distance |p - (h - r)| - r
    rb = EXAMPLES["box_rounded"]
    p = np.array([0.9, 0.8, 0.7])
    assert float(rb(*p)) == pytest.approx(
        np.linalg.norm(p - np.array([0.4, 0.3, 0.2])) - 0.1, abs=1e-15
    )
    # turned about z: the same values at the turned points
    turned, a = EXAMPLES["box"], 0.4
    q = rng.uniform(-1, 1, (100, 3))
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    ref = Box((0.0, 0.0, 0.0), turned.half_size)
    np.testing.assert_allclose(
        ev(turned, q @ rot.T + np.array(turned.center)), ev(ref, q), atol=1e-14
    )


def test_capsule_and_cylinder_exact():
    cap = EXAMPLES["capsule"]
    d = np.array(cap.direction) / np.linalg.norm(cap.direction)
    seg = np.array(cap.center) + np.linspace(-0.5, 0.5, 20001)[:, None] * d
    p = rng.uniform(-1.2, 1.2, (200, 3))
    brute = np.min(np.linalg.norm(p[:, None, :] - seg[None], axis=2), axis=1) - 0.25
    np.testing.assert_allclose(ev(cap, p), brute, atol=2e-9)  # sampling spacing 5e-5
    cyl = Cylinder((0.0, 0.0, 0.0), 0.3, 0.6)  # along z
    cases = [
        ((0.0, 0.0, 0.0), -0.3),
        ((0.1, 0.0, 0.55), -0.05),  # nearest the cap
        ((0.0, 0.5, 0.1), 0.2),  # side
        ((0.0, 0.1, 0.9), 0.3),  # above the cap
        ((0.6, 0.0, 1.0), 0.5),  # rim region: sqrt(0.3^2 + 0.4^2)
    ]
    for q, v in cases:
        assert float(cyl(*q)) == pytest.approx(v, abs=1e-15)
    tilted = EXAMPLES["cylinder"]  # rotation invariance: z-cylinder seen along (1, 1, 1)
    e3 = np.array(tilted.direction) / np.sqrt(3)
    e1 = np.array([1.0, -1.0, 0.0]) / np.sqrt(2)
    frame = np.stack([e1, np.cross(e3, e1), e3], axis=1)  # columns: images of x, y, z
    q = rng.uniform(-1, 1, (200, 3))
    np.testing.assert_allclose(
        ev(tilted, q @ frame.T + np.array(tilted.center)), ev(cyl, q), atol=1e-14
    )


def test_ellipsoid_is_a_second_order_distance():
    """Exact zero set and sign, exact for a sphere, |phi - d| <= d^2 / min(r) near the
    surface at true distance d (points q + d n along the normal, |d| below the smallest
    radius of curvature, so q is the nearest point)."""
    for axes in ((1.0, 0.7, 0.5), (1.5, 0.5, 0.6)):
        ax = np.array(axes)
        e = Ellipsoid((0.0, 0.0, 0.0), axes)
        q = unit_vectors(2000) * ax
        n = q / ax**2
        n /= np.linalg.norm(n, axis=1)[:, None]
        np.testing.assert_allclose(ev(e, q), 0.0, atol=1e-14)
        d = rng.uniform(-0.1, 0.1, 2000) * ax.min()
        phi = ev(e, q + d[:, None] * n)
        assert np.all(np.sign(phi) == np.sign(d))
        assert np.all(np.abs(phi - d) <= d**2 / ax.min())
    ball = Ellipsoid((0.1, 0.2, 0.3), (0.6, 0.6, 0.6), angle=0.7)
    p = rng.uniform(-1, 1, (100, 3))
    np.testing.assert_allclose(ev(ball, p), ev(Sphere((0.1, 0.2, 0.3), 0.6), p), atol=1e-14)
    assert float(ball(0.1, 0.2, 0.3)) == -0.6


@pytest.mark.parametrize("name", [k for k in EXAMPLES if k != "ellipsoid"])
def test_unit_gradient_by_autodiff(name):
    """The exact shapes have |grad phi| = 1 (autodiff) at random points off the medial axis."""
    shape = EXAMPLES[name]
    p = jnp.asarray(rng.uniform(-1.5, 1.5, (300, 3)))
    g = jax.vmap(jax.grad(lambda x: shape(x[0], x[1], x[2])))(p)
    norms = np.linalg.norm(np.asarray(g), axis=1)
    assert np.mean(np.abs(norms - 1) < 1e-12) > 0.97  # medial-axis points have |grad| < 1
    assert np.all(np.isfinite(norms))
    assert np.all(np.isfinite(np.asarray(jax.grad(lambda x: shape(*x))(jnp.asarray(shape.center)))))


# --------------------------------------------------------------------------------------------
# volumes, CSG, transforms


@pytest.mark.parametrize("name", list(EXAMPLES))
def test_volume_by_sampling(name):
    """n = 100 cells per axis: measured relative errors <= 7.6e-4; tolerance 3e-3 (the
    worst-case tube bound, surface x half a cell diagonal, is ~10 % and says nothing)."""
    shape = EXAMPLES[name]
    assert shape.volume(100) == pytest.approx(VOLUMES[name], rel=3e-3)


def test_csg_3d():
    r = 0.7
    ball = Sphere((0.0, 0.0, 0.0), r)
    hole = Cylinder((0.0, 0.0, 0.0), 0.4, 2.0)  # along z, longer than the ball
    ring = ball - hole  # napkin ring: volume pi h^3 / 6 with h its height
    h = 2 * math.sqrt(r**2 - 0.4**2)
    assert ring.volume(120) == pytest.approx(math.pi * h**3 / 6, rel=5e-3)
    assert float(ring(0.0, 0.0, 0.0)) > 0 and float(ring(0.55, 0.0, 0.0)) < 0
    lens = ball & Sphere((0.5, 0.0, 0.0), r)  # two equal balls at distance d
    d = 0.5
    assert lens.volume(100) == pytest.approx(
        math.pi * (4 * r + d) * (2 * r - d) ** 2 / 12, rel=3e-3
    )
    pair = ball | Sphere((2.0, 0.0, 0.0), r)
    assert pair.volume(100) == pytest.approx(2 * 4 / 3 * math.pi * r**3, rel=3e-3)
    assert pair.bbox() == (-r, 2 + r, -r, r, -r, r)
    assert lens.bbox() == (0.5 - r, r, -r, r, -r, r)


def test_translate_and_rotate_3d():
    box = Box((0.0, 0.0, 0.0), (0.5, 0.3, 0.2))
    p = rng.uniform(-1, 1, (200, 3))
    moved = box.translate(0.1, -0.2, 0.3)
    np.testing.assert_allclose(
        ev(moved, p), ev(Box((0.1, -0.2, 0.3), (0.5, 0.3, 0.2)), p), atol=1e-15
    )
    turned = Rotate(Box((0.2, 0.1, 0.0), (0.5, 0.3, 0.2)), 0.6, about=(0.2, 0.1))
    np.testing.assert_allclose(
        ev(turned, p), ev(Box((0.2, 0.1, 0.0), (0.5, 0.3, 0.2), angle=0.6), p), atol=1e-14
    )
    b = turned.bbox()
    assert len(b) == 6 and b[4:] == (-0.2, 0.2)
    inside = p[ev(turned, p) < 0]
    assert np.all((inside >= np.array(b[0::2])) & (inside <= np.array(b[1::2])))


def test_bbox_contains_every_3d_shape():
    for shape in EXAMPLES.values():
        b = np.array(shape.bbox())
        lo, hi = b[0::2], b[1::2]
        p = rng.uniform(lo - 0.3, hi + 0.3, (20000, 3))
        inside = p[ev(shape, p) < 0]
        assert len(inside) > 100
        assert np.all((inside >= lo - 1e-12) & (inside <= hi + 1e-12))


def test_jit_and_round_trip_3d():
    nested = ((EXAMPLES["sphere"] | EXAMPLES["box"]) - EXAMPLES["cylinder"]).translate(
        0.1, 0.0, -0.1
    )
    shapes = [
        *EXAMPLES.values(),
        nested,
        Intersection(EXAMPLES["torus"], EXAMPLES["capsule"]).rotate(0.3),
    ]
    X, Y, Z = (jnp.asarray(a) for a in rng.uniform(-1, 1, (3, 7, 5)))
    for shape in shapes:
        d = shape.to_dict()
        back = shape_from_dict(json.loads(json.dumps(d)))
        assert back == shape
        out = jax.jit(lambda X, Y, Z, s=shape: s(X, Y, Z))(X, Y, Z)
        assert out.shape == (7, 5)
        np.testing.assert_allclose(out, shape(X, Y, Z), rtol=1e-13, atol=1e-13)
    assert isinstance(shape_from_dict({"type": "Sphere", "radius": 2}), Sphere)
    assert isinstance(shape_from_dict(Union(Sphere(), Sphere((1, 1, 1))).to_dict()).a, Sphere)
