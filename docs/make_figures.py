"""Regenerate the scenario pictures of docs/scenarios.md and docs/fssi.md.

    python docs/make_figures.py            # runs what is missing, then draws
    python docs/make_figures.py fssi       # only the several-solid pictures (docs/fssi.md)
    python docs/make_figures.py 3d         # only the 3D scenarios (docs/scenarios.md)
Runs (into runs/doc_*) the thesis's scenarios at 128^2 (stick at 96^2) and the FSSI
scenarios two_balls and ball_stick at 96^2 with the `refmap run` command and draws panels
of a field at chosen times, with the interface of every solid, into docs/img/.
"""

import subprocess
import sys
from pathlib import Path

import numpy as np

import refmap
from refmap.io import save_panel_png, save_surface_png

ROOT = Path(__file__).resolve().parents[1]
RUNS = {
    "circle": (["--n", "128", "--t-end", "5", "--frames", "20"], [0.0, 0.5, 1.0, 5.0]),
    "stick": (["--n", "96", "--t-end", "20", "--frames", "20"], [0.0, 4.0, 7.0, 10.0]),
    "rotor": (["--n", "128", "--t-end", "10", "--frames", "40"], [0.0, 2.5, 5.0, 10.0]),
}
# several solids with contact (docs/fssi.md): (run options, times drawn, field drawn)
FSSI_RUNS = {
    "two_balls": (
        ["--n", "96", "--t-end", "16", "--frames", "16"],
        [0.0, 2.0, 3.0, 4.0, 8.0, 16.0],
        "pressure",
    ),
    "ball_stick": (
        ["--n", "96", "--t-end", "8", "--frames", "32"],
        [0.0, 0.5, 1.0, 2.0, 4.0, 8.0],
        "pressure",
    ),
}

# 3D scenarios (docs/scenarios.md, "3D"): (run options, times drawn, slice); a slice of the
# pressure (the middle z plane unless the slice says otherwise) and a 3D view of the
# surfaces at the last time
RUNS_3D = {
    "sphere_relax": (["--n", "32", "--t-end", "2", "--frames", "8"], [0.0, 0.25, 0.5, 2.0], {}),
    "sphere_cavity": (["--n", "32", "--t-end", "4", "--frames", "8"], [0.0, 1.0, 2.0, 4.0], {}),
    "cross": (["--n", "32", "--t-end", "4", "--frames", "8"], [0.0, 1.0, 2.0, 4.0], {}),
    # the plane z = -0.3 cuts three of the four spheres
    "spheres_settle": (["--n", "32", "--frames", "16"], [0.0, 1.0, 2.0, 8.0],
                       {"slice_axis": "z", "slice_at": -0.3}),
}
# the axis drawn upwards in the surface view (gravity along -y in spheres_settle)
VERTICAL_3D = {"spheres_settle": "y"}


def _run(name, args, prefix="doc"):
    run = ROOT / "runs" / f"{prefix}_{name}"
    if not (run / "summary.json").exists():
        subprocess.run(
            [
                sys.executable,
                "-m",
                "refmap",
                "run",
                name,
                *args,
                "--out",
                str(run),
                "--overwrite",
                "--no-progress",
            ],
            check=True,
        )
    return run


def _panels(run, times, field):
    ds = refmap.open_run(run)
    grid = refmap.io.grid_from_attrs(ds.attrs)
    panels = []
    for t in times:
        i = int(np.argmin(np.abs(ds.time.values - t)))
        panels.append(
            (float(ds.time[i]), ds[field].isel(time=i).values, ds["phi"].isel(time=i).values)
        )
    return grid, panels


def scenario_figures():
    for name, (args, times) in RUNS.items():
        grid, panels = _panels(_run(name, args), times, "pressure")
        out = ROOT / "docs" / "img" / f"{name}_pressure.png"
        save_panel_png(out, grid, panels, "pressure", "corner", ncols=2)
        print("wrote", out)


def fssi_figures():
    """docs/img/fssi_<scenario>.png: six times of each FSSI scenario, every solid's
    interface drawn in black over the field."""
    for name, (args, times, field) in FSSI_RUNS.items():
        grid, panels = _panels(_run(name, args, "doc_fssi"), times, field)
        out = ROOT / "docs" / "img" / f"fssi_{name}.png"
        save_panel_png(out, grid, panels, field, "corner", ncols=3)
        print("wrote", out)


def figures_3d():
    """docs/img/<scenario>_pressure.png (the middle z plane at four times) and
    docs/img/<scenario>_surface.png (the solid's surface at the last time drawn)."""
    for name, (args, times, plane) in RUNS_3D.items():
        run = _run(name, args)
        grid, panels = _panels(run, times, "pressure")
        out = ROOT / "docs" / "img" / f"{name}_pressure.png"
        save_panel_png(out, grid, panels, "pressure", "corner", ncols=2, **plane)
        print("wrote", out)
        t, _, phis = panels[-1]
        out = ROOT / "docs" / "img" / f"{name}_surface.png"
        save_surface_png(out, phis, grid, time=t, vertical=VERTICAL_3D.get(name, "z"))
        print("wrote", out)


def main():
    (ROOT / "docs" / "img").mkdir(exist_ok=True)
    what = sys.argv[1:] or ["scenarios", "fssi", "3d"]
    if "scenarios" in what:
        scenario_figures()
    if "fssi" in what:
        fssi_figures()
    if "3d" in what:
        figures_3d()


if __name__ == "__main__":
    main()
