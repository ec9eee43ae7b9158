"""Soft disc in a lid-driven cavity (VALIDATION.md section 4; Sugiyama et al. 2011).

Unit square, lid u = 1 at y = 1 (a ``velocity`` segment over the whole top edge), the other
edges no-slip walls; a disc of radius 0.2 centred at (0.6, 0.5); rho_s = rho_f = 1;
mu = 0.01 (Re = 100) in the fluid *and* in the solid; G = 0.1; both at rest at t = 0.  The
disc centroid is compared with the digitized trajectory of Sugiyama et al. (2011, 1024^2)
in ``shared/data/lid_cavity_disc_sugiyama2011_1024.csv``.

Choices (see docs/validation_lid_cavity.md for the reasons):

* solid law :class:`~refmap.materials.LogNeoHookean`, sigma = (G/J)(B - I) + kappa (J-1) I,
  kappa = 10 = 100 G (the references' solid is incompressible, sigma' = G B');
* viscosity: ``eta = 0`` and ``extra_viscosity = mu = 0.01``, i.e. mu lap(v) everywhere.
  This is Sugiyama's viscous hyperelastic solid with the fluid's viscosity (mu_s = mu_f),
  and for the fluid it equals div(2 mu D) up to mu grad(div v), which vanishes for
  incompressible flow.  (``eta`` is blended out inside the solid, so it cannot give the
  solid its viscosity.)
* fluid: lambda_f = 100 (sound speed c = 10, Mach 0.1 at the lid);
* a numerical bulk viscosity zeta = beta c h (beta = 1): the isotropic stress
  zeta (div v) I, added as a model body-force term (:class:`BulkViscosity`, built with the
  model's own corner stencils).  Without it the fluid is unstable at this Mach number: the
  scheme pairs the centred divergence of the density update with the one-sided
  (bottom-left-node) pressure gradient, and sound waves then grow at a rate up to
  ~c (1 - cos(k h)) / (2 h) unless the viscosity exceeds ~c h / 2 (see the doc page);
  mu = 0.01 would need h < 1/500 at c = 10.  zeta -> 0 with h, and acts only on div v,
  which is O(Mach^2) in the fluid and ~0 in a nearly incompressible solid.
* fixed time step dt = cfl min(h^2 / (4 (mu + zeta)), h / c, h / c_solid), cfl = 0.5
  (explicit diffusion limit of mu + zeta; the model's adaptive step does not know zeta).

Run ``python validation/lid_cavity.py`` (about 50 minutes on one core; runs are cached in
$REFMAP_LID_RUNS, default /work/runs/lid, and continued from their last state when a
longer run is asked for).  ``--quick`` runs the small version only.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from refmap.boundary import Boundary, Segment
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.materials import LogNeoHookean
from refmap.model import Model, Solid
from refmap.operators import div_node, grad_corner
from refmap.state import FluidParams, Numerics, Params, State

MU = 0.01  # fluid (and solid) dynamic viscosity, Re = U L / nu = 100
G = 0.1  # solid shear modulus (Sugiyama's c1 = G / 2 = 0.05)
CENTER, RADIUS = (0.6, 0.5), 0.2
RUNS = Path(os.environ.get("REFMAP_LID_RUNS", "/work/runs/lid"))
REPO = Path(__file__).resolve().parents[1]
REFERENCE = REPO.parent / "shared" / "data" / "lid_cavity_disc_sugiyama2011_1024.csv"
# first-loop extents quoted in VALIDATION.md (digitizing error about 0.005)
REF_EXTENTS = {"x_max": 0.702, "x_min": 0.289, "y_max": 0.868, "y_min": 0.494}
# winding centre: the reference trajectory turns monotonically about this point, and one
# turn about it from the start reproduces the quoted first-loop extents exactly
SPIRAL_CENTER = (0.555, 0.72)
COLUMNS = ("t", "cx", "cy", "area", "J_min", "J_max", "max_speed", "fluid_mass", "p_min", "p_max")


@dataclass(frozen=True)
class BulkViscosity:
    """Body-force term: the divergence of the isotropic stress zeta (div v) I.

    div v is taken at the corners with the model's bottom-left-triangle gradient and the
    stress divergence back at the nodes with its top-right-triangle stencil, like every
    other stress of the method (so the term is a negative semi-definite operator on v).
    """

    zeta: float

    def __call__(self, ctx):
        model, state = ctx["model"], ctx["state"]
        g = model.grid
        vp = model.bc.pad_velocity(state.v, state.t)[:, 1:-1, 1:-1]
        ux, _ = grad_corner(vp[0], g.dx, g.dy)
        _, vy = grad_corner(vp[1], g.dx, g.dy)
        q = self.zeta * (ux + vy)
        return div_node(q, jnp.zeros_like(q), q, g.dx, g.dy)


def build(n, lambda_f=100.0, kappa=10.0, beta=1.0, cfl=0.5, viscosity=None,
          fluid_mass="advected", blend="erf", blur_width=2.0):
    """(model, params, dt, zeta) for an n x n grid.

    ``viscosity=None`` (the validated set-up): zeta as the :class:`BulkViscosity` body force,
    acting everywhere, explicit.  ``"explicit"`` or ``"implicit"``: zeta as the fluid's
    ``bulk_viscosity`` (weighted by the fluid fraction like the rest of the fluid stress,
    so not in the solid) with ``Numerics.viscosity`` set so; implicit drops the diffusion
    limit from dt (docs/validation.md, "Implicit viscosity").  ``fluid_mass``: the
    ``Numerics`` option ("conserved" keeps the box's fluid mass; docs/method.md).
    ``blend``, ``blur_width``: the blend kernel (docs/method.md, "Blend kernels").
    """
    h = 1.0 / n
    c = float(np.sqrt(lambda_f))
    zeta = beta * c * h
    c_solid = float(np.sqrt(kappa + 2.0 * G))  # longitudinal speed of LogNeoHookean, rho = 1
    diffusion = h * h / (4.0 * (MU + zeta)) if viscosity != "implicit" else np.inf
    dt = cfl * min(diffusion, h / c, h / c_solid)
    as_fluid = viscosity is not None
    model = Model(
        Grid(n, n, 0.0, 1.0, 0.0, 1.0),
        (
            Solid(
                shape=Disc(center=CENTER, radius=RADIUS),
                law=LogNeoHookean(G=G, kappa=kappa, rho0=1.0),
                name="disc",
            ),
        ),
        Boundary(top=(Segment("velocity", velocity=(1.0, 0.0)),)),
        Numerics(dt_fixed=dt, viscosity=viscosity or "explicit", fluid_mass=fluid_mass,
                 blend=blend, blur_width=blur_width),
        body_forces=(BulkViscosity(zeta),) if zeta > 0 and not as_fluid else (),
    )
    params = Params(
        fluid=FluidParams(rho0=1.0, lambda_f=lambda_f, eta=0.0, extra_viscosity=MU,
                          bulk_viscosity=zeta if as_fluid else 0.0),
        laws=(model.solids[0].law,),
    )
    return model, params, dt, zeta


def _row(diag, s):
    d = jax.device_get(diag)
    so = d["solids"][0]
    return (
        float(s.t),
        float(so["centroid_x"]),
        float(so["centroid_y"]),
        float(so["area"]),
        float(d["J_min"]),
        float(d["J_max"]),
        float(d["max_speed"]),
        float(d["fluid_mass"]),
        float(d["min_pressure"]),
        float(d["max_pressure"]),
    )


def run(n, t_end, every=0.05, state=None, snap_every=1.0, log=None, **kw):
    """Advance from ``state`` (default: rest) to t_end; the diagnostics every ``every`` and a
    snapshot (level set, speed) every ``snap_every``.  Returns (rows, state, info, snaps)."""
    model, params, dt, zeta = build(n, **kw)
    adv = jax.jit(model.advance)
    diag = jax.jit(model.diagnostics)
    s = model.initial_state(params) if state is None else state
    t_start = float(s.t)
    k0 = int(round(t_start / every))
    times = every * np.arange(k0, int(round(t_end / every)) + 1)
    rows, snaps = [], {}
    t0 = time.perf_counter()
    for tt in times:
        if tt > t_start + 1e-12:
            s, info = adv(s, params, float(tt))
            if not bool(info["ok"]):
                raise RuntimeError(f"n={n} {kw}: the run blew up before t = {tt:g}")
        if tt > t_start + 1e-12 or state is None:
            rows.append(_row(diag(s, params), s))
            if abs(tt / snap_every - round(tt / snap_every)) < 1e-9:
                snaps[f"{tt:.2f}"] = (np.asarray(s.phi[0]), np.asarray(jnp.hypot(s.v[0], s.v[1])))
        if log is not None and rows and abs(tt - round(tt)) < 1e-9:
            el = time.perf_counter() - t0
            print(
                f"  n={n} {kw} t={tt:.1f} c=({rows[-1][1]:.4f}, {rows[-1][2]:.4f}) "
                f"area={rows[-1][3]:.4f} [{el:.0f} s]",
                file=log,
                flush=True,
            )
    info = dict(
        dt=dt, zeta=zeta, steps=int(s.step), wall_s=time.perf_counter() - t0, t_start=t_start
    )
    return np.array(rows).reshape(-1, len(COLUMNS)), s, info, snaps


def cache_name(n, **kw):
    items = "_".join(
        f"{k}{v}" if isinstance(v, str) else f"{k}{v:g}" for k, v in sorted(kw.items())
    )
    return f"lid_n{n}_{items}.npz" if items else f"lid_n{n}.npz"


def run_cached(n, t_end, out_dir=None, every=0.05, log=None, **kw):
    """Centroid history up to t_end: reuses an earlier run of the same case in out_dir,
    continuing it from its saved final state when it is shorter.  Returns (rows, info, snaps)."""
    out_dir = Path(out_dir or RUNS)
    f = out_dir / cache_name(n, **kw)
    rows0, state0, snaps0, info0 = None, None, {}, {}
    if f.exists():
        z = np.load(f, allow_pickle=True)
        rows0, info0, snaps0 = z["rows"], dict(z["info"].item()), dict(z["snaps"].item())
        if abs(float(z["every"]) - every) > 1e-12:
            rows0, snaps0, info0 = None, {}, {}
        elif rows0[-1, 0] >= t_end - 1e-9:
            return rows0[rows0[:, 0] <= t_end + 1e-9], info0, snaps0
        else:
            state0 = State(
                t=jnp.asarray(float(z["t"])),
                step=jnp.asarray(int(z["step"])),
                v=jnp.asarray(z["v"]),
                rho_f=jnp.asarray(z["rho_f"]),
                xi=jnp.asarray(z["xi"]),
                phi=jnp.asarray(z["phi"]),
            )
    rows, s, info, snaps = run(n, t_end, every=every, state=state0, log=log, **kw)
    if rows0 is not None:
        rows = np.concatenate([rows0, rows])
        info["wall_s"] += float(info0.get("wall_s", 0.0))
        snaps = {**snaps0, **snaps}
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = f.with_suffix(".tmp.npz")
    np.savez(
        tmp,
        rows=rows,
        every=every,
        info=np.array(info, dtype=object),
        snaps=np.array(snaps, dtype=object),
        t=float(s.t),
        step=int(s.step),
        v=np.asarray(s.v),
        rho_f=np.asarray(s.rho_f),
        xi=np.asarray(s.xi),
        phi=np.asarray(s.phi),
    )
    os.replace(tmp, f)
    return rows, info, snaps


# ---------------------------------------------------------------------------- comparison
def load_reference(path=REFERENCE):
    lines = [
        ln for ln in Path(path).read_text().splitlines() if ln.strip() and not ln.startswith("#")
    ]
    return np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])  # lines[0]: "x,y"


def winding(x, y, center=SPIRAL_CENTER):
    """Turns made clockwise about ``center`` since the first point (running maximum, so
    small backward wiggles near the spiral's centre do not count twice)."""
    a = np.unwrap(np.arctan2(np.asarray(y) - center[1], np.asarray(x) - center[0]))
    return np.maximum.accumulate((a[0] - a) / (2 * np.pi))


def extents(x, y, w, turns=1.0):
    """x_max, x_min, y_max, y_min of the points of the first ``turns`` turns."""
    m = w <= turns
    return {
        "x_max": float(x[m].max()),
        "x_min": float(x[m].min()),
        "y_max": float(y[m].max()),
        "y_min": float(y[m].min()),
    }


def _densify(x, y, k=8):
    s = np.linspace(0, len(x) - 1, (len(x) - 1) * k + 1)
    i = np.arange(len(x))
    return np.interp(s, i, x), np.interp(s, i, y), s


def path_distance(rows, ref, window=0.25):
    """Distance of each reference point to the computed path, loop-matched: the nearest
    computed point (path densified by linear interpolation) whose winding is within
    ``window`` turns of the reference point's.  Reference points beyond the computed
    path's winding are not covered.  Returns (distances of covered points, n covered)."""
    rx, ry = ref[:, 0], ref[:, 1]
    rw = winding(rx, ry)
    x, y = rows[:, 1], rows[:, 2]
    w = winding(x, y)
    xd, yd, s = _densify(x, y)
    wd = np.interp(s, np.arange(len(w)), w)
    out = []
    for xi_, yi_, wi in zip(rx, ry, rw, strict=True):
        if wi > wd[-1] + 1e-9:
            break
        m = np.abs(wd - wi) <= window
        out.append(np.min(np.hypot(xd[m] - xi_, yd[m] - yi_)))
    return np.array(out), len(out)


def distance_to_reference(rows, ref, window=0.25):
    """The other direction: distance of each computed centroid sample to the (densified)
    reference path, loop-matched as in :func:`path_distance`; samples beyond the
    reference's winding are left out."""
    fake = np.column_stack([np.zeros(len(ref)), ref])
    d, _ = path_distance(fake, rows[:, 1:3], window)
    return d


def compare(rows, ref):
    """Metrics of one run against the reference."""
    x, y, t = rows[:, 1], rows[:, 2], rows[:, 0]
    w = winding(x, y)
    rw = winding(ref[:, 0], ref[:, 1])
    out = {"t_end": float(t[-1]), "turns": float(w[-1])}
    d, ncov = path_distance(rows, ref)
    out["covered"] = ncov
    out["n_ref"] = len(ref)
    first = rw <= 1.0
    d1 = d[: min(ncov, int(first.sum()))]
    out["rms_first_loop"] = float(np.sqrt(np.mean(d1**2))) if w[-1] >= 1.0 else float("nan")
    out["rms_all"] = float(np.sqrt(np.mean(d**2))) if len(d) else float("nan")
    out["max_all"] = float(d.max()) if len(d) else float("nan")
    if w[-1] >= 1.0:
        out.update(extents(x, y, w))
        out["t_loop"] = float(np.interp(1.0, w, t))
        i = np.searchsorted(w, 1.0)
        out["area_change_loop"] = float(rows[i, 3] / rows[0, 3] - 1.0)
    out["area_change_end"] = float(rows[-1, 3] / rows[0, 3] - 1.0)
    out["J_range_end"] = (float(rows[-1, 4]), float(rows[-1, 5]))
    return out


# (name, keyword arguments of build, the variant one level below)
SENSITIVITY = [
    # zeta = c h grows with the sound speed
    ("base", {}, None),
    ("lambda_f, kappa x2", {"lambda_f": 200.0, "kappa": 20.0}, "base"),
    ("lambda_f, kappa x4", {"lambda_f": 400.0, "kappa": 40.0}, "lambda_f, kappa x2"),
    # zeta fixed at 20 h (the x4 run's value): only lambda_f and kappa change
    ("zeta x2 (20 h)", {"beta": 2.0}, "base"),
    (
        "lambda_f, kappa x2, zeta 20 h",
        {"lambda_f": 200.0, "kappa": 20.0, "beta": 2.0**0.5},
        "zeta x2 (20 h)",
    ),
    (
        "lambda_f, kappa x4, zeta 20 h",
        {"lambda_f": 400.0, "kappa": 40.0},
        "lambda_f, kappa x2, zeta 20 h",
    ),
    # which of the two: kappa alone, then lambda_f on top of it
    ("kappa x4, zeta 20 h", {"kappa": 40.0, "beta": 2.0}, "zeta x2 (20 h)"),
    (
        "+ lambda_f x4 (= both x4, zeta 20 h)",
        {"lambda_f": 400.0, "kappa": 40.0},
        "kappa x4, zeta 20 h",
    ),
]


def max_gap(rows_a, rows_b):
    """Largest distance between two runs' centroids at equal times (common samples)."""
    m = min(len(rows_a), len(rows_b))
    assert np.allclose(rows_a[:m, 0], rows_b[:m, 0])
    return float(np.max(np.hypot(rows_a[:m, 1] - rows_b[:m, 1], rows_a[:m, 2] - rows_b[:m, 2])))


# ---------------------------------------------------------------------------- stability
def acoustic_growth(c, nu, h, m=2000):
    """Largest growth rate of 1D sound waves under the scheme's spatial operators: density
    update with the centred divergence, pressure force from the one-sided (bottom-left)
    difference, viscosity nu with the 3-point Laplacian (semi-discrete, exact in time)."""
    th = np.linspace(1e-3, np.pi, m)
    dc = 1j * np.sin(th) / h
    dm = (1 - np.exp(-1j * th)) / h
    lap = -(2 - 2 * np.cos(th)) / h**2
    # eigenvalues of [[0, -dc], [-c^2 dm, nu lap]] for every wavenumber
    tr = nu * lap
    det = -(c**2) * dc * dm
    disc = np.sqrt(tr**2 - 4 * det + 0j)
    return float(np.max(np.maximum(((tr + disc) / 2).real, ((tr - disc) / 2).real)))


def acoustic_threshold(c, h):
    """Smallest viscosity for which :func:`acoustic_growth` is <= 0 (bisection)."""
    lo, hi = 0.0, 10.0 * c * h
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if acoustic_growth(c, mid, h) > 1e-9 else (lo, mid)
    return hi


# ---------------------------------------------------------------------------- the study
def figure(results, ref, snaps, n_snap, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 2, figsize=(11, 5.2))
    ax = axs[0]
    ax.plot(ref[:, 0], ref[:, 1], "ko", ms=3.5, mfc="none", label="Sugiyama et al. 2011 (1024$^2$)")
    for (n, _), (rows, _) in sorted(results.items()):
        ax.plot(
            rows[:, 1], rows[:, 2], "-", lw=1.4, label=f"refmap {n}$^2$ (t $\\leq$ {rows[-1, 0]:g})"
        )
    ax.set_xlabel("centroid x")
    ax.set_ylabel("centroid y")
    ax.set_aspect("equal")
    ax.set_xlim(0.25, 0.75)
    ax.set_ylim(0.45, 0.92)
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title("disc centroid trajectory")
    ax = axs[1]
    keys = sorted(snaps, key=float)
    pick = [k for k in keys if float(k) in (0.0, 3.0, 5.0, 7.0)] or keys[:4]
    h = 1.0 / n_snap
    xs = (np.arange(n_snap) + 0.5) * h
    last = pick[-1]
    im = ax.imshow(
        snaps[last][1].T, origin="lower", extent=(0, 1, 0, 1), cmap="viridis", vmin=0, vmax=1
    )
    for k, col in zip(pick, ["w", "orange", "r", "magenta"], strict=False):
        ax.contour(xs, xs, snaps[k][0].T, levels=[0.0], colors=col, linewidths=1.3)
        ax.plot([], [], color=col, label=f"t = {float(k):g}")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_aspect("equal")
    ax.set_title(f"disc outline ({n_snap}$^2$), speed |v| at t = {float(last):g}")
    fig.colorbar(im, ax=ax, shrink=0.8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fmt(v, nd=3):
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.{nd}f}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--grids", default="32,48,64", help="resolutions of the first-loop study")
    ap.add_argument("--t-loop", type=float, default=9.0, help="end time of the first-loop runs")
    ap.add_argument(
        "--span-grids", default="32,48,64", help="resolutions also run over the whole reference"
    )
    ap.add_argument("--t-span", type=float, default=20.0)
    ap.add_argument("--sens-n", type=int, default=48, help="resolution of the sensitivity study")
    ap.add_argument(
        "--quick", action="store_true", help="small version: 32^2 to t = 9, no sensitivity"
    )
    ap.add_argument("--out", default=str(RUNS))
    ap.add_argument("--figure", default=str(REPO / "docs" / "img" / "lid_cavity.png"))
    ap.add_argument(
        "--kernel", default="erf:2", help="blend kernel:width of every run (e.g. sine:1)"
    )
    a = ap.parse_args(argv)
    from refmap.blend import parse_kernel

    kernel = parse_kernel(a.kernel)
    # the erf 2 runs keep the cache names of the runs made before the option existed
    blend_kw = {} if kernel == ("erf", 2.0) else dict(zip(("blend", "blur_width"), kernel, strict=True))
    if a.quick:
        a.grids, a.span_grids, a.sens_n = "32", "", 0
        if a.figure == ap.get_default("figure"):
            a.figure = str(Path(a.out) / "lid_cavity_quick.png")
    if blend_kw and a.figure == ap.get_default("figure"):
        a.figure = str(Path(a.out) / f"lid_cavity_{a.kernel.replace(':', '')}.png")
    grids = [int(s) for s in a.grids.split(",") if s]
    span = [int(s) for s in a.span_grids.split(",") if s]
    ref = load_reference()
    log = sys.stderr

    print("1D sound waves under the scheme's operators (c = 10):")
    for n in (32, 64, 128, 256):
        h = 1.0 / n
        print(
            f"  n = {n}: growth without viscosity {acoustic_growth(10.0, 0.0, h):.0f} "
            f"(= {acoustic_growth(10.0, 0.0, h) * h / 10.0:.3f} c/h), stable for viscosity >= "
            f"{acoustic_threshold(10.0, h):.4f} (= {acoustic_threshold(10.0, h) / (10.0 * h):.3f} c h)"
        )
    results = {}
    for n in grids:
        te = a.t_span if n in span else a.t_loop
        rows, info, snaps = run_cached(n, te, out_dir=a.out, log=log, **blend_kw)
        results[(n, "base")] = (rows, info)
    rw = winding(ref[:, 0], ref[:, 1])
    print(
        "Reference first loop (one turn about (0.555, 0.72)):",
        {k: round(v, 4) for k, v in extents(ref[:, 0], ref[:, 1], rw).items()},
    )
    print()
    print(
        "| n | dt | zeta | t first loop | x_max (err) | x_min (err) | y_max (err) | y_min (err) "
        "| RMS dist. first loop | RMS dist. covered (points) | area change first loop | wall s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    summary = {"reference_extents": REF_EXTENTS, "runs": {}}
    for (n, _), (rows, info) in sorted(results.items()):
        c = compare(rows[rows[:, 0] <= a.t_loop + 1e-9], ref)
        call = compare(rows, ref)
        errs = {k: c[k] - REF_EXTENTS[k] for k in REF_EXTENTS if k in c}
        summary["runs"][f"{n}"] = {"first_loop": c, "all": call, "info": info}
        print(
            f"| {n} | {info['dt']:.2e} | {info['zeta']:.3f} | {fmt(c.get('t_loop'), 2)} | "
            + " | ".join(f"{fmt(c.get(k))} ({errs.get(k, float('nan')):+.3f})" for k in REF_EXTENTS)
            + f" | {fmt(c['rms_first_loop'], 4)} | {fmt(call['rms_all'], 4)} "
            f"({call['covered']}/{call['n_ref']}, t<={call['t_end']:g}) | {c.get('area_change_loop', float('nan')):+.3f} "
            f"| {info['wall_s']:.0f} |"
        )

    if a.sens_n:
        n = a.sens_n
        print()
        print(f"Sensitivity at {n}^2, t <= {a.t_loop:g} (first loop):")
        print(
            "| variant | lambda_f (c) | kappa | zeta | x_max | x_min | y_max | y_min | RMS dist. first loop "
            "| max gap to base (same t) | max gap to previous level | area change first loop |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        rows_of = {}
        sens = {}
        for name, kw, prev in SENSITIVITY:
            rows, info, _ = run_cached(n, a.t_loop, out_dir=a.out, log=log, **kw, **blend_kw)
            rows = rows[rows[:, 0] <= a.t_loop + 1e-9]
            rows_of[name] = rows
            c = compare(rows, ref)
            gap = max_gap(rows, rows_of["base"])
            gprev = max_gap(rows, rows_of[prev]) if prev else float("nan")
            sens[name] = {
                "kw": kw,
                "first_loop": c,
                "gap_to_base": gap,
                "gap_to_previous": gprev,
                "info": info,
            }
            lam = kw.get("lambda_f", 100.0)
            print(
                f"| {name} | {lam:g} ({np.sqrt(lam):.1f}) | {kw.get('kappa', 10.0):g} | {info['zeta']:.3f} | "
                + " | ".join(fmt(c.get(k)) for k in REF_EXTENTS)
                + f" | {fmt(c['rms_first_loop'], 4)} | {gap:.4f} | {fmt(gprev, 4)} "
                f"| {c.get('area_change_loop', float('nan')):+.3f} |"
            )
        summary["sensitivity"] = sens

    n_snap = max(grids)
    _, _, snaps = run_cached(
        n_snap, a.t_span if n_snap in span else a.t_loop, out_dir=a.out, **blend_kw
    )
    figure(results, ref, snaps, n_snap, Path(a.figure))
    with open(Path(a.out) / "summary.json", "w") as f:
        json.dump(summary, f, indent=1, default=float)
    print(f"\nfigure: {a.figure}; numbers: {Path(a.out) / 'summary.json'}")


if __name__ == "__main__":
    main()
