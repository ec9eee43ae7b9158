"""solid_tiles.mixed_on_windows (docs/design_windows.md, landing 2): the mixed stress,
density and fluid fractions of `Model.derived` computed on one window per solid equal the
full-grid ones to round-off, with discs straddling periodic edges and corners, touching
walls, and overlapping each other's windows."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap import model as model_module
from refmap import solid_tiles, windows
from refmap.boundary import Boundary
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.materials import NeoHookean
from refmap.model import Model, Solid
from refmap.state import Numerics

PERIODIC = Boundary(left="periodic", right="periodic", bottom="periodic", top="periodic")


def _model(boundary, centers, n=64):
    solids = tuple(
        Solid(shape=Disc(center=c, radius=0.3), law=NeoHookean(G=10.0, kappa=10.0, rho0=1.0 + 0.3 * k),
              name=f"d{k}")
        for k, c in enumerate(centers)
    )
    return Model(Grid(n, n), solids, boundary, Numerics())


CASES = {
    # a disc across the x edge, one across the corner, one inside; with a drift so the maps
    # are not the identity
    "periodic": (PERIODIC, [(1.9, 0.2), (-1.95, -1.9), (0.1, 0.3)], (0.4, -0.3)),
    # walls: a disc touching the left wall, one near the top, two close together
    "walls": (Boundary(), [(-1.72, 0.0), (0.5, 1.65), (0.3, -0.6), (0.95, -0.6)], (0.0, -0.5)),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_mixed_fields_on_windows_equal_the_full_grid(name):
    boundary, centers, gravity = CASES[name]
    model = _model(boundary, centers)
    params = model.default_params(gravity=gravity)
    s = jax.jit(model.initial_state)(params)
    # strained maps (a smooth shear and stretch, periodic on the box), then moved a little
    X, Y = (jnp.asarray(a) for a in model.grid.mesh("node"))
    q = jnp.pi / 2
    strain = jnp.stack([0.04 * jnp.sin(q * Y) * jnp.cos(q * X), 0.03 * jnp.sin(q * X)])
    s = s.replace(xi=s.xi + strain[None])
    s = jax.jit(lambda s: model.run_steps(s, params, 20))(s)
    bc, n = model.bc, model.numerics
    h = model.h
    periodic = bc.periodic
    core = model._core(1)
    phip2, xip2 = bc.pad_linear(s.phi), bc.pad_affine(s.xi)
    rng = np.random.default_rng(0)
    cshape = tuple(k + 1 for k in model.grid.shape())
    s_f = [jnp.asarray(rng.normal(size=cshape)) for _ in range(3)]
    full = model._solids_full(s_f, s.rho_f, s.phi, phip2[core], xip2[core], params)["mixed"]

    W = (46, 46)
    reach = solid_tiles.cutoff(n.blend, n.blur_width * h) * (1 - 1e-12)  # 1 - H is 0 from there
    origins, fits = jax.vmap(lambda p: windows.placement(p, reach, W, periodic))(s.phi)
    assert bool(jnp.all(fits))
    rho0 = jnp.stack([jnp.asarray(law.rho0) for law in params.laws])
    got = solid_tiles.mixed_on_windows(
        s_f, s.rho_f, phip2, xip2, model.spacing, origins, W, periodic, params.laws, rho0,
        model_module._solid_stresses, h, n)
    s_mix, rho, wf_c, wf_n = full
    g_mix, g_rho, g_wfc, g_wfn = got
    for a, b in zip(s_mix, g_mix, strict=True):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.asarray(g_rho), np.asarray(rho), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.asarray(g_wfc), np.asarray(wf_c), rtol=0, atol=1e-13)
    np.testing.assert_allclose(np.asarray(g_wfn), np.asarray(wf_n), rtol=0, atol=1e-13)
    # the case is not trivial: solids and their stress are there, and windows wrap / clip
    assert float(jnp.min(wf_n)) < 0.01 and float(jnp.max(jnp.abs(s_mix[0] - wf_c * s_f[0]))) > 1e-3


def test_a_window_too_small_is_seen():
    """With windows that miss part of a solid's blend zone the mixed fields differ (the
    equality above is not automatic), and placement says the windows do not fit."""
    boundary, centers, gravity = CASES["periodic"]
    model = _model(boundary, centers[:1])
    params = model.default_params()
    s = jax.jit(model.initial_state)(params)
    n, h = model.numerics, model.h
    reach = solid_tiles.cutoff(n.blend, n.blur_width * h) * (1 - 1e-12)  # 1 - H is 0 from there
    _, fits = jax.vmap(lambda p: windows.placement(p, reach, (20, 20), model.bc.periodic))(s.phi)
    assert not bool(jnp.any(fits))


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_model_with_solid_windows_steps_as_the_default(name):
    """``Numerics(solid_storage="window")``: the step with the mixed fields on windows
    equals the default step (tiles or the whole grid) to round-off over 15 steps, and a
    window too small for the bodies falls back on the whole grid with the same result."""
    import dataclasses

    boundary, centers, gravity = CASES[name]
    base = _model(boundary, centers)
    params = base.default_params(gravity=gravity)
    win = Model(base.grid, base.solids, boundary, dataclasses.replace(base.numerics, solid_storage="window"))
    assert win.solid_window is not None and base.solid_window is None
    assert all(w < n for w, n in zip(win.solid_window, base.grid.shape(), strict=True))
    small = Model(base.grid, base.solids, boundary, dataclasses.replace(base.numerics, solid_storage="window"))
    small.solid_window = (12, 12)  # far less than a body's blend zone: every step falls back
    out = []
    for m in (base, win, small):
        s = jax.jit(m.initial_state)(params)
        X, Y = (jnp.asarray(a) for a in m.grid.mesh("node"))
        q = jnp.pi / 2
        s = s.replace(xi=s.xi + jnp.stack([0.04 * jnp.sin(q * Y) * jnp.cos(q * X), 0.03 * jnp.sin(q * X)])[None])
        out.append(jax.jit(lambda s, m=m: m.run_steps(s, params, 15))(s))
    a, b, c = out
    for f in ("v", "rho_f", "xi", "phi"):
        ref = np.asarray(getattr(a, f))
        scale = max(float(np.max(np.abs(ref))), 1.0)
        for other in (b, c):
            np.testing.assert_allclose(np.asarray(getattr(other, f)), ref, rtol=0, atol=1e-11 * scale,
                                       err_msg=f)
    assert float(jnp.max(jnp.abs(a.v))) > 1e-3  # the bodies move


def test_solid_storage_is_checked_and_in_case_files():
    from refmap.casefile import case_from_dict

    with pytest.raises(ValueError, match="numerics solid_storage must be 'grid' or 'window', got 'tiles'"):
        Numerics(solid_storage="tiles")
    import dataclasses
    import tomllib

    from refmap.casefile import case_to_toml
    from refmap.scenarios import get_case

    case = get_case("circle", 32)
    case = case.replace(numerics=dataclasses.replace(case.numerics, solid_storage="window"))
    text = case_to_toml(case)
    assert 'solid_storage = "window"' in text
    back = case_from_dict(tomllib.loads(text)).case
    assert back.numerics.solid_storage == "window"
    assert back.build()[0].solid_window is not None


BAND_CASES = {
    # a disc across the x edge, one across the corner, one inside (as CASES["periodic"])
    "periodic": CASES["periodic"],
    # walls: a disc 3.6 cells from the left wall (not glued to it), one near the top, two
    # close together
    "walls": (Boundary(), [(-1.55, 0.0), (0.5, 1.6), (0.3, -0.6), (0.95, -0.6)], (0.0, -0.5)),
}


def _perturbed(m, s):
    """``s`` with a strain added to every map (on the grid; back in the model's storage)."""
    g = m.on_grid(s)
    X, Y = (jnp.asarray(a) for a in m.grid.mesh("node"))
    q = jnp.pi / 2
    g = g.replace(xi=g.xi + jnp.stack([0.04 * jnp.sin(q * Y) * jnp.cos(q * X), 0.03 * jnp.sin(q * X)])[None])
    return m.adopt(g)


def _assert_same_on_grid(a, b, model, atol=1e-11):
    """The whole-grid fields of states ``a`` and ``b`` equal to ``atol`` of each field's
    scale; the maps inside the bands only (the windows leave the identity map outside them,
    the whole grid stale values that no phase reads)."""
    a, b = model.on_grid(a), model.on_grid(b)
    band = np.asarray(a.phi) < model.numerics.phi_max * model.h * (1 - 1e-9)
    for f in ("v", "rho_f", "xi", "phi"):
        ref, got = np.asarray(getattr(a, f)), np.asarray(getattr(b, f))
        if f == "xi":
            keep = np.broadcast_to(band[:, None], ref.shape)
            ref, got = np.where(keep, ref, 0.0), np.where(keep, got, 0.0)
        scale = max(float(np.max(np.abs(ref))), 1.0)
        np.testing.assert_allclose(got, ref, rtol=0, atol=atol * scale, err_msg=f)


@pytest.mark.parametrize("name", sorted(BAND_CASES))
def test_solids_stored_in_windows_step_as_the_whole_grid(name, monkeypatch):
    """``solid_storage = "window"`` stores each solid's map and level set in a window that
    follows its body (``State.origin``) and runs the map advection, pinning,
    re-distancing, extrapolation and smoothing, the stress and blend there.  Outside the
    band the grid's phases change nothing either, so 30 steps equal the whole grid's
    (``band_sweeps = "grid"``) to round-off, with bodies across a periodic edge and corner
    (the window wraps and the map is made continuous in it) and next to a wall (the
    window's ghosts are the grid's linear ones), the band swept on its tiles in the window
    or over the whole window.  (Round-off can flip an ENO stencil choice where two
    differences tie, which moves a map by ~dt h^3 |d^3 xi|; not seen in these runs, whose
    differences stay at 1e-13.)"""
    import dataclasses

    boundary, centers, gravity = BAND_CASES[name]
    base = _model(boundary, centers, n=96)
    base = Model(base.grid, base.solids, boundary, dataclasses.replace(base.numerics, band_sweeps="grid"))
    params = base.default_params(gravity=gravity)
    # the band's tiles swept in each window (band_sweeps "band"; at this size the band holds
    # more than BAND_TILE_FRACTION of a window's tiles, so the limit is lifted), and the whole
    # window ("grid")
    with monkeypatch.context() as mp:
        mp.setattr(model_module, "BAND_TILE_FRACTION", 1.0)
        win = Model(base.grid, base.solids, boundary,
                    dataclasses.replace(base.numerics, solid_storage="window", band_sweeps="band"))
    whole = Model(base.grid, base.solids, boundary, dataclasses.replace(base.numerics, solid_storage="window"))
    assert not win.bc._glue
    assert win.state_window is not None and base.state_window is None
    assert win._band_window_tiles is not None and whole._band_window_tiles is None
    assert all(w < n for w, n in zip(win.state_window, base.grid.shape(), strict=True))
    out = []
    for m in (base, win, whole):
        s = _perturbed(m, jax.jit(m.initial_state)(params))
        assert (s.origin is not None) == (m is not base)
        if m is not base:
            assert s.xi.shape[2:] == m.state_window and s.phi.shape[1:] == m.state_window
        out.append(jax.jit(lambda s, m=m: m.run_steps(s, params, 30))(s))
    a, b, c = out
    for other in (b, c):
        _assert_same_on_grid(a, other, win)
    assert float(jnp.max(jnp.abs(a.v))) > 1e-3  # the bodies move
    assert bool(jnp.all(b.origin >= 0)) and bool(jnp.all(c.origin >= 0))  # every body fits
    # the windows followed the bodies (the drift moves them by several cells)
    s0 = win.initial_state(params)
    assert int(jnp.max(jnp.abs(b.origin - s0.origin))) >= 1
    # the bodies' maps changed inside their bands
    g, g0 = win.on_grid(b), win.on_grid(s0)
    band = np.asarray(g.phi) < 0
    assert float(np.max(np.abs(np.where(band[:, None], np.asarray(g.xi) - np.asarray(g0.xi), 0.0)))) > 1e-3


@pytest.mark.parametrize("name", sorted(BAND_CASES))
def test_band_work_in_batches_of_solids_is_bitwise_the_same(name, monkeypatch):
    """Solids stored in windows have their band work (advection, pinning, re-distancing,
    extrapolation, smoothing, moving the windows) done in batches of at most
    ``model.solid_batch("band")`` solids (``lax.map``), each batch's shape parameters passed with
    it and the last batch padded with copies of the last solid, and their stresses mixed
    batch after batch into the same padded sums (the padding's part multiplied by 0):
    10 steps in batches of 2 (3 or 4 discs: the last batch padded, or not), and with the
    band work one solid at a time (the CPU's default), equal the steps with every solid in
    one batch bit for bit, across a periodic corner and next to walls; a model whose solids are
    of two shape kinds is not batched (its ``_shape_table`` is None)."""
    import dataclasses

    from refmap.geometry import Ellipse

    boundary, centers, gravity = BAND_CASES[name]
    base = _model(boundary, centers, n=96)
    out, traced = [], []
    real = Model._band_on_windows_batch

    def spy(self, xi, *rest):
        traced.append(xi.shape[0])  # the solids of the batch being traced
        return real(self, xi, *rest)

    monkeypatch.setattr(Model, "_band_on_windows_batch", spy)
    mixed, real_mix = [], solid_tiles.window_contributions

    def spy_mix(phiw, *rest):
        mixed.append(phiw.shape[0])  # the solids whose stresses are mixed together
        return real_mix(phiw, *rest)

    monkeypatch.setattr(solid_tiles, "window_contributions", spy_mix)
    for band, mix in ((64, 64), (2, 2), (1, 2)):
        monkeypatch.setattr(model_module, "SOLID_BATCH", {"band": {"other": band}, "mix": {"other": mix}})
        m = Model(base.grid, base.solids, boundary, dataclasses.replace(base.numerics, solid_storage="window"))
        assert m.state_window is not None and m._shape_table() is not None
        params = m.default_params(gravity=gravity)
        s = _perturbed(m, jax.jit(m.initial_state)(params))
        out.append(jax.jit(lambda s, m=m, p=params: m.run_steps(s, p, 10))(s))
    a = out[0]
    assert set(traced) == {len(centers), 2, 1}  # all at once, then batches of 2, then of 1
    assert set(mixed) == {len(centers), 2}  # the stresses' mixing too
    for b in out[1:]:
        for f in ("v", "rho_f", "xi", "phi", "origin"):
            assert np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f))), f
    assert float(jnp.max(jnp.abs(a.v))) > 1e-3  # the bodies move
    mixed = base.solids[:-1] + (dataclasses.replace(
        base.solids[-1], shape=Ellipse(center=centers[-1], semi_axes=(0.3, 0.25), angle=0.2)),)
    assert Model(base.grid, mixed, boundary, Numerics(solid_storage="window"))._shape_table() is None


