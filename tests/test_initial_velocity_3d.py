"""The initial velocity on a 3D grid (issue 12): callables f(x, y, z) -> (u, v, w), arrays
(3, nx, ny, nz), formulas u, v, w in x, y and z, .npy / .h5 files, checked against the
node values; z and w refused in 2D; errors that name the shape the grid's dimension needs."""

from __future__ import annotations

import copy
import pickle

import h5py
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap.boundary import Boundary
from refmap.case import Case, CaseError
from refmap.geometry import Disc, Sphere
from refmap.grid import Grid, Grid3D
from refmap.initial import (
    InitialVelocityError,
    VelocityArray,
    VelocityExpression,
    VelocityFile,
    as_initial_velocity,
    parse_expression,
)
from refmap.materials import NeoHookean
from refmap.model import Solid

#: a rigid rotation about an oblique axis, omega x r: every component uses all three axes
W = (0.3, -0.2, 0.5)


def _rotation(x, y, z):
    return W[1] * z - W[2] * y, W[2] * x - W[0] * z, W[0] * y - W[1] * x


def _grid():
    return Grid3D(10, 8, 12, -1.0, 1.0, -0.8, 0.8, -1.2, 1.2)


def _case(initial_velocity=None, solids=()):
    return Case(name="spin3", grid=_grid(), solids=solids,
                boundary=Boundary(back="wall", front="wall"), initial_velocity=initial_velocity)


def _expected():
    return np.stack(_rotation(*_grid().mesh("node")))


FORMULAS = {"u": f"{W[1]} * z - {W[2]} * y", "v": f"{W[2]} * x - {W[0]} * z",
            "w": f"{W[0]} * y - {W[1]} * x"}


# ------------------------------------------------------------------------ the node values


@pytest.mark.parametrize("form", ["callable", "jax callable", "array", "jax array", "formula",
                                  "expression"])
def test_every_form_gives_the_exact_node_values(form):
    """The field is sampled on the nodes (x_i = ax + (i + 1/2) dx, ...), components first,
    indexed [c, i, j, k]: the same float64 products as the reference, bit for bit."""
    want = _expected()
    given = {
        "callable": _rotation,
        "jax callable": lambda x, y, z: tuple(jnp.asarray(c) for c in _rotation(x, y, z)),
        "array": want.copy(),
        "jax array": jnp.asarray(want),
        "formula": dict(FORMULAS),
        "expression": VelocityExpression(FORMULAS["u"], FORMULAS["v"], FORMULAS["w"]),
    }[form]
    case = _case(given)
    got = case.validate().initial_velocity_field()
    assert got.shape == (3, 10, 8, 12) and got.dtype == np.float64
    assert np.array_equal(got, want)


def test_callable_may_return_one_array_and_broadcast_scalars():
    X, Y, Z = _grid().mesh("node")
    whole = _case(lambda x, y, z: np.stack([x, y, z])).initial_velocity_field()
    assert np.array_equal(whole, np.stack([X, Y, Z]))
    uniform = _case(lambda x, y, z: (1.0, 0.0, -2.0)).initial_velocity_field()
    assert np.all(uniform[0] == 1.0) and np.all(uniform[1] == 0.0) and np.all(uniform[2] == -2.0)


def test_left_out_formulas_are_zero_and_z_is_a_variable():
    case = _case({"w": "sin(pi * z) * x"})
    X, _, Z = case.grid.mesh("node")
    got = case.initial_velocity_field()
    assert np.all(got[0] == 0.0) and np.all(got[1] == 0.0)
    assert np.array_equal(got[2], np.sin(np.pi * Z) * X)
    # a dict without w on a 3D grid is 3D too: w = "0"
    only_u = _case({"u": "z"}).initial_velocity
    assert only_u == VelocityExpression("z", "0", "0") and only_u.dim == 3
    assert VelocityExpression("z", dim=3).to_dict() == {"u": "z", "v": "0", "w": "0"}


