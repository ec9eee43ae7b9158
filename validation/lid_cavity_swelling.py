"""Where the lid-driven cavity's disc swells (issue 15, item 4): J by distance to the
interface, and how much reference material the contour holds, at t = 3, 6, 9, 12.

    python validation/lid_cavity_swelling.py 64 conserved     # or: advected

Printed per time: the disc's area (sum of its blended solid fraction, as the validation page
reports it) and the node count of phi < 0, both relative to pi R^2 - 1; ``material``, the
reference area inside the contour, sum over phi < 0 of det(grad xi) h^2, relative to pi R^2
- 1 (zero while the contour holds exactly the disc's material); and the mean J = 1 /
det(grad xi) deep inside (phi < -3h), near the interface (-3h <= phi < -h) and in the last
cell (-h <= phi < 0).  Results: docs/method.md, known weaknesses, item 4 (e).
"""

import sys

import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import lid_cavity as L  # noqa: E402

from refmap.convergence import node_gradient  # noqa: E402
from refmap.grid import Grid  # noqa: E402


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2 or argv[1] not in ("advected", "conserved"):
        raise SystemExit("usage: lid_cavity_swelling.py N advected|conserved")
    n, mode = int(argv[0]), argv[1]
    h = 1.0 / n
    grid = Grid(n, n, 0.0, 1.0, 0.0, 1.0)
    disc = np.pi * L.RADIUS**2
    print(f"lid-driven cavity, {n}^2, fluid_mass = {mode}")
    state, area0 = None, None
    for t_end in (3.0, 6.0, 9.0, 12.0):
        rows, state, _, _ = L.run(n, t_end, state=state, fluid_mass=mode, snap_every=100.0)
        area0 = rows[0, 3] if area0 is None else area0
        xi, phi = np.asarray(state.xi[0]), np.asarray(state.phi[0])
        gx, gy = node_gradient(xi[0], grid), node_gradient(xi[1], grid)
        det = gx[0] * gy[1] - gx[1] * gy[0]
        inside = phi < 0
        layers = []
        for lo, hi in ((-np.inf, -3.0), (-3.0, -1.0), (-1.0, 0.0)):
            m = (phi >= lo * h) & (phi < hi * h)
            layers.append(f"J[{lo:g}h,{hi:g}h) {np.mean(1.0 / det[m]):.4f}")
        print(
            f"t = {t_end:4.1f}  area {rows[-1, 3] / area0 - 1:+.4f}  "
            f"count {inside.sum() * h * h / disc - 1:+.4f}  "
            f"material {det[inside].sum() * h * h / disc - 1:+.4f}  " + "  ".join(layers),
            flush=True,
        )


if __name__ == "__main__":
    main()