def test_a_window_too_small_for_a_body_is_refused_and_a_body_that_outgrows_it_stops_the_run(tmp_path):
    """A window that does not hold a body's band (with its margins) is refused with the
    solid's name; a body whose band comes to the edge of its window during a run stops the
    run with a message that names it and the way out, keeping the frames written."""
    import dataclasses

    from refmap.scenarios_fssi import suspension
    from refmap.simulation import Simulation, SimulationBlowUp

    base = _model(Boundary(), [(0.0, 0.0)], n=96)
    m = Model(base.grid, base.solids, Boundary(), dataclasses.replace(base.numerics, solid_storage="window"))
    params = m.default_params()
    s = m.on_grid(m.initial_state(params))
    m.state_window = (30, 30)
    with pytest.raises(ValueError, match=r"solid\(s\) \['d0'\]: the band does not fit the window of \(30, 30\)"):
        m.to_windows(s)

    case = suspension(128, count=4)
    case = case.replace(numerics=dataclasses.replace(case.numerics, solid_storage="window"),
                        t_end=0.02, frames=2)
    sim = Simulation(case, tmp_path / "run", progress=False, pictures=False)
    assert sim.model.state_window is not None
    follow = windows.follow

    def outgrown(*args, **kw):  # every body's band reaches its window's edge
        o, fits = follow(*args, **kw)
        return o, fits & jnp.zeros((), bool)

    import unittest.mock as mock

    with mock.patch.object(model_module.windows, "follow", outgrown), \
            pytest.raises(SimulationBlowUp, match=r"stopped at step 1, t = .*the band of solid 'disc0 .*' no longer "
                                                  r"fits the window of \d+ x \d+ nodes.*solid_storage = 'grid'"):
        sim.run()
    assert (tmp_path / "run" / "frames" / "frame_00000.h5").is_file()


