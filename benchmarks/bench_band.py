"""The band operator alone (extrapolation.extend) on the rotor, two source trees compared.

For each tree (a folder holding ``src/refmap``; ``git archive REV src | tar -x -C DIR``
makes one of a revision) a fresh single-threaded process builds the rotor at ``--size``, moves it
5 steps, and times ``extrapolation.extend`` on the solid's map with the model's band
capacity (tiles) and with ``capacity=None`` (full grid): extrapolation only, and
extrapolation + ``--sweeps`` fixed smoothing sweeps.  Processes of the two trees alternate
(old, new, new, old, ...), best of all calls kept.  Prints ms per call and new/old.

Usage: python benchmarks/bench_band.py /tmp/old . --size 512 --rounds 2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

# one thread for XLA, as in benchmarks/compare_revisions.py
SINGLE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"

_MEASURE = r"""
import json, time
import jax, jax.numpy as jnp
import refmap
from refmap import extrapolation
from refmap.scenarios import get_case

model, params = get_case("rotor", SIZE).build()
s = jax.jit(model.initial_state)(params)
s = jax.jit(lambda s: model.run_steps(s, params, 5))(s)
f = s.xi - jnp.asarray(model.grid.mesh("node"))
n = model.numerics
kw = dict(dx=model.grid.dx, dy=model.grid.dy, band=n.band * model.h,
          periodic=model.bc.periodic, tile=model.band_tile)
tiles = model.band_capacity  # as Model._extend_all passes it: with its tighter first level
if getattr(model, "_band_tight", None) is not None:
    tiles = (model._band_tight, tiles)
out = dict(capacity=tiles)
for name, smooth in (("ext", None), ("ext+smooth", dict(fixed_sweeps=SWEEPS))):
    for lay, cap in (("tiles", tiles), ("grid", None)):
        fn = jax.jit(lambda f, p, cap=cap, smooth=smooth: extrapolation.extend(
            f, p, capacity=cap, smooth=smooth, **kw))
        jax.block_until_ready(fn(f, s.phi))
        best = float("inf")
        for _ in range(REPS):
            c0 = time.process_time()
            jax.block_until_ready(fn(f, s.phi))
            best = min(best, time.process_time() - c0)
        out[name + ":" + lay] = best * 1e3
print("@@" + json.dumps(out))
"""


def measure(tree, size, sweeps, reps):
    env = dict(
        os.environ,
        PYTHONPATH=str(tree / "src"),
        XLA_FLAGS=SINGLE_THREAD,
        OMP_NUM_THREADS="1",
        JAX_PLATFORMS="cpu",
    )
    code = f"SIZE={size}\nSWEEPS={sweeps}\nREPS={reps}\n" + _MEASURE
    cmd = ["taskset", "-c", os.environ.get("BENCH_CPU", "1"), sys.executable, "-c", code]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
    return json.loads(next(line for line in out.splitlines() if line.startswith("@@"))[2:])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--sweeps", type=int, default=80)
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args()
    old, new = Path(a.old).resolve(), Path(a.new).resolve()
    res = {"old": {}, "new": {}}
    for r in range(a.rounds):
        order = (("old", old), ("new", new)) if r % 2 == 0 else (("new", new), ("old", old))
        for label, tree in order:
            for k, v in measure(tree, a.size, a.sweeps, a.reps).items():
                res[label][k] = v if k == "capacity" else min(res[label].get(k, v), v)
    print(f"rotor {a.size}^2, capacity old {res['old']['capacity']} new {res['new']['capacity']}")
    print(f"{'case':>24} {'old [ms]':>10} {'new [ms]':>10} {'new/old':>8}")
    for k in res["old"]:
        if k != "capacity":
            o, n = res["old"][k], res["new"][k]
            print(f"{k:>24} {o:>10.2f} {n:>10.2f} {n / o:>8.3f}")


if __name__ == "__main__":
    main()
