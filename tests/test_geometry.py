"""Tests for refmap.geometry: signed-distance shapes, CSG, transforms, serialisation."""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import refmap  # noqa: F401  (enables float64)
from refmap.geometry import (
    SHAPES,
    Capsule,
    Difference,
    Disc,
    Ellipse,
    Intersection,
    Rectangle,
    Rotate,
    Rotor,
    Shape,
    Translate,
    Union,
    register_shape,
    shape_from_dict,
)

# --------------------------------------------------------------------------------------------
# helpers


def rotor_scalar(x, y, cx=0.0, cy=0.0, L=1.1, w=0.4, b=0.8):
    """Direct Python transcription of the rotor formula of Valkov's thesis."""
    xx, yy = abs(x - cx), abs(y - cy)
    if xx < b and yy < b:
        return (b - w) - math.sqrt((xx - b) ** 2 + (yy - b) ** 2)
    if xx < yy:
        xx, yy = yy, xx
    if xx < L:
        return yy - w
    return math.sqrt((xx - L) ** 2 + yy**2) - w


def ellipse_distance_reference(a, b, px, py):
    """Unsigned distance from (px, py) to the axis-aligned ellipse, by brute force + Newton."""
    t = np.linspace(0.0, 2 * np.pi, 4096, endpoint=False)
    d2 = (px[:, None] - a * np.cos(t)) ** 2 + (py[:, None] - b * np.sin(t)) ** 2
    t = t[np.argmin(d2, axis=1)]
    for _ in range(8):  # Newton on d/dt |p - e(t)|^2 = 0, from the best sample
        ex, ey = a * np.cos(t), b * np.sin(t)
        dx, dy = -a * np.sin(t), b * np.cos(t)
        g = (ex - px) * dx + (ey - py) * dy
        h = dx * dx + dy * dy + (ex - px) * (-ex) + (ey - py) * (-ey)
        t = t - g / h
    return np.hypot(px - a * np.cos(t), py - b * np.sin(t))


def grad_norm_in_band(shape, band, n=601, pad=0.2):
    """|grad phi| by central differences at grid points where |phi| < band."""
    x0, x1, y0, y1 = shape.bbox()
    x = np.linspace(x0 - pad, x1 + pad, n)
    y = np.linspace(y0 - pad, y1 + pad, n)
    hx, hy = x[1] - x[0], y[1] - y[0]
    X, Y = np.meshgrid(x, y, indexing="ij")
    phi = np.asarray(shape(X, Y))
    gx = (phi[2:, 1:-1] - phi[:-2, 1:-1]) / (2 * hx)
    gy = (phi[1:-1, 2:] - phi[1:-1, :-2]) / (2 * hy)
    mask = np.abs(phi[1:-1, 1:-1]) < band
    assert mask.sum() > 100, "band contains too few grid points"
    return np.hypot(gx, gy)[mask]


def area_tolerance(shape, perimeter, n=400):
    """Bound on the sampling error of ``Shape.area(n)``.

    A cell is misclassified only if the contour passes between its centre and some point of
    it, so the error is at most the area of the tube of half-width h_diag = half a cell
    diagonal around the contour: 2 * h_diag * P + pi * h_diag^2.
    """
    x0, x1, y0, y1 = shape.bbox()
    h_diag = 0.5 * math.hypot((x1 - x0) / n, (y1 - y0) / n)
    return 2 * h_diag * perimeter + math.pi * h_diag**2


def ellipse_perimeter(a, b):
    h = ((a - b) / (a + b)) ** 2
    return math.pi * (a + b) * (1 + 3 * h / (10 + math.sqrt(4 - 3 * h)))  # Ramanujan II


def rotor_area(L=1.1, w=0.4, b=0.8):
    r = b - w
    return 2 * (2 * L * 2 * w) - (2 * w) ** 2 + 2 * math.pi * w**2 + 4 * (r**2 - math.pi * r**2 / 4)


