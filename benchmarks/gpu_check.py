"""GPU/CPU parity and GPU throughput, in one short run (issue 14 item 6; issue 10's GPU runs).

1. **Parity.** The rotor and two_balls at ``--parity-n`` cells for ``--parity-steps`` fixed
   steps, run on the CPU and on the default backend (the GPU when there is one) in the same
   process; prints the largest difference of every prognostic field relative to that
   field's largest value and fails (exit 1) above ``--tol`` (default 1e-9: float64 on both,
   the sums only reordered; the ENO tie rule keeps round-off from choosing stencils, see
   docs/method.md).
2. **Throughput.** The rotor step (the explicit viscous step, as in every earlier figure)
   at each of ``--sizes`` (fixed dt, full smoothing sweeps)
   and the 100-disc ``suspension`` at each of ``--suspension``: compile time, ms per step,
   Mcell-updates/s, the step's own dt and the wall time per unit of simulated time.
3. **Options that the CPU tuned** (each optional): ``--band-compare`` times the rotor with
   the band sweeps on tiles and on the full grid (``Numerics.band_sweeps``; the "auto"
   rule's threshold was measured on a CPU; ``--band-compare-3d`` the same for the 3D
   ``sphere_relax`` on 8^3 tiles); ``--incompressible`` times the rotor with the
   incompressible fluid (projection with the fast and the multigrid preconditioners:
   larger dt, a linear solve per step); ``--sizes-3d`` times the 3D ``sphere_relax``.

Each section is guarded: an error is printed and recorded and the next section runs, and
``--json`` is rewritten after every row, so a run stopped at a time limit keeps what it
measured.

Everything is float64.  On a machine without a GPU both runs use the CPU (parity then
checks determinism).  Usage::

    python benchmarks/gpu_check.py                                   # defaults below
    python benchmarks/gpu_check.py --sizes 128 --parity-n 32 --parity-steps 50   # a CPU try
    python benchmarks/gpu_check.py --sizes 64 --parity-n 32 --parity-steps 10 \
        --band-compare 64 --incompressible 64 --sizes-3d 16 --suspension 64 --steps 3

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


def best_of(fn, arg, reps=3):
    """``(out, best, compile_s)``: a first call (compile and run), then the best wall time
    of ``reps`` calls of the jitted ``fn(arg)``."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(arg))
    compile_s = time.perf_counter() - t0
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(arg))
        best = min(best, time.perf_counter() - t0)
    return out, best, compile_s


def _full_sweeps(case):
    """The case with every map smoothed the full sweep count each step (as in a real run
    after the first moments; the adaptive rule stops at once on unstrained starts)."""
    from dataclasses import replace

    return case.replace(numerics=replace(case.numerics,
                                         fixed_smooth_sweeps=case.numerics.smooth_max_sweeps))


def bandwidth(n=1 << 27, reps=5):
    """Measured memory bandwidth of the default device: y = 1.0001 x over ``n`` float64
    values (bytes read plus bytes written per second), the ceiling that a step which moves
    B bytes per cell cannot beat."""
    x = jax.numpy.ones(n)
    fn = jax.jit(lambda a: a * 1.0001)
    jax.block_until_ready(fn(x))
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(x))
        best = min(best, time.perf_counter() - t0)
    return 16.0 * n / best


def _with(case, **numerics):
    from dataclasses import replace

    return case.replace(numerics=replace(case.numerics, **numerics))


def _rotor(n):
    """The rotor with the explicit viscous step, whose throughput the earlier figures (and
    issue 14's Mcell-updates/s targets) measure; the scenario itself is implicit since
    2026-12-05, and the parity check runs it so."""
    return _with(get_case("rotor", n), viscosity="explicit")


def _throughput(case, steps):
    model, params = _full_sweeps(case).build()
    state = jax.jit(model.initial_state)(params)
    dt = model.time_step(state, params)[0]
    fn = jax.jit(lambda s: model.run_steps(s, params, steps, dt=dt))
    _, best, comp = best_of(fn, state)
    cells = int(np.prod(model.grid.shape()))
    ms = best / steps * 1e3
    return dict(compile_s=comp, ms_per_step=ms, mcell_updates_s=cells * steps / best / 1e6,
                dt=float(dt), s_per_unit_time=ms * 1e-3 / float(dt))


