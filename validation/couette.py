"""Oscillating Couette sandwich (VALIDATION.md section 2; Sugiyama et al. 2011).

Periodic in x, y in [0, 1]: a solid layer (G = 5, ``LogNeoHookean``, for which simple shear
is exact at any amplitude: sigma_xy = G gamma) on 0 < y < 0.5, glued to the resting wall
y = 0, under a fluid layer (dynamic viscosity mu_f = 1) on 0.5 < y < 1; rho = 1; the wall
y = 1 moves with u = sin(pi t); everything starts at rest.  The flow is a pure shear
u(y, t), so the fluid is not compressed at all and J = 1 in the solid.

Viscosity in refmap: the fluid stress is ``eta sym(grad v)`` (dynamic viscosity eta / 2),
blended with the solid stress by the fluid fraction, and ``extra_viscosity * lap(v)`` acts
everywhere (solid included, dynamic viscosity extra_viscosity).  So in this shear flow
mu_f = eta / 2 + extra_viscosity and the solid has mu_s = extra_viscosity.  Two set-ups:

* ``uniform``: eta = 0, extra_viscosity = 1: mu_s = mu_f = 1 (closed form 0.437003, +0.3540);
* ``thesis``: the default extra_viscosity = 0.02 and eta = 1.96: mu_s = 0.02, mu_f = 1
  (close to the inviscid-solid closed form 0.679527, +0.6770; the exact target is
  computed here for mu_s = 0.02).

References written here: :func:`closed_form` (the long-time periodic state of
VALIDATION.md section 2) and :func:`solve_1d` (the two-layer shear problem from rest:
finite volumes with the interface on a node, Crank-Nicolson in time, second order).

Run ``python validation/couette.py`` to regenerate every number of
docs/validation_couette.md and the figure docs/img/couette.png (``--quick`` for a short
check; finished runs are cached in out/couette/, ``--fresh`` ignores the cache).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

G = 5.0
RHO = 1.0
MU_F = 1.0
L_S = 0.5
L_F = 0.5
OMEGA = math.pi
V_WALL = 1.0
TIMES = (2.0, 2.8, 4.0, 4.8)
PERIOD = 2 * math.pi / OMEGA
SETUPS = {"uniform": 1.0, "thesis": 0.02}  # name -> mu_s = extra_viscosity
ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "out" / "couette"  # git-ignored


# ---------------------------------------------------------------------- closed form
def _coefficients(mu_s, mu_f=MU_F):
    mut = mu_s + G / (1j * OMEGA)
    ks = np.sqrt(1j * OMEGA * RHO / mut)
    kf = np.sqrt(1j * OMEGA * RHO / mu_f)
    r = mut * ks * np.cosh(ks * L_S) / (mu_f * kf)
    A = V_WALL / (r * np.sinh(kf * L_F) + np.sinh(ks * L_S) * np.cosh(kf * L_F))
    C = A * np.sinh(ks * L_S)
    B = r * A
    return A, B, C, ks, kf


def phasor(y, mu_s, mu_f=MU_F):
    """Complex amplitude v_hat(y) of the periodic state, u = Im(v_hat e^{i omega t})."""
    A, B, C, ks, kf = _coefficients(mu_s, mu_f)
    y = np.asarray(y, dtype=float)
    yp = y - L_S
    return np.where(y <= L_S, A * np.sinh(ks * y), B * np.sinh(kf * yp) + C * np.cosh(kf * yp))


def closed_form(y, t, mu_s, mu_f=MU_F):
    """Long-time periodic velocity u(y, t)."""
    return np.imag(phasor(y, mu_s, mu_f) * np.exp(1j * OMEGA * t))


def interface_amplitude_phase(mu_s, mu_f=MU_F):
    """(|V_I|, arg V_I): u(L_s, t) = |V_I| sin(omega t + arg V_I) in the periodic state."""
    v = complex(phasor(L_S, mu_s, mu_f))
    return abs(v), math.atan2(v.imag, v.real)


def fit_sine(t, u):
    """Least-squares fit u ~ a sin(omega t) + b cos(omega t) + c -> (amplitude, phase)."""
    t = np.asarray(t)
    M = np.stack([np.sin(OMEGA * t), np.cos(OMEGA * t), np.ones_like(t)], axis=1)
    (a, b, _), *_ = np.linalg.lstsq(M, np.asarray(u), rcond=None)
    return math.hypot(a, b), math.atan2(b, a)


# ---------------------------------------------------------------------- 1D reference
def _operator(n, mu_s, mu_f):
    """Semi-discrete two-layer shear problem dz/dt = A z + b(t) on n cells (n even).

    Nodes y_j = j / n carry u (u_0 = 0, u_n = sin(omega t) given, u_1 .. u_{n-1} unknown);
    cell k = [y_k, y_k+1] carries the shear stress tau_k = mu_k (u_k+1 - u_k)/dy + G_k gamma_k
    with the shear strain gamma_k (solid cells k < n/2 only, d gamma_k / dt = (u_k+1 - u_k)/dy).
    rho du_j/dt = (tau_j - tau_j-1)/dy.  The interface y = 1/2 is node n/2, so every cell is
    of one material: the jump in tau's law is exact and the scheme second order.
    """
    if n % 2:
        raise ValueError("n must be even (the interface sits on a node)")
    dy = 1.0 / n
    m = n // 2  # solid cells
    nu_ = n - 1
    N = nu_ + m
    mu = np.where(np.arange(n) < m, mu_s, mu_f)
    rows, cols, vals = [], [], []

    def add(r, c, v):
        rows.append(r)
        cols.append(c)
        vals.append(v)

    # unknowns: u_j at index j - 1 (j = 1 .. n-1), gamma_k at index n - 1 + k (k < m)
    for k in range(n):  # cell k adds +tau_k / (rho dy) to node k and -tau_k / (rho dy) to k + 1
        for node, f in ((k, 1.0), (k + 1, -1.0)):
            if not 1 <= node <= n - 1:
                continue
            for nb, dd in ((k + 1, 1.0), (k, -1.0)):
                if 1 <= nb <= n - 1:
                    add(node - 1, nb - 1, f * mu[k] * dd / (dy * dy * RHO))
            if k < m:
                add(node - 1, nu_ + k, f * G / (dy * RHO))
        if k < m:  # d gamma_k / dt = (u_k+1 - u_k) / dy
            for nb, dd in ((k + 1, 1.0), (k, -1.0)):
                if 1 <= nb <= n - 1:
                    add(nu_ + k, nb - 1, dd / dy)
    A = sp.csc_matrix((vals, (rows, cols)), shape=(N, N))  # duplicates are summed
    # the wall velocity u_n(t) enters node n-1 through tau_{n-1} = mu_f (u_n - u_{n-1}) / dy
    bvec = np.zeros(N)
    bvec[n - 2] = mu_f / (dy * dy * RHO)
    return A, bvec


def solve_1d(n, mu_s, t_out=TIMES, dt=None, t_end=None, series_from=None):
    """Two-layer shear problem from rest on n cells, Crank-Nicolson in time.

    Returns dict(y (n+1), u {t: u(y) at each t_out}, and when ``series_from`` is given the
    interface velocity series (t, u(1/2, t)) for t >= series_from up to t_end).
    ``dt`` defaults to 0.4 / (n / 20) (so the output times, multiples of 0.4, are landed
    on exactly, and dt / dy stays fixed: second order in space and time together).
    """
    dt = dt if dt is not None else 0.4 / max(1, n // 20)
    t_end = t_end if t_end is not None else max(t_out)
    A, bvec = _operator(n, MU_F if mu_s is None else mu_s, MU_F)
    N = A.shape[0]
    Id = sp.identity(N, format="csc")
    lhs = spla.splu((Id - 0.5 * dt * A).tocsc())
    rhs_op = (Id + 0.5 * dt * A).tocsr()
    z = np.zeros(N)
    y = np.linspace(0.0, 1.0, n + 1)
    out = {}
    steps = int(round(t_end / dt))
    want = {int(round(t / dt)): t for t in t_out}
    ts, us = [], []
    for s in range(1, steps + 1):
        t0, t1 = (s - 1) * dt, s * dt
        z = lhs.solve(rhs_op @ z + 0.5 * dt * (math.sin(OMEGA * t0) + math.sin(OMEGA * t1)) * bvec)
        if s in want or (series_from is not None and t1 >= series_from - 1e-12):
            u = np.concatenate([[0.0], z[: n - 1], [V_WALL * math.sin(OMEGA * t1)]])
            if s in want:
                out[want[s]] = u
            if series_from is not None and t1 >= series_from - 1e-12:
                ts.append(t1)
                us.append(u[n // 2])
    res = dict(y=y, u=out)
    if series_from is not None:
        res["series"] = (np.array(ts), np.array(us))
    return res


# ---------------------------------------------------------------------- refmap runs
NX = 8  # periodic columns: the flow does not depend on x; Grid needs nx >= 8
LAMBDA_F = 100.0  # fluid sound speed 10: irrelevant here (div v = 0), not limiting dt
KAPPA = 100.0  # solid bulk modulus (J = 1 in simple shear anyway)
SAMPLES_PER_PERIOD = 40


def make_case(ny: int, setup: str = "uniform", numerics=None):
    """The sandwich on an NX x ny grid of square cells (x-period NX / ny)."""
    import refmap  # noqa: F401  (enables float64)
    from refmap.boundary import Boundary, Segment
    from refmap.case import Case
    from refmap.geometry import Rectangle
    from refmap.grid import Grid
    from refmap.materials import LogNeoHookean
    from refmap.model import Solid
    from refmap.state import FluidParams, Numerics

    if ny % 2:
        raise ValueError("ny must be even (the interface y = 1/2 is then a cell face)")
    mu_s = SETUPS[setup]
    h = 1.0 / ny
    width = NX * h
    # the slab fills y < 1/2 and reaches well beyond the bottom wall and the x-period
    slab = Rectangle(center=(0.5 * width, 0.0), half_size=(100.0, L_S))
    return Case(
        name=f"couette_{setup}_{ny}",
        grid=Grid(NX, ny, 0.0, width, 0.0, 1.0),
        solids=(Solid(shape=slab, law=LogNeoHookean(G=G, kappa=KAPPA, rho0=RHO), name="layer"),),
        boundary=Boundary(
            left="periodic",
            right="periodic",
            bottom=(Segment("wall"),),
            top=(Segment("velocity", velocity=(V_WALL, 0.0), omega=OMEGA),),
        ),
        fluid=FluidParams(
            rho0=RHO, lambda_f=LAMBDA_F, eta=2.0 * (MU_F - mu_s), extra_viscosity=mu_s
        ),
        numerics=numerics if numerics is not None else Numerics(),
        t_end=max(TIMES),
        description="oscillating Couette sandwich (VALIDATION.md section 2)",
    )


def run_2d(ny: int, setup: str = "uniform", t_end: float | None = None, numerics=None):
    """Run the sandwich; return u(y) at TIMES (x-averaged), the interface velocity series
    (x-average of the two node rows next to y = 1/2) and a few health numbers."""
    import jax
    import jax.numpy as jnp

    case = make_case(ny, setup, numerics)
    t_end = t_end if t_end is not None else max(TIMES)
    model, params = case.build()
    s = model.initial_state(params)
    advance = jax.jit(model.advance)
    dt_s = PERIOD / SAMPLES_PER_PERIOD
    n_samples = int(round(t_end / dt_s))
    want = {int(round(t / dt_s)): t for t in TIMES if t <= t_end + 1e-12}
    j = ny // 2
    ts, ui, profiles = [0.0], [0.0], {}
    steps = 0
    vy_max = 0.0
    x_var = 0.0
    t0 = time.time()
    for k in range(1, n_samples + 1):
        s, info = advance(s, params, jnp.asarray(k * dt_s))
        if not bool(info["ok"]):
            raise RuntimeError(f"couette {setup} ny={ny}: non-finite state near t = {k * dt_s}")
        steps += int(info["steps"])
        u = np.asarray(s.v[0])
        ts.append(float(s.t))
        ui.append(float(0.5 * (u[:, j - 1] + u[:, j]).mean()))
        vy_max = max(vy_max, float(np.abs(np.asarray(s.v[1])).max()))
        x_var = max(x_var, float(np.ptp(u, axis=0).max()))
        if k in want:
            profiles[want[k]] = u.mean(axis=0)
    d = model.derived(s, params)
    inside = np.asarray(d["phic"][0]) < 0
    J = np.asarray(d["J"][0])[inside]
    return dict(
        ny=ny,
        setup=setup,
        y=case.grid.axes("node")[1],
        profiles=profiles,
        t=np.array(ts),
        u_interface=np.array(ui),
        steps=steps,
        seconds=time.time() - t0,
        vy_max=vy_max,
        x_variation=x_var,
        J_range=(float(J.min()), float(J.max())),
    )


def _cached_run(ny, setup, fresh=False, blur_width=None, blend="erf"):
    """One 2D run (cached); ``blend``/``blur_width`` pick the kernel (None: erf at 2 h)."""
    from refmap.state import Numerics

    CACHE.mkdir(parents=True, exist_ok=True)
    if blend == "erf":
        tag = "" if blur_width is None or blur_width == 2.0 else f"_blur{blur_width:g}"
    else:
        tag = f"_{blend}{blur_width:g}"
    f = CACHE / f"{setup}_{ny}{tag}.json"
    if f.exists() and not fresh:
        r = json.loads(f.read_text())
    else:
        num = None if not tag else Numerics(blur_width=blur_width, blend=blend)
        r = run_2d(ny, setup, numerics=num)
        f.write_text(
            json.dumps(
                {
                    k: (v.tolist() if isinstance(v, np.ndarray) else v)
                    for k, v in r.items()
                    if k != "profiles"
                }
                | {"profiles": {str(t): p.tolist() for t, p in r["profiles"].items()}}
            )
        )
        r = json.loads(f.read_text())
    r["profiles"] = {float(t): np.array(p) for t, p in r["profiles"].items()}
    r["y"] = np.array(r["y"])
    r["t"] = np.array(r["t"])
    r["u_interface"] = np.array(r["u_interface"])
    return r


# ---------------------------------------------------------------------- errors
N_REF = 2560  # 1D reference cells: a node at every 2D node of ny | 1280; error ~4e-6


def reference(setup: str, n: int = N_REF):
    return solve_1d(n, SETUPS[setup], series_from=0.0)


def fit_window(t, u):
    """Amplitude and phase of u(t) fitted over the window t >= FIT_FROM."""
    t, u = np.asarray(t), np.asarray(u)
    m = t >= FIT_FROM - 1e-9
    return fit_sine(t[m], u[m])


FIT_FROM = 2.8  # fit window [2.8, 4.8]: one period; the slowest transient decays like
# exp(-3.49 t) (uniform) or exp(-2.17 t) (thesis), so it is down to 6e-5 (2e-3) by t = 2.8


def errors(run, ref):
    """L2 (root mean square over the nodes) and max errors of u(y) at each time."""
    y = run["y"]
    n = len(ref["y"]) - 1
    idx = np.rint(y * n).astype(int)
    if not np.allclose(ref["y"][idx], y, atol=1e-12):
        raise ValueError("the 1D reference grid must contain the 2D nodes")
    out = {}
    for t in TIMES:
        e = run["profiles"][t] - ref["u"][t][idx]
        out[t] = (float(np.sqrt(np.mean(e * e))), float(np.abs(e).max()))
    return out


def interface_fit(run):
    return fit_window(run["t"], run["u_interface"])


def sampled_interface_amplitude_phase(mu_s, ny):
    """What the two-node average (u(1/2 - h/2) + u(1/2 + h/2)) / 2 of the *exact* periodic
    state gives: u has a kink at the interface (the shear rate jumps), so this sampling is
    itself O(h) off |V_I| -- comparing with it isolates the solver's own error."""
    h = 1.0 / ny
    v = complex(0.5 * (phasor(L_S - 0.5 * h, mu_s) + phasor(L_S + 0.5 * h, mu_s)))
    return abs(v), math.atan2(v.imag, v.real)


