"""Runs split over several devices (refmap.sharding) equal the one-device run.

The comparisons need several devices; on a CPU they are virtual ones, which XLA creates
only when ``--xla_force_host_platform_device_count`` is set before JAX starts, so they run
in a subprocess with that flag.  The rest (bad input, the ENO tie rule that makes the
comparison possible) runs here on one device.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401
from refmap.operators import _eno2
from refmap.scenarios import get_case
from refmap.sharding import check_devices, shard_state
from refmap.simulation import Simulation

SRC = Path(__file__).resolve().parents[1] / "src"

# Sharded and one-device runs are the same program; only the order of the terms of the few
# global sums (the pivot's rigid fit, contact totals) differs, i.e. round-off, 1e-16 of the
# field scale per step.  After the steps below the measured differences are <= 1e-17
# absolute (rotor v) and exactly 0 elsewhere; 1e-12 of the field's largest value leaves
# room for round-off growth but fails for any real difference (a wrong halo, a stencil
# chosen differently: those give 1e-6 and more, see test_eno_ties_go_centred).
TOL = 1e-12

_SCRIPT = r"""
import json, sys
import jax, numpy as np
import refmap
from refmap.scenarios import get_case
from refmap.sharding import shard_state, sharded_advance, gather_state
from refmap.simulation import Simulation

assert jax.device_count() == 4, jax.devices()
out = {}
for name, n, t_end, *numerics in SPECS:
    case = get_case(name, n)
    if numerics:  # Numerics fields to replace, e.g. the incompressible fluid
        import dataclasses
        case = case.replace(numerics=dataclasses.replace(case.numerics, **numerics[0]))
    model, params = case.build()
    s0 = model.initial_state(params)
    ref, info = jax.jit(model.advance)(s0, params, t_end)
    row = {"steps": int(info["steps"])}
    for nd in (2, 4):
        got, info2 = sharded_advance(model, nd)(shard_state(s0, nd), params, t_end)
        assert len(got.v.sharding.device_set) == nd, got.v.sharding
        assert tuple(got.v.sharding.spec) == (None, "x"), got.v.sharding
        assert int(info2["steps"]) == row["steps"]
        got = gather_state(got)
        for f in ("v", "rho_f", "xi", "phi") + (("p",) if ref.p is not None else ()):
            a, b = np.asarray(getattr(ref, f)), np.asarray(getattr(got, f))
            row[f"{f}_{nd}"] = float(np.abs(a - b).max() / np.abs(a).max())
    out[name] = row
# the Simulation path (frames, diagnostics, device placement) with devices=2: with one frame
# it advances from the initial state to t_end in one call, as the reference above did
if SIM:
    name, n, t_end = SPECS[0]
    model, params = get_case(name, n).build()
    ref, info = jax.jit(model.advance)(model.initial_state(params), params, t_end)
    sim = Simulation(get_case(name, n).replace(t_end=t_end, frames=1), None, progress=False,
                     pictures=False, devices=2)
    got = sim.run()
    assert len(got.v.sharding.device_set) == 2, got.v.sharding
    row = {f: float(np.abs(np.asarray(getattr(ref, f)) - np.asarray(getattr(got, f))).max()
                    / np.abs(np.asarray(getattr(ref, f))).max()) for f in ("v", "rho_f", "xi", "phi")}
    row["steps"] = [int(info["steps"]), sim.total_steps]
    out["sim"] = row