def rotor_perimeter(L=1.1, w=0.4, b=0.8):
    # 4 arms x 2 straight sides from the fillet (at b) to L, 4 semicircular ends of radius w,
    # 4 quarter-circle fillets of radius b - w
    return 8 * (L - b) + 4 * math.pi * w + 2 * math.pi * (b - w)


PRIMITIVES = {
    "disc": Disc((0.3, -0.2), 0.7),
    "ellipse": Ellipse((0.1, 0.2), (1.0, 0.5), angle=0.4),
    "ellipse_tall": Ellipse((0.0, 0.0), (0.3, 0.9)),
    "rectangle_rounded": Rectangle((0.2, 0.1), (0.8, 0.5), angle=0.3, corner_radius=0.15),
    "capsule": Capsule((-0.1, 0.2), 0.6, 0.25, angle=1.0),
    "rotor": Rotor((0.2, -0.1)),
}


# --------------------------------------------------------------------------------------------
# exact values


def test_disc_values():
    d = Disc((1.0, 2.0), 0.5)
    X = np.array([1.0, 1.5, 4.0, 1.0])
    Y = np.array([2.0, 2.0, 6.0, 2.25])
    np.testing.assert_allclose(np.asarray(d(X, Y)), [-0.5, 0.0, 4.5, -0.25], atol=1e-15)


def test_rectangle_values():
    r = Rectangle((1.0, -1.0), (2.0, 1.0))
    pts = {
        (1.0, -1.0): -1.0,  # centre: distance to the long sides
        (2.5, -1.0): -0.5,  # inside, nearer the right side
        (4.0, -1.0): 1.0,  # outside, right of the box
        (1.0, 1.0): 1.0,  # above
        (6.0, 4.0): 5.0,  # beyond the corner (3, 0): 3-4-5 triangle
        (3.0, 0.0): 0.0,  # the corner itself
    }
    X, Y = np.array([p[0] for p in pts]), np.array([p[1] for p in pts])
    np.testing.assert_allclose(np.asarray(r(X, Y)), list(pts.values()), atol=1e-14)


def test_rectangle_rotated_and_rounded_values():
    r = Rectangle((0.0, 0.0), (2.0, 1.0), angle=math.pi / 2)  # long side along y now
    np.testing.assert_allclose(float(r(0.0, 3.0)), 1.0, atol=1e-14)
    np.testing.assert_allclose(float(r(2.0, 0.0)), 1.0, atol=1e-14)
    rr = Rectangle((0.0, 0.0), (2.0, 1.0), corner_radius=0.5)
    # beyond the rounded corner: distance to the corner circle centred at (1.5, 0.5)
    np.testing.assert_allclose(float(rr(1.5 + 3.0, 0.5 + 4.0)), 5.0 - 0.5, atol=1e-14)
    # sides are unchanged by the rounding
    np.testing.assert_allclose(float(rr(0.0, 1.0)), 0.0, atol=1e-14)
    np.testing.assert_allclose(float(rr(3.0, 0.0)), 1.0, atol=1e-14)


def test_capsule_values_and_direction():
    c = Capsule((0.0, 0.0), 1.0, 0.25)  # along x
    np.testing.assert_allclose(float(c(0.0, 0.0)), -0.25, atol=1e-15)
    np.testing.assert_allclose(float(c(0.5, 1.0)), 0.75, atol=1e-15)  # over the segment
    np.testing.assert_allclose(float(c(1.25, 0.0)), 0.0, atol=1e-15)  # arm tip
    np.testing.assert_allclose(float(c(4.0, 4.0)), 5.0 - 0.25, atol=1e-14)  # beyond the end
    v = Capsule((1.0, 1.0), 1.0, 0.25, angle=math.pi / 2)  # along y
    np.testing.assert_allclose(float(v(1.0, 2.25)), 0.0, atol=1e-14)
    np.testing.assert_allclose(float(v(2.0, 1.0)), 0.75, atol=1e-14)
    assert float(v(2.0, 1.0)) > 0 > float(v(1.0, 1.9))


