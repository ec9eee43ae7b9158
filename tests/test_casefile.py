"""Case files (TOML): round trips of the built-in scenarios, named errors for malformed
input (listed and random), shapes from data, the example files."""

from __future__ import annotations

import copy
import math
import tomllib
from pathlib import Path

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import refmap  # noqa: F401  (float64)
from refmap.case import CaseError, CaseWarning
from refmap.casefile import (
    ArrayShape,
    CaseFileError,
    build_shape,
    case_from_dict,
    case_to_toml,
    dump_case,
    load_case,
    load_run,
    show_scenario,
    to_toml,
)
from refmap.geometry import SHAPES, Disc

ROOT = Path(__file__).resolve().parents[1]

# A small case touching every section: two solids (CSG shape with a region anchor; a
# pre-strained rotor on a pivot, with an svk law from E and nu), segments, contact.
BASE_TOML = """
name = "base"
gravity = [0.0, -0.5]

[grid]
n = 32

[time]
t_end = 0.5
frames = 2

[fluid]
eta = 0.1

[numerics]
cfl = 0.4

[output]
picture_field = "pressure"

[boundary]
left = [{kind = "velocity", end = 0.5, velocity = [0.2, 0.0], ramp = 0.5}, {kind = "slip", start = 0.5}]
right = "outflow"
bottom = "slip"
top = "wall"

[contact]
strength = 1.0

[[solids]]
name = "bar"
law = {law = "neo_hookean", G = 10, kappa = 10, rho0 = 1}

[solids.shape]
type = "Union"
a = {type = "Rectangle", center = [-0.8, 0.0], half_size = [0.6, 0.2]}
b = {type = "Disc", center = [-0.8, 0.5], radius = 0.35}

[solids.anchor]
type = "region"
region = {type = "Disc", center = [-0.8, 0.0], radius = 0.2}

[[solids]]
name = "wheel"
law = {law = "svk", E = 20, nu = 0.3}
strain = [[1.1, 0.0], [0.0, 0.9090909090909091]]
strain_center = [0.9, 0.0]
velocity = [0.0, 0.1]

[solids.shape]
type = "Rotor"
center = [0.9, 0.0]
arm_half_length = 0.7
half_width = 0.2
fillet_center = 0.4

[solids.anchor]
type = "pivot"
center = [0.9, 0.0]
fit_radius = 0.4
hold_radius = 0.3
"""
BASE = tomllib.loads(BASE_TOML)


def _scenarios():
    """The scenario registry with the contact scenarios registered too.

    Called inside tests only: importing ``refmap.scenarios_fssi`` at collection time would
    add its scenarios to the parametrisations of other test modules."""
    from refmap import scenarios

    try:
        import refmap.scenarios_fssi  # noqa: F401  (registers the contact scenarios)
    except ImportError:
        pass
    return scenarios


def _collected_scenarios():
    from refmap.scenarios import SCENARIOS

    return sorted(SCENARIOS)


def test_base_case_loads_with_every_section():
    plan = case_from_dict(BASE)
    case = plan.case
    assert case.name == "base" and case.grid.nx == case.grid.ny == 32
    assert case.gravity == (0.0, -0.5) and case.t_end == 0.5 and case.frames == 2
    assert case.fluid.eta == 0.1 and case.numerics.cfl == 0.4
    assert [s.name for s in case.solids] == ["bar", "wheel"]
    assert type(case.solids[1].law).__name__ == "StVenantKirchhoff"
    assert case.boundary.left[0].kind == "velocity" and case.boundary.right[0].kind == "outflow"
    assert getattr(case, "contact", None) is not None
    again = case_from_dict(tomllib.loads(case_to_toml(case))).case
    assert again.to_dict() == case.to_dict()