def test_band_windows_are_not_used_with_anchors_glue_or_large_bodies():
    """The band work stays on the whole grid where its windows do not apply: an anchored
    solid (its region is a grid field), a solid glued to a wall at t = 0 (its ghosts are
    not linear), a body whose box is more than half the grid."""
    import dataclasses

    from refmap.anchors import RegionAnchor

    numerics = Numerics(solid_storage="window")
    law = NeoHookean(G=10.0, kappa=10.0, rho0=1.0)
    grid = Grid(96, 96)
    free = Model(grid, (Solid(shape=Disc(center=(0.0, 0.0), radius=0.3), law=law),), Boundary(), numerics)
    assert free.solid_band_window is not None and free._boxes is not None
    anchored = Model(grid, (Solid(shape=Disc(center=(0.0, 0.0), radius=0.3), law=law,
                                  anchor=RegionAnchor(Disc(center=(0.0, 0.0), radius=0.1))),),
                     Boundary(), numerics)
    assert anchored.solid_band_window is None and anchored.solid_window is not None
    glued = Model(grid, (Solid(shape=Disc(center=(-1.8, 0.0), radius=0.3), law=law),), Boundary(), numerics)
    assert glued.bc._glue and glued.solid_band_window is None and glued._boxes is None
    big = Model(grid, (Solid(shape=Disc(center=(0.0, 0.0), radius=1.2), law=law),), Boundary(), numerics)
    assert big.solid_band_window is None and big._boxes is None
    grid_mode = Model(grid, free.solids, Boundary(), dataclasses.replace(numerics, solid_storage="grid"))
    assert grid_mode.solid_band_window is None