def test_rotor_matches_thesis_formula():
    rng = np.random.default_rng(0)
    center = (0.3, -0.2)
    rot = Rotor(center)
    pts = rng.uniform(-2.0, 2.0, size=(2000, 2)) + np.array(center)
    want = np.array([rotor_scalar(x, y, *center) for x, y in pts])
    got = np.asarray(rot(pts[:, 0], pts[:, 1]))
    np.testing.assert_allclose(got, want, atol=1e-14)


@pytest.mark.parametrize(
    "point, expected",
    [
        ((0.0, 0.0), 0.4 - 0.8 * math.sqrt(2)),  # fillet branch, centre
        ((0.8, 0.8), 0.4),  # fillet branch boundary value: the fillet centre, outside
        ((0.7, 0.7), 0.4 - 0.1 * math.sqrt(2)),  # inside the fillet square, outside the body
        ((0.5, 0.5), 0.4 - 0.3 * math.sqrt(2)),  # inside the fillet square, inside the body
        ((1.0, 0.1), -0.3),  # arm side branch
        ((0.1, -1.0), -0.3),  # arm side branch, swapped (vertical arm)
        ((1.5, 0.0), 0.0),  # arm tip, |x| = L + w
        ((-1.1, 1.0), 0.6),  # arm end branch: xx = L exactly
        ((1.4, 0.4), math.hypot(0.3, 0.4) - 0.4),  # rounded arm end
        ((0.0, -2.0), 0.5),  # far along the vertical arm
    ],
)
def test_rotor_branches(point, expected):
    x, y = point
    assert rotor_scalar(x, y) == pytest.approx(expected, abs=1e-14)
    assert float(Rotor()(x, y)) == pytest.approx(expected, abs=1e-14)


def test_rotor_reach():
    r = Rotor()
    assert r.bbox() == pytest.approx((-1.5, 1.5, -1.5, 1.5))
    for x, y in [(1.5, 0.0), (-1.5, 0.0), (0.0, 1.5), (0.0, -1.5)]:
        assert abs(float(r(x, y))) < 1e-14


def test_ellipse_zero_contour_and_distance():
    a, b, ang, c = 1.2, 0.4, 0.7, (0.3, -0.5)
    e = Ellipse(c, (a, b), angle=ang)
    # local coordinates: 256 points on the contour, then 512 random points around it
    t = np.linspace(0, 2 * np.pi, 256, endpoint=False)
    rng = np.random.default_rng(1)
    lx = np.concatenate([a * np.cos(t), rng.uniform(-2.0, 2.0, 512)])
    ly = np.concatenate([b * np.sin(t), rng.uniform(-2.0, 2.0, 512)])
    X = c[0] + np.cos(ang) * lx - np.sin(ang) * ly
    Y = c[1] + np.sin(ang) * lx + np.cos(ang) * ly
    phi = np.asarray(e(X, Y))
    np.testing.assert_allclose(phi[:256], 0.0, atol=1e-13)
    # signed distance against a brute-force closest-point search
    sign = np.where((lx / a) ** 2 + (ly / b) ** 2 < 1, -1.0, 1.0)
    want = sign * ellipse_distance_reference(a, b, lx, ly)
    np.testing.assert_allclose(phi[256:], want[256:], atol=1e-10)


def test_ellipse_circle_limit_is_a_disc():
    e = Ellipse((0.5, 0.5), (0.3, 0.3))
    d = Disc((0.5, 0.5), 0.3)
    # a 601 x 601 grid, like grad_norm_in_band: same structure and array shape, no recompile
    X, Y = np.meshgrid(np.linspace(0, 1, 601), np.linspace(0, 1, 601))
    np.testing.assert_allclose(np.asarray(e(X, Y)), np.asarray(d(X, Y)), atol=1e-13)
    assert np.all(np.isfinite(np.asarray(e(0.5, 0.5))))  # centre of the circle: no NaN


# --------------------------------------------------------------------------------------------
# distance property, area, bbox


@pytest.mark.parametrize("name", sorted(PRIMITIVES))
def test_unit_gradient_near_contour(name):
    shape = PRIMITIVES[name]
    g = grad_norm_in_band(shape, band=0.04)
    np.testing.assert_allclose(g, 1.0, atol=2e-3)


