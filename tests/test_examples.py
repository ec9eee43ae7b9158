"""The documented examples run (at tiny resolution)."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_api_quickstart_runs(tmp_path):
    env = dict(os.environ, REFMAP_EXAMPLE_N="32", REFMAP_EXAMPLE_T="0.1", REFMAP_EXAMPLE_OUT=str(tmp_path),
               MPLBACKEND="Agg")
    r = subprocess.run([sys.executable, str(ROOT / "examples" / "api_quickstart.py")], env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "holed_block" / "u_final.png").is_file()
    assert (tmp_path / "holed_block" / "run.xdmf").is_file()


def test_example_case_files_validate():
    from refmap.casefile import load_case

    for f in sorted((ROOT / "examples").glob("*.toml")):
        case = load_case(f, {"n": 32})
        assert case.solids, f


def test_spinning_square_example_starts_from_its_formula_and_runs(tmp_path):
    """examples/spinning_square.toml ([initial_velocity] formulas): frame 0 holds the
    formula's rigid rotation on the square, and a few steps run."""
    import numpy as np

    import refmap
    from refmap.casefile import load_run
    from refmap.simulation import Simulation

    plan = load_run(ROOT / "examples" / "spinning_square.toml", {"n": 32, "t_end": 0.02, "frames": 1})
    Simulation(plan.case, tmp_path / "run", progress=False, pictures=False).run()
    ds = refmap.open_run(tmp_path / "run")
    X, Y = plan.case.grid.mesh("node")
    fade = 0.5 * (1 - np.tanh((np.hypot(X, Y) - 1.2) / 0.1))
    u0, v0 = ds["u"].isel(time=0).values, ds["v"].isel(time=0).values
    # the formula, evaluated by numpy in the same order: equal to round-off
    assert np.allclose(u0, -0.5 * Y * 0.5 * (1 - np.tanh((np.hypot(X, Y) - 1.2) / 0.1)),
                       rtol=1e-14, atol=1e-15)
    assert np.allclose(v0, 0.5 * X * fade, rtol=1e-14, atol=1e-15)
    inside = np.hypot(X, Y) < 0.8  # the square's nodes spin rigidly (fade 1 - 3.4e-4 at r = 0.8)
    assert np.allclose(u0[inside], -0.5 * Y[inside], rtol=4e-4, atol=0)
    assert float(ds.time[-1]) == 0.02 and np.isfinite(ds["u"].isel(time=-1).values).all()
