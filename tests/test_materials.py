"""Tests for refmap.materials: closed-form stresses against autodiff, objectivity, moduli,
pytree behaviour (jit / grad / vmap over parameters), validation and serialisation."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import refmap  # noqa: F401  (enables float64)
from refmap.materials import (
    LAWS,
    EnergyLaw,
    HyperelasticLaw,
    LogNeoHookean,
    NeoHookean,
    StVenantKirchhoff,
    law_from_dict,
    log_neo_hookean_energy,
    neo_hookean_energy,
    svk_energy,
)

G0, K0 = 10.0, 10.0

BUILTINS = {
    "neo_hookean": NeoHookean(G0, K0),
    "log_neo_hookean": LogNeoHookean(G0, K0),
    "svk": StVenantKirchhoff.from_G_kappa(G0, K0),
    "svk_auxetic": StVenantKirchhoff.from_E_nu(3.0, -0.3, rho0=2.0),
    "neo_hookean_soft": NeoHookean(0.7, 25.0, rho0=1.5),
}
LAW_IDS = list(BUILTINS)

HYP = settings(
    max_examples=30,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)

# jitted entry points, shared by all laws of a class (the law is a pytree argument)
_closed = jax.jit(lambda law, F: law.stress(F))
_auto = jax.jit(lambda law, F: law.stress_autodiff(F))


def rot(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s], [s, c]])


@functools.cache
def scale(law):
    """The stress scale of a law (its longitudinal modulus M), cached: laws are hashable."""
    return float(law.moduli()[1])


angles = st.floats(-math.pi, math.pi, allow_nan=False)
stretches = st.floats(0.3, 3.0, allow_nan=False)


@st.composite
def deformations(draw):
    """F = R(theta) R(phi) diag(l1, l2) R(phi)^T: any F with det F > 0 (polar form)."""
    th, ph = draw(angles), draw(angles)
    l1, l2 = draw(stretches), draw(stretches)
    R = rot(ph)
    return rot(th) @ R @ np.diag([l1, l2]) @ R.T


def assert_close_rel(a, b, law, rtol=1e-10):
    """|a - b| <= rtol * max(|b|, 1e-2 M): relative, with a floor near the stress-free state."""
    a, b = np.asarray(a), np.asarray(b)
    err = np.linalg.norm(a - b)
    ref = max(np.linalg.norm(b), 1e-2 * scale(law))
    assert err <= rtol * ref, (err, ref, a, b)


HAND_PICKED = [
    np.array([[1.0, 2.0], [0.0, 1.0]]),  # simple shear gamma = 2
    np.array([[1.0, 0.0], [-1.5, 1.0]]),  # simple shear the other way
    np.array([[3.0, 0.0], [0.0, 1.0]]),  # uniaxial stretch 3
    np.array([[0.3, 0.0], [0.0, 1.0]]),  # uniaxial compression to 30 %
    np.array([[2.5, 0.0], [0.0, 2.5]]),  # equibiaxial expansion
    np.array([[0.4, 0.0], [0.0, 0.5]]),  # strong volumetric compression
    rot(2.0) @ np.array([[2.0, 0.7], [0.1, 0.6]]),  # rotated general large strain
    np.array([[0.2, -1.1], [0.9, 1.7]]),  # general, det = 1.33
]


# ---------------------------------------------------------------- closed form == autodiff


@pytest.mark.parametrize("name", LAW_IDS)
@HYP
@given(F=deformations())
def test_closed_form_matches_autodiff(name, F):
    law = BUILTINS[name]
    assert_close_rel(_closed(law, F), _auto(law, F), law)


@pytest.mark.parametrize("name", LAW_IDS)
@HYP
@given(a=st.lists(st.floats(-0.9, 0.9, allow_nan=False), min_size=4, max_size=4))
def test_closed_form_matches_autodiff_near_identity(name, a):
    F = np.eye(2) + np.reshape(a, (2, 2))
    if np.linalg.det(F) < 0.05:
        F = F + np.eye(2)  # keep det F > 0
    law = BUILTINS[name]
    assert_close_rel(_closed(law, F), _auto(law, F), law)


@pytest.mark.parametrize("name", LAW_IDS)
def test_closed_form_matches_autodiff_hand_picked(name):
    law = BUILTINS[name]
    for F in HAND_PICKED:
        assert np.linalg.det(F) > 0
        assert_close_rel(law.stress(F), law.stress_autodiff(F), law)


def test_psi_matches_energy_functions():
    F = HAND_PICKED[-1]
    assert float(NeoHookean(2.0, 3.0).psi(F)) == pytest.approx(
        float(neo_hookean_energy(F, {"G": 2.0, "kappa": 3.0})), rel=1e-14
    )
    assert float(LogNeoHookean(2.0, 3.0).psi(F)) == pytest.approx(
        float(log_neo_hookean_energy(F, {"G": 2.0, "kappa": 3.0})), rel=1e-14
    )
    assert float(StVenantKirchhoff(2.0, 3.0).psi(F)) == pytest.approx(
        float(svk_energy(F, {"mu": 2.0, "lam": 3.0})), rel=1e-14
    )
    for law in BUILTINS.values():
        assert abs(float(law.psi(np.eye(2)))) < 1e-13
        assert abs(float(law.psi(rot(0.8)))) < 1e-12 * scale(law)


def test_log_neo_hookean_simple_shear_is_linear():
    """sigma_12 = G gamma exactly and sigma_22 = 0: the exact finite-amplitude shear wave."""
    law = LogNeoHookean(3.0, 7.0)
    for g in (0.1, 1.0, 4.0):
        s = np.asarray(law.stress(np.array([[1.0, g], [0.0, 1.0]])))
        np.testing.assert_allclose(s, [[3.0 * g * g, 3.0 * g], [3.0 * g, 0.0]], atol=1e-13)


def test_neo_hookean_closed_form_formula():
    F = np.array([[1.2, 0.3], [-0.1, 0.8]])
    G, k = 2.0, 5.0
    J = np.linalg.det(F)
    B = F @ F.T
    expected = G * J ** (-5 / 3) * (B - (np.trace(B) + 1) / 3 * np.eye(2)) + k * (J - 1) * np.eye(2)
    np.testing.assert_allclose(NeoHookean(G, k).stress(F), expected, rtol=1e-13)


# ---------------------------------------------------------------- stress-free states, symmetry


@pytest.mark.parametrize("name", LAW_IDS)
def test_identity_is_stress_free(name):
    law = BUILTINS[name]
    assert np.max(np.abs(law.stress(np.eye(2)))) < 1e-14 * scale(law)
    assert np.max(np.abs(law.stress_autodiff(np.eye(2)))) < 1e-14 * scale(law)


@pytest.mark.parametrize("name", LAW_IDS)
@HYP
@given(t=angles)
def test_rigid_rotation_is_stress_free(name, t):
    law = BUILTINS[name]
    Q = rot(t)
    assert np.max(np.abs(_closed(law, Q))) < 1e-13 * scale(law)
    assert np.max(np.abs(_auto(law, Q))) < 1e-13 * scale(law)


@pytest.mark.parametrize("name", LAW_IDS)
@HYP
@given(F=deformations(), t=angles)
def test_frame_indifference(name, F, t):
    law = BUILTINS[name]
    Q = rot(t)
    lhs = _closed(law, Q @ F)
    rhs = Q @ np.asarray(_closed(law, F)) @ Q.T
    assert_close_rel(lhs, rhs, law, rtol=1e-12)


@pytest.mark.parametrize("name", LAW_IDS)
@HYP
@given(F=deformations())
def test_stress_is_symmetric(name, F):
    law = BUILTINS[name]
    s = np.asarray(_closed(law, F))
    # built by construction from one off-diagonal value; XLA fusion may still differ by an ulp
    assert abs(s[0, 1] - s[1, 0]) <= 1e-14 * max(np.linalg.norm(s), scale(law))
    sa = np.asarray(_auto(law, F))
    assert abs(sa[0, 1] - sa[1, 0]) <= 1e-12 * max(np.linalg.norm(sa), scale(law))


# ---------------------------------------------------------------- moduli and wave speeds


def test_wave_speeds_reference_values():
    cT, cL = NeoHookean(10.0, 10.0).wave_speeds()
    assert float(cT) == pytest.approx(3.162278, abs=1e-6)
    assert float(cL) == pytest.approx(4.830459, abs=1e-6)
    assert float(cL) == pytest.approx(math.sqrt(10 + 40 / 3), rel=1e-12)

    cT, cL = LogNeoHookean(10.0, 10.0).wave_speeds()
    assert float(cT) == pytest.approx(3.162278, abs=1e-6)
    assert float(cL) == pytest.approx(5.477226, abs=1e-6)

    svk = StVenantKirchhoff.from_G_kappa(10.0, 10.0)
    assert svk.mu == 10.0
    assert svk.lam == pytest.approx(10.0 - 20.0 / 3.0, rel=1e-14)
    cT, cL = svk.wave_speeds()
    assert float(cT) == pytest.approx(3.162278, abs=1e-6)
    assert float(cL) == pytest.approx(math.sqrt(svk.lam + 2 * svk.mu), rel=1e-12)
    assert float(cL) == pytest.approx(4.830459, abs=1e-6)


def test_moduli_and_density():
    mu, M = NeoHookean(2.0, 5.0, rho0=4.0).moduli()
    assert float(mu) == pytest.approx(2.0, rel=1e-12)
    assert float(M) == pytest.approx(5.0 + 8.0 / 3.0, rel=1e-12)
    cT, cL = NeoHookean(2.0, 5.0, rho0=4.0).wave_speeds()
    assert float(cT) == pytest.approx(math.sqrt(2.0 / 4.0), rel=1e-12)
    assert float(cL) == pytest.approx(math.sqrt((5.0 + 8.0 / 3.0) / 4.0), rel=1e-12)
    mu, M = StVenantKirchhoff(3.0, -1.0).moduli()
    assert (float(mu), float(M)) == pytest.approx((3.0, 5.0), rel=1e-12)
    # moduli work under jit (the law is an ordinary argument)
    mu, M = jax.jit(lambda law: law.moduli())(LogNeoHookean(2.0, 5.0))
    assert (float(mu), float(M)) == pytest.approx((2.0, 9.0), rel=1e-12)


def test_from_E_nu():
    E, nu = 7.0, 0.3
    law = StVenantKirchhoff.from_E_nu(E, nu, rho0=3.0)
    assert law.rho0 == 3.0
    assert 2 * law.mu * (1 + nu) == pytest.approx(E, rel=1e-14)
    kappa = law.lam + 2 * law.mu / 3
    assert 3 * kappa * (1 - 2 * nu) == pytest.approx(E, rel=1e-14)


# ---------------------------------------------------------------- user laws


def test_energy_law_reproduces_neo_hookean():
    params = {"G": 4.0, "kappa": 9.0}
    user = EnergyLaw(neo_hookean_energy, params, rho0=2.0)
    ref = NeoHookean(4.0, 9.0, rho0=2.0)
    F = np.stack(HAND_PICKED)
    np.testing.assert_allclose(user.stress(F), ref.stress(F), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(user.wave_speeds(), ref.wave_speeds(), rtol=1e-12)
    assert float(user.psi(F[0])) == pytest.approx(float(ref.psi(F[0])), rel=1e-14)


def test_energy_law_custom_function_and_jit():
    def mooney_like(F, p):
        C = F.T @ F
        J = jnp.linalg.det(F)
        return 0.5 * p["a"] * (jnp.trace(C) - 2 - 2 * jnp.log(J)) + 0.5 * p["b"] * jnp.log(J) ** 2

    law = EnergyLaw(mooney_like, {"a": 1.5, "b": 4.0})
    mu, M = law.moduli()
    assert (float(mu), float(M)) == pytest.approx((1.5, 7.0), rel=1e-12)
    F = jnp.broadcast_to(jnp.asarray(HAND_PICKED[0]), (3, 5, 2, 2))
    s = jax.jit(lambda law, F: law.stress(F))(law, F)
    assert s.shape == (3, 5, 2, 2)
    np.testing.assert_allclose(s[1, 2], law.stress(HAND_PICKED[0]), rtol=1e-13)


def test_energy_law_params_are_differentiable():
    F = jnp.asarray(HAND_PICKED[0])

    def f(G):
        return EnergyLaw(log_neo_hookean_energy, {"G": G, "kappa": 3.0}).stress(F)[0, 1]

    # sigma_12 = G gamma under simple shear for this energy
    assert float(jax.grad(f)(2.0)) == pytest.approx(2.0, rel=1e-12)


# ---------------------------------------------------------------- pytree behaviour


@pytest.mark.parametrize("cls", [NeoHookean, LogNeoHookean])
def test_grad_with_respect_to_G(cls):
    F = jnp.asarray(HAND_PICKED[6])

    def loss(G):
        return jnp.sum(cls(G, 3.0).stress(F) ** 2)

    g = jax.grad(loss)(2.0)
    h = 1e-6
    fd = (loss(2.0 + h) - loss(2.0 - h)) / (2 * h)
    assert float(g) == pytest.approx(float(fd), rel=1e-7)

    # the whole law as a pytree argument: gradients come back shaped like a law, and a zero
    # cotangent (for rho0) must not trip the parameter validation
    glaw = jax.grad(lambda law: jnp.sum(law.stress(F) ** 2))(cls(2.0, 3.0))
    assert isinstance(glaw, cls)
    assert float(glaw.G) == pytest.approx(float(g), rel=1e-12)
    assert float(glaw.rho0) == 0.0


def test_grad_through_wave_speed_and_svk():
    cT = jax.grad(lambda G: NeoHookean(G, 10.0, rho0=2.0).wave_speeds()[0])(8.0)
    assert float(cT) == pytest.approx(0.5 / math.sqrt(8.0 * 2.0), rel=1e-10)
    F = jnp.asarray(HAND_PICKED[2])
    d = jax.grad(lambda mu: StVenantKirchhoff(mu, 1.0).stress(F)[0, 0])(2.0)
    # uniaxial stretch l: sigma_11 = l (lam + 2 mu) E11, E11 = (l^2 - 1)/2, d/dmu = l (l^2 - 1)
    assert float(d) == pytest.approx(3.0 * 8.0, rel=1e-12)


def test_jit_does_not_retrace_on_new_parameter_values():
    traces = []

    @jax.jit
    def f(law, F):
        traces.append(1)
        return law.stress(F)

    F = jnp.asarray(HAND_PICKED[0])
    f(NeoHookean(1.0, 2.0), F)
    f(NeoHookean(3.0, 4.0, rho0=5.0), F)
    assert len(traces) == 1


def test_vmap_over_parameters_and_tree_ops():
    F = jnp.asarray(HAND_PICKED[0])
    Gs = jnp.array([1.0, 2.0, 3.0])
    s = jax.vmap(lambda G: LogNeoHookean(G, 5.0).stress(F))(Gs)
    np.testing.assert_allclose(s[:, 0, 1], 2.0 * Gs, rtol=1e-13)
    law = NeoHookean(1.0, 2.0)
    leaves, treedef = jax.tree_util.tree_flatten(law)
    assert leaves == [1.0, 2.0, 1.0]
    assert jax.tree_util.tree_unflatten(treedef, leaves) == law
    zeros = jax.tree_util.tree_map(jnp.zeros_like, law)  # unflattening does not validate
    assert float(zeros.G) == 0.0
    assert jax.tree_util.tree_map(lambda x: None, law).G is None
    paths = [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_flatten_with_path(law)[0]]
    assert paths == [".G", ".kappa", ".rho0"]


def test_treedefs_of_different_laws_differ():
    """Regression: with jax.tree_util.register_dataclass the treedefs of NeoHookean and
    LogNeoHookean compare equal (same arity, no metadata), so jit's cache could hand one
    law's compiled stress to the other on a hash collision."""
    ts = jax.tree_util.tree_structure
    laws = [NeoHookean(1.0, 2.0), LogNeoHookean(1.0, 2.0), StVenantKirchhoff(1.0, 2.0)]
    for i, a in enumerate(laws):
        for j, b in enumerate(laws):
            assert (ts(a) == ts(b)) == (i == j)
    e1 = EnergyLaw(neo_hookean_energy, {"G": 1.0, "kappa": 2.0})
    e2 = EnergyLaw(log_neo_hookean_energy, {"G": 1.0, "kappa": 2.0})
    assert ts(e1) != ts(e2)
    assert ts(e1) == ts(EnergyLaw(neo_hookean_energy, {"G": 3.0, "kappa": 4.0}))


