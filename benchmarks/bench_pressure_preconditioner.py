"""The incompressible projection's preconditioners: CG iterations and step time per scenario.

For each scenario and size the case is built with ``fluid_model = "incompressible"``,
moved ``--warm`` steps (with the fast preconditioner), and then, from that one state,
for each ``pressure_preconditioner`` ("fast", "jacobi", "multigrid"):

* the CG iterations of the projection in each of the next ``--steps`` steps (mean and
  max; the step run with ``Projection.project(return_info=True)``, i.e. plain CG, which
  iterates exactly as the differentiable solve);
* the wall time of one jitted step (``Model.step`` at the adaptive dt of the state),
  best of ``--reps`` calls, the preconditioners interleaved call by call so that a busy
  machine slows all of them alike; the compressible step from the same state is timed
  with them for scale.

One thread for XLA (set before JAX is imported, as in bench_sharding.py), so the figures
are comparable across machines of different core counts.

Usage: python benchmarks/bench_pressure_preconditioner.py
       [--cases rotor:128,rotor:256,two_balls:128,stick:128,circle:128] [--warm 10]
       [--steps 5] [--reps 5]
docs/validation_incompressible.md ("Preconditioners") has the figures.
"""

from __future__ import annotations

import os

SINGLE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
os.environ["XLA_FLAGS"] = (SINGLE_THREAD + " " + os.environ.get("XLA_FLAGS", "")).strip()

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import time  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402

import refmap  # noqa: E402, F401  (float64)
from refmap.projection import PRECONDITIONERS  # noqa: E402
from refmap.scenarios import get_case  # noqa: E402


def _model(name, n, **numerics):
    case = get_case(name, n)
    num = dataclasses.replace(case.numerics, **numerics)
    return dataclasses.replace(case, numerics=num).build()


def _counting_step(model, params):
    """A jitted ``state -> (next state, CG iterations)``: the step with its projection
    asked for the solver's info (plain CG)."""
    pr = model.projection

    def fn(s):
        box = {}
        orig = pr.project

        def spy(*args, return_info=False, **kw):
            v, _, info = orig(*args, return_info=True, **kw)
            box["it"] = info["iterations"]
            return v

        pr.project = spy
        try:
            out = model.step(s, params, model.time_step(s, params)[0])
        finally:
            pr.project = orig
        return out, box["it"]

    return jax.jit(fn)


def run(name, n, warm, steps, reps):
    models = {k: _model(name, n, fluid_model="incompressible", pressure_preconditioner=k)
              for k in PRECONDITIONERS}
    models["compressible"] = _model(name, n)
    model0, params = models["fast"]
    s0 = jax.jit(lambda p: model0.run_steps(model0.initial_state(p), p, warm))(params)
    dt = float(model0.time_step(s0, params)[0])
    rows = {}
    for k, (m, p) in models.items():
        it = []
        if m.projection is not None:
            count = _counting_step(m, p)
            s = s0
            for _ in range(steps):
                s, i = count(s)
                it.append(int(i))
        step = jax.jit(m.step)
        t0 = time.perf_counter()
        jax.block_until_ready(step(s0, p, dt))
        rows[k] = dict(it=it, step=step, params=p, compile=time.perf_counter() - t0,
                       best=float("inf"))
    for _ in range(reps):  # interleaved: one call of each per round
        for r in rows.values():
            t0 = time.perf_counter()
            jax.block_until_ready(r["step"](s0, r["params"], dt))
            r["best"] = min(r["best"], time.perf_counter() - t0)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="rotor:128,rotor:256,two_balls:128,stick:128,circle:128")
    ap.add_argument("--warm", type=int, default=10)
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--reps", type=int, default=5)
    a = ap.parse_args(argv)
    print(f"incompressible projection preconditioners; jax {jax.__version__} on "
          f"{jax.devices()[0].platform}, XLA_FLAGS={os.environ['XLA_FLAGS']!r}; "
          f"{a.warm} steps first, iterations over the next {a.steps}, step time best of "
          f"{a.reps} (interleaved)", flush=True)
    print(f"{'case':>14} {'preconditioner':>15} {'CG mean':>8} {'CG max':>7} {'ms/step':>9} "
          f"{'vs fast':>8} {'vs compr.':>9}", flush=True)
    for spec in a.cases.split(","):
        name, n = spec.split(":")
        rows = run(name, int(n), a.warm, a.steps, a.reps)
        fast, comp = rows["fast"]["best"], rows["compressible"]["best"]
        for k, r in rows.items():
            it = r["it"]
            mean = f"{np.mean(it):8.1f}" if it else f"{'-':>8}"
            mx = f"{max(it):7d}" if it else f"{'-':>7}"
            print(f"{name + ' ' + n + '^2':>14} {k:>15} {mean} {mx} {1e3 * r['best']:9.1f} "
                  f"{r['best'] / fast:8.2f} {r['best'] / comp:9.2f}", flush=True)


if __name__ == "__main__":
    main()