@pytest.mark.parametrize("periodic", [False, True])
def test_contact_on_windows_equals_the_grid(periodic):
    """With band windows the contact's pair and wall pressures come from the windows
    (``contact._contact_stress_windows``: the two nearest solids per corner by scatter-min,
    their gradients by scatter-add), equal to the whole grid's: a pair pressed together, a
    disc thrown at the bottom wall (walled box) or across the periodic edge, and a free one."""
    from refmap.contact import Contact, contact_stress

    bnd = PERIODIC if periodic else Boundary()
    law = NeoHookean(G=10.0, kappa=10.0, rho0=1.0)
    discs = [((-0.32, 0.0), (0.5, 0.0)), ((0.32, 0.0), (-0.5, 0.0)), ((0.0, -1.67), (0.0, -0.5)),
             ((1.9 if periodic else 1.5, 1.0), (0.5, 0.0))]
    solids = tuple(Solid(shape=Disc(center=c, radius=0.3), law=law, velocity=v, name=f"d{k}")
                   for k, (c, v) in enumerate(discs))
    out = []
    models = []
    for mode in ("grid", "window"):
        m = Model(Grid(128, 128), solids, bnd, Numerics(solid_storage=mode), body_forces=(Contact(),))
        assert (m.solid_band_window is not None) == (mode == "window")
        assert (m.state_window is not None) == (mode == "window")
        models.append(m)
        params = m.default_params()
        s = jax.jit(m.initial_state)(params)
        s = jax.jit(lambda s, m=m, p=params: m.run_steps(s, p, 10))(s)
        c = jax.jit(lambda s, m=m, p=params: contact_stress(m.body_forces[0], m, s, p))(s)
        out.append((c, jax.jit(lambda s, m=m, p=params: m.run_steps(s, p, 10))(s)))
    (ca, sa), (cb, sb) = out
    assert float(jnp.max(ca["Pi"])) > 0.1  # the pair is in contact
    if not periodic:
        assert float(jnp.max(ca["Pi_wall"])) > 0.1  # and the disc at the wall
    for key in ("Pi", "Pi_wall"):
        np.testing.assert_allclose(np.asarray(cb[key]), np.asarray(ca[key]), rtol=0, atol=1e-12, err_msg=key)
    for key in ("pair", "wall"):
        for x, y in zip(ca[key], cb[key], strict=True):
            np.testing.assert_allclose(np.asarray(y), np.asarray(x), rtol=0, atol=1e-12, err_msg=key)
    _assert_same_on_grid(sa, sb, models[1])


