"""The band work on tiles against the full grid (and, in 3D, the box round each band), in one run.

For each scenario (2D or 3D) and size, the model is built once per layout, differing only in
where each solid's extrapolation and smoothing sweeps run:

* ``grid``: the whole grid (``Numerics.band_sweeps = "grid"``; the 3D code before tiles);
* ``window`` (3D only): a box round each band that follows the body (``Model.band_window``,
  the layout ``"auto"`` used in 3D before tiles, forced here even where "auto" would not);
* ``tiles``: the listed tiles of each band (``band_sweeps = "band"``; 16 x 16 in 2D,
  8 x 8 x 8 in 3D), whatever share of the grid they list.

The printed layout says how many tiles the tighter capacity sweeps, the capacity, and the
grid's tiles: ``"auto"`` tiles a band when capacity / grid's tiles <= ``BAND_TILE_FRACTION``.

Timed, one process, best of ``--reps`` calls after a compile call:

1. the band operator alone, ``refmap.extrapolation.extend`` on the state after two steps,
   with the smoothing's full 80 sweeps (what a strained body costs; an unstrained start
   stops the adaptive smoothing at once);
2. the whole step, ``--steps`` steps in one jitted call, 80 smoothing sweeps per step.

The three layouts give the same numbers (printed: the largest difference of the maps from
the grid's).  Pin one core for one-core figures::

    XLA_FLAGS=--xla_cpu_multi_thread_eigen=false taskset -c 0 \\
        python benchmarks/bench_band_layouts.py --cases sphere_relax:48,sphere_relax:64,spheres_settle:48
    ... --cases rotor:64,rotor:128,rotor:256,two_balls:128,two_balls:256

docs/benchmarks.md ("Band tiles in 3D", "Where 'auto' tiles in 2D") has the figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import refmap  # noqa: F401  (float64)
from refmap import extrapolation
from refmap import model as model_module
from refmap.scenarios import get_case

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gpu_check import best_of  # noqa: E402  (the same timing rule as the GPU figures)

MODES = ("grid", "window", "tiles")


def build(name, n, mode):
    case = get_case(name, n)
    numerics = dataclasses.replace(
        case.numerics,
        fixed_smooth_sweeps=case.numerics.smooth_max_sweeps,
        band_sweeps={"grid": "grid", "window": "auto", "tiles": "band"}[mode],
    )
    saved = model_module.BAND_TILE_FRACTION
    saved_w = model_module.BAND_WINDOW_FRACTION
    if mode == "window":  # no tiles, and the box whatever its size
        model_module.BAND_TILE_FRACTION = 0.0
        model_module.BAND_WINDOW_FRACTION = 1.0
    try:
        model, params = case.replace(numerics=numerics).build()
    finally:
        model_module.BAND_TILE_FRACTION = saved
        model_module.BAND_WINDOW_FRACTION = saved_w
    return model, params


def layout(model):
    if model.band_capacity is not None:
        total = int(np.prod(extrapolation.narrowband.n_tiles(model.grid.shape(), model.band_tile)))
        return f"tiles {model._band_tight}/{model.band_capacity} of {total}"
    if model.band_window is not None:
        frac = np.prod(model.band_window) / np.prod(model.grid.shape())
        return f"box {'x'.join(map(str, model.band_window))} ({frac:.0%})"
    return "full grid"


def run_case(name, n, steps, reps):
    rows = {}
    nd = get_case(name, n).grid.ndim
    modes = MODES if nd == 3 else ("grid", "tiles")
    for mode in modes:
        model, params = build(name, n, mode)
        s0 = model.initial_state(params)
        dt = model.time_step(s0, params)[0]
        s2 = jax.jit(lambda s, m=model, p=params, dt=dt: m.run_steps(s, p, 2, dt=dt))(s0)
        f = s2.xi - jnp.stack([jnp.asarray(x) for x in model.grid.mesh("node")])[None]
        op = jax.jit(lambda f, m=model, phi=s2.phi: m._extend_all(f, phi))
        ext, t_op, _ = best_of(op, f, reps)
        run = jax.jit(lambda s, m=model, p=params, dt=dt: m.run_steps(s, p, steps, dt=dt))
        out, t_step, comp = best_of(run, s0, reps)
        rows[mode] = dict(op=t_op * 1e3, step=t_step / steps * 1e3, compile=comp,
                          xi=np.asarray(out.xi), ext=np.asarray(ext), layout=layout(model))
    print(f"\n{name} {n}^{nd} (80 smoothing sweeps)", flush=True)
    print(f"  {'layout':7s} {'where':34s} {'operator [ms]':>14s} {'step [ms]':>10s} "
          f"{'compile [s]':>11s} {'max |dxi|':>10s}")
    for mode in modes:
        r = rows[mode]
        diff = max(float(np.abs(r["xi"] - rows["grid"]["xi"]).max()),
                   float(np.abs(r["ext"] - rows["grid"]["ext"]).max()))
        print(f"  {mode:7s} {r['layout']:34s} {r['op']:14.1f} {r['step']:10.1f} "
              f"{r['compile']:11.1f} {diff:10.1e}")
    g, t = rows["grid"], rows["tiles"]
    line = f"  tiles against grid: operator {g['op'] / t['op']:.2f}x, step {g['step'] / t['step']:.2f}x"
    if "window" in rows:
        w = rows["window"]
        line += f"; against the box: operator {w['op'] / t['op']:.2f}x, step {w['step'] / t['step']:.2f}x"
    print(line, flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="sphere_relax:48,sphere_relax:64,spheres_settle:48",
                    help="comma-separated NAME:N (2D or 3D scenarios)")
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--reps", type=int, default=2)
    a = ap.parse_args(argv)
    print(f"device: {jax.devices()[0].platform}; steps per call {a.steps}; best of {a.reps} calls")
    for item in a.cases.split(","):
        name, n = item.split(":")
        run_case(name, int(n), a.steps, a.reps)


if __name__ == "__main__":
    main()