print("@@" + json.dumps(out))
"""


def _run_devices(specs, sim=False):
    code = f"SPECS = {specs!r}\nSIM = {sim!r}\n" + _SCRIPT
    env = dict(os.environ, PYTHONPATH=str(SRC),
               XLA_FLAGS="--xla_force_host_platform_device_count=4")
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                       timeout=1800)
    for line in r.stdout.splitlines():
        if line.startswith("@@"):
            return json.loads(line[2:])
    raise AssertionError(f"sharded run failed:\n{r.stdout[-2000:]}\n{r.stderr[-4000:]}")


def _check(res, names):
    for name in names:
        row = res[name]
        assert row["steps"] >= 30, row  # enough steps for a stencil/halo error to show
        for key, val in row.items():
            if key != "steps":
                assert val <= TOL, (name, key, val)
    if "sim" in res:
        sim = res["sim"]
        assert sim["steps"][0] == sim["steps"][1] > 0, sim
        for key in ("v", "rho_f", "xi", "phi"):
            assert sim[key] <= TOL, (key, sim[key])


# Each default test takes 20-60 s on the 2-core machine, nearly all of it compiling the
# step for 1, 2 and 4 devices (the runs themselves are 40-50 steps at 32^2).


def test_sharded_rotor_equals_one_device():
    # open edges, an inflow edge (where ENO ties are structural), a pivot anchor (a global
    # sum) and the implicit viscous solve (global dot products): 33 steps at 32^2 on 2 and
    # 4 devices, and a Simulation with devices=2
    _check(_run_devices([("rotor", 32, 0.25)], sim=True), ["rotor"])


def test_sharded_incompressible_equals_one_device():
    # the incompressible fluid carries its pressure in the state (State.p, sharded like
    # rho_f), and its projection's CG sums over the whole grid: the circle at 32^2 with the
    # Jacobi pressure preconditioner, 59 steps on 2 and 4 devices (measured on 2: v 3e-15,
    # p 4e-14 relative).  The default "fast" (FFT) preconditioner fails under sharding in
    # XLA's CPU FFT (fft_thunk: IsMonotonicWithDim0Major), before and after State.p.
    num = {"fluid_model": "incompressible", "pressure_preconditioner": "jacobi"}
    _check(_run_devices([("circle", 32, 0.05, num)]), ["circle"])


def test_sharded_two_balls_equals_one_device():
    # two solids, contact, a region anchor and a ramped inflow, with the implicit viscous
    # solve (held nodes fixed in it): 35 steps at 32^2 on 2 and 4 devices
    _check(_run_devices([("two_balls", 32, 0.45)]), ["two_balls"])


def test_sharded_3d_equals_one_device():
    # the 3D step split along x (the same partition spec: components first, then x): the
    # cross on its axle (a global sum) with its flow through two faces, 16x16x8, on 2 and
    # 4 devices (measured: sphere_relax on 2 devices differs by 2e-16)
    _check(_run_devices([("cross", 16, 0.3)]), ["cross"])


@pytest.mark.slow
def test_sharded_equals_one_device_longer():
    # hundreds of steps at 64^2 (the round-off of the split sums must not grow)
    res = _run_devices([("rotor", 64, 0.5), ("two_balls", 64, 0.3), ("circle", 64, 0.1)], sim=True)
    _check(res, ["rotor", "two_balls", "circle"])


def test_eno_ties_go_centred():
    # next to a prescribed-velocity edge the ghosts are g1 = 2U - u0, g2 = 2U - u1, and both
    # smoothness indicators of the backward ENO difference at u0 equal |2U + u1 - 3 u0|
    # exactly; a plain ``>`` picks the stencil by round-off and the two stencils differ
    # by O(1) here (the rotor's inflow: u_x = -4.7 against -1.6).  Ties must go centred.
    U, u0, u1 = 0.2, 3.6605435383917917e-03, 1.1878933389856412e-05
    f1, f0, fm1, fm2 = u1, u0, 2 * U - u0, 2 * U - u1
    centred = f1 - fm1
    for eps in (0.0, 1e-17, -1e-17, 4e-16, -4e-16):
        got = float(_eno2(jnp.asarray(f1), jnp.asarray(f0 + eps), jnp.asarray(fm1), jnp.asarray(fm2)))
        assert got == pytest.approx(centred + eps, abs=1e-15)
    # a real difference in smoothness still picks the one-sided stencil (3 p1 - 4 p2 + p3)
    p = np.array([0.0, 1.0, 1.5, 1.75])  # smoother towards p3: |p1 - 2 p2 + p3| = 0.25 < 0.5
    got = float(_eno2(*map(jnp.asarray, p)))
    assert got == pytest.approx(3 * p[1] - 4 * p[2] + p[3], abs=1e-15)


def test_bad_device_counts():
    with pytest.raises(ValueError, match=r"nx = 30 is not divisible by devices = 4.*28 or 32"):
        check_devices(4, nx=30)
    for bad in (0, -2, 1.5, True, "2"):
        with pytest.raises(ValueError, match="devices must be an integer >= 1"):
            check_devices(bad)
    with pytest.raises(ValueError, match="JAX sees only 1 cpu device"):
        check_devices(10**6, nx=10**6)
    # Simulation and shard_state refuse before compiling anything
    case = get_case("rotor", 30)
    with pytest.raises(ValueError, match="nx = 30 is not divisible by devices = 4"):
        Simulation(case, None, progress=False, pictures=False, devices=4)
    model, params = case.build()
    with pytest.raises(ValueError, match="nx = 30 is not divisible by devices = 4"):
        shard_state(model.initial_state(params), 4)
    assert check_devices(1, nx=30) == 1


def test_cli_rejects_indivisible_grid(tmp_path):
    from typer.testing import CliRunner

    from refmap.cli import app

    out = tmp_path / "run"
    r = CliRunner().invoke(app, ["run", "rotor", "--n", "30", "--devices", "4", "--out", str(out),
                                 "--no-progress"])
    assert r.exit_code == 2, r.output
    assert "nx = 30 is not divisible by devices = 4" in r.output
    assert not out.exists() or not any(out.iterdir())
