"""Validation figures of two source trees side by side (before/after a change).

Each tree is a git revision (checked out into a temporary worktree) or a folder holding a
``src/refmap`` package; every figure is computed in a separate process that imports refmap
from that tree, so the two runs cannot share caches or code.  The figures are the small,
CI-sized versions of the validation pages:

* ``shear``: the finite-amplitude shear wave, max error of u at n = 16, 32 and the order;
* ``rotor``: the rotor ladder 24, 32, 48 against 96 at t = 0.5 (L2 orders of u, xi_x, grad xi);
* ``couette``: the Couette sandwich at ny = 20 (L2 error of u, interface amplitude and
  phase errors against the closed form);
* ``cavity``: the lid-driven cavity disc at 32^2 over its first loop (extents against
  Sugiyama et al., RMS path distance, area change).

Usage::

    python validation/compare_revisions.py main HEAD            # two revisions
    python validation/compare_revisions.py 5e5da9d . --only shear,rotor

Prints one table row per figure, old | new | ratio (or difference).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT.parent / "shared" / "data" / "lid_cavity_disc_sugiyama2011_1024.csv"

_SHEAR = """
import inspect, math
from shear_wave import run
# the same setup in every revision: the undamped forward-Euler wave that scripts before
# 2026-12 ran (fine for half a period at 16^2 and 32^2; see shear_wave.py)
kw = {"integrator": "explicit-undamped"} if "integrator" in inspect.signature(run).parameters else {}
e16 = run(16, **kw)[0]; e32 = run(32, **kw)[0]
out = dict(shear_u16=e16, shear_u32=e32, shear_order=math.log(e16 / e32, 2))
"""

_ROTOR = """
import inspect
from refmap.convergence import analyse, run_ladder
# the thesis's explicit step (the scenario's own is implicit since 2026-12-05)
kw = {"viscosity": "explicit"} if "viscosity" in inspect.signature(run_ladder).parameters else {}
res = run_ladder("rotor", [24, 32, 48], 96, 0.5, WORK, **kw)
st = analyse([res[n]["path"] for n in (24, 32, 48)], res[96]["path"])
out = {f"rotor_order_{q}": st.orders[q]["l2"] for q in ("u", "xi_x", "grad_xi")}
out.update({f"rotor_err48_{q}": st.errors[q]["l2"][-1] for q in ("u", "xi_x", "grad_xi")})
"""

_COUETTE = """
import couette as cou
ref = cou.reference("uniform")
r = cou.run_2d(20, "uniform")
e = cou.errors(r, ref)
amp, ph = cou.interface_amplitude_phase(1.0)
a, p = cou.interface_fit(r)
out = dict(couette_l2=max(v[0] for v in e.values()), couette_amp_err=abs(a - amp) / amp,
           couette_phase_err=abs(p - ph))
"""

_CAVITY = """
import sys
import numpy as np
import lid_cavity as L
sys.modules["lid_cavity"] = L
rows, *_ = L.run(32, 9.0, every=0.05)
c = L.compare(rows, L.load_reference(REF))
out = {f"cavity_{k}_err": abs(c[k] - v) for k, v in L.REF_EXTENTS.items()}
out["cavity_rms_loop"] = c["rms_first_loop"]
out["cavity_area_change_loop"] = c["area_change_loop"]
out["cavity_area_change_max"] = float(np.abs(rows[:, 3] / rows[0, 3] - 1).max())
"""

FIGURES = {"shear": _SHEAR, "rotor": _ROTOR, "couette": _COUETTE, "cavity": _CAVITY}


def _tree(rev: str, tmp: Path) -> Path:
    """A folder holding src/refmap for ``rev`` (a folder is used as it is)."""
    p = Path(rev)
    if (p / "src" / "refmap").is_dir():
        return p.resolve()
    dest = tmp / rev.replace("/", "_")
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(dest), rev],
                   check=True, capture_output=True)
    return dest


def _figure(tree: Path, name: str, work: Path) -> dict:
    """Run one figure in a fresh process importing refmap (and validation/) from ``tree``."""
    code = (
        "import json, sys\n"
        f"WORK = {str(work)!r}\n"
        f"REF = {str(REFERENCE)!r}\n"
        + FIGURES[name]
        + "\nprint('@@' + json.dumps({k: float(v) for k, v in out.items()}))\n"
    )
    env = dict(os.environ, PYTHONPATH=f"{tree / 'src'}{os.pathsep}{tree / 'validation'}",
               MPLBACKEND="Agg")
    # the validation scripts read the reference data from ../shared beside the repo: run
    # from the repository's validation folder of the tree so their relative paths hold
    r = subprocess.run([sys.executable, "-c", code], cwd=tree / "validation", env=env,
                       capture_output=True, text=True)
    for line in r.stdout.splitlines():
        if line.startswith("@@"):
            return json.loads(line[2:])
    raise RuntimeError(f"{name} failed in {tree}:\n{r.stderr[-3000:]}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", help="git revision or folder (the baseline)")
    ap.add_argument("new", help="git revision or folder (the change)")
    ap.add_argument("--only", default=",".join(FIGURES), help="comma list of " + ",".join(FIGURES))
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    a = ap.parse_args(argv)
    names = [s.strip() for s in a.only.split(",") if s.strip()]
    bad = [s for s in names if s not in FIGURES]
    if bad:
        ap.error(f"unknown figure(s) {bad}; choose from {sorted(FIGURES)}")
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        trees = [_tree(a.old, tmp), _tree(a.new, tmp)]
        res = {"old": {}, "new": {}}
        for name in names:
            for label, tree in zip(("old", "new"), trees, strict=True):
                work = tmp / f"{label}_{name}"
                work.mkdir()
                res[label].update(_figure(tree, name, work))
                print(f"  {label} {name}: done", file=sys.stderr, flush=True)
        for t in trees:
            if str(t).startswith(str(tmp)):
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(t)],
                               capture_output=True)
    print(f"{'figure':32s} {'old':>12s} {'new':>12s} {'new/old':>9s}")
    for k in res["old"]:
        o, n = res["old"][k], res["new"].get(k, float("nan"))
        ratio = n / o if o else float("nan")
        print(f"{k:32s} {o:12.4g} {n:12.4g} {ratio:9.3f}")
    if a.json:
        a.json.write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
