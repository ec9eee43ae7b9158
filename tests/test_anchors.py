"""RegionAnchor.hold_entering: no free node may carry a held body's material.

A free node next to the contour of a body held whole by a RegionAnchor has the fluid's
velocity, so its advected map is ``x - dt v`` and the level set pinned to it is
``phi0(x - dt v)``.  Where ``dt v`` reaches past the node's distance to the contour, the
node turns solid although the anchor does not hold it, and the stiff solid's explicit
stress on it blows the run up (Turek-Hron CFD1 at 8 cells across the flag: a node 0.012 h
outside the cylinder crossed at t = 1.175 s).  ``hold_entering = True`` gives such a node
the reference map ``xi0`` instead (held material is at rest, so it cannot be there).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap.anchors import RegionAnchor
from refmap.boundary import Boundary
from refmap.casefile import build_anchor
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.materials import NeoHookean
from refmap.model import Model, Solid
from refmap.state import Numerics

PERIODIC = Boundary(left="periodic", right="periodic", bottom="periodic", top="periodic")


def test_region_anchor_holds_a_map_that_enters_its_region():
    """``RegionAnchor(hold_entering=True)``: a free node whose advected map points into the
    held region gets ``xi0`` back (else the pinned level set makes it an unheld node of
    the solid: the 8-cell Turek--Hron CFD1 blew up so); every other node is unchanged, bit
    for bit, and the velocity is the plain anchor's."""
    g = Grid(16, 16, -1.0, 1.0, -1.0, 1.0)
    disc = Disc(center=(0.0, 0.0), radius=0.5)
    X = np.stack(g.mesh("node"))
    rng = np.random.default_rng(0)
    v = jnp.asarray(rng.normal(size=X.shape))
    free = np.asarray(disc(*X)) >= 0.0
    # every free node's map moved 0.6 h towards the centre: the nodes within 0.6 h outside
    # the disc now point into it
    r = np.hypot(*X)
    xi = jnp.asarray(X - 0.6 * g.h * X / np.maximum(r, 1e-12))
    plain = RegionAnchor(disc)
    held = RegionAnchor(disc, hold_entering=True)
    v0, xi_plain = plain.apply(g, v, xi, jnp.asarray(X))
    v1, xi_held = held.apply(g, v, xi, jnp.asarray(X))
    np.testing.assert_array_equal(np.asarray(v1), np.asarray(v0))
    entering = free & (np.asarray(disc(*np.asarray(xi))) < 0.0)
    assert entering.any()
    np.testing.assert_array_equal(np.asarray(xi_held)[:, entering], X[:, entering])
    np.testing.assert_array_equal(np.asarray(xi_held)[:, ~entering], np.asarray(xi_plain)[:, ~entering])
    assert held.to_dict()["hold_entering"] is True and "hold_entering" not in plain.to_dict()


def _held_disc_in_a_stream(gap_cells: float, hold_entering: bool):
    """A stiff disc held whole in a uniform stream u = 0.2 (incompressible fluid, implicit
    viscosity, periodic 32^2 box), its radius chosen so that the node nearest (0.4, 0) on
    its downstream side lies ``gap_cells`` h outside the contour.  dt = h / 4: the stream
    moves a map by 0.05 h per step, and the solid's wave (c = 150) crosses 37 cells per
    step, far past its explicit limit, as in CFD1, so only the anchor keeps it still."""
    n = 32
    grid = Grid(n, n, -1.0, 1.0, -1.0, 1.0)
    X, Y = (np.asarray(a) for a in grid.mesh("node"))
    j0 = int(np.argmin(np.abs(Y[0])))
    i0 = int(np.argmin(np.abs(X[:, 0] - 0.4)))
    r = float(np.hypot(X[i0, j0], Y[i0, j0]) - gap_cells * grid.dx)
    disc = Disc(center=(0.0, 0.0), radius=r)
    anchor = RegionAnchor(disc, hold_entering=hold_entering)
    solid = Solid(shape=disc, law=NeoHookean(G=1e4, kappa=1e4, rho0=1.0), anchor=anchor)
    model = Model(
        grid, (solid,), PERIODIC, Numerics(fluid_model="incompressible", viscosity="implicit")
    )
    params = model.default_params()
    s = model.initial_state(params)
    held = np.asarray(anchor.weight(grid)) > 0.5
    s = s.replace(v=jnp.stack([0.2 * jnp.asarray(~held, float), jnp.zeros_like(s.rho_f)]))
    return model, params, s, held, 0.25 * grid.dx


def test_hold_entering_keeps_free_nodes_out_of_a_held_body():
    """Node 0.01 h outside the contour, downstream: without the option the node is advected
    into the body and the run is not finite within 10 steps (measured: |v| 4e23 after 5
    steps, 113 unheld solid nodes); with it no free node turns solid in 30 steps and the
    speed stays at the stream's (measured 0.253 after 5 steps, 0.233 after 30)."""
    out = {}
    for hold in (False, True):
        model, params, s, held, dt = _held_disc_in_a_stream(0.01, hold)
        run = jax.jit(lambda s, model=model, params=params, dt=dt: model.run_steps(s, params, 5, dt))
        worst, unheld = 0.0, 0
        for _ in range(6):
            s = run(s)
            speed = float(jnp.max(jnp.abs(s.v)))
            worst = max(worst, speed) if np.isfinite(speed) else np.inf  # NaN counts as blown up
            unheld = max(unheld, int(jnp.sum((s.phi[0] < 0) & jnp.asarray(~held))))
        out[hold] = (worst, unheld)
    assert not out[False][0] < 1.0  # blew up (or NaN)
    assert out[True][1] == 0
    assert out[True][0] < 0.3  # the stream's 0.2 and its start-up transient


def test_hold_entering_changes_nothing_where_no_map_enters():
    """Nearest node half a cell outside: no map reaches the body in 10 steps (0.05 h per
    step), so the option leaves the run bit for bit as it was."""
    states = []
    for hold in (False, True):
        model, params, s, _, dt = _held_disc_in_a_stream(0.5, hold)
        states.append(jax.jit(lambda s, m=model, p=params, dt=dt: m.run_steps(s, p, 10, dt))(s))
    a, b = states
    for f in ("v", "xi", "phi", "p"):
        assert np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f))), f
    assert bool(jnp.all(jnp.isfinite(a.v)))


@pytest.mark.parametrize("value", [True, False])
def test_hold_entering_in_case_files(value):
    d = {"type": "region", "region": {"type": "disc", "center": [0.0, 0.0], "radius": 0.3},
         "hold_entering": value}
    anchor = build_anchor(d)
    assert isinstance(anchor, RegionAnchor) and anchor.hold_entering is value
    assert build_anchor(anchor.to_dict()) == anchor
    assert ("hold_entering" in anchor.to_dict()) is value
