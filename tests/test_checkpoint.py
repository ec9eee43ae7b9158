"""Checkpoint and restart: a resumed run equals an uninterrupted one bit for bit; Ctrl-C
checkpoints the last completed frame; an interrupted checkpoint write loses nothing."""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest
from typer.testing import CliRunner

import refmap  # noqa: F401  (float64)
from refmap.checkpoint import (
    CHECKPOINT_FILE,
    PREV_CHECKPOINT_FILE,
    CheckpointError,
    load_checkpoint,
    rebuild_case,
    save_checkpoint,
)
from refmap.cli import app
from refmap.io import open_diagnostics, open_run
from refmap.scenarios import get_case
from refmap.simulation import Simulation
from refmap.state import FluidParams, State

runner = CliRunner()
FIELDS = ("t", "step", "v", "rho_f", "xi", "phi")


def tiny_case(t_end=0.04, frames=4):
    return get_case("circle", 24).replace(t_end=t_end, frames=frames)


def same_state(a, b):
    return {f: np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f))) for f in FIELDS}


def strip_wall(df):
    return df.drop(columns=["wall_s"])


@pytest.fixture(scope="module")
def straight(tmp_path_factory):
    """The reference: one uninterrupted run (checkpoint every frame)."""
    out = tmp_path_factory.mktemp("straight") / "run"
    sim = Simulation(tiny_case(), out, progress=False, pictures=False)
    sim.run()
    return sim


class Killed(Exception):
    """Stands in for the process dying."""


def _killed_after_frame_3(case, out):
    """Run ``case`` into ``out`` with a checkpoint every 2 frames and "kill" it once frame 3
    is written (so the checkpoint holds frame 2); returns ``out``."""
    sim = Simulation(case, out, progress=False, pictures=False, checkpoint_every=2)

    def die(i, state):
        if i == 3:
            raise Killed

    with pytest.raises(Killed):
        sim.run(on_frame=die)
    return out


def test_kill_and_resume_is_bitwise_identical(straight, tmp_path):
    out = tmp_path / "killed"
    sim = Simulation(tiny_case(), out, progress=False, pictures=False, checkpoint_every=2)

    def die(i, state):
        if i == 3:  # frame 3 is written but not checkpointed (checkpoint_every=2)
            raise Killed

    with pytest.raises(Killed):
        sim.run(on_frame=die)
    assert (out / "frames" / "frame_00003.h5").is_file()
    st, info = load_checkpoint(out)
    assert info["frame_index"] == 2 and info["next_frame"] == 3 and info["diag_rows"] == 3
    assert len(open_diagnostics(out)) == 4

    res = Simulation.resume(out, progress=False, pictures=False)
    assert res.case.to_dict() == straight.case.to_dict()
    final = res.run()
    assert all(same_state(final, straight.state).values()), same_state(final, straight.state)
    # the run folder is the one an uninterrupted run writes
    a, b = open_run(straight.out_dir), open_run(out)
    assert np.array_equal(a.time.values, b.time.values)
    for name in ("u", "v", "rho_f", "phi", "xi_x", "pressure"):
        assert np.array_equal(a[name].values, b[name].values, equal_nan=True), name
    da, db = strip_wall(open_diagnostics(straight.out_dir)), strip_wall(open_diagnostics(out))
    assert da.equals(db)
    assert (straight.out_dir / "run.xdmf").read_text() == (out / "run.xdmf").read_text()
    assert res.total_steps == straight.total_steps
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["resumes"][0]["from_frame"] == 2
    # the final checkpoint holds the final state
    st, info = load_checkpoint(out)
    assert all(same_state(st, straight.state).values())
    assert info["frame_index"] == 4 and info["total_steps"] == straight.total_steps