@pytest.mark.parametrize("name", LAW_IDS)
@pytest.mark.parametrize("batch", [(), (7,), (3, 4), (2, 3, 5)])
def test_batched_shapes_under_jit(name, batch):
    law = BUILTINS[name]
    rng = np.random.default_rng(hash(batch) % 2**32)
    F = np.eye(2) + 0.3 * rng.standard_normal(batch + (2, 2))
    F[..., 0, 0] += 0.5 * (np.linalg.det(F) < 0.1)  # keep det F > 0
    F[..., 1, 1] += 0.5 * (np.linalg.det(F) < 0.1)
    assert np.all(np.linalg.det(F) > 0)
    s = _closed(law, F)
    sa = _auto(law, F)
    assert s.shape == batch + (2, 2) and sa.shape == batch + (2, 2)
    assert s.dtype == jnp.float64
    flat_F = F.reshape(-1, 2, 2)
    flat_s = np.asarray(s).reshape(-1, 2, 2)
    for k in range(flat_F.shape[0]):
        np.testing.assert_allclose(flat_s[k], law.stress(flat_F[k]), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(s, sa, rtol=1e-10, atol=1e-10 * scale(law))


def test_bad_shape_rejected():
    with pytest.raises(ValueError, match="shape"):
        NeoHookean(1.0, 1.0).stress(np.eye(3))


# ---------------------------------------------------------------- validation


@pytest.mark.parametrize(
    "make, param, value",
    [
        (lambda: NeoHookean(-1.0, 2.0), "G", "-1.0"),
        (lambda: NeoHookean(1.0, 0.0), "kappa", "0.0"),
        (lambda: NeoHookean(1.0, 2.0, rho0=-3.0), "rho0", "-3.0"),
        (lambda: LogNeoHookean(0, 2.0), "G", "0.0"),
        (lambda: LogNeoHookean(1.0, -2.5), "kappa", "-2.5"),
        (lambda: LogNeoHookean(1.0, 2.0, rho0=0.0), "rho0", "0.0"),
        (lambda: StVenantKirchhoff(-2.0, 1.0), "mu", "-2.0"),
        (lambda: StVenantKirchhoff(3.0, -4.0), "lam", "-4.0"),
        (lambda: StVenantKirchhoff(3.0, 1.0, rho0=-1.0), "rho0", "-1.0"),
        (lambda: StVenantKirchhoff.from_E_nu(-1.0, 0.3), "E", "-1.0"),
        (lambda: StVenantKirchhoff.from_E_nu(1.0, 0.5), "nu", "0.5"),
        (lambda: StVenantKirchhoff.from_G_kappa(1.0, -1.0), "kappa", "-1.0"),
        (lambda: NeoHookean(float("nan"), 1.0), "G", "nan"),
        (
            lambda: EnergyLaw(neo_hookean_energy, {"G": 1.0, "kappa": 1.0}, rho0=-2.0),
            "rho0",
            "-2.0",
        ),
        (lambda: EnergyLaw(neo_hookean_energy, {"G": -1.0, "kappa": 1.0}), "mu", "-1.0"),
    ],
)
def test_bad_parameters_raise(make, param, value):
    with pytest.raises(ValueError) as info:
        make()
    msg = str(info.value)
    assert param in msg and value in msg, msg


def test_explicit_validate_on_arrays():
    law = NeoHookean(jnp.asarray(-1.0), 1.0)  # arrays are not checked at construction
    with pytest.raises(ValueError, match="'G'"):
        law.validate()


def test_abstract_base_cannot_be_instantiated():
    with pytest.raises(TypeError):
        HyperelasticLaw()


# ---------------------------------------------------------------- registry and serialisation


def test_registry_and_round_trip():
    assert LAWS == {
        "neo_hookean": NeoHookean,
        "log_neo_hookean": LogNeoHookean,
        "svk": StVenantKirchhoff,
    }
    for law in BUILTINS.values():
        d = law.to_dict()
        assert d["law"] in LAWS
        assert all(isinstance(v, float) for k, v in d.items() if k != "law")
        assert law_from_dict(d) == law
    assert NeoHookean(1, 2).to_dict() == {"law": "neo_hookean", "G": 1.0, "kappa": 2.0, "rho0": 1.0}
    assert law_from_dict({"law": "log_neo_hookean", "G": 2, "kappa": 3}) == LogNeoHookean(2.0, 3.0)


def test_svk_dict_alternatives():
    a = law_from_dict({"law": "svk", "E": 7.0, "nu": 0.3, "rho0": 2.0})
    assert a == StVenantKirchhoff.from_E_nu(7.0, 0.3, rho0=2.0)
    b = law_from_dict({"law": "svk", "G": 10.0, "kappa": 10.0})
    assert b == StVenantKirchhoff.from_G_kappa(10.0, 10.0)


def test_bad_dicts():
    with pytest.raises(ValueError, match="unknown material law 'rubber'"):
        law_from_dict({"law": "rubber", "G": 1.0})
    with pytest.raises(ValueError, match="'law' key"):
        law_from_dict({"G": 1.0, "kappa": 1.0})
    with pytest.raises(ValueError, match="unknown \\['E'\\]"):
        law_from_dict({"law": "neo_hookean", "G": 1.0, "kappa": 1.0, "E": 3.0})
    with pytest.raises(ValueError, match="missing \\['kappa'\\]"):
        law_from_dict({"law": "neo_hookean", "G": 1.0})
    with pytest.raises(ValueError, match="'G'"):
        law_from_dict({"law": "neo_hookean", "G": -1.0, "kappa": 1.0})


def test_energy_law_cannot_be_serialised():
    law = EnergyLaw(neo_hookean_energy, {"G": 1.0, "kappa": 1.0})
    with pytest.raises(ValueError, match="cannot be serialised"):
        law.to_dict()


def test_case_velocity_scales_take_each_distinct_law_once(monkeypatch):
    """``Case.velocity_scales`` (the run's growth checks) takes the moduli of each distinct
    law once, not once per solid (a thousand discs of two densities took 30 s), and gives
    the fastest wave of all the laws: here the stiffer of two, whichever solids hold it."""
    import dataclasses

    from refmap.materials import NeoHookean
    from refmap.scenarios import get_case

    calls = []
    real = NeoHookean.moduli

    def counted(self):
        calls.append(self)
        return real(self)

    monkeypatch.setattr(NeoHookean, "moduli", counted)
    case = get_case("suspension", 64)
    soft, stiff = NeoHookean(G=1.0, kappa=10.0, rho0=1.5), NeoHookean(G=4.0, kappa=10.0, rho0=1.5)
    solids = tuple(dataclasses.replace(s, law=stiff if k == 37 else soft) for k, s in enumerate(case.solids))
    scales = case.replace(solids=solids).velocity_scales()
    assert len(calls) == 2
    _, M = real(stiff)
    assert scales["solid wave speed"] == pytest.approx(math.sqrt(float(M) / 1.5), rel=1e-14)
