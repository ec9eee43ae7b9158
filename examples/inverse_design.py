"""Design problem: choose the inflow speed and the gravity that put a body at a target.

A soft, slightly heavy disc is carried by a stream in a channel: the fluid and the disc
start with the uniform velocity U, and the fluid enters on the left and leaves on the right
at that speed (the stick scenario's edges), free slip at the top and bottom, gravity g
along y.  Which (U, g) carry the disc's centroid to a given point at a
given time T?  The target here is where the disc is at T for U = 0.15, g = -0.8 (so the
answer is known); starting from U = 0.05, g = 0 the two controls are found by L-BFGS
(optax) on the squared distance to the target, with gradients from reverse-mode
differentiation through the whole run.  U enters through
``refmap.differentiable.with_traced(model, edge_velocity_scale=...)`` (the prescribed edge
velocities times a traced factor) and the initial velocity, g through ``Params.gravity``.

    python examples/inverse_design.py            # 32^2, 100 steps
    python examples/inverse_design.py --quick    # 16^2, 40 steps (CI)

Writes ``inverse_design.png`` (distance to the target per iteration, the controls, the
centroid paths for the start, the answer and the target) and ``inverse_design.json`` to
``--out``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import refmap  # noqa: F401  (enables float64)
from refmap import blend
from refmap import differentiable as rd
from refmap.boundary import Boundary, Segment
from refmap.case import Case
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.materials import NeoHookean
from refmap.model import Solid, solid_fractions
from refmap.state import FluidParams, Numerics

U0 = 0.1  # the case's edge speed; the control is the factor s, U = s U0
TRUE = (1.5, -0.8)  # (s, g) that define the target
START = (0.5, 0.0)


def build(n: int):
    solid = Solid(shape=Disc((-0.3, 0.1), 0.3), law=NeoHookean(G=1.0, kappa=2.0, rho0=1.5),
                  name="disc")
    flow = Segment("velocity", velocity=(U0, 0.0))
    case = Case(name="inverse_design", grid=Grid(n, n, -1.0, 1.0, -1.0, 1.0), solids=(solid,),
                boundary=Boundary(left=(flow,), right=(flow,), bottom="slip", top="slip"),
                fluid=FluidParams(lambda_f=4.0), numerics=Numerics(compression="corner"))
    model, state, params = rd.from_case(case)
    # the adaptive step of the fastest flow the search may visit (s = 4), held constant
    fast = rd.with_traced(model, edge_velocity_scale=4.0)
    dt = rd.stable_dt(fast, state.replace(v=state.v.at[0].add(4.0 * U0)), params)
    return model, state, params, dt


def centroid(model, s):
    """Centroid of the solid, weighted by its blended fraction (smooth in the state)."""
    n = model.numerics
    H = blend.heaviside(s.phi, n.blend, n.blur_width * model.h)
    ws = solid_fractions(H)[0][0]
    X, Y = (jnp.asarray(a) for a in model.grid.mesh("node"))
    total = jnp.sum(ws)
    return jnp.stack([jnp.sum(ws * X) / total, jnp.sum(ws * Y) / total])


def make_simulate(model, state, params, dt, n_steps):
    """``simulate(theta)`` -> centroid path (n_steps, 2) for theta = (s, g)."""

    ex = jnp.zeros_like(state.v).at[0].set(1.0)

    def simulate(theta):
        m = rd.with_traced(model, edge_velocity_scale=theta[0])
        p = dataclasses.replace(params, gravity=(0.0, theta[1]))
        s0 = state.replace(v=state.v + theta[0] * U0 * ex)  # the stream at t = 0
        return rd.rollout(m, s0, p, n_steps, dt, observe=lambda s: centroid(model, s)).observations

    return simulate


def design(simulate, target, h, iters: int, tol: float = 1e-14, verbose: bool = True):
    """L-BFGS (optax) on (s, g) for |centroid(T) - target|^2 / h^2, at most ``iters``
    iterations, stopping below ``tol``; returns the history.  The whole loop is one
    compiled ``lax.while_loop``."""

    def loss(theta):
        return jnp.sum((simulate(theta)[-1] - target) ** 2) / h**2

    it, x, vals, xs = rd.minimize_lbfgs(loss, jnp.asarray(START, dtype=jnp.float64), iters, tol)
    hist = [dict(iteration=k, loss=float(vals[k]), s=float(xs[k, 0]), g=float(xs[k, 1]))
            for k in range(it)]
    hist.append(dict(iteration=it, loss=float(jax.jit(loss)(x)), s=float(x[0]), g=float(x[1])))
    if verbose:
        for r in hist:
            print(f"  it {r['iteration']:3d}  (distance/h)^2 {r['loss']:.3e}  "
                  f"U {U0 * r['s']:.6f}  g {r['g']:+.6f}")
    return hist


def plot(hist, paths, target, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(13, 3.6))
    it = [h["iteration"] for h in hist]
    ax[0].semilogy(it, [max(h["loss"], 1e-30) for h in hist], "o-", ms=3)
    ax[0].set(xlabel="iteration", ylabel="(distance / h)$^2$", title="distance to the target")
    ax[1].plot(it, [U0 * h["s"] for h in hist], "o-", ms=3, label="U")
    ax[1].plot(it, [h["g"] for h in hist], "s-", ms=3, label="g")
    ax[1].axhline(U0 * TRUE[0], color="C0", ls="--")
    ax[1].axhline(TRUE[1], color="C1", ls="--")
    ax[1].set(xlabel="iteration", title="controls (dashed: answer)")
    ax[1].legend()
    for label, p, style in paths:
        ax[2].plot(p[:, 0], p[:, 1], style, label=label)
    ax[2].plot(*target, "k*", ms=12, label="target")
    ax[2].set(xlabel="x", ylabel="y", title="centroid path", aspect="equal")
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="16^2, 40 steps (CI)")
    ap.add_argument("--n", type=int, default=None, help="grid size (default 32, quick 16)")
    ap.add_argument("--steps", type=int, default=None, help="steps (default 100, quick 40)")
    ap.add_argument("--iters", type=int, default=30, help="most iterations (default 30)")
    ap.add_argument("--out", type=Path, default=Path("inverse_out"), help="output directory")
    ap.add_argument("--no-plot", action="store_true")
    a = ap.parse_args(argv)
    n = a.n or (16 if a.quick else 32)
    steps = a.steps or (40 if a.quick else 100)
    a.out.mkdir(parents=True, exist_ok=True)

    model, state, params, dt = build(n)
    simulate = make_simulate(model, state, params, dt, steps)
    sim_fwd = jax.jit(simulate)
    true_path = np.asarray(sim_fwd(jnp.asarray(TRUE)))
    target = jnp.asarray(true_path[-1])
    print(f"disc in a channel, {n}^2, {steps} steps of dt = {dt:.4g} (T = {steps * dt:.3g}); "
          f"target centroid ({float(target[0]):.4f}, {float(target[1]):.4f}), "
          f"start at ({true_path[0, 0]:.4f}, {true_path[0, 1]:.4f})")
    t0 = time.perf_counter()
    hist = design(simulate, target, model.h, a.iters)
    total = time.perf_counter() - t0
    s, g = hist[-1]["s"], hist[-1]["g"]
    err = dict(U=abs(s - TRUE[0]) / abs(TRUE[0]), g=abs(g - TRUE[1]) / abs(TRUE[1]))
    print(f"found U = {U0 * s:.6f} (answer {U0 * TRUE[0]:g}), g = {g:.6f} (answer {TRUE[1]:g}); "
          f"relative errors {err['U']:.2e}, {err['g']:.2e}; {len(hist) - 1} iterations, {total:.1f} s")
    result = dict(n=n, steps=steps, dt=dt, T=steps * dt, iterations=len(hist) - 1,
                  target=[float(c) for c in target], U=U0 * s, g=g, U_true=U0 * TRUE[0],
                  g_true=TRUE[1], relative_error=err, seconds=total, history=hist)
    (a.out / "inverse_design.json").write_text(json.dumps(result, indent=1))
    if not a.no_plot:
        paths = [("start", np.asarray(sim_fwd(jnp.asarray(START))), ":"),
                 ("found", np.asarray(sim_fwd(jnp.asarray([s, g]))), "--"),
                 ("answer", true_path, "k-")]
        plot(hist, paths, np.asarray(target), a.out / "inverse_design.png")
        print(f"wrote {a.out / 'inverse_design.png'}")
    return result


if __name__ == "__main__":
    main()
