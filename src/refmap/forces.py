"""Forces on held bodies from the discrete momentum balance (drag and lift).

The velocity update of :meth:`refmap.model.Model.step` is ``v <- v + dt a`` with the
acceleration

    a = -(v . grad) v + (div sigma + extra_viscosity lap v + sum of body forces) / rho + g,

after which an anchor sets v = 0 on the nodes it holds.  The anchor therefore removes the
momentum ``rho a dA`` from every held node each step: the force it applies to hold the body
is ``-sum_held rho a dA``, and the force the rest of the world (fluid, and any free part of
the same solid) exerts on the held nodes is

    F_held = sum_held rho a dA = sum_held (div sigma + extra_viscosity lap v + f_body) dA

(``(v . grad) v`` vanishes on held nodes, where v = 0).  The stress divergence telescopes
(the top-right-triangle divergence is a difference of corner values), so this is exactly the
traction of the blended corner stress on the staircase contour round the held nodes.

When a free elastic part (the Turek--Hron flag) hangs on the held part (the cylinder) and
the flow is steady, the flag is in equilibrium and passes the fluid load on it to its root,
so F_held is the drag and lift on cylinder + flag.  :func:`region_force` with a larger
region (a box round the body, in the fluid) gives the control-volume form

    F_box = sum_box rho a dA = F_held + sum_(box, not held) rho a dA,

i.e. the stress traction on the box's edges minus the (non-conservative, as in the scheme)
momentum flux; the difference from F_held is the rate of change of the momentum of what is
free inside the box, which is zero in a steady state.  Comparing the two is a check that the
state is steady.  Everything here repeats the model's own terms, so the balance is exact to
round-off at every step (tested against :meth:`Model.step`).

Incompressible fluid (``Numerics(fluid_model="incompressible")``).  The fluid pressure is
not in the blended stress: the projection applies ``v = v* - dt rho^-1 G p`` after the
predictor ``v* = v + dt a`` (:mod:`refmap.projection`; ``G = -B^T`` the backward
difference), and an anchor's nodes take no correction (weight ``1 - w_anchor``).  The
momentum the clamp removes from a held node is therefore ``rho a - G p`` per unit area:
the pressure force ``-G p dA`` (not divided by rho) is added to every node of the region.
``pressure`` is the projection pressure of the step from ``state``
(:func:`projection_pressure`, i.e. ``Model.step(..., return_pressure=True)``); when it is
not given for an incompressible model it is computed with the model's own time step
(``Numerics.dt_fixed`` in the validation runs).  Inside a held region ``p`` is not fixed
by the projection (no free velocity in its continuity rows), but those rows contribute
nothing to a sum of ``G p`` over the region (a constant in ``B^T``'s row telescopes), so
the region force is well defined.

With ``Numerics.viscosity = "implicit"`` the step takes the viscous force at the new
velocity; :func:`acceleration` evaluates it at the state's, so the balance holds once the
flow is steady (where the two are equal), not step by step.  (The incompressible step
carries the last pressure, ``State.p``, and solves for its increment; the pressure here is
always the whole one, ``p^n + increment``.)
"""

from __future__ import annotations

import jax.numpy as jnp

from refmap.operators import advect, div_node, laplacian


def acceleration(model, state, params, derived=None):
    """The model's acceleration a (2, nx, ny) before anchors, and the mixed density rho."""
    g = model.grid
    fl = params.fluid
    d = model.derived(state, params) if derived is None else derived
    vp = model.bc.pad_velocity(state.v, state.t)
    force = div_node(d["sxx"], d["sxy"], d["syy"], g.dx, g.dy)
    force = force + fl.extra_viscosity * laplacian(vp, g.dx, g.dy, g=2)
    ctx = dict(state=state, params=params, derived=d, model=model)
    for term in model.body_forces:
        force = force + term(ctx)
    rho = d["rho"]
    acc = (
        advect(vp, state.v, g.dx, g.dy)
        + force / rho[None]
        + jnp.asarray(params.gravity)[:, None, None]
    )
    return acc, rho


def projection_pressure(model, state, params, dt=None):
    """The projection pressure (nx, ny) of the step of size ``dt`` (default: the model's
    own, :meth:`Model.time_step`) from ``state``; incompressible models only."""
    if model.projection is None:
        raise ValueError("projection_pressure: the model's fluid is not incompressible")
    if dt is None:
        dt, _ = model.time_step(state, params)
    return model.step(state, params, dt, return_pressure=True)


def pressure_force_density(model, pressure):
    """``-G p`` (2, nx, ny): the projection pressure's force per unit area on each node."""
    return model.projection.BT(pressure)


def region_force(model, state, params, weight, derived=None, pressure=None):
    """``sum weight * (rho * a - G p) * dA`` (2,): the net force on the nodes selected by
    ``weight`` (a 0/1 node mask or a weight field, (nx, ny)).  The projection pressure's
    term ``-G p`` only for an incompressible model (``pressure``: see the module notes;
    computed with the model's time step when None)."""
    acc, rho = acceleration(model, state, params, derived)
    w = jnp.asarray(weight)
    f = rho[None] * acc
    if model.projection is not None:
        if pressure is None:
            pressure = projection_pressure(model, state, params)
        f = f + pressure_force_density(model, pressure)
    elif pressure is not None:
        raise ValueError("region_force: a pressure was given but the fluid is compressible")
    return jnp.sum(w[None] * f, axis=(-2, -1)) * model.grid.cell_area


def anchor_weight(model, k: int = 0):
    """Node weight (nx, ny) of the anchor of solid k (its held nodes)."""
    anchor = model.solids[k].anchor
    if anchor is None or not hasattr(anchor, "weight"):
        raise ValueError(f"solid {k} has no region anchor")
    return anchor.weight(model.grid)


def held_force(model, state, params, k: int = 0, derived=None, pressure=None):
    """Force (2,) the surroundings exert on the nodes held by solid k's region anchor:
    minus the anchor's reaction; the drag (x) and lift (y) on the held body and whatever
    hangs on it, once the flow is steady.  ``pressure``: see :func:`region_force`."""
    return region_force(model, state, params, anchor_weight(model, k), derived, pressure)


def box_mask(grid, box):
    """0/1 node mask of the nodes inside ``box = (x0, x1, y0, y1)``."""
    X, Y = grid.mesh("node")
    x0, x1, y0, y1 = box
    return ((X > x0) & (X < x1) & (Y > y0) & (Y < y1)).astype(float)


__all__ = [
    "acceleration",
    "projection_pressure",
    "pressure_force_density",
    "region_force",
    "anchor_weight",
    "held_force",
    "box_mask",
]
