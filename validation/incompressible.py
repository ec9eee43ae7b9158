"""Validation of the incompressible fluid (Numerics.fluid_model = "incompressible").

Prints the numbers of docs/validation_incompressible.md:

1. Taylor-Green vortex on the periodic [0, 2 pi]^2 (eta = 0.1, no extra viscosity, to
   t = 0.5, dt = 0.05 h): amplitude and field errors against v0 exp(-eta t), orders;
2. Poiseuille flow (periodic channel, no-slip walls, body force 1, eta = 1, steady at t = 2):
   max error against y (1 - y), orders;
3. cost: conjugate-gradient iterations per step and wall time per step, compressible
   against incompressible, for the thesis's circle (64^2, 128^2);
4. the soft disc in the lid-driven cavity (validation/lid_cavity.py's set-up with an
   incompressible fluid: no lambda_f, no bulk viscosity): centroid path against the
   digitized reference of Sugiyama et al. (2011), first-loop extents, area history.

Run ``python validation/incompressible.py`` (about 5 minutes on one core);
``--quick`` skips the cavity's finer grids.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import refmap.projection as projection
from refmap.boundary import Boundary, Segment
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.linsolve import cg
from refmap.materials import LogNeoHookean
from refmap.model import Model, Solid
from refmap.scenarios import get_case
from refmap.state import FluidParams, Numerics, Params

sys.path.insert(0, str(Path(__file__).resolve().parent))
import lid_cavity  # noqa: E402  (the reference trajectory and its comparison)

PERIODIC = Boundary(left="periodic", right="periodic", bottom="periodic", top="periodic")
INC = Numerics(fluid_model="incompressible")


def taylor_green(n, T=0.5, eta=0.1):
    L = 2.0 * math.pi
    g = Grid(n, n, 0.0, L, 0.0, L)
    X, Y = g.mesh("node")
    v0 = np.stack([np.sin(X) * np.cos(Y), -np.cos(X) * np.sin(Y)])
    m = Model(g, (), PERIODIC, dataclasses.replace(INC, dt_fixed=0.05 * g.h), initial_velocity=v0)
    p = m.default_params(FluidParams(eta=eta, extra_viscosity=0.0))
    s, info = jax.jit(lambda s: m.advance(s, p, T))(m.initial_state(p))
    v = np.asarray(s.v)
    decay = math.exp(-eta * T)
    amp = float(np.sum(v * v0) / np.sum(v0 * v0))
    return dict(n=n, steps=int(info["steps"]), amplitude_error=abs(amp / decay - 1.0),
                field_l2=float(np.sqrt(np.mean((v - decay * v0) ** 2))),
                divergence=float(jnp.max(jnp.abs(m.projection.divergence(s.v, s.t)))))


def poiseuille(ny):
    g = Grid(8, ny, 0.0, 8.0 / ny, 0.0, 1.0)
    m = Model(g, (), Boundary(left="periodic", right="periodic", bottom="wall", top="wall"), INC)
    p = m.default_params(FluidParams(eta=1.0, extra_viscosity=0.0), gravity=(1.0, 0.0))
    s, info = jax.jit(lambda s: m.advance(s, p, 2.0))(m.initial_state(p))
    _, Y = g.mesh("node")
    err = np.abs(np.asarray(s.v[0]) - Y * (1.0 - Y))
    return dict(ny=ny, steps=int(info["steps"]), max_rel_error=float(err.max() / 0.25))


def orders(errs, key):
    e = [r[key] for r in errs]
    return [math.log2(a / b) for a, b in zip(e[:-1], e[1:], strict=True)]


def cost(name, n, t_end=0.5):
    """Wall time per step (compiled, second run) and, incompressible, the CG iterations per
    step (recorded by a CG that reports them through a host callback)."""
    out = {}
    for model in ("compressible", "incompressible"):
        case = get_case(name, n)
        case = dataclasses.replace(case, numerics=dataclasses.replace(case.numerics,
                                                                       fluid_model=model))
        m, p = case.build()
        s0 = m.initial_state(p)
        iters = []
        if model == "incompressible":
            def counting(A, b, iters=iters, **kw):
                x, info = cg(A, b, **kw)
                jax.debug.callback(lambda k: iters.append(int(k)), info["iterations"])
                return x

            orig = projection.solve_spd
            projection.solve_spd = counting
        try:
            adv = jax.jit(lambda s, m=m, p=p: m.advance(s, p, t_end))
            s, info = adv(s0)
            jax.block_until_ready(s.v)
            iters.clear()
            t0 = time.perf_counter()
            s, info = adv(s0)
            jax.block_until_ready(s.v)
            wall = time.perf_counter() - t0
        finally:
            if model == "incompressible":
                projection.solve_spd = orig
        steps = int(info["steps"])
        out[model] = dict(steps=steps, ms_per_step=1e3 * wall / steps)
        if iters:
            out[model].update(cg_mean=float(np.mean(iters)), cg_max=int(np.max(iters)))
    return out


def build_cavity(n, cfl=0.5, numerics=None):
    """(model, params, dt): validation/lid_cavity.py's soft disc (LogNeoHookean G = 0.1,
    kappa = 10, mu = 0.01 as extra viscosity, eta = 0) in an incompressible fluid;
    dt = cfl min(h^2 / (4 mu), h / c_solid) (no sound, no bulk viscosity)."""
    h = 1.0 / n
    c_solid = math.sqrt(10.0 + 2.0 * lid_cavity.G)
    dt = cfl * min(h * h / (4.0 * lid_cavity.MU), h / c_solid)
    law = LogNeoHookean(G=lid_cavity.G, kappa=10.0, rho0=1.0)
    m = Model(Grid(n, n, 0.0, 1.0, 0.0, 1.0),
              (Solid(shape=Disc(center=lid_cavity.CENTER, radius=lid_cavity.RADIUS), law=law,
                     name="disc"),),
              Boundary(top=(Segment("velocity", velocity=(1.0, 0.0)),)),
              dataclasses.replace(numerics or INC, dt_fixed=dt))
    p = Params(fluid=FluidParams(rho0=1.0, eta=0.0, extra_viscosity=lid_cavity.MU), laws=(law,))
    return m, p, dt


def cavity(n, t_end, cfl=0.5, numerics=None):
    """The incompressible cavity (:func:`build_cavity`) to t_end, diagnostics every 0.05,
    compared with the reference path (``lid_cavity.compare``)."""
    m, p, dt = build_cavity(n, cfl, numerics)
    adv = jax.jit(m.advance)
    diag = jax.jit(m.diagnostics)
    s = m.initial_state(p)
    rows = []
    t0 = time.perf_counter()
    blew_up = None
    for tt in np.arange(0.0, t_end + 1e-9, 0.05):
        if tt > 0:
            s2, info = adv(s, p, float(tt))
            if not bool(info["ok"]):
                blew_up = float(tt)
                break
            s = s2
        d = jax.device_get(diag(s, p))
        so = d["solids"][0]
        rows.append((float(s.t), so["centroid_x"], so["centroid_y"], so["area"], d["J_min"],
                     d["J_max"], d["max_speed"]))
    rows = np.array(rows, dtype=float)
    ref = lid_cavity.load_reference()
    metrics = lid_cavity.compare(rows, ref)  # the compressible page's measures
    metrics["area_range"] = [float(rows[:, 3].min() / rows[0, 3] - 1.0),
                             float(rows[:, 3].max() / rows[0, 3] - 1.0)]
    dist, covered = lid_cavity.path_distance(rows, ref)
    w = lid_cavity.winding(rows[:, 1], rows[:, 2])
    ext = lid_cavity.extents(rows[:, 1], rows[:, 2], w) if w[-1] >= 1.0 else None
    div = float(jnp.max(jnp.abs(m.projection.divergence(s.v, s.t))))
    return dict(n=n, dt=dt, steps=int(s.step), wall_s=time.perf_counter() - t0,
                blew_up_before=blew_up, t_reached=float(s.t), rows=rows.tolist(),
                compare=metrics,
                turns=float(w[-1]), path_mean=float(np.mean(dist)) if len(dist) else None,
                path_max=float(np.max(dist)) if len(dist) else None, covered=int(covered),
                extents=ext, area_change=float(rows[-1, 3] / rows[0, 3] - 1.0),
                area_range=[float(rows[:, 3].min() / rows[0, 3] - 1.0),
                            float(rows[:, 3].max() / rows[0, 3] - 1.0)],
                J=[float(rows[:, 4].min()), float(rows[:, 5].max())],
                max_speed=float(rows[:, 6].max()), divergence=div)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", default=None)
    ap.add_argument("--cavity-only", action="store_true")
    ap.add_argument("--t-end", type=float, default=20.0)
    a = ap.parse_args(argv)
    res = {}
    if a.cavity_only:
        for n in (32,) if a.quick else (32, 48, 64):
            r = cavity(n, a.t_end)
            print(json.dumps({k: v for k, v in r.items() if k != "rows"}, indent=1), flush=True)
            res.setdefault("cavity", []).append(r)
        if a.json:
            Path(a.json).write_text(json.dumps(res))
        return
    res["taylor_green"] = tg = [taylor_green(n) for n in (16, 32, 64)]
    res["taylor_green_orders"] = dict(amplitude=orders(tg, "amplitude_error"),
                                      field=orders(tg, "field_l2"))
    print(json.dumps(res["taylor_green"], indent=1), res["taylor_green_orders"], flush=True)
    res["poiseuille"] = po = [poiseuille(n) for n in (8, 16, 32)]
    res["poiseuille_orders"] = orders(po, "max_rel_error")
    print(json.dumps(po, indent=1), res["poiseuille_orders"], flush=True)
    res["cost"] = {f"circle_{n}": cost("circle", n) for n in (64, 128)}
    print(json.dumps(res["cost"], indent=1), flush=True)
    grids = (32,) if a.quick else (32, 48, 64)
    res["cavity"] = []
    for n in grids:
        res["cavity"].append(cavity(n, a.t_end))
        print(json.dumps({k: v for k, v in res["cavity"][-1].items() if k != "rows"}, indent=1),
              flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
