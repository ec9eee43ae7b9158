"""The 3D step: exact checks (rigid motion, uniform strain, rest, sound) and the 2D limit.

Grids are small (<= 24^3) so that the file runs in CI's default set.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from refmap.boundary import Boundary
from refmap.geometry import Cylinder, Disc, Ellipsoid, Sphere
from refmap.grid import Grid, Grid3D
from refmap.materials import LogNeoHookean, NeoHookean
from refmap.model import Model, Solid
from refmap.state import FluidParams, Numerics

PERIODIC_3D = dict(left="periodic", right="periodic", bottom="periodic", top="periodic",
                   back="periodic", front="periodic")
WALLS_3D = dict(back="wall", front="wall")


def _rotation(axis, theta):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(theta) * K + (1 - math.cos(theta)) * K @ K


def _rigid_ellipsoid_model(n=24, periodic=False, center=(0.07, -0.11, 0.05)):
    """An ellipsoid moved rigidly: xi(x) = R^T (x - c) + c, R a rotation about a skew axis
    through c (in 3D, I - R^T is singular, so a rotation and a shift cannot be folded into
    one centre as the 2D test does; a rotation about an off-centre point is as general)."""
    A = _rotation((1.0, 2.0, 0.5), 0.6).T
    cc = np.asarray(center)
    shape = Ellipsoid(center=(0.0, 0.0, 0.0), semi_axes=(0.4, 0.3, 0.25), angle=0.3)
    solid = Solid(shape=shape, law=NeoHookean(G=10.0, kappa=10.0, dim=3),
                  strain=tuple(map(tuple, A)), strain_center=tuple(cc))
    bnd = Boundary(**(PERIODIC_3D if periodic else WALLS_3D))
    model = Model(Grid3D(n, n, n, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0), (solid,), bnd)
    return model, model.default_params()


def _band_stress(model, params, state):
    d = jax.jit(model.derived)(state, params)
    sig = np.asarray(d["sigma_s"][0])
    valid = np.asarray(d["valid"][0])
    return np.abs(sig[valid]).max(), valid.sum(), np.asarray(d["phic"][0])[valid].max()


def test_rigid_motion_is_stress_free_in_solid_and_band_3d():
    model, params = _rigid_ellipsoid_model()
    state = model.initial_state(params)
    state = state.replace(xi=jax.jit(model.extrapolate)(state.xi, state.phi))
    smax, count, reach = _band_stress(model, params, state)
    assert count > 1000
    assert reach > 4.0 * model.h  # the check covers the extrapolated band, not only the solid
    assert smax < 1e-9


def test_translating_body_in_periodic_box_stays_stress_free_3d():
    """Uniform motion of fluid and solid in a triply periodic box: sigma stays 0."""
    model, params = _rigid_ellipsoid_model(n=20, periodic=True)
    state = model.initial_state(params)
    U = jnp.array([0.37, -0.21, 0.29])
    state = state.replace(v=jnp.broadcast_to(U[:, None, None, None], state.v.shape))
    state = jax.jit(lambda s: model.run_steps(s, params, 12))(state)
    smax, count, _ = _band_stress(model, params, state)
    assert count > 300
    assert smax < 1e-8
    assert np.allclose(state.v, U[:, None, None, None], atol=1e-10)
    assert np.allclose(state.rho_f, 1.0, atol=1e-12)


def test_strained_body_has_the_law_stress_3d():
    A = np.array([[0.9, 0.2, 0.05], [0.0, 1.1, -0.1], [0.1, 0.0, 0.95]])
    law = LogNeoHookean(G=10.0, kappa=10.0, dim=3)
    solid = Solid(shape=Sphere(radius=0.5), law=law, strain=tuple(map(tuple, A)))
    model = Model(Grid3D(16, 16, 16, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0), (solid,), Boundary(**WALLS_3D))
    params = model.default_params()
    d = model.derived(model.initial_state(params), params)
    expected = np.asarray(law.stress(jnp.asarray(np.linalg.inv(A))))
    sig = np.asarray(d["sigma_s"][0])
    inside = np.asarray(d["phic"][0]) < 0
    assert inside.sum() > 100
    assert np.allclose(sig[inside], expected, atol=1e-10)
    J = np.asarray(d["J"][0])[inside]
    assert np.allclose(J, 1.0 / np.linalg.det(A), rtol=1e-12)


def test_fluid_at_rest_stays_at_rest_3d():
    model = Model(Grid3D(10, 10, 10), (), Boundary(**WALLS_3D))
    params = model.default_params()
    s = jax.jit(lambda s: model.run_steps(s, params, 5))(model.initial_state(params))
    assert np.abs(np.asarray(s.v)).max() == 0.0
    assert np.allclose(s.rho_f, 1.0)


def test_fluid_sound_wave_speed_along_z():
    """A standing acoustic mode along z oscillates at omega = k sqrt(lambda_f / rho0):
    rho' = eps cos(k z) crosses zero first at t0 = pi / (2 omega) = 0.5 (c = 2, k = pi / 2);
    the 3D twin of the 2D test along x (dispersion error ~1e-3 at k h = 0.05)."""
    g = Grid3D(8, 8, 128, 0.0, 0.25, 0.0, 0.25, 0.0, 4.0)
    fl = FluidParams(rho0=1.0, lambda_f=4.0, eta=0.01, extra_viscosity=0.0)
    model = Model(g, (), Boundary(**PERIODIC_3D), Numerics(cfl=0.2))
    params = model.default_params(fl)
    s = model.initial_state(params)
    Z = g.mesh("node")[2]
    k = 2 * np.pi / 4.0
    mode = np.cos(k * Z)
    s = s.replace(rho_f=jnp.asarray(1.0 + 1e-4 * mode))
    adv = jax.jit(model.advance)

    def amplitude(T):
        s2, info = adv(s, params, T)
        assert bool(info["ok"])
        return np.sum((np.asarray(s2.rho_f) - 1.0) * mode) / np.sum(mode * mode)

    a1, a2 = amplitude(0.45), amplitude(0.55)
    assert a1 > 0 > a2
    t0 = 0.45 + 0.1 * a1 / (a1 - a2)
    assert np.pi / (2 * t0) / k == pytest.approx(2.0, rel=0.01)


@pytest.mark.parametrize("viscosity", ["explicit", "implicit", "implicit-fast", "incompressible"])
def test_z_invariant_3d_run_matches_the_2d_run(viscosity):
    """A strained disc (2D, plane strain) and the same strained cylinder, infinitely long
    along a periodic z (3D, 8 layers), follow the same motion: in 3D every z difference
    of a z-invariant field is exactly 0 and the 3D laws restricted to F_zz = 1 are the
    plane-strain 2D ones, so the two runs differ only by round-off (the 3D averages sum 8
    corners instead of 4, the 3D extrapolation takes more sweeps).  Tolerance: relative
    1e-6 of each field's scale after 15 steps of a fixed dt.  With implicit viscosity the
    3D backward-Euler solve (BiCGSTAB, Jacobi preconditioner, converged to 1e-12) must give
    the 2D solve's velocity too, at a step 5 times the explicit viscous limit, with either
    preconditioner (the "fast" one with a z transform in 3D).  With the
    incompressible fluid (explicit viscosity) the 3D projection (its z faces periodic, the
    fast preconditioner with a z transform, CG to 1e-10) must give the 2D projection's
    velocity: the z row of D and of G vanish on a z-invariant field."""
    n = 32
    A2 = np.array([[1.1, 0.15], [0.0, 0.92]])
    A3 = np.eye(3)
    A3[:2, :2] = A2
    c2 = (0.1, 0.0)
    law = NeoHookean(G=5.0, kappa=5.0)
    s2 = Solid(shape=Disc(center=c2, radius=0.6), law=law, strain=tuple(map(tuple, A2)), strain_center=c2)
    s3 = Solid(shape=Cylinder(center=(*c2, 0.0), radius=0.6, half_length=100.0), law=law.with_dim(3),
               strain=tuple(map(tuple, A3)), strain_center=(*c2, 0.0))
    h = 2.0 / n
    if viscosity == "incompressible":
        num = Numerics(fluid_model="incompressible")
    elif viscosity == "implicit-fast":
        num = Numerics(viscosity="implicit", viscosity_rtol=1e-12, viscosity_preconditioner="fast")
        viscosity = "implicit"
    else:
        num = Numerics(viscosity=viscosity, viscosity_rtol=1e-12)
    m2 = Model(Grid(n, n, -1.0, 1.0, -1.0, 1.0), (s2,), Boundary(), num)
    m3 = Model(Grid3D(n, n, 8, -1.0, 1.0, -1.0, 1.0, 0.0, 8 * h), (s3,),
               Boundary(back="periodic", front="periodic"), num)
    fluid = FluidParams(eta=0.5, extra_viscosity=0.1)  # a viscous limit well below the others
    p2, p3 = m2.default_params(fluid), m3.default_params(fluid)
    dt = 0.2 * Model(m2.grid, (s2,), Boundary()).time_step(m2.initial_state(p2), p2)[0]
    if viscosity == "implicit":
        dt = 5 * h * h * 1.0 / (4 * (0.5 + 0.1))
    run2 = jax.jit(lambda s: jax.lax.fori_loop(0, 15, lambda i, s: m2.step(s, p2, dt), s))
    run3 = jax.jit(lambda s: jax.lax.fori_loop(0, 15, lambda i, s: m3.step(s, p3, dt), s))
    a = run2(m2.initial_state(p2))
    b = run3(m3.initial_state(p3))
    # z-invariant
    disp = np.asarray(b.xi) - np.stack(m3.grid.mesh("node"))[None]  # xi_z = z is not invariant
    for f in (b.v, b.rho_f, disp, b.phi):
        f = np.asarray(f)
        assert np.abs(f - f[..., :1]).max() <= 1e-12 * max(np.abs(f).max(), 1.0)
    assert np.abs(np.asarray(b.v[2])).max() < 1e-12
    for name, f2, f3 in (("v", a.v, b.v[:2]), ("rho_f", a.rho_f, b.rho_f), ("phi", a.phi, b.phi),
                         ("xi", a.xi, b.xi[:, :2])):
        f2 = np.asarray(f2)
        f3 = np.asarray(f3)[..., 0]
        scale = max(np.abs(f2).max(), 1e-3)
        err = np.abs(f3 - f2)
        if name == "xi":
            # the material's own maps to 1e-6; the extrapolated band to 1e-5: the 3D
            # extrapolation sweeps ceil(sqrt(3) band / h) + 3 times instead of
            # ceil(sqrt(2) band / h) + 3, which settles the outer band nodes a little
            # further (measured 1.4e-6 with implicit viscosity's larger step)
            inside = np.asarray(a.phi)[:, None] < 0
            assert err[np.broadcast_to(inside, err.shape)].max() <= 1e-6 * scale, name
            assert err.max() <= 1e-5 * scale, name
            continue
        assert err.max() <= 1e-6 * scale, name
    assert np.abs(np.asarray(a.v)).max() > 1e-3  # it moved


def test_sheared_sphere_relaxes_in_a_closed_box():
    """A sphere released from an isochoric shear in a closed box: the step stays finite, the
    elastic energy is released into motion and damped, the fluid mass is kept to the
    scheme's (advective, not conservative) accuracy."""
    A = np.array([[1.0, 0.25, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    solid = Solid(shape=Sphere(radius=0.45), law=NeoHookean(G=5.0, kappa=5.0, dim=3),
                  strain=tuple(map(tuple, A)))
    model = Model(Grid3D(16, 16, 16, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0), (solid,), Boundary(**WALLS_3D))
    params = model.default_params()
    s0 = model.initial_state(params)
    d0 = model.diagnostics(s0, params)
    s1, info = jax.jit(model.advance)(s0, params, 0.3)
    assert bool(info["ok"])
    d1 = model.diagnostics(s1, params)
    e0 = float(d0["elastic_energy"] + d0["kinetic_energy"])
    e1 = float(d1["elastic_energy"] + d1["kinetic_energy"])
    assert float(d0["elastic_energy"]) > 0
    assert float(d1["kinetic_energy"]) > 1e-3 * e0  # it moved
    assert e1 < e0  # viscous: no energy gained
    assert float(d1["fluid_mass"]) == pytest.approx(float(d0["fluid_mass"]), rel=2e-2)
    row = d1["solids"][0]
    assert {"centroid_z", "velocity_z"} <= set(row)
    # the shear in the x-y plane is symmetric under z -> -z, but the scheme is not exactly:
    # its corner gradient and node divergence are one-sided (the bottom-left / top-right
    # pair), an O(h) bias on a motion of amplitude ~0.1 (measured drift 1.7e-4 = 1.4e-3 h)
    assert abs(float(row["centroid_z"])) < 0.01 * model.h


def test_3d_settings_not_yet_available_are_named():
    solid = Solid(shape=Sphere(radius=0.4), law=NeoHookean(G=1.0, kappa=1.0, dim=3))
    g = Grid3D(8, 8, 8)
    with pytest.raises(ValueError, match="band_force 'solid'"):
        Model(g, (solid,), Boundary(**WALLS_3D), Numerics(band_force="solid"))
    with pytest.raises(ValueError, match="is 2D"):  # a plane-strain law on a 3D shape
        Solid(shape=Sphere(radius=0.4), law=NeoHookean(G=1.0, kappa=1.0))
    with pytest.raises(ValueError, match="3 finite numbers"):
        Solid(shape=Sphere(radius=0.4), law=NeoHookean(G=1.0, kappa=1.0, dim=3), velocity=(1.0, 0.0))
    with pytest.raises(ValueError, match="grid is 3D"):
        Model(g, (Solid(shape=Disc(radius=0.4), law=NeoHookean(G=1.0, kappa=1.0)),), Boundary(**WALLS_3D))
    with pytest.raises(ValueError, match="3 components"):
        Model(g, (solid,), Boundary(**WALLS_3D)).default_params(gravity=(0.0, -1.0))


@pytest.mark.parametrize("name", ["sphere_relax", "sphere_cavity", "cross"])
def test_3d_scenario_short_run_writes_a_readable_run(name, tmp_path):
    """Each 3D scenario, coarse and short, through Simulation as `refmap run` does: finite,
    closed box so the fluid mass is kept to the scheme's accuracy, the solid's volume
    bounded, and the run folder holds 3D frames that read back with x, y, z coordinates,
    an XDMF with a 3D mesh, and pictures."""
    import xml.etree.ElementTree as ET

    from refmap.io import open_run
    from refmap.scenarios import get_case
    from refmap.simulation import Simulation

    case = get_case(name, 16).replace(t_end=0.1, frames=2)
    sim = Simulation(case, tmp_path / "run", progress=False, pictures=True, movie=False)
    sim.run()
    ds = open_run(tmp_path / "run")
    assert ds.sizes["time"] == 3 and {"x", "y", "z"} <= set(ds.coords)
    assert {"u", "v", "w", "sigma_xz", "xi_z"} <= set(ds.data_vars)
    assert np.all(np.isfinite(ds["w"].values))
    topo = ET.parse(tmp_path / "run" / "run.xdmf").getroot().find(".//Topology")
    assert topo.get("TopologyType") == "3DCoRectMesh"
    assert any((tmp_path / "run").glob("*.png"))
    # closed boxes: the fluid mass moves only by the non-conservative advection (2D:
    # 0.02-0.3 % per unit time); the solid's volume ("area" in any dimension) by the blur
    c = sim.conservation
    assert abs(c["fluid_mass_change"]["relative"]) < 0.01
    assert abs(c["solid_area_change"]["relative"]) < 0.05
    a = ds["solid_area"].values[:, 0]
    assert 0.95 < a[-1] / a[0] < 1.05


def _load_validation(name):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "validation" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("wave_axis, disp_axis", [(2, 0), (0, 1)])
def test_3d_shear_wave_converges_at_second_order(wave_axis, disp_axis):
    """The finite-amplitude shear wave (exact, a k = 0.31) travelling along z (displacement
    along x) and along x (displacement along y), forward Euler with the least stabilising
    viscosity against the damped exact wave (validation/shear_wave.py).  Measured relative
    max errors of the velocity 1.543e-2 (32 cells) and 3.972e-3 (64): order 1.96, equal to
    the 2D figures (the wave sees the same 1D stencils).  Issue 12 asks for >= 1.9."""
    sw = _load_validation("shear_wave")
    e32 = sw.run(32, dim=3, wave_axis=wave_axis, disp_axis=disp_axis)
    e64 = sw.run(64, dim=3, wave_axis=wave_axis, disp_axis=disp_axis)
    assert e64[0] < 0.0046 and e64[1] < 0.0046
    assert sw.orders([32, 64], [e32[0], e64[0]])[0] >= 1.9
    assert e64[2] < 1e-9  # no velocity across the displacement appears


def test_3d_pivot_holds_the_axle_and_lets_the_body_turn():
    """PivotAnchor in 3D (an axle along z): a held node's velocity is the rigid rotation
    omega z x r about the axle, with omega the least-squares fit over the fit cylinder; a
    rigidly rotating field is left as it is; nodes beyond the axle's length are free."""
    from refmap.anchors import PivotAnchor

    g = Grid3D(16, 16, 16, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0)
    X, Y, Z = g.mesh("node")
    pivot = PivotAnchor(center=(0.1, 0.0, 0.0), fit_radius=0.4, hold_radius=0.3, half_length=0.5)
    rot = np.stack([-0.7 * Y, 0.7 * (X - 0.1), np.zeros_like(X)])
    v, _ = pivot.apply(g, jnp.asarray(rot), None, None)
    assert np.allclose(np.asarray(v), rot, atol=1e-13)
    rng = np.random.default_rng(0)
    noise = rng.normal(size=rot.shape)
    v, _ = pivot.apply(g, jnp.asarray(rot + noise), None, None)
    w = pivot.velocity_weight(g)
    held = w == 1.0
    r = np.stack([X - 0.1, Y])
    omega = (np.asarray(v)[1][held] / r[0][held])[np.abs(r[0][held]) > 0.05]
    assert np.allclose(omega, omega[0], rtol=1e-10)  # one rigid rotation on the held nodes
    assert abs(omega[0] - 0.7) < 0.2  # the fit averages the noise out (hundreds of nodes)
    assert np.asarray(v)[2][held].max() == 0.0  # no motion along the axle
    assert np.all(w[np.abs(Z) > 0.5] == 0.0)
    assert np.array_equal(np.asarray(v)[:, w == 0.0], (rot + noise)[:, w == 0.0])
    with pytest.raises(ValueError, match="2 coordinates, the grid is 3D"):
        PivotAnchor(center=(0.0, 0.0)).velocity_weight(g)
    with pytest.raises(ValueError, match="hold_map is 2D only"):
        PivotAnchor(center=(0.0, 0.0, 0.0), hold_map=True)


def test_band_window_gives_the_full_grid_result():
    """3D extrapolation on a box round each band (Model.band_window) equals the full-grid
    sweeps exactly: two small spheres thrown at each other, one sheared (measured on 48^3:
    identical to the last bit after 0.2 time units, the step 2.2 times faster on one
    core).  At 24^3 the automatic box would not pay (the band is 6 cells on each side),
    so the test sets one that holds the bands with a few nodes to spare and checks that it
    was used; a box too small for the bands falls back on the full grid."""
    from refmap import extrapolation

    law = NeoHookean(G=5.0, kappa=5.0, dim=3)
    A = ((1.0, 0.2, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    solids = (Solid(shape=Sphere(center=(-0.55, 0.1, 0.0), radius=0.3), law=law, strain=A,
                    strain_center=(-0.55, 0.1, 0.0), velocity=(0.3, 0.0, 0.0)),
              Solid(shape=Sphere(center=(0.55, -0.1, 0.15), radius=0.3), law=law,
                    velocity=(-0.3, 0.0, 0.0), name="b"))
    big = Model(Grid3D(48, 48, 48, -1.5, 1.5, -1.5, 1.5, -1.5, 1.5), solids, Boundary(**WALLS_3D))
    # at 48^3 "auto" tiles these bands (test_narrowband.py); the box is what it would use
    # were tiles refused
    assert big.band_capacity is not None and big.band_window is None
    window = big._initial_band_window()
    assert window is not None and np.prod(window) < 0.6 * 48**3
    g = Grid3D(24, 24, 24, -1.5, 1.5, -1.5, 1.5, -1.5, 1.5)
    mw = Model(g, solids, Boundary(**WALLS_3D))
    assert mw.band_capacity is None  # 27 tiles, all but listed: not tiled
    mg = Model(g, solids, Boundary(**WALLS_3D), Numerics(band_sweeps="grid"))
    mw.band_window = (22, 21, 22)
    band = mw.numerics.band * mw.h
    p = mw.default_params()
    s = mw.initial_state(p)
    _, fits, _ = extrapolation.window_placement(s.phi, band, mw.band_window, (False,) * 3)
    assert bool(np.all(fits))
    a, _ = jax.jit(mw.advance)(s, p, 0.1)
    b, _ = jax.jit(mg.advance)(s, p, 0.1)
    _, fits, _ = extrapolation.window_placement(a.phi, band, mw.band_window, (False,) * 3)
    assert bool(np.all(fits))
    for f in ("v", "xi", "phi", "rho_f"):
        assert np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f))), f
    # a window smaller than the bands: the full grid
    f = a.xi - jnp.stack([jnp.asarray(x) for x in g.mesh("node")])[None]
    kw = dict(dz=g.dz, periodic=(False, False, False))
    full = extrapolation.extend(f, a.phi, g.dx, g.dy, band, **kw)
    _, fits, _ = extrapolation.window_placement(a.phi, band, (6, 6, 6), (False,) * 3)
    assert not bool(np.any(fits))
    small = extrapolation.extend(f, a.phi, g.dx, g.dy, band, window=(6, 6, 6), **kw)
    # (eager against the compiled branch of a lax.cond: equal to round-off, not bitwise)
    assert np.abs(np.asarray(full) - np.asarray(small)).max() <= 1e-13 * np.abs(np.asarray(full)).max()


def test_relative_gravity_conserves_momentum_and_settles_a_sphere():
    """refmap.gravity.RelativeGravity in a triply periodic box: the force sums to zero (the
    mixture's mean weight is held by the uniform pressure gradient), the grid's total
    momentum stays zero, and a sphere twice as dense as the fluid settles downward.  Its
    speed against Hasimoto's periodic-array drag (validation/settling_sphere.py): measured
    -30.9 % at 6.4 cells across the sphere (16^3, t = 0.6), -23.6 % at 9.6 (24^3): the
    blurred interface makes the sphere hydrodynamically larger by about a cell; the bound
    below (within 40 %, and downward) is for this coarse CI grid."""
    ss = _load_validation("settling_sphere")
    model, params = ss.build(16)
    s = model.initial_state(params)
    f = model.body_forces[0](dict(state=s, params=params, derived=model.derived(s, params), model=model))
    assert np.abs(np.asarray(jnp.sum(f, axis=(1, 2, 3)))).max() < 1e-12 * np.abs(np.asarray(f)).sum()
    out = ss.run(16, t_end=0.6, log=lambda m: None)
    assert 0.6 < out["U"] / out["exact"] < 1.4
    s2, _ = jax.jit(model.advance)(s, params, 0.05)
    mom = np.asarray(jnp.sum(model.derived(s2, params)["rho"][None] * s2.v, axis=(1, 2, 3)))
    assert np.abs(mom).max() < 1e-3 * float(jnp.sum(model.derived(s2, params)["rho"])) * out["exact"]