def test_contact_table_round_trips_and_reaches_the_model():
    """[contact] gives Case.contact (every key, defaults for the ones left out), writes back
    to an equal table, and Case.build() hands it to the model as its body force; without
    the table the case has no contact and its file no [contact] table."""
    from refmap.contact import Contact

    d = copy.deepcopy(BASE)
    d["contact"] = {"width": 2.5, "reach": 1.5, "cutoff": 0.0, "strength": 0.5, "walls": False}
    case = case_from_dict(d).case
    assert case.contact == Contact(width=2.5, reach=1.5, cutoff=0.0, strength=0.5, walls=False)
    text = case_to_toml(case)
    assert "[contact]" in text and "walls = false" in text
    back = case_from_dict(tomllib.loads(text)).case
    assert back == case and back.to_dict()["contact"] == case.contact.to_dict()
    model, _ = back.build()
    assert model.body_forces == (case.contact,)
    d["contact"] = {"strength": 2.0}
    assert case_from_dict(d).case.contact == Contact(strength=2.0)
    del d["contact"]
    case = case_from_dict(d).case
    assert case.contact is None and "contact" not in case.to_dict()
    assert "[contact]" not in case_to_toml(case)
    assert case.build()[0].body_forces == ()


# --------------------------------------------------------------------------------------------
# round trips


def _check_round_trip(name, tmp_path):
    sc = _scenarios()
    for n in (None, 40):
        case = sc.get_case(name, n)  # n None: the scenario's own default, as `refmap show`
        text = show_scenario(name, n)
        assert text.startswith("# refmap case file")
        back = case_from_dict(tomllib.loads(text)).case
        assert back.to_dict() == case.to_dict()  # floats compared exactly
        assert back == case
        assert type(back) is type(case)
        path = dump_case(case, tmp_path / f"{name}_{n}.toml")
        assert load_case(path).to_dict() == case.to_dict()


@pytest.mark.parametrize("name", _collected_scenarios())
def test_every_scenario_round_trips_through_toml(name, tmp_path):
    _check_round_trip(name, tmp_path)


def test_every_scenario_registered_at_run_time_round_trips(tmp_path):
    """Also the contact scenarios of refmap.scenarios_fssi (registered on import)."""
    names = sorted(_scenarios().SCENARIOS)
    assert {"circle", "stick", "rotor"} <= set(names)
    for name in names:
        _check_round_trip(name, tmp_path)


def test_round_trip_gives_the_same_state_after_steps():
    case = _scenarios().get_case("circle", 32)
    back = case_from_dict(tomllib.loads(show_scenario("circle", 32))).case
    states = []
    for c in (case, back):
        model, params = c.build()
        s = model.run_steps(model.initial_state(params), params, 5)
        states.append(jax.device_get(s))
    a, b = states
    assert int(a.step) == 5
    for f in ("t", "v", "rho_f", "xi", "phi"):
        assert np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f))), f


# --------------------------------------------------------------------------------------------
# named errors


def _set(path, value):
    def mut(d):
        node = d
        for p in path[:-1]:
            node = node[p]
        node[path[-1]] = value

    return mut


def _rename(path, new):
    def mut(d):
        node = d
        for p in path[:-1]:
            node = node[p]
        node[new] = node.pop(path[-1])

    return mut


def _delete(path):
    def mut(d):
        node = d
        for p in path[:-1]:
            node = node[p]
        del node[path[-1]]

    return mut


