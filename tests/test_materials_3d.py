"""The hyperelastic laws in 3D (issue 12): the 2D plane-strain laws are their restriction,
closed forms agree with autodiff, objectivity, zero stress at rest, layouts, dim checks."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (enables float64)
from refmap.materials import (
    EnergyLaw,
    LogNeoHookean,
    NeoHookean,
    StVenantKirchhoff,
    law_from_dict,
    neo_hookean_energy,
    svk_energy,
    sym_components,
    sym_from_components,
)
from refmap.operators import SYM_COMPONENTS, div_node

G0, K0 = 10.0, 10.0

LAWS_2D = {
    "neo_hookean": NeoHookean(G0, K0),
    "log_neo_hookean": LogNeoHookean(G0, K0),
    "svk": StVenantKirchhoff.from_G_kappa(G0, K0),
    "svk_auxetic": StVenantKirchhoff.from_E_nu(3.0, -0.3, rho0=2.0),
    "neo_hookean_soft": NeoHookean(0.7, 25.0, rho0=1.5),
    "energy_nh": EnergyLaw(neo_hookean_energy, {"G": 2.0, "kappa": 7.0}),
    "energy_svk": EnergyLaw(svk_energy, {"mu": 2.0, "lam": 3.0}),
}
IDS = list(LAWS_2D)

rng = np.random.default_rng(3)


def random_F(n, d, amp=0.3):
    """n deformation gradients I + amp * noise with det F > 0.2 (away from inversion)."""
    F = np.eye(d) + amp * rng.standard_normal((4 * n, d, d))
    return F[np.linalg.det(F) > 0.2][:n]


def random_rotations(n):
    Q, R = np.linalg.qr(rng.standard_normal((n, 3, 3)))
    Q = Q * np.sign(np.diagonal(R, axis1=1, axis2=2))[:, None, :]
    Q[np.linalg.det(Q) < 0, :, 0] *= -1.0  # proper rotations only
    return Q


def M(law):
    return float(law.moduli()[1])


@pytest.mark.parametrize("name", IDS)
def test_2d_law_is_the_restriction_of_the_3d_law(name):
    """At F = diag-block(F2, 1): psi3 = psi2, the in-plane block of sigma3 is sigma2 and the
    out-of-plane shears vanish (exactly: every product with them is a product with 0)."""
    law2 = LAWS_2D[name]
    law3 = law2.with_dim(3)
    F2 = random_F(40, 2, amp=0.4)
    F3 = np.zeros((len(F2), 3, 3))
    F3[:, :2, :2] = F2
    F3[:, 2, 2] = 1.0
    s2, s3 = np.asarray(law2.stress(F2)), np.asarray(law3.stress(F3))
    np.testing.assert_allclose(s3[:, :2, :2], s2, rtol=1e-13, atol=1e-13 * M(law2))
    assert np.all(s3[:, :2, 2] == 0.0) and np.all(s3[:, 2, :2] == 0.0)
    psi2 = jax.vmap(law2.psi)(F2)
    psi3 = jax.vmap(law3.psi)(F3)
    np.testing.assert_allclose(psi3, psi2, rtol=1e-13, atol=1e-13 * M(law2))


@pytest.mark.parametrize("name", IDS)
def test_closed_form_matches_autodiff_3d(name):
    law = LAWS_2D[name].with_dim(3)
    F = random_F(50, 3).reshape(5, 10, 3, 3)  # batched
    s, sa = law.stress(F), law.stress_autodiff(F)
    assert s.shape == (5, 10, 3, 3)
    np.testing.assert_allclose(s, sa, rtol=1e-11, atol=1e-11 * M(law))
    if not isinstance(law, EnergyLaw):  # closed forms assemble sigma from one triangle
        np.testing.assert_array_equal(s, np.swapaxes(s, -1, -2))


@pytest.mark.parametrize("name", IDS)
def test_frame_indifference_and_isotropy_3d(name):
    """sigma(QF) = Q sigma(F) Q^T (objectivity) and sigma(F Q) = sigma(F) (isotropy)."""
    law = LAWS_2D[name].with_dim(3)
    F, Q = random_F(30, 3), random_rotations(30)
    s = np.asarray(law.stress(F))
    rotated = np.asarray(law.stress(Q @ F))
    tol = 1e-12 * M(law)
    np.testing.assert_allclose(rotated, Q @ s @ np.swapaxes(Q, 1, 2), rtol=1e-11, atol=tol)
    np.testing.assert_allclose(law.stress(F @ Q), s, rtol=1e-11, atol=tol)


@pytest.mark.parametrize("name", IDS)
def test_zero_stress_at_rest_and_under_rotation_3d(name):
    law = LAWS_2D[name].with_dim(3)
    assert np.array_equal(np.asarray(law.stress(np.eye(3))), np.zeros((3, 3)))
    np.testing.assert_allclose(law.stress(random_rotations(20)), 0.0, atol=1e-13 * M(law))
    assert float(law.psi(jnp.eye(3))) == pytest.approx(0.0, abs=1e-14)


def test_neo_hookean_uniaxial_stretch_analytic():
    """F = diag(l, 1, 1): J = l, B = diag(l^2, 1, 1),
    sigma11 = G l^(-5/3) (l^2 - (l^2 + 2)/3) + kappa (l - 1), sigma22 = sigma33."""
    G, kappa, lam = 2.0, 5.0, 1.3
    s = np.asarray(NeoHookean(G, kappa, dim=3).stress(np.diag([lam, 1.0, 1.0])))
    g = G * lam ** (-5.0 / 3.0)
    tr3 = (lam**2 + 2.0) / 3.0
    assert s[0, 0] == pytest.approx(g * (lam**2 - tr3) + kappa * (lam - 1), rel=1e-14)
    assert s[1, 1] == pytest.approx(g * (1.0 - tr3) + kappa * (lam - 1), rel=1e-14)
    assert s[2, 2] == s[1, 1]


def test_moduli_are_the_same_in_3d():
    for law in LAWS_2D.values():
        np.testing.assert_allclose(law.with_dim(3).moduli(), law.moduli(), rtol=1e-13)


def test_energy_law_with_a_3d_only_energy():
    """An energy that reads F[2, 2] needs dim=3; its stress is the autodiff one and its
    small-strain moduli are checked on 3x3 F."""

    def psi(F, p):  # neo-Hookean written with explicit 3D entries
        J = jnp.linalg.det(F)
        I1 = F[0, 0] ** 2 + F[1, 1] ** 2 + F[2, 2] ** 2 + jnp.sum(F * F) - jnp.sum(jnp.diag(F) ** 2)
        return 0.5 * p["G"] * (I1 / jnp.cbrt(J) ** 2 - 3.0) + 0.5 * p["kappa"] * (J - 1.0) ** 2

    law = EnergyLaw(psi, {"G": 2.0, "kappa": 7.0}, dim=3)
    F = random_F(10, 3)
    np.testing.assert_allclose(
        law.stress(F), NeoHookean(2.0, 7.0, dim=3).stress(F), rtol=1e-11, atol=1e-11
    )
    with pytest.raises(ValueError, match="must be positive"):
        EnergyLaw(psi, {"G": -2.0, "kappa": 7.0}, dim=3)


def test_dim_is_checked_and_serialised():
    law = NeoHookean(1.0, 2.0, dim=3)
    with pytest.raises(ValueError, match=r"\(\.\.\., 3, 3\)"):
        law.stress(np.eye(2))
    with pytest.raises(ValueError, match="dim=3"):
        NeoHookean(1.0, 2.0).stress(np.eye(3))
    with pytest.raises(ValueError, match="'dim'"):
        NeoHookean(1.0, 2.0, dim=4)
    assert law.to_dict() == {"law": "neo_hookean", "G": 1.0, "kappa": 2.0, "rho0": 1.0, "dim": 3}
    assert "dim" not in NeoHookean(1.0, 2.0).to_dict()
    assert law_from_dict(law.to_dict()) == law
    assert law_from_dict({"law": "svk", "E": 3.0, "nu": 0.25, "dim": 3}).dim == 3
    assert law != NeoHookean(1.0, 2.0)


def test_3d_law_is_a_pytree_under_jit_and_grad():
    law = NeoHookean(3.0, 5.0, dim=3)
    F = jnp.asarray(random_F(8, 3))
    f = jax.jit(lambda lw, F: lw.stress(F))
    np.testing.assert_allclose(f(law, F), law.stress(F), rtol=1e-14, atol=1e-14)
    # sigma is affine in G: d sigma / d G = sigma(G=2) - sigma(G=1)
    dG = jax.grad(lambda lw: jnp.sum(lw.stress(F)))(law).G
    dev = NeoHookean(2.0, 5.0, dim=3).stress(F) - NeoHookean(1.0, 5.0, dim=3).stress(F)
    assert float(dG) == pytest.approx(float(jnp.sum(dev)), rel=1e-12)


def test_symmetric_component_layout():
    for d in (2, 3):
        s = np.asarray(LAWS_2D["neo_hookean"].with_dim(d).stress(random_F(6, d)))
        comps = sym_components(s)
        assert len(comps) == len(SYM_COMPONENTS[d])
        for name, c in zip(SYM_COMPONENTS[d], comps, strict=True):
            a, b = "xyz".index(name[0]), "xyz".index(name[1])
            assert np.array_equal(c, s[:, a, b])
        assert np.array_equal(np.asarray(sym_from_components(comps, d)), s)
    # a 3D corner stress feeds the 3D stencil directly
    sig = LAWS_2D["svk"].with_dim(3).stress(random_F(5 * 4 * 6, 3).reshape(5, 4, 6, 3, 3))
    assert div_node(*sym_components(sig), 0.1, 0.2, 0.3).shape == (3, 4, 3, 5)
    with pytest.raises(ValueError, match="6 components"):
        sym_from_components(comps[:5], 3)