def test_unit_gradient_sharp_rectangle():
    # the distance has a kink along the diagonals that end at the sharp corners (inside) and
    # is strongly curved just outside them, so central differences are off in a few cells
    # around each corner: allow a small fraction of band points to be off
    g = grad_norm_in_band(Rectangle((0.1, 0.0), (0.7, 0.4), angle=0.2), band=0.04)
    assert np.mean(np.abs(g - 1.0) < 1e-6) > 0.97


def test_ellipse_gradient_contract_high_aspect():
    # contract: |grad phi| within a few % of 1 within 0.1*min(a, b) of the contour
    e = Ellipse((0.0, 0.0), (1.0, 0.2), angle=0.3)
    g = grad_norm_in_band(e, band=0.02)
    np.testing.assert_allclose(g, 1.0, atol=1e-2)


@pytest.mark.parametrize(
    "shape, area, perimeter",
    [
        (Disc((0.2, 0.1), 0.8), math.pi * 0.64, 2 * math.pi * 0.8),
        (Rectangle((0.0, 0.0), (1.0, 0.3)), 4 * 0.3, 4 * 1.3),
        (
            Rectangle((0.0, 0.0), (1.0, 0.5), corner_radius=0.2),
            4 * 0.5 - (4 - math.pi) * 0.04,
            4 * 1.5 - 8 * 0.2 + 2 * math.pi * 0.2,
        ),
        (
            Capsule((0.0, 0.0), 0.7, 0.3, angle=0.5),
            4 * 0.7 * 0.3 + math.pi * 0.09,
            4 * 0.7 + 0.6 * math.pi,
        ),
        (Ellipse((0.0, 0.0), (1.0, 0.4), angle=0.2), math.pi * 0.4, ellipse_perimeter(1.0, 0.4)),
        (Rotor(), rotor_area(), rotor_perimeter()),
    ],
    ids=["disc", "rectangle", "rounded_rectangle", "capsule", "ellipse", "rotor"],
)
def test_area(shape, area, perimeter):
    tol = area_tolerance(shape, perimeter)
    assert tol < 0.05 * area  # the bound itself is meaningful at n = 400
    assert shape.area() == pytest.approx(area, abs=tol)


def test_bbox_contains_shape():
    for shape in PRIMITIVES.values():
        x0, x1, y0, y1 = shape.bbox()
        x = np.linspace(x0 - 1, x1 + 1, 301)
        y = np.linspace(y0 - 1, y1 + 1, 301)
        X, Y = np.meshgrid(x, y, indexing="ij")
        inside = np.asarray(shape(X, Y)) < 0
        assert np.all((X[inside] >= x0 - 1e-12) & (X[inside] <= x1 + 1e-12))
        assert np.all((Y[inside] >= y0 - 1e-12) & (Y[inside] <= y1 + 1e-12))


# --------------------------------------------------------------------------------------------
# transforms


def test_translate_moves_zero_contour():
    d = Disc((0.0, 0.0), 0.5)
    m = d.translate(1.0, -2.0)
    assert isinstance(m, Translate)
    rng = np.random.default_rng(2)
    X, Y = rng.uniform(-1, 1, (2, 100))
    np.testing.assert_allclose(np.asarray(m(X + 1.0, Y - 2.0)), np.asarray(d(X, Y)), atol=1e-14)
    assert abs(float(m(1.5, -2.0))) < 1e-14
    assert m.bbox() == pytest.approx((0.5, 1.5, -2.5, -1.5))


