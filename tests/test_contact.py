"""Contact between solids (thesis 4.11): refmap.contact and the FSSI scenarios.

All runs are small (32^2 to 48^2) and short; every model is compiled once and shared
through module-scoped fixtures, so the file runs in about a minute and a half on 2 cores.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401
from refmap.boundary import Boundary
from refmap.case import CaseError
from refmap.contact import Contact, contact_diagnostics, contact_force
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.materials import NeoHookean
from refmap.model import Model, Solid, solid_fractions
from refmap.scenarios import SCENARIOS, get_case

LAW = NeoHookean(G=10.0, kappa=10.0)
PERIODIC = Boundary(left="periodic", right="periodic", bottom="periodic", top="periodic")


def _disc(center, radius, law=LAW, **kw):
    return Solid(shape=Disc(center=center, radius=radius), law=law, **kw)


def _init(model, params):
    return jax.jit(model.initial_state)(params)


# ---------------------------------------------------------------- pair search
@pytest.mark.parametrize("n_solids, shape", [(2, (6, 7)), (5, (4, 5, 3)), (40, (9, 8))])
@pytest.mark.parametrize("step", [0.5, 1e-7])
def test_two_nearest_equals_two_argmin_passes(n_solids, shape, step):
    """The one-pass search of the two nearest solids gives the indices of two argmin passes
    (the second with the first's masked out), ties to the lower index: values on a coarse
    lattice make many ties, a row of +inf makes every value tie."""
    from refmap.contact import _two_nearest

    rng = np.random.default_rng(n_solids)
    phi = np.round(rng.normal(size=(n_solids, *shape)) / step) * step
    phi[:, 0] = np.inf
    phi[1:, -1] = phi[0, -1]  # every solid ties with the first
    phi = jnp.asarray(phi)
    a, b = jax.jit(_two_nearest)(phi)
    a_ref = jnp.argmin(phi, axis=0)
    k = jnp.arange(n_solids).reshape((-1,) + (1,) * len(shape))
    b_ref = jnp.argmin(jnp.where(k == a_ref[None], jnp.inf, phi), axis=0)
    assert a.dtype == a_ref.dtype and b.dtype == b_ref.dtype
    np.testing.assert_array_equal(a, a_ref)
    np.testing.assert_array_equal(b, b_ref)
    assert bool(jnp.all(a[0] == 0)) and bool(jnp.all(b[0] == 0))  # the +inf row


# ---------------------------------------------------------------- mixing rule
def test_solid_fractions_partition_of_unity_with_overlapping_blur_zones():
    """Three discs whose blur zones overlap (two of them even overlap as bodies): the node
    and corner weights stay a partition of unity in [0, 1]; where sum(1 - H_k) > 1 the
    fluid weight is 0 and the solid fractions keep their ratios (renormalisation)."""
    solids = (_disc((-0.35, 0.0), 0.45), _disc((0.4, 0.0), 0.4), _disc((0.0, 0.8), 0.33))
    model = Model(Grid(40, 40), solids)
    params = model.default_params()
    state = _init(model, params)
    d = jax.jit(model.derived)(state, params)
    for ws, wf in ((d["ws_n"], d["wf_n"]), (d["ws_c"], d["wf_c"])):
        ws, wf = np.asarray(ws), np.asarray(wf)
        assert np.allclose(ws.sum(axis=0) + wf, 1.0, atol=1e-14)
        assert ws.min() >= 0.0 and wf.min() >= 0.0 and ws.max() <= 1.0 and wf.max() <= 1.0
    raw = 1.0 - np.asarray(d["Hn"])
    over = raw.sum(axis=0) > 1.0 + 1e-12
    assert over.sum() > 10  # the blur zones do overlap
    ws = np.asarray(d["ws_n"])
    assert np.abs(np.asarray(d["wf_n"])[over]).max() < 1e-15
    assert np.allclose(ws[:, over] * raw[:, over].sum(axis=0), raw[:, over], atol=1e-14)
    # solid_fractions on arbitrary weights, including N = 1 and fully solid points
    H = jnp.asarray(np.random.default_rng(3).uniform(0, 1, size=(4, 12, 12)))
    for h in (H, H[:1], jnp.zeros((2, 3, 3))):
        ws, wf = solid_fractions(h)
        assert np.allclose(np.asarray(jnp.sum(ws, axis=0) + wf), 1.0, atol=1e-14)


# ---------------------------------------------------------------- the force itself
def test_contact_parameters_are_checked():
    with pytest.raises(ValueError, match="width"):
        Contact(width=0.0)
    with pytest.raises(ValueError, match="strength"):
        Contact(strength=-1.0)
    with pytest.raises(ValueError, match="cutoff"):
        Contact(cutoff=1.0)
    with pytest.raises(ValueError, match="reach"):
        Contact(reach=float("nan"))


def test_pair_forces_are_equal_and_opposite():
    """Two pairs of unequal discs, one nearly touching and one overlapping by two cells: each
    pair's forces sum to zero to round-off, push the two bodies apart, and a fifth body
    far from everything feels nothing."""
    h = 4.0 / 48
    solids = (
        _disc((-1.0, 0.9), 0.5),
        _disc((-1.0 + 0.5 + 0.35 + 0.5 * h, 0.75), 0.35),  # gap h/2, off-centre
        _disc((0.2, -0.9), 0.6),
        _disc((0.2 + 0.6 + 0.4 - 2.0 * h, -0.6), 0.4),  # overlaps by two cell widths
        _disc((-1.2, -1.0), 0.3),
    )
    model = Model(Grid(48, 48), solids, body_forces=(Contact(),))
    params = model.default_params()
    state = _init(model, params)
    cf = jax.jit(lambda s: contact_force(Contact(), model, s, params))(state)
    f = np.asarray(cf["pair_force"])
    total = np.abs(f).sum()
    assert total > 1.0
    assert np.abs(f.sum(axis=(1, 2))).max() < 1e-12 * total
    dd = jax.jit(lambda s: contact_diagnostics(model, s, params))(state)
    F = np.asarray(dd["pair_force"])
    for i, j in ((0, 1), (2, 3)):
        scale = np.abs(F[i]).max()
        assert scale > 1e-3
        assert np.abs(F[i] + F[j]).max() < 1e-12 * scale
        ci, cj = np.asarray(solids[i].shape.center), np.asarray(solids[j].shape.center)
        assert np.dot(F[j] - F[i], cj - ci) > 0  # repulsive
    assert np.all(F[4] == 0.0)
    assert np.asarray(dd["min_gap"])[0, 1] > 0 > np.asarray(dd["min_gap"])[2, 3]
    assert float(dd["overlap_area"][2, 3]) > 0 == float(dd["overlap_area"][0, 1])
    # the solids are far from the walls: no wall force at all
    assert np.all(np.asarray(cf["wall_force"]) == 0.0)
    # the flat form for Model.diagnostics
    flat = jax.jit(lambda s: Contact().diagnostics(model, s, params))(state)
    assert float(flat["contact_min_gap"]) == pytest.approx(float(dd["min_gap"][2, 3]))
    assert float(flat["contact_max_pressure"]) > 0.0
    assert [float(p["contact_fx"]) for p in flat["solids"]] == pytest.approx(list(F[:, 0]))


def test_one_solid_with_contact_equals_no_contact():
    """With a single solid away from the walls contact does nothing, exactly."""
    solid = _disc((0.2, 0.1), 0.7, strain=((0.9, 0.15), (0.0, 1.1)), velocity=(0.3, -0.2))
    runs = []
    for forces in ((), (Contact(),)):
        model = Model(Grid(32, 32), (solid,), body_forces=forces)
        params = model.default_params(gravity=(0.0, -0.5))
        s0 = _init(model, params)
        runs.append(jax.jit(lambda s, m=model, p=params: m.run_steps(s, p, 60))(s0))
    for name in ("v", "rho_f", "xi", "phi"):
        a, b = np.asarray(getattr(runs[0], name)), np.asarray(getattr(runs[1], name))
        assert np.abs(a - b).max() <= 1e-13 * max(1.0, np.abs(a).max()), name


# ---------------------------------------------------------------- a head-on pair
def _mirror(s):
    """Reflection across the diagonal y = x, which also swaps the two solids."""

    def T(f):
        return jnp.swapaxes(f, -1, -2)

    return s.replace(
        v=jnp.stack([T(s.v[1]), T(s.v[0])]),
        rho_f=T(s.rho_f),
        phi=jnp.stack([T(s.phi[1]), T(s.phi[0])]),
        xi=jnp.stack(
            [jnp.stack([T(s.xi[1, 1]), T(s.xi[1, 0])]), jnp.stack([T(s.xi[0, 1]), T(s.xi[0, 0])])]
        ),
    )


def _head_on(contact: bool, push=6.0, n=32, t_end=0.8, numerics=None):
    """Two identical discs, mirror images across y = x, driven into each other by a body
    force on their material, in a periodic box.  Returns per-checkpoint (gap / h, overlap
    area / h^2, mirror error)."""
    c0, r = 0.42, 0.45
    solids = (_disc((c0, -c0), r, name="A"), _disc((-c0, c0), r, name="B"))
    e = push / math.sqrt(2.0)

    def drive(ctx):
        ws = ctx["derived"]["ws_n"]
        return e * jnp.stack([ws[1] - ws[0], ws[0] - ws[1]])

    forces = (drive, Contact()) if contact else (drive,)
    model = Model(Grid(n, n), solids, PERIODIC, numerics=numerics, body_forces=forces)
    params = model.default_params()
    s = _init(model, params)
    m = _mirror(s)
    # make the start exactly symmetric (the re-distancing of the initial level sets is
    # symmetric only to round-off); (a + b) / 2 is bitwise symmetric
    s = s.replace(
        v=0.5 * (s.v + m.v),
        rho_f=0.5 * (s.rho_f + m.rho_f),
        xi=0.5 * (s.xi + m.xi),
        phi=0.5 * (s.phi + m.phi),
    )
    adv = jax.jit(model.advance)
    diag = jax.jit(lambda s: contact_diagnostics(model, s, params))
    rows = []
    for k in range(8):
        s, info = adv(s, params, t_end * (k + 1) / 8)
        assert bool(info["ok"])
        dd = diag(s)
        m = _mirror(s)
        err = max(
            float(jnp.max(jnp.abs(getattr(s, f) - getattr(m, f))))
            for f in ("v", "rho_f", "xi", "phi")
        )
        rows.append(
            (
                float(dd["min_gap"][0, 1]) / model.h,
                float(dd["overlap_area"][0, 1]) / model.h**2,
                err,
                np.asarray(dd["pair_force"]),
                float(dd["max_contact_pressure"]),
            )
        )
    return rows


@pytest.fixture(scope="module")
def head_on():
    return _head_on(True), _head_on(False)


def test_head_on_pair_stays_mirror_symmetric(head_on):
    """The scheme (triangle stencils included) is symmetric under the reflection y <-> x,
    and so is the contact force: the pair stays mirror-symmetric to round-off through
    the whole collision.  (A periodic box: next to no-slip walls the base scheme amplifies
    round-off asymmetries to ~1e-9 within t = 0.3, with or without contact.)"""
    on, _ = head_on
    assert max(r[4] for r in on) > 1.0  # the contact pressure did act
    for _, _, err, F, _ in on:
        assert err < 1e-10
        # the mirror image of A's force (fx, fy) is B's (fy, fx)
        scale = 1.0 + np.abs(F).max()
        assert abs(F[0][0] - F[1][1]) <= 1e-10 * scale and abs(F[0][1] - F[1][0]) <= 1e-10 * scale


def test_pushed_pair_does_not_overlap_with_contact_but_does_without(head_on):
    """Driven together by 6 per unit volume (a contact pressure of a third of the
    longitudinal modulus), the pair never overlaps with contact: the gap stays above
    -0.1 h (the figure is the accuracy of the pinned, re-distanced zero level set, whose
    contour moves by about a tenth of a cell per re-distancing) and no node is inside both.
    Without contact the same pair overlaps by a fifth of a cell from t = 0.5 on.
    (Measured: the gap with contact bottoms out at +0.06 h under a contact pressure of
    4.5, a fifth of M, close to the M / 4 at which the default contact lets bodies touch.)"""
    on, off = head_on
    assert min(r[0] for r in on) > -0.1
    assert all(r[1] == 0.0 for r in on)
    assert off[-1][0] < -0.1 and off[-1][1] > 0.0
    # contact also leaves a gap that scales with h: the pair stops within about 2 cells
    assert min(r[0] for r in on) < 2.0


def test_presence_is_the_blend_kernel():
    """The contact presence is 1 - H of the model's blend kernel: with erf, the thesis's
    truncated erfc / 2 (bitwise the formula used before kernels were a choice); with sine,
    1 - H of half-width SINE_REACH reach cells, reaching exactly 0 at that distance."""
    from jax.scipy.special import erfc

    from refmap import blend
    from refmap.contact import SINE_REACH, _presence

    h = 0.1
    phi = jnp.linspace(-0.4, 0.4, 161)
    c = Contact(reach=1.3)
    old = jnp.maximum(0.5 * erfc(phi / (1.3 * h)) - 0.01, 0.0) / 0.99
    assert np.array_equal(np.asarray(_presence(phi, c, h, "erf")), np.asarray(old))
    eps = SINE_REACH * 1.3 * h
    sine = np.asarray(_presence(phi, c, h, "sine"))
    np.testing.assert_allclose(
        sine, 1.0 - np.asarray(blend.heaviside(phi, "sine", eps)), atol=1e-15
    )
    p = np.asarray(phi)
    assert np.all(sine[p >= eps] == 0.0) and np.all(sine[p <= -eps] == 1.0)
    assert np.all(sine[np.abs(p) < eps - 1e-12] > 0.0)
    # the same support as the truncated erf presence, to within a hundredth of a cell
    erf_support = p[np.asarray(old) > 0].max()
    assert abs(erf_support - eps) < 0.05 * h


def test_pushed_pair_does_not_overlap_with_the_sine_kernel():
    """The head-on collision with the compact sine blend (half-width 1.5 h), whose contact
    presence is the same kernel.  Driven by 3 per unit volume, the pair stops 0.13-0.17 h
    apart with contact and stays mirror-symmetric; without contact the same pair overlaps
    (gap -0.1 h, nodes inside both from t = 0.5).  (Measured: under the push of 6 of the erf
    test above, the sine pair touches, gap -0.09 h to +0.06 h at a contact pressure 0.25 M,
    where contact is designed to let bodies touch; the erf pair stays 0.12 h apart at 0.18 M:
    with the sharper blend the same contact settings are softer; raise ``strength`` for
    harder contact.)"""
    from refmap.state import Numerics

    numerics = Numerics(blend="sine", blur_width=1.5)
    on = _head_on(True, push=3.0, numerics=numerics)
    off = _head_on(False, push=3.0, numerics=numerics)
    assert max(r[4] for r in on) > 1.0
    assert min(r[0] for r in on) > 0.05
    assert all(r[1] == 0.0 for r in on)
    assert max(r[2] for r in on) < 1e-10
    assert off[-1][0] < -0.05 and off[-1][1] > 0.0


# ---------------------------------------------------------------- walls
@pytest.mark.parametrize("walls", [True, False])
def test_wall_contact_keeps_a_falling_ball_out_of_the_floor(walls):
    """A ball of density 2 falls under g = 1 onto the floor of a closed box.  Without wall
    contact its reference map leaks through the no-slip wall (the ghost values are linear
    extrapolations) and the body sinks into the floor by more than 1.5 cells by t = 1.5;
    with it the ball stays above the floor (wall gap > -0.1 h) and bounces."""
    law = NeoHookean(G=10.0, kappa=10.0, rho0=2.0)
    model = Model(
        Grid(32, 32), (_disc((0.0, -1.2), 0.5, law=law),), body_forces=(Contact(walls=walls),)
    )
    params = model.default_params(gravity=(0.0, -1.0))
    s = _init(model, params)
    adv = jax.jit(model.advance)
    diag = jax.jit(lambda s: contact_diagnostics(model, s, params, Contact(walls=walls)))
    gaps = []
    for k in range(6):
        s, info = adv(s, params, 0.25 * (k + 1))
        assert bool(info["ok"])
        gaps.append(float(diag(s)["wall_gap"][0]) / model.h)
    assert min(gaps[:2]) > 1.0  # it starts clear of the floor
    if walls:
        assert min(gaps) > -0.1
    else:
        assert min(gaps) < -1.5


# ---------------------------------------------------------------- scenarios
def test_suspension_discs_are_apart_and_balanced():
    """The suspension's 100 discs: equal radii covering 30 % of the box, no two closer than
    0.06 (2 cells at 128^2), all 0.22 off the walls (two cells at 40^2, as case files need), 50 heavy (1.5) and 50 light (0.6),
    deterministic; impossible packings are refused with the count named."""
    from refmap.scenarios_fssi import suspension_discs

    d = suspension_discs()
    assert d == suspension_discs()
    c = np.array([x[0] for x in d])
    r = d[0][1]
    assert len(d) == 100 and all(x[1] == r for x in d)
    assert 100 * math.pi * r**2 == pytest.approx(0.3 * 16.0)
    D = np.sqrt(((c[:, None] - c[None]) ** 2).sum(-1)) + 9.0 * np.eye(100)
    assert D.min() - 2 * r > 0.06
    assert np.all(np.abs(c) + r < 2.0 - 0.22)
    assert sorted(x[2] for x in d) == [0.6] * 50 + [1.5] * 50
    with pytest.raises(ValueError, match="400 discs"):
        suspension_discs(400, fill=0.9)


def test_suspension_short_run():
    """``suspension`` (100 discs) at 48^2 for 8 steps: finite, every disc keeps its own
    nodes (no node inside two discs) and the suspension starts to fall freely."""
    case = get_case("suspension", 48)
    assert len(case.solids) == 100
    model, params = case.build()
    s0 = _init(model, params)
    s = jax.jit(lambda s: model.run_steps(s, params, 8))(s0)
    for f in ("v", "rho_f", "xi", "phi"):
        assert np.all(np.isfinite(np.asarray(getattr(s, f))))
    inside = np.asarray(s.phi) < 0
    assert inside.sum(axis=0).max() == 1
    assert np.all(inside.sum(axis=(1, 2)) > 0)
    # the box starts uniform and at rest, and by t = 0.007 no sound wave from the walls (c t
    # = 0.015) has reached a disc (0.23 away): the suspension falls freely, its discs' mean
    # vertical velocity -g t (measured within 0.7 %; single discs differ by up to 1e-3
    # through their start-up elastic and contact transients)
    ws = np.asarray(model.derived(s, params)["ws_n"])
    vy = (ws * np.asarray(s.v[1])[None]).sum(axis=(1, 2)) / ws.sum(axis=(1, 2))
    g_t = -case.gravity[1] * float(s.t)
    assert abs(vy.mean() + g_t) < 0.05 * g_t


def test_fssi_scenarios_are_registered_with_contact():
    for name in ("two_balls", "ball_stick", "settle", "suspension"):
        assert name in SCENARIOS
        case = get_case(name, 64 if name == "suspension" else 32)  # its discs: 4 cells at 64^2
        assert isinstance(case.contact, Contact)
        assert case.to_dict()["contact"]["strength"] == case.contact.strength
        model, _ = case.build()
        assert case.contact in model.body_forces
        assert model.n_solids >= 2
    assert 3 <= len(get_case("settle", 32).solids) <= 6
    assert all(1.5 <= s.law.rho0 <= 2.0 for s in get_case("settle", 32).solids)
    # a Case without contact builds a model without it, and has no contact entry
    case = get_case("settle", 32).replace(contact=None)
    model, _ = case.build()
    assert model.body_forces == () and "contact" not in case.to_dict()


def test_case_contact_field_is_checked_before_any_compile():
    """A bad contact value raises CaseError (a ValueError) when the Case is made."""
    case = get_case("two_balls", 32)
    with pytest.raises(CaseError, match="contact must be a refmap.contact.Contact"):
        case.replace(contact={"strength": 1.0})
    with pytest.raises(ValueError, match="walls"):
        Contact(walls="no")
    with pytest.raises(ValueError, match="width"):
        Contact(width=True)
    bad = Contact()
    object.__setattr__(bad, "strength", -2.0)  # bypassing the constructor's check
    with pytest.raises(CaseError, match="contact: Contact strength must be"):
        case.replace(contact=bad)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "t_end"), [("settle", 1.0), ("ball_stick", 1.0), ("two_balls", 4.0)]
)
def test_fssi_implicit_viscosity_follows_the_explicit_paths(name, t_end):
    """The FSSI scenarios take implicit viscosity (a step 15-18x the explicit one at 32^2:
    the explicit wave-damping limit is gone).  Their bodies must follow the explicit run's
    paths.  Measured at 32^2 (steps explicit / implicit; largest centroid difference;
    kinetic-energy difference; the bodies' largest displacement): settle to t = 1,
    1167 / 64, 0.025 h, 0.6 %, 1.9 cells; ball_stick to t = 1, 1167 / 78, 0.0070 h,
    0.13 %, 2.5 cells; two_balls to t = 4 (the inflow ramps up over t = 1, contact from
    t ~ 2.7), 4667 / 310, 0.047 h, 0.06 %, 1.4 cells (the anchored bodies held in the
    viscous solve; solved free and zeroed after it: 0.0076 h and 0.050 h).  The differences are the
    first-order time error of the longer step.  Bounds: 0.1 h and 3 %.  1-2 minutes each
    on a quiet core (the explicit runs)."""
    import dataclasses

    case = get_case(name, 32)
    assert case.numerics.viscosity == "implicit"
    out = {}
    for mode in ("explicit", "implicit"):
        c = dataclasses.replace(case, numerics=dataclasses.replace(case.numerics, viscosity=mode))
        model, params = c.build()
        s0 = model.initial_state(params)
        s, info = jax.jit(model.advance)(s0, params, jnp.asarray(t_end))
        assert bool(info["ok"])
        d0, d = model.diagnostics(s0, params), model.diagnostics(s, params)
        out[mode] = dict(
            start=np.array(
                [[float(q["centroid_x"]), float(q["centroid_y"])] for q in d0["solids"]]
            ),
            end=np.array([[float(q["centroid_x"]), float(q["centroid_y"])] for q in d["solids"]]),
            ke=float(d["kinetic_energy"]),
            steps=int(info["steps"]),
        )
    e, i = out["explicit"], out["implicit"]
    h = case.grid.dx
    assert i["steps"] * 10 < e["steps"]
    assert np.abs(e["end"] - e["start"]).max() > h  # the paths are long enough to compare
    assert np.abs(e["end"] - i["end"]).max() < 0.1 * h
    assert abs(i["ke"] - e["ke"]) < 0.03 * e["ke"]


@pytest.mark.parametrize("name", ["ball_stick", "settle"])
def test_fssi_scenario_short_run(name):
    """ball_stick and settle, coarse and short: finite, no overlap, fluid mass conserved
    (two_balls: test_two_balls_run_writes_contact_diagnostics).

    The closed boxes conserve fluid mass up to the scheme's non-conservative update of
    rho_f (rho_t = -v.grad rho - rho div v, ENO and centred differences), whose error is
    largest for an impulsive start on a coarse grid: measured 0.39 % over t = 0.2 for the
    thrown ball at 32^2 and 0.03 % for the settling balls; the bound is the 1 % that
    test_model's smoke test allows.
    """
    case = get_case(name, 32).replace(t_end=0.2, frames=1)
    model, params = case.build()
    s0 = _init(model, params)
    diag = jax.jit(model.diagnostics)  # includes the contact numbers
    d0 = diag(s0, params)
    s1, info = jax.jit(model.advance)(s0, params, case.t_end)
    assert bool(info["ok"])
    for f in ("v", "rho_f", "xi", "phi"):
        assert np.all(np.isfinite(np.asarray(getattr(s1, f)))), f
    d1 = diag(s1, params)
    m0, m1 = float(d0["fluid_mass"]), float(d1["fluid_mass"])
    assert abs(m1 - m0) <= 1e-2 * m0
    assert float(d1["contact_overlap_area"]) == 0.0
    assert all(np.isfinite(float(p["contact_fx"])) for p in d1["solids"])
    assert float(d1["J_min"]) > 0.5 and float(d1["J_max"]) < 2.0


def test_two_balls_run_writes_contact_diagnostics(tmp_path):
    """two_balls at 32^2 through the Simulation: diagnostics.csv has, per solid, the
    centroid, velocity, area, min/max J and contact force, and per pair the minimum gap and
    overlap area; every HDF5 frame holds the same numbers as arrays, and open_run reads
    them back equal to the csv.  The pair starts 0.3 = 2.4 cells apart, inside the 3.3
    cells at which the contact engages, so the contact force is already on: equal and
    opposite on the two balls, pushing them apart along x.

    Fluid mass: the box exchanges fluid only through its left and right edges, where the
    same velocity U(t) <= 0.3 is prescribed over the full height L = 4, so the mass changes
    by at most U L t (max rho_f - min rho_f) (the difference of the densities carried in
    and out) plus the closed-box error of the non-conservative density update (below 0.1 %
    for this gentle, ramped start, against 0.39 % for the impulsive ball_stick start).
    """
    from refmap.io import open_diagnostics, open_run
    from refmap.simulation import Simulation

    case = get_case("two_balls", 32).replace(t_end=0.2, frames=2)
    sim = Simulation(case, tmp_path / "run", progress=False, pictures=False, checkpoint_every=None)
    sim.run()
    df = open_diagnostics(tmp_path / "run")
    ds = open_run(tmp_path / "run")
    assert len(df) == 3 and ds.sizes["time"] == 3
    for k in range(2):
        for key in (
            "centroid_x",
            "centroid_y",
            "velocity_x",
            "velocity_y",
            "area",
            "J_min",
            "J_max",
            "contact_fx",
            "contact_fy",
            "wall_gap",
        ):
            assert f"solid{k}_{key}" in df.columns, key
    for key in ("pair0_1_min_gap", "pair0_1_overlap_area", "contact_min_gap", "contact_pairs"):
        assert key in df.columns, key
    assert np.all(np.isfinite(df.drop(columns=["dt_limit"]).to_numpy(dtype=float)))
    # the frames hold the same numbers
    np.testing.assert_array_equal(ds["contact_force"].values[:, 0, 0], df["solid0_contact_fx"])
    np.testing.assert_array_equal(ds["contact_force"].values[:, 1, 1], df["solid1_contact_fy"])
    np.testing.assert_array_equal(ds["contact_min_gap"].values[:, 0, 1], df["pair0_1_min_gap"])
    np.testing.assert_array_equal(ds["contact_min_gap"].values[:, 1, 0], df["pair0_1_min_gap"])
    np.testing.assert_array_equal(
        ds["contact_overlap_area"].values[:, 0, 1], df["pair0_1_overlap_area"]
    )
    np.testing.assert_array_equal(ds["solid_centroid"].values[:, 1, 0], df["solid1_centroid_x"])
    np.testing.assert_array_equal(ds["solid_J_min"].values[:, 0], df["solid0_J_min"])
    assert np.all(np.isnan(ds["contact_min_gap"].values[:, 0, 0]))
    # the contact acts from the start: apart along x, equal and opposite, no overlap
    fx0, fx1 = df["solid0_contact_fx"].to_numpy(), df["solid1_contact_fx"].to_numpy()
    assert np.all(fx0 > 0) and np.all(fx1 < 0)  # the anchored ball is on the right
    assert np.allclose(fx0 + fx1, 0.0, atol=1e-12 * np.abs(fx0).max())
    h = case.grid.h
    gap = df["pair0_1_min_gap"].to_numpy() / h
    assert np.all((gap > 1.5) & (gap < 3.3)) and np.all(df["pair0_1_overlap_area"] == 0.0)
    m = df["fluid_mass"].to_numpy()
    rho = ds["rho_f"].values
    allowed = 0.3 * 4.0 * case.t_end * (rho.max() - rho.min()) + 1e-3 * m[0]
    assert np.abs(m - m[0]).max() <= allowed


@pytest.mark.slow
def test_two_balls_film_density_stays_bounded_with_corner_compression():
    """The fluid film between the pressed balls of ``two_balls`` at 96^2 (about 10 minutes
    of one core).  With the thesis's centred compression a one-node velocity jet in the
    film pumped its density without bound (measured rho_f max 11.8 at t = 9, 67 at t = 11,
    broken at t ~ 14; docs/method.md); the scenario's energy-consistent compression keeps
    it bounded (measured peak 3.8 at t = 5.5, 2.8 at t = 14) with no overlap of the balls.
    The bound 6 is 1.6 times the largest value seen; the broken run passes 6 before
    t = 8.5 and grows x1.5 per half time unit."""
    from refmap.scenarios_fssi import two_balls

    case = two_balls(96)
    assert case.numerics.compression == "corner"
    model, params = case.build()
    s = jax.jit(model.initial_state)(params)
    advance = jax.jit(model.advance)
    worst = 0.0
    for t in np.arange(1.0, 12.01, 1.0):
        s, info = advance(s, params, float(t))
        assert bool(info["ok"]), f"not finite at t = {t}"
        worst = max(worst, float(jnp.max(s.rho_f)))
        assert worst < 6.0, f"film density {worst:.3g} at t = {t}"
        # no node inside both balls
        assert not bool(jnp.any((s.phi[0] < 0) & (s.phi[1] < 0))), f"overlap at t = {t}"
    jax.clear_caches()


# ---------------------------------------------------------------- issue 15, item 7 (open)
def _pressed_pair_film_asymmetry(n, t_end=2.0, nout=4):
    """Two identical discs (r = 0.5, centres -+0.55) pressed head-on along x by a body force
    of 2 per unit volume on their material, in a light fluid (rho_f0 = 0.1), corner
    compression, default contact, periodic box.  The set-up is mirror-symmetric about x = 0.
    Returns the largest mirror asymmetry |v(x, y) - M v(-x, y)| over the nodes within 3
    cells of the mid-plane, at the outputs with t >= 1 (the pair is pressed, at rest up to
    a slow sliding)."""
    c0 = 0.55
    solids = (_disc((-c0, 0.0), 0.5, name="A"), _disc((c0, 0.0), 0.5, name="B"))

    def drive(ctx):
        ws = ctx["derived"]["ws_n"]
        return 2.0 * jnp.stack([ws[0] - ws[1], jnp.zeros_like(ws[0])])

    from refmap.state import FluidParams, Numerics

    model = Model(
        Grid(n, n), solids, PERIODIC, Numerics(compression="corner"), body_forces=(drive, Contact())
    )
    params = model.default_params(fluid=FluidParams(rho0=0.1))
    s = _init(model, params)
    adv = jax.jit(model.advance)
    X, _ = model.grid.mesh("node")
    near = np.abs(X) < 3 * model.h
    worst = 0.0
    for k in range(nout):
        t = t_end * (k + 1) / nout
        s, info = adv(s, params, t)
        assert bool(info["ok"])
        if t < 1.0:
            continue
        v = np.asarray(s.v)
        a = np.hypot(v[0] + v[0][::-1], v[1] - v[1][::-1])
        worst = max(worst, float(a[near].max()))
    return worst


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue 15 item 7: one-node jet at the contact, open")
def test_pressed_pair_film_is_mirror_symmetric():
    """Known defect (issue 15, item 7; docs/method.md "Known weaknesses"): in the film between
    two pressed, mirror-symmetric bodies one node next to the mid-plane (a surface node with
    |phi| < 0.1 h) keeps moving at ~0.3 while its mirror node is nearly still.  Measured
    max asymmetry near the mid-plane for t in [1, 2]: 0.35 (32^2), 0.21 (48^2), 0.30 (64^2):
    it does not refine.  Away from the film the first-order asymmetry of the triangle
    stencils is ~0.04 at 48^2 (a pair thrown head-on at 0.5, late in the run); 0.05 is the
    bound a cure should meet.  Strict xfail: when a fix lands this
    XPASSes and fails, so the marker must then be removed."""
    assert _pressed_pair_film_asymmetry(48) < 0.05
