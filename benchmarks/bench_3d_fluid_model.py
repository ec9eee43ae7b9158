"""Cost of the 3D incompressible fluid against the compressible one, on ``sphere_cavity``.

For each cube size n (default 16, 32) the built-in ``sphere_cavity`` (a soft sphere in a
lid-driven cube, Re = 100, lid Mach number 0.1 in the compressible fluid) is built three
ways: as the scenario has it (compressible, with the bulk viscosity c h that damps its
sound), and with ``fluid_model = "incompressible"`` (bulk viscosity 0: nothing to damp)
and the pressure solve preconditioned by the 3D fast transform (``"fast"``) or by the
diagonal (``"jacobi"``).  Each is warmed up (20 steps from rest, so the flow and the
pressure are not trivial), then ``--steps`` steps of its own adaptive dt run in one jitted
``lax.fori_loop``.  Printed: dt and what limits it, wall time per step, and wall time per
unit of simulated time (per step / dt), each also relative to the compressible row of the
same n (one process: ratios, not absolute times, are the figure).

Usage: python benchmarks/bench_3d_fluid_model.py [--sizes 16,32] [--steps 10]
docs/validation_incompressible.md ("Three dimensions") has the figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax

import refmap  # noqa: F401  (float64)
import refmap.scenarios_3d  # noqa: F401  (registers the 3D scenarios)
from refmap.model import LIMIT_NAMES
from refmap.scenarios import get_case

VARIANTS = {
    "compressible": {},
    "incompressible, fast": {"fluid_model": "incompressible", "pressure_preconditioner": "fast"},
    "incompressible, jacobi": {"fluid_model": "incompressible", "pressure_preconditioner": "jacobi"},
}


def measure(n, changes, steps):
    case = get_case("sphere_cavity", n)
    case = case.replace(numerics=dataclasses.replace(case.numerics, **changes))
    if changes.get("fluid_model") == "incompressible":
        # no sound to damp: the scenario's bulk viscosity c h does nothing to a divergence-
        # free flow but would still set the explicit viscous step limit
        case = case.replace(fluid=dataclasses.replace(case.fluid, bulk_viscosity=0.0))
    model, params = case.build()
    state = jax.jit(lambda s: model.run_steps(s, params, 20))(model.initial_state(params))
    dt, limit = model.time_step(state, params)

    @jax.jit
    def run(s):
        return jax.lax.fori_loop(0, steps, lambda i, s: model.step(s, params, dt), s)

    jax.block_until_ready(run(state))  # compile
    t0 = time.perf_counter()
    out = jax.block_until_ready(run(state))
    wall = (time.perf_counter() - t0) / steps
    assert bool(jax.numpy.all(jax.numpy.isfinite(out.v)))
    return float(dt), LIMIT_NAMES[int(limit)], wall


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="16,32")
    ap.add_argument("--steps", type=int, default=10)
    args = ap.parse_args(argv)
    print(f"{'n':>4} {'fluid':<24} {'dt':>10} {'limit':<14} {'s/step':>9} {'rel':>6} "
          f"{'s per unit t':>12} {'rel':>6}")
    for n in (int(x) for x in args.sizes.split(",")):
        base = None
        for name, changes in VARIANTS.items():
            dt, limit, wall = measure(n, changes, args.steps)
            per_t = wall / dt
            if base is None:
                base = (wall, per_t)
            print(f"{n:>4} {name:<24} {dt:>10.3e} {limit:<14} {wall:>9.4f} {wall / base[0]:>6.2f} "
                  f"{per_t:>12.2f} {per_t / base[1]:>6.2f}", flush=True)


if __name__ == "__main__":
    main()
