"""refmap.forces with an incompressible fluid: the projection pressure's force -G p."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401
from refmap.anchors import RegionAnchor
from refmap.boundary import Boundary, Segment
from refmap.forces import (
    acceleration,
    held_force,
    pressure_force_density,
    projection_pressure,
    region_force,
)
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.materials import NeoHookean
from refmap.model import Model, Solid
from refmap.state import FluidParams, Numerics, Params


def test_hydrostatic_held_disc_feels_weight_minus_buoyancy():
    """A closed box of incompressible fluid (rho_f = 1) at rest under gravity g = -2 with a
    disc (rho_s = 3, r = 0.15) held by an anchor region that covers its whole blur zone
    (r + 8h: the erfc tail beyond it is 1e-8)
    (so every free node is pure fluid and rest is an exact discrete equilibrium).  The
    projection pressure is hydrostatic, p = rho_f g y + c, the state stays at rest, and
    the held force is weight minus buoyancy: sum_held (rho - rho_f) g dA exactly, which is
    (rho_s - rho_f) pi (r^2 + 2 h^2) g, the blurred disc's weight less its buoyancy.  Without the pressure term the held
    force would be the whole weight of the held nodes."""
    g = Grid(32, 32, 0.0, 1.0, 0.0, 1.0)
    r, rho_s, rho_f, grav = 0.15, 3.0, 1.0, -2.0
    disc = Disc(center=(0.5, 0.5), radius=r)
    solid = Solid(
        shape=disc,
        law=NeoHookean(G=5.0, kappa=10.0, rho0=rho_s),
        anchor=RegionAnchor(Disc(center=(0.5, 0.5), radius=r + 8.0 * g.h)),
    )
    model = Model(g, (solid,), Boundary(), Numerics(fluid_model="incompressible", dt_fixed=1e-3))
    params = Params(
        fluid=FluidParams(rho0=rho_f, lambda_f=10.0, eta=0.1, extra_viscosity=0.0),
        laws=(solid.law,),
        gravity=(0.0, grav),
    )
    s = model.initial_state(params)
    p = np.asarray(jax.jit(lambda st: projection_pressure(model, st, params))(s))
    held = np.asarray(solid.anchor.weight(g))
    # hydrostatic on the free nodes' rows (the rows inside the held region are free)
    _, Y = g.mesh("node")
    hyd = rho_f * grav * Y  # grad p = rho_f g
    free = held == 0
    dev = (p - hyd)[free]
    assert np.ptp(dev) < 1e-8 * np.ptp(hyd)
    s1 = jax.jit(model.step)(s, params, 1e-3)
    assert float(jnp.max(jnp.abs(s1.v))) < 1e-10
    F = np.asarray(held_force(model, s, params))
    rho = np.asarray(model.derived(s, params)["rho"])
    expect = np.sum(held * (rho - rho_f)) * grav * g.cell_area
    assert abs(F[0]) < 1e-9
    np.testing.assert_allclose(F[1], expect, rtol=1e-8)
    # the blurred disc's solid area: pi (r^2 + 2 h^2) (a Gaussian blur of variance 2 h^2)
    area = math.pi * (r**2 + 2.0 * g.h**2)
    np.testing.assert_allclose(F[1], (rho_s - rho_f) * area * grav, rtol=0.03)
    # the same with the pressure passed in; the weight alone is far off
    np.testing.assert_allclose(np.asarray(held_force(model, s, params, pressure=p)), F, atol=1e-12)
    weight = np.sum(held * rho) * grav * g.cell_area
    assert abs(weight - F[1]) > 0.5 * abs(F[1])


def _incompressible_channel(anchor):
    g = Grid(40, 24, 0.0, 1.0, 0.0, 0.6)
    inflow = Segment("velocity", velocity=(0.4, 0.0), profile="parabolic")
    bnd = Boundary(left=(inflow,), right=(Segment("outflow"),))
    solid = Solid(
        shape=Disc(center=(0.35, 0.3), radius=0.12), law=NeoHookean(G=4.0, kappa=8.0), anchor=anchor
    )
    model = Model(g, (solid,), bnd, Numerics(fluid_model="incompressible", dt_fixed=2e-3))
    params = Params(
        fluid=FluidParams(rho0=1.0, lambda_f=10.0, eta=0.1, extra_viscosity=0.01),
        laws=(solid.law,),
        gravity=(0.0, -0.3),
    )
    return model, params


def test_incompressible_region_force_is_the_step_momentum_change():
    """One step of the incompressible model with a held disc: on every free node (not the
    inflow column, whose u is prescribed) rho (v_new - v) / dt = rho a - G p with the
    step's own projection pressure (low-edge rows left out: their normal velocity is
    prescribed), so region_force over the free nodes is their momentum change per unit
    time to round-off; the held force is the rest of the whole-domain force
    and its pressure part is not small (the clamp holds the body against the pressure)."""
    disc = Disc(center=(0.35, 0.3), radius=0.12)
    model, params = _incompressible_channel(RegionAnchor(disc))
    s = model.initial_state(params)
    X, Y = model.grid.mesh("node")
    w = np.asarray(RegionAnchor(disc).weight(model.grid))
    v = np.stack([0.3 + 0.1 * np.sin(5 * Y), 0.05 * np.cos(4 * X)]) * (1 - w)[None]
    s = s.replace(v=jnp.asarray(v))
    dt = 2e-3
    s1 = jax.jit(model.step)(s, params, dt)
    p = jax.jit(lambda st: model.step(st, params, dt, return_pressure=True))(s)
    acc, rho = acceleration(model, s, params)
    rate = rho[None] * (s1.v - s.v) / dt
    pred = rho[None] * acc + pressure_force_density(model, p)
    free = (1 - w).copy()
    # the low edges' normal components are prescribed, not corrected: leave out the inflow
    # column and the bottom wall's row
    free[0, :] = 0.0
    free[:, 0] = 0.0
    np.testing.assert_allclose(
        np.asarray(rate * free[None]), np.asarray(pred * free[None]), rtol=0, atol=1e-9
    )
    ca = model.grid.cell_area
    F_free = np.asarray(region_force(model, s, params, free, pressure=p))
    np.testing.assert_allclose(
        F_free, np.asarray(jnp.sum(free[None] * rate, axis=(1, 2))) * ca, rtol=1e-10, atol=1e-10
    )
    F_held = np.asarray(held_force(model, s, params, pressure=p))
    F_all = np.asarray(region_force(model, s, params, np.ones_like(w), pressure=p))
    F_col = np.asarray(region_force(model, s, params, 1 - w - free, pressure=p))
    np.testing.assert_allclose(F_held + F_free + F_col, F_all, rtol=1e-12, atol=1e-12)
    no_p = np.asarray(jnp.sum(w[None] * rho[None] * acc, axis=(1, 2))) * ca
    assert np.linalg.norm(F_held - no_p) > 0.1 * np.linalg.norm(F_held)


def test_region_force_rejects_a_pressure_for_a_compressible_model():
    g = Grid(8, 8, 0.0, 1.0, 0.0, 1.0)
    model = Model(g, (), Boundary(), Numerics(dt_fixed=1e-3))
    params = Params(fluid=FluidParams(rho0=1.0, lambda_f=1.0, eta=0.1), laws=())
    s = model.initial_state(params)
    with pytest.raises(ValueError, match="compressible"):
        region_force(model, s, params, np.ones(g.shape()), pressure=jnp.zeros(g.shape()))
    with pytest.raises(ValueError, match="not incompressible"):
        projection_pressure(model, s, params)
