"""3D case files (issue 12): ``[grid] dim = 3`` and what follows from it (z extent, faces
back / front, 3D shapes, laws 3D without saying so, three-number vectors, u, v, w formulas),
round trips, errors for settings of the other dimension (each naming its key path and
value) and for 2D-only settings, and a short run of the 3D example through Simulation."""

from __future__ import annotations

import copy
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap.case import CaseWarning
from refmap.casefile import (
    CaseFileError,
    build_shape,
    case_from_dict,
    case_to_toml,
    dump_case,
    load_case,
    load_run,
    show_scenario,
)
from refmap.geometry import Box, Difference, Ellipsoid, Sphere, Translate
from refmap.grid import Grid3D
from refmap.initial import VelocityExpression
from refmap.materials import NeoHookean, StVenantKirchhoff

ROOT = Path(__file__).resolve().parents[1]

# Two solids: a pre-strained, moving ellipsoid, and a CSG body (a box less a sphere, moved
# by a 3-number Translate) with an svk law from E and nu; an inflow face, an outflow face
# and slip walls; gravity along z; formulas in x, y and z.
BASE_TOML = """
name = "three"
gravity = [0.0, 0.0, -0.01]

[grid]
dim = 3
n = 16
ax = -1.0
bx = 2.0
ay = -0.75
by = 0.75
az = -0.75
bz = 0.75

[time]
t_end = 0.5
frames = 2

[fluid]
lambda_f = 10.0
eta = 0.2

[boundary]
left = [{kind = "velocity", velocity = [0.1, 0.0, 0.0], ramp = 0.2}]
right = "outflow"
bottom = "slip"
top = "slip"
back = "wall"
front = [{kind = "wall", velocity = [0.05, 0.0, 0.0]}]

[initial_velocity]
u = "0.1 * (1 - z * z)"
w = "0.01 * sin(pi * x) * y"

[[solids]]
name = "blob"
law = {law = "neo_hookean", G = 1, kappa = 10}
strain = [[1.1, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.9090909090909091]]
strain_center = [-0.2, 0.0, 0.0]
velocity = [0.0, 0.0, 0.05]

[solids.shape]
type = "Ellipsoid"
center = [-0.2, 0.0, 0.0]
semi_axes = [0.4, 0.3, 0.3]

[[solids]]
name = "holed"
law = {law = "svk", E = 20, nu = 0.3}

[solids.shape]
type = "Translate"
offset = [1.0, 0.0, 0.0]
shape = {type = "Difference", a = {type = "Box", center = [0.0, 0.0, 0.0], half_size = [0.3, 0.3, 0.3]}, b = {type = "Sphere", radius = 0.15}}
"""
BASE = tomllib.loads(BASE_TOML)

BASE_2D = tomllib.loads("""
name = "flat"
[grid]
n = 16
[[solids]]
law = {law = "neo_hookean", G = 1, kappa = 10}
shape = {type = "Disc", center = [0.0, 0.0], radius = 0.8}
""")


def _load(doc, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CaseWarning)
        return case_from_dict(doc, **kw).case