def orders(hs, es):
    return [math.log(es[i] / es[i + 1]) / math.log(hs[i] / hs[i + 1]) for i in range(len(es) - 1)]


# ---------------------------------------------------------------------- report
def reference_convergence(setup: str, ns=(80, 160, 320, 640, 1280)):
    """Max error of the 1D solve at TIMES against N_REF cells, and of its interface fit
    against the closed form."""
    ref = reference(setup)
    amp, ph = interface_amplitude_phase(SETUPS[setup])
    rows = []
    for n in (*ns, N_REF):
        r = ref if n == N_REF else solve_1d(n, SETUPS[setup], series_from=0.0)
        step = N_REF // n
        e = max(float(np.abs(r["u"][t] - ref["u"][t][::step]).max()) for t in TIMES)
        a, p = fit_window(*r["series"])
        rows.append(
            dict(
                n=n,
                err=e if n != N_REF else float("nan"),
                amp=a,
                phase=p,
                amp_err=a - amp,
                phase_err=p - ph,
            )
        )
    return rows


def study(setup: str, nys, fresh=False, kernel=("erf", 2.0)):
    ref = reference(setup)
    amp, ph = interface_amplitude_phase(SETUPS[setup])
    rows = []
    for ny in nys:
        run = _cached_run(ny, setup, fresh, blur_width=kernel[1], blend=kernel[0])
        e = errors(run, ref)
        a, p = interface_fit(run)
        sa, sp_ = sampled_interface_amplitude_phase(SETUPS[setup], ny)
        rows.append(
            dict(
                ny=ny,
                l2=max(v[0] for v in e.values()),
                linf=max(v[1] for v in e.values()),
                per_time=e,
                amp=a,
                phase=p,
                amp_err=a - amp,
                phase_err=p - ph,
                amp_err_s=a - sa,
                phase_err_s=p - sp_,
                steps=run["steps"],
                seconds=run["seconds"],
                vy_max=run["vy_max"],
                x_variation=run["x_variation"],
                J_range=run["J_range"],
                run=run,
            )
        )
    return dict(
        setup=setup, mu_s=SETUPS[setup], amp=amp, phase=ph, ref=ref, rows=rows, kernel=kernel
    )


