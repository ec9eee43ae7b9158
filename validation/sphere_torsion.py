"""The lowest torsional mode of a free elastic sphere (Lamb 1882), in a light fluid (3D).

A torsional mode of a sphere moves its material on spheres about its centre, without
changing volume: for the mode of degree n (axisymmetric, m = 0) the displacement is
azimuthal, ``u_phi = j_n(k r) dP_n/dtheta`` up to a factor, ``k = omega / c_s`` with the
shear speed ``c_s = sqrt(G / rho)``.  Its traction on the surface r = R is
``G r d/dr (u_phi / r)``, so a free surface needs ``d/dr (j_n(k r) / r) = 0`` at R, i.e.

    (n - 1) j_n(x) = x j_{n+1}(x),   x = k R.

n = 1 is the rigid rotation (x = 0) and then x = 5.763; the lowest genuine mode is
n = 2 at x = 2.5011 (computed below with scipy; Lamb's value 2.501), frequency
``omega = 2.5011 c_s / R``.  Its velocity field in Cartesian form is

    v = e(t) j_2(k r) z (-y, x, 0) / r^2,

(the two hemispheres twist in opposite senses about z).  The small-strain theory holds for
any hyperelastic law at small amplitude (the mode is isochoric, so kappa does not enter).

Set-up: sphere R = 0.5 (neo-Hookean G = 1, kappa = 2/3, rho = 1), fluid ten times lighter
(rho = 0.1, sound speed 2, eta = 0), extra viscosity 0.002 everywhere (solid and fluid;
in the solid a decay rate nu k^2 / 2 = 0.025 against omega = 5, a frequency shift of
1e-5), in a closed box [-0.75, 0.75]^3.  The fluid's viscous boundary layer,
delta = sqrt(2 nu_f / omega) = 0.09 = 0.18 R, loads the surface: the period grows by about
(rho_f / rho_s) (delta / R) times a factor of order one, i.e. of order 1 %.  (A lighter fluid
is not better: with rho_f = 0.01 the blend's fringe, where the mixed density is that of
the fluid but a few per cent of the solid's stress acts, dominates, and the mode is lost
within a period at 16 cells across.)  The sphere starts undeformed with the mode's velocity (amplitude 0.02 at
its largest), weighted by its blend fraction.  Measured: the projection of the velocity
on the mode shape over the solid, e(t), whose zero crossings (linear interpolation between
samples 1/80 period apart) give the period.

Run ``python validation/sphere_torsion.py`` for the table (16, 24, 32 cells across).
"""

from __future__ import annotations

import math
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import brentq
from scipy.special import spherical_jn

import refmap  # noqa: F401
from refmap import blend
from refmap.boundary import Boundary
from refmap.geometry import Sphere
from refmap.grid import Grid3D
from refmap.materials import NeoHookean
from refmap.model import Model, Solid
from refmap.state import FluidParams, Numerics

R = 0.5
G, KAPPA, RHO = 1.0, 2.0 / 3.0, 1.0
FLUID = FluidParams(rho0=0.1, lambda_f=0.4, eta=0.0, extra_viscosity=0.002)
BOX = 0.75
AMPLITUDE = 0.02


def lamb_root(n: int = 2) -> float:
    """The lowest positive root of (n - 1) j_n(x) = x j_{n+1}(x) (x = 0 excluded)."""
    def f(x):
        return (n - 1) * spherical_jn(n, x) - x * spherical_jn(n + 1, x)

    xs = np.linspace(0.5, 12.0, 2000)
    vals = f(xs)
    i = int(np.nonzero(np.sign(vals[:-1]) != np.sign(vals[1:]))[0][0])
    return brentq(f, xs[i], xs[i + 1], xtol=1e-14)


def exact_period() -> float:
    return 2 * math.pi * R / (lamb_root(2) * math.sqrt(G / RHO))


