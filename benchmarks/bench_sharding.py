"""Wall time per step of the rotor with its grid split over 1, 2, 4 devices (refmap.sharding).

On a CPU the devices are virtual (``--xla_force_host_platform_device_count``, set here
before JAX starts); XLA runs each device's part on its own thread, so on a machine with
several cores a split can use them where the one-device step does not.  With
``--single-thread`` every device computes on one thread (``intra_op_parallelism_threads=1``
and no Eigen thread pool), so 1 device uses one core and D devices up to D cores: the
split's own speed-up.  Without it the one-device step may already use all cores through
XLA's intra-op threads.

Usage: python benchmarks/bench_sharding.py [--sizes 128,256] [--devices 1,2] [--steps 20]
       [--reps 3] [--single-thread] [--smooth-sweeps 80]
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def _args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="128,256")
    ap.add_argument("--devices", default="1,2")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--single-thread", action="store_true")
    ap.add_argument("--smooth-sweeps", type=int, default=80,
                    help="fixed smoothing sweeps (0: the adaptive rule)")
    return ap.parse_args(argv)


def main(argv=None) -> int:
    a = _args(argv)
    devices = [int(d) for d in a.devices.split(",")]
    flags = [f"--xla_force_host_platform_device_count={max(devices)}"]
    if a.single_thread:
        flags += ["--xla_cpu_multi_thread_eigen=false", "intra_op_parallelism_threads=1"]
    if "jax" in sys.modules:
        raise RuntimeError("run as a script: XLA_FLAGS must be set before JAX is imported")
    os.environ["XLA_FLAGS"] = " ".join(flags + [os.environ.get("XLA_FLAGS", "")]).strip()

    from dataclasses import replace

    import jax
    import numpy as np

    import refmap  # noqa: F401
    from refmap.scenarios import get_case
    from refmap.sharding import gather_state, shard_state, sharded_run_steps

    print(f"backend {jax.default_backend()}, {jax.device_count()} devices, {os.cpu_count()} CPUs, "
          f"XLA_FLAGS={os.environ['XLA_FLAGS']!r}")
    print(f"{'n':>6} {'devices':>8} {'compile [s]':>12} {'ms/step':>9} {'Mcell-upd/s':>12} "
          f"{'speed-up':>9} {'max |diff|':>11}")
    for n in (int(s) for s in a.sizes.split(",")):
        # the explicit viscous step, as in docs/parallel.md's figures
        case = get_case("rotor", n)
        case = case.replace(numerics=replace(case.numerics, viscosity="explicit"))
        if a.smooth_sweeps:
            case = case.replace(numerics=replace(case.numerics, fixed_smooth_sweeps=a.smooth_sweeps))
        model, params = case.build()
        state = jax.jit(lambda s, model=model, params=params: model.run_steps(s, params, 5))(
            model.initial_state(params))
        dt = model.time_step(state, params)[0]
        base = ref = None
        for d in devices:
            run = sharded_run_steps(model, d, a.steps, dt=dt)
            s0 = shard_state(state, d)
            t0 = time.perf_counter()
            out = jax.block_until_ready(run(s0, params))
            first = time.perf_counter() - t0
            best = float("inf")
            for _ in range(a.reps):
                t0 = time.perf_counter()
                out = jax.block_until_ready(run(s0, params))
                best = min(best, time.perf_counter() - t0)
            v = np.asarray(gather_state(out).v)
            ref = v if ref is None else ref
            base = best if base is None else base
            print(f"{n:>6} {d:>8} {first - best:>12.2f} {best / a.steps * 1e3:>9.2f} "
                  f"{n * n * a.steps / best / 1e6:>12.2f} {base / best:>9.2f} "
                  f"{np.abs(v - ref).max():>11.1e}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
