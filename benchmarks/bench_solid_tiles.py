"""Solids' stress, weights and density on tiles against the full grid (issue 14).

    python benchmarks/bench_solid_tiles.py --n 256 --counts 1,4,16,64

For the ``suspension`` scenario (N soft discs in a closed box) this times, in one process
and single-threaded, the part of :meth:`refmap.model.Model.derived` that the step reads
(the mixed stress, density and fluid fractions) and the whole step, with the solids'
fields on the full grid (``band_sweeps = "grid"``; the band sweeps then run on the full
grid too) and on tiles (``"band"``), and the step with only the sweeps on tiles (the
solids' fields on the full grid: the revision before :mod:`refmap.solid_tiles`).  Best
process CPU time of ``--reps`` calls of ``--steps`` steps after the compile, the smoothing
doing its full 80 sweeps (``fixed_smooth_sweeps``) as it does once bodies deform.
"""

from __future__ import annotations

import os

os.environ.setdefault(
    "XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
)

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import time  # noqa: E402

import jax  # noqa: E402

import refmap  # noqa: E402, F401  (float64)
from refmap.scenarios_fssi import suspension  # noqa: E402

MIXED = ("s", "rho", "wf_c", "wf_n")


def _cpu_best(f, reps):
    best = float("inf")
    for _ in range(reps):
        t0 = time.process_time()
        jax.block_until_ready(f())
        best = min(best, time.process_time() - t0)
    return best


def measure(n: int, count: int, mode: str, steps: int, reps: int, sweeps: int):
    case = suspension(n, count)
    num = dataclasses.replace(case.numerics, band_sweeps="grid" if mode == "grid" else "band",
                              fixed_smooth_sweeps=sweeps, solid_storage="grid")
    model, params = case.replace(numerics=num).build()
    if mode == "sweeps-only":
        model.solid_tiles = None
    s = model.initial_state(params)
    s = jax.jit(lambda s: model.run_steps(s, params, 3))(s)
    derived = jax.jit(lambda s: {k: model.derived(s, params)[k] for k in MIXED})
    run = jax.jit(lambda s: model.run_steps(s, params, steps, dt=1e-4))
    t0 = time.perf_counter()
    jax.block_until_ready(run(s))
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(derived(s))
    t_d = _cpu_best(lambda: derived(s), reps)
    t_s = _cpu_best(lambda: run(s), reps) / steps
    return dict(derived_ms=1e3 * t_d, step_ms=1e3 * t_s, compile_s=compile_s,
                tiles=None if model.solid_tiles is None else model.solid_tiles[1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--counts", default="1,4,16")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--sweeps", type=int, default=80, help="smoothing sweeps per step")
    a = ap.parse_args(argv)
    print(f"suspension at {a.n}^2, single-threaded, CPU ms (best of {a.reps})")
    print(f"{'N':>5} {'mode':>12} {'derived':>9} {'step':>9} {'compile s':>10}  capacities")
    rows = {}
    for count in [int(c) for c in a.counts.split(",")]:
        for mode in ("grid", "sweeps-only", "band"):
            r = measure(a.n, count, mode, a.steps, a.reps, a.sweeps)
            rows[count, mode] = r
            print(f"{count:>5} {mode:>12} {r['derived_ms']:>9.2f} {r['step_ms']:>9.2f} "
                  f"{r['compile_s']:>10.1f}  {r['tiles']}", flush=True)
        b, o = rows[count, "band"], rows[count, "sweeps-only"]
        print(f"{count:>5} {'band/sweeps':>12} {b['derived_ms'] / o['derived_ms']:>9.3f} "
              f"{b['step_ms'] / o['step_ms']:>9.3f}")


if __name__ == "__main__":
    main()
