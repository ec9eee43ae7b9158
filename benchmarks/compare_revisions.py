"""Step cost of two source trees side by side, measured in one interleaved run.

Each tree is a git revision (checked out into a temporary worktree) or a folder holding
``src/refmap`` (``.`` is the working tree, uncommitted changes included).  Every
measurement runs in a fresh, single-threaded process that imports refmap from one tree
(``PYTHONPATH=TREE/src``), so the trees share no code or caches; the processes of the two
trees alternate (old, new, new, old, ...) so that a change in the machine's load hits both.

Cases (each at every ``--sizes`` n):

* ``rotor``: the rotor scenario (one solid with a pivot anchor, open edges), as in
  benchmarks/bench_step.py, with the explicit viscous step in every revision;
* ``discsN``: N discs on a lattice in a closed box with contact and gravity, as in
  benchmarks/bench_contact.py (``refmap.contact._lattice_of_discs``), for N in ``--counts``.

Each is moved 5 steps, then ``--steps`` steps of fixed dt are timed ``--reps`` times (best
kept).  The map smoothing runs its full ``smooth_max_sweeps`` (80) sweeps every step
(``Numerics.fixed_smooth_sweeps``), its real cost once a body has deformed (the adaptive
rule stops after a few sweeps on the nearly affine maps of the first steps);
``--adaptive`` keeps the adaptive rule, and ``--warm-up T`` first advances the case to
t = T so that it runs on deformed bodies.  Per tree and case it reports:

* ``step_ms``: CPU time of the process per step (one thread, so CPU time is the time the
  step needs; on a shared machine it varies far less than wall time), and ``wall_ms``;
* ``Mcups``: grid cells x steps per CPU second, in millions;
* ``compile_s``: time of the first call minus a steady call (tracing + XLA compilation);
* ``B/cell``: XLA's cost analysis of one compiled step, bytes accessed per grid cell.  XLA
  counts the body of each loop once (not times its trip count), so this undercounts the
  extrapolation and smoothing sweeps; it compares revisions, it is not the true traffic;
* ``flop/cell``: the same analysis's floating-point operations per cell (same caveat);
* ``peak GB``: the process's peak resident memory (build, compile and steps).

A case that the old tree cannot hold (``--cases 1000@1024``: 1000 discs on the whole grid
need about 1 TB) is skipped for that tree when refmap's own estimate for whole-grid
storage (:func:`refmap.resources.estimate_memory`'s fit) exceeds ``--old-max-gb``; its
row shows the new tree alone.

It also measures this machine's memory bandwidth (a numpy copy of 256 MB, read + write,
one thread), to set ``B/cell x Mcups`` against.

Usage::

    python benchmarks/compare_revisions.py 94dddff HEAD                 # 128^2 and 256^2
    python benchmarks/compare_revisions.py 94dddff . --sizes 128 --counts 1,10
    python benchmarks/compare_revisions.py main HEAD --large --counts 1,10,100
    python benchmarks/compare_revisions.py 9ff03f0 . --no-rotor --sizes 300 --counts 1,10,100 \
        --new-storage window      # the per-body windows against the old default
    python benchmarks/compare_revisions.py 9ff03f0 . --no-rotor --counts '' --cases 1000@1024 \
        --new-storage window --steps 2 --reps 1 --rounds 1   # new tree only (old cannot fit)

Prints one table row per case and figure: old | new | new/old.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# one thread for XLA: the figures are per-core costs, and two processes never compete for
# the same thread pool
SINGLE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"

# measured in the tree's own process; CASE, N, SIZE, STEPS, REPS, FIXED, WARM, STORAGE are
# prepended
_MEASURE = r"""
import json, resource, time
from dataclasses import replace
import jax
import refmap
from refmap.state import Numerics