def _row(label, n, case, steps, rows, report):
    """Time one case, print and record the row (or the error) and rewrite the JSON."""
    nd = 3 if label.endswith("3D") else 2
    try:
        r = dict(case=label, n=n, **_throughput(case, steps))
        print(f"{label:34s} {n:5d}^{nd}  compile {r['compile_s']:6.1f} s  {r['ms_per_step']:9.3f} ms/step"
              f"  {r['mcell_updates_s']:8.1f} Mcell-updates/s  dt {r['dt']:.2e}"
              f"  {r['s_per_unit_time']:8.2f} s per unit time", flush=True)
    except Exception as e:  # noqa: BLE001  (record it, go on with the next row)
        r = dict(case=label, n=n, error=f"{type(e).__name__}: {e}")
        print(f"{label:34s} {n:5d}^{nd}  FAILED {r['error'][:300]}", flush=True)
    rows.append(r)
    report()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parity-n", type=int, default=64)
    ap.add_argument("--parity-steps", type=int, default=200)
    ap.add_argument("--tol", type=float, default=1e-9)
    ap.add_argument("--sizes", default="512,1024,2048,4096")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--suspension", default="", help="grid sizes for the 100-disc suspension (e.g. 300)")
    ap.add_argument("--band-compare", default="", help="rotor sizes timed with band_sweeps 'band' and 'grid'")
    ap.add_argument("--band-compare-3d", default="",
                    help="sphere_relax cube sizes timed with band_sweeps 'band' (8^3 tiles) and 'grid'")
    ap.add_argument("--incompressible", default="", help="rotor sizes timed with the incompressible fluid")
    ap.add_argument("--sizes-3d", default="", help="cube sizes of the 3D sphere_relax (e.g. 64,128)")
    ap.add_argument("--json", default=None, help="also write the figures here (rewritten after every row)")
    a = ap.parse_args(argv)

    def sizes(text):
        return [int(x) for x in text.split(",") if x]

    print("JAX", jax.__version__, "devices:", jax.devices(), flush=True)
    out = dict(jax=jax.__version__, devices=[str(d) for d in jax.devices()], parity_ok=None,
               parity=[], throughput=[])

    def report():
        if a.json:
            with open(a.json, "w") as f:
                json.dump(out, f, indent=1)

    try:
        ok, out["parity"] = parity(a.parity_n, a.parity_steps, a.tol)
        for r in out["parity"]:
            print(f"parity {r['case']:10s} {r['field']:6s} rel. diff {r['rel_diff']:.2e}", flush=True)
        print("PARITY", "OK" if ok else "FAILED", f"(tol {a.tol:g})", flush=True)
    except Exception as e:  # noqa: BLE001
        ok = False
        out["parity_error"] = f"{type(e).__name__}: {e}"
        print("PARITY FAILED to run:", out["parity_error"][:500], flush=True)
    out["parity_ok"] = ok
    try:
        out["bandwidth_GB_s"] = bandwidth() / 1e9
        print(f"memory bandwidth (scale of 2^27 float64): {out['bandwidth_GB_s']:.0f} GB/s", flush=True)
    except Exception as e:  # noqa: BLE001
        print("bandwidth measurement failed:", e, flush=True)
    report()
    rows = out["throughput"]
    for n in sizes(a.sizes):
        _row("rotor", n, _rotor(n), a.steps, rows, report)
    for n in sizes(a.suspension):
        _row("suspension (100 discs)", n, get_case("suspension", n), a.steps, rows, report)
    for n in sizes(a.band_compare):
        for mode in ("band", "grid"):
            _row(f"rotor, band_sweeps={mode}", n, _with(_rotor(n), band_sweeps=mode),
                 a.steps, rows, report)
    for n in sizes(a.band_compare_3d):
        for mode in ("band", "grid"):
            _row(f"sphere_relax, band_sweeps={mode} 3D", n,
                 _with(get_case("sphere_relax", n), band_sweeps=mode), a.steps, rows, report)
    for n in sizes(a.incompressible):
        for pre in ("fast", "multigrid"):
            case = _with(_rotor(n), fluid_model="incompressible", pressure_preconditioner=pre)
            _row(f"rotor, incompressible ({pre})", n, case, a.steps, rows, report)
    for n in sizes(a.sizes_3d):
        _row("sphere_relax 3D", n, get_case("sphere_relax", n), a.steps, rows, report)
    return 0 if ok and not any("error" in r for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
