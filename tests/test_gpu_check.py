"""benchmarks/gpu_check.py (the GPU command's script) keeps working on a CPU-only machine:
its parity check of a backend against itself is exact, and a throughput row is printed."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_gpu_check_runs_on_cpu(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("gpu_check", ROOT / "benchmarks" / "gpu_check.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "g.json"
    rc = mod.main(["--sizes", "32", "--steps", "2", "--parity-n", "32", "--parity-steps", "5",
                   "--json", str(out)])
    assert rc == 0
    d = json.loads(out.read_text())
    assert d["parity_ok"] and len(d["parity"]) == 8
    # the default backend is the CPU here, so both runs are the same computation: bitwise equal
    assert all(r["rel_diff"] == 0.0 for r in d["parity"])
    assert d["throughput"][0]["n"] == 32 and d["throughput"][0]["ms_per_step"] > 0
    assert "PARITY OK" in capsys.readouterr().out
