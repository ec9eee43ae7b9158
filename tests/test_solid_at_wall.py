"""Solids touching the domain edges: what Case.validate allows, and the glued-wall ghosts of
the reference map (BoundaryConditions.glue)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401
from refmap.boundary import Boundary, BoundaryConditions, Segment
from refmap.case import Case, CaseError
from refmap.geometry import Disc, Rectangle
from refmap.grid import Grid
from refmap.materials import LogNeoHookean
from refmap.model import Solid
from refmap.state import FluidParams, Numerics

LAW = LogNeoHookean(G=2.0, kappa=10.0, rho0=1.0)
GRID = Grid(24, 24, 0.0, 1.0, 0.0, 1.0)
FLUID = FluidParams(rho0=1.0, lambda_f=10.0, eta=0.05, extra_viscosity=0.02)


def _case(shape, boundary=None, gravity=(0.0, 0.0), grid=GRID):
    return Case(
        name="wall",
        grid=grid,
        solids=(Solid(shape=shape, law=LAW, name="block"),),
        boundary=boundary if boundary is not None else Boundary(),
        fluid=FLUID,
        numerics=Numerics(),
        gravity=gravity,
    )


CORNER = Rectangle(center=(0.0, 0.0), half_size=(0.4, 0.3))  # fills x < 0.4, y < 0.3


def test_validate_allows_walls_slip_and_tangential_velocity_rejects_flow_through():
    slab = Rectangle(center=(0.5, 0.0), half_size=(2.0, 0.3))  # touches left, right, bottom
    _case(slab).validate()
    _case(slab, Boundary(bottom="slip", left="slip", right="slip")).validate()
    lid = Rectangle(center=(0.5, 1.0), half_size=(2.0, 0.3))
    moving = Boundary(top=(Segment("velocity", velocity=(1.0, 0.0)),))
    _case(lid, moving).validate()
    with pytest.raises(CaseError, match="right edge where it is a 'outflow' segment"):
        _case(slab, Boundary(right="outflow")).validate()
    inflow = Boundary(left=(Segment("velocity", velocity=(0.5, 0.0)),), right="outflow")
    with pytest.raises(CaseError, match="left edge where it is a 'velocity' segment"):
        _case(Disc(center=(0.05, 0.5), radius=0.2), inflow).validate()
    # an inflow on the upper half of the left edge only: the corner block touches the wall part
    part = Boundary(
        left=(Segment("wall", 0.0, 0.5), Segment("velocity", 0.5, 1.0, velocity=(0.5, 0.0))),
        right="outflow",
    )
    _case(CORNER, part).validate()
    with pytest.raises(CaseError, match="left edge"):
        _case(Rectangle(center=(0.0, 0.5), half_size=(0.3, 0.4)), part).validate()


def test_glue_ghosts_reflect_about_the_initial_face_value():
    grid = Grid(10, 12, 0.0, 1.0, 0.0, 1.2)
    bnd = Boundary(left="periodic", right="periodic", bottom=(Segment("wall"),), top="slip")
    bc = BoundaryConditions(grid, bnd)
    X = np.asarray(grid.mesh("node"))
    rng = np.random.default_rng(0)
    d0 = 0.01 * rng.standard_normal((1, 2) + grid.shape())
    solid0 = np.ones((1,) + grid.shape(), dtype=bool)
    plain = np.asarray(bc.pad_affine(jnp.asarray(X + d0)))
    bc.glue(d0, solid0)
    d = d0 + 0.02 * rng.standard_normal(d0.shape)  # a later, different map
    xip = np.asarray(bc.pad_affine(jnp.asarray(X + d)))
    Xp = bc.padded_coords(2)
    dp = xip - Xp
    face_bottom = 1.5 * d0[..., 0] - 0.5 * d0[..., 1]  # (1, 2, nx)
    # bottom (no-slip wall at rest): both components odd about the initial face value
    np.testing.assert_allclose(0.5 * (dp[..., 2:-2, 1] + dp[..., 2:-2, 2]), face_bottom, atol=1e-14)
    np.testing.assert_allclose(0.5 * (dp[..., 2:-2, 0] + dp[..., 2:-2, 3]), face_bottom, atol=1e-14)
    # top (slip): the normal component (y) odd about its face value, the tangential one even
    face_top = 1.5 * d0[..., -1] - 0.5 * d0[..., -2]
    np.testing.assert_allclose(
        0.5 * (dp[:, 1, 2:-2, -2] + dp[:, 1, 2:-2, -3]), face_top[:, 1], atol=1e-14
    )
    np.testing.assert_allclose(dp[:, 0, 2:-2, -2], dp[:, 0, 2:-2, -3], atol=1e-14)
    # periodic x: the ghost columns are wrapped copies
    np.testing.assert_allclose(dp[..., 0, :], dp[..., -4, :], atol=1e-14)
    # a solid that touches no edge at t = 0 is padded exactly as before (linear ghosts)
    bc2 = BoundaryConditions(grid, bnd)
    away = np.zeros_like(solid0)
    away[:, 3:7, 4:8] = True
    bc2.glue(d0, away)
    assert np.array_equal(np.asarray(bc2.pad_affine(jnp.asarray(X + d0))), plain)


def _advance(case, t):
    model, params = case.build()
    s = model.initial_state(params)
    s, info = jax.jit(model.advance)(s, params, t)
    return model, params, s, info


def test_solid_glued_in_a_corner_stays_at_rest_with_zero_stress():
    model, params, s, info = _advance(_case(CORNER), 0.5)
    assert bool(info["ok"])
    d = model.derived(s, params)
    assert float(jnp.abs(s.v).max()) < 1e-12
    assert float(jnp.abs(d["sigma_s"]).max()) < 1e-10  # solid and extrapolated band
    np.testing.assert_allclose(np.asarray(s.xi), model._xi0, atol=1e-12)


def test_loaded_solid_in_a_corner_settles():
    """A block (rho = rho_f) glued into a corner under gravity settles under its weight.

    With linear ghosts of xi the first node row gets no elastic force normal to the wall
    (the wall-face strain copies the next one) and the corner runs away: measured at 24^2,
    t = 2: max |v| 0.40 and J in [0.80, 1.09] (at 32^2 J fell to 0.17 by t = 4).  With the
    glued ghosts: max |v| 0.019, J in [0.949, 1.036].  The bounds sit between the two.
    """
    model, params, s, info = _advance(_case(CORNER, gravity=(0.0, -1.0)), 2.0)
    assert bool(info["ok"])
    d = model.derived(s, params)
    inside = np.asarray(d["phic"][0]) < 0
    J = np.asarray(d["J"][0])[inside]
    assert float(jnp.abs(s.v).max()) < 0.05
    assert 0.85 < J.min() and J.max() < 1.1