def build():
    if CASE == "rotor":
        from refmap.scenarios import get_case
        case = get_case("rotor", SIZE)
        # the explicit step, so that revisions before and after the scenario's switch to
        # implicit viscosity (2026-12-05) time the same work
        case = case.replace(numerics=replace(case.numerics, viscosity="explicit"))
        if FIXED:
            case = case.replace(numerics=replace(case.numerics,
                                                 fixed_smooth_sweeps=case.numerics.smooth_max_sweeps))
        model, params = case.build()
        return model, params
    from refmap.boundary import Boundary
    from refmap.contact import Contact, _lattice_of_discs
    from refmap.grid import Grid
    from refmap.materials import NeoHookean
    from refmap.model import Model
    numerics = Numerics()
    if FIXED:
        numerics = replace(numerics, fixed_smooth_sweeps=numerics.smooth_max_sweeps)
    if STORAGE != "grid":  # only passed to a tree that has it (--new-storage)
        numerics = replace(numerics, solid_storage=STORAGE)
    solids = _lattice_of_discs(N, NeoHookean(G=10.0, kappa=10.0))
    model = Model(Grid(SIZE, SIZE), solids, Boundary(), numerics=numerics, body_forces=(Contact(),))
    return model, model.default_params(gravity=(0.0, -0.2))

model, params = build()
state = jax.jit(model.initial_state)(params)
state = jax.jit(lambda s: model.run_steps(s, params, 5))(state)  # a few steps under way
if WARM > 0:  # deformed bodies: the adaptive smoothing no longer stops at once
    state = jax.jit(lambda s: model.advance(s, params, WARM)[0])(state)
dt = model.time_step(state, params)[0]
run = jax.jit(lambda s: model.run_steps(s, params, STEPS, dt=dt))

t0, c0 = time.perf_counter(), time.process_time()
jax.block_until_ready(run(state))
first_wall, first_cpu = time.perf_counter() - t0, time.process_time() - c0
best_cpu = best_wall = float("inf")
for _ in range(REPS):
    t0, c0 = time.perf_counter(), time.process_time()
    jax.block_until_ready(run(state))
    best_wall = min(best_wall, time.perf_counter() - t0)
    best_cpu = min(best_cpu, time.process_time() - c0)

cost = jax.jit(lambda s: model.step(s, params, dt)).lower(state).compile().cost_analysis()
if isinstance(cost, (list, tuple)):
    cost = cost[0] if cost else {}
cost = cost or {}
cells = SIZE * SIZE
out = dict(step_ms=best_cpu / STEPS * 1e3, wall_ms=best_wall / STEPS * 1e3,
           Mcups=cells * STEPS / best_cpu / 1e6, compile_s=first_wall - best_wall,
           bytes_per_cell=float(cost.get("bytes accessed", float("nan"))) / cells,
           flops_per_cell=float(cost.get("flops", float("nan"))) / cells,
           peak_GB=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6)
