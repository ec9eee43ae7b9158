"""Benchmark the whole RMT step and its phases on the rotor case.

Prints, for each grid size, the compile time and the steady throughput in Mcell-updates/s
(grid cells x steps per second) of the whole step and of its phases:

* stress+update  -- derived fields (solid and fluid stress, blending) and the v, rho_f, xi
  updates, i.e. the step without the band work;
* extrapolation  -- affine-exact extrapolation of xi into the band;
* smoothing      -- diffusion of the extrapolated values (thesis Algorithm 3);
* pinning        -- level-set pinning to phi0(xi) and re-distancing.

Usage: python benchmarks/bench_step.py [--sizes 128,256,512,1024] [--steps 20]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp

import refmap  # noqa: F401
from refmap import extrapolation
from refmap.scenarios import get_case


def _time(fn, *args, reps):
    t0 = time.perf_counter()
    out = fn(*args)
    jax.block_until_ready(out)
    compile_s = time.perf_counter() - t0
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        out = fn(*args)
        jax.block_until_ready(out)
        best = min(best, time.perf_counter() - t0)
    return compile_s, best


def bench(n: int, steps: int, reps: int = 3):
    case = get_case("rotor", n)
    # the explicit viscous step, as in every figure of docs/benchmarks.md (the scenario is
    # implicit since 2026-12-05)
    case = case.replace(numerics=dataclasses.replace(case.numerics, viscosity="explicit"))
    model, params = case.build()
    state = model.initial_state(params)
    # move it a little so the band work is representative
    state = jax.jit(lambda s: model.run_steps(s, params, 5))(state)
    dt = model.time_step(state, params)[0]
    cells = n * n
    rows = []

    whole = jax.jit(lambda s: model.run_steps(s, params, steps, dt=dt))
    c, t = _time(whole, state, reps=reps)
    rows.append(("whole step", c, cells * steps / t / 1e6, t / steps * 1e3))

    def no_band(s):
        def body(s, _):
            d = model.derived(s, params)
            return s.replace(v=s.v + 1e-9 * d["sxx"][:-1, :-1], t=s.t + dt), None

        return jax.lax.scan(body, s, None, length=steps)[0]

    # the stress + update phase is the full step with band work removed
    orig = (model.pin, model.extrapolate)
    model.pin = lambda phi, xi, dt: phi
    model.extrapolate = lambda xi, phi: xi
    su = jax.jit(lambda s: model.run_steps(s, params, steps, dt=dt))
    c, t = _time(su, state, reps=reps)
    model.pin, model.extrapolate = orig
    rows.append(("stress+update", c, cells * steps / t / 1e6, t / steps * 1e3))

    n_ = model.numerics
    h = model.h
    kw = dict(dx=model.grid.dx, dy=model.grid.dy, periodic=model.bc.periodic)
    Xn = jnp.asarray(model.grid.mesh("node"))

    def ext(xi, phi):
        def body(d, _):
            d = jax.vmap(lambda f: extrapolation.extrapolate_linear(f, phi[0], band=n_.band * h, **kw))(d)
            return d, None

        return jax.lax.scan(body, xi[0] - Xn, None, length=steps)[0]

    c, t = _time(jax.jit(ext), state.xi, state.phi, reps=reps)
    rows.append(("extrapolation", c, cells * steps / t / 1e6, t / steps * 1e3))

    def smo(xi, phi):
        def body(d, _):
            d = jax.vmap(
                lambda f: extrapolation.smooth_extrapolated(
                    f, phi[0], band=n_.band * h, coef=n_.smooth_coef, max_sweeps=n_.smooth_max_sweeps,
                    ratio=n_.smooth_ratio, atol=n_.smooth_atol, **kw)
            )(d)
            return d, None

        return jax.lax.scan(body, xi[0] - Xn, None, length=steps)[0]

    c, t = _time(jax.jit(smo), state.xi, state.phi, reps=reps)
    rows.append(("smoothing", c, cells * steps / t / 1e6, t / steps * 1e3))

    def pin(phi, xi):
        def body(p, _):
            return model.pin(p, xi, dt), None

        return jax.lax.scan(body, phi, None, length=steps)[0]

    c, t = _time(jax.jit(pin), state.phi, state.xi, reps=reps)
    rows.append(("pinning", c, cells * steps / t / 1e6, t / steps * 1e3))
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="128,256,512,1024")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--reps", type=int, default=2)
    a = ap.parse_args()
    print(f"backend: {jax.default_backend()}  devices: {jax.devices()}")
    print(f"{'n':>6} {'phase':>15} {'compile [s]':>12} {'Mcell-upd/s':>12} {'ms/step':>10}")
    for n in (int(s) for s in a.sizes.split(",")):
        for name, c, m, ms in bench(n, a.steps, a.reps):
            print(f"{n:>6} {name:>15} {c:>12.2f} {m:>12.2f} {ms:>10.2f}", flush=True)


if __name__ == "__main__":
    main()