def test_phi0_of_all_solids_batched_by_shape_kind():
    """``Model._phi0_all`` (the pinning of solids stored in windows) evaluates the solids
    whose shapes differ only in their numbers with one ``vmap``: the same values as
    ``phi0`` solid by solid, for discs and ellipses mixed in any order, across a periodic
    corner (every image examined)."""
    from refmap.geometry import Ellipse

    law = NeoHookean(G=10.0, kappa=10.0, rho0=1.0)
    shapes = [Disc(center=(1.9, 1.9), radius=0.3), Ellipse(center=(0.0, 0.5), semi_axes=(0.4, 0.2), angle=0.3),
              Disc(center=(-1.0, 0.2), radius=0.25), Ellipse(center=(1.0, -1.2), semi_axes=(0.3, 0.25), angle=-0.2)]
    m = Model(Grid(96, 96), tuple(Solid(shape=s, law=law, name=f"s{k}") for k, s in enumerate(shapes)),
              PERIODIC, Numerics(solid_storage="window"))
    X, Y = (np.asarray(a) for a in m.grid.mesh("node"))
    xi = jnp.asarray(np.stack([np.stack([X + 0.05 * k + 0.02 * np.sin(Y), Y - 0.03 * k]) for k in range(4)]))
    got = np.asarray(jax.jit(m._phi0_all)(xi))
    ref = np.stack([np.asarray(jax.jit(lambda x, k=k: m.phi0(k, x))(xi[k])) for k in range(4)])
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-14)
    assert np.all(np.min(got, axis=(1, 2)) < 0)  # every body is there


