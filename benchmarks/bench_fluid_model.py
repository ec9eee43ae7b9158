"""Time to solution of the compressible and the incompressible fluid on the lid-driven cavity.

The soft disc of validation/lid_cavity.py (Sugiyama et al. 2011) is run from rest to
``--t-end`` (default 8.5: one loop of the vortex) on each grid, in one process, with

* ``compressible``: the validated set-up of validation/lid_cavity.py (lambda_f = 100, bulk
  viscosity beta c h as a body force, dt = 0.5 min(h^2 / (4 (mu + zeta)), h / c, h / c_solid));
* ``incompressible``: validation/incompressible.py's (no sound, no bulk viscosity,
  dt = 0.5 min(h^2 / (4 mu), h / c_solid)), default volume correction.

Each model is compiled and warmed up first (a short advance from a copy of the initial
state), so the wall time is the run's alone; diagnostics are sampled every 0.05 in both
(the path needs them).  Accuracy: the compressible page's measures (``lid_cavity.compare``)
against the digitized reference path: RMS distance over the first loop, the four extents
of the first loop and the area change over it.

Usage: python benchmarks/bench_fluid_model.py [--sizes 64,128] [--t-end 8.5]
docs/validation_incompressible.md ("Time to solution") has the figures.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import numpy as np

import refmap  # noqa: F401  (float64)

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "validation"))
import incompressible  # noqa: E402
import lid_cavity  # noqa: E402


def build(n, fluid_model):
    if fluid_model == "compressible":
        model, params, dt, _ = lid_cavity.build(n)
    else:
        model, params, dt = incompressible.build_cavity(n)
    return model, params, dt


def run(n, fluid_model, t_end, every=0.05):
    model, params, dt = build(n, fluid_model)
    adv = jax.jit(model.advance)
    diag = jax.jit(model.diagnostics)
    s0 = model.initial_state(params)
    t0 = time.perf_counter()
    warm, _ = adv(s0, params, 2 * dt)  # compile and warm up; the run starts from s0 again
    lid_cavity._row(diag(warm, params), warm)
    compile_s = time.perf_counter() - t0
    s = s0
    rows = [lid_cavity._row(diag(s, params), s)]
    t0 = time.perf_counter()
    for tt in every * np.arange(1, int(round(t_end / every)) + 1):
        s, info = adv(s, params, float(tt))
        if not bool(info["ok"]):
            raise RuntimeError(f"{fluid_model} {n}^2: the run failed before t = {tt:g}")
        rows.append(lid_cavity._row(diag(s, params), s))
    wall = time.perf_counter() - t0
    c = lid_cavity.compare(np.array(rows), lid_cavity.load_reference())
    return dict(n=n, model=fluid_model, dt=dt, steps=int(s.step), wall=wall, compile=compile_s, **c)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="64,128")
    ap.add_argument("--t-end", type=float, default=8.5)
    a = ap.parse_args(argv)
    sizes = [int(x) for x in a.sizes.split(",")]
    ref = lid_cavity.REF_EXTENTS
    print(
        f"lid-driven cavity, soft disc, t = 0 -> {a.t_end}; jax {jax.__version__} "
        f"on {jax.devices()[0].platform}",
        flush=True,
    )
    head = (
        f"{'n':>5} {'fluid':>15} {'dt':>9} {'steps':>7} {'wall s':>8} {'ms/step':>8} "
        f"{'RMS loop':>9} {'dx_max':>7} {'dx_min':>7} {'dy_max':>7} {'dy_min':>7} {'area loop':>9}"
    )
    print(head, flush=True)
    for n in sizes:
        res = {}
        for model in ("compressible", "incompressible"):
            r = run(n, model, a.t_end)
            res[model] = r
            err = {k: r.get(k, float("nan")) - v for k, v in ref.items()}
            print(
                f"{n:>5} {model:>15} {r['dt']:>9.3g} {r['steps']:>7} {r['wall']:>8.1f} "
                f"{1e3 * r['wall'] / r['steps']:>8.2f} {r.get('rms_first_loop', float('nan')):>9.4f} "
                f"{err['x_max']:>+7.3f} {err['x_min']:>+7.3f} {err['y_max']:>+7.3f} "
                f"{err['y_min']:>+7.3f} {100 * r.get('area_change_loop', float('nan')):>+8.2f}%",
                flush=True,
            )
        speed = res["compressible"]["wall"] / res["incompressible"]["wall"]
        print(f"{n:>5} time to solution, compressible / incompressible: {speed:.1f}x", flush=True)


if __name__ == "__main__":
    main()