MALFORMED = [
    (_set(("solids", 0, "law", "G"), -3), "solids[0].law.G: must be > 0 (got -3)"),
    (_rename(("grid",), "grd"), "unknown key 'grd' (did you mean 'grid'?)"),
    (_set(("boundary", "right"), "periodic"), "boundary.left: inflow segment on a periodic edge"),
    (
        _set(("solids", 1, "shape", "center"), [-0.5, 0.0]),
        "solids[0] and solids[1] overlap at t = 0",
    ),
    (
        _set(("solids", 0, "shape"), {"type": "Disc", "center": [5.0, 5.0], "radius": 0.5}),
        "solids[0].shape: outside the domain",
    ),
    (  # reaching the inflow segment of the left edge (the same rule as Case.validate's)
        _set(("solids", 0, "shape", "b", "center"), [-1.8, -0.5]),
        "solids[0] ('bar'): the shape reaches the left edge where it is a 'velocity' segment",
    ),
    (_set(("solids", 1, "law", "nu"), 0.7), "solids[1].law.nu: must lie in (-1, 0.5) (got 0.7)"),
    (
        _set(("solids", 0, "law", "law"), "neohookean"),
        "solids[0].law.law: unknown material law 'neohookean' (did you mean 'neo_hookean'?)",
    ),
    (_delete(("solids", 0, "law", "kappa")), "solids[0].law: missing required key 'kappa'"),
    (_set(("solids", 0, "law", "G"), "ten"), "solids[0].law.G: must be a number (got 'ten')"),
    (_set(("grid", "n"), 32.5), "grid.n: must be an integer (got 32.5)"),
    (_set(("grid", "n"), 4), "grid.n: must be >= 8 (got 4)"),
    (_set(("grid", "nx"), 32), "grid.nx: give either n or nx and ny, not both"),
    (_set(("grid", "bx"), -3.0), "grid.bx: must be > ax = -2.0 (got -3.0)"),
    (_set(("time", "t_end"), -1), "time.t_end: must be > 0 (got -1)"),
    (_set(("time", "frames"), 0), "time.frames: must be >= 1 (got 0)"),
    (_set(("numerics", "cfl"), 3), "numerics.cfl: must be <= 1 (got 3)"),
    (_set(("numerics", "stress_band"), 9.0), "numerics.stress_band:"),
    (_set(("numerics", "blend"), "gauss"), "numerics.blend"),
    (_set(("numerics", "smooth_check_every"), 0), "numerics.smooth_check_every: must be >= 1 (got 0)"),
    (_set(("numerics", "smooth_check_every"), 2.5), "numerics.smooth_check_every: must be an integer (got 2.5)"),
    (_set(("fluid", "rho0"), 0), "fluid.rho0: must be > 0 (got 0)"),
    (_set(("fluid", "eta"), math.nan), "fluid.eta: must be a finite number (got nan)"),
    (_rename(("fluid", "eta"), "etta"), "fluid: unknown key 'etta' (did you mean 'eta'?)"),
    (_set(("gravity",), [0.0, "down"]), "gravity[1]: must be a number (got 'down')"),
    (_set(("output", "picture_field"), "presure"), "output.picture_field: must be one of"),
    (
        _rename(("solids", 0, "shape", "b", "radius"), "radus"),
        "solids[0].shape.b: unknown key 'radus' for shape type 'Disc' (did you mean 'radius'?)",
    ),
    (
        _set(("solids", 0, "shape", "b", "radius"), -0.1),
        "solids[0].shape.b.radius: must be positive (got -0.1)",
    ),
    (
        _set(("solids", 0, "shape", "a", "type"), "Rectangel"),
        "solids[0].shape.a.type: unknown shape type 'Rectangel' (did you mean 'Rectangle'?)",
    ),
    (_delete(("solids", 0, "shape", "type")), "solids[0].shape: missing required key 'type'"),
    (
        _rename(("solids", 0, "shape"), "shap"),
        "solids[0]: unknown key 'shap' (did you mean 'shape'?)",
    ),
    (
        _set(("solids", 0, "strain"), [[1.0, 0.0], [0.0, -1.0]]),
        "solids[0].strain: must have a positive",
    ),
    (_set(("solids", 0, "strain"), [[1.0, 0.0], [0.0]]), "solids[0].strain[1]: too few entries"),
    (
        _set(("solids", 1, "anchor", "fit_radius"), 0.01),
        "solids[1].anchor.fit_radius: holds no grid node",
    ),
    (
        _set(("solids", 1, "anchor", "type"), "pin"),
        "solids[1].anchor.type: must be one of 'region' or 'pivot' (got 'pin')",
    ),
    (_delete(("solids", 0, "anchor", "region")), "solids[0].anchor: missing required key 'region'"),
    (_set(("boundary", "bottom"), "slp"), "boundary.bottom: must be one of"),
    (
        _set(("boundary", "left", 1, "start"), 0.6),
        "boundary.left: segments must tile [0, 1] without gaps or overlaps",
    ),
    (
        _set(("boundary", "left", 0, "kind"), "periodic"),
        "boundary.left[0].kind: 'periodic' applies to a whole edge",
    ),
    (_set(("boundary", "left", 0, "end"), 1.5), "boundary.left[0].end: must be <= 1 (got 1.5)"),
    (_set(("contact", "cutoff"), 1.5), "contact.cutoff: must be < 1 (got 1.5)"),
    (_set(("contact", "cutoff"), -0.1), "contact.cutoff: must be >= 0 (got -0.1)"),
    (_set(("contact", "width"), 0.0), "contact.width: must be > 0 (got 0.0)"),
    (_set(("contact", "reach"), float("inf")), "contact.reach: must be a finite number (got inf)"),
    (_set(("contact", "strength"), True), "contact.strength: must be a number (got true)"),
    (_set(("contact", "walls"), "yes"), "contact.walls: must be true or false (got 'yes')"),
    (
        _rename(("contact", "strength"), "strenght"),
        "contact: unknown key 'strenght' (did you mean 'strength'?)",
    ),
    (_set(("contact",), 3), "contact: must be a table (got 3)"),
    (_set(("solids",), {"name": "x"}), "solids: must be a list"),
    (_set(("grid",), 5), "grid: must be a table (got 5)"),
]


