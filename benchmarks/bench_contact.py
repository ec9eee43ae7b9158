"""Benchmark contact (refmap.contact) against the number of solids.

For N discs on a lattice in a closed box, prints the cost per step of the whole step with
contact, of the same step without contact, and of the contact force alone, plus the
compile time.  The contact force does O(N) work per grid corner (the two nearest solids by
two ``argmin`` passes over the solid axis), so its cost should grow linearly in N; the
whole step is O(N) too (every solid has its own reference map, level set and
extrapolation band).  Run it on one core for numbers comparable with docs/benchmarks.md:
XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1".

Usage: python benchmarks/bench_contact.py [--n 256] [--counts 1,2,4,8,32] [--steps 5]
       [--reps 2] [--no-compare] [--smooth-sweeps 80] [--wall]
"""

from __future__ import annotations

import argparse

import numpy as np

import refmap  # noqa: F401
from refmap.contact import benchmark
from refmap.state import Numerics


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--counts", default="1,2,4,8,32")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--no-compare", action="store_true", help="skip the step without contact")
    ap.add_argument(
        "--smooth-sweeps",
        type=int,
        default=None,
        help="smooth every map exactly this many sweeps (80: the worst case of the adaptive rule)",
    )
    ap.add_argument("--wall", action="store_true", help="wall time instead of CPU time")
    a = ap.parse_args()
    counts = tuple(int(c) for c in a.counts.split(","))
    numerics = Numerics(fixed_smooth_sweeps=a.smooth_sweeps) if a.smooth_sweeps else None
    rows = benchmark(
        counts,
        n=a.n,
        steps=a.steps,
        reps=a.reps,
        compare=not a.no_compare,
        cpu_time=not a.wall,
        numerics=numerics,
    )
    base = rows[0]
    print("\nratio to N = 1 (linear growth means ratio ~ N):")
    for r in rows:
        print(
            f"N = {r['n_solids']:>3}: step x{r['step_ms'] / base['step_ms']:.2f}, "
            f"contact force x{r['contact_ms'] / base['contact_ms']:.2f}"
        )
    if len(rows) >= 3:
        # linear model step = a + b N (a: the grid-sized fluid work, b: the work per solid);
        # growth no faster than linear means the marginal cost per added solid stays put
        N = np.array([r["n_solids"] for r in rows], dtype=float)
        t = np.array([r["step_ms"] for r in rows])
        b, a = np.polyfit(N, t, 1)
        print(f"\nleast-squares fit: step = {a:.1f} ms + {b:.1f} ms x N")
        print("marginal cost per added solid, (step(N) - step(N_prev)) / (N - N_prev):")
        for r0, r1 in zip(rows, rows[1:], strict=False):
            m = (r1["step_ms"] - r0["step_ms"]) / (r1["n_solids"] - r0["n_solids"])
            print(f"  N {r0['n_solids']:>3} -> {r1['n_solids']:>3}: {m:8.1f} ms per solid")
        worst = np.max(np.abs(t - (a + b * N)) / t)
        print(f"largest relative deviation from the linear fit: {100 * worst:.1f} %")


if __name__ == "__main__":
    main()
