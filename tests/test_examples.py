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