def print_study(st):
    rows = st["rows"]
    print(
        f"\n## {st['setup']} ({st['kernel'][0]} {st['kernel'][1]:g}): mu_s = {st['mu_s']}, "
        f"mu_f = {MU_F}; closed form |V_I| = "
        f"{st['amp']:.6f}, phase {st['phase']:+.4f} rad"
    )
    print(
        "| ny | L2 err u | order | max err u | order | fit \\|V_I\\| | rel. err | (sampled) "
        "| fit phase | err (rad) | (sampled) | steps | s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    hs = [1.0 / r["ny"] for r in rows]
    o2 = [None] + orders(hs, [r["l2"] for r in rows])
    oi = [None] + orders(hs, [r["linf"] for r in rows])
    for r, a, b in zip(rows, o2, oi, strict=True):
        fa = "" if a is None else f"{a:.2f}"
        fb = "" if b is None else f"{b:.2f}"
        print(
            f"| {r['ny']} | {r['l2']:.2e} | {fa} | {r['linf']:.2e} | {fb} | {r['amp']:.4f} | "
            f"{r['amp_err'] / st['amp']:+.2%} | {r['amp_err_s'] / st['amp']:+.2%} | "
            f"{r['phase']:+.4f} | {r['phase_err']:+.4f} | {r['phase_err_s']:+.4f} | "
            f"{r['steps']} | {r['seconds']:.0f} |"
        )
    oa = orders(hs, [abs(r["amp_err"]) for r in rows])
    op = orders(hs, [abs(r["phase_err"]) for r in rows])
    print("observed order, amplitude error:", ", ".join(f"{o:.2f}" for o in oa))
    print("observed order, phase error    :", ", ".join(f"{o:.2f}" for o in op))
    oa = orders(hs, [abs(r["amp_err_s"]) for r in rows])
    op = orders(hs, [abs(r["phase_err_s"]) for r in rows])
    print(
        "  (against the sampled closed form):",
        ", ".join(f"{o:.2f}" for o in oa),
        "/",
        ", ".join(f"{o:.2f}" for o in op),
    )
    print("\nper time (L2 / max):")
    print("| ny | " + " | ".join(f"t = {t}" for t in TIMES) + " |")
    print("|---|" + "---|" * len(TIMES))
    for r in rows:
        cells = " | ".join(f"{r['per_time'][t][0]:.2e} / {r['per_time'][t][1]:.2e}" for t in TIMES)
        print(f"| {r['ny']} | {cells} |")
    worst = max(r["vy_max"] for r in rows), max(r["x_variation"] for r in rows)
    jr = min(r["J_range"][0] for r in rows), max(r["J_range"][1] for r in rows)
    print(
        f"health: max |v_y| {worst[0]:.1e}, max x-variation of u {worst[1]:.1e}, "
        f"J in solid [{jr[0]:.12f}, {jr[1]:.12f}]"
    )


BLUR_RUNS = ((20, 1.0), (40, 1.0), (20, 3.0))  # (ny, blur width / h); the default is 2


def blur_sensitivity(setup="uniform", runs=BLUR_RUNS, fresh=False):
    """Errors of the uniform set-up when only the blur width changes."""
    ref = reference(setup)
    amp, _ = interface_amplitude_phase(SETUPS[setup])
    print(f"\n## blur width ({setup}); default 2h")
    print(
        "| ny | blur / h | L2 err u | max err u | amplitude err (sampled) | phase err (sampled) |"
    )
    print("|---|---|---|---|---|---|")
    rows = sorted(set(runs) | {(ny, 2.0) for ny, _ in runs})
    for ny, bw in rows:
        run = _cached_run(ny, setup, fresh, None if bw == 2.0 else bw)
        e = errors(run, ref)
        a, p = interface_fit(run)
        sa, sp_ = sampled_interface_amplitude_phase(SETUPS[setup], ny)
        print(
            f"| {ny} | {bw:g} | {max(v[0] for v in e.values()):.2e} | "
            f"{max(v[1] for v in e.values()):.2e} | {(a - sa) / amp:+.2%} | {p - sp_:+.4f} |"
        )


def print_reference(setup, rows):
    print(
        f"\n## 1D reference ({setup}): max error at the four times against n = {N_REF}; "
        "interface fit over [2.8, 4.8] against the closed form"
    )
    print("| n | max err | order | fit |V_I| - closed | fit phase - closed |")
    print("|---|---|---|---|---|")
    prev = None
    for r in rows:
        o = (
            ""
            if prev is None or not math.isfinite(r["err"])
            else f"{math.log(prev / r['err']) / math.log(2):.2f}"
        )
        e = "(reference)" if not math.isfinite(r["err"]) else f"{r['err']:.2e}"
        print(f"| {r['n']} | {e} | {o} | {r['amp_err']:+.1e} | {r['phase_err']:+.1e} |")
        prev = r["err"]


def figure(studies, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, len(studies), figsize=(6.0 * len(studies), 13.0), squeeze=False)
    # u has period 2 and the transient is gone by t = 2: u(y, 4) ~ u(y, 2), u(y, 4.8) ~ u(y, 2.8)
    styles = {2.0: ("C0", "-"), 2.8: ("C3", "-"), 4.0: ("C0", "--"), 4.8: ("C3", "--")}
    marks = ("x", "+", "o", "s", "^")
    for col, st in enumerate(studies):
        ref = st["ref"]
        ax = axes[0, col]
        for t in TIMES:
            c, ls = styles[t]
            ax.plot(ref["u"][t], ref["y"], ls, color=c, lw=1.2, label=f"1D ref., t = {t}")
        for r, mk in zip(st["rows"], marks, strict=False):
            for t in (2.8, 4.0):
                ax.plot(
                    r["run"]["profiles"][t],
                    r["run"]["y"],
                    mk,
                    color=styles[t][0],
                    ms=4,
                    mfc="none",
                    label=f"refmap ny = {r['ny']}" if t == 2.8 else None,
                )
        ax.axhline(L_S, color="0.5", lw=0.6, ls=":")
        ax.set_xlabel("u")
        ax.set_ylabel("y")
        ax.set_title(f"u(y), {st['setup']}: $\\mu_s$ = {st['mu_s']}, $\\mu_f$ = {MU_F}")
        ax.legend(fontsize=7, ncol=2)
        ax = axes[1, col]
        n = len(ref["y"]) - 1
        for r, mk in zip(st["rows"], marks, strict=False):
            run = r["run"]
            idx = np.rint(run["y"] * n).astype(int)
            for t, c in ((2.8, "C3"), (4.0, "C0")):
                ax.plot(
                    run["profiles"][t] - ref["u"][t][idx],
                    run["y"],
                    "-" + mk,
                    color=c,
                    lw=0.6,
                    ms=3,
                    mfc="none",
                    label=f"t = {t}, ny = {r['ny']}",
                )
        ax.axhline(L_S, color="0.5", lw=0.6, ls=":")
        ax.axvline(0.0, color="0.5", lw=0.6)
        ax.set_xlabel("u (refmap) - u (1D reference)")
        ax.set_ylabel("y")
        ax.set_title("error profile")
        ax.legend(fontsize=7, ncol=2)
        ax = axes[2, col]
        ts, us = ref["series"]
        tt = np.linspace(0, max(TIMES), 600)
        ax.plot(
            tt,
            st["amp"] * np.sin(OMEGA * tt + st["phase"]),
            "k:",
            lw=1,
            label="closed form (periodic)",
        )
        ax.plot(ts, us, "k-", lw=1.0, label="1D reference")
        for r, mk in zip(st["rows"], marks, strict=False):
            ax.plot(
                r["run"]["t"],
                r["run"]["u_interface"],
                mk,
                ms=3,
                mfc="none",
                label=f"refmap ny = {r['ny']}",
            )
        ax.axvspan(FIT_FROM, max(TIMES), color="0.9", zorder=0)
        ax.set_xlabel("t")
        ax.set_ylabel("u at y = 1/2")
        ax.set_title("interface velocity (grey: fit window)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="ny = 20, 40, uniform set-up only")
    ap.add_argument("--fresh", action="store_true", help="recompute cached runs")
    ap.add_argument("--uniform", default="20,40,80,160", help="ny ladder of the uniform set-up")
    ap.add_argument(
        "--thesis", default="20,40,80", help="ny ladder of the thesis set-up ('' to skip)"
    )
    ap.add_argument(
        "--kernel",
        default="erf:2",
        help="blend kernel:width of the ladders (e.g. sine:1); the figure and the blur "
        "sensitivity are made for erf:2 only",
    )
    ap.add_argument("--figure", default=str(ROOT / "docs" / "img" / "couette.png"))
    a = ap.parse_args(argv)
    from refmap.blend import parse_kernel

    kernel = parse_kernel(a.kernel)
    ladders = {"uniform": a.uniform, "thesis": a.thesis}
    if a.quick:
        ladders = {"uniform": "20,40", "thesis": ""}
    studies = []
    for setup, spec in ladders.items():
        nys = [int(x) for x in spec.split(",") if x.strip()]
        if not nys:
            continue
        print_reference(setup, reference_convergence(setup))
        st = study(setup, nys, fresh=a.fresh, kernel=kernel)
        print_study(st)
        studies.append(st)
    if studies and not a.quick and kernel == ("erf", 2.0):
        blur_sensitivity(fresh=a.fresh)
        figure(studies, Path(a.figure))
        print(f"\nfigure: {a.figure}")


if __name__ == "__main__":
    main()
