"""Shared by the warm-start tests of the implicit viscosity and the projection: one
``Model.advance`` call (warm-started solves) against a loop of cold ``Model.step`` calls."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def advance_against_cold_steps(model, params, n_steps: int):
    """``(dt, diff, states)``: the first step's dt, the relative L2 difference of the
    velocity after ``n_steps`` steps of ``advance`` and of cold steps (the same dt
    sequence: adaptive, the last one the shortened landing step), and the cold run's
    states (the initial one first)."""
    s0 = model.initial_state(params)
    dt = float(model.time_step(s0, params)[0])
    t_end = n_steps * dt * 0.999
    warm, info = jax.jit(model.advance)(s0, params, jnp.asarray(t_end))
    assert int(info["steps"]) == n_steps
    step = jax.jit(model.step)
    cold, states = s0, [s0]
    for _ in range(n_steps):
        h = min(float(model.time_step(cold, params)[0]), t_end - float(cold.t))
        cold = step(cold, params, jnp.asarray(h))
        states.append(cold)
    diff = float(jnp.linalg.norm(warm.v - cold.v) / jnp.linalg.norm(cold.v))
    return dt, diff, states