@pytest.mark.parametrize("mutate,expected", MALFORMED, ids=[m[1][:40] for m in MALFORMED])
def test_malformed_case_gives_one_named_error(mutate, expected):
    d = copy.deepcopy(BASE)
    mutate(d)
    with pytest.raises(CaseError) as err:
        case_from_dict(d)
    msg = str(err.value)
    assert expected in msg.splitlines()[0], msg
    assert isinstance(err.value, CaseFileError)


def test_case_file_accepts_what_case_validate_accepts():
    """A solid reaching past a wall is accepted from a case file as from Python (it is
    glued to the resting wall); the case files used to refuse any solid within two node
    rows of a non-periodic edge, a stricter rule than Case.validate's."""
    d = copy.deepcopy(BASE)
    d["solids"][0]["shape"]["b"]["center"] = [-0.8, 1.8]  # through the top wall
    with pytest.warns(CaseWarning):  # (the base case's gravity warning)
        case = case_from_dict(d).case
    with pytest.warns(CaseWarning):
        case.validate()  # the Python rule agrees (no error)
    model, params = case.build()
    state = model.initial_state(params)
    out = jax.jit(lambda s: model.run_steps(s, params, 20))(state)
    assert all(bool(np.all(np.isfinite(np.asarray(getattr(out, f))))) for f in ("v", "xi", "phi"))


def test_several_problems_are_one_error_listing_each():
    d = copy.deepcopy(BASE)
    d["solids"][0]["law"]["G"] = -3
    d["time"]["t_end"] = "soon"
    with pytest.raises(CaseFileError) as err:
        case_from_dict(d)
    msg = str(err.value)
    assert "time.t_end: must be a number (got 'soon')" in msg
    assert "solids[0].law.G: must be > 0 (got -3)" in msg


