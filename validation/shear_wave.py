"""Finite-amplitude plane shear wave in a periodic, solid-only box (VALIDATION.md section 1).

xi_x = x - a sin(k y - omega t), xi_y = y, v_x = -a omega cos(k y - omega t),
omega = k sqrt(G / rho), exact at any amplitude for sigma = (G/J)(B - I) + kappa (J - 1) I
(refmap.materials.LogNeoHookean).  The body fills the whole box (a rectangle much larger
than the periodic domain), so the blend weights select the solid everywhere.

In 3D (``run(n, dim=3, wave_axis=..., disp_axis=...)``) the same wave travels along
``wave_axis`` with displacement along ``disp_axis`` in a periodic box [0, 1]^3 of
``n`` cells along the wave and 8 across it (the field is constant across):
xi_d = x_d - a sin(k x_w - omega t), v_d = -a omega cos(k x_w - omega t).

Run ``python validation/shear_wave.py`` for the convergence table (``--3d`` adds the 3D
table for every pair of axes).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

import refmap  # noqa: F401
from refmap.boundary import Boundary
from refmap.case import Case
from refmap.geometry import Box, Rectangle
from refmap.grid import Grid, Grid3D
from refmap.materials import LogNeoHookean
from refmap.model import Solid
from refmap.state import FluidParams, Numerics

G = 10.0
RHO = 1.0


def exact(X, Y, t, a, k):
    omega = k * math.sqrt(G / RHO)
    ph = k * Y - omega * t
    return X - a * np.sin(ph), Y.copy(), -a * omega * np.cos(ph)


def run(n: int, a: float = 0.05, t_end: float | None = None, c_dt: float = 2.0, dim: int = 2,
        wave_axis: int = 1, disp_axis: int = 0):
    """Run the wave on an n x n grid over [0, 1]^2 (or, with ``dim=3``, on [0, 1]^3 with n
    cells along ``wave_axis`` and 8 along the others); return the relative max errors
    (of the displacement-direction velocity, of that map component, and the largest other
    velocity component).

    dt = c_dt h^2 (so the first-order time error shrinks like the second-order space error).
    """
    k = 2 * math.pi
    omega = k * math.sqrt(G / RHO)
    t_end = t_end if t_end is not None else 0.5 * (2 * math.pi / omega)  # half a period
    per = "periodic"
    h = 1.0 / n
    law = LogNeoHookean(G=G, kappa=10.0, rho0=RHO, dim=dim)
    if dim == 2:
        grid = Grid(n, n, 0.0, 1.0, 0.0, 1.0)
        shape = Rectangle(center=(0.5, 0.5), half_size=(50.0, 50.0))
        boundary = Boundary(left=per, right=per, bottom=per, top=per)
    else:
        if wave_axis == disp_axis:
            raise ValueError("a shear wave needs wave_axis != disp_axis")
        cells = [8, 8, 8]
        cells[wave_axis] = n
        grid = Grid3D(*cells, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0)
        shape = Box(center=(0.5, 0.5, 0.5), half_size=(50.0, 50.0, 50.0))
        boundary = Boundary(left=per, right=per, bottom=per, top=per, back=per, front=per)
    case = Case(
        name="shear_wave",
        grid=grid,
        solids=(Solid(shape=shape, law=law, name="slab"),),
        boundary=boundary,
        fluid=FluidParams(rho0=1.0, lambda_f=1.0, eta=0.0, extra_viscosity=0.0),
        numerics=Numerics(dt_fixed=c_dt * h * h),
        t_end=t_end,
    )
    model, params = case.build()
    s = model.initial_state(params)
    Xn = grid.mesh("node")
    if dim == 2:
        wave_axis, disp_axis = 1, 0

    def fields(t):
        ph = k * Xn[wave_axis] - omega * t
        xi = [np.array(x, dtype=float) for x in Xn]
        xi[disp_axis] = Xn[disp_axis] - a * np.sin(ph)
        v = [np.zeros_like(Xn[0]) for _ in Xn]
        v[disp_axis] = -a * omega * np.cos(ph)
        return np.stack(xi), np.stack(v)

    xi0, v0 = fields(0.0)
    s = s.replace(xi=jnp.asarray(xi0)[None], v=jnp.asarray(v0))
    s, info = jax.jit(model.advance)(s, params, t_end)
    assert bool(info["ok"])
    xi1, v1 = fields(float(s.t))
    v = np.asarray(s.v)
    err_u = np.abs(v[disp_axis] - v1[disp_axis]).max() / (a * omega)
    err_xi = np.abs(np.asarray(s.xi[0, disp_axis]) - xi1[disp_axis]).max() / a
    others = [c for c in range(dim) if c != disp_axis]
    err_v = max(np.abs(v[c]).max() for c in others) / (a * omega)
    return err_u, err_xi, err_v


def orders(ns, errs):
    return [math.log(errs[i] / errs[i + 1]) / math.log(ns[i + 1] / ns[i]) for i in range(len(ns) - 1)]


def _table(ns, res):
    eu = [r[0] for r in res]
    ex = [r[1] for r in res]
    print("n    rel.err u    rel.err xi       rel. max other v")
    for n, r in zip(ns, res, strict=True):
        print(f"{n:<4d} {r[0]:.3e}    {r[1]:.3e}      {r[2]:.1e}")
    print("observed order u :", [f"{o:.2f}" for o in orders(ns, eu)])
    print("observed order xi:", [f"{o:.2f}" for o in orders(ns, ex)])


if __name__ == "__main__":
    import sys

    ns = [16, 32, 64]
    print("2D: wave along y, displacement along x")
    _table(ns, [run(n) for n in ns])
    if "--3d" in sys.argv:
        for w in range(3):
            for d in range(3):
                if w != d:
                    print(f"3D: wave along {'xyz'[w]}, displacement along {'xyz'[d]}")
                    _table(ns, [run(n, dim=3, wave_axis=w, disp_axis=d) for n in ns])