def test_a_3d_case_file_loads():
    case = _load(BASE)
    g = case.grid
    # n cells along x; ny and nz follow for cubic cells
    assert g == Grid3D(16, 8, 8, -1.0, 2.0, -0.75, 0.75, -0.75, 0.75)
    assert case.gravity == (0.0, 0.0, -0.01)
    b = case.boundary
    assert b.ndim == 3 and b.faces[-2:] == ("back", "front")
    assert b.left[0].kind == "velocity" and b.left[0].velocity == (0.1, 0.0, 0.0)
    assert b.left[0].ramp == 0.2 and b.right[0].kind == "outflow"
    assert b.bottom[0].kind == "slip" and b.bottom[0].velocity == (0.0, 0.0, 0.0)
    assert b.back[0].kind == "wall" and b.front[0].velocity == (0.05, 0.0, 0.0)
    blob, holed = case.solids
    assert blob.shape == Ellipsoid((-0.2, 0.0, 0.0), (0.4, 0.3, 0.3))
    assert holed.shape == Translate(Difference(Box((0.0, 0.0, 0.0), (0.3, 0.3, 0.3)),
                                               Sphere(radius=0.15)), (1.0, 0.0, 0.0))
    # the laws are 3D although the file does not say so
    assert blob.law == NeoHookean(G=1.0, kappa=10.0, dim=3)
    assert holed.law == StVenantKirchhoff.from_E_nu(20.0, 0.3, dim=3)
    assert blob.ndim == holed.ndim == 3
    assert blob.strain[2] == (0.0, 0.0, 0.9090909090909091)
    assert blob.strain_center == (-0.2, 0.0, 0.0) and blob.velocity == (0.0, 0.0, 0.05)
    assert holed.strain == ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    assert holed.velocity == (0.0, 0.0, 0.0)
    assert case.initial_velocity == VelocityExpression("0.1 * (1 - z * z)", "0",
                                                       "0.01 * sin(pi * x) * y")
    X, Y, Z = g.mesh("node")
    v0 = case.initial_velocity_field()
    assert np.array_equal(v0[0], 0.1 * (1 - Z * Z)) and np.all(v0[1] == 0.0)
    assert np.array_equal(v0[2], 0.01 * np.sin(np.pi * X) * Y)


def test_grid_keys_and_overrides_in_3d():
    d = copy.deepcopy(BASE)
    d["grid"] = {"dim": 3, "nx": 24, "ny": 12, "nz": 10, "ax": -1.0, "bx": 2.0, "ay": -0.75,
                 "by": 0.75, "az": -0.75, "bz": 0.75}
    assert _load(d).grid.shape() == (24, 12, 10)
    # n on an nx x ny x nz grid keeps the aspect ratios: ny and nz are scaled
    assert _load(d, overrides={"n": 48}).grid.shape() == (48, 24, 20)
    assert _load(d, overrides={"nz": 16}).grid.shape() == (24, 12, 16)
    assert _load(BASE, overrides={"n": 32}).grid.shape() == (32, 16, 16)
    # z bounds default to [-2, 2] like the others
    d = {"grid": {"dim": 3, "n": 16}}
    assert _load(d).grid == Grid3D(16, 16, 16)


def test_round_trip_to_an_equal_case(tmp_path):
    case = _load(BASE)
    text = case_to_toml(case)
    assert "dim = 3" in text and "back = " in text and "front = " in text
    assert "dim" not in text.split("[[solids]]", 1)[1]  # laws take the grid's dimension
    back = _load(tomllib.loads(text))
    assert back == case and back.to_dict() == case.to_dict()
    path = dump_case(case, tmp_path / "again.toml")
    again = load_case(path)
    assert again == case and again.to_dict() == case.to_dict()
    # a grid that is not cubic-celled is written as nx, ny, nz
    d = copy.deepcopy(BASE)
    d["grid"].pop("n")
    d["grid"].update(nx=20, ny=9, nz=11)
    odd = _load(d)
    text = case_to_toml(odd)
    assert "nx = 20" in text and "nz = 11" in text
    assert _load(tomllib.loads(text)) == odd


@pytest.mark.parametrize("name", ["sphere_relax", "sphere_cavity", "spheres_settle"])
def test_3d_scenarios_print_as_case_files_that_load_back(name):
    """``refmap show NAME`` without --n prints the scenario at its own default, 32 cells in
    3D, the grid `refmap run NAME` uses (it once printed the 2D default, 128^3)."""
    from refmap import scenarios

    for n in (None, 16):
        case = scenarios.get_case(name, n)
        assert case.grid.nx == (32 if n is None else n)
        text = show_scenario(name, n)
        assert text.startswith("# refmap case file") and "dim = 3" in text
        back = _load(tomllib.loads(text))
        assert back == case and back.to_dict() == case.to_dict()


def test_2d_case_files_keep_their_form():
    """No dim, no z faces, laws as before: a 2D file is written as it always was."""
    case = _load(BASE_2D)
    text = case_to_toml(case)
    assert "dim" not in text and "back" not in text and "front" not in text
    assert "gravity = [0.0, 0.0]" in text and "velocity = [0.0, 0.0]" in text
    assert 'law = {law = "neo_hookean", G = 1.0, kappa = 10.0, rho0 = 1.0}' in text
    d = copy.deepcopy(BASE_2D)
    d["grid"]["dim"] = 2  # allowed, and the same case
    assert _load(d) == case


