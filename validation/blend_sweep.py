"""Every scenario with every blend kernel: which kernels keep the runs healthy (issue 10).

For each scenario (the built-in ones and the example case files) and each blend kernel and
width, the run goes to the scenario's end time at ``--n`` cells and is inspected at
``--checks`` evenly spaced times.  Per run it records

* ``ok``: finished without a blow-up (non-finite field, collapsing dt or runaway speed),
  and the time it stopped at otherwise;
* ``wrinkle``: the largest, over the checks and the solids, 99th percentile of
  ``|h lap(phi)|`` on the nodes next to the zero contour (``|phi| < h``).  A smooth
  interface of curvature kappa gives ``h kappa`` (0.08 for a disc of radius 0.8 at 64^2 on
  the [-2, 2] box); wrinkles a cell long give values of order one;
* ``checker``: the largest ratio of the odd-even part of the velocity and of the fluid
  density to their variation: ``rms(D f) / (max f - min f)`` with ``D`` the 3 x 3 stencil
  ``d_xx d_yy / 16`` (amplitude 1 on a pure checkerboard, ``O((k h)^4)`` on smooth fields);
* ``min_gap`` / ``overlap``: for cases with contact, the smallest gap between two solids
  or a solid and a wall, in cells, and the largest overlap area in cells^2;
* ``area``: the largest relative change of a solid's blurred area (its solid fractions'
  sum) from t = 0 over the checks, signed (the swelling of issue 15 item 4 shows here);
* ``x_end``, ``y_end``: the first solid's centroid at the end (to see how far the kernels
  change the physics) and the run's wall time.

Usage::

    python validation/blend_sweep.py --n 64 --out sweep.jsonl          # everything
    python validation/blend_sweep.py --only rotor,stick --kernels erf:2,sine:1.5
    python validation/blend_sweep.py --table sweep.jsonl               # print the table

Each finished run is appended to the JSON-lines file at once, so an interrupted sweep keeps
what it did (and a rerun skips the runs already there).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import jax
import numpy as np

import refmap  # noqa: F401  (enables float64)
from refmap.blend import parse_kernel
from refmap.casefile import load_case
from refmap.scenarios import SCENARIOS, get_case

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ("flap_valve", "ring", "spinning_square")
KERNELS = ("erf:2", "sine:2.5", "sine:2", "sine:1.5", "sine:1")


def _case(name: str, n: int):
    if name in SCENARIOS:
        return get_case(name, n)
    return load_case(ROOT / "examples" / f"{name}.toml", {"n": n})


def _checker(f):
    f = np.asarray(f)
    d = (
        f[:-2, :-2] - 2 * f[1:-1, :-2] + f[2:, :-2]
        - 2 * (f[:-2, 1:-1] - 2 * f[1:-1, 1:-1] + f[2:, 1:-1])
        + f[:-2, 2:] - 2 * f[1:-1, 2:] + f[2:, 2:]
    ) / 16.0
    span = float(f.max() - f.min())
    return float(np.sqrt(np.mean(d**2)) / span) if span > 1e-14 else 0.0


def _wrinkle(phi, dx, dy, h):
    worst = 0.0
    for p in np.asarray(phi):
        lap = (p[2:, 1:-1] - 2 * p[1:-1, 1:-1] + p[:-2, 1:-1]) / dx**2 + (
            p[1:-1, 2:] - 2 * p[1:-1, 1:-1] + p[1:-1, :-2]
        ) / dy**2
        near = np.abs(p[1:-1, 1:-1]) < h
        if near.any():
            worst = max(worst, float(np.percentile(np.abs(h * lap[near]), 99)))
    return worst


def run_one(name: str, kernel: str, width: float, n: int, checks: int, t_end=None) -> dict:
    case = _case(name, n)
    if t_end is not None:
        case = case.replace(t_end=float(t_end))
    case = case.replace(numerics=dataclasses.replace(case.numerics, blend=kernel, blur_width=width))
    model, params = case.build()
    state = jax.jit(model.initial_state)(params)
    g = model.grid
    speeds = case.velocity_scales()
    limit = 10.0 * max([abs(float(v)) for v in speeds.values()] + [1e-3])
    adv = jax.jit(lambda s, t: model.advance(s, params, t, speed_limit=limit))
    diag = jax.jit(lambda s: model.diagnostics(s, params))
    row = dict(case=name, kernel=kernel, width=width, n=n, t_end=case.t_end, ok=True, t_stop=case.t_end,
               wrinkle=0.0, checker=0.0, min_gap=math.inf, overlap=0.0, steps=0, area=0.0)
    area0 = [float(so["area"]) for so in diag(state).get("solids", [])]
    t0 = time.perf_counter()
    for k in range(1, checks + 1):
        t = case.t_end * k / checks
        state, info = adv(state, t)
        row["steps"] += int(info["steps"])
        if not bool(info["ok"]):
            row.update(ok=False, t_stop=float(state.t))
            break
        row["wrinkle"] = max(row["wrinkle"], _wrinkle(state.phi, g.dx, g.dy, model.h))
        row["checker"] = max(row["checker"], _checker(state.v[0]), _checker(state.v[1]),
                             _checker(state.rho_f))
        d = diag(state)
        if "contact_min_gap" in d:
            row["min_gap"] = min(row["min_gap"], float(d["contact_min_gap"]) / model.h)
        for key in ("contact_overlap_area", "overlap_area"):
            if key in d:
                row["overlap"] = max(row["overlap"], float(np.max(d[key])) / model.h**2)
        for a0, so in zip(area0, d.get("solids", []), strict=True):
            da = float(so["area"]) / a0 - 1.0 if a0 > 0 else 0.0
            if abs(da) > abs(row["area"]):
                row["area"] = da
        if d.get("solids"):
            row["x_end"] = float(d["solids"][0]["centroid_x"])
            row["y_end"] = float(d["solids"][0]["centroid_y"])
    row["wall_s"] = time.perf_counter() - t0
    if not math.isfinite(row["min_gap"]):
        row["min_gap"] = None
    return row


def table(rows) -> str:
    head = ("| case | kernel | ok | wrinkle | checker | min gap (h) | overlap (h²) | area change "
            "| centroid at end | steps | wall (s) |")
    out = [head, "|" + "---|" * 11]
    for r in rows:
        ok = "yes" if r["ok"] else f"**blew up** t = {r['t_stop']:.3g}"
        gap = "" if r.get("min_gap") is None else f"{r['min_gap']:.2f}"
        ov = f"{r['overlap']:.2f}" if r.get("min_gap") is not None else ""
        cen = f"({r['x_end']:.3f}, {r['y_end']:.3f})" if "x_end" in r else ""
        area = f"{r['area']:+.1%}" if "area" in r else ""
        out.append(
            f"| {r['case']} | {r['kernel']} {r['width']:g} | {ok} | {r['wrinkle']:.3f} | "
            f"{r['checker']:.1e} | {gap} | {ov} | {area} | {cen} | {r['steps']} | {r['wall_s']:.0f} |"
        )
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=64)
    ap.add_argument("--checks", type=int, default=10)
    ap.add_argument("--only", default=None, help="comma-separated case names")
    ap.add_argument("--kernels", default=",".join(KERNELS), help="kernel:width, comma-separated")
    ap.add_argument("--t-end", type=float, default=None, help="end time (default: each case's)")
    ap.add_argument("--out", default="blend_sweep.jsonl")
    ap.add_argument("--table", default=None, help="print the table of a results file and stop")
    a = ap.parse_args(argv)
    if a.table:
        print(table([json.loads(x) for x in Path(a.table).read_text().splitlines() if x.strip()]))
        return
    names = a.only.split(",") if a.only else list(SCENARIOS) + list(EXAMPLES)
    kernels = [parse_kernel(kw) for kw in a.kernels.split(",")]
    out = Path(a.out)
    done = set()
    if out.exists():
        for x in out.read_text().splitlines():
            if x.strip():
                r = json.loads(x)
                done.add((r["case"], r["kernel"], r["width"], r["n"]))
    for k, w in kernels:
        for name in names:
            if (name, k, w, a.n) in done:
                continue
            r = run_one(name, k, w, a.n, a.checks, a.t_end)
            print(json.dumps(r), flush=True)
            with out.open("a") as f:
                f.write(json.dumps(r) + "\n")


if __name__ == "__main__":
    main()
