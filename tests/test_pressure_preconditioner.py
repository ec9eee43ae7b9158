"""The projection's multigrid preconditioner (``pressure_preconditioner = "multigrid"``,
refmap.multigrid): a fixed symmetric positive definite operator on grids with a held
obstacle, a density jump, periodic axes, outflow edges and sizes that are not powers of
two; the same projections as the other preconditioners in far fewer CG iterations on the
rotor.  docs/validation_incompressible.md has the benchmark."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap.boundary import Boundary, Segment
from refmap.grid import Grid, Grid3D
from refmap.model import Model
from refmap.multigrid import Hierarchy, apply_faces, face_diagonal
from refmap.projection import Projection
from refmap.state import Numerics

MG = Numerics(fluid_model="incompressible", pressure_preconditioner="multigrid")
EDGES = {
    # closed box: the constants' null space (s P0)
    "walls": Boundary(top=(Segment("wall", velocity=(1.0, 0.0)),)),
    # a periodic axis of odd size and an outflow edge (A definite, identity rows)
    "periodic-outflow": Boundary(left="periodic", right="periodic", bottom="wall", top="outflow"),
    # a partial outflow on a low edge
    "partial-outflow": Boundary(
        left=(Segment("outflow", 0.0, 0.5), Segment("wall", 0.5, 1.0)),
        bottom=(Segment("velocity", velocity=(0.0, 1.0)),),
        top="slip",
    ),
}


def _dense(f, shape):
    n = int(np.prod(shape))
    return np.asarray(jax.jacfwd(lambda x: f(x.reshape(shape)).ravel())(jnp.zeros(n)))


def _obstacle_and_density(grid):
    """A held disc (weight 0 inside, a ring of 0.5 around it) and a density of 10 in a
    patch beside it, 1 elsewhere (ratio 10)."""
    x, y = (np.asarray(a) for a in grid.mesh("node"))
    lx, ly = grid.highs[0] - grid.lows[0], grid.highs[1] - grid.lows[1]
    r = np.hypot(x - 0.4 * lx, y - 0.5 * ly)
    weight = np.where(r < 0.2 * ly, 0.0, np.where(r < 0.2 * ly + 1.5 * grid.h, 0.5, 1.0))
    rho = np.where((x > 0.65 * lx) & (y > 0.3 * ly), 10.0, 1.0)
    return jnp.asarray(weight), jnp.asarray(rho)


@pytest.mark.parametrize("edges", sorted(EDGES))
def test_multigrid_symmetric_positive_and_faces_are_the_operator(edges):
    """On a 41 x 26 grid (odd, periodic x in one case; four levels: 41 x 26, 21 x 13,
    11 x 7, 6 x 4) with a held disc and a density ratio of 10: the face form the cycle
    coarsens is exactly A on the rows that move (A's own s P0 term aside), and the
    preconditioner as a dense matrix is symmetric to round-off and positive definite."""
    m = Model(Grid(41, 26, 0.0, 1.0, 0.0, 26 / 41), (), EDGES[edges], MG)
    pr = m.projection
    assert len(pr.hierarchy.shapes) == 4
    shape = tuple(m.grid.shape())
    weight, rho = _obstacle_and_density(m.grid)
    inv = weight / rho
    A_op, s = pr.operator(rho, weight)
    A = _dense(A_op, shape)
    faces, extra = pr.faces(inv)
    L = _dense(lambda x: apply_faces(faces, extra, x), shape)
    moving = np.asarray(face_diagonal(faces, extra) > 0).ravel()
    held = np.asarray(pr.moving_rows(weight)).ravel() == 0
    assert held.sum() > 20 and not moving[held].any()  # the disc's interior is there
    if not pr.has_outflow:
        A = A - s / A.shape[0]  # the s P0 term: s mean(p) on every row
    else:
        assert not moving[pr.keep.ravel() == 0].any()  # outflow rows: identity in A
        np.testing.assert_allclose(np.diag(A)[pr.keep.ravel() == 0], 1.0)
    both = np.ix_(moving, moving)
    np.testing.assert_allclose(L[both], A[both], atol=1e-12 * np.abs(A).max())
    P = _dense(pr.preconditioner(rho, s, weight), shape)
    assert np.max(np.abs(P - P.T)) < 1e-12 * np.max(np.abs(P))
    lam = np.linalg.eigvalsh(0.5 * (P + P.T))
    assert lam[0] > 1e-8 * lam[-1]
    if pr.has_outflow:  # exactly the identity on the rows nothing moves (held, outflow)
        fixed = ~moving
        np.testing.assert_array_equal(P[np.ix_(fixed, fixed)], np.eye(fixed.sum()))
        np.testing.assert_array_equal(P[np.ix_(fixed, moving)], 0.0)


def test_multigrid_3d_symmetric_positive():
    """The cycle is dimension-generic: a 13 x 10 x 9 box, periodic along z (odd), a held
    ball and a heavy slab: symmetric positive definite, and it solves the projection."""
    nums = dataclasses.replace(MG, pressure_rtol=1e-12)
    b = Boundary(back="periodic", front="periodic", top=(Segment("wall", velocity=(1.0, 0.0, 0.0)),))
    g = Grid3D(13, 10, 9, 0.0, 1.0, 0.0, 10 / 13, 0.0, 9 / 13)
    pr = Model(g, (), b, nums).projection
    x, y, z = (np.asarray(a) for a in g.mesh("node"))
    weight = jnp.asarray(np.where(np.hypot(np.hypot(x - 0.5, y - 0.4), z - 0.35) < 0.2, 0.0, 1.0))
    rho = jnp.asarray(np.where(x > 0.7, 10.0, 1.0))
    _, s = pr.operator(rho, weight)
    P = _dense(pr.preconditioner(rho, s, weight), tuple(g.shape()))
    assert np.max(np.abs(P - P.T)) < 1e-12 * np.max(np.abs(P))
    assert np.linalg.eigvalsh(0.5 * (P + P.T))[0] > 0
    # at rest in the held ball, as an anchor would hold it (else its rows, null in A, would
    # ask for a divergence nothing can remove)
    v = jnp.asarray(np.random.default_rng(0).standard_normal((3,) + tuple(g.shape()))) * weight
    vp, _, info = pr.project(v, rho, 0.1, 0.01, weight=weight, return_info=True)
    # measured 18 iterations to 1e-12 (fast 50, jacobi 109)
    assert bool(info["converged"]) and int(info["iterations"]) <= 25
    assert float(jnp.max(jnp.abs(pr.divergence(vp, 0.1)))) < 1e-9


@pytest.mark.parametrize(
    "n, shapes",
    [
        (128, [128, 64, 32, 16, 8]),
        (96, [96, 48, 24, 12, 6]),
        (100, [100, 50, 25, 13, 7]),
        (48, [48, 24, 12, 6]),
    ],
)
def test_hierarchy_any_size(n, shapes):
    """Aggregates of two nodes, the last one alone on an odd axis, down to 64 nodes or
    fewer; an axis of 2 nodes is not coarsened further."""
    h = Hierarchy.build((n, n), (False, True))
    assert [s[0] for s in h.shapes] == shapes and all(s[0] == s[1] for s in h.shapes)
    assert Hierarchy.build((200, 3), (False, False)).shapes[-1] == (25, 2)


def _rotor_projection_inputs(n, steps):
    """The rotor (incompressible) after ``steps`` steps, and the arguments its next step
    passes to the projection (held hub: weight 0 there)."""
    from refmap.scenarios import get_case

    case = get_case("rotor", n)
    case = dataclasses.replace(
        case, numerics=dataclasses.replace(case.numerics, fluid_model="incompressible")
    )
    model, params = case.build()
    s = jax.jit(lambda p: model.run_steps(model.initial_state(p), p, steps))(params)
    pr = model.projection
    box = {}

    def capture(s):
        orig = pr.project

        def spy(v, rho, t, dt, weight=None, return_info=False, source=None, **kw):
            box.update(v=v, rho=rho, t=t, dt=dt, weight=weight, source=source)
            return orig(v, rho, t, dt, weight=weight, return_info=return_info, source=source, **kw)

        pr.project = spy
        try:
            model.step(s, params, model.time_step(s, params)[0])
        finally:
            pr.project = orig
        return dict(box)

    return model, jax.jit(capture)(s)


# measured (rotor, 3 steps): n = 32: fast 37, jacobi 167, multigrid 9 CG iterations;
# n = 48: 45, 284, 10; n = 64: 86, 385, 10; at 128^2 103 -> 10, at 256^2 67 -> 10
def test_multigrid_on_the_rotor_same_projection_fewer_iterations():
    model, a = _rotor_projection_inputs(48, 3)
    pr = model.projection
    out = {}
    for kind in ("fast", "jacobi", "multigrid"):
        proj = Projection(model, rtol=1e-10, maxiter=1000, preconditioner=kind)
        v, p, info = jax.jit(lambda a, proj=proj: proj.project(
            a["v"], a["rho"], a["t"], a["dt"], weight=a["weight"], source=a["source"],
            return_info=True))(a)
        assert bool(info["converged"]), kind
        out[kind] = (v, int(info["iterations"]))
        # D v = the (masked) source on every row, to the solver's tolerance
        src = a["source"] * pr.moving_rows(a["weight"])
        res = pr.divergence(v, a["t"]) - (src - jnp.mean(src))
        assert float(jnp.max(jnp.abs(res))) < 1e-10, kind
    scale = float(jnp.max(jnp.abs(out["fast"][0])))
    for kind in ("jacobi", "multigrid"):
        assert float(jnp.max(jnp.abs(out[kind][0] - out["fast"][0]))) < 1e-9 * scale
    # 10 against 45 measured: at most 15, and at most a third of the fast one's (margin for
    # other BLAS/XLA round-off paths; the count is grid-independent from 32^2 to 256^2)
    assert out["multigrid"][1] <= 15
    assert 3 * out["multigrid"][1] <= out["fast"][1]


def test_multigrid_rotor_run_equals_fast_run():
    """Four steps of the incompressible rotor (32^2) with either preconditioner agree to
    the CG tolerance (measured difference ~1e-13 of the velocity scale)."""
    from refmap.scenarios import get_case

    runs = {}
    for kind in ("fast", "multigrid"):
        case = get_case("rotor", 32)
        num = dataclasses.replace(case.numerics, fluid_model="incompressible",
                                  pressure_preconditioner=kind)
        model, params = dataclasses.replace(case, numerics=num).build()
        s = jax.jit(lambda p, model=model: model.run_steps(model.initial_state(p), p, 4))(params)
        runs[kind] = s
    vf, vm = np.asarray(runs["fast"].v), np.asarray(runs["multigrid"].v)
    assert np.max(np.abs(vf)) > 0.1
    np.testing.assert_allclose(vm, vf, atol=1e-9 * np.max(np.abs(vf)))
    np.testing.assert_allclose(np.asarray(runs["multigrid"].xi), np.asarray(runs["fast"].xi),
                               atol=1e-11)


def test_bad_preconditioner_names_the_value():
    with pytest.raises(ValueError, match="pressure_preconditioner must be 'auto', 'fast', "
                                         "'jacobi' or 'multigrid', got 'ilu'"):
        Numerics(fluid_model="incompressible", pressure_preconditioner="ilu")
    m = Model(Grid(8, 8, 0.0, 1.0, 0.0, 1.0), (), Boundary(), MG)
    with pytest.raises(ValueError, match="'multigrid', got 'amg'"):
        Projection(m, preconditioner="amg")


def test_case_file_accepts_multigrid(tmp_path):
    import tomllib

    from refmap.casefile import CaseFileError, case_from_dict, dump_case, load_case

    text = (
        '[grid]\nn = 16\n[time]\nt_end = 0.1\n[numerics]\nfluid_model = "incompressible"\n'
        'pressure_preconditioner = "multigrid"\n'
    )
    case = case_from_dict(tomllib.loads(text)).case
    model, _ = case.build()
    assert model.projection.preconditioner_kind == "multigrid"
    back = load_case(dump_case(case, tmp_path / "mg.toml"))
    assert back.numerics.pressure_preconditioner == "multigrid"
    doc = tomllib.loads(text)
    doc["numerics"]["pressure_preconditioner"] = "ilu"
    with pytest.raises(CaseFileError, match="pressure_preconditioner.*'ilu'"):
        case_from_dict(doc)


@pytest.mark.parametrize("name, expected", [("rotor", "multigrid"), ("stick", "multigrid"),
                                            ("two_balls", "multigrid"), ("circle", "fast"),
                                            ("settle", "fast")])
def test_auto_takes_multigrid_where_an_anchor_holds_nodes(name, expected):
    """The default ``"auto"``: the cycle where a solid has an anchor (rotor's hub, stick's
    clamp, two_balls' held ball: fast needs 26-103 CG iterations there, the cycle 10-12),
    the fast solve for free bodies (nearly exact at uniform density: 2-4 iterations)."""
    from refmap.scenarios import get_case

    case = get_case(name, 16)
    assert case.numerics.pressure_preconditioner == "auto"
    num = dataclasses.replace(case.numerics, fluid_model="incompressible")
    model, _ = dataclasses.replace(case, numerics=num).build()
    has_anchor = any(s.anchor is not None for s in model.solids)
    assert has_anchor == (expected == "multigrid")
    assert model.projection.preconditioner_kind == expected
    # an explicit choice is kept
    num = dataclasses.replace(num, pressure_preconditioner="jacobi")
    model, _ = dataclasses.replace(case, numerics=num).build()
    assert model.projection.preconditioner_kind == "jacobi"


def _incompressible_circle(precond):
    from refmap.scenarios import get_case

    case = get_case("circle", 16)
    num = dataclasses.replace(case.numerics, fluid_model="incompressible",
                              pressure_preconditioner=precond)
    return case.replace(numerics=num, t_end=0.02, frames=2)


def test_frames_report_the_pressure_solve():
    """Every frame's diagnostics carry the pressure solve's CG iterations, relative residual
    and convergence (the solve of a step from the frame's state, as its p_fluid)."""
    from refmap.simulation import Simulation

    sim = Simulation(_incompressible_circle("auto"), None, progress=False, pictures=False)
    sim.run()
    assert len(sim.rows) == 3
    for row in sim.rows:
        assert row["pressure_cg_converged"] == 1.0
        assert 1 <= row["pressure_cg_iterations"] <= 20
        assert row["pressure_cg_residual"] <= 1e-10


def test_a_pressure_solve_that_stops_at_maxiter_warns_once():
    """Cut CG at 2 iterations (the Jacobi preconditioner needs ~100 here): the run warns,
    once, naming the residual, the tolerance, the preconditioner and the cure; the frames
    record the failed solves."""
    from refmap.simulation import Simulation

    sim = Simulation(_incompressible_circle("jacobi"), None, progress=False, pictures=False)
    sim.model.projection.maxiter = 2
    with pytest.warns(RuntimeWarning, match=r"did not converge .* after 2 iterations .* "
                      r"pressure_rtol = 1e-10 \(pressure_preconditioner = 'jacobi'\).*multigrid") as rec:
        sim.run()
    assert sum("did not converge" in str(w.message) for w in rec) == 1
    assert all(row["pressure_cg_converged"] == 0.0 for row in sim.rows[1:])
    assert all(row["pressure_cg_residual"] > 1e-10 for row in sim.rows[1:])


def test_refmap_info_reports_the_pressure_solves(tmp_path):
    """``refmap info`` sums up the frames' pressure solves: iterations, largest residual, and
    how many frames did not converge (none with the default; every one after t = 0 with CG
    cut at 2 Jacobi iterations)."""
    from refmap.postprocess import format_info, run_info
    from refmap.simulation import Simulation

    Simulation(_incompressible_circle("auto"), tmp_path / "ok", progress=False,
               pictures=False).run()
    ps = run_info(tmp_path / "ok")["pressure_solve"]
    assert ps["frames"] == 3 and ps["not_converged"] == 0 and 1 <= ps["iterations_max"] <= 20
    assert "NOT converged" not in format_info(run_info(tmp_path / "ok"))

    sim = Simulation(_incompressible_circle("jacobi"), tmp_path / "cut", progress=False,
                     pictures=False)
    sim.model.projection.maxiter = 2
    with pytest.warns(RuntimeWarning, match="did not converge"):
        sim.run()
    info = run_info(tmp_path / "cut")
    assert info["pressure_solve"]["iterations_max"] == 2
    assert info["pressure_solve"]["not_converged"] >= 2
    assert "NOT converged in" in format_info(info)