def test_rotate_moves_zero_contour():
    cap = Capsule((1.0, 0.0), 0.5, 0.1)  # along x, tips at x = 0.4 and 1.6
    r = cap.rotate(math.pi / 2, about=(1.0, 1.0))
    assert isinstance(r, Rotate)
    # centre (1, 0) -> (2, 1); the segment is now along y
    assert float(r(2.0, 1.0)) == pytest.approx(-0.1, abs=1e-14)
    assert float(r(2.0, 1.6)) == pytest.approx(0.0, abs=1e-14)
    assert float(r(2.0, 0.4)) == pytest.approx(0.0, abs=1e-14)
    assert float(r(2.1, 1.0)) == pytest.approx(0.0, abs=1e-14)
    # equivalent to a capsule built with the rotated angle and centre
    direct = Capsule((2.0, 1.0), 0.5, 0.1, angle=math.pi / 2)
    X, Y = np.meshgrid(np.linspace(1, 3, 21), np.linspace(0, 2, 21))
    np.testing.assert_allclose(np.asarray(r(X, Y)), np.asarray(direct(X, Y)), atol=1e-14)
    x0, x1, y0, y1 = r.bbox()
    assert x0 <= 1.9 + 1e-12 and x1 >= 2.1 - 1e-12 and y0 <= 0.4 + 1e-12 and y1 >= 1.6 - 1e-12


def test_rotation_angle_convention_matches_primitives():
    # Rectangle(angle) and Rectangle.rotate(angle) about its centre are the same shape
    base = Rectangle((0.3, 0.2), (0.6, 0.2))
    X, Y = np.meshgrid(np.linspace(-1, 1.5, 31), np.linspace(-1, 1.5, 31))
    for ang in (0.3, -1.1, 2.5):
        a = Rectangle((0.3, 0.2), (0.6, 0.2), angle=ang)
        b = base.rotate(ang, about=(0.3, 0.2))
        np.testing.assert_allclose(np.asarray(a(X, Y)), np.asarray(b(X, Y)), atol=1e-13)


@settings(max_examples=25, deadline=None)
@given(
    angle=st.floats(-2 * math.pi, 2 * math.pi),
    about=st.tuples(st.floats(-2, 2), st.floats(-2, 2)),
    which=st.sampled_from(["ellipse", "rectangle_rounded", "capsule", "rotor"]),
)
def test_rotation_invariance(angle, about, which):
    shape = PRIMITIVES[which]
    rotated = shape.rotate(angle, about=about)
    # values are invariant: rotated shape at the rotated point == shape at the point
    # (a 200 x 200 grid, the array shape area(n=200) uses, so only one new compilation)
    X, Y = np.meshgrid(np.linspace(-2, 2, 200), np.linspace(-2, 2, 200), indexing="ij")
    c, s = math.cos(angle), math.sin(angle)
    Xr = about[0] + c * (X - about[0]) - s * (Y - about[1])
    Yr = about[1] + s * (X - about[0]) + c * (Y - about[1])
    np.testing.assert_allclose(np.asarray(rotated(Xr, Yr)), np.asarray(shape(X, Y)), atol=1e-12)
    # and so is the sampled area, up to the sampling error of both estimates (see
    # area_tolerance: sqrt(2) * P * h for each, with h the larger cell side of the two)
    a0 = shape.area(n=200)
    a1 = rotated.area(n=200)
    x0, x1, y0, y1 = rotated.bbox()
    h1 = max(x1 - x0, y1 - y0) / 200
    perimeter_bound = 12.0  # every shape in PRIMITIVES has a contour shorter than this
    assert abs(a1 - a0) < 2 * math.sqrt(2) * perimeter_bound * h1


def test_translation_invariance_of_area():
    for shape in PRIMITIVES.values():
        moved = shape.translate(3.0, -1.5)
        assert moved.area(n=200) == pytest.approx(shape.area(n=200), rel=1e-12)


# --------------------------------------------------------------------------------------------
# CSG