def test_file_errors_and_overrides(tmp_path):
    with pytest.raises(CaseFileError, match="no case file"):
        load_case(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'x'\n[grid\nn = 3\n")
    with pytest.raises(CaseFileError, match="not valid TOML"):
        load_case(bad)
    good = tmp_path / "good.toml"
    good.write_text(BASE_TOML.replace("[output]", '[output]\nout = "results"'))
    plan = load_run(good)
    assert plan.out == tmp_path / "results" and plan.case.name == "base"
    plan = load_run(
        good,
        {
            "n": 40,
            "t_end": 0.25,
            "frames": 5,
            "cfl": 0.3,
            "out": "elsewhere",
            "movie": True,
            "fluid.eta": 0.05,
            "frames_unused": None,
        },
    )
    c = plan.case
    assert (c.grid.nx, c.grid.ny, c.t_end, c.frames, c.numerics.cfl, c.fluid.eta) == (
        40,
        40,
        0.25,
        5,
        0.3,
        0.05,
    )
    assert plan.out == Path("elsewhere") and plan.movie
    with pytest.raises(CaseFileError, match=r"time.t_end: must be > 0 \(got -1"):
        load_case(good, {"t_end": -1.0})
    with pytest.raises(CaseFileError, match="unknown override 'nn' \\(did you mean 'n'\\?\\)"):
        load_case(good, {"nn": 40})
    # n on an nx x ny grid keeps the aspect ratio
    d = copy.deepcopy(BASE)
    d["grid"] = {"nx": 32, "ny": 48, "ay": -3.0, "by": 3.0}
    assert (case_from_dict(d, overrides={"n": 64}).case.grid.ny) == 96
    # name defaults to the file's stem
    nameless = tmp_path / "my_case.toml"
    nameless.write_text(BASE_TOML.replace('name = "base"', ""))
    assert load_case(nameless).name == "my_case"


# --------------------------------------------------------------------------------------------
# random malformed input: only CaseError, never another exception

BAD_VALUES = [
    None,
    True,
    False,
    0,
    -1,
    1,
    3,
    10**6,
    10**30,
    10**400,
    -1e300,
    1e300,
    0.0,
    -0.5,
    1.5,
    math.nan,
    math.inf,
    -math.inf,
    "",
    "x",
    "wall",
    "periodic",
    "Disc",
    "neo_hookean",
    [],
    [1],
    [1, 2, 3],
    [[1, 2], [3]],
    [0.5, 0.5],
    {},
    {"type": "Disc"},
    {"x": 1},
    {"type": "Disc", "center": [0.0, 0.0], "radius": 0.5},
]


def _paths(node, prefix=()):
    if prefix:
        yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


@st.composite
def malformed_cases(draw):
    doc = copy.deepcopy(BASE)
    for _ in range(draw(st.integers(1, 3))):
        paths = list(_paths(doc))
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = doc
        for p in path[:-1]:
            parent = parent[p]
        key = path[-1]
        value = parent[key]
        op = draw(
            st.sampled_from(
                ["delete", "replace", "number", "unknown", "wrap_list", "wrap_table", "unwrap"]
            )
        )
        if op == "delete":
            del parent[key]
        elif op == "replace":
            parent[key] = copy.deepcopy(draw(st.sampled_from(BAD_VALUES)))
        elif op == "number":
            parent[key] = draw(st.one_of(st.floats(), st.integers(-(10**20), 10**20)))
        elif op == "unknown":
            target = (
                value if isinstance(value, dict) else parent if isinstance(parent, dict) else None
            )
            if target is not None:
                target[
                    draw(st.sampled_from(["grd", "colour", "radius", "type", "G", "n", "kind"]))
                ] = 1
        elif op == "wrap_list":
            parent[key] = [value]
        elif op == "wrap_table":
            parent[key] = {"value": value}
        elif op == "unwrap":
            if isinstance(value, list) and value:
                parent[key] = value[0]
            elif isinstance(value, dict) and value:
                parent[key] = next(iter(value.values()))
    return doc


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(malformed_cases())
def test_random_malformed_cases_raise_only_case_errors(doc):
    try:
        plan = case_from_dict(doc)
    except CaseError as e:
        msg = str(e)
        assert msg and "Traceback" not in msg
    else:  # a mutation that happens to be valid must give a valid case
        plan.case.validate()


@settings(max_examples=40, deadline=None)
@given(
    st.recursive(
        st.one_of(
            st.booleans(),
            st.integers(-(2**63), 2**63 - 1),
            st.floats(allow_nan=False),
            st.text(max_size=12),
        ),
        lambda children: (
            st.lists(children, max_size=3)
            | st.dictionaries(st.text(min_size=1, max_size=6), children, min_size=1, max_size=3)
        ),
        max_leaves=10,
    ).filter(lambda v: isinstance(v, dict))
)
def test_toml_writer_round_trips(doc):
    assert tomllib.loads(to_toml(doc)) == doc


# --------------------------------------------------------------------------------------------
# shapes from data


def _disc_mask(n=160, center=(0.2, -0.1), r=0.6):
    x = -1.0 + (np.arange(n) + 0.5) * 2.0 / n
    X, Y = np.meshgrid(x, x, indexing="ij")
    return (X - center[0]) ** 2 + (Y - center[1]) ** 2 < r**2


def test_mask_shape_from_npy_has_the_disc_area_and_distance(tmp_path):
    np.save(tmp_path / "disc.npy", _disc_mask())
    s = ArrayShape(str(tmp_path / "disc.npy"), (-1.0, 1.0, -1.0, 1.0))
    assert s.area(400) == pytest.approx(math.pi * 0.36, rel=0.01)
    disc = Disc((0.2, -0.1), 0.6)
    P = np.random.default_rng(0).uniform(-1.0, 1.0, (2, 2000))
    d_ref = np.asarray(disc(P[0], P[1]))
    near = np.abs(d_ref) < 0.3
    assert np.abs(np.asarray(s(P[0], P[1])) - d_ref)[near].max() < 0.02  # a signed distance
    assert build_shape(s.to_dict()) == s
    u = s | Disc((0.0, 0.9), 0.2)
    assert build_shape(u.to_dict()) == u
    assert "ArrayShape" not in SHAPES  # the geometry registry keeps its built-in types
    # float masks and an sdf array give the same kind of shape
    np.save(
        tmp_path / "sdf.npy",
        np.asarray(
            disc(
                *np.meshgrid(
                    np.linspace(-0.99, 0.99, 100), np.linspace(-0.99, 0.99, 100), indexing="ij"
                )
            )
        ),
    )
    sdf = ArrayShape(str(tmp_path / "sdf.npy"), (-1.0, 1.0, -1.0, 1.0), mode="sdf")
    assert sdf.area(400) == pytest.approx(math.pi * 0.36, rel=0.01)


def test_mask_shape_in_a_case_file_relative_path_and_png(tmp_path):
    import matplotlib.pyplot as plt

    np.save(tmp_path / "disc.npy", _disc_mask())
    img = np.ones((100, 200, 3))
    yy, xx = np.mgrid[0:100, 0:200]
    img[(xx - 50) ** 2 + (yy - 30) ** 2 < 20**2] = 0.0  # a dark disc, upper left
    plt.imsave(tmp_path / "blob.png", img)
    (tmp_path / "case.toml").write_text("""
name = "masks"
[grid]
n = 32
[[solids]]
law = {law = "neo_hookean", G = 10, kappa = 10}
[solids.shape]
type = "mask"
file = "disc.npy"
extent = [-1.0, 1.0, -1.0, 1.0]
[[solids]]
law = {law = "neo_hookean", G = 10, kappa = 10}
[solids.shape]
type = "Translate"
offset = [-0.5, 0.2]
shape = {type = "mask", file = "blob.png", extent = [1.0, 3.0, 0.0, 1.0]}
""")
    case = load_case(tmp_path / "case.toml")
    png = case.solids[1].shape.shape
    x0, x1, y0, y1 = png.bbox()  # picture read as it looks: the disc is upper left
    assert 1.25 < x0 < 1.35 and 1.65 < x1 < 1.75 and 0.45 < y0 < 0.55 and 0.85 < y1 < 0.95
    assert png.area() == pytest.approx(math.pi * 0.2**2, rel=0.03)
    (tmp_path / "sub").mkdir()
    out = dump_case(case, tmp_path / "sub" / "again.toml")
    assert 'file = "../disc.npy"' in out.read_text()
    assert load_case(out).to_dict() == case.to_dict()
    model, params = case.build()
    assert float(model.initial_state(params).phi.min()) < 0


def test_bad_mask_files_are_named(tmp_path):
    base = {
        "name": "m",
        "grid": {"n": 32},
        "solids": [
            {
                "law": {"law": "neo_hookean", "G": 1, "kappa": 1},
                "shape": {"type": "mask", "file": "nope.npy", "extent": [-1, 1, -1, 1]},
            }
        ],
    }
    with pytest.raises(CaseFileError, match=r"solids\[0\]\.shape\.file: names no readable file"):
        case_from_dict(base, base_dir=tmp_path)
    np.save(tmp_path / "empty.npy", np.zeros((10, 10), dtype=bool))
    base["solids"][0]["shape"]["file"] = "empty.npy"
    with pytest.raises(CaseFileError, match=r"solids\[0\]\.shape\.file: .*no inside pixels"):
        case_from_dict(base, base_dir=tmp_path)
    np.save(tmp_path / "disc.npy", _disc_mask())
    base["solids"][0]["shape"].update(file="disc.npy", extent=[1, -1, -1, 1])
    with pytest.raises(CaseFileError, match=r"solids\[0\]\.shape\.extent: needs x1 > x0"):
        case_from_dict(base, base_dir=tmp_path)
    base["solids"][0]["shape"].update(extent=[-1, 1, -1, 1], mode="sdf")
    with pytest.raises(
        CaseFileError, match=r"solids\[0\]\.shape: unknown key 'mode' for shape type 'mask'"
    ):
        case_from_dict(base, base_dir=tmp_path)


# --------------------------------------------------------------------------------------------
# example files


EXAMPLES = sorted((ROOT / "examples").glob("*.toml"))


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_example_case_files_load_and_validate(path):
    plan = load_run(path)
    case = plan.case.validate()
    assert case.solids and case.description
    assert load_case(path, {"n": 64}).grid.nx == 64
    assert case_from_dict(tomllib.loads(case_to_toml(case))).case.to_dict() == case.to_dict()


def test_the_valve_example_is_a_new_geometry():
    case = load_case(ROOT / "examples" / "flap_valve.toml")
    assert case.grid.ny == case.grid.nx // 2  # a 2:1 channel
    assert len(case.solids) == 2 and all(s.anchor is not None for s in case.solids)
    assert case.boundary.left[0].profile == "parabolic"


def test_the_annotated_example_in_the_docs_loads():
    import re

    text = (ROOT / "docs" / "casefiles.md").read_text()
    block = re.findall(r"```toml\n(.*?)```", text, re.S)[0]
    case = case_from_dict(tomllib.loads(block)).case
    assert case.name == "flap_valve" and len(case.solids) == 2
    assert case.to_dict() == load_case(ROOT / "examples" / "flap_valve.toml").to_dict()


def test_unwritable_cases_and_unknown_scenarios_are_named():
    from refmap.materials import EnergyLaw, neo_hookean_energy

    case = case_from_dict(BASE).case
    law = EnergyLaw(neo_hookean_energy, {"G": 1.0, "kappa": 1.0})
    bad = case.replace(
        solids=(case.solids[0], case.solids[1].__class__(**{**case.solids[1].__dict__, "law": law}))
    )
    with pytest.raises(CaseFileError, match=r"solids\[1\]\.law: cannot be written to a case file"):
        case_to_toml(bad)
    with pytest.raises(CaseError, match="unknown scenario 'nope'"):
        show_scenario("nope")
