"""Which storage layout for many bodies (issue 14, item 1): measured with today's code.

Issue 14 asks to choose, by measurement, between (a) a fixed-size window per body that
follows it and (b) K shared map slots per node, bodies whose bands can meet in different
slots.  Neither exists yet; both costs can be bounded from below with the code as it is,
because each layout's work is a kind of run refmap already does:

* ``solids``: today's layout, the ``suspension`` scenario, one solid (a full-grid map and
  level set) per disc;
* ``slots``: layout (b) with K = 4, the same discs packed into four solids, each the union
  (``Disc | Disc | ...``) of the discs of one colour of a 2 x 2 colouring of the lattice, so
  that discs of one slot are two lattice spacings apart and their bands never meet in this
  short run.  This is what the slot layout's band work, stress and contact cost; the
  slots' bookkeeping (which body a node belongs to, moving a body between slots) is not
  counted, and the union is evaluated as a min over the slot's discs, which a lookup
  would replace;
* ``stored``: layout (a) as far as it is built: ``Numerics(solid_storage = "window")``,
  every solid's band work, stress, weights and density on its window, the maps and level
  sets still stored on the whole grid (docs/design_windows.md, landings 2 and 3a);
* ``window``: layout (a), one disc alone in a closed box of W x W cells at the same grid
  spacing (the window that would hold it), with and without the disc: the difference is
  one body's work in its window; the fluid on the whole grid (``fluid``, the scenario
  without solids) is paid once.  The scatter of the windows into the grid and the contact
  between windows are not counted.

Each figure comes from its own single-threaded process (CPU ms per step, best of
``--reps`` calls of ``--steps`` steps after a compile call; the smoothing at its full 80
sweeps, its cost once the bodies have deformed) and its peak resident memory.  The
one-disc step on the whole grid is printed too: the issue's "marginal cost of an added
small disc" is measured against it.

    XLA_FLAGS=--xla_cpu_multi_thread_eigen=false taskset -c 0 \\
        python benchmarks/bench_many_body_layouts.py                # 100 discs at 300^2
    ... --n 1024 --count 1000 --layouts slots window fluid          # the 1000-disc case

docs/benchmarks.md ("Many bodies: which layout") has the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

_MEASURE = r"""
import json, math, resource, sys, time
from dataclasses import replace
import jax
import refmap  # noqa: F401  (float64)
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.model import Solid
from refmap.scenarios_fssi import _law, suspension, suspension_discs

layout, n, count, window, steps, reps = sys.argv[1:7]
n, count, window, steps, reps = int(n), int(count), int(window), int(steps), int(reps)
case = suspension(n, count=count)
case = case.replace(numerics=replace(case.numerics, solid_storage="grid",  # the layouts compared
                                     fixed_smooth_sweeps=case.numerics.smooth_max_sweeps))
discs = suspension_discs(count)
h = case.grid.dx
if layout == "one":
    c, r, rho = discs[0]
    case = case.replace(solids=(Solid(shape=Disc(center=(0.0, 0.0), radius=r), law=_law(rho),
                                      name="disc"),))
elif layout == "fluid":
    case = case.replace(solids=())
elif layout == "slots":
    # the lattice of suspension_discs: side x side sites, spacing 0.9 L / side, from -0.9 box
    side = math.ceil(math.sqrt(count))
    spacing = 0.9 * (case.grid.bx - case.grid.ax) / side
    x0 = 0.9 * case.grid.ax
    groups = {}
    for c, r, rho in discs:
        i = round((c[0] - x0) / spacing - 0.5)
        j = round((c[1] - x0) / spacing - 0.5)
        groups.setdefault((i % 2, j % 2), []).append(Disc(center=c, radius=r))
    solids = []
    for key, members in sorted(groups.items()):
        shape = members[0]
        for d in members[1:]:
            shape = shape | d
        solids.append(Solid(shape=shape, law=_law(1.0), name=f"slot {key}"))
    case = case.replace(solids=tuple(solids))
elif layout == "stored":
    case = case.replace(numerics=replace(case.numerics, solid_storage="window"))
