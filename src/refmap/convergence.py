"""Grid-convergence studies: run a ladder of grids to a common time and measure observed orders.

Usage (see also ``refmap convergence --help``)::

    from refmap.convergence import run_ladder, analyse, format_table
    paths = run_ladder("rotor", [60, 72, 90, 120, 180], ref=360, t_end=4.0, out="runs/conv")
    study = analyse(paths, ref_path)

How it works
------------
* **Rungs.**  Every grid of the ladder (and the reference) is the registered scenario's case
  built with that ``n`` and run to the same ``t_end``.  The final state is saved as
  ``SCENARIO_nN.npz`` (prognostic fields ``v``, ``rho_f``, ``xi``, ``phi`` plus a JSON
  header).  A rung counts as finished only when that file exists: it is written under a
  temporary name and renamed, so an interrupted write never looks finished.  Finished rungs
  are reused, not recomputed.  A long rung also leaves ``SCENARIO_nN.partial.npz`` behind
  every ``checkpoint_s`` seconds of wall time and continues from it when restarted; the
  chunk boundaries in simulated time are fixed, so a resumed rung is bit for bit the
  uninterrupted one.
* **Common points.**  Every run is compared on the nodes (cell centres) of the *coarsest*
  grid.  Those points lie inside the node hull of every finer grid on the same domain
  (they are at least h_coarse / 2 from the edge, the finer nodes reach to h_fine / 2), so
  bilinear interpolation from the finer grids never extrapolates.  The coarsest grid is
  sampled exactly; for odd refinement ratios (60 -> 180) the coarse nodes coincide with fine
  nodes, for even ones (60 -> 120, 360) they sit midway between them.  Bilinear
  interpolation is exact for bilinear fields and second-order accurate for smooth ones,
  below the first-to-second-order errors being measured.
* **Norms.**  The discrete L2 norm of the thesis (eq. 4.30),
  ``||f - f_ref|| = sqrt(sum_ij (f[ij] - f_ref(x_ij, y_ij))^2 dx dy)``, with dx dy the
  coarsest grid's cell area, and the max norm.  Velocity (``u``, ``v``) is compared at every
  common point; the reference map (``xi_x``, ``xi_y``) and its gradient (``grad_xi``, the
  four components together; central differences on each run's own nodes) only where every
  run and the reference have the solid: phi < -margin * h_coarse in all of them.
* **Orders.**  A least-squares line through (log h, log error) over all rungs, and the
  pairwise orders log(e_i / e_j) / log(h_i / h_j) of neighbouring rungs.  Both treat the
  reference as exact; a reference only 2x finer than the finest rung inflates them (with a
  true order 1, rungs 60-180 against 360 give a slope of 1.46).  So the order p of the model
  error = C (h^p - h_ref^p), which allows for the reference's own error when every run errs
  with one sign, is fitted as well (``fit_order_with_reference``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time as _time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from refmap.grid import Grid

QUANTITIES = ("u", "v", "xi_x", "xi_y", "grad_xi")
SOLID_QUANTITIES = ("xi_x", "xi_y", "grad_xi")
FORMAT_VERSION = 1


class ConvergenceError(ValueError):
    """Bad input to a convergence study, or a rung that cannot be used."""


# ---------------------------------------------------------------------- input checks
def parse_grids(text) -> list[int]:
    """``"60,72,90"`` (or a sequence) -> sorted distinct ints; ConvergenceError otherwise."""
    items = text.split(",") if isinstance(text, str) else list(text)
    out = []
    for it in items:
        s = str(it).strip()
        if not s:
            raise ConvergenceError(f"empty entry in the grid list {text!r}")
        try:
            n = int(s)
        except ValueError:
            raise ConvergenceError(f"grid sizes must be integers, got {s!r} in {text!r}") from None
        if isinstance(it, float) and not float(it).is_integer():
            raise ConvergenceError(f"grid sizes must be integers, got {it!r}")
        out.append(n)
    if len(out) < 2:
        raise ConvergenceError(f"a ladder needs at least two grids, got {out}")
    if len(set(out)) != len(out):
        raise ConvergenceError(f"repeated grid size in {out}")
    return sorted(out)


def _with_numerics(case, viscosity: str | None, kernel: str | None = None):
    """``case`` with its viscous step and its blend kernel replaced (None: the scenario's
    own).  ``kernel`` is a ``"KERNEL:WIDTH"`` spec (``"sine:1"``: the sine kernel of
    half-width 1 h; :func:`refmap.blend.parse_kernel`).  A bad value gets
    :class:`refmap.state.Numerics`' own error, as a :class:`ConvergenceError`."""
    from refmap.blend import parse_kernel

    changes = {}
    try:
        if viscosity is not None:
            changes["viscosity"] = viscosity
        if kernel is not None:
            changes["blend"], changes["blur_width"] = parse_kernel(kernel)
        if not changes:
            return case
        return case.replace(numerics=dataclasses.replace(case.numerics, **changes))
    except ValueError as e:
        raise ConvergenceError(str(e)) from None