@pytest.mark.parametrize("name", sorted(BAND_CASES))
def test_a_windowed_model_is_built_on_boxes_round_its_bodies(name, monkeypatch):
    """A model that stores its solids in windows forms them at t = 0 on a box round each
    body (``Model._initial_boxes``: no whole-grid array per solid, which for 1000 discs at
    1024^2 would be 24 GB): the window sizes, the initial windows' places and contents and
    the velocity the solids' fractions give are those of the whole grid's construction
    (the maps bit for bit; the level sets re-distanced in a smaller array, to round-off),
    with bodies across periodic edges and corners or near walls, one of them strained at
    t = 0 and each with its own velocity."""
    import dataclasses

    boundary, centers, _ = BAND_CASES[name]
    base = _model(boundary, centers, n=96)
    solids = list(base.solids)
    solids[0] = dataclasses.replace(solids[0], strain=((1.05, 0.1), (0.0, 0.97)))
    solids = tuple(dataclasses.replace(s, velocity=(0.3 - 0.2 * k, 0.1 * k)) for k, s in enumerate(solids))
    numerics = dataclasses.replace(base.numerics, solid_storage="window")
    boxed = Model(base.grid, solids, boundary, numerics)
    assert boxed._boxes is not None and boxed._xi0 is None and boxed._phi_t0 is None
    with monkeypatch.context() as mp:  # the whole grid's construction, as for grid storage
        mp.setattr(Model, "_initial_boxes", lambda self: None)
        whole = Model(base.grid, solids, boundary, numerics)
    assert whole._xi0 is not None
    for name_ in ("state_window", "solid_window", "solid_band_window", "_band_window_tiles"):
        assert getattr(boxed, name_) == getattr(whole, name_), name_
    params = boxed.default_params()
    a, b = (jax.jit(m.initial_state)(params) for m in (whole, boxed))
    np.testing.assert_array_equal(np.asarray(b.origin), np.asarray(a.origin))
    np.testing.assert_array_equal(np.asarray(b.xi), np.asarray(a.xi))
    # measured 1.1e-16 (of phi_max h = 0.5): the same re-distancing sweeps, another array
    np.testing.assert_allclose(np.asarray(b.phi), np.asarray(a.phi), rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.asarray(b.v), np.asarray(a.v), rtol=0, atol=1e-15)
    assert float(jnp.max(jnp.abs(b.v))) > 0.2  # the bodies' velocities are in it
    np.testing.assert_array_equal(np.asarray(b.rho_f), np.asarray(a.rho_f))
    # the boxed model never forms whole-grid coordinates (the grid path's first step)
    monkeypatch.setattr(Grid, "mesh", lambda self, loc="node": (_ for _ in ()).throw(AssertionError("mesh")))
    again = Model(base.grid, solids, boundary, numerics)
    np.testing.assert_array_equal(np.asarray(again.initial_state(params).xi), np.asarray(b.xi))


