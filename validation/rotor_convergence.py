"""Rotor grid convergence (thesis section 4.10; VALIDATION.md section 3).

The thesis runs the rotor to t = 4 on 60^2, 72^2, 90^2, 120^2 and 180^2 and compares each
with a 360^2 run in the discrete L2 norm of eq. 4.30; it reports observed orders 1.26 for the
horizontal fluid velocity u, 1.55 for the horizontal reference-map component and 1.32 for a
derivative of it (the reference-map figures use only 60^2, 120^2 and 180^2).

This script runs (or reuses) those rungs with :mod:`refmap.convergence` and reports several
comparisons, so that the effect of the reference's own error can be seen:

* ``thesis``: 60, 72, 90, 120, 180 against 360 (the thesis's set-up; 360 is only 2x finer
  than 180);
* ``thesis_xi``: 60, 120, 180 against 360 (the thesis's rungs for xi and its derivative);
* ``ref3x``: 60, 72, 90, 120 against 360 (reference 3x finer than the finest rung);
* ``vs180``: 60, 72, 90 against 180 (reference 2x finer; no 360 run needed);
* ``vs180_all``: 60, 72, 90, 120 against 180;
* ``vs240``, ``vs240_all``: 60, 72, 90 (and 120) against 240 (needs ``--with-240``, about
  27,000 steps of the 240^2 rung, ~50 minutes of one core).

Regenerate (the 360^2 rung is ~60,000 steps, about two hours of one core; the others take
about ten minutes together; finished rungs in --out are reused, an interrupted 360^2 run
continues from its last checkpoint)::

    python validation/rotor_convergence.py --out /work/runs/rotor_conv
    python validation/rotor_convergence.py --out /work/runs/rotor_conv --no-run  # analyse only

Writes docs/img/rotor_convergence.png (thesis set-up; or the vs180 comparison while the
360^2 rung is missing), docs/img/rotor_convergence_vs180.png,
docs/img/rotor_convergence_vs240.png (with the 240^2 rung), and OUT/summary.md +
OUT/<comparison>.csv.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from refmap.convergence import (
    analyse,
    format_table,
    plot_study,
    run_ladder,
    rung_path,
    write_csv,
)

ROOT = Path(__file__).resolve().parents[1]
THESIS = {"u": 1.26, "xi_x": 1.55, "grad_xi": 1.32}
T_END = 4.0
LADDER = [60, 72, 90, 120, 180]
REF = 360
COMPARISONS = {
    "thesis": ([60, 72, 90, 120, 180], 360),
    "thesis_xi": ([60, 120, 180], 360),
    "ref3x": ([60, 72, 90, 120], 360),
    "vs180": ([60, 72, 90], 180),
    "vs180_all": ([60, 72, 90, 120], 180),
    "vs240": ([60, 72, 90], 240),
    "vs240_all": ([60, 72, 90, 120], 240),
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--out", type=Path, default=ROOT / "runs" / "rotor_conv", help="folder of the rungs"
    )
    ap.add_argument("--jobs", type=int, default=1, help="rungs run at once (separate processes)")
    ap.add_argument("--no-run", action="store_true", help="only analyse the rungs already in --out")
    ap.add_argument("--margin", type=float, default=1.0, help="solid margin in coarse cells")
    ap.add_argument(
        "--img", type=Path, default=ROOT / "docs" / "img", help="folder for the figures"
    )
    ap.add_argument(
        "--with-240", action="store_true", help="also run the 240^2 reference (vs240 rows)"
    )
    ap.add_argument(
        "--kernel",
        default=None,
        help="blend kernel:width for every rung (e.g. sine:1; default the rotor's own, erf:2); "
        "use its own --out and --img",
    )
    ap.add_argument(
        "--ladder",
        default=",".join(map(str, LADDER)),
        help="rungs to run (default the thesis's); the reference is --ref",
    )
    ap.add_argument("--ref", type=int, default=REF, help="reference grid to run (default 360)")
    a = ap.parse_args(argv)

    if not a.no_run:
        if a.with_240:
            run_ladder("rotor", [60, 72, 90, 120], 240, T_END, a.out, jobs=a.jobs,
                       viscosity="explicit", kernel=a.kernel)
        run_ladder("rotor", a.ladder, a.ref, T_END, a.out, jobs=a.jobs, viscosity="explicit",
                   kernel=a.kernel)
    have = {n for n in [*LADDER, REF, 240] if rung_path(a.out, "rotor", n).exists()}
    lines = [
        "| comparison | rungs | reference | u | v | xi_x | xi_y | grad_xi |",
        "|---|---|---|---|---|---|---|---|",
        "| thesis (sec. 4.10) | 60-180 (xi: 60, 120, 180) | 360 | 1.26 | - | 1.55 | - | 1.32 |",
    ]
    studies = {}
    for name, (rungs, ref) in COMPARISONS.items():
        if not set([*rungs, ref]) <= have:
            print(f"{name}: skipped, missing rungs {sorted(set([*rungs, ref]) - have)}")
            continue
        st = analyse(
            [rung_path(a.out, "rotor", n) for n in rungs],
            rung_path(a.out, "rotor", ref),
            margin=a.margin,
        )
        studies[name] = st
        print(f"\n== {name} ==")
        print(format_table(st))
        write_csv(st, a.out / f"{name}.csv")
        o, oc = st.orders, st.orders_refcorr
        lines.append(
            f"| {name} | {', '.join(map(str, rungs))} | {ref} | "
            + " | ".join(
                f"{o[q]['l2']:.2f} ({oc[q]['l2']:.2f})"
                for q in ("u", "v", "xi_x", "xi_y", "grad_xi")
            )
            + " |"
        )
    if not studies:
        print("no comparison possible yet", file=sys.stderr)
        return 1
    summary = "\n".join(lines)
    print(
        "\nObserved orders, least-squares fit of the discrete L2 errors "
        "(in brackets: allowing for the reference's own error):\n" + summary
    )
    (a.out / "summary.md").write_text(summary + "\n", encoding="utf-8")
    a.img.mkdir(parents=True, exist_ok=True)
    if "vs180" in studies:
        plot_study(
            studies["vs180"],
            a.img / "rotor_convergence_vs180.png",
            title="rotor, t = 4: 60, 72, 90 against 180 (reference 2x finer)",
        )
    if "vs240_all" in studies:
        plot_study(
            studies["vs240_all"],
            a.img / "rotor_convergence_vs240.png",
            title="rotor, t = 4: 60-120 against 240 (reference 2x finer)",
        )
    if "thesis" in studies:
        plot_study(
            studies["thesis"],
            a.img / "rotor_convergence.png",
            title="rotor, t = 4: 60-180 against 360 (the thesis's set-up)",
        )
    elif "vs180_all" in studies:  # until the 360^2 rung exists: the best comparison we have
        plot_study(
            studies["vs180_all"],
            a.img / "rotor_convergence.png",
            title="rotor, t = 4: 60-120 against 180 (the 360^2 reference is still missing)",
        )
    print(f"figures in {a.img}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