def check_study(
    scenario: str,
    grids,
    ref: int,
    t_end: float | None,
    viscosity: str | None = None,
    kernel: str | None = None,
):
    """Validate everything before any run; returns (grids, ref, t_end, {n: case}).
    ``viscosity``, ``kernel``: as in :func:`run_rung`."""
    from refmap.case import CaseError
    from refmap.scenarios import SCENARIOS, get_case

    if scenario not in SCENARIOS:
        raise ConvergenceError(
            f"unknown scenario {scenario!r}; available: {', '.join(sorted(SCENARIOS))}"
        )
    grids = parse_grids(grids)
    if isinstance(ref, bool) or not isinstance(ref, (int, np.integer)):
        raise ConvergenceError(f"the reference grid must be an integer, got {ref!r}")
    ref = int(ref)
    if ref <= max(grids):
        raise ConvergenceError(
            f"the reference grid ({ref}) must be finer than every grid of the ladder (finest {max(grids)})"
        )
    cases = {}
    for n in [*grids, ref]:
        try:
            case = _with_numerics(get_case(scenario, n), viscosity, kernel)
            if t_end is not None:
                case = case.replace(t_end=float(t_end))
            cases[n] = case.validate()
        except CaseError as e:
            raise ConvergenceError(f"grid {n}: {e}") from None
    t_end = cases[ref].t_end
    doms = {(c.grid.ax, c.grid.bx, c.grid.ay, c.grid.by) for c in cases.values()}
    if len(doms) != 1:
        raise ConvergenceError(
            f"the scenario's domain changes with n ({sorted(doms)}); cannot compare"
        )
    return grids, ref, float(t_end), cases


# ---------------------------------------------------------------------- one rung
def rung_path(out, scenario: str, n: int) -> Path:
    return Path(out) / f"{scenario}_n{n}.npz"


def _partial_path(out, scenario: str, n: int) -> Path:
    return Path(out) / f"{scenario}_n{n}.partial.npz"


def _atomic_savez(path: Path, header: dict, arrays: dict):
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    with open(tmp, "wb") as f:
        np.savez(f, header=np.asarray(json.dumps(header)), **arrays)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def load_rung(path) -> dict:
    """A saved rung: dict with ``header`` (dict) and the arrays."""
    with np.load(path, allow_pickle=False) as z:
        out = {k: z[k] for k in z.files if k != "header"}
        out["header"] = json.loads(str(z["header"]))
    return out


def _state_arrays(state, model) -> dict:
    state = model.on_grid(state)  # solids stored in windows: the rung holds grid fields
    out = {k: np.asarray(getattr(state, k)) for k in ("t", "step", "v", "rho_f", "xi", "phi")}
    if state.p is not None:  # the incompressible fluid's pressure (State.p)
        out["p"] = np.asarray(state.p)
    return out


# what rungs written before the header named them were run with
_OLD_HEADER = dict(viscosity="explicit", blend="erf", blur_width=2.0)


def _check_header(h: dict, path: Path, scenario: str, n: int, t_end: float, numerics: dict):
    want = dict(scenario=scenario, n=n, t_end=t_end, **numerics)
    got = {k: h.get(k, _OLD_HEADER.get(k)) for k in want}
    if got != want:
        raise ConvergenceError(
            f"{path} holds {got}, not {want}; use another output folder or delete the file"
        )


