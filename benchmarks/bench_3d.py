"""Throughput of the 3D step (issue 12), one process, on the built-in ``sphere_relax``.

For each cube size n (default 32, 64, 128) the scenario's model is built, one step is
compiled and run (warm-up), then ``--steps`` steps of a fixed dt run inside one jitted
``lax.fori_loop``; the figure is node updates per second (n^3 steps / wall time), the
same measure as the 2D figures of docs/benchmarks.md.  A fluid-only box of the same size
is timed too (the solid's share of the step is the difference).  With ``--xla-memory`` the
compiled step's XLA memory analysis (temporaries per node) is printed.

Usage: python benchmarks/bench_3d.py [--sizes 32,64,128] [--steps 5]
Pin one core with ``taskset -c 0`` (and XLA_FLAGS=--xla_cpu_multi_thread_eigen=false) for
one-core figures; docs/benchmarks.md ("3D step") has them.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp

import refmap  # noqa: F401  (float64)
from refmap.boundary import Boundary
from refmap.model import Model
from refmap.scenarios import get_case


def timed(model, params, steps):
    state = model.initial_state(params)
    dt = model.time_step(state, params)[0]

    @jax.jit
    def run(s):
        return jax.lax.fori_loop(0, steps, lambda i, s: model.step(s, params, dt), s)

    @jax.jit
    def one(s):
        return model.step(s, params, dt)

    t0 = time.perf_counter()
    jax.block_until_ready(one(state))
    jax.block_until_ready(run(state).v)  # compile the loop too
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = run(state)
    jax.block_until_ready(out.v)
    wall = time.perf_counter() - t0
    ok = bool(jnp.all(jnp.isfinite(out.v)))
    return wall / steps, compile_s, ok, one


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="32,64,128")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--xla-memory", action="store_true")
    args = ap.parse_args()
    dev = jax.devices()[0]
    print(f"device: {dev.platform} ({dev.device_kind}); steps timed per size: {args.steps}")
    print(f"{'case':<14} {'n':>4} {'nodes':>9} {'ms/step':>9} {'Mnode/s':>8} {'compile s':>9}")
    for n in (int(s) for s in args.sizes.split(",")):
        case = get_case("sphere_relax", n)
        model, params = case.build()
        fluid = Model(case.grid, (), Boundary(back="wall", front="wall"), case.numerics)
        for label, (m, p) in (("sphere_relax", (model, params)), ("fluid only", (fluid, fluid.default_params()))):
            per, comp, ok, one = timed(m, p, args.steps)
            nodes = n**3
            flag = "" if ok else "  (not finite!)"
            print(f"{label:<14} {n:>4} {nodes:>9} {1e3 * per:>9.1f} {nodes / per / 1e6:>8.2f} {comp:>9.1f}{flag}")
            if args.xla_memory:
                mem = one.lower(m.initial_state(p)).compile().memory_analysis()
                if mem is not None:
                    print(f"    XLA temporaries {mem.temp_size_in_bytes / 2**20:.0f} MiB = "
                          f"{mem.temp_size_in_bytes / 8 / nodes:.0f} float64 per node")


if __name__ == "__main__":
    main()
