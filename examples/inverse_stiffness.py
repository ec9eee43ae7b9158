"""Inverse problem: recover the shear modulus G of a soft solid from its observed motion.

A pre-stretched soft disc is released in a closed box of fluid and springs back towards a
circle.  The "observation" is the velocity at a coarse lattice of probe nodes after every
step, generated here with the true modulus G = 2 (synthetic data).  Starting from a guess
G = 0.7, the shear modulus is recovered by minimising the misfit between the simulated and
the observed velocities with L-BFGS (optax) on log G; the gradient of the misfit comes from
reverse-mode differentiation through the whole run (:func:`refmap.differentiable.rollout`).

    python examples/inverse_stiffness.py            # 32^2, 100 steps
    python examples/inverse_stiffness.py --quick    # 16^2, 40 steps (CI)

Writes ``inverse_stiffness.png`` (misfit and G per iteration, one probe's velocity for the
initial guess, the truth and the recovered G) and ``inverse_stiffness.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import refmap  # noqa: F401  (enables float64)
from refmap import differentiable as rd
from refmap.case import Case
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.materials import NeoHookean
from refmap.model import Solid
from refmap.state import FluidParams, Numerics

G_TRUE = 2.0
G_START = 0.7


def build(n: int):
    """Model, state, params and step of the stretched-disc case on an n x n grid."""
    s = 1.2  # stretched 1.2x along x, squeezed along y (J = 1): xi = A x, A = diag(1/s, s)
    solid = Solid(shape=Disc((0.0, 0.0), 0.5), law=NeoHookean(G=G_TRUE, kappa=4.0),
                  strain=((1.0 / s, 0.0), (0.0, s)), name="disc")
    case = Case(name="inverse_stiffness", grid=Grid(n, n, -1.0, 1.0, -1.0, 1.0), solids=(solid,),
                fluid=FluidParams(lambda_f=4.0, eta=0.12, extra_viscosity=0.02),
                numerics=Numerics(compression="corner"))
    model, state, params = rd.from_case(case)
    # the step the adaptive rule picks for the stiffest G the search may visit (4 G_TRUE),
    # held constant so that every G is run with the same, stable step
    stiff = rd.replace_law(params, 0, G=4.0 * G_TRUE)
    dt = rd.stable_dt(model, state, stiff)
    return model, state, params, dt


def make_simulate(model, state, params, dt, n_steps):
    """``simulate(log_G)`` -> probe velocities (n_steps, 2, p, p)."""
    stride = max(1, model.grid.nx // 8)

    def observe(s):
        return s.v[:, ::stride, ::stride]

    def simulate(log_G):
        p = rd.replace_law(params, 0, G=jnp.exp(log_G))
        return rd.rollout(model, state, p, n_steps, dt, observe=observe).observations

    return simulate


def recover(simulate, observed, iters: int, tol: float = 1e-12, verbose: bool = True):
    """L-BFGS (optax, zoom line search) on log G from G_START, at most ``iters``
    iterations, stopping once the misfit is below ``tol``; returns the history of
    (misfit, G) per iteration.  The whole loop is one compiled ``lax.while_loop``."""
    scale = jnp.sum(observed**2)

    def misfit(log_G):
        return jnp.sum((simulate(log_G) - observed) ** 2) / scale

    x0 = jnp.asarray(math.log(G_START), dtype=jnp.float64)
    it, x, vals, xs = rd.minimize_lbfgs(misfit, x0, iters, tol)
    hist = [dict(iteration=k, misfit=float(vals[k]), G=float(jnp.exp(xs[k]))) for k in range(it)]
    hist.append(dict(iteration=it, misfit=float(jax.jit(misfit)(x)), G=float(jnp.exp(x))))
    if verbose:
        for h in hist:
            print(f"  it {h['iteration']:3d}  misfit {h['misfit']:.3e}  G {h['G']:.6f}")
    return hist


def plot(hist, traces, times, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(13, 3.6))
    it = [h["iteration"] for h in hist]
    ax[0].semilogy(it, [h["misfit"] for h in hist], "o-", ms=3)
    ax[0].set(xlabel="iteration", ylabel="relative misfit", title="misfit")
    ax[1].plot(it, [h["G"] for h in hist], "o-", ms=3, label="estimate")
    ax[1].axhline(G_TRUE, color="k", ls="--", label=f"true G = {G_TRUE:g}")
    ax[1].set(xlabel="iteration", ylabel="G", title="shear modulus")
    ax[1].legend()
    for label, tr, style in traces:
        ax[2].plot(times, tr, style, label=label)
    ax[2].set(xlabel="t", ylabel="u at a probe", title="observed motion")
    ax[2].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="16^2, 40 steps (CI)")
    ap.add_argument("--n", type=int, default=None, help="grid size (default 32, quick 16)")
    ap.add_argument("--steps", type=int, default=None, help="steps (default 100, quick 40)")
    ap.add_argument("--iters", type=int, default=None, help="most iterations (default 30)")
    ap.add_argument("--out", type=Path, default=Path("inverse_out"), help="output directory")
    ap.add_argument("--no-plot", action="store_true")
    a = ap.parse_args(argv)
    n = a.n or (16 if a.quick else 32)
    steps = a.steps or (40 if a.quick else 100)
    iters = a.iters or 30
    a.out.mkdir(parents=True, exist_ok=True)

    model, state, params, dt = build(n)
    print(f"stretched disc, {n}^2, {steps} steps of dt = {dt:.4g} (t = {steps * dt:.3g}); "
          f"true G = {G_TRUE}, start G = {G_START}")
    simulate = make_simulate(model, state, params, dt, steps)
    sim_fwd = jax.jit(simulate)
    observed = sim_fwd(jnp.log(G_TRUE))  # synthetic observation at the true modulus
    t0 = time.perf_counter()
    hist = recover(simulate, observed, iters)
    total = time.perf_counter() - t0
    G = hist[-1]["G"]
    err = abs(G - G_TRUE) / G_TRUE
    print(f"recovered G = {G:.6f} (true {G_TRUE}), relative error {err:.2e}, {total:.1f} s")

    result = dict(n=n, steps=steps, dt=dt, iterations=len(hist) - 1, G_true=G_TRUE, G_start=G_START,
                  G=G, relative_error=err, seconds=total, history=hist)
    (a.out / "inverse_stiffness.json").write_text(json.dumps(result, indent=1))
    if not a.no_plot:
        i, j = n // 8 * 2, n // 8 * 4
        stride = max(1, n // 8)
        traces = [(f"G = {g:.3g} ({lab})", np.asarray(sim_fwd(jnp.log(g)))[:, 0, i // stride, j // stride], st)
                  for g, lab, st in ((G_START, "start", ":"), (G_TRUE, "true", "k-"), (G, "recovered", "--"))]
        plot(hist, traces, dt * np.arange(1, steps + 1), a.out / "inverse_stiffness.png")
        print(f"wrote {a.out / 'inverse_stiffness.png'}")
    return result


if __name__ == "__main__":
    main()
