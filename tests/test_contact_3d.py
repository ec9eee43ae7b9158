"""Contact (refmap.contact) in 3D, and its 2D results bitwise unchanged by the generalisation.

* 2D: every output of the dimension-generic contact term equals, bit for bit, the frozen
  copy of the 2D code (tests/frozen_2d_contact.py) on states of the ``two_balls`` and
  ``suspension`` scenarios with contact active, eager and under jit;
* 3D: two spheres pushed together along the grid's diagonal and along a skew direction
  (force along the line of centres, equal and opposite, momentum conserved, zero far
  apart); a z-invariant pair of cylinders against the 2D pair of discs; a sphere at a
  back / front face; a short collision run; the ``spheres_collide`` scenario end to end.

Grids are small (<= 32 x 32 x 8, 24^3) so that the file runs in CI's default set.
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap.contact as C
from refmap.boundary import Boundary
from refmap.contact import Contact, contact_diagnostics, contact_force, wall_distances
from refmap.geometry import Cylinder, Disc, Sphere
from refmap.grid import Grid, Grid3D
from refmap.materials import NeoHookean
from refmap.model import Model, Solid
from refmap.scenarios import get_case

sys.path.insert(0, str(Path(__file__).resolve().parent))
import frozen_2d_contact as frozen  # noqa: E402

LAW3 = NeoHookean(G=10.0, kappa=10.0, dim=3)
WALLS_3D = dict(back="wall", front="wall")


# ---------------------------------------------------------------- 2D: bitwise unchanged
def _two_balls(where: str, steps: int = 10):
    """``two_balls`` at 48^2 with the mobile ball moved so that contact acts from the start:
    1.5 cells from the anchored ball and a little off its axis (``pair``), or one cell
    above the floor (``floor``); then ``steps`` steps."""
    case = get_case("two_balls", 48)
    fixed, mobile = case.solids
    h = 4.0 / 48
    c = (0.05 - 0.5 - 1.5 * h, 0.07) if where == "pair" else (-1.2, -2.0 + 0.5 + h)
    mobile = Solid(shape=Disc(center=c, radius=0.5), law=mobile.law, name=mobile.name)
    return _stepped(case.replace(solids=(fixed, mobile)), steps)


def _stepped(case, steps):
    model, params = case.build()
    s = jax.jit(model.initial_state)(params)
    if steps:
        s = jax.jit(lambda s: model.run_steps(s, params, steps))(s)
    return model, params, s, case.contact


def _same(a, b, what):
    if a is None or b is None:
        assert a is None and b is None, what
        return
    if isinstance(a, (tuple, list)):
        assert len(a) == len(b), what
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{what}[{k}]")
        return
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype, what
    assert np.array_equal(a, b, equal_nan=True), what


def _compare_with_frozen(model, params, s, ct, modes=("eager", "jit"), full=True):
    """Every output of the contact term -- contact_force's dict (pressures, stresses, the
    two nearest solids, forces), the body-force term and contact_diagnostics -- equal bit
    for bit to the frozen 2D code's, eager and under jit (one function each, so that the
    100-solid case compiles twice, not eight times)."""
    d = jax.jit(model.derived)(s, params)

    def everything(mod, call_term):
        def fn(s, d):
            ctx = dict(state=s, params=params, derived=d, model=model)
            out = (
                mod.contact_force(ct, model, s, params, d),
                ct(ctx) if call_term else mod._total_force(ct, model, s, params, d),
            )
            if full:
                out += (
                    mod._total_force(ct, model, s, params, d),
                    mod.contact_diagnostics(model, s, params, ct, derived=d),
                )
            return out

        return fn

    for mode in modes:
        wrap = jax.jit if mode == "jit" else (lambda f: f)
        new = wrap(everything(C, True))(s, d)
        old = wrap(everything(frozen, False))(s, d)
        names = ("contact_force", "term", "total", "diagnostics")[: len(old)]
        for what, n_, o_ in zip(names, new, old, strict=True):
            if isinstance(o_, dict):
                assert set(n_) == set(o_), what
                for k in o_:
                    _same(n_[k], o_[k], f"{mode} {what} {k}")
            else:
                _same(n_, o_, f"{mode} {what}")
    return old


@pytest.mark.parametrize("where", ["pair", "floor"])
def test_2d_contact_is_bitwise_the_frozen_2d_code_two_balls(where):
    model, params, s, ct = _two_balls(where)
    cf = _compare_with_frozen(model, params, s, ct)[0]
    part = "pair_force" if where == "pair" else "wall_force"
    assert float(jnp.abs(cf[part]).max()) > 0.1  # the part under test is active
    # the 2D output names are unchanged
    assert ct.frame_array_dims(model)["contact_force"] == ("solid", "xy")
    flat = ct.diagnostics(model, s, params)
    assert set(flat["solids"][0]) == {"contact_fx", "contact_fy", "wall_gap"}


def test_2d_contact_is_bitwise_the_frozen_2d_code_suspension():
    """The 100 discs of ``suspension`` (closest pairs 0.7 cells apart at 48^2: many pairs in
    contact from the start, the two-nearest selection at work).  Its initial state (the
    contact term reads only the level sets, and compiling steps of 100 solids takes 30 s),
    under jit only and the force and the model's term only (every 100-solid compile takes
    5-10 s, mostly tracing the 100 laws' moduli; the rest is the code checked on
    two_balls)."""
    model, params, s, ct = _stepped(get_case("suspension", 48), 0)
    cf = _compare_with_frozen(model, params, s, ct, modes=("jit",), full=False)[0]
    assert float(jnp.abs(cf["pair_force"]).max()) > 0.1


# ---------------------------------------------------------------- 3D: a pair of spheres
def _pair_model(direction, gap_cells, n=24, r=0.4, center=(0.03, -0.02, 0.05), boundary=None):
    """Two equal spheres whose centres lie on ``direction`` through ``center``, ``gap_cells``
    cells apart, in [-1, 1]^3 (closed box unless ``boundary`` says otherwise)."""
    u = np.asarray(direction, dtype=float)
    u /= np.linalg.norm(u)
    h = 2.0 / n
    half = 0.5 * (2.0 * r + gap_cells * h)
    c = np.asarray(center)
    solids = tuple(
        Solid(shape=Sphere(center=tuple(c + sign * half * u), radius=r), law=LAW3, name=name)
        for sign, name in ((-1.0, "a"), (1.0, "b"))
    )
    model = Model(Grid3D(n, n, n, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0), solids,
                  boundary or Boundary(**WALLS_3D), body_forces=(Contact(),))
    params = model.default_params()
    return model, params, jax.jit(model.initial_state)(params), u


@pytest.mark.parametrize(
    "direction, gap_cells, transverse",
    [
        # along the grid's diagonal the scheme (bottom-left / top-right stencils included) is
        # symmetric under permutations of the axes: the force is along it to round-off
        ((1.0, 1.0, 1.0), 0.5, 1e-12),
        # a skew direction is no symmetry of the grid: measured transverse / axial 0.010
        # (gap 0.5 cells) and 0.017 (1.5 cells)
        ((0.8, 0.5, 0.33), 0.5, 0.03),
        ((0.8, 0.5, 0.33), 1.5, 0.03),
    ],
)
def test_sphere_pair_force_is_along_the_line_of_centres_and_conserves_momentum(
    direction, gap_cells, transverse
):
    center = (0.01, 0.01, 0.01) if direction == (1.0, 1.0, 1.0) else (0.03, -0.02, 0.05)
    model, params, s, u = _pair_model(direction, gap_cells, center=center)
    dd = contact_diagnostics(model, s, params, Contact())
    F = np.asarray(dd["pair_force"])
    assert F.shape == (2, 3)
    axial = F[0] @ u
    assert axial < -1e-4  # repulsive: a (behind) is pushed back along -u, b along +u
    assert np.linalg.norm(F[0] - axial * u) <= transverse * abs(axial)
    assert np.abs(F[0] + F[1]).max() <= 1e-12 * abs(axial)  # equal and opposite
    # momentum: the force density sums to zero over the grid (a stress divergence whose
    # pressure vanishes on the box's faces), and the spheres are off the walls
    cf = contact_force(Contact(), model, s, params)
    f = np.asarray(cf["force"])
    assert np.abs(np.asarray(cf["wall_force"])).max() == 0.0
    assert np.abs(f.sum(axis=(1, 2, 3))).max() <= 1e-13 * np.abs(f).sum()
    assert np.abs(np.asarray(dd["net_pair_force"])).max() <= 1e-12 * abs(axial)
    assert float(dd["max_contact_pressure"]) > 0.0
    assert 0.0 < float(dd["min_gap"][0, 1]) < (gap_cells + 0.5) * model.h
    assert float(dd["overlap_area"][0, 1]) == 0.0


def test_sphere_pair_five_cells_apart_feels_nothing():
    """Farther apart than the contact's reach (3.3 cells), and over 2 cells off the walls
    (4 from their mirror images): the truncated kernels make the force exactly zero."""
    model, params, s, _ = _pair_model((1.0, 0.2, -0.3), 5.0, r=0.3)
    cf = contact_force(Contact(), model, s, params)
    assert np.all(np.asarray(cf["force"]) == 0.0) and np.all(np.asarray(cf["Pi"]) == 0.0)
    assert np.all(np.asarray(cf["Pi_wall"]) == 0.0)
    dd = contact_diagnostics(model, s, params, Contact())
    assert np.all(np.asarray(dd["force"]) == 0.0)
    assert float(dd["min_gap"][0, 1]) > 4.5 * model.h
    assert float(dd["wall_gap"].min()) > 2.0 * model.h


# ---------------------------------------------------------------- 3D: the 2D limit
def test_z_invariant_cylinders_feel_the_force_of_the_2d_discs():
    """Two discs 0.7 cells apart (one of them 0.8 cells off the floor, so the wall part acts
    too) and the same two cylinders, infinitely long along a periodic z (8 layers): every
    z difference vanishes, so the 3D contact stress and force are the 2D ones, with zero
    z components.  Measured: relative differences 1.3e-15 (pair force), 9e-16 (wall force),
    5e-16 (per-solid forces per unit length); z components exactly 0."""
    n = 32
    h = 2.0 / n
    law2 = NeoHookean(G=10.0, kappa=10.0)
    discs = (((-0.3, -1.0 + 0.35 + 0.8 * h), 0.35), ((-0.3 + 0.35 + 0.4 + 0.7 * h, -0.45), 0.4))
    s2 = tuple(Solid(shape=Disc(center=c, radius=r), law=law2) for c, r in discs)
    s3 = tuple(Solid(shape=Cylinder(center=(*c, 0.0), radius=r, half_length=100.0), law=law2.with_dim(3))
               for c, r in discs)
    m2 = Model(Grid(n, n, -1.0, 1.0, -1.0, 1.0), s2, Boundary(), body_forces=(Contact(),))
    m3 = Model(Grid3D(n, n, 8, -1.0, 1.0, -1.0, 1.0, 0.0, 8 * h), s3,
               Boundary(back="periodic", front="periodic"), body_forces=(Contact(),))
    p2, p3 = m2.default_params(), m3.default_params()
    st2, st3 = jax.jit(m2.initial_state)(p2), jax.jit(m3.initial_state)(p3)
    a = contact_force(Contact(), m2, st2, p2)
    b = contact_force(Contact(), m3, st3, p3)
    for key in ("pair_force", "wall_force"):
        f2, f3 = np.asarray(a[key]), np.asarray(b[key])
        scale = np.abs(f2).max()
        assert scale > 0.1, key  # both parts act
        assert np.abs(f3[2]).max() <= 1e-12 * scale
        err = np.abs(f3[:2] - f2[..., None]).max() / scale
        assert err <= 1e-10, (key, err)
    for key in ("Pi", "Pi_wall"):
        p2_, p3_ = np.asarray(a[key]), np.asarray(b[key])
        assert np.abs(p3_ - p2_[..., None]).max() <= 1e-10 * np.abs(p2_).max(), key
    # the 2D stress components sit at (xx, xy, yy) = positions (0, 1, 3) of the 3D six
    for part in ("pair", "wall"):
        s2_, s3_ = a[part], b[part]
        assert len(s3_) == 6
        scale = max(np.abs(np.asarray(x)).max() for x in s2_)
        for i2, i3 in ((0, 0), (1, 1), (2, 3)):
            assert np.abs(np.asarray(s3_[i3]) - np.asarray(s2_[i2])[..., None]).max() <= 1e-10 * scale
        for i3 in (2, 4, 5):  # xz, yz, zz
            assert np.abs(np.asarray(s3_[i3])).max() <= 1e-12 * scale
    # the per-solid forces of the diagnostics: those of the 2D discs per unit length
    d2 = contact_diagnostics(m2, st2, p2, Contact())
    d3 = contact_diagnostics(m3, st3, p3, Contact())
    F2, F3 = np.asarray(d2["force"]), np.asarray(d3["force"]) / (8 * h)
    assert np.abs(F3[:, :2] - F2).max() <= 1e-10 * np.abs(F2).max()
    assert np.abs(np.asarray(d3["wall_gap"]) - np.asarray(d2["wall_gap"])).max() <= 1e-12


# ---------------------------------------------------------------- 3D: the walls
@pytest.mark.parametrize("face, sign", [("back", 1.0), ("front", -1.0)])
def test_sphere_at_a_back_or_front_face_is_pushed_away_from_it(face, sign):
    """A sphere 0.8 cells from the back (z low) or front (z high) face: the wall part of the
    contact pushes it off that face (along +z at the back, -z at the front; the wall stress
    is -Pi_w e_z (x) e_z, so the x and y components are exactly 0), the same at either
    face (measured 0.010620 both); the six faces are all walls."""
    n = 24
    h = 2.0 / n
    r = 0.4
    z = sign * (-1.0 + r + 0.8 * h)
    solid = Solid(shape=Sphere(center=(0.0, 0.0, z), radius=r), law=LAW3)
    model = Model(Grid3D(n, n, n, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0), (solid,), Boundary(**WALLS_3D),
                  body_forces=(Contact(),))
    params = model.default_params()
    s = jax.jit(model.initial_state)(params)
    walls = wall_distances(model)
    assert [w for _, w in walls] == [
        (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0),
        (0.0, 0.0, 1.0), (0.0, 0.0, -1.0),
    ]
    dd = contact_diagnostics(model, s, params, Contact())
    F = np.asarray(dd["wall_force"])[0]
    assert sign * F[2] > 1e-3
    assert np.all(F[:2] == 0.0)
    assert float(dd["max_wall_pressure"]) > 0.0
    assert float(dd["wall_gap"][0]) == pytest.approx(0.8 * h, abs=0.1 * h)
    # the flat diagnostics and the frame arrays name the z component
    flat = Contact().diagnostics(model, s, params)
    assert float(flat["solids"][0]["contact_fz"]) == pytest.approx(float(dd["force"][0, 2]))
    assert Contact().frame_array_dims(model)["contact_force"] == ("solid", "xyz")
    assert Contact().frame_arrays(model, s, params)["contact_force"].shape == (1, 3)


# ---------------------------------------------------------------- 3D: runs
def test_spheres_thrown_head_on_bounce_without_overlap():
    """Two spheres (radius 0.3, density 2) thrown at each other at speeds +-1 along x from
    2.9 cells apart, in the light fluid of ``spheres_collide`` (rho 0.2, sound speed 5), at
    24^3 to t = 0.15: finite, no node inside both spheres, the contact acting with equal
    and opposite forces, the approach stopped.  Measured: gap 2.60, 2.23, 2.09 cells at
    t = 0.05, 0.1, 0.15 (then the pair bounces: 2.25 at t = 0.2), contact pressure up to
    0.045, the left sphere's mean velocity 0.49 -> 0.04.  At this resolution (radius 3.6
    cells) the squeezed fluid film between the blur zones stops the pair about two cells
    apart even without contact (the same gaps to 3 digits), so this run checks that the
    3D contact term steps stably, not that it is what holds the spheres apart; the forces
    themselves are checked above."""
    base = get_case("spheres_collide", 24)
    law = base.solids[0].law
    solids = tuple(
        Solid(shape=Sphere(center=(sign * 0.42, 0.0, 0.0), radius=0.3), law=law,
              velocity=(-sign * 1.0, 0.0, 0.0), name=name)
        for sign, name in ((-1.0, "left"), (1.0, "right"))
    )
    model, params = base.replace(solids=solids).build()
    assert model.body_forces == (Contact(),)
    h = model.h
    s = jax.jit(model.initial_state)(params)
    adv = jax.jit(lambda s, t: model.advance(s, params, t))
    diag = jax.jit(lambda s: contact_diagnostics(model, s, params, Contact()))
    u0 = float(model.diagnostics(s, params)["solids"][0]["velocity_x"])
    gaps, pressures = [], []
    for t in (0.05, 0.1, 0.15):
        s, info = adv(s, t)
        assert bool(info["ok"])
        for f in ("v", "rho_f", "xi", "phi"):
            assert np.all(np.isfinite(np.asarray(getattr(s, f))))
        dd = diag(s)
        assert float(dd["overlap_area"][0, 1]) == 0.0
        F = np.asarray(dd["pair_force"])
        assert np.abs(F[0] + F[1]).max() <= 1e-12 * np.abs(F[0]).max()
        assert F[0, 0] < 0.0 < F[1, 0]  # repulsive
        gaps.append(float(dd["min_gap"][0, 1]) / h)
        pressures.append(float(dd["max_contact_pressure"]))
    assert min(gaps) > 1.0 and gaps[-1] < gaps[0]
    assert max(pressures) > 0.01
    u1 = float(model.diagnostics(s, params)["solids"][0]["velocity_x"])
    assert u0 > 0.4 and abs(u1) < 0.2 * u0  # stopped


def test_spheres_collide_scenario_short_run_writes_a_readable_run(tmp_path):
    """``spheres_collide``, coarse (16^3, radius 2.4 cells) and short, through Simulation as
    `refmap run` does: finite, the contact numbers in the frames with x, y, z components,
    the fluid mass kept (closed box), no overlap.  (The same case to t = 1: contact from
    the start, smallest gap 0.90 cells, contact pressure up to 1.1, no overlap.)"""
    from refmap.io import open_run
    from refmap.simulation import Simulation

    case = get_case("spheres_collide", 16).replace(t_end=0.1, frames=2)
    assert case.contact == Contact() and case.grid.ndim == 3
    sim = Simulation(case, tmp_path / "run", progress=False, pictures=False, movie=False)
    sim.run()
    ds = open_run(tmp_path / "run")
    assert ds.sizes["time"] == 3 and {"x", "y", "z"} <= set(ds.coords)
    assert np.all(np.isfinite(ds["w"].values))
    f = ds["contact_force"]
    assert f.dims[-2:] == ("solid", "xyz") and f.shape[-1] == 3
    assert np.all(np.isfinite(f.values))
    assert np.all(ds["contact_overlap_area"].values[:, 0, 1] == 0.0)
    assert np.nanmax(np.abs(f.values[-1])) > 0.0  # in contact
    assert abs(sim.conservation["fluid_mass_change"]["relative"]) < 0.01


def test_spheres_settle_scenario_short_run_falls_and_keeps_the_fluid_mass(tmp_path):
    """``spheres_settle``, coarse (16^3) and short, through Simulation as `refmap run` does:
    finite; every sphere (all heavier than the fluid) has started to fall; the contact
    numbers are in the frames with no overlap; the fluid mass is the initial one to
    round-off (``fluid_mass = "conserved"``, exact by construction: the bound is 1e-12 of
    the mass, ~1e4 ulps over the run's ~100 steps); the spheres' volume within 2 %."""
    from refmap.io import open_run
    from refmap.scenarios_3d import SETTLE_SPHERES
    from refmap.simulation import Simulation

    case = get_case("spheres_settle", 16).replace(t_end=0.2, frames=2)
    assert case.contact == Contact() and case.grid.ndim == 3 and case.gravity[1] < 0
    sim = Simulation(case, tmp_path / "run", progress=False, pictures=False, movie=False)
    sim.run()
    ds = open_run(tmp_path / "run")
    assert ds.sizes["time"] == 3 and ds.sizes["solid"] == len(SETTLE_SPHERES)
    assert np.all(np.isfinite(ds["v"].values))
    vy = ds["solid_velocity"].values[-1, :, 1]
    assert np.all(vy < -0.01), vy
    assert np.all(np.nan_to_num(ds["contact_overlap_area"].values) == 0.0)
    c = sim.conservation
    assert abs(c["fluid_mass_change"]["relative"]) < 1e-12
    assert abs(c["solid_area_change"]["relative"]) < 0.02