def run_rung(
    scenario: str,
    n: int,
    t_end: float,
    out,
    *,
    n_chunks: int = 40,
    checkpoint_s: float = 120.0,
    log=None,
    stop_after_chunks: int | None = None,
    viscosity: str | None = None,
    kernel: str | None = None,
) -> dict:
    """Run one rung to ``t_end`` (or reuse the finished file); returns a summary dict.

    ``viscosity`` ("explicit" or "implicit") replaces the scenario's viscous step and
    ``kernel`` (``"sine:1"``, ``"erf:2"``) its blend (None: the scenario's own); both are
    recorded in the rung's header, and a finished rung made with other ones is refused.
    ``stop_after_chunks`` (tests only) stops early after that many chunks, leaving a
    partial checkpoint, to exercise the restart.
    """
    import jax
    import jax.numpy as jnp

    from refmap.scenarios import get_case
    from refmap.state import State

    log = log or (lambda msg: print(msg, flush=True))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    final = rung_path(out, scenario, n)
    case = _with_numerics(get_case(scenario, n), viscosity, kernel).replace(t_end=float(t_end))
    numerics = dict(
        viscosity=case.numerics.viscosity,
        blend=case.numerics.blend,
        blur_width=float(case.numerics.blur_width),
    )
    if final.exists():
        h = load_rung(final)["header"]
        _check_header(h, final, scenario, n, t_end, numerics)
        return dict(n=n, path=str(final), reused=True, steps=h["steps"], wall_s=h["wall_s"])

    model, params = case.build()
    partial = _partial_path(out, scenario, n)
    times = np.linspace(0.0, t_end, n_chunks + 1)[1:]
    if partial.exists():
        z = load_rung(partial)
        h = z["header"]
        _check_header(h, partial, scenario, n, t_end, numerics)
        if h.get("n_chunks") != n_chunks:
            raise ConvergenceError(
                f"{partial} was written with {h.get('n_chunks')} chunks, not {n_chunks}"
            )
        state = State(
            t=jnp.asarray(z["t"]),
            step=jnp.asarray(z["step"]),
            v=jnp.asarray(z["v"]),
            rho_f=jnp.asarray(z["rho_f"]),
            xi=jnp.asarray(z["xi"]),
            phi=jnp.asarray(z["phi"]),
            p=jnp.asarray(z["p"]) if "p" in z else None,
        )
        state = model.adopt(state)
        first, steps, wall0 = int(h["chunks_done"]), int(h["steps"]), float(h["wall_s"])
        log(
            f"[{scenario} n={n}] continuing from t = {float(z['t']):.4g} (chunk {first}/{n_chunks})"
        )
    else:
        state = model.initial_state(params)
        first, steps, wall0 = 0, 0, 0.0
    advance = jax.jit(model.advance)
    header = dict(
        format=FORMAT_VERSION,
        scenario=scenario,
        n=n,
        t_end=float(t_end),
        **numerics,
        n_chunks=n_chunks,
        grid=dict(
            nx=case.grid.nx,
            ny=case.grid.ny,
            ax=case.grid.ax,
            bx=case.grid.bx,
            ay=case.grid.ay,
            by=case.grid.by,
        ),
    )
    t_start = _time.perf_counter()
    last_save = t_start
    for k in range(first, n_chunks):
        state, info = advance(state, params, float(times[k]))
        info = jax.device_get(info)
        steps += int(info["steps"])
        if not bool(info["ok"]):
            raise ConvergenceError(f"{scenario} n={n} blew up near t = {float(state.t):.4g}")
        wall = wall0 + _time.perf_counter() - t_start
        now = _time.perf_counter()
        done = k + 1
        if done < n_chunks and (now - last_save > checkpoint_s or done == stop_after_chunks):
            _atomic_savez(
                partial,
                {**header, "chunks_done": done, "steps": steps, "wall_s": wall},
                _state_arrays(state, model),
            )
            last_save = now
        if done % max(1, n_chunks // 10) == 0 or done == n_chunks:
            eta = (wall - wall0) / (done - first) * (n_chunks - done)
            log(
                f"[{scenario} n={n}] t = {float(state.t):.4g}/{t_end:g}, {steps} steps, "
                f"{wall:.0f} s, ETA {eta:.0f} s"
            )
        if stop_after_chunks is not None and done == stop_after_chunks and done < n_chunks:
            return dict(
                n=n, path=str(partial), reused=False, steps=steps, wall_s=wall, stopped=True
            )
    wall = wall0 + _time.perf_counter() - t_start
    from refmap import __version__

    _atomic_savez(
        final,
        {**header, "steps": steps, "wall_s": wall, "refmap": __version__, "t": float(state.t)},
        _state_arrays(state, model),
    )
    if partial.exists():
        partial.unlink()
    return dict(n=n, path=str(final), reused=False, steps=steps, wall_s=wall)


def _rung_worker(args):
    scenario, n, t_end, out, n_chunks, checkpoint_s, viscosity, kernel = args
    return run_rung(scenario, n, t_end, out, n_chunks=n_chunks, checkpoint_s=checkpoint_s,
                    viscosity=viscosity, kernel=kernel)


def run_ladder(
    scenario: str,
    grids,
    ref: int,
    t_end: float | None,
    out,
    *,
    jobs: int = 1,
    n_chunks: int = 40,
    checkpoint_s: float = 120.0,
    log=None,
    viscosity: str | None = None,
    kernel: str | None = None,
) -> dict[int, dict]:
    """Run (or reuse) every rung and the reference; returns {n: summary}.

    With ``jobs > 1`` the rungs run in that many separate processes (largest first, so the
    long reference starts at once); each process runs one rung on one core.  ``viscosity``,
    ``kernel``: as in :func:`run_rung`, for every rung.
    """
    grids, ref, t_end, _ = check_study(scenario, grids, ref, t_end, viscosity, kernel)
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ConvergenceError(f"jobs must be an integer >= 1, got {jobs!r}")
    log = log or (lambda msg: print(msg, flush=True))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    order = sorted([*grids, ref], reverse=True)
    results: dict[int, dict] = {}
    todo = []
    for n in order:
        p = rung_path(out, scenario, n)
        if p.exists():
            results[n] = run_rung(scenario, n, t_end, out, n_chunks=n_chunks, log=log,
                                  viscosity=viscosity, kernel=kernel)
            log(f"[{scenario} n={n}] finished earlier: {p}")
        else:
            todo.append(n)
    if jobs == 1 or len(todo) <= 1:
        for n in todo:
            results[n] = run_rung(
                scenario, n, t_end, out, n_chunks=n_chunks, checkpoint_s=checkpoint_s, log=log,
                viscosity=viscosity, kernel=kernel,
            )
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        ctx = mp.get_context("spawn")  # JAX is not fork-safe
        with ProcessPoolExecutor(max_workers=min(jobs, len(todo)), mp_context=ctx) as ex:
            futs = {
                n: ex.submit(
                    _rung_worker, (scenario, n, t_end, str(out), n_chunks, checkpoint_s, viscosity, kernel)
                )
                for n in todo
            }
            for n, f in futs.items():
                results[n] = f.result()
    for n in todo:
        r = results[n]
        log(f"[{scenario} n={n}] done: {r['steps']} steps in {r['wall_s']:.1f} s")
    return dict(sorted(results.items()))


# ---------------------------------------------------------------------- sampling and norms
def grid_of(header: dict) -> Grid:
    g = header["grid"]
    return Grid(
        int(g["nx"]), int(g["ny"]), float(g["ax"]), float(g["bx"]), float(g["ay"]), float(g["by"])
    )


def bilinear(values, grid: Grid, px, py):
    """Bilinear interpolation of node values (..., nx, ny) at points (px, py) (same shape).

    Points must lie inside the node hull [ax + dx/2, bx - dx/2] x [ay + dy/2, by - dy/2]
    (a small round-off tolerance is allowed); raises ValueError otherwise.
    """
    values = np.asarray(values, dtype=np.float64)
    px, py = np.asarray(px, dtype=np.float64), np.asarray(py, dtype=np.float64)
    fi = (px - grid.ax) / grid.dx - 0.5
    fj = (py - grid.ay) / grid.dy - 0.5
    tol = 1e-9
    if (
        fi.min() < -tol
        or fj.min() < -tol
        or fi.max() > grid.nx - 1 + tol
        or fj.max() > grid.ny - 1 + tol
    ):
        raise ValueError("bilinear: points outside the node hull of the grid")
    i0 = np.clip(np.floor(fi).astype(int), 0, grid.nx - 2)
    j0 = np.clip(np.floor(fj).astype(int), 0, grid.ny - 2)
    tx, ty = fi - i0, fj - j0
    f00 = values[..., i0, j0]
    f10 = values[..., i0 + 1, j0]
    f01 = values[..., i0, j0 + 1]
    f11 = values[..., i0 + 1, j0 + 1]
    return (1 - tx) * (1 - ty) * f00 + tx * (1 - ty) * f10 + (1 - tx) * ty * f01 + tx * ty * f11


def node_gradient(f, grid: Grid):
    """(d/dx, d/dy) of node values (nx, ny): central differences inside, one-sided at edges."""
    return np.gradient(np.asarray(f, dtype=np.float64), grid.dx, grid.dy)


def rung_fields(rung: dict, solid: int = 0) -> dict:
    """The compared fields of one rung on its own nodes: name -> (components, nx, ny), and phi."""
    g = grid_of(rung["header"])
    xi = rung["xi"][solid]
    gx = node_gradient(xi[0], g)
    gy = node_gradient(xi[1], g)
    return dict(
        u=rung["v"][0][None],
        v=rung["v"][1][None],
        xi_x=xi[0][None],
        xi_y=xi[1][None],
        grad_xi=np.stack([gx[0], gx[1], gy[0], gy[1]]),
        phi=rung["phi"][solid],
    )


def discrete_l2(diff, dA: float, mask=None) -> float:
    """sqrt(sum over points (and components) of diff^2 * dA) -- thesis eq. 4.30."""
    d = np.asarray(diff, dtype=np.float64)
    if d.ndim == 2:
        d = d[None]
    if mask is not None:
        d = d[:, mask]
    return float(np.sqrt(np.sum(d * d) * dA))


def max_norm(diff, mask=None) -> float:
    d = np.asarray(diff, dtype=np.float64)
    if d.ndim == 2:
        d = d[None]
    if mask is not None:
        d = d[:, mask]
    if d.size == 0:
        return float("nan")
    return float(np.max(np.abs(d)))


def fit_order(h, err) -> float:
    """Least-squares slope of log(err) against log(h)."""
    h, err = np.asarray(h, dtype=float), np.asarray(err, dtype=float)
    ok = (err > 0) & np.isfinite(err)
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(h[ok]), np.log(err[ok]), 1)[0])


