"""Time to solution of explicit vs implicit viscosity on the thesis's rotor.

For each grid size the rotor (``refmap.scenarios.rotor``, cfl 0.3; the scenario itself
uses implicit viscosity since 2026-12-05) is run from rest to ``--t-end`` three times:

* ``explicit``: the forward-Euler step (the thesis's; its time step is bound by the
  wave-damping limit at 128^2 and the viscous limit h^2 rho / (4 nu) above);
* ``implicit``: ``Numerics.viscosity = "implicit"`` (backward-Euler viscosity, maps advected
  with the new velocity; the solid-wave limit binds);
* ``reference``: explicit with the time step divided by ``--ref-factor`` (4 by default).

and prints for each run: steps, the time-step limit reported, the wall time (compile time
excluded: each run is compiled and warmed up on a short advance first) and its accuracy,
the relative L2 difference of the velocity field at t_end to the reference run and the
root-mean-square difference of the reference map (``err xi``, a length).  The speed-up is the explicit wall time over the implicit one.

Usage: python benchmarks/bench_viscosity.py [--sizes 128,256] [--t-end 0.5] [--ref-factor 4]
       python benchmarks/bench_viscosity.py --sizes 512   (long on a small machine)
docs/validation.md ("Implicit viscosity") has the figures of
``--sizes 128,256 --t-end 0.25 --ref-factor 2``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

import refmap  # noqa: F401
from refmap.model import LIMIT_NAMES
from refmap.scenarios import get_case


def run(n, t_end, viscosity="explicit", dt_divide=1.0):
    case = get_case("rotor", n)
    num = dataclasses.replace(case.numerics, viscosity=viscosity, cfl=case.numerics.cfl / dt_divide)
    model, params = dataclasses.replace(case, numerics=num).build()
    s0 = model.initial_state(params)
    advance = jax.jit(model.advance)
    t0 = time.perf_counter()
    jax.block_until_ready(advance(s0, params, jnp.asarray(1e-3 * t_end)))  # compile, warm up
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    s, info = advance(s0, params, jnp.asarray(t_end))
    jax.block_until_ready(s.v)
    wall = time.perf_counter() - t0
    if not bool(info["ok"]):
        raise RuntimeError(f"rotor {n}^2 {viscosity}: the run failed before t = {t_end}")
    return dict(
        v=np.asarray(s.v), xi=np.asarray(s.xi), steps=int(info["steps"]), dt=float(info["dt"]),
        limit=LIMIT_NAMES[int(info["limit"])], wall=wall, compile=compile_s,
    )


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="128,256")
    ap.add_argument("--t-end", type=float, default=0.5)
    ap.add_argument("--ref-factor", type=float, default=4.0)
    a = ap.parse_args(argv)
    print(f"rotor from rest to t = {a.t_end}; reference: explicit with dt / {a.ref_factor:g}")
    print(f"{'n':>5} {'run':>10} {'steps':>7} {'dt':>10} {'limit':>12} {'wall s':>8} "
          f"{'compile s':>9} {'err v':>9} {'err xi':>9}")
    for n in (int(x) for x in a.sizes.split(",")):
        ref = run(n, a.t_end, "explicit", a.ref_factor)
        out = {"explicit": run(n, a.t_end, "explicit"), "implicit": run(n, a.t_end, "implicit"),
               "reference": ref}
        for name, r in out.items():
            ev = rel(r["v"], ref["v"])
            exi = float(np.linalg.norm(r["xi"] - ref["xi"]) / np.sqrt(r["xi"].size))
            print(f"{n:>5} {name:>10} {r['steps']:>7} {r['dt']:>10.3e} {r['limit']:>12} "
                  f"{r['wall']:>8.1f} {r['compile']:>9.1f} {ev:>9.2e} {exi:>9.2e}", flush=True)
        sp = out["explicit"]["wall"] / out["implicit"]["wall"]
        print(f"{n:>5} speed-up (explicit wall / implicit wall): {sp:.2f}x", flush=True)


if __name__ == "__main__":
    main()
