"""Cost of a reverse-mode gradient through a run, relative to the forward run (issue 13).

For each grid size and step count: the forward run (``refmap.differentiable.rollout``, no
rematerialisation, loss only) and the gradient of the loss with respect to the parameters
and the initial velocity, with ``checkpoint="sqrt"`` (nested scan, ~sqrt(n) chunks, every
chunk and step rematerialised), ``"nested"`` with k levels (named ``nested3``,
``nested4``, ...: k nested scans of ~n^(1/k) steps), ``"binomial"`` with s snapshots
(named ``binomial13``, ...: Griewank's revolve schedule in a custom VJP), ``"step"`` and
``None`` (no rematerialisation).  The ``states`` column is the number of states the strategy's
backward pass keeps by construction (``"sqrt"``: outer plus inner scan lengths;
``nested``: the sum of its scan lengths; ``binomial``: s + 1, the snapshots and the state
before the last step; ``"step"``: n).

* Memory: the compiled executables' ``memory_analysis()`` (XLA's temporary buffers plus
  arguments and outputs), so no run is needed: the 10000-step figures are exact for what
  XLA allocates, without running 10000 steps.
* Time: CPU time of this process (``time.process_time``: on a shared machine the wall
  time varies with the other jobs), best of ``--reps`` after a warm-up run, measured only
  for step counts up to ``--time-steps`` (each run that long is timed).

Case: the thesis's circle (a sheared disc relaxing in a closed box, one solid,
fixed smoothing sweeps), step size the adaptive one of the initial state, held constant.

    python benchmarks/bench_gradient.py --quick          # 32^2, 20 and 100 steps
    python benchmarks/bench_gradient.py                  # 64^2 and 128^2, 100/1000/10000
    python benchmarks/bench_gradient.py --sizes 64 --steps 100 1000 --time-steps 100
    python benchmarks/bench_gradient.py --sizes 128 --steps 10000 --time-steps 0 \
        --strategies sqrt nested3 nested4 nested6 binomial13      # memory only

Targets (issue 13): gradient time <= 10x forward, memory <= 4x forward at 10000 steps, 128^2.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import jax
import jax.numpy as jnp

import refmap  # noqa: F401
from refmap import differentiable as rd
from refmap.scenarios import get_case

STRATEGIES = ("sqrt", "nested3", "nested4", "binomial13", "step", "none")


def _strategy(name):
    """``(checkpoint, levels or snapshots)`` of a strategy name: sqrt, step, none, nestedK,
    binomialS."""
    if name in (None, "none"):
        return None, 3
    if name in ("sqrt", "step"):
        return name, 3
    if name.startswith("nested") and name[6:].isdigit() and int(name[6:]) >= 1:
        return "nested", int(name[6:])
    if name.startswith("binomial") and name[8:].isdigit() and int(name[8:]) >= 1:
        return "binomial", int(name[8:])
    raise ValueError(f"unknown strategy {name!r}; use sqrt, step, none, nestedK or binomialS "
                     "(K, S >= 1)")


def _states(name, steps):
    """The number of states the backward pass of strategy ``name`` keeps by construction."""
    ck, levels = _strategy(name)
    if ck == "sqrt":
        chunk, n_full, rem = rd._chunks(steps, "sqrt")
        return n_full + chunk  # the outer carries, then one chunk's inner carries
    if ck == "nested":
        return sum(rd.nested_chunks(steps, levels))
    if ck == "binomial":
        return levels + 1
    return steps if ck == "step" else 0


def _bytes(compiled):
    m = compiled.memory_analysis()
    if m is None:
        return math.nan, math.nan
    temp = m.temp_size_in_bytes
    total = temp + m.argument_size_in_bytes + m.output_size_in_bytes - m.alias_size_in_bytes
    return temp, total


def _time(fn, args, reps):
    jax.block_until_ready(fn(*args))  # warm-up (and compile, if not done)
    best = math.inf
    for _ in range(reps):
        t0 = time.process_time()
        jax.block_until_ready(fn(*args))
        best = min(best, time.process_time() - t0)
    return best


def circle(n, band_sweeps=None):
    """The circle case at ``n``^2, with ``Numerics.band_sweeps`` replaced if given."""
    case = get_case("circle", max(n, 16))
    if band_sweeps is not None:
        case = dataclasses.replace(case, numerics=dataclasses.replace(case.numerics,
                                                                      band_sweeps=band_sweeps))
    return case


def bench(n, steps, time_steps, reps, strategies, band_sweeps=None):
    model, state, params = rd.from_case(circle(n, band_sweeps))
    dt = rd.stable_dt(model, state, params)

    def loss(s):
        return jnp.sum(s.v**2) + jnp.sum(s.rho_f**2)

    def forward(params, v):
        return rd.rollout(model, state.replace(v=v), params, steps, dt, loss=loss,
                          checkpoint=None).loss

    args = (params, state.v)
    t0 = time.perf_counter()
    fwd = jax.jit(forward).lower(*args).compile()
    c_fwd = time.perf_counter() - t0
    fwd_temp, fwd_total = _bytes(fwd)
    run = steps <= time_steps
    t_fwd = _time(fwd, args, reps) if run else math.nan
    rows = []
    state_mib = sum(a.size * a.dtype.itemsize for a in jax.tree_util.tree_leaves(state)) / 2**20
    for name in strategies:
        ck, levels = _strategy(name)

        def f(params, v, ck=ck, levels=levels):
            return rd.rollout(model, state.replace(v=v), params, steps, dt, loss=loss,
                              checkpoint=ck, levels=levels, snapshots=levels).loss

        t0 = time.perf_counter()
        grad = jax.jit(jax.grad(f, argnums=(0, 1))).lower(*args).compile()
        c_grad = time.perf_counter() - t0
        temp, total = _bytes(grad)
        t_grad = _time(grad, args, reps) if run else math.nan
        rows.append(dict(n=n, steps=steps, checkpoint=str(name), fwd_s=t_fwd, grad_s=t_grad,
                         states=_states(name, steps), state_mib=state_mib,
                         time_ratio=t_grad / t_fwd, fwd_mib=fwd_total / 2**20,
                         grad_mib=total / 2**20, mem_ratio=total / fwd_total,
                         fwd_temp_mib=fwd_temp / 2**20, grad_temp_mib=temp / 2**20,
                         compile_fwd_s=c_fwd, compile_grad_s=c_grad))
        r = rows[-1]
        print(f"{n:>5} {steps:>6} {r['checkpoint']:>8} {r['fwd_s']:>9.3f} {r['grad_s']:>9.3f} "
              f"{r['time_ratio']:>6.2f} {r['fwd_mib']:>9.2f} {r['grad_mib']:>10.2f} "
              f"{r['mem_ratio']:>7.2f} {r['states']:>7} {state_mib * r['states']:>9.2f} "
              f"{c_grad:>8.1f}", flush=True)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="32^2, 20 and 100 steps, all timed")
    ap.add_argument("--sizes", type=int, nargs="+", default=None, help="grid sizes (64 128)")
    ap.add_argument("--steps", type=int, nargs="+", default=None, help="steps (100 1000 10000)")
    ap.add_argument("--time-steps", type=int, default=None,
                    help="time runs of at most this many steps (default 100; quick: all)")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--strategies", nargs="+", default=None,
                    help="checkpoint strategies among sqrt nestedK binomialS step none "
                         "(default sqrt nested3 nested4 binomial13 step none)")
    ap.add_argument("--band-sweeps", choices=("auto", "band", "grid"), default=None,
                    help="Numerics.band_sweeps of the circle (default: the scenario's, auto)")
    a = ap.parse_args(argv)
    sizes = a.sizes or ([32] if a.quick else [64, 128])
    steps = a.steps or ([20, 100] if a.quick else [100, 1000, 10000])
    time_steps = a.time_steps if a.time_steps is not None else (max(steps) if a.quick else 100)
    strategies = STRATEGIES if a.strategies is None else tuple(a.strategies)
    for s in strategies:
        try:
            _strategy(s)
        except ValueError as e:
            ap.error(str(e))
    print(f"backend {jax.default_backend()}, circle scenario (band_sweeps "
          f"{a.band_sweeps or 'default'}), CPU time best of {a.reps}; "
          f"memory from memory_analysis() (temporaries + arguments + outputs)")
    print(f"{'n':>5} {'steps':>6} {'ckpt':>8} {'fwd [s]':>9} {'grad [s]':>9} {'ratio':>6} "
          f"{'fwd MiB':>9} {'grad MiB':>10} {'mem x':>7} {'states':>7} {'st. MiB':>9} "
          f"{'compile':>8}")
    rows = []
    for n in sizes:
        for k in steps:
            rows += bench(n, k, time_steps, a.reps, strategies, a.band_sweeps)
    return rows


if __name__ == "__main__":
    main()