def test_csg_sign_logic():
    a = Disc((0.0, 0.0), 1.0)
    b = Disc((1.0, 0.0), 1.0)
    # points: only in a, in both, only in b, in neither
    X = np.array([-0.5, 0.5, 1.5, 3.0])
    Y = np.zeros(4)
    u, i, d = a | b, a & b, a - b
    assert isinstance(u, Union) and isinstance(i, Intersection) and isinstance(d, Difference)
    np.testing.assert_array_equal(np.asarray(u(X, Y)) < 0, [True, True, True, False])
    np.testing.assert_array_equal(np.asarray(i(X, Y)) < 0, [False, True, False, False])
    np.testing.assert_array_equal(np.asarray(d(X, Y)) < 0, [True, False, False, False])
    # values are min / max / max(a, -b)
    pa, pb = np.asarray(a(X, Y)), np.asarray(b(X, Y))
    np.testing.assert_allclose(np.asarray(u(X, Y)), np.minimum(pa, pb))
    np.testing.assert_allclose(np.asarray(i(X, Y)), np.maximum(pa, pb))
    np.testing.assert_allclose(np.asarray(d(X, Y)), np.maximum(pa, -pb))


def test_csg_areas_and_bbox():
    big = Rectangle((0.0, 0.0), (1.0, 1.0))
    hole = Disc((0.0, 0.0), 0.5)
    ring = big - hole
    assert ring.area() == pytest.approx(4.0 - math.pi * 0.25, abs=0.02)
    assert ring.bbox() == pytest.approx(big.bbox())
    left, right = Rectangle((-0.5, 0.0), (1.0, 0.5)), Rectangle((0.5, 0.0), (1.0, 0.5))
    assert (left & right).bbox() == pytest.approx((-0.5, 0.5, -0.5, 0.5))
    assert (left & right).area() == pytest.approx(1.0, abs=0.01)
    assert (left | right).bbox() == pytest.approx((-1.5, 1.5, -0.5, 0.5))
    assert (left | right).area() == pytest.approx(3.0, abs=0.02)
    far = Disc((10.0, 10.0), 0.5)
    assert (hole & far).area() == 0.0


def test_csg_rejects_non_shapes():
    with pytest.raises(TypeError):
        _ = Disc() | 3.0
    with pytest.raises(TypeError, match="'a'"):
        Union("disc", Disc())


# --------------------------------------------------------------------------------------------
# arrays, jit, hashing


def test_accepts_numpy_and_jax_arrays_of_any_shape():
    shape = Rotor() | Capsule((1.0, 1.0), 0.5, 0.2)
    for dims in [(), (7,), (5, 6), (2, 3, 4)]:
        X = np.linspace(-2, 2, int(np.prod(dims))).reshape(dims)
        Y = X[::-1] if X.ndim else X
        out_np = shape(X, Y)
        out_jx = shape(jnp.asarray(X), jnp.asarray(Y))
        assert out_np.shape == dims and out_jx.shape == dims
        assert out_np.dtype == jnp.float64
        np.testing.assert_array_equal(np.asarray(out_np), np.asarray(out_jx))
    assert shape(np.array([0, 1]), np.array([0, 0])).dtype == jnp.float64  # ints promoted


def all_example_shapes():
    prims = list(PRIMITIVES.values()) + [Rectangle((0.0, 0.0), (0.5, 0.3))]
    nested = ((prims[0] | prims[1]) & prims[2]) - prims[3].rotate(0.5, (0.1, 0.2))
    return prims + [
        Capsule((0.1, 0.0), 0.5, 0.2),
        nested.translate(0.3, -0.4),
        Rotor() - Disc(radius=0.2),
    ]


def _walk(d):
    yield d
    for v in d.values():
        if isinstance(v, dict):
            yield from _walk(v)


def test_jit_compatible():
    X, Y = np.meshgrid(np.linspace(-2, 2, 64), np.linspace(-2, 2, 48))
    shapes = all_example_shapes()[-3:]  # capsule, nested CSG of the others, rotor - disc
    assert {d["type"] for s in shapes for d in _walk(s.to_dict())} == set(SHAPES)
    for shape in shapes:
        f = jax.jit(lambda X, Y, shape=shape: shape(X, Y))  # shape captured by closure
        out = f(jnp.asarray(X), jnp.asarray(Y))
        assert out.shape == X.shape
        np.testing.assert_allclose(np.asarray(out), np.asarray(shape(X, Y)), rtol=1e-13, atol=1e-13)


