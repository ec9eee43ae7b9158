"""Incompressible fluid in 3D (refmap.projection on a Grid3D): the same operator, solver and
edge rules as in 2D, one axis more.  The z-invariant 3D run against the 2D run is in
tests/test_model_3d.py (``test_z_invariant_3d_run_matches_the_2d_run[incompressible]``)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap.boundary import Boundary, Segment
from refmap.geometry import Sphere
from refmap.grid import Grid3D
from refmap.materials import NeoHookean
from refmap.model import Model, Solid
from refmap.operators import div_node
from refmap.state import FluidParams, Numerics

INC = Numerics(fluid_model="incompressible")
WALLS = dict(back="wall", front="wall")
EDGES = {
    "walls-lid": Boundary(top=(Segment("wall", velocity=(1.0, 0.0, 0.5)),), **WALLS),
    "periodic": Boundary(left="periodic", right="periodic", bottom="periodic", top="periodic",
                         back="periodic", front="periodic"),
    "through-z": Boundary(back=(Segment("velocity", velocity=(0.0, 0.0, 1.0), profile="parabolic"),),
                          front=(Segment("velocity", velocity=(0.0, 0.0, 1.0), profile="parabolic"),),
                          left="periodic", right="periodic"),
}
OUTFLOW = {
    "x-channel": Boundary(left=(Segment("velocity", velocity=(1.0, 0.0, 0.0), profile="parabolic"),),
                          right="outflow", **WALLS),
    "outflow-front": Boundary(bottom=(Segment("velocity", velocity=(0.0, 0.5, 0.0)),),
                              back="slip", front="outflow"),
}
N = (9, 8, 10)


def _model(boundary, numerics=INC, n=N, solids=()):
    return Model(Grid3D(*n, 0.0, 1.0, 0.0, n[1] / n[0], 0.0, n[2] / n[0]), solids, boundary, numerics)


def _rho(shape, seed=0):
    return jnp.asarray(1.0 + 2.0 * np.random.default_rng(seed).random(shape))


def _dense(f, n):
    return np.asarray(jax.jacfwd(f)(jnp.zeros(n)))


def _naive_divergence(v, his, h, periodic):
    """Forward differences by loops: (v_a[i + e_a] - v_a[i]) / h_a, beyond the high face its
    normal velocity (or the wrap)."""
    nx, ny, nz = v.shape[1:]
    out = np.zeros((nx, ny, nz))
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                idx = (i, j, k)
                for a in range(3):
                    nxt = list(idx)
                    nxt[a] += 1
                    if nxt[a] < v.shape[1 + a]:
                        up = v[a][tuple(nxt)]
                    elif periodic[a]:
                        nxt[a] = 0
                        up = v[a][tuple(nxt)]
                    else:
                        face = [idx[b] for b in range(3) if b != a]
                        up = his[a][tuple(face)]
                    out[idx] += (up - v[a][idx]) / h[a]
    return out


@pytest.mark.parametrize("edges", sorted(EDGES))
def test_operator_symmetric_null_space_constants_3d(edges):
    """A = B rho^-1 B^T on a 9 x 8 x 10 grid as a dense matrix: symmetric, positive
    semi-definite, exactly one zero eigenvalue with the constant as its eigenvector (no
    checkerboard mode in 3D either); the divergence equals forward differences written as
    loops (with the faces' normal velocities beyond the high faces); away from the low
    faces G = -B^T is the compressible model's div_node of the bottom-left-node corner
    pressure."""
    m = _model(EDGES[edges])
    pr = m.projection
    shape = m.grid.shape()
    size = int(np.prod(shape))
    rho = _rho(shape)
    A = _dense(lambda p: pr.B(pr.BT(p.reshape(shape)) / rho[None]).ravel(), size)
    assert np.max(np.abs(A - A.T)) < 1e-12 * np.max(np.abs(A))
    lam, vec = np.linalg.eigh(A)
    assert lam[0] > -1e-10 * lam[-1]
    assert lam[1] > 1e-3 * lam[-1]
    np.testing.assert_allclose(vec[:, 0] / vec[0, 0], 1.0, atol=1e-10)
    # the divergence against loops
    v = np.random.default_rng(4).standard_normal((3, *shape))
    t = 0.4
    vb = np.asarray(pr.prescribe(jnp.asarray(v), t))
    his = [None if p else np.asarray(h) for p, h in zip(pr.periodic, pr._his(t), strict=True)]
    naive = _naive_divergence(vb, his, m.grid.spacing, pr.periodic)
    np.testing.assert_allclose(np.asarray(pr.divergence(jnp.asarray(v), t)), naive, atol=1e-12)
    # the gradient against div_node of the corner pressure
    p = jnp.asarray(np.random.default_rng(1).random(shape))
    pc = jnp.pad(p, ((1, 0),) * 3, mode="wrap")  # corner (i, j, k) <- node (i-1, j-1, k-1)
    z = 0 * pc
    force = -div_node(pc, z, z, pc, z, pc, *m.grid.spacing)
    G = np.asarray(pr.gradient(p))
    np.testing.assert_allclose(G[:, 1:, 1:, 1:], -np.asarray(force)[:, 1:, 1:, 1:], atol=1e-12)


@pytest.mark.parametrize("edges", sorted(EDGES) + sorted(OUTFLOW))
@pytest.mark.parametrize("precond", ["fast", "jacobi", "multigrid"])
def test_projection_against_dense_solve_3d(edges, precond):
    """CG's projection equals a dense (least-squares) solve, and D v is below 1e-10 after
    it, with both preconditioners; with an outflow face A is definite and the pressure is
    zero on the outflow layer; with uniform density and no outflow the 3D fast
    preconditioner is exact (at most two iterations; with an outflow it is not: it puts the
    zero pressure half a cell beyond the outflow layer, the operator on it, as in 2D)."""
    nums = Numerics(fluid_model="incompressible", pressure_preconditioner=precond, pressure_rtol=1e-13)
    boundary = EDGES.get(edges) or OUTFLOW[edges]
    m = _model(boundary, nums)
    pr = m.projection
    shape = m.grid.shape()
    size = int(np.prod(shape))
    v = jnp.asarray(np.random.default_rng(2).standard_normal((3, *shape)))
    rho = _rho(shape, seed=3)
    t, dt = 0.7, 0.01
    vp, p, info = pr.project(v, rho, t, dt, return_info=True)
    assert bool(info["converged"])
    assert float(jnp.max(jnp.abs(pr.divergence(vp, t)))) < 1e-10
    assert float(jnp.max(jnp.abs(pr.divergence(v, t)))) > 1.0  # it had something to do
    A_op, _ = pr.operator(rho)
    A = _dense(lambda q: A_op(q.reshape(shape)).ravel(), size)
    b = -np.asarray(pr.divergence(pr.prescribe(v, t), t)).ravel() / dt
    if pr.has_outflow:
        assert np.linalg.eigvalsh(A)[0] > 1e-4 * np.abs(A).max()
        pd = np.linalg.solve(A, b)
        np.testing.assert_allclose(np.ravel(p), pd, atol=1e-8 * np.abs(pd).max())
        assert np.all(np.ravel(p)[pr.keep.ravel() == 0] == 0.0)
    else:
        Ad = _dense(lambda q: pr.B(pr.BT(q.reshape(shape)) / rho[None]).ravel(), size)
        pd = np.linalg.lstsq(Ad, b - b.mean(), rcond=None)[0]
        np.testing.assert_allclose(np.ravel(p) - np.mean(p), pd - pd.mean(), atol=1e-7 * np.abs(pd).max())
    if precond == "fast" and not pr.has_outflow:
        _, _, info1 = pr.project(v, jnp.full(shape, 2.0), t, dt, return_info=True)
        assert int(info1["iterations"]) <= 2


def test_unbalanced_3d_faces_are_refused():
    """Normal velocities that do not balance (an inflow through the back face, walls
    elsewhere) are refused when the model is built, with the net inflow named."""
    b = Boundary(back=(Segment("velocity", velocity=(0.0, 0.0, 1.0)),), front="wall")
    with pytest.raises(ValueError, match="do not balance"):
        _model(b)


def test_soft_sphere_in_a_lid_driven_incompressible_cube():
    """A soft sphere in a lid-driven cube (16^3, the fluid incompressible, no volume
    correction): every step ends divergence-free (max |D v| below 1e-11 of the lid speed
    over h), the fluid and the sphere move (the sphere at -0.022 along x by t = 0.1), and
    the solid stays isochoric: J within 2e-3 of 1 and its volume, from the second step on,
    within 0.2 % (measured J in [0.9992, 1.0003] and -0.014 %; the blurred volume measure
    jumps by +1.0 % in the first two steps in every fluid model, compressible included, as
    the level set is first pinned to the maps: not a volume change of the material)."""
    n = 16
    solid = Solid(shape=Sphere(center=(0.6, 0.5, 0.5), radius=0.2), law=NeoHookean(G=1.0, kappa=10.0, dim=3))
    m = _model(Boundary(top=(Segment("velocity", velocity=(1.0, 0.0, 0.0)),), **WALLS),
               Numerics(fluid_model="incompressible", volume_correction=0.0), n=(n, n, n), solids=(solid,))
    p = m.default_params(FluidParams(eta=0.0, extra_viscosity=0.01))
    s0 = jax.jit(lambda s: m.run_steps(s, p, 2))(m.initial_state(p))
    s1, info = jax.jit(m.advance)(s0, p, 0.1)
    assert bool(info["ok"])
    assert float(jnp.max(jnp.abs(m.projection.divergence(s1.v, s1.t)))) < 1e-11 * n
    d0, d1 = m.diagnostics(s0, p), m.diagnostics(s1, p)
    assert float(d1["kinetic_energy"]) > 1e-3
    # carried along by the flow the lid drives (against the lid, below the vortex's centre)
    assert float(d1["solids"][0]["velocity_x"]) < -1e-2
    assert abs(float(d1["solid_area"]) / float(d0["solid_area"]) - 1.0) < 2e-3
    assert abs(float(d1["J_min"]) - 1.0) < 2e-3 and abs(float(d1["J_max"]) - 1.0) < 2e-3


def _tg_run_3d(n, plane, T=0.5, eta=0.1):
    """The Taylor-Green vortex of tests/test_incompressible.py in the ``plane`` (a, b) of a
    triply periodic box, n x n cells in the plane and 8 across: v_a = sin x_a cos x_b,
    v_b = -cos x_a sin x_b, e^(-eta t).  Returns (amplitude error, field L2 error, max |D v|,
    largest velocity across the plane)."""
    import math

    from refmap.grid import Grid3D as G3

    L = 2.0 * math.pi
    cells = [8, 8, 8]
    a, b = plane
    cells[a] = cells[b] = n
    lengths = [L * c / n if k not in plane else L for k, c in enumerate(cells)]
    g = G3(*cells, 0.0, lengths[0], 0.0, lengths[1], 0.0, lengths[2])
    X = g.mesh("node")
    v0 = np.zeros((3, *g.shape()))
    v0[a] = np.sin(X[a]) * np.cos(X[b])
    v0[b] = -np.cos(X[a]) * np.sin(X[b])
    m = Model(g, (), EDGES["periodic"], Numerics(fluid_model="incompressible", dt_fixed=0.05 * g.h),
              initial_velocity=v0)
    p = m.default_params(FluidParams(eta=eta, extra_viscosity=0.0))
    s, info = jax.jit(lambda s: m.advance(s, p, T))(m.initial_state(p))
    v = np.asarray(s.v)
    decay = math.exp(-eta * T)
    amp = float(np.sum(v * v0) / np.sum(v0 * v0))
    field = float(np.sqrt(np.mean((v[[a, b]] - decay * v0[[a, b]]) ** 2)))  # the 2D measure
    div = float(jnp.max(jnp.abs(m.projection.divergence(s.v, s.t))))
    across = [c for c in range(3) if c not in plane][0]
    return abs(amp / decay - 1.0), field, div, float(np.abs(v[across]).max())


@pytest.mark.parametrize("plane", [(0, 2), (1, 2)], ids=["xz", "yz"])
def test_taylor_green_in_a_plane_with_z_matches_the_2d_figures(plane):
    """The Taylor-Green vortex turning in the x-z and y-z planes (so the projection's z
    rows, the z transform of the fast preconditioner and the z faces' wrap all carry the
    flow) decays as the 2D vortex of tests/test_incompressible.py: amplitude errors
    3.71e-2 (16) and 9.27e-3 (32) there; here the same to 1e-6 relative (the plane's 2D
    stencils, the third axis idle), order 2; D v below 1e-10; no velocity across the plane."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_incompressible import _tg_run

    (a16, f16, d16, x16), (a32, f32, d32, x32) = (_tg_run_3d(n, plane) for n in (16, 32))
    for n, a3, f3 in ((16, a16, f16), (32, a32, f32)):
        a2, f2, _ = _tg_run(n)
        assert a3 == pytest.approx(a2, rel=1e-6) and f3 == pytest.approx(f2, rel=1e-6)
    assert a16 == pytest.approx(3.71e-2, rel=0.01) and a32 == pytest.approx(9.27e-3, rel=0.01)
    assert np.log2(a16 / a32) > 1.9
    assert np.log2(f16 / f32) > 0.9
    assert max(d16, d32) < 1e-10
    assert max(x16, x32) < 1e-12