def test_ctrl_c_checkpoints_and_resume_extends_to_the_same_result(straight, tmp_path):
    """Ctrl-C after frame 1 of a shorter run (no periodic checkpoints), then `refmap resume
    --t-end` to the reference's end time: same final state, bit for bit."""
    out = tmp_path / "ctrlc"
    sim = Simulation(tiny_case(t_end=0.02, frames=2), out, progress=False, pictures=False,
                     checkpoint_every=None)

    def ctrl_c(i, state):
        if i == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sim.run(on_frame=ctrl_c)
    st, info = load_checkpoint(out)
    assert info["frame_index"] == 1 and float(st.t) == pytest.approx(0.01)
    assert not (out / PREV_CHECKPOINT_FILE).exists()  # the only checkpoint is the Ctrl-C one

    r = runner.invoke(app, ["resume", str(out), "--t-end", "0.04", "--no-progress", "--no-pictures"])
    assert r.exit_code == 0, r.output
    assert "from frame 1" in r.output
    st, info = load_checkpoint(out)
    assert all(same_state(st, straight.state).values()), same_state(st, straight.state)
    assert np.array_equal(open_run(out).time.values, open_run(straight.out_dir).time.values)
    assert json.loads((out / "metadata.json").read_text())["case"]["t_end"] == 0.04
    da, db = strip_wall(open_diagnostics(straight.out_dir)), strip_wall(open_diagnostics(out))
    assert da.equals(db)
    # resuming a complete run is a no-op that says so
    r = runner.invoke(app, ["resume", str(out), "--no-progress"])
    assert r.exit_code == 0 and "already complete" in r.output
    r = runner.invoke(app, ["resume", str(out), "--t-end", "0.01", "--no-progress"])
    assert r.exit_code == 2 and "t_end 0.01" in r.output


def _fake_state(value):
    return State(t=np.float64(value), step=np.int64(7), v=np.full((2, 4, 3), value),
                 rho_f=np.ones((4, 3)), xi=np.zeros((1, 2, 4, 3)), phi=np.zeros((1, 4, 3)))


def test_interrupted_checkpoint_write_keeps_the_previous_one(straight, tmp_path, monkeypatch):
    import refmap.checkpoint as ck

    run = tmp_path / "run"
    shutil.copytree(straight.out_dir, run)
    good, _ = load_checkpoint(run)

    def half_written(path, arrays, info):  # dies in the middle of the HDF5 file
        path.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 100)
        raise OSError("No space left on device")

    monkeypatch.setattr(ck, "_write_h5", half_written)
    with pytest.raises(OSError, match="No space"):
        save_checkpoint(run, _fake_state(9.0), {"frame_index": 99})
    monkeypatch.undo()

    def no_fsync(fd):
        raise OSError("I/O error")

    monkeypatch.setattr(ck.os, "fsync", no_fsync)
    with pytest.raises(OSError, match="I/O error"):
        save_checkpoint(run, _fake_state(9.0), {"frame_index": 99})
    monkeypatch.undo()

    assert not list(run.glob(".*.tmp")) and not list(run.glob("*.tmp"))
    st, info = load_checkpoint(run)
    assert info["frame_index"] == 4 and all(same_state(st, good).values())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = open_run(run)  # every frame still readable, no leftovers
    assert ds.sizes["time"] == 5


def test_checkpoint_roundtrip_rotation_and_damaged_file(tmp_path):
    save_checkpoint(tmp_path, _fake_state(1.0), {"frame_index": 1, "note": [1, None]})
    save_checkpoint(tmp_path, _fake_state(2.0), {"frame_index": 2})
    st, info = load_checkpoint(tmp_path)
    assert info["frame_index"] == 2 and info["format"] == "refmap-checkpoint-1"
    assert st.step.dtype == np.int64 and st.t.dtype == np.float64 and float(st.t) == 2.0
    assert st.xi.shape == (1, 2, 4, 3)
    # a damaged newest checkpoint: fall back to the previous one, with a warning
    p = tmp_path / CHECKPOINT_FILE
    p.write_bytes(p.read_bytes()[:200])
    with pytest.warns(UserWarning, match="previous checkpoint"):
        st, info = load_checkpoint(tmp_path)
    assert info["frame_index"] == 1 and float(st.t) == 1.0
    (tmp_path / PREV_CHECKPOINT_FILE).unlink()
    with pytest.raises(CheckpointError, match="no usable checkpoint"):
        load_checkpoint(tmp_path)


def test_rebuild_case_refuses_a_case_that_does_not_match(straight):
    _, info = load_checkpoint(straight.out_dir)
    assert rebuild_case(info).to_dict() == straight.case.to_dict()
    other = get_case("circle", 24).replace(fluid=FluidParams(eta=0.5))
    with pytest.raises(CheckpointError, match="fluid.eta"):
        rebuild_case(info, case=other)
    bad = dict(info, case=dict(info["case"], name="my_own_case"))
    with pytest.raises(CheckpointError, match="pass the Case"):
        rebuild_case(bad)