@pytest.mark.parametrize("ext", ["npy", "h5"])
def test_velocity_from_a_file(tmp_path, ext):
    want = _expected() + 0.1 * np.cos(_grid().mesh("node")[2])
    if ext == "npy":
        np.save(tmp_path / "v0.npy", want)
        given = {"file": str(tmp_path / "v0.npy")}
    else:
        with h5py.File(tmp_path / "v0.h5", "w") as f:
            f["other"] = np.zeros(2)
            f["fields/v0"] = want
        given = {"file": str(tmp_path / "v0.h5"), "dataset": "fields/v0"}
    case = _case(given)
    assert isinstance(case.initial_velocity, VelocityFile)
    assert np.array_equal(case.initial_velocity_field(), want)
    # the same file on another grid is refused, naming both shapes
    with pytest.raises(CaseError) as e:
        case.replace(grid=Grid3D(10, 8, 10, -1.0, 1.0, -0.8, 0.8, -1.2, 1.2)).validate()
    assert "initial_velocity.file" in str(e.value)
    assert "(3, 10, 8, 12)" in str(e.value) and "(3, nx, ny, nz) = (3, 10, 8, 10)" in str(e.value)


def test_model_starts_from_the_field_with_the_solid_velocity_added():
    """Model.initial_state: v = v0 + (1 - H) V, here V = 0 (the field alone) and V != 0."""
    law = NeoHookean(G=1.0, kappa=10.0, dim=3)
    ball = Solid(shape=Sphere((0.1, 0.0, -0.1), 0.5), law=law, name="ball")
    case = _case(dict(FORMULAS), (ball,))
    model, params = case.build()
    v = np.asarray(model.initial_state(params).v)
    assert v.shape == (3, 10, 8, 12) and np.array_equal(v, _expected())


# ------------------------------------------------------------------------ bad input


@pytest.mark.parametrize(
    "given, words",
    [
        (np.zeros((2, 10, 8)), ["shape (2, 10, 8)", "(3, nx, ny, nz)", "3D grid"]),
        (np.zeros((3, 10, 8, 11)), ["shape (3, 10, 8, 11)", "(3, nx, ny, nz) = (3, 10, 8, 12)"]),
        (lambda x, y: (x, y), ["f(x, y, z)", "TypeError"]),
        (lambda x, y, z: (x, y), ["must return (u, v, w)", "2 items"]),
        (lambda x, y, z: np.zeros((2, 10, 8, 12)),
         ["shape (2, 10, 8, 12)", "(3, nx, ny, nz) = (3, 10, 8, 12)"]),
        (lambda x, y, z: (x, y, np.log(z)),
         ["initial_velocity.w", "not finite", "(x, y, z) = (", "node [0, 0, 0]", "nan"]),
        ({"u": "1", "w": "t"}, ["initial_velocity.w", "'t' is not allowed", "x, y, z"]),
        ({"u": "1", "q": "2"}, ["'w': FORMULA", "['q', 'u']"]),
        ("x", ["f(x, y, z) -> (u, v, w)", "(3, nx, ny, nz)"]),
        (VelocityExpression("-y", "x"), ["2D grid but the grid is 3D", "give w"]),
    ],
)
def test_bad_3d_initial_velocity_names_the_3d_shape(given, words):
    with pytest.raises(CaseError) as e:
        _case(given).validate()
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def _case_2d(initial_velocity):
    return Case(name="flat", grid=Grid(16, 16), initial_velocity=initial_velocity)


