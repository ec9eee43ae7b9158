"""Implicit viscosity against the explicit runs (docs/validation.md, "Implicit viscosity").

Three validation cases, each run with ``Numerics.viscosity = "explicit"`` and
``"implicit"`` (backward-Euler viscosity, maps advected with the new velocity; its larger
time step):

* the oscillating Couette sandwich (validation/couette.py), both parameter sets, against
  the 1D reference: L2 and max errors of u(y) (worst of the four times), interface
  amplitude and phase errors against the closed form;
* the soft disc in the lid-driven cavity (validation/lid_cavity.py) to t = 3 on 32^2: RMS
  distance of the centroid samples to Sugiyama et al.'s path and the centroid at t = 3;
  the numerical bulk viscosity zeta = c h goes in as the fluid's ``bulk_viscosity`` for
  both runs here (the validated set-up applies it everywhere as a body force, explicit);
* the rotor (thesis Appendix E) from rest to t = 1: relative L2 differences of u and the
  RMS difference of xi to an explicit run with dt / 4.

Usage: python validation/implicit_viscosity.py [--couette 20,40] [--lid 32] [--rotor 64]
(--skip couette,lid,rotor to leave cases out).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent


def _load(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def couette(nys):
    from refmap.state import Numerics

    cou = _load("couette")
    for setup in ("uniform", "thesis"):
        ref = cou.reference(setup)
        amp, ph = cou.interface_amplitude_phase(cou.SETUPS[setup])
        for ny in nys:
            for mode in ("explicit", "implicit"):
                t0 = time.perf_counter()
                run = cou.run_2d(ny, setup, numerics=Numerics(viscosity=mode))
                e = cou.errors(run, ref)
                a, p = cou.interface_fit(run)
                print(
                    f"couette {setup:>7} ny={ny:>3} {mode:>8}: steps {run['steps']:>6} "
                    f"L2 {max(v[0] for v in e.values()):.3e} max {max(v[1] for v in e.values()):.3e} "
                    f"amp {100 * (a - amp) / amp:+.2f} % phase {p - ph:+.4f} rad "
                    f"vy_max {run['vy_max']:.1e} [{time.perf_counter() - t0:.0f} s]",
                    flush=True,
                )


def lid(n, t_end=3.0):
    L = _load("lid_cavity")
    path = L.REFERENCE
    if not path.exists():  # a git worktree: the shared data sits beside the main checkout
        path = Path("/work/shared/data") / path.name
    ref = L.load_reference(path)
    for mode in (None, "explicit", "implicit"):
        rows, s, info, _ = L.run(n, t_end, every=0.05, viscosity=mode)
        d = L.distance_to_reference(rows, ref)
        area = rows[:, 3] / rows[0, 3] - 1.0
        print(
            f"lid n={n} {mode or 'body-force zeta':>15}: dt {info['dt']:.3e} steps {info['steps']} "
            f"RMS distance {np.sqrt(np.mean(d ** 2)):.4f} centroid(t={t_end:g}) "
            f"({rows[-1, 1]:.4f}, {rows[-1, 2]:.4f}) area {area.min():+.3f}/{area.max():+.3f} "
            f"max speed {rows[:, 6].max():.3f} [{info['wall_s']:.0f} s]",
            flush=True,
        )


def rotor(n, t_end=1.0, ref_factor=4.0):
    import jax
    import jax.numpy as jnp

    from refmap.model import LIMIT_NAMES
    from refmap.scenarios import get_case

    def one(mode, divide=1.0):
        case = get_case("rotor", n)
        num = dataclasses.replace(case.numerics, viscosity=mode, cfl=case.numerics.cfl / divide)
        model, params = dataclasses.replace(case, numerics=num).build()
        t0 = time.perf_counter()
        s, info = jax.jit(model.advance)(model.initial_state(params), params, jnp.asarray(t_end))
        jax.block_until_ready(s.v)
        return s, info, time.perf_counter() - t0

    ref, _, _ = one("explicit", ref_factor)
    for mode in ("explicit", "implicit"):
        s, info, wall = one(mode)
        du = float(np.linalg.norm(s.v - ref.v) / np.linalg.norm(ref.v))
        dxi = float(np.sqrt(np.mean((np.asarray(s.xi) - np.asarray(ref.xi)) ** 2)))
        print(
            f"rotor n={n} {mode:>8}: steps {int(info['steps'])} dt {float(info['dt']):.3e} "
            f"({LIMIT_NAMES[int(info['limit'])]}) |v - v_ref| / |v_ref| {du:.2e} "
            f"RMS(xi - xi_ref) {dxi:.2e} [{wall:.0f} s]",
            flush=True,
        )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--couette", default="20,40")
    ap.add_argument("--lid", type=int, default=32)
    ap.add_argument("--rotor", type=int, default=64)
    ap.add_argument("--skip", default="")
    a = ap.parse_args(argv)
    skip = set(a.skip.split(","))
    if "couette" not in skip:
        couette([int(x) for x in a.couette.split(",")])
    if "lid" not in skip:
        lid(a.lid)
    if "rotor" not in skip:
        rotor(a.rotor)


if __name__ == "__main__":
    main()