def fit_order_with_reference(h, err, h_ref: float) -> float:
    """Order p of the model err = C (h^p - h_ref^p), least squares in log(err).

    When the reference is not much finer than the rungs its own error is not negligible:
    if every run's error is e(h) ~ C h^p with one sign (the asymptotic regime), the measured
    difference to the reference is C (h^p - h_ref^p), which falls faster than h^p near
    h_ref and inflates the plain log-log slope.  This fit removes that bias under that
    assumption (C is solved in closed form for each p; p is searched on [0.05, 6]).
    """
    h, err = np.asarray(h, dtype=float), np.asarray(err, dtype=float)
    ok = (err > 0) & np.isfinite(err) & (h > h_ref)
    if ok.sum() < 2:
        return float("nan")
    lh, le = np.log(h[ok]), np.log(err[ok])
    lr = math.log(h_ref)

    def resid(ps):
        ps = np.asarray(ps, dtype=float)[:, None]
        # log(h^p - h_ref^p) = p log h + log(1 - (h_ref/h)^p), stable for small p too
        g = ps * lh + np.log(-np.expm1(ps * (lr - lh)))
        c = np.mean(le - g, axis=1, keepdims=True)
        return np.sum((le - c - g) ** 2, axis=1)

    ps = np.linspace(0.05, 6.0, 5951)
    p0 = ps[np.argmin(resid(ps))]
    fine = np.linspace(max(0.05, p0 - 2e-3), p0 + 2e-3, 4001)
    return float(fine[np.argmin(resid(fine))])


