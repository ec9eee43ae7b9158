"""Run the step with the grid fields split over several devices (SPMD, one mesh axis).

The prognostic fields are split along the grid's x axis (the ``nx`` axis: axis 1 of ``v``,
0 of ``rho_f``, 2 of ``xi``, 1 of ``phi``) over a one-dimensional device mesh; the clock,
the step count and the parameters are replicated.  :func:`sharded_advance` compiles
:meth:`refmap.model.Model.advance` with these input and output shardings, and XLA's SPMD
partitioner splits every operation of the step and inserts the exchanges it needs itself:
neighbour halos for the stencils (collective permutes), and all-reduces for the global
maxima (time step, smoothing stop rule, speed check) and sums (anchor fits, contact).  No
message passing is written by hand, so the sharded step is the same program as the
single-device one; only the order of the terms of a few sums differs, which moves results
by round-off (tests/test_sharding.py: <= 1e-12 of the field scale after tens of steps).

Usage::

    from refmap.sharding import shard_state, sharded_advance
    state = shard_state(model.initial_state(params), 4)
    advance = sharded_advance(model, 4)
    state, info = advance(state, params, t_end)

or ``Simulation(case, out, devices=4)`` / ``refmap run rotor --devices 4``.  On a CPU the
devices are virtual: ``XLA_FLAGS=--xla_force_host_platform_device_count=4`` must be set
before JAX is imported (docs/parallel.md).
"""

from __future__ import annotations

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from refmap.state import State

#: name of the one mesh axis (the grid's x axis is split along it)
AXIS = "x"


def request_cpu_devices(n_devices: int) -> bool:
    """Ask JAX for ``n_devices`` (virtual) CPU devices; True if it took effect.

    Works only before JAX has run anything (it sets ``jax_num_cpu_devices``); afterwards, or
    when ``XLA_FLAGS`` already sets ``--xla_force_host_platform_device_count``, it does
    nothing and :func:`check_devices` reports a shortfall.  A GPU backend is not affected.
    """
    import os

    if "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", ""):
        return False
    try:
        jax.config.update("jax_num_cpu_devices", int(n_devices))
    except RuntimeError:  # backends already initialised
        return False
    return True


def check_devices(n_devices, nx: int | None = None) -> int:
    """``n_devices`` as an int, else ValueError naming the value: an integer >= 1, at most
    the number of devices JAX sees, dividing ``nx`` (when given).  Nothing is compiled."""
    if isinstance(n_devices, bool) or not isinstance(n_devices, (int, np.integer)) or n_devices < 1:
        raise ValueError(f"devices must be an integer >= 1, got {n_devices!r}")
    n_devices = int(n_devices)
    if nx is not None and nx % n_devices:
        near = [c for c in (n_devices * (nx // n_devices), n_devices * (nx // n_devices + 1)) if c > 0]
        raise ValueError(f"the grid's nx = {nx} is not divisible by devices = {n_devices} "
                         f"(the x axis is split evenly over the devices); use nx = "
                         f"{' or '.join(map(str, near))}, or another device count")
    have = jax.device_count()
    if n_devices > have:
        hint = ""
        if jax.default_backend() == "cpu":
            hint = (f"; on a CPU set XLA_FLAGS=--xla_force_host_platform_device_count={n_devices} "
                    "before JAX runs anything, or call refmap.sharding.request_cpu_devices first")
        raise ValueError(f"devices = {n_devices} but JAX sees only {have} "
                         f"{jax.default_backend()} device(s){hint}")
    return n_devices


def make_mesh(n_devices: int, nx: int | None = None) -> Mesh:
    """A one-axis mesh (axis name :data:`AXIS`) over the first ``n_devices`` devices."""
    n_devices = check_devices(n_devices, nx)
    return Mesh(np.asarray(jax.devices()[:n_devices]), (AXIS,))


def state_shardings(mesh: Mesh, pressure: bool = False, windows: bool = False) -> State:
    """A State of NamedShardings: fields split along the grid's x axis, scalars replicated.
    ``pressure``: the state carries the incompressible fluid's pressure (``State.p``);
    ``windows``: its solids are stored in windows (``State.origin``; ``Numerics.solid_storage
    = "window"``), which are small and replicated."""
    def ns(*spec):
        return NamedSharding(mesh, P(*spec))

    return State(t=ns(), step=ns(), v=ns(None, AXIS), rho_f=ns(AXIS),
                 xi=ns() if windows else ns(None, None, AXIS), phi=ns() if windows else ns(None, AXIS),
                 p=ns(AXIS) if pressure else None, origin=ns() if windows else None)


def replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, P())


def _mesh_for(devices_or_mesh, nx: int) -> Mesh:
    if isinstance(devices_or_mesh, Mesh):
        mesh = devices_or_mesh
        if mesh.axis_names != (AXIS,):
            raise ValueError(f"the mesh must have the one axis {AXIS!r}, got {mesh.axis_names}")
        check_devices(mesh.size, nx)
        return mesh
    return make_mesh(devices_or_mesh, nx)


def shard_state(state: State, devices) -> State:
    """``state`` placed on the devices: ``devices`` a count (the first ones JAX lists) or a
    mesh from :func:`make_mesh`.  The grid's nx (``state.rho_f.shape[0]``) must be divisible
    by the count (ValueError otherwise, before anything is placed)."""
    nx = int(np.shape(state.rho_f)[0])
    mesh = _mesh_for(devices, nx)
    return jax.device_put(state, state_shardings(mesh, state.p is not None, state.origin is not None))


def gather_state(state: State) -> State:
    """``state`` with every field on the first device (e.g. to compare with a one-device run)."""
    return jax.device_put(state, jax.devices()[0])


def sharded_advance(model, devices, max_steps: int = 10**9):
    """:meth:`Model.advance` compiled for states sharded by :func:`shard_state`:
    ``advance(state, params, t_target, speed_limit=inf) -> (state, info)``; the returned
    state stays sharded the same way, ``info`` is replicated."""
    import jax.numpy as jnp

    mesh = _mesh_for(devices, model.grid.nx)
    rep = replicated(mesh)

    def run(state, params, t_target, speed_limit):
        return model.advance(state, params, t_target, max_steps=max_steps, speed_limit=speed_limit)

    # a sharding given for a whole sub-tree (params, info) applies to all its leaves
    ss = state_shardings(mesh, model.projection is not None, model.state_window is not None)
    jitted = jax.jit(run, in_shardings=(ss, rep, rep, rep), out_shardings=(ss, rep))

    def advance(state, params, t_target, speed_limit=jnp.inf):
        return jitted(state, params, jnp.asarray(t_target, dtype=jnp.float64),
                      jnp.asarray(speed_limit, dtype=jnp.float64))

    advance.mesh = mesh
    advance.jitted = jitted
    return advance


def sharded_run_steps(model, devices, n_steps: int, dt=None):
    """:meth:`Model.run_steps` compiled for sharded states: ``run(state, params) -> state``."""
    mesh = _mesh_for(devices, model.grid.nx)
    rep = replicated(mesh)
    ss = state_shardings(mesh, model.projection is not None, model.state_window is not None)
    return jax.jit(lambda s, p: model.run_steps(s, p, n_steps, dt=dt),
                   in_shardings=(ss, rep), out_shardings=ss)


__all__ = ["AXIS", "request_cpu_devices", "check_devices", "make_mesh", "state_shardings", "replicated", "shard_state",
           "gather_state", "sharded_advance", "sharded_run_steps"]