def mode_shape(X, Y, Z, k):
    r2 = X * X + Y * Y + Z * Z
    r = np.sqrt(r2)
    safe = np.where(r > 0, r, 1.0)
    g = np.where(r > 0, spherical_jn(2, k * safe) / np.where(r2 > 0, r2, 1.0), k * k / 15.0)
    return np.stack([-g * Z * Y, g * Z * X, np.zeros_like(X)])


def build(cells_across: int):
    n = int(round(cells_across * 2 * BOX / (2 * R)))
    grid = Grid3D(n, n, n, -BOX, BOX, -BOX, BOX, -BOX, BOX)
    solid = Solid(shape=Sphere(radius=R), law=NeoHookean(G=G, kappa=KAPPA, rho0=RHO, dim=3), name="sphere")
    numerics = Numerics(cfl=0.5)
    k = lamb_root(2) / R
    X, Y, Z = grid.mesh("node")
    shape = mode_shape(X, Y, Z, k)
    shape = shape / np.abs(shape).max()
    phi = np.sqrt(X * X + Y * Y + Z * Z) - R
    ws = 1.0 - np.asarray(blend.heaviside(jnp.asarray(phi), numerics.blend, numerics.blur_width * grid.h))
    model = Model(grid, (solid,), Boundary(back="wall", front="wall"), numerics,
                  initial_velocity=AMPLITUDE * shape * ws)
    return model, model.default_params(FLUID), shape


def run(cells_across: int, periods: float = 0.85, samples_per_period: int = 80, fluid=None, log=print):
    """Returns dict(period, exact, error, decay per period, steps, wall)."""
    model, params, shape = build(cells_across)
    if fluid is not None:
        params = model.default_params(fluid)
    T = exact_period()
    state = model.initial_state(params)
    adv = jax.jit(model.advance)
    shape_j = jnp.asarray(shape)

    @jax.jit
    def amplitude(s):
        d = model.derived(s, params)
        ws = d["ws_n"][0]  # the solid's node fraction
        return jnp.sum(ws * jnp.sum(s.v * shape_j, axis=0)) / jnp.sum(ws * jnp.sum(shape_j * shape_j, axis=0))

    ts, es = [0.0], [float(amplitude(state))]
    steps = 0
    t0 = time.perf_counter()
    for i in range(1, int(periods * samples_per_period) + 1):
        state, info = adv(state, params, i * T / samples_per_period)
        if not bool(info["ok"]):
            raise RuntimeError(f"blew up near t = {float(state.t):.4g}")
        steps += int(info["steps"])
        ts.append(float(state.t))
        es.append(float(amplitude(state)))
    wall = time.perf_counter() - t0
    ts, es = np.asarray(ts), np.asarray(es)
    cross = []
    for i in range(len(es) - 1):
        if es[i] == 0.0 or np.sign(es[i]) != np.sign(es[i + 1]):
            cross.append(ts[i] + (ts[i + 1] - ts[i]) * es[i] / (es[i] - es[i + 1]))
    if len(cross) < 2:
        raise RuntimeError(f"only {len(cross)} zero crossings in {periods} periods")
    # e(t) ~ cos(omega t): zero at T/4 and 3T/4
    period = 2.0 * float(cross[1] - cross[0])
    # the amplitude's decay over a period: the trough between the crossings against e(0)
    trough = np.abs(es[(ts > cross[0]) & (ts < cross[1])]).max()
    decay = float((trough / abs(es[0])) ** 2)
    out = dict(cells=cells_across, n=model.grid.nx, period=period, exact=T, error=period / T - 1.0,
               decay_per_period=decay, steps=steps, wall=wall)
    log(f"{cells_across:3d} cells across ({model.grid.nx}^3): period {period:.5f} vs Lamb {T:.5f} "
        f"({100 * (period / T - 1):+.2f} %), amplitude x{decay:.3f} per period, "
        f"{steps} steps, {wall:.0f} s")
    return out


if __name__ == "__main__":
    print(f"Lamb n = 2 torsional root x = {lamb_root(2):.6f}; exact period {exact_period():.6f}")
    rows = [run(c) for c in (16, 24, 32)]
