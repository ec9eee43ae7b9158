"""A sphere settling through a periodic array at low Reynolds number (3D), against
Hasimoto's drag (issue 12, item 7).

A sphere of radius R = 0.3 and density 2 in a fluid of density 1, in a triply periodic
cube of side L = 1.5 (a simple cubic array, solid fraction phi = 4 pi R^3 / 3 L^3 = 0.0335),
driven by :class:`refmap.gravity.RelativeGravity` (gravity minus the mixture's mean weight,
the periodic set-up of Hasimoto 1959).  Hasimoto's drag on a simple cubic array of spheres,
F = 6 pi mu R U / K(phi) with

    K = 1 - 1.7601 phi^(1/3) + phi - 1.5593 phi^2 + O(phi^(8/3)),

gives the settling speed relative to the cell's mean velocity, U = K (rho_s - rho_f) V g /
(6 pi mu R).  Viscosity: refmap's stress is eta sym(grad v) plus extra_viscosity lap(v),
so the dynamic viscosity is mu = eta / 2 + extra_viscosity (docs/method.md); here eta = 0
and extra_viscosity = mu = 0.5.  g = 2.66 makes U ~ 0.05: Reynolds number rho U 2R / mu =
0.06, Mach number U / c = 0.01 (lambda_f = 25).  The solid is stiff (G = kappa = 20: strain
~ F / (G R^2) ~ 0.2 % at the surface).  Measured: the sphere's mean velocity (weighted by
its blend fraction) minus the grid's mean velocity, once steady (t = 1.2, about 10 times
the slowest viscous time L^2 / (4 pi^2 nu)).

Run ``python validation/settling_sphere.py`` (24^3, 32^3, 48^3).
"""

from __future__ import annotations

import math
import time

import jax
import jax.numpy as jnp

import refmap  # noqa: F401
from refmap.boundary import Boundary
from refmap.geometry import Sphere
from refmap.gravity import RelativeGravity
from refmap.grid import Grid3D
from refmap.materials import NeoHookean
from refmap.model import Model, Solid
from refmap.state import FluidParams, Numerics

R, L = 0.3, 1.5
RHO_S, RHO_F = 2.0, 1.0
MU = 0.5
G_ACC = 2.66
PER = "periodic"


def hasimoto_speed():
    V = 4.0 / 3.0 * math.pi * R**3
    phi = V / L**3
    K = 1.0 - 1.7601 * phi ** (1.0 / 3.0) + phi - 1.5593 * phi**2
    stokes = (RHO_S - RHO_F) * V * G_ACC / (6.0 * math.pi * MU * R)
    return K * stokes, stokes, phi, K


def build(n: int):
    grid = Grid3D(n, n, n, -L / 2, L / 2, -L / 2, L / 2, -L / 2, L / 2)
    solid = Solid(shape=Sphere(radius=R), law=NeoHookean(G=20.0, kappa=20.0, rho0=RHO_S, dim=3), name="sphere")
    boundary = Boundary(left=PER, right=PER, bottom=PER, top=PER, back=PER, front=PER)
    model = Model(grid, (solid,), boundary, Numerics(cfl=0.5),
                  body_forces=(RelativeGravity((0.0, 0.0, -G_ACC)),))
    params = model.default_params(FluidParams(rho0=RHO_F, lambda_f=25.0, eta=0.0, extra_viscosity=MU))
    return model, params


def run(n: int, t_end: float = 1.2, log=print):
    model, params = build(n)
    state = model.initial_state(params)

    @jax.jit
    def speed(s):
        ws = model.derived(s, params)["ws_n"][0]
        return jnp.sum(ws * s.v[2]) / jnp.sum(ws) - jnp.mean(s.v[2])

    adv = jax.jit(model.advance)
    t0 = time.perf_counter()
    hist, steps = [], 0
    for k in range(1, 7):
        state, info = adv(state, params, t_end * k / 6)
        if not bool(info["ok"]):
            raise RuntimeError(f"n = {n}: not finite near t = {float(state.t):.3g}")
        steps += int(info["steps"])
        hist.append(-float(speed(state)))
    wall = time.perf_counter() - t0
    U, stokes, phi, K = hasimoto_speed()
    out = dict(n=n, cells_across=2 * R / model.h, U=hist[-1], history=hist, exact=U,
               error=hist[-1] / U - 1.0, steps=steps, wall=wall)
    log(f"{n}^3 ({2 * R / model.h:.1f} cells across): U = {hist[-1]:.5f} vs Hasimoto {U:.5f} "
        f"({100 * (hist[-1] / U - 1):+.1f} %); history {[round(u, 4) for u in hist]}; "
        f"{steps} steps, {wall:.0f} s")
    return out


if __name__ == "__main__":
    U, stokes, phi, K = hasimoto_speed()
    print(f"phi = {phi:.4f}, K = {K:.4f}, Stokes speed {stokes:.5f}, Hasimoto {U:.5f}")
    for n in (24, 32, 48):
        run(n)
