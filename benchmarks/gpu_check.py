"""GPU/CPU parity and GPU throughput, in one short run (issue 14 item 6; issue 10's GPU runs).

1. **Parity.** The rotor and two_balls at ``--parity-n`` cells for ``--parity-steps`` fixed
   steps, run on the CPU and on the default backend (the GPU when there is one) in the same
   process; prints the largest difference of every prognostic field relative to that
   field's largest value and fails (exit 1) above ``--tol`` (default 1e-9: float64 on both,
   the sums only reordered; the ENO tie rule keeps round-off from choosing stencils, see
   docs/method.md).
2. **Throughput.** The rotor step at each of ``--sizes`` (fixed dt, full smoothing sweeps)
   and the 100-disc ``suspension`` at each of ``--suspension``: compile time, ms per step,
   Mcell-updates/s.

Everything is float64.  On a machine without a GPU both runs use the CPU (parity then
checks determinism).  Usage::

    python benchmarks/gpu_check.py                                   # defaults below
    python benchmarks/gpu_check.py --sizes 128 --parity-n 32 --parity-steps 50   # a CPU try

``benchmarks/gpu.sh`` wraps it for the device machine (wheels for packages its image lacks).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import jax
import numpy as np

import refmap  # noqa: F401  (float64)
from refmap.scenarios import get_case

FIELDS = ("v", "rho_f", "xi", "phi")


def _run(case_name, n, steps, device):
    case = get_case(case_name, n)
    model, params = case.build()
    with jax.default_device(device):
        state = jax.jit(model.initial_state)(params)
        dt = float(model.time_step(state, params)[0])
        out = jax.jit(lambda s: model.run_steps(s, params, steps, dt=dt))(state)
        return {f: np.asarray(getattr(out, f)) for f in FIELDS}


def parity(n, steps, tol):
    cpu = jax.devices("cpu")[0]
    dev = jax.devices()[0]
    rows, ok = [], True
    for name in ("rotor", "two_balls"):
        a = _run(name, n, steps, cpu)
        b = _run(name, n, steps, dev)
        for f in FIELDS:
            scale = max(float(np.abs(a[f]).max()), 1e-300)
            err = float(np.abs(a[f] - b[f]).max()) / scale
            ok &= err <= tol
            rows.append(dict(case=name, field=f, rel_diff=err))
    return ok, rows


def _timed(fn, arg, reps=3):
    t0 = time.perf_counter()
    jax.block_until_ready(fn(arg))
    comp = time.perf_counter() - t0
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(arg))
        best = min(best, time.perf_counter() - t0)
    return comp, best


def _full_sweeps(case):
    """The case with every map smoothed the full sweep count each step (as in a real run
    after the first moments; the adaptive rule stops at once on unstrained starts)."""
    from dataclasses import replace

    return case.replace(numerics=replace(case.numerics,
                                         fixed_smooth_sweeps=case.numerics.smooth_max_sweeps))


def _throughput(case, steps):
    model, params = _full_sweeps(case).build()
    state = jax.jit(model.initial_state)(params)
    dt = model.time_step(state, params)[0]
    fn = jax.jit(lambda s: model.run_steps(s, params, steps, dt=dt))
    comp, best = _timed(fn, state)
    cells = model.grid.nx * model.grid.ny
    return comp, best / steps * 1e3, cells * steps / best / 1e6


def rotor_rows(sizes, steps):
    rows = []
    for n in sizes:
        comp, ms, mcups = _throughput(get_case("rotor", n), steps)
        rows.append(dict(case="rotor", n=n, compile_s=comp, ms_per_step=ms, mcell_updates_s=mcups))
        print(f"rotor {n:5d}^2  compile {comp:7.1f} s  {ms:9.3f} ms/step  {mcups:9.1f} Mcell-updates/s",
              flush=True)
    return rows


def suspension_rows(sizes, steps):
    rows = []
    for n in sizes:
        comp, ms, mcups = _throughput(get_case("suspension", n), steps)
        rows.append(dict(case="suspension (100 discs)", n=n, compile_s=comp, ms_per_step=ms,
                         mcell_updates_s=mcups))
        print(f"suspension (100 discs) {n:5d}^2  compile {comp:7.1f} s  {ms:9.3f} ms/step", flush=True)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parity-n", type=int, default=64)
    ap.add_argument("--parity-steps", type=int, default=200)
    ap.add_argument("--tol", type=float, default=1e-9)
    ap.add_argument("--sizes", default="512,1024,2048,4096")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--suspension", default="", help="grid sizes for the 100-disc suspension (e.g. 300)")
    ap.add_argument("--json", default=None, help="also write the figures here")
    a = ap.parse_args(argv)
    print("JAX", jax.__version__, "devices:", jax.devices(), flush=True)
    ok, prow = parity(a.parity_n, a.parity_steps, a.tol)
    for r in prow:
        print(f"parity {r['case']:10s} {r['field']:6s} rel. diff {r['rel_diff']:.2e}", flush=True)
    print("PARITY", "OK" if ok else "FAILED", f"(tol {a.tol:g})", flush=True)
    rows = rotor_rows([int(x) for x in a.sizes.split(",") if x], a.steps)
    if a.suspension:
        rows += suspension_rows([int(x) for x in a.suspension.split(",")], a.steps)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(dict(jax=jax.__version__, devices=[str(d) for d in jax.devices()],
                           parity_ok=ok, parity=prow, throughput=rows), f, indent=1)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