elif layout in ("window", "window_fluid"):
    half = window * h / 2
    c, r, rho = discs[0]
    solids = (Solid(shape=Disc(center=(0.0, 0.0), radius=r), law=_law(rho), name="disc"),)
    case = case.replace(grid=Grid(window, window, -half, half, -half, half),
                        solids=solids if layout == "window" else ())
model, params = case.build()
state = jax.jit(model.initial_state)(params)
# a fixed dt, the same in every layout: the solids' wave limit of the scenario
dt = 0.5 * h / math.sqrt(30.0)
run = jax.jit(lambda s: model.run_steps(s, params, steps, dt=dt))
t0 = time.perf_counter()
state = jax.block_until_ready(run(state))
compile_s = time.perf_counter() - t0
best = float("inf")
for _ in range(reps):
    c0 = time.process_time()
    state = jax.block_until_ready(run(state))
    best = min(best, time.process_time() - c0)
ok = bool(jax.numpy.all(jax.numpy.isfinite(state.v)))
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print("@@" + json.dumps(dict(step_ms=1e3 * best / steps, compile_s=compile_s, rss_mb=rss,
                             solids=len(case.solids), finite=ok,
                             band_window=getattr(model, "solid_band_window", None))))
"""

SINGLE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


def measure(layout, n, count, window, steps, reps):
    env = dict(os.environ, XLA_FLAGS=SINGLE_THREAD)
    args = [
        sys.executable,
        "-c",
        _MEASURE,
        layout,
        str(n),
        str(count),
        str(window),
        str(steps),
        str(reps),
    ]
    out = subprocess.run(args, env=env, capture_output=True, text=True, check=False)
    for line in out.stdout.splitlines():
        if line.startswith("@@"):
            return json.loads(line[2:])
    raise RuntimeError(f"{layout}: no result\n{out.stderr[-2000:]}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=300, help="grid (n x n, the suspension's box)")
    ap.add_argument("--count", type=int, default=100, help="discs")
    ap.add_argument("--window", type=int, default=48, help="cells a side of a body's window")
    ap.add_argument("--steps", type=int, default=2)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument(
        "--layouts",
        nargs="+",
        default=["fluid", "one", "solids", "stored", "slots", "window", "window_fluid"],
        choices=["fluid", "one", "solids", "stored", "slots", "window", "window_fluid"],
    )
    a = ap.parse_args(argv)
    res = {}
    for layout in a.layouts:
        r = measure(layout, a.n, a.count, a.window, a.steps, a.reps)
        res[layout] = r
        print(
            f"{layout:13s} solids {r['solids']:5d}  step {r['step_ms']:9.2f} ms  compile "
            f"{r['compile_s']:6.1f} s  peak RSS {r['rss_mb']:7.0f} MB  finite {r['finite']}",
            flush=True,
        )
    print(f"\n{a.count} discs at {a.n}^2, CPU ms per step (one thread):")
    fluid = res.get("fluid", {}).get("step_ms")
    one = res.get("one", {}).get("step_ms")
    if "solids" in res:
        print(f"  (today) one solid per disc      {res['solids']['step_ms']:9.1f}")
    if "stored" in res:
        r = res["stored"]
        print(f"  solid_storage = window (built)  {r['step_ms']:9.1f}  (band windows {r['band_window']})")
        if "solids" in res:
            print(f"    per step against today: {res['solids']['step_ms'] / r['step_ms']:.2f}x")
    if "slots" in res:
        print(f"  (b) 4 slots, no bookkeeping     {res['slots']['step_ms']:9.1f}")
    if {"window", "window_fluid"} <= res.keys() and fluid is not None:
        body = res["window"]["step_ms"] - res["window_fluid"]["step_ms"]
        est = fluid + a.count * body
        print(
            f"  (a) windows: fluid {fluid:.1f} + {a.count} x {body:.2f} per body = {est:9.1f}"
            " (no scatter, no contact)"
        )
        if one is not None:
            print(
                f"  one body's window work / one-disc step on the grid: {body / one:.3f}"
                f" (one-disc step {one:.1f} ms, fluid alone {fluid:.1f} ms)"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