def test_rebuild_a_user_defined_case_from_the_stored_case_file_text():
    from dataclasses import replace

    from refmap.checkpoint import case_toml
    from refmap.geometry import Disc
    from refmap.materials import NeoHookean

    base = get_case("circle", 24)
    solid = replace(base.solids[0], shape=Disc(center=(0.3, 0.1), radius=0.6),
                    law=NeoHookean(G=5.0, kappa=7.0, rho0=1.5), name="soft")
    mine = base.replace(name="my_disc", solids=(solid,), t_end=0.3, frames=3)
    info = {"case": mine.to_dict(), "case_toml": case_toml(mine)}
    assert info["case_toml"] and "my_disc" in info["case_toml"]
    assert rebuild_case(info).to_dict() == mine.to_dict()
    with pytest.raises(CheckpointError, match="my_disc"):
        rebuild_case({"case": mine.to_dict()})


def test_resume_errors_exit_2_naming_the_folder(tmp_path):
    r = runner.invoke(app, ["resume", str(tmp_path / "nowhere")])
    assert r.exit_code == 2 and "no run folder" in r.output and "nowhere" in r.output
    (tmp_path / "empty").mkdir()
    r = runner.invoke(app, ["resume", str(tmp_path / "empty")])
    assert r.exit_code == 2 and "no usable checkpoint" in r.output and "empty" in r.output


def test_post_processing_commands_on_a_real_run(straight, tmp_path):
    run = str(straight.out_dir)
    r = runner.invoke(app, ["info", run])
    assert r.exit_code == 0, r.output
    for text in ("circle", "24 x 24", "5 frames", f"{straight.total_steps} steps", "fluid_mass",
                 "solid_area", "wave damping", "jax 0.", "checkpoint  frame 4"):
        assert text in r.output, text
    out = tmp_path / "w.png"
    r = runner.invoke(app, ["plot", run, "--field", "vorticity", "--time", "0.021", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = runner.invoke(app, ["plot", run, "--field", "J", "--time", "0.04", "--out", str(tmp_path / "J.png")])
    assert r.exit_code == 0, r.output


def test_incompressible_run_resumes_bitwise_with_its_pressure(tmp_path):
    """An incompressible run carries its pressure in the state (``State.p``, the incremental
    projection); the checkpoint stores it, so a run killed after a checkpoint and resumed
    ends bit for bit where the uninterrupted one does.  (Restarted from p = 0 instead, the
    first resumed step would solve for the whole pressure and differ at the solver's
    tolerance.)"""
    import dataclasses

    base = tiny_case()
    case = base.replace(numerics=dataclasses.replace(base.numerics, fluid_model="incompressible"))
    straight = Simulation(case, tmp_path / "straight", progress=False, pictures=False)
    ref = straight.run()
    assert ref.p is not None and np.abs(np.asarray(ref.p)).max() > 0

    out = _killed_after_frame_3(case, tmp_path / "killed")
    st, info = load_checkpoint(out)
    assert st.p is not None and st.p.shape == st.rho_f.shape
    final = Simulation.resume(out, progress=False, pictures=False).run()
    for f in FIELDS + ("p",):
        assert np.array_equal(np.asarray(getattr(final, f)), np.asarray(getattr(ref, f))), f


def test_a_run_with_solids_in_windows_resumes_bitwise(tmp_path):
    """``solid_storage = "window"`` stores each solid in a window that follows its body
    (``State.origin``); the checkpoint keeps the windows and their origins, so a run killed
    after a checkpoint and resumed ends bit for bit where the uninterrupted one does, and
    its frames hold the union of the level sets on the grid and the windows (run.xdmf, with
    the integer solid_index, as the uninterrupted run's)."""
    import dataclasses

    from refmap.scenarios_fssi import suspension

    case = suspension(128, count=4)
    case = case.replace(numerics=dataclasses.replace(case.numerics, solid_storage="window"),
                        t_end=0.03, frames=4)
    straight = Simulation(case, tmp_path / "straight", progress=False, pictures=False)
    assert straight.model.state_window is not None
    ref = straight.run()
    assert ref.origin is not None and ref.phi.shape[1:] == straight.model.state_window

    out = _killed_after_frame_3(case, tmp_path / "killed")
    st, _ = load_checkpoint(out)
    assert st.origin is not None and st.origin.shape == (4, 2)
    final = Simulation.resume(out, progress=False, pictures=False).run()
    for f in FIELDS + ("origin",):
        assert np.array_equal(np.asarray(getattr(final, f)), np.asarray(getattr(ref, f))), f
    run = open_run(out, windows=True)
    assert run["phi"].shape[-2:] == (128, 128)
    on_grid = straight.model.on_grid(ref)
    np.testing.assert_array_equal(run["phi"].values[-1], np.asarray(on_grid.phi).min(0))
    np.testing.assert_array_equal(run["xi_window"].values[-1], np.asarray(ref.xi))
    assert (straight.out_dir / "run.xdmf").read_text() == (out / "run.xdmf").read_text()