# --------------------------------------------------------------------------------------------
# errors: each names its key path and the offending value


def _set(doc, path, value):
    node = doc
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value


SHAPE = ("solids", 0, "shape")
MISMATCH_3D = [
    (SHAPE + ("type",), "Disc", "solids[0].shape.type",
     ["shape type 'Disc' is 2D but the grid is 3D", "3D types: Box", "(got 'Disc')"]),
    (("solids", 1, "shape", "shape", "b"), {"type": "disc", "radius": 0.1},
     "solids[1].shape.shape.b.type", ["'Disc' is 2D but the grid is 3D", "(got 'disc')"]),
    (SHAPE, {"type": "mask", "file": "m.npy", "extent": [0, 1, 0, 1]}, "solids[0].shape.type",
     ["'mask' shape is 2D", "grid is 3D", "(got 'mask')"]),
    (("solids", 1, "shape", "offset"), [1.0, 0.0], "solids[1].shape.offset",
     ["must be a list of 3 numbers", "(got [1.0, 0.0])"]),
    (("solids", 0, "law", "dim"), 2, "solids[0].law.dim",
     ["the law is 2D but the grid is 3D", "leave dim out", "(got 2)"]),
    (("solids", 0, "law", "dim"), "3", "solids[0].law.dim", ["must be 2 or 3", "(got '3')"]),
    (("solids", 0, "strain"), [[1.0, 0.0], [0.0, 1.0]], "solids[0].strain[0]",
     ["too few entries", "[1.0, 0.0]"]),
    (("solids", 0, "strain"), [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "solids[0].strain",
     ["positive, finite determinant", "det = -1"]),
    (("solids", 0, "velocity"), [0.0, 0.1], "solids[0].velocity",
     ["too few entries", "[0.0, 0.1]"]),
    (("solids", 0, "strain_center"), [0, 0, 0, 0], "solids[0].strain_center",
     ["must have 3 entries", "[0, 0, 0, 0]"]),
    (("gravity",), [0.0, -1.0], "gravity", ["too few entries", "[0.0, -1.0]"]),
    (("boundary", "front"), [{"kind": "velocity", "velocity": [0.1, 0.0]}],
     "boundary.front[0].velocity", ["too few entries", "[0.1, 0.0]"]),
    (("boundary", "back"), [{"kind": "velocity", "end": 0.5, "velocity": [0.0, 0.0, 0.1]},
                            {"start": 0.5}],
     "boundary.back[0].end", ["whole-face segments only", "(got 0.5)"]),
    (("boundary", "back"), "periodic", "boundary.front",
     ['must be "periodic"', "back is \"periodic\""]),
    (("initial_velocity", "w"), "t", "initial_velocity.w", ["'t' is not allowed", "(got 't')"]),
    (("initial_velocity",), {"u": "1", "file": "v0.npy"}, "initial_velocity.u",
     ["formulas u, v, w or a file, not both"]),
    (("grid", "nz"), 16, "grid.nz", ["give either n or nx, ny and nz", "nz = 16"]),
    (("grid", "bz"), -1.0, "grid.bz", ["must be > az = -0.75", "(got -1.0)"]),
    (("grid", "dim"), 4, "grid.dim", ["must be 2 or 3", "(got 4)"]),
    (("grid", "dim"), 3.0, "grid.dim", ["must be 2 or 3", "(got 3.0)"]),
]


@pytest.mark.parametrize("path, value, key, words", MISMATCH_3D,
                         ids=[m[2] + ":" + m[3][0][:24] for m in MISMATCH_3D])
def test_3d_file_errors_name_the_key_and_value(path, value, key, words):
    d = copy.deepcopy(BASE)
    _set(d, path, value)
    with pytest.raises(CaseFileError) as e:
        _load(d)
    msg = str(e.value).splitlines()[0]
    assert e.value.key == key, msg
    assert msg.startswith(key + ": "), msg
    for w in words:
        assert w in msg, (w, msg)


MISMATCH_2D = [
    (SHAPE + ("type",), "Sphere", "solids[0].shape.type",
     ["shape type 'Sphere' is 3D but the grid is 2D", "dim = 3 in [grid]", "(got 'Sphere')"]),
    (SHAPE, {"type": "Union", "a": {"type": "Disc", "radius": 0.5}, "b": {"type": "torus"}},
     "solids[0].shape.b.type", ["'Torus' is 3D but the grid is 2D", "(got 'torus')"]),
    (("solids", 0, "law", "dim"), 3, "solids[0].law.dim", ["the law is 3D but the grid is 2D"]),
    (("grid", "nz"), 16, "grid.nz", ["is for a 3D case: add dim = 3 to [grid]", "(got 16)"]),
    (("grid", "az"), -1.0, "grid.az", ["add dim = 3 to [grid]", "(got -1.0)"]),
    (("boundary",), {"back": "wall"}, "boundary.back",
     ["z-low face of a 3D box", "add dim = 3", "(got 'wall')"]),
    (("gravity",), [0.0, 0.0, -1.0], "gravity", ["must have 2 entries", "[0.0, 0.0, -1.0]"]),
    (("initial_velocity",), {"u": "1", "w": "0.5"}, "initial_velocity",
     ["unknown key 'w'", "for a 3D case", "(got w = '0.5')"]),
    (("initial_velocity",), {"u": "z"}, "initial_velocity.u",
     ["name 'z' is not allowed on a 2D grid", "(got 'z')"]),
]


@pytest.mark.parametrize("path, value, key, words", MISMATCH_2D,
                         ids=[m[2] + ":" + m[3][0][:24] for m in MISMATCH_2D])
def test_3d_settings_in_a_2d_file_name_the_key_and_value(path, value, key, words):
    d = copy.deepcopy(BASE_2D)
    _set(d, path, value)
    with pytest.raises(CaseFileError) as e:
        _load(d)
    msg = str(e.value).splitlines()[0]
    assert e.value.key == key, msg
    for w in words:
        assert w in msg, (w, msg)


NOT_IN_3D = [
    (("numerics",), {"band_force": "solid"}, "numerics.band_force",
     ["not available in 3D yet", "(got 'solid')"]),
]


@pytest.mark.parametrize("path, value, key, words", NOT_IN_3D, ids=[m[2] for m in NOT_IN_3D])
def test_2d_only_settings_in_3d_are_named(path, value, key, words):
    d = copy.deepcopy(BASE)
    _set(d, path, value)
    with pytest.raises(CaseFileError) as e:
        _load(d)
    msg = str(e.value).splitlines()[0]
    assert e.value.key == key and msg.startswith(key + ": "), msg
    for w in words:
        assert w in msg, (w, msg)


def test_3d_anchors_load_and_a_2d_pivot_centre_is_named():
    """A 3D pivot is an axle (refmap.anchors.PivotAnchor with a 3D centre); a region anchor
    takes a 3D shape; a 2-number centre names its key."""
    from refmap.anchors import PivotAnchor, RegionAnchor

    d = copy.deepcopy(BASE)
    _set(d, ("solids", 0, "anchor"), {"type": "pivot", "center": [-0.2, 0.0, 0.0],
                                      "half_length": 0.2, "fit_radius": 0.2, "hold_radius": 0.1})
    a = _load(d).solids[0].anchor
    assert isinstance(a, PivotAnchor) and a.center == (-0.2, 0.0, 0.0) and a.axis == (0.0, 0.0, 1.0)
    d = copy.deepcopy(BASE)
    _set(d, ("solids", 0, "anchor"), {"type": "region",
                                      "region": {"type": "Sphere", "center": [-0.2, 0.0, 0.0], "radius": 0.25}})
    assert isinstance(_load(d).solids[0].anchor, RegionAnchor)
    d = copy.deepcopy(BASE)
    _set(d, ("solids", 0, "anchor"), {"type": "pivot", "center": [0.0, 0.0]})
    with pytest.raises(CaseFileError) as e:
        _load(d)
    assert e.value.key.startswith("solids[0].anchor"), str(e.value)
    assert "center" in str(e.value)


def test_geometry_errors_in_3d_name_the_solid_and_the_z_extent():
    d = copy.deepcopy(BASE)
    _set(d, SHAPE + ("center",), [-0.2, 0.0, 0.6])  # through the (moving) front wall: allowed
    _load(d)
    _set(d, SHAPE + ("center",), [-0.8, 0.0, 0.0])  # into the left face's inflow: refused
    with pytest.raises(CaseFileError) as e:
        _load(d)
    msg = str(e.value)
    assert "solids[0] ('blob'): the shape reaches the left edge where it is a 'velocity'" in msg
    assert "[-1.0, 2.0] x [-0.75, 0.75] x [-0.75, 0.75]" in msg and "z in [" in msg
    _set(d, SHAPE + ("center",), [5.0, 5.0, 5.0])
    # the span in current coordinates: the strain (0.909 along z about z = 0) widens z
    with pytest.raises(CaseFileError, match=r"outside the domain .*y in \[4\.7, 5\.3\], z in \[5\.17"):
        _load(d)
    d = copy.deepcopy(BASE)
    _set(d, ("solids", 1, "shape", "offset"), [-0.2, 0.0, 0.0])
    with pytest.raises(CaseFileError, match=r"solids\[0\] and solids\[1\] overlap at t = 0.*z in"):
        _load(d)


def test_build_shape_without_a_dimension_reads_both():
    assert build_shape({"type": "Sphere", "radius": 0.5}) == Sphere(radius=0.5)
    assert build_shape({"type": "Translate", "offset": [1, 2, 3],
                        "shape": {"type": "Sphere"}}).offset == (1.0, 2.0, 3.0)
    assert build_shape({"type": "Disc"}, dim=2).ndim == 2


# --------------------------------------------------------------------------------------------
# the example, run


def test_the_3d_example_in_the_docs_is_the_example_file():
    import re

    text = (ROOT / "docs" / "casefiles.md").read_text()
    section = text.split("## Three dimensions", 1)[1]
    block = re.findall(r"```toml\n(.*?)```", section, re.S)[0]
    assert 'name = "sphere_in_flow"' in block
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CaseWarning)
        assert (case_from_dict(tomllib.loads(block)).case.to_dict()
                == load_case(ROOT / "examples" / "sphere_in_flow.toml").to_dict())