def test_shapes_are_hashable_static_args():
    shapes = all_example_shapes()
    assert len({hash(s) for s in shapes}) == len(shapes)
    assert Disc((0, 0), 1) == Disc((0.0, 0.0), 1.0)
    assert hash(Disc([0, 0], 1)) == hash(Disc((0.0, 0.0), 1.0))  # lists normalised to tuples

    f = jax.jit(lambda X, Y, shape: shape(X, Y), static_argnums=2)
    np.testing.assert_allclose(float(f(0.0, 0.0, Disc(radius=2.0))), -2.0)


# --------------------------------------------------------------------------------------------
# serialisation


def test_round_trip_every_type():
    seen = set()
    for shape in all_example_shapes():
        d = shape.to_dict()
        assert shape_from_dict(json.loads(json.dumps(d))) == shape
        seen |= {sub["type"] for sub in _walk(d)}
    assert seen == set(SHAPES)


def test_from_dict_defaults_and_errors():
    assert shape_from_dict({"type": "Rotor"}) == Rotor()
    assert shape_from_dict({"type": "Disc", "radius": 2}) == Disc((0.0, 0.0), 2.0)
    with pytest.raises(ValueError, match="Blob"):
        shape_from_dict({"type": "Blob", "radius": 1.0})
    with pytest.raises(ValueError, match="radiu"):
        shape_from_dict({"type": "Disc", "radiu": 1.0})
    with pytest.raises(ValueError, match="type"):
        shape_from_dict({"radius": 1.0})
    with pytest.raises(ValueError, match="semi_axes"):
        shape_from_dict({"type": "Ellipse", "center": [0, 0]})
    with pytest.raises(ValueError, match="radius"):
        shape_from_dict({"type": "Disc", "radius": -1.0})
    with pytest.raises(ValueError, match="Blob"):  # nested unknown type
        shape_from_dict({"type": "Union", "a": {"type": "Disc"}, "b": {"type": "Blob"}})


finite = st.floats(-5, 5, allow_nan=False)
pos = st.floats(0.05, 3.0)
points = st.tuples(finite, finite)

primitive_st = st.one_of(
    st.builds(Disc, points, pos),
    st.builds(Ellipse, points, st.tuples(pos, pos), finite),
    st.builds(
        lambda c, h, a, f: Rectangle(c, h, a, f * min(h)),
        points,
        st.tuples(pos, pos),
        finite,
        st.floats(0, 1),
    ),
    st.builds(Capsule, points, st.floats(0, 3), pos, finite),
    st.builds(
        lambda c, w, f1, f2: Rotor(c, w * (1 + f1) * (1 + f2), w, w * (1 + f1)),
        points,
        pos,
        st.floats(0.05, 2),
        st.floats(0.05, 2),
    ),
)
shape_st = st.recursive(
    primitive_st,
    lambda kids: st.one_of(
        st.builds(Union, kids, kids),
        st.builds(Intersection, kids, kids),
        st.builds(Difference, kids, kids),
        st.builds(Translate, kids, points),
        st.builds(Rotate, kids, finite, points),
    ),
    max_leaves=6,
)


@settings(max_examples=25, deadline=None)
@given(shape_st)
def test_round_trip_property(shape):
    d = shape.to_dict()
    back = shape_from_dict(json.loads(json.dumps(d)))
    assert back == shape  # equal fields, hence the same function
    assert hash(back) == hash(shape)
    assert back.to_dict() == d


# --------------------------------------------------------------------------------------------
# parameter validation


