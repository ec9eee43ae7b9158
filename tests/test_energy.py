"""Energy of a freely vibrating body in a viscous fluid (issue 15, item 3).

An isolated system with viscosity can only lose energy.  The body here is a free elastic
disc (radius 0.5, 32 cells across, G = 1, kappa = 2, rho = 1) in a light viscous fluid
(rho = 0.1, eta = 0.02, extra viscosity 0.002) in a closed box, started in its lowest
torsional mode (tangential velocity amp J1(k r), J2(k R) = 0, period 0.61) or in a
breathing (radial) motion.  The total energy -- kinetic + elastic + the fluid's compression
energy -- must never grow.

With the thesis's treatment (the default) the extrapolated reference maps just outside the
body (0 <= phi < h) change with the body's interior, not with the velocity at those nodes,
so the solid stress there does work that does not match the change of the elastic energy
stored there: the torsional mode gains 3.0 % of its energy within a twelfth of a period at
this resolution (the breathing motion 1.2 %).  Two options remove the source:
``Numerics(band_force="solid")`` applies the band's solid force to the solid nodes through
the transpose of the extrapolation, ``Numerics(advected_band=1)`` keeps the advected maps on
those nodes; each costs accuracy elsewhere, so neither is (yet) the default
(docs/method.md, "Defects fixed (issue 15)").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import j1

from refmap.boundary import Boundary
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.materials import NeoHookean
from refmap.model import Model, Solid
from refmap.state import FluidParams, Numerics

R = 0.5
K_TORSION = 5.135622301840683 / R  # first root of J2: traction-free torsional mode
PERIOD = 2 * np.pi / K_TORSION  # shear wave speed sqrt(G / rho) = 1


def _vibrating_disc(mode, n=64, amp=0.05, numerics=None):
    grid = Grid(n, n, -1.0, 1.0, -1.0, 1.0)
    solid = Solid(shape=Disc(center=(0.0, 0.0), radius=R), law=NeoHookean(G=1.0, kappa=2.0, rho0=1.0))
    model = Model(grid, (solid,), Boundary(), numerics or Numerics())
    params = model.default_params(FluidParams(rho0=0.1, lambda_f=1.0, eta=0.02, extra_viscosity=0.002))
    state = model.initial_state(params)
    X, Y = grid.mesh("node")
    r = np.hypot(X, Y)
    inside = r < R
    if mode == "torsion":
        omega = np.where(inside, amp * j1(K_TORSION * r) / np.maximum(r, 1e-12), 0.0)
        v = np.stack([-omega * Y, omega * X])
    else:  # breathing: radial velocity amp sin(pi r / R)
        vr = np.where(inside, amp * np.sin(np.pi * r / R), 0.0) / np.maximum(r, 1e-12)
        v = np.stack([vr * X, vr * Y])
    return model, params, state.replace(v=jnp.asarray(v))


def _total_energy(model, params, state):
    """Kinetic + elastic (Model.diagnostics) + the fluid's compression energy.

    The fluid's pressure p = lambda (rho / rho0 - 1) is the derivative of the energy per
    unit volume e(rho) = lambda / rho0 (rho ln(rho / rho0) - rho + rho0) (rho e' - e = p),
    weighted by the fluid fraction like the fluid's mass."""
    d = model.diagnostics(state, params)
    fl = params.fluid
    rf = state.rho_f
    e = fl.lambda_f / fl.rho0 * (rf * jnp.log(rf / fl.rho0) - rf + fl.rho0)
    wf = model.derived(state, params)["wf_n"]
    return d["kinetic_energy"] + d["elastic_energy"] + jnp.sum(wf * e) * model.grid.cell_area


def _energy_history(mode, t_end, frames, **kw):
    model, params, state = _vibrating_disc(mode, **kw)
    advance = jax.jit(model.advance)
    energy = jax.jit(lambda s: _total_energy(model, params, s))
    out = [float(energy(state))]
    for t in np.linspace(0.0, t_end, frames + 1)[1:]:
        state, info = advance(state, params, t)
        assert bool(info["ok"])
        out.append(float(energy(state)))
    return np.asarray(out)


@pytest.mark.parametrize(
    "mode, numerics",
    [
        ("torsion", Numerics(band_force="solid")),
        ("breathing", Numerics(band_force="solid")),
        ("torsion", Numerics(advected_band=1.0)),
    ],
    ids=["torsion-band_force", "breathing-band_force", "torsion-advected_band"],
)
def test_energy_of_a_vibrating_disc_never_grows(mode, numerics):
    """Energy sampled 12 times over one period never rises by more than 1e-3 (relative)
    from one sample to the next.  The allowance covers what the discrete energy does not
    balance exactly even when nothing is wrong: forward Euler (an undamped oscillator gains
    (omega dt)^2 per step, ~1e-5 per sample here, and the viscosities damp it by far more)
    and the terms cubic in the amplitude (advection, the moving blend weights; strains are
    ~1e-2).  Measured with the extrapolated near band (the default): +3.0e-2 (torsion),
    +1.2e-2 (breathing); with either option every sample is lower than the one before it
    (largest ratios: band_force 0.994 and 0.983, advected_band 0.995 and 0.991)."""
    E = _energy_history(mode, PERIOD, 12, numerics=numerics)
    rise = np.max(E[1:] / E[:-1] - 1.0)
    assert rise < 1e-3, f"{mode}: energy rose by {rise:.3e} between samples; E/E0 = {np.round(E / E[0], 4)}"
    assert E[-1] < E[0]


@pytest.mark.xfail(strict=True, reason="issue 15 item 3: the default extrapolated near band "
                   "creates energy (+3.0e-2 per twelfth of a period); strict, so a fix of the "
                   "default shows up here")
def test_default_numerics_torsion_energy_never_grows():
    E = _energy_history("torsion", PERIOD, 12)
    assert np.max(E[1:] / E[:-1] - 1.0) < 1e-3


def test_advected_band_outside_the_advected_zone_is_refused():
    with pytest.raises(ValueError, match="advected_band"):
        Numerics(advected_band=3.5)  # band 6: the map is advected only where phi < 3h
    with pytest.raises(ValueError, match="advected_band"):
        Numerics(advected_band=-1.0)
    with pytest.raises(ValueError, match="band_force"):
        Numerics(band_force="band")


def test_band_force_transfer_keeps_total_force_and_torque():
    """band_force='solid' moves the band's solid force onto solid nodes; the extrapolation
    reproduces affine fields, so the sum of the forces and their torque about any point are
    unchanged (to round-off relative to the forces moved)."""
    model, params, state = _vibrating_disc("torsion", n=32, amp=0.2,
                                           numerics=Numerics(band_force="solid"))
    state = jax.jit(lambda s: model.run_steps(s, params, 20))(state)  # a strained state
    d = model.derived(state, params)
    corr = np.asarray(model.band_force_to_solid(state, d))
    X, Y = model.grid.mesh("node")
    phi = np.asarray(state.phi[0])
    moved = np.abs(corr[:, phi >= 0]).sum()
    assert moved > 1e-3  # the band did carry solid force
    assert np.abs(corr.sum(axis=(1, 2))).max() < 1e-10 * moved
    torque = np.sum(X * corr[1] - Y * corr[0])
    assert abs(torque) < 1e-10 * moved
