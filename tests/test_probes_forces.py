"""Material-point probe (refmap.probes) and momentum-balance forces (refmap.forces)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import refmap  # noqa: F401
from refmap.anchors import RegionAnchor
from refmap.boundary import Boundary, Segment
from refmap.forces import acceleration, box_mask, held_force, region_force
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.materials import NeoHookean
from refmap.model import Model, Solid
from refmap.probes import bilinear, material_point
from refmap.state import FluidParams, Numerics, Params


def test_material_point_is_exact_for_an_affine_map():
    """xi(x) = A x + b is reproduced exactly by bilinear interpolation, so Newton lands on
    x = A^-1 (X0 - b) to round-off, for points anywhere in the grid (not on nodes)."""
    g = Grid(23, 17, 0.1, 1.3, -0.2, 0.5)
    X, Y = g.mesh("node")
    A = np.array([[1.1, 0.3], [-0.2, 0.9]])
    b = np.array([0.05, -0.03])
    xi = jnp.asarray(np.stack([A[0, 0] * X + A[0, 1] * Y + b[0], A[1, 0] * X + A[1, 1] * Y + b[1]]))
    X0 = np.array([[0.41, 0.77, 1.02], [0.13, -0.05, 0.31]])
    x, res = material_point(xi, g, X0)
    exact = np.linalg.solve(A, X0 - b[:, None])
    np.testing.assert_allclose(np.asarray(x), exact, atol=1e-13)
    assert float(jnp.max(res)) < 1e-13


def test_material_point_found_after_a_move_longer_than_the_band():
    """A disc of radius 0.1 translated by 0.3 (15 cells): the map is affine (xi = x - d)
    inside the disc and its 3-cell band, and holds stale values (its initial identity, as
    a band leaves behind) elsewhere.  Started at X0 the Newton iteration lands where the
    stale map equals X0, i.e. where the point was, and the residual there is zero; that
    is the failure that lost the Turek--Hron point A once the flag tip had fallen 8 cells.
    Started from the nearest node inside ``phi < 2h`` it finds the moved point exactly."""
    g = Grid(50, 40, 0.0, 1.0, 0.0, 0.8)
    X, Y = g.mesh("node")
    d = np.array([0.3, -0.12])
    c = np.array([0.62, 0.3])  # centre now; the material came from c - d
    phi = np.hypot(X - c[0], Y - c[1]) - 0.1
    band = phi < 3 * g.h
    xi = jnp.asarray(np.stack([np.where(band, X - d[0], X), np.where(band, Y - d[1], Y)]))
    # one point inside the disc, one just outside it (0.102 from the centre), in its band
    X0 = np.array([[0.32 + 0.05, 0.32 - 0.1], [0.42, 0.42 + 0.02]])
    x_old, _ = material_point(xi, g, X0)
    assert np.all(np.abs(np.asarray(x_old) - X0) < 1e-12)  # stuck where it was
    x, res = material_point(xi, g, X0, phi=jnp.asarray(phi))
    np.testing.assert_allclose(np.asarray(x), X0 + d[:, None], atol=1e-13)
    assert float(jnp.max(res)) < 1e-13


def test_material_point_of_a_smooth_map_is_second_order():
    """A smooth non-affine displacement: the bilinear error halves twice per refinement."""
    errs = []
    for n in (16, 32):
        g = Grid(n, n, 0.0, 1.0, 0.0, 1.0)
        X, Y = g.mesh("node")
        # x = chi(X) = X + 0.05 (sin(2 X + Y), cos(X - 3 Y)) and xi = chi^-1 on the nodes,
        # by fixed-point iteration (contraction: |grad of the displacement| <= 0.2)
        Xr, Yr = X.copy(), Y.copy()
        for _ in range(80):
            Xr = X - 0.05 * np.sin(2 * Xr + Yr)
            Yr = Y - 0.05 * np.cos(Xr - 3 * Yr)
        xi = jnp.asarray(np.stack([Xr, Yr]))
        P = np.array([0.43, 0.61])
        exact = P + 0.05 * np.array([np.sin(2 * P[0] + P[1]), np.cos(P[0] - 3 * P[1])])
        x, _ = material_point(xi, g, P)
        errs.append(np.abs(np.asarray(x) - exact).max())
    assert errs[1] < errs[0] / 3.0  # ~4x for second order; > 3x leaves room for the offset
    assert errs[1] < 2e-4


def test_bilinear_gradient_matches_finite_difference():
    g = Grid(12, 10, 0.0, 1.0, 0.0, 1.0)
    X, Y = g.mesh("node")
    f = jnp.asarray(np.sin(3 * X) * np.cos(2 * Y))
    x, y, e = 0.437, 0.291, 1e-7
    _, fx, fy = bilinear(f, g, x, y)
    fxp = bilinear(f, g, x + e, y)[0]
    fxm = bilinear(f, g, x - e, y)[0]
    fyp = bilinear(f, g, x, y + e)[0]
    fym = bilinear(f, g, x, y - e)[0]
    assert abs(float(fx) - float(fxp - fxm) / (2 * e)) < 1e-6
    assert abs(float(fy) - float(fyp - fym) / (2 * e)) < 1e-6


def _channel_model(anchor):
    g = Grid(40, 24, 0.0, 1.0, 0.0, 0.6)
    inflow = Segment("velocity", velocity=(0.4, 0.0), profile="parabolic")
    bnd = Boundary(left=(inflow,), right=(Segment("outflow"),))
    solid = Solid(
        shape=Disc(center=(0.35, 0.3), radius=0.12), law=NeoHookean(G=4.0, kappa=8.0), anchor=anchor
    )
    model = Model(g, (solid,), bnd, Numerics(dt_fixed=2e-3))
    params = Params(
        fluid=FluidParams(rho0=1.0, lambda_f=10.0, eta=0.1, extra_viscosity=0.01),
        laws=(solid.law,),
        gravity=(0.0, -0.3),
    )
    return model, params


def _stirred_state(model, params):
    s = model.initial_state(params)
    X, Y = model.grid.mesh("node")
    v = jnp.asarray(np.stack([0.3 + 0.1 * np.sin(5 * Y), 0.05 * np.cos(4 * X)]))
    return s.replace(v=v, rho_f=s.rho_f * (1 + 0.01 * jnp.asarray(np.sin(7 * X))))


def test_acceleration_is_the_model_step_update():
    """Model.step does v <- v + dt a (no anchor): forces.acceleration must be that a."""
    model, params = _channel_model(anchor=None)
    s = _stirred_state(model, params)
    dt = 2e-3
    s1 = jax.jit(model.step)(s, params, dt)
    acc, _ = jax.jit(lambda st: acceleration(model, st, params))(s)
    np.testing.assert_allclose(np.asarray(s1.v), np.asarray(s.v + dt * acc), rtol=0, atol=1e-12)


def test_held_force_is_the_momentum_the_clamp_removes():
    """With a region anchor, the momentum removed in one step, sum rho (v_free - v) dA / dt
    (v_free: the same step without the anchor), equals held_force; the box form over the
    whole domain minus the free nodes' rate of change is the same number."""
    disc = Disc(center=(0.35, 0.3), radius=0.12)
    model_a, params = _channel_model(anchor=RegionAnchor(disc))
    model_f, _ = _channel_model(anchor=None)
    s = _stirred_state(model_a, params)
    w = np.asarray(RegionAnchor(disc).weight(model_a.grid))
    s = s.replace(v=s.v * (1 - w)[None])  # held nodes at rest, as after any step
    dt = 2e-3
    v_free = jax.jit(model_f.step)(s, params, dt).v
    v_held = jax.jit(model_a.step)(s, params, dt).v
    rho = model_a.derived(s, params)["rho"]
    removed = (
        np.asarray(jnp.sum(rho[None] * (v_free - v_held), axis=(1, 2)))
        * model_a.grid.cell_area
        / dt
    )
    F = np.asarray(held_force(model_a, s, params))
    np.testing.assert_allclose(F, removed, rtol=1e-10, atol=1e-12)
    acc, rho = acceleration(model_a, s, params)
    whole = np.asarray(region_force(model_a, s, params, np.ones(model_a.grid.shape())))
    free = (
        np.asarray(jnp.sum((1 - w)[None] * rho[None] * acc, axis=(1, 2))) * model_a.grid.cell_area
    )
    np.testing.assert_allclose(whole - free, F, rtol=1e-10, atol=1e-12)
    assert box_mask(model_a.grid, (0.2, 0.5, 0.15, 0.45)).sum() > w.sum()