@pytest.mark.parametrize("periodic", [False, True])
def test_case_check_evaluates_each_shape_on_a_box(periodic):
    """``Case.validate``'s mask of the nodes inside each solid at t = 0 is formed on a box
    round the shape's ``bbox()`` (1000 discs at 1024^2: 1000 small boxes, not 1000 whole
    grids): the same mask as the whole grid's evaluation, for shapes across a periodic
    corner or past a wall, rotated, strained at t = 0, combined, and the rotor."""
    import dataclasses

    from refmap.case import _inside_at_t0
    from refmap.geometry import Capsule, Ellipse, Rectangle, Rotor, Union

    law = NeoHookean(G=10.0, kappa=10.0, rho0=1.0)
    grid = Grid(72, 64)
    boundary = PERIODIC if periodic else Boundary()
    shapes = [
        Disc(center=(1.9, -1.95), radius=0.4),  # across the corner (past the walls)
        Ellipse(center=(0.3, 0.2), semi_axes=(0.9, 0.3), angle=0.7),
        Rectangle(center=(-1.8, 0.5), half_size=(0.5, 0.2), angle=0.3),
        Union(a=Capsule(center=(0.0, -1.0), half_length=0.5, radius=0.15, angle=0.4),
              b=Disc(center=(1.0, 1.0), radius=0.3)),
        Rotor(center=(0.2, 0.0), arm_half_length=1.2, half_width=0.2, fillet_center=0.4),
    ]
    Xn = grid.mesh("node")
    for k, shape in enumerate(shapes):
        solid = Solid(shape=shape, law=law, name=f"s{k}")
        for s in (solid, dataclasses.replace(solid, strain=((1.1, 0.2), (-0.1, 0.9)), strain_center=(0.2, -0.1))):
            want = np.asarray(s.shape(*s.initial_map(*Xn))) < 0
            got = _inside_at_t0(grid, s, Xn, boundary)
            assert want.any()
            np.testing.assert_array_equal(got, want)


def test_solid_batch_sizes_are_checked(monkeypatch):
    """``model.solid_batch`` reads the backend's batch size and refuses a size that is not
    an integer >= 1, naming the entry and the value."""
    table = model_module.SOLID_BATCH["band"]
    assert model_module.solid_batch("band") == table.get(jax.default_backend(), table["other"])
    for bad in (0, 2.0, True):
        monkeypatch.setattr(model_module, "SOLID_BATCH", {"band": {"other": bad}, "mix": {"other": 4}})
        with pytest.raises(ValueError, match=rf"SOLID_BATCH\['band'\]: .* got {bad!r}"):
            model_module.solid_batch("band")