def test_the_3d_example_loads_and_runs_a_few_steps(tmp_path):
    """examples/sphere_in_flow.toml through load_run + Simulation on a coarse grid: frame 0
    is the stream (u = 0.2) with the body at rest inside it (velocity -0.2 added by its
    fraction), w = 0; a few steps stay finite and reach t_end."""
    from scipy.special import erfc

    from refmap.simulation import Simulation

    path = ROOT / "examples" / "sphere_in_flow.toml"
    full = load_case(path)
    assert full.grid.ndim == 3 and full.grid.shape() == (48, 24, 24) and full.description
    # n = 16 (ny = nz = 8); the extra bulk viscosity keeps sound damped on this coarse grid
    plan = load_run(path, {"n": 16, "t_end": 0.03, "frames": 1, "fluid.bulk_viscosity": 0.15,
                           "out": str(tmp_path / "run")})
    assert plan.case.grid.shape() == (16, 8, 8)
    sim = Simulation(plan.case, plan.out_dir, progress=False, pictures=False)
    end = sim.run()
    assert float(end.t) == pytest.approx(0.03, abs=1e-12)
    assert np.isfinite(np.asarray(end.v)).all()
    ds = refmap.open_run(tmp_path / "run")
    u0, v0, w0 = (ds[c].isel(time=0).values for c in "uvw")
    phi = ds["phi"].isel(time=0, solid=0).values
    h = plan.case.grid.h
    assert np.all(v0 == 0.0) and np.all(w0 == 0.0)
    # one solid: u0 = U + (1 - H) V with V = -U, 1 - H = erfc(phi / (2 h)) / 2 (blur 2 h)
    assert np.abs(u0 - (0.2 - 0.2 * 0.5 * erfc(phi / (2 * h)))).max() < 1e-14
    assert u0.min() < 0.1 and np.abs(u0[phi > 4 * h] - 0.2).max() < 1e-3