def pairwise_orders(h, err) -> list[float]:
    """Orders between neighbouring rungs, log(e_i / e_{i+1}) / log(h_i / h_{i+1})."""
    h, err = np.asarray(h, dtype=float), np.asarray(err, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return [
            float(np.log(err[i] / err[i + 1]) / np.log(h[i] / h[i + 1])) for i in range(len(h) - 1)
        ]


@dataclass
class Study:
    """Errors and observed orders of a ladder against a reference."""

    scenario: str
    t_end: float
    grids: list[int]
    ref: int
    h: list[float]
    margin: float
    solid_points: int
    points: int
    errors: dict = field(default_factory=dict)  # quantity -> {"l2": [...], "max": [...]}
    orders: dict = field(default_factory=dict)  # quantity -> {"l2": fit, "max": fit}
    # quantity -> {"l2": p, "max": p} of err = C (h^p - h_ref^p) (fit_order_with_reference)
    orders_refcorr: dict = field(default_factory=dict)
    pairwise: dict = field(default_factory=dict)  # quantity -> {"l2": [...], "max": [...]}


def analyse(rungs, ref, *, margin: float = 1.0, solid: int = 0) -> Study:
    """Errors of every rung against the reference on the coarsest grid's nodes.

    ``rungs``: paths (or loaded dicts) of the ladder; ``ref``: the reference's.  ``margin``:
    the reference map and its gradient are compared only where phi < -margin * h_coarse in
    every run (the ladder's and the reference's).
    """
    runs = [load_rung(r) if not isinstance(r, dict) else r for r in rungs]
    refr = load_rung(ref) if not isinstance(ref, dict) else ref
    runs.sort(key=lambda r: r["header"]["n"])
    heads = [r["header"] for r in [*runs, refr]]
    scen = {h["scenario"] for h in heads}
    tends = {h["t_end"] for h in heads}
    if len(scen) != 1 or len(tends) != 1:
        raise ConvergenceError(
            f"the runs differ in scenario or t_end: {sorted(scen)}, {sorted(tends)}"
        )
    if len(runs) < 2:
        raise ConvergenceError("need at least two rungs to measure an order")
    grids = [grid_of(h) for h in heads]
    coarse = grids[0]
    if grids[-1].nx <= max(g.nx for g in grids[:-1]):
        raise ConvergenceError("the reference must be finer than every rung")
    X, Y = coarse.mesh("node")
    fields = [rung_fields(r, solid) for r in [*runs, refr]]
    sampled = [{k: bilinear(f[k], g, X, Y) for k in f} for f, g in zip(fields, grids, strict=True)]
    hc = coarse.h
    solid_mask = np.ones(X.shape, dtype=bool)
    for s in sampled:
        solid_mask &= s["phi"] < -margin * hc
    dA = coarse.cell_area
    ref_s = sampled[-1]
    st = Study(
        scenario=heads[0]["scenario"],
        t_end=float(heads[0]["t_end"]),
        grids=[g.nx for g in grids[:-1]],
        ref=grids[-1].nx,
        h=[g.h for g in grids[:-1]],
        margin=margin,
        solid_points=int(solid_mask.sum()),
        points=int(X.size),
    )
    if st.solid_points == 0:
        raise ConvergenceError(
            "no common point lies inside the solid in every run; lower the margin"
        )
    for q in QUANTITIES:
        mask = solid_mask if q in SOLID_QUANTITIES else None
        l2 = [discrete_l2(s[q] - ref_s[q], dA, mask) for s in sampled[:-1]]
        mx = [max_norm(s[q] - ref_s[q], mask) for s in sampled[:-1]]
        st.errors[q] = {"l2": l2, "max": mx}
        st.orders[q] = {"l2": fit_order(st.h, l2), "max": fit_order(st.h, mx)}
        hr = grids[-1].h
        st.orders_refcorr[q] = {
            "l2": fit_order_with_reference(st.h, l2, hr),
            "max": fit_order_with_reference(st.h, mx, hr),
        }
        st.pairwise[q] = {"l2": pairwise_orders(st.h, l2), "max": pairwise_orders(st.h, mx)}
    return st


# ---------------------------------------------------------------------- reporting
def format_table(st: Study) -> str:
    """Plain-text table: errors per rung, pairwise orders between rungs, fitted order."""
    head = f"{st.scenario} at t = {st.t_end:g}: grids {st.grids} against {st.ref}"
    info = (
        f"common points: the {st.grids[0]}^2 nodes ({st.points}); solid fields on "
        f"{st.solid_points} points with phi < -{st.margin:g} h in every run"
    )
    cols = "".join(f"{n:>10d}" for n in st.grids)
    lines = [
        head,
        info,
        f"{'quantity':10s}{'norm':>5s}{cols}{'fit order':>11s}{'ref-corr.':>11s}",
    ]
    for q in QUANTITIES:
        for norm in ("l2", "max"):
            errs = "".join(f"{e:10.3e}" for e in st.errors[q][norm])
            lines.append(
                f"{q:10s}{norm:>5s}{errs}{st.orders[q][norm]:11.3f}"
                f"{st.orders_refcorr[q][norm]:11.3f}"
            )
            pw = "".join(f"{p:10.2f}" for p in st.pairwise[q][norm])
            lines.append(f"{'':10s}{'pair':>5s}{'':5s}{pw}")
    lines.append(
        "fit order: least-squares slope of log(error) against log(h); ref-corr.: the order p "
        "of error = C (h^p - h_ref^p), which allows for the reference's own error"
    )
    return "\n".join(lines)


def write_csv(st: Study, path) -> Path:
    """One row per quantity and rung: n, h, L2 and max errors, pairwise orders to the next
    finer rung, and the quantity's fitted orders, plain and reference-corrected (repeated on
    each row)."""
    path = Path(path)
    rows = [
        "scenario,t_end,ref,quantity,n,h,l2,max,pair_order_l2,pair_order_max,fit_order_l2,fit_order_max,"
        "refcorr_order_l2,refcorr_order_max"
    ]
    for q in QUANTITIES:
        for i, n in enumerate(st.grids):
            pl = st.pairwise[q]["l2"][i] if i < len(st.grids) - 1 else float("nan")
            pm = st.pairwise[q]["max"][i] if i < len(st.grids) - 1 else float("nan")
            rows.append(
                f"{st.scenario},{st.t_end:g},{st.ref},{q},{n},{st.h[i]:.10g},"
                f"{st.errors[q]['l2'][i]:.10g},{st.errors[q]['max'][i]:.10g},{pl:.6g},{pm:.6g},"
                f"{st.orders[q]['l2']:.6g},{st.orders[q]['max']:.6g},"
                f"{st.orders_refcorr[q]['l2']:.6g},{st.orders_refcorr[q]['max']:.6g}"
            )
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def plot_study(st: Study, path, title: str | None = None) -> Path:
    """Log-log plot of the L2 and max errors against h, with the fitted orders and slopes 1, 2."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6))
    h = np.asarray(st.h)
    for ax, norm, label in zip(
        axes, ("l2", "max"), ("discrete L2 norm (eq. 4.30)", "max norm"), strict=True
    ):
        for q, mk in zip(QUANTITIES, "osD^v", strict=True):
            e = np.asarray(st.errors[q][norm])
            p = st.orders[q][norm]
            pc = st.orders_refcorr[q][norm]
            ax.loglog(h, e, mk + "-", label=f"{q}: order {p:.2f} (ref-corr. {pc:.2f})")
        lo = min(min(st.errors[q][norm]) for q in QUANTITIES)
        for slope, ls in ((1, ":"), (2, "--")):
            ax.loglog(h, lo * 0.5 * (h / h[-1]) ** slope, "k" + ls, lw=1, label=f"slope {slope}")
        ax.set_xlabel("grid spacing h")
        ax.set_ylabel(f"error against {st.ref}$^2$")
        ax.set_title(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title or f"{st.scenario}: grids {st.grids} vs {st.ref} at t = {st.t_end:g}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def study(
    scenario: str,
    grids,
    ref: int,
    t_end: float | None,
    out,
    *,
    jobs: int = 1,
    margin: float = 1.0,
    log=None,
    plot: bool = True,
    viscosity: str | None = None,
    kernel: str | None = None,
) -> Study:
    """Run (or reuse) the ladder, analyse it, write ``convergence.csv`` and
    ``convergence.png`` into ``out`` and return the :class:`Study`.  ``viscosity``,
    ``kernel``: as in :func:`run_rung`."""
    grids, ref, t_end, _ = check_study(scenario, grids, ref, t_end, viscosity, kernel)
    if not (isinstance(margin, (int, float)) and math.isfinite(margin) and margin >= 0):
        raise ConvergenceError(f"margin must be a number >= 0, got {margin!r}")
    res = run_ladder(
        scenario, grids, ref, t_end, out, jobs=jobs, log=log, viscosity=viscosity, kernel=kernel
    )
    st = analyse([res[n]["path"] for n in grids], res[ref]["path"], margin=margin)
    write_csv(st, Path(out) / "convergence.csv")
    if plot:
        plot_study(st, Path(out) / "convergence.png")
    return st


__all__ = [
    "ConvergenceError",
    "Study",
    "analyse",
    "bilinear",
    "check_study",
    "discrete_l2",
    "fit_order",
    "fit_order_with_reference",
    "format_table",
    "load_rung",
    "max_norm",
    "pairwise_orders",
    "parse_grids",
    "plot_study",
    "run_ladder",
    "run_rung",
    "rung_path",
    "study",
    "write_csv",
]

if __name__ == "__main__":  # pragma: no cover
    sys.exit("use `refmap convergence`")
