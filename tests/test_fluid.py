"""The fluid on its own: reference density at flow-through edges, bulk viscosity, and the
warning for under-damped sound."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401
from refmap.boundary import Boundary, Segment
from refmap.case import Case, CaseWarning
from refmap.grid import Grid
from refmap.scenarios import SCENARIOS
from refmap.state import FluidParams


def _lid(n=32, bulk=0.0):
    return Case(
        name="lid",
        grid=Grid(n, n, 0.0, 1.0, 0.0, 1.0),
        boundary=Boundary(top=(Segment("velocity", velocity=(1.0, 0.0)),)),
        fluid=FluidParams(lambda_f=100.0, eta=0.0, extra_viscosity=0.01, bulk_viscosity=bulk),
        t_end=0.1,
        frames=1,
    )


@pytest.mark.filterwarnings("ignore::refmap.case.CaseWarning")
def test_uniform_inflow_of_a_dense_fluid_stays_uniform():
    """Uniform flow U through a channel (velocity inflow on the left, outflow on the right,
    periodic in y) is an exact steady state whatever the fluid's density: the inflow's
    density ghosts must carry the fluid's own rho0 (they once carried 1.0, a jump of
    lambda_f (1/rho0 - 1), about -4000 Pa, in pressure at the inlet for rho0 = 1000)."""
    U = 0.2
    case = Case(
        name="channel",
        grid=Grid(24, 8, 0.0, 3.0, 0.0, 1.0),
        boundary=Boundary(
            left=(Segment("velocity", velocity=(U, 0.0)),),
            right="outflow",
            bottom="periodic",
            top="periodic",
        ),
        fluid=FluidParams(rho0=1000.0, lambda_f=4000.0, eta=2.0, extra_viscosity=0.0),
    )
    model, params = case.build()
    s0 = model.initial_state(params)
    s0 = s0.replace(v=jnp.stack([jnp.full_like(s0.rho_f, U), jnp.zeros_like(s0.rho_f)]))
    assert np.allclose(np.asarray(s0.rho_f), 1000.0)
    s = model.run_steps(s0, params, 50)
    # round-off of the sums of O(1000) densities: 1e-9 relative
    assert np.abs(np.asarray(s.rho_f) / 1000.0 - 1.0).max() < 1e-9
    assert np.abs(np.asarray(s.v[0]) - U).max() < 1e-9


def test_bulk_viscosity_adds_zeta_div_v_to_the_normal_stresses():
    """v = a (x, y): div v = 2a everywhere, so sxx and syy gain exactly 2 a zeta."""
    a, zeta = 0.3, 0.7
    base = Case(name="bulk", grid=Grid(16, 16), boundary=Boundary(*(["periodic"] * 4)))
    out = []
    for z in (0.0, zeta):
        case = base.replace(fluid=FluidParams(bulk_viscosity=z))
        model, params = case.build()
        s = model.initial_state(params)
        X, Y = model.grid.mesh("node")
        s = s.replace(v=jnp.stack([a * jnp.asarray(X), a * jnp.asarray(Y)]))
        d = model.derived(s, params)
        out.append((np.asarray(d["sxx"]), np.asarray(d["syy"]), np.asarray(d["sxy"])))
    # away from the periodic seam, where the linear field wraps
    inner = (slice(2, -2), slice(2, -2))
    assert np.allclose(out[1][0][inner] - out[0][0][inner], 2 * a * zeta, atol=1e-12)
    assert np.allclose(out[1][1][inner] - out[0][1][inner], 2 * a * zeta, atol=1e-12)
    assert np.allclose(out[1][2][inner], out[0][2][inner], atol=1e-14)


def test_under_damped_sound_warns_and_names_the_cure():
    with pytest.warns(CaseWarning, match=r"bulk_viscosity >= 0\.146"):
        _lid().validate()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _lid(bulk=0.15).validate()


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_scenarios_do_not_warn(name):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        SCENARIOS[name](n=64).validate()


def test_bulk_viscosity_tames_the_low_mach_cavity():
    """Lid-driven cavity, c = 10, viscosity 0.01, 32^2.  Without damping the sound grows
    (measured max |v| = 12 at t = 0.1 for a lid speed of 1); with bulk_viscosity = c h it
    stays below the lid speed (measured 0.65) and the mean density stays at 1 (4e-5)."""
    results = {}
    for bulk in (0.0, 10.0 / 32):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CaseWarning)
            model, params = _lid(bulk=bulk).build()
        s = model.initial_state(params)
        s = model.advance(s, params, 0.1)[0]
        results[bulk] = (float(jnp.abs(s.v).max()), float(jnp.mean(s.rho_f)))
    assert results[0.0][0] > 3.0  # the instability this guards against
    assert results[10.0 / 32][0] < 1.0
    assert abs(results[10.0 / 32][1] - 1.0) < 1e-3
    jax.clear_caches()


def test_no_sound_warning_without_fluid():
    """A periodic box filled with solid has no fluid, so its fluid parameters do not matter."""
    from refmap.geometry import Rectangle
    from refmap.materials import LogNeoHookean
    from refmap.model import Solid

    solid = Solid(shape=Rectangle(center=(0.5, 0.5), half_size=(2.0, 2.0)), law=LogNeoHookean(G=10.0, kappa=10.0))
    case = Case(
        name="filled",
        grid=Grid(16, 16, 0.0, 1.0, 0.0, 1.0),
        solids=(solid,),
        boundary=Boundary(*(["periodic"] * 4)),
        fluid=FluidParams(eta=0.0, extra_viscosity=0.0),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        case.validate()
    with pytest.warns(CaseWarning):
        case.replace(solids=()).validate()