@pytest.mark.parametrize(
    "make, name",
    [
        (lambda: Disc((0, 0), 0.0), "radius"),
        (lambda: Disc((0, 0), -1.0), "radius"),
        (lambda: Disc((0, 0, 0), 1.0), "center"),
        (lambda: Disc((0, float("nan")), 1.0), "center"),
        (lambda: Ellipse((0, 0), (1.0, 0.0)), "semi_axes"),
        (lambda: Ellipse((0, 0), 1.0), "semi_axes"),
        (lambda: Rectangle((0, 0), (-1.0, 1.0)), "half_size"),
        (lambda: Rectangle((0, 0), (1.0, 1.0), corner_radius=-0.1), "corner_radius"),
        (lambda: Rectangle((0, 0), (1.0, 0.5), corner_radius=0.6), "corner_radius"),
        (lambda: Rectangle((0, 0), (1.0, 0.5), angle="x"), "angle"),
        (lambda: Capsule((0, 0), -0.5, 0.1), "half_length"),
        (lambda: Capsule((0, 0), 0.5, 0.0), "radius"),
        (lambda: Rotor(arm_half_length=-1.0), "arm_half_length"),
        (lambda: Rotor(half_width=0.0), "half_width"),
        (lambda: Rotor(fillet_center=0.3), "fillet_center"),  # <= half_width
        (lambda: Rotor(fillet_center=1.2), "fillet_center"),  # >= arm_half_length
        (lambda: Translate(Disc(), (1.0,)), "offset"),
        (lambda: Rotate(Disc(), 0.1, about=(0.0, float("inf"))), "about"),
    ],
)
def test_bad_parameters_name_the_parameter(make, name):
    with pytest.raises(ValueError, match=f"'{name}'") as info:
        make()
    assert name in str(info.value)


def test_error_message_shows_value():
    with pytest.raises(ValueError, match=r"radius=-2\.0"):
        Disc((0, 0), -2.0)
    with pytest.raises(ValueError, match="Capsule"):
        Capsule((0, 0), 1.0, -0.1)


def test_area_rejects_bad_n():
    with pytest.raises(ValueError, match="'n'"):
        Disc().area(n=0)


def test_registry_lists_builtin_types():
    assert issubclass(Disc, Shape)
    assert set(SHAPES) == {
        "Disc",
        "Ellipse",
        "Rectangle",
        "Capsule",
        "Rotor",
        "Union",
        "Intersection",
        "Difference",
        "Translate",
        "Rotate",
    }


def test_same_structure_different_numbers_give_different_values():
    # shapes that differ only in their numbers share a compilation: the numbers must not leak
    X = np.array([0.0, 0.5, 2.0])
    Y = np.zeros(3)
    for r in (0.25, 1.0, 1.5):
        np.testing.assert_allclose(np.asarray(Disc((0.0, 0.0), r)(X, Y)), X - r)
    e1, e2 = Ellipse((0, 0), (1.0, 0.5)), Ellipse((0, 0), (0.5, 1.0))
    assert float(e1(0.0, 0.75)) == pytest.approx(0.25)
    assert float(e2(0.0, 0.75)) == pytest.approx(-0.25)


def test_float32_inputs_stay_float32():
    out = Rotor()(np.zeros(4, np.float32), np.ones(4, np.float32))
    assert out.dtype == jnp.float32


def test_user_defined_shapes():
    @register_shape
    class Annulus(Shape):
        center: tuple[float, float]
        inner: float
        outer: float

        def _sdf(self, X, Y):
            r = jnp.hypot(X - self.center[0], Y - self.center[1])
            return jnp.maximum(r - self.outer, self.inner - r)

        def bbox(self):
            (cx, cy), R = self.center, self.outer
            return (cx - R, cx + R, cy - R, cy + R)

    class HalfPlane(Shape):  # not a dataclass: evaluated directly, not serialisable
        def __call__(self, X, Y):
            return jnp.asarray(X, dtype=float) - 1.0

        def bbox(self):
            return (-10.0, 1.0, -10.0, 10.0)

    try:
        ring = Annulus((0.0, 0.0), 0.5, 1.0)
        assert float(ring(0.75, 0.0)) == pytest.approx(-0.25)
        assert shape_from_dict(ring.to_dict()) == ring
        combo = ring & HalfPlane()
        np.testing.assert_allclose(
            np.asarray(combo(np.array([0.0, 0.9]), np.zeros(2))), [0.5, -0.1]
        )
        with pytest.raises(TypeError, match="register_shape"):
            combo.to_dict()
    finally:
        SHAPES.pop("Annulus", None)