print("@@" + json.dumps(out))
"""

FIGURES = (("step_ms", "step [ms CPU]", "{:.2f}"), ("wall_ms", "step [ms wall]", "{:.2f}"),
           ("Mcups", "Mcell-upd/s", "{:.3f}"), ("compile_s", "compile [s]", "{:.2f}"),
           ("bytes_per_cell", "B/cell (XLA)", "{:.0f}"), ("flops_per_cell", "flop/cell (XLA)", "{:.0f}"),
           ("peak_GB", "peak GB", "{:.2f}"))


def grid_storage_gb(n_solids: int, size: int) -> float:
    """refmap's estimate (:mod:`refmap.resources`: 600 MiB + 100 B per node + 1100 B per node
    and solid) of a run with every solid on the whole grid, in GB."""
    return (600 * 2**20 + size * size * (100 + 1100 * n_solids)) / 1e9


def _tree(rev: str, tmp: Path) -> tuple[Path, str]:
    """(folder holding src/refmap, label) for a revision or a folder."""
    p = Path(rev)
    if (p / "src" / "refmap").is_dir():
        return p.resolve(), f"{rev} (folder)"
    sha = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", rev], check=True,
                         capture_output=True, text=True).stdout.strip()
    dest = tmp / rev.replace("/", "_")
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(dest), rev],
                   check=True, capture_output=True)
    return dest, f"{rev} ({sha})"


def _command() -> list[str]:
    """Pin the measuring process to one CPU when taskset exists (less migration noise)."""
    if shutil.which("taskset"):
        cpu = os.environ.get("BENCH_CPU", "0")
        return ["taskset", "-c", cpu, sys.executable]
    return [sys.executable]


def measure(tree: Path, case: str, n_solids: int, size: int, steps: int, reps: int,
            fixed: bool, warm: float = 0.0, storage: str = "grid") -> dict:
    head = (f"CASE = {case!r}\nN = {n_solids}\nSIZE = {size}\nSTEPS = {steps}\nREPS = {reps}\n"
            f"FIXED = {fixed!r}\nWARM = {warm!r}\nSTORAGE = {storage!r}\n")
    env = dict(os.environ, PYTHONPATH=str(tree / "src"), XLA_FLAGS=SINGLE_THREAD,
               OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    r = subprocess.run(_command() + ["-c", head + _MEASURE], cwd=tree, env=env,
                       capture_output=True, text=True)
    for line in r.stdout.splitlines():
        if line.startswith("@@"):
            return json.loads(line[2:])
    raise RuntimeError(f"{case} n={size} N={n_solids} failed in {tree}:\n{r.stderr[-3000:]}")


def memory_bandwidth(mbytes: int = 256, reps: int = 5) -> float:
    """Copy bandwidth of one thread in GB/s: (read + write) bytes per second of the best of
    ``reps`` copies of an ``mbytes`` array (far larger than the caches)."""
    a = np.ones(mbytes * 2**20 // 8)
    b = np.empty_like(a)
    np.copyto(b, a)  # touch the pages
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        np.copyto(b, a)
        best = min(best, time.perf_counter() - t0)
    return 2 * a.nbytes / best / 1e9


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", help="git revision or folder (the baseline)")
    ap.add_argument("new", help="git revision or folder (the change); '.' is the working tree")
    ap.add_argument("--sizes", default="128,256", help="grid sizes n (n x n), comma list")
    ap.add_argument("--large", action="store_true", help="add 512 and 1024 to --sizes")
    ap.add_argument("--counts", default="1,10", help="numbers of discs N, comma list ('' for none)")
    ap.add_argument("--no-rotor", action="store_true", help="skip the rotor case")
    ap.add_argument("--cases", default="", help="more disc cases N@n (N discs at n x n), comma list")
    ap.add_argument("--old-max-gb", type=float, default=16.0,
                    help="skip the old tree where whole-grid storage needs more than this (GB)")
    ap.add_argument("--steps", type=int, default=10, help="steps per timed call")
    ap.add_argument("--reps", type=int, default=3, help="timed calls per process (best kept)")
    ap.add_argument("--rounds", type=int, default=2,
                    help="processes per tree and case, alternating old/new (best kept)")
    ap.add_argument("--adaptive", action="store_true",
                    help="adaptive smoothing instead of the full fixed sweeps")
    ap.add_argument("--warm-up", type=float, default=0.0,
                    help="simulated time to advance (adaptive dt) before timing, so that the "
                         "bodies have deformed (with --adaptive: the smoothing's real cost)")
    ap.add_argument("--new-storage", choices=("grid", "window"), default="grid",
                    help="Numerics.solid_storage of the new tree's disc cases (the old tree keeps "
                         "its default): 'window' compares the per-body windows with the old code")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    a = ap.parse_args(argv)
    sizes = [int(s) for s in a.sizes.split(",") if s.strip()]
    if a.large:
        sizes += [s for s in (512, 1024) if s not in sizes]
    counts = [int(s) for s in a.counts.split(",") if s.strip()]
    bad = [s for s in sizes if s < 16] + [c for c in counts if c < 1]
    if bad or a.steps < 1 or a.reps < 1 or a.rounds < 1:
        ap.error(f"sizes must be >= 16, counts, steps, reps and rounds >= 1 (got {bad or 'steps/reps/rounds'})")
    cases = ([] if a.no_rotor else [("rotor", 1)]) + [("discs", c) for c in counts]
    extra = [tuple(int(x) for x in c.split("@")) for c in a.cases.split(",") if c.strip()]

    bw = memory_bandwidth()
    print(f"machine: {os.cpu_count()} CPUs; numpy copy bandwidth (1 thread) {bw:.1f} GB/s; "
          f"XLA_FLAGS={SINGLE_THREAD!r}; taskset: {'yes' if shutil.which('taskset') else 'no'}",
          flush=True)
    res: dict = {}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        trees = [_tree(a.old, tmp), _tree(a.new, tmp)]
        try:
            todo = [(size, case, N) for size in sizes for case, N in cases]
            todo += [(size, "discs", N) for N, size in extra]
            for size, case, N in todo:
                key = f"{case}{'' if case == 'rotor' else N} {size}^2"
                runs = {"old": [], "new": []}
                for r in range(a.rounds):
                    order = ("old", "new") if r % 2 == 0 else ("new", "old")
                    for label in order:
                        if label == "old" and grid_storage_gb(N, size) > a.old_max_gb:
                            continue  # cannot hold it: the new tree alone
                        tree = trees[0 if label == "old" else 1][0]
                        storage = a.new_storage if label == "new" and case != "rotor" else "grid"
                        runs[label].append(measure(tree, case, N, size, a.steps, a.reps,
                                                   not a.adaptive, a.warm_up, storage))
                        print(f"  {key}: {label} round {r + 1} "
                              f"{runs[label][-1]['step_ms']:.2f} ms/step", file=sys.stderr,
                              flush=True)
                # best of the rounds: the least disturbed process
                res[key] = {label: {k: min(x[k] for x in rows) if k != "Mcups"
                                    else max(x[k] for x in rows) for k in rows[0]}
                            for label, rows in runs.items() if rows}
        finally:
            for t, _ in trees:
                if str(t).startswith(str(tmp)):
                    subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(t)],
                                   capture_output=True)
    print(f"old = {trees[0][1]}, new = {trees[1][1]}; {a.steps} steps x best of {a.reps} calls "
          f"x best of {a.rounds} processes; smoothing: "
          f"{'adaptive' if a.adaptive else 'fixed 80 sweeps'}"
          + (f", timed after t = {a.warm_up:g}" if a.warm_up > 0 else "")
          + (f"; new tree's discs with solid_storage = {a.new_storage!r}" if a.new_storage != "grid" else ""))
    print(f"{'case':16s} {'figure':16s} {'old':>10s} {'new':>10s} {'new/old':>8s}")
    for key, r in res.items():
        if "old" not in r:
            N, size = (int(x) for x in key.removeprefix("discs").removesuffix("^2").split())
            r["old"] = {name: float("nan") for name, _, _ in FIGURES}
            print(f"{key:16s} old tree not run: whole-grid storage needs about "
                  f"{grid_storage_gb(N, size):.0f} GB (> --old-max-gb {a.old_max_gb:g})")
        for name, title, fmt in FIGURES:
            o, n = r["old"][name], r["new"][name]
            ratio = n / o if o else float("nan")
            print(f"{key:16s} {title:16s} {fmt.format(o):>10s} {fmt.format(n):>10s} {ratio:8.3f}")
        gbs = [r[x]["bytes_per_cell"] * r[x]["Mcups"] * 1e6 / 1e9 for x in ("old", "new")]
        print(f"{key:16s} {'XLA B/s [GB/s]':16s} {gbs[0]:10.2f} {gbs[1]:10.2f}   "
              f"({gbs[0] / bw:.2f}, {gbs[1] / bw:.2f} x copy bandwidth)")
    if a.json:
        a.json.write_text(json.dumps({"bandwidth_GBs": bw, "old": trees[0][1], "new": trees[1][1],
                                      "results": res}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
