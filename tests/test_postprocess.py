"""`refmap plot`, `refmap movie`, `refmap info` on a synthetic run folder whose fields and
diagnostics have known values (no solver needed), and their errors (exit 2, named value)."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from refmap.cli import app
from refmap.grid import Grid
from refmap.io import RunWriter
from refmap.postprocess import PostprocessError, field_at, format_info, nearest_frame, run_info
from refmap.scenarios import get_case

runner = CliRunner()
GRID = Grid(24, 20, -2.0, 2.0, -2.0, 2.0)  # nx != ny on purpose
TIMES = (0.0, 0.5, 1.0, 1.5)
DIAG = [  # t, step, dt, dt_limit, steps_in_frame, wall_s, fluid_mass, solid_area
    (0.0, 0, 0.0, "", 0, 0.0, 16.0, 2.0),
    (0.5, 10, 0.05, "viscous", 10, 1.0, 16.004, 1.9995),
    (1.0, 30, 0.025, "solid wave", 20, 2.0, 16.01, 1.999),
    (1.5, 50, 0.025, "solid wave", 20, 4.0, 16.016, 1.998),
]


def _fields(t):
    X, Y = GRID.mesh("node")
    Xc, Yc = GRID.mesh("corner")
    one = np.ones_like(Xc)
    return {
        "u": -Y * (1 + t),  # vorticity 2 (1 + t), speed |x| (1 + t)
        "v": X * (1 + t),
        "pressure": t + Xc,
        "sigma_xx": 3.0 * one,
        "sigma_xy": 0.0 * one,
        "sigma_yy": 0.0 * one,  # von Mises 3
        "phi": np.stack([np.hypot(X + 1, Y) - 0.5, np.hypot(X - 1, Y) - 0.6]),
        "J": np.stack([(1.0 + 0.01 * t) * one, (1.1 + 0.01 * t) * one]),
    }


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("post") / "two_discs"
    case = get_case("circle", 24).replace(name="two_discs", grid=GRID)
    meta = {"case": case.to_dict(), "versions": {"refmap": "0.1.0", "jax": "0.10.2", "git": "abcdef0123456789"},
            "command": "refmap run two_discs"}
    with RunWriter(out, GRID, meta) as w:
        for k, t in enumerate(TIMES):
            w.write_frame(k, t, _fields(t), attrs={"step": DIAG[k][1]})
            w.append_diagnostics(dict(zip(("t", "step", "dt", "dt_limit", "steps_in_frame", "wall_s",
                                           "fluid_mass", "solid_area"), DIAG[k], strict=True)))
    return out


def test_derived_fields_at_the_nearest_frame(run_dir):
    assert nearest_frame(run_dir, 0.7)[:2] == (1, 0.5)
    assert nearest_frame(run_dir, 0.8)[:2] == (2, 1.0)
    w = field_at(run_dir, "vorticity", 0.6)
    assert w["time"] == 0.5 and w["data"].shape == (24, 20)
    assert np.allclose(w["data"], 3.0)
    assert w["phis"].shape == (2, 24, 20)
    assert np.allclose(field_at(run_dir, "von_mises", 1.5)["data"], 3.0)
    p = field_at(run_dir, "pressure", 1.0)["data"]
    assert p.shape == (25, 21) and np.allclose(p, 1.0 + GRID.mesh("corner")[0])
    J1 = field_at(run_dir, "J", 1.5, solid=1)
    assert J1["solid"] == 1 and np.allclose(J1["data"], 1.115)


def test_plot_writes_a_png(run_dir, tmp_path):
    out = tmp_path / "w.png"
    r = runner.invoke(app, ["plot", str(run_dir), "--field", "vorticity", "--time", "1.0", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = runner.invoke(app, ["plot", str(run_dir), "--field", "J", "--time", "0", "--solid", "0"])
    assert r.exit_code == 0, r.output
    assert (run_dir / "plots" / "J_0_t0.png").is_file()
    r = runner.invoke(app, ["plot", str(run_dir), "--field", "speed", "--time", "1.4"])
    assert r.exit_code == 0 and (run_dir / "plots" / "speed_t1.5.png").is_file()


@pytest.mark.parametrize(
    "args, named",
    [
        (["plot", "{run}", "--field", "nope", "--time", "1"], ["unknown field 'nope'", "vorticity"]),
        (["plot", "{run}", "--field", "speed", "--time", "7"], ["time 7", "[0, 1.5]"]),
        (["plot", "{run}", "--field", "speed", "--time", "-0.5"], ["time -0.5"]),
        (["plot", "{run}", "--field", "J", "--time", "1"], ["'J' is per solid", "--solid"]),
        (["plot", "{run}", "--field", "J", "--time", "1", "--solid", "5"], ["solid 5"]),
        (["plot", "{run}x", "--field", "speed", "--time", "1"], ["no run folder", "two_discsx"]),
        (["movie", "{run}", "--field", "nope"], ["unknown field 'nope'"]),
        (["movie", "{run}", "--fps", "0"], ["fps", "0"]),
        (["movie", "{run}x"], ["no run folder"]),
        (["info", "{run}x"], ["no run folder", "two_discsx"]),
        (["info", "{parent}"], ["holds no frames"]),
    ],
)
def test_bad_arguments_exit_2_naming_the_value(run_dir, args, named):
    args = [a.format(run=run_dir, parent=run_dir.parent) for a in args]
    r = runner.invoke(app, args)
    assert r.exit_code == 2, r.output
    assert r.output.strip().startswith("error:") and len(r.output.strip().splitlines()) == 1
    for text in named:
        assert text in r.output, (text, r.output)


def test_info_reports_dt_statistics_and_conservation(run_dir):
    info = run_info(run_dir)
    assert info["frames_written"] == 4 and info["steps"] == 50 and info["wall_time_s"] == 4.0
    assert info["dt"]["min"] == 0.025 and info["dt"]["max"] == 0.05
    assert info["dt"]["mean"] == pytest.approx(0.1 / 3)
    assert info["dt"]["mean_all_steps"] == pytest.approx(1.5 / 50)
    assert info["dt_limits"] == pytest.approx({"solid wave": 2 / 3, "viscous": 1 / 3})
    assert info["conservation"]["fluid_mass"]["relative_change"] == pytest.approx(1e-3)
    assert info["conservation"]["solid_area"]["relative_change"] == pytest.approx(-1e-3)
    assert info["checkpoint"] is None
    text = format_info(info)
    r = runner.invoke(app, ["info", str(run_dir)])
    assert r.exit_code == 0 and r.output.strip() == text.strip()
    for s in ("two_discs on 24 x 20", "4 frames", "50 steps", "solid wave 67%", "viscous 33%",
              "+1.000e-03", "-1.000e-03", "jax 0.10.2", "git abcdef012345", "checkpoint  none"):
        assert s in text, s


def test_movie(run_dir, tmp_path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    try:
        imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError:
        pytest.skip("no ffmpeg")
    out = tmp_path / "p.mp4"
    r = runner.invoke(app, ["movie", str(run_dir), "--field", "pressure", "--out", str(out), "--fps", "4"])
    assert r.exit_code == 0, r.output
    nframes, secs = imageio_ffmpeg.count_frames_and_secs(str(out))
    assert nframes == len(TIMES) and secs == pytest.approx(1.0, abs=0.3)
    r = runner.invoke(app, ["movie", str(run_dir), "--field", "J", "--solid", "1"])
    assert r.exit_code == 0, r.output
    assert (run_dir / "J_1.mp4").stat().st_size > 0


def test_postprocess_error_is_a_value_error():
    assert issubclass(PostprocessError, ValueError)