@pytest.mark.parametrize(
    "given, words",
    [
        ({"u": "z * 2"}, ["initial_velocity.u", "name 'z' is not allowed on a 2D grid", "'z * 2'"]),
        ({"u": "1", "w": "0"}, ["initial_velocity.w", "a w formula is for a 3D grid", "'0'"]),
        (VelocityExpression("0", "0", "y"), ["3D grid but the grid is 2D"]),
        (np.zeros((3, 16, 16, 16)), ["shape (3, 16, 16, 16)", "(2, nx, ny)"]),
        (lambda x, y: (x, y, x), ["must return (u, v)", "3 items"]),
    ],
)
def test_z_and_w_are_refused_in_2d(given, words):
    with pytest.raises(CaseError) as e:
        _case_2d(given).validate()
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def test_the_evaluator_takes_z_in_3d_only():
    x, y, z = np.meshgrid(np.linspace(-1, 1, 5), np.linspace(-0.9, 1.1, 4), np.linspace(0.1, 2, 3),
                          indexing="ij")
    f = parse_expression("where(z > 1, hypot(x, z), -y * z) + atan2(z, x) + z ** 2 % 0.7", dim=3)
    want = np.where(z > 1, np.hypot(x, z), -y * z) + np.arctan2(z, x) + z**2 % 0.7
    assert np.array_equal(f(x, y, z), want)
    assert parse_expression("1.5", dim=3)(x, y, z).shape == x.shape
    with pytest.raises(ValueError, match="name 'z' is not allowed on a 2D grid"):
        parse_expression("x + z")
    with pytest.raises(ValueError, match="name 't' is not allowed; use x, y, z, numbers"):
        parse_expression("t", dim=3)
    with pytest.raises(ValueError, match="must be a formula in x, y and z"):
        parse_expression(None, dim=3)
    with pytest.raises(ValueError, match="dim must be 2 or 3"):
        parse_expression("x", dim=4)


def test_expression_objects_in_3d():
    f = VelocityExpression("-y", "x", "z * 2")
    assert f.dim == 3 and f.w == "z * 2"
    u, v, w = f(np.array([1.0]), np.array([2.0]), np.array([3.0]))
    assert (u[0], v[0], w[0]) == (-2.0, 1.0, 6.0)
    assert f.to_dict() == {"u": "-y", "v": "x", "w": "z * 2"}
    assert VelocityExpression("-y", "x").to_dict() == {"u": "-y", "v": "x"}  # 2D unchanged
    assert f != VelocityExpression("-y", "x") and f == VelocityExpression("-y", "x", "z * 2", 3)
    assert hash(f) == hash(VelocityExpression("-y", "x", "z * 2"))
    with pytest.raises(TypeError, match="takes 3 coordinate arrays"):
        f(np.zeros(2), np.zeros(2))
    with pytest.raises(InitialVelocityError) as e:
        VelocityExpression("z", "0", dim=2)
    assert e.value.key == "u"


def test_fields_pickle_copy_and_describe_themselves(tmp_path):
    np.save(tmp_path / "v0.npy", _expected())
    for given in (dict(FORMULAS), {"file": str(tmp_path / "v0.npy")}, _expected()):
        case = _case(given)
        for back in (pickle.loads(pickle.dumps(case)), copy.deepcopy(case)):
            assert back == case
            assert np.array_equal(back.initial_velocity_field(), case.initial_velocity_field())
    assert _case(dict(FORMULAS)).to_dict()["initial_velocity"] == FORMULAS
    arr = _case(_expected()).to_dict()["initial_velocity"]
    assert arr["array"] == [3, 10, 8, 12] and len(arr["sha1"]) == 40


def test_as_initial_velocity_without_a_dimension_accepts_either_form():
    assert VelocityArray(np.zeros((3, 8, 8, 8))).values.shape == (3, 8, 8, 8)
    assert VelocityArray(np.zeros((2, 8, 8))).values.shape == (2, 8, 8)
    with pytest.raises(InitialVelocityError, match=r"\(2, nx, ny\) or \(3, nx, ny, nz\)"):
        VelocityArray(np.zeros((3, 8, 8)))
    assert as_initial_velocity({"u": "1", "v": "0", "w": "z"}).dim == 3  # w makes it 3D
    assert as_initial_velocity({"u": "1"}).dim == 2
    with pytest.raises(InitialVelocityError, match="dim must be 2 or 3"):
        as_initial_velocity({"u": "1"}, dim=1)


def test_a_2d_case_is_unchanged():
    """Disc, 2D formulas: the 2D forms, dimension and description as before."""
    case = Case(name="spin", grid=Grid(16, 16),
                solids=(Solid(shape=Disc((0.0, 0.0), 1.0), law=NeoHookean(G=1.0, kappa=10.0)),),
                initial_velocity={"u": "-y", "v": "x"})
    assert case.initial_velocity.dim == 2 and case.initial_velocity_field().shape == (2, 16, 16)
    assert case.to_dict()["initial_velocity"] == {"u": "-y", "v": "x"}
