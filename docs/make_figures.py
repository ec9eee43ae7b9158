"""Regenerate the scenario pictures of docs/scenarios.md.

    python docs/make_figures.py            # runs what is missing, then draws
Runs (into runs/doc_*) the thesis's scenarios at 128^2 (stick at 96^2) with the
`refmap run` command and draws pressure panels at chosen times into docs/img/.
"""

import subprocess
import sys
from pathlib import Path

import numpy as np

import refmap
from refmap.io import save_panel_png

ROOT = Path(__file__).resolve().parents[1]
RUNS = {
    "circle": (["--n", "128", "--t-end", "5", "--frames", "20"], [0.0, 0.5, 1.0, 5.0]),
    "stick": (["--n", "96", "--t-end", "20", "--frames", "20"], [0.0, 4.0, 7.0, 10.0]),
    "rotor": (["--n", "128", "--t-end", "10", "--frames", "40"], [0.0, 2.5, 5.0, 10.0]),
}


def main():
    (ROOT / "docs" / "img").mkdir(exist_ok=True)
    for name, (args, times) in RUNS.items():
        run = ROOT / "runs" / f"doc_{name}"
        if not (run / "summary.json").exists():
            subprocess.run([sys.executable, "-m", "refmap", "run", name, *args, "--out", str(run),
                            "--overwrite", "--no-progress"], check=True)
        ds = refmap.open_run(run)
        grid = refmap.io.grid_from_attrs(ds.attrs)
        panels = []
        for t in times:
            i = int(np.argmin(np.abs(ds.time.values - t)))
            panels.append((float(ds.time[i]), ds["pressure"].isel(time=i).values, ds["phi"].isel(time=i).values))
        out = ROOT / "docs" / "img" / f"{name}_pressure.png"
        save_panel_png(out, grid, panels, "pressure", "corner", ncols=2)
        print("wrote", out)


if __name__ == "__main__":
    main()
