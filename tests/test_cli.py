"""The command line end to end, as a user runs it."""

import json

import numpy as np
from typer.testing import CliRunner

import refmap
from refmap.cli import app

runner = CliRunner()


def test_list_shows_the_scenarios():
    r = runner.invoke(app, ["list"])
    assert r.exit_code == 0
    for name in ("circle", "stick", "rotor"):
        assert name in r.output


def test_run_writes_a_usable_run_folder(tmp_path):
    out = tmp_path / "circle"
    r = runner.invoke(app, ["run", "circle", "--n", "32", "--t-end", "0.1", "--frames", "2",
                            "--out", str(out), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "steps/s" in r.output
    for f in ("run.xdmf", "diagnostics.csv", "metadata.json", "pressure_panels.png", "summary.json"):
        assert (out / f).is_file(), f
    assert len(list((out / "frames").glob("frame_*.h5"))) == 3
    assert list((out / "pictures").glob("*.png"))
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["case"]["name"] == "circle" and meta["versions"]["jax"]
    ds = refmap.open_run(out)
    assert np.allclose(ds.time.values, [0.0, 0.05, 0.1])
    assert ds["u"].dims == ("time", "x", "y")
    assert ds["phi"].dims == ("time", "solid", "x", "y")
    assert ds["pressure"].dims == ("time", "xc", "yc")
    assert np.all(np.isfinite(ds["u"].values))


def test_bad_input_exits_with_a_named_error(tmp_path):
    r = runner.invoke(app, ["run", "nope", "--out", str(tmp_path / "a")])
    assert r.exit_code == 2 and "unknown scenario 'nope'" in r.output
    r = runner.invoke(app, ["run", "circle", "--n", "4", "--out", str(tmp_path / "b")])
    assert r.exit_code == 2 and "grid size" in r.output
    r = runner.invoke(app, ["run", "circle", "--t-end", "-1", "--out", str(tmp_path / "c")])
    assert r.exit_code == 2 and "t_end" in r.output and "-1" in r.output
    r = runner.invoke(app, ["run", "circle", "--cfl", "3", "--out", str(tmp_path / "d")])
    assert r.exit_code == 2 and "cfl" in r.output
    # nothing was written for rejected input
    assert not (tmp_path / "a").exists() and not (tmp_path / "c").exists()


def test_show_and_run_a_case_file(tmp_path):
    r = runner.invoke(app, ["show", "circle", "--n", "32"])
    assert r.exit_code == 0 and "[grid]" in r.output
    path = tmp_path / "circle.toml"
    path.write_text(r.output)
    out = tmp_path / "run"
    r = runner.invoke(app, ["run", str(path), "--t-end", "0.05", "--frames", "1", "--out", str(out),
                            "--no-progress", "--no-pictures"])
    assert r.exit_code == 0, r.output
    ds = refmap.open_run(out)
    assert ds.sizes["time"] == 2
    bad = tmp_path / "bad.toml"
    bad.write_text(path.read_text().replace("G = 10.0", "G = -3.0"))
    r = runner.invoke(app, ["run", str(bad), "--out", str(tmp_path / "x")])
    assert r.exit_code == 2 and "G" in r.output and "-3" in r.output
