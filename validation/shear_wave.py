"""Finite-amplitude plane shear wave in a periodic, solid-only box (VALIDATION.md section 1).

xi_x = x - a sin(k y - omega t), xi_y = y, v_x = -a omega cos(k y - omega t),
omega = k sqrt(G / rho), exact at any amplitude for sigma = (G/J)(B - I) + kappa (J - 1) I
(refmap.materials.LogNeoHookean).  The body fills the whole box (a rectangle much larger
than the periodic domain), so the blend weights select the solid everywhere.

Time integration.  Forward Euler (the default ``Numerics.viscosity = "explicit"``)
amplifies every undamped elastic wave: per step a mode of speed c and wavenumber k has its
energy multiplied by 1 - dt nu k^2 + (c k dt)^2, so without viscosity it grows at the rate
c^2 k^2 dt / 2, which for the grid's shortest longitudinal waves (k = 2 / h along the wave)
and dt = 2 h^2 is 4 M / rho ~ 80 per unit time at every resolution.  Run undamped, the
explicit wave is only transiently right: round-off in the longitudinal velocity grows by
~1e6 every half period (measured at 16^2: 2e-9 of a omega after half a period, 4e-3 after
one, blown up after two; at 64^2 it reaches 1.5e-2 within half a period).  The script
therefore offers (``integrator=``):

* ``"explicit"`` (default): forward Euler with the least extra viscosity that keeps
  every wave from growing, extra_viscosity = M dt (the energy factor above is <= 1 for
  dt <= nu / c^2), and dt = h^2 / 2.  The viscosity scales like h^2, and its effect is in
  the exact solution: with the linear-in-displacement shear stress sigma_xy = G u_y, the
  damped wave u = a exp(-beta t) sin(k y - omega_d t), beta = nu k^2 / 2,
  omega_d = sqrt(c^2 k^2 - beta^2), nu = extra_viscosity / rho, is exact at any
  amplitude.  Measured: the longitudinal velocity stays at round-off (5e-13 of a omega)
  for eight periods at 32^2;
* ``"symplectic"``: ``Numerics.viscosity = "implicit"`` with no viscosity and dt = 2 h^2:
  the reference map then moves with the new velocity (symplectic Euler), under which
  the undamped wave itself is stable and the time error is ten times smaller than
  forward Euler's; but a longitudinal velocity still grows, at ~20 per unit time at 32^2
  (from 1e-12 of a omega after one period to 6e-5 after four and O(1) after eight; an
  extra viscosity of |v|^2 dt slows it but does not stop it; mechanism not identified), so
  it suits short runs only;
* ``"explicit-undamped"``: forward Euler, no viscosity, dt = 2 h^2, as this script ran
  before 2026-12 (kept to show the instability).

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
INTEGRATORS = ("explicit", "symplectic", "explicit-undamped")
RHO = 1.0


def wave_constants(k: float, nu: float) -> tuple[float, float]:
    """(beta, omega_d): decay rate and frequency of the shear wave of wavenumber ``k`` with
    kinematic viscosity ``nu`` (roots of s^2 + nu k^2 s + (G / rho) k^2 = 0)."""
    beta = 0.5 * nu * k * k
    return beta, math.sqrt(G / RHO * k * k - beta * beta)


def exact(X, Y, t, a, k, nu: float = 0.0):
    """Exact (xi_x, xi_y, v_x) at time t for the wave of amplitude a, wavenumber k and
    kinematic viscosity nu (see the module docstring)."""
    beta, omega = wave_constants(k, nu)
    ph = k * Y - omega * t
    amp = a * math.exp(-beta * t)
    return X - amp * np.sin(ph), Y.copy(), -amp * (omega * np.cos(ph) + beta * np.sin(ph))


def run(n: int, a: float = 0.05, t_end: float | None = None, c_dt: float | None = None, dim: int = 2,
        wave_axis: int = 1, disp_axis: int = 0, integrator: str = "explicit"):
    """Run the wave on an n x n grid over [0, 1]^2 (or, with ``dim=3``, on [0, 1]^3 with n
    cells along ``wave_axis`` and 8 along the others); return the relative max errors
    (of the displacement-direction velocity, of that map component, and the largest other
    velocity component).

    dt = c_dt h^2 (so the first-order time error shrinks like the second-order space error);
    c_dt defaults to 0.5 for ``"explicit"`` and 2 otherwise.
    ``integrator`` is one of INTEGRATORS (module docstring); with ``"explicit"`` the errors
    are against the damped exact wave.  Velocity errors are relative to the undamped
    amplitude a omega.
    """
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator = {integrator!r}: expected one of {INTEGRATORS}")
    k = 2 * math.pi
    omega = k * math.sqrt(G / RHO)
    t_end = t_end if t_end is not None else 0.5 * (2 * math.pi / omega)  # half a period
    per = "periodic"
    h = 1.0 / n
    law = LogNeoHookean(G=G, kappa=10.0, rho0=RHO, dim=dim)
    if c_dt is None:
        c_dt = 0.5 if integrator == "explicit" else 2.0
    dt = c_dt * h * h
    extra = float(law.moduli()[1]) * dt if integrator == "explicit" else 0.0
    nu = extra / RHO
    beta, omega_d = wave_constants(k, nu)
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
        fluid=FluidParams(rho0=1.0, lambda_f=1.0, eta=0.0, extra_viscosity=extra),
        numerics=Numerics(dt_fixed=dt,
                          viscosity="implicit" if integrator == "symplectic" else "explicit"),
        t_end=t_end,
    )
    model, params = case.build()
    s = model.initial_state(params)
    Xn = grid.mesh("node")
    if dim == 2:
        wave_axis, disp_axis = 1, 0

    def fields(t):
        ph = k * Xn[wave_axis] - omega_d * t
        amp = a * math.exp(-beta * t)
        xi = [np.array(x, dtype=float) for x in Xn]
        xi[disp_axis] = Xn[disp_axis] - amp * np.sin(ph)
        v = [np.zeros_like(Xn[0]) for _ in Xn]
        v[disp_axis] = -amp * (omega_d * np.cos(ph) + beta * np.sin(ph))
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
    for integ in INTEGRATORS[:2]:
        print(f"2D, {integ}: wave along y, displacement along x, half a period")
        _table(ns, [run(n, integrator=integ) for n in ns])
    period = 1.0 / math.sqrt(G / RHO)
    print("2D, 32^2, eight periods (rel. err u, xi, max other v):")
    for integ in INTEGRATORS:
        try:
            r = run(32, t_end=8 * period, integrator=integ)
            print(f"  {integ:<18s} {r[0]:.3e} {r[1]:.3e} {r[2]:.1e}")
        except AssertionError:
            print(f"  {integ:<18s} blew up")
    if "--3d" in sys.argv:
        for w in range(3):
            for d in range(3):
                if w != d:
                    print(f"3D: wave along {'xyz'[w]}, displacement along {'xyz'[d]}")
                    _table(ns, [run(n, dim=3, wave_axis=w, disp_axis=d) for n in ns])
