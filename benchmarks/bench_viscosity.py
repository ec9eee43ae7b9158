"""Time to solution of explicit vs implicit viscosity on the thesis's rotor.

For each grid size the rotor (``refmap.scenarios.rotor``, cfl 0.3; the scenario itself
uses implicit viscosity since 2026-12-05) is run from rest to ``--t-end`` in these modes:

* ``explicit``: the forward-Euler step (the thesis's; its time step is bound by the
  wave-damping limit at 128^2 and the viscous limit h^2 rho / (4 nu) above);
* ``implicit``: ``Numerics.viscosity = "implicit"`` (backward-Euler viscosity, maps advected
  with the new velocity; the solid-wave limit binds), once per entry of
  ``--implicit-divides`` (time step divided by it, named ``implicit/k``) and of
  ``--implicit-rtols`` (solver tolerance, named ``implicit@rtol``);
* ``reference``: explicit with the time step divided by ``--ref-factor`` (4 by default;
  ``--ref-factor 0`` leaves it out, for grids where it would cost most of the run).

and prints for each run: steps, the time-step limit reported, the wall time (compile time
excluded: each run is compiled and warmed up on a short advance first) and its accuracy,
the relative L2 difference of the velocity field at t_end to the reference run and the
root-mean-square difference of the reference map (``err xi``, a length).  The speed-up is the explicit wall time over the implicit one.

The time reference measures each mode's *time* error only.  What a user pays for is the
*total* error, grid and time together, so with several sizes the script also prints,
for every size but the finest, each mode's error against the next finer grid's explicit
run (interpolated bilinearly onto the coarse nodes; velocity in relative L2 over the
box, the map as an RMS over the coarse solid's nodes) and their ratio, implicit over
explicit.  "Equal accuracy" means an implicit run whose total error in v is at most
``--tolerance`` (5 %) above the explicit run's; ``--implicit-divides 1,2,4`` adds implicit
runs at smaller steps, and the speed-up at equal accuracy is taken from the fastest
implicit run that qualifies.  For the finest size, where no finer
run exists, it prints the difference between the two modes against that size's grid
error estimated by Richardson extrapolation from the two sizes below it (for a
ladder of sizes each twice the one before).

Usage: python benchmarks/bench_viscosity.py [--sizes 128,256] [--t-end 0.5] [--ref-factor 4]
       python benchmarks/bench_viscosity.py --sizes 512   (long on a small machine)
       python benchmarks/bench_viscosity.py --sizes 128,256,512 --t-end 0.25 --ref-factor 0 \
           --implicit-divides 1,2,4      (equal accuracy; ~25 minutes on one core)
docs/validation.md ("Implicit viscosity") has the figures of
``--sizes 128,256 --t-end 0.25 --ref-factor 2`` and of the equal-accuracy command above.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

import refmap  # noqa: F401
from refmap.convergence import bilinear
from refmap.model import LIMIT_NAMES
from refmap.scenarios import get_case


def run(n, t_end, viscosity="explicit", dt_divide=1.0, rtol=None):
    case = get_case("rotor", n)
    num = dataclasses.replace(case.numerics, viscosity=viscosity, cfl=case.numerics.cfl / dt_divide)
    if rtol is not None:
        num = dataclasses.replace(num, viscosity_rtol=rtol)
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
        v=np.asarray(s.v),
        xi=np.asarray(s.xi),
        phi=np.asarray(s.phi),
        grid=case.grid,
        steps=int(info["steps"]),
        dt=float(info["dt"]),
        limit=LIMIT_NAMES[int(info["limit"])],
        wall=wall,
        compile=compile_s,
    )


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def on_coarse(fine, coarse_grid, key):
    """A fine run's field interpolated bilinearly onto a coarse grid's nodes."""
    px, py = coarse_grid.mesh("node")
    return bilinear(fine[key], fine["grid"], px, py)


def total_errors(coarse, fine_explicit):
    """Velocity (relative L2 over the box) and map (RMS over the coarse solid's nodes)
    differences of a coarse run to the finer grid's explicit run."""
    g = coarse["grid"]
    v_ref = on_coarse(fine_explicit, g, "v")
    xi_ref = on_coarse(fine_explicit, g, "xi")
    inside = coarse["phi"] < 0  # (solids, nx, ny)
    d = coarse["xi"] - xi_ref  # (solids, 2, nx, ny)
    exi = float(np.sqrt(np.sum((d * d).sum(axis=-3)[inside]) / inside.sum()))
    return rel(coarse["v"], v_ref), exi


def equal_accuracy_report(runs, divides, tolerance):
    """Each mode's total error against the next finer grid, the equal-accuracy speed-up,
    and at the finest size the modes' difference against a Richardson estimate of the
    grid error."""
    sizes = sorted(runs)
    print("\nequal accuracy: each run against the next finer grid's explicit run")
    if len(sizes) < 2:
        print("(one size: no finer grid)")
    else:
        print(
            f"{'n':>5} {'against':>8} {'run':>12} {'wall s':>8} {'err v':>10} {'/ expl':>7} "
            f"{'err xi':>10} {'/ expl':>7}"
        )
    grid_err = {}
    for n, m in zip(sizes, sizes[1:], strict=False):
        ve, xe = total_errors(runs[n]["explicit"], runs[m]["explicit"])
        grid_err[n] = ve
        best = None
        for name, r in runs[n].items():
            v, x = (ve, xe) if name == "explicit" else total_errors(r, runs[m]["explicit"])
            print(
                f"{n:>5} {m:>8} {name:>12} {r['wall']:>8.1f} {v:>10.3e} {v / ve:>7.3f} "
                f"{x:>10.3e} {x / xe:>7.3f}",
                flush=True,
            )
            if (
                name != "explicit"
                and v <= (1 + tolerance) * ve
                and (best is None or r["wall"] < best[1]["wall"])
            ):
                best = (name, r)
        if best is None:
            print(
                f"{n:>5} no implicit run (dt / {', '.join(f'{k:g}' for k in divides)}) is within "
                f"{tolerance:.0%} of the explicit run's error in v",
                flush=True,
            )
        else:
            sp = runs[n]["explicit"]["wall"] / best[1]["wall"]
            print(
                f"{n:>5} speed-up at equal accuracy (v within {tolerance:.0%}): {sp:.2f}x "
                f"({best[0]})",
                flush=True,
            )
    top = sizes[-1]
    d = {
        k: rel(r["v"], runs[top]["explicit"]["v"]) for k, r in runs[top].items() if k != "explicit"
    }
    dtext = ", ".join(f"{k} {e:.3e}" for k, e in d.items())
    if len(sizes) >= 3 and sizes[-2] * 2 == top and sizes[-3] * 2 == sizes[-2]:
        a, b = grid_err[sizes[-3]], grid_err[sizes[-2]]
        p = np.log2(a / b)  # observed order of the explicit runs' differences
        est = b / (2.0**p) if p > 0 else float("nan")
        print(
            f"{top:>5}: difference to the explicit run: {dtext}; grid error of the explicit "
            f"v estimated {est:.3e} (order {p:.2f} from {sizes[-3]}, {sizes[-2]})",
            flush=True,
        )
    else:
        print(
            f"{top:>5}: difference to the explicit run: {dtext} (no finer grid; a Richardson "
            "estimate needs three sizes, each twice the one before)",
            flush=True,
        )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="128,256")
    ap.add_argument("--t-end", type=float, default=0.5)
    ap.add_argument("--ref-factor", type=float, default=4.0)
    ap.add_argument(
        "--implicit-divides",
        default="1",
        help="implicit runs with the time step divided by each of these (e.g. 1,2,4)",
    )
    ap.add_argument(
        "--implicit-rtols",
        default=None,
        help="implicit runs at each of these solver tolerances (Numerics.viscosity_rtol; "
        "default: the scenario's), e.g. 1e-6,1e-4",
    )
    ap.add_argument(
        "--tolerance",
        type=float,
        default=0.05,
        help="equal accuracy: an implicit run's total error in v within this fraction "
        "above the explicit run's",
    )
    a = ap.parse_args(argv)
    if a.ref_factor < 0 or 0 < a.ref_factor < 1:
        ap.error(f"--ref-factor {a.ref_factor:g}: must be 0 (no time reference) or >= 1")
    try:
        divides = [float(x) for x in a.implicit_divides.split(",")]
    except ValueError:
        ap.error(f"--implicit-divides {a.implicit_divides!r}: not a list of numbers")
    if any(k < 1 for k in divides):
        ap.error(f"--implicit-divides {a.implicit_divides!r}: every entry must be >= 1")
    try:
        rtols = (
            [None] if a.implicit_rtols is None else [float(x) for x in a.implicit_rtols.split(",")]
        )
    except ValueError:
        ap.error(f"--implicit-rtols {a.implicit_rtols!r}: not a list of numbers")
    if any(r is not None and not 0 < r < 1 for r in rtols):
        ap.error(f"--implicit-rtols {a.implicit_rtols!r}: every entry must lie in (0, 1)")
    ref_text = f"explicit with dt / {a.ref_factor:g}" if a.ref_factor else "none"
    print(f"rotor from rest to t = {a.t_end}; time reference: {ref_text}")
    print(
        f"{'n':>5} {'run':>12} {'steps':>7} {'dt':>10} {'limit':>12} {'wall s':>8} "
        f"{'compile s':>9} {'err v':>9} {'err xi':>9}"
    )
    runs = {}
    for n in (int(x) for x in a.sizes.split(",")):
        out = {"explicit": run(n, a.t_end, "explicit")}
        for k in divides:
            for rt in rtols:
                name = ("implicit" if k == 1 else f"implicit/{k:g}") + (
                    "" if rt is None else f"@{rt:g}"
                )
                out[name] = run(n, a.t_end, "implicit", k, rt)
        ref = run(n, a.t_end, "explicit", a.ref_factor) if a.ref_factor else None
        if ref is not None:
            out["reference"] = ref
        for name, r in out.items():
            if ref is None:
                ev = exi = float("nan")
            else:
                ev = rel(r["v"], ref["v"])
                exi = float(np.linalg.norm(r["xi"] - ref["xi"]) / np.sqrt(r["xi"].size))
            print(
                f"{n:>5} {name:>12} {r['steps']:>7} {r['dt']:>10.3e} {r['limit']:>12} "
                f"{r['wall']:>8.1f} {r['compile']:>9.1f} {ev:>9.2e} {exi:>9.2e}",
                flush=True,
            )
        for name, r in out.items():
            if name.startswith("implicit"):
                sp = out["explicit"]["wall"] / r["wall"]
                print(f"{n:>5} speed-up (explicit wall / {name} wall): {sp:.2f}x", flush=True)
        out.pop("reference", None)
        runs[n] = out
    equal_accuracy_report(runs, divides, a.tolerance)


if __name__ == "__main__":
    main()
