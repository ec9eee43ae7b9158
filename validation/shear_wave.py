"""Finite-amplitude plane shear wave in a periodic, solid-only box (VALIDATION.md section 1).

xi_x = x - a sin(k y - omega t), xi_y = y, v_x = -a omega cos(k y - omega t),
omega = k sqrt(G / rho), exact at any amplitude for sigma = (G/J)(B - I) + kappa (J - 1) I
(refmap.materials.LogNeoHookean).  The body fills the whole box (a rectangle much larger
than the periodic domain), so the blend weights select the solid everywhere.

Run ``python validation/shear_wave.py`` for the convergence table.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

import refmap  # noqa: F401
from refmap.boundary import Boundary
from refmap.case import Case
from refmap.geometry import Rectangle
from refmap.grid import Grid
from refmap.materials import LogNeoHookean
from refmap.model import Solid
from refmap.state import FluidParams, Numerics

G = 10.0
RHO = 1.0


def exact(X, Y, t, a, k):
    omega = k * math.sqrt(G / RHO)
    ph = k * Y - omega * t
    return X - a * np.sin(ph), Y.copy(), -a * omega * np.cos(ph)


def run(n: int, a: float = 0.05, t_end: float | None = None, c_dt: float = 2.0):
    """Run the wave on an n x n grid over [0, 1]^2; return (max error of u, of xi_x).

    dt = c_dt h^2 (so the first-order time error shrinks like the second-order space error).
    """
    k = 2 * math.pi
    omega = k * math.sqrt(G / RHO)
    t_end = t_end if t_end is not None else 0.5 * (2 * math.pi / omega)  # half a period
    per = "periodic"
    h = 1.0 / n
    case = Case(
        name="shear_wave",
        grid=Grid(n, n, 0.0, 1.0, 0.0, 1.0),
        solids=(Solid(shape=Rectangle(center=(0.5, 0.5), half_size=(50.0, 50.0)),
                      law=LogNeoHookean(G=G, kappa=10.0, rho0=RHO), name="slab"),),
        boundary=Boundary(left=per, right=per, bottom=per, top=per),
        fluid=FluidParams(rho0=1.0, lambda_f=1.0, eta=0.0, extra_viscosity=0.0),
        numerics=Numerics(dt_fixed=c_dt * h * h),
        t_end=t_end,
    )
    model, params = case.build()
    s = model.initial_state(params)
    X, Y = case.grid.mesh("node")
    xx, xy, u = exact(X, Y, 0.0, a, k)
    s = s.replace(xi=jnp.asarray(np.stack([xx, xy]))[None], v=jnp.stack([jnp.asarray(u), jnp.zeros_like(jnp.asarray(u))]))
    s, info = jax.jit(model.advance)(s, params, t_end)
    assert bool(info["ok"])
    xx, xy, u = exact(X, Y, float(s.t), a, k)
    err_u = np.abs(np.asarray(s.v[0]) - u).max() / (a * omega)
    err_xi = np.abs(np.asarray(s.xi[0, 0]) - xx).max() / a
    err_v = np.abs(np.asarray(s.v[1])).max() / (a * omega)
    return err_u, err_xi, err_v


def orders(ns, errs):
    return [math.log(errs[i] / errs[i + 1]) / math.log(ns[i + 1] / ns[i]) for i in range(len(ns) - 1)]


if __name__ == "__main__":
    ns = [16, 32, 64]
    res = [run(n) for n in ns]
    eu = [r[0] for r in res]
    ex = [r[1] for r in res]
    print("n    rel.err u    rel.err xi_x   rel. max v_y")
    for n, r in zip(ns, res, strict=True):
        print(f"{n:<4d} {r[0]:.3e}    {r[1]:.3e}      {r[2]:.1e}")
    print("observed order u :", [f"{o:.2f}" for o in orders(ns, eu)])
    print("observed order xi:", [f"{o:.2f}" for o in orders(ns, ex)])
