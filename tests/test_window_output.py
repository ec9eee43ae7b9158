"""Output frames of solids stored in windows (``Numerics.solid_storage = "window"``):
instead of S whole-grid level sets and maps (8 GB a field and frame at 1000 discs on
1024^2), the union level set, the nearest solid's index and J on the grid and the windows
with their origins in a group of their own, from which the per-solid fields are rebuilt
exactly (docs/restart.md, "Output of solids stored in windows").

One short run (five discs at 96^2, periodic along x and walled along y, two discs across
the periodic edge and two next to a wall, three frames) is shared by the tests; compiling
its step is most of the module's time."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET

import h5py
import jax
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap.boundary import Boundary
from refmap.case import Case, CaseError
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.io import RunWriter, list_frames, open_run, per_solid_fields, read_frame, read_state
from refmap.materials import NeoHookean
from refmap.model import Solid
from refmap.postprocess import available_fields, field_at, make_run_movie, plot_frame
from refmap.simulation import Simulation, _check_start_state
from refmap.state import Numerics

# periodic along x, walls at the bottom and top
BOUNDARY = Boundary(left="periodic", right="periodic")
# across the x edge, across it next to the bottom wall (3.6 cells off it: not glued), one
# next to the bottom wall, two inside; all drifting, so the maps are not the identity and
# the windows move
CENTRES = [(1.8, 0.1), (-1.9, -1.55), (0.3, -1.55), (-0.9, 1.0), (0.9, 0.0)]
N = 96
STATE_FIELDS = ("t", "step", "v", "rho_f", "xi", "phi", "origin")


def _case(centres=CENTRES, boundary=BOUNDARY, n=N, storage="window"):
    solids = tuple(
        Solid(shape=Disc(center=c, radius=0.3), law=NeoHookean(G=10.0, kappa=10.0, rho0=1.0 + 0.2 * k),
              name=f"d{k}", velocity=(0.4, 0.1))
        for k, c in enumerate(centres))
    return Case(name="discs", grid=Grid(n, n, -2.0, 2.0, -2.0, 2.0), solids=solids, boundary=boundary,
                numerics=Numerics(solid_storage=storage), t_end=0.12, frames=2)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """The run: its Simulation, folder and the state of every frame (frame 0's kept as
    ``Simulation.run`` makes it)."""
    out = tmp_path_factory.mktemp("windows") / "run"
    sim = Simulation(_case(), out, progress=False, pictures=True)
    assert sim.model.state_window is not None
    states = {}
    make = sim.model.initial_state
    sim.model.initial_state = lambda params: states.setdefault(0, make(params))
    sim.run(on_frame=lambda i, s: states.__setitem__(i, s))
    return sim, out, states


_JITTED = {}


def _on_grid(model, state):
    """``model.on_grid(state)``, compiled once (it only places values: the same as eager)."""
    if ("on_grid", model) not in _JITTED:
        _JITTED["on_grid", model] = jax.jit(model.on_grid)
    return _JITTED["on_grid", model](state)


def _frames(out):
    return dict(list_frames(out))


def _nearest_J(model, state, params):
    """The grid layout's per-solid J merged by hand: at each corner the J of the solid with
    the least corner level set among those whose stress is taken there, NaN where none is."""
    if ("derived", model) not in _JITTED:
        _JITTED["derived", model] = jax.jit(lambda s, p: model.derived(model.on_grid(s), p))
    d = _JITTED["derived", model](state, params)
    valid, J, phic = (np.asarray(d[k]) for k in ("valid", "J", "phic"))
    k = np.where(valid, phic, np.inf).argmin(0)
    return np.where(valid.any(0), np.take_along_axis(J, k[None], 0)[0], np.nan)


def test_frames_hold_the_union_and_the_windows(run):
    """Each frame: ``phi`` the least of the solids' level sets (the minimum over
    ``on_grid(state).phi``, exactly), ``solid_index`` its argmin where below ``phi_max h``
    (else -1), ``J`` the nearest solid's; no per-solid grid field; the windows and their
    origins in ``/windows``, which rebuild every solid's ``phi`` and ``xi`` exactly."""
    sim, out, states = run
    m = sim.model
    far = m.numerics.phi_max * m.h
    frames = _frames(out)
    assert sorted(frames) == sorted(states) == [0, 1, 2]
    moved = False
    for i, state in states.items():
        with h5py.File(frames[i]) as f:
            assert sorted(f["fields"]) == sorted(
                ["u", "v", "rho_f", "rho", "p_fluid", "pressure", "sigma_xx", "sigma_xy", "sigma_yy",
                 "phi", "solid_index", "J"])
            assert f["fields/phi"].shape == (N, N) and f["fields/J"].shape == (N + 1, N + 1)
            assert f["fields/solid_index"].dtype == np.int32 and not f["fields/phi"].attrs["per_solid"]
            g = f["windows"]
            assert g["phi_window"].shape == (5, *m.state_window)
            assert g["xi_window"].shape == (5, 2, *m.state_window)
            assert g["origin"].dtype == np.int32 and g["origin"].shape == (5, 2)
            assert g["phi_window"].attrs["dims"] == "solid wx wy"
            assert g.attrs["far"] == far and list(g.attrs["periodic"]) == [True, False]
            o = g["origin"][()]
            # windows across the periodic edge and against the walls
            assert np.any(o[:, 0] + m.state_window[0] > N) and np.any(o[:, 1] == 0)
        _, fields, attrs = read_frame(frames[i])
        grid = _on_grid(m, state)
        phis = np.asarray(grid.phi)
        np.testing.assert_array_equal(fields["phi"], phis.min(0))
        least = phis.min(0)
        np.testing.assert_array_equal(fields["solid_index"], np.where(least < far, phis.argmin(0), -1))
        assert set(np.unique(fields["solid_index"])) == {-1, 0, 1, 2, 3, 4}
        J = _nearest_J(m, state, sim.params)
        np.testing.assert_array_equal(np.isnan(fields["J"]), np.isnan(J))
        np.testing.assert_allclose(fields["J"], J, rtol=1e-12, atol=0)
        # the windows as the state holds them, and the per-solid fields rebuilt exactly
        win = attrs["windows"]
        for name, key in (("phi_window", "phi"), ("xi_window", "xi"), ("origin", "origin")):
            np.testing.assert_array_equal(win[name], np.asarray(getattr(state, key)))
        rebuilt = per_solid_fields(frames[i])
        np.testing.assert_array_equal(rebuilt["phi"], phis)
        np.testing.assert_array_equal(rebuilt["xi_x"], np.asarray(grid.xi[:, 0]))
        np.testing.assert_array_equal(rebuilt["xi_y"], np.asarray(grid.xi[:, 1]))
        one = per_solid_fields((None, fields, attrs), solid=1)
        np.testing.assert_array_equal(one["xi_y"], np.asarray(grid.xi[1, 1]))
        moved |= bool(np.any(win["origin"] != np.asarray(states[0].origin)))
    assert moved  # the windows followed the bodies


def test_run_xdmf_lists_the_grid_fields(run):
    """run.xdmf gives ParaView the union ``phi``, ``solid_index`` (int32) and ``J``; the
    windows are not in it."""
    _, out, _ = run
    root = ET.parse(out / "run.xdmf").getroot()
    grids = [g for g in root.iter("Grid") if g.get("GridType") == "Uniform"]
    assert len(grids) == 3
    for g in grids:
        attrs = {a.get("Name"): a for a in g.iter("Attribute")}
        assert {"phi", "solid_index", "J", "velocity", "pressure"} <= set(attrs)
        assert not any(n.startswith(("phi_", "xi_", "J_")) for n in attrs)
        item = attrs["solid_index"].find("DataItem")
        assert (item.get("NumberType"), item.get("Precision"), item.get("Dimensions")) == ("Int", "4", f"{N} {N}")
        item = attrs["phi"].find("DataItem")
        assert (item.get("NumberType"), item.get("Precision")) == ("Float", "8")
        assert attrs["J"].get("Center") == "Node" and attrs["phi"].get("Center") == "Cell"
        path, dset = attrs["solid_index"].find("DataItem").text.split(":")
        with h5py.File(out / path) as f:
            assert f[dset].shape == (N, N)


def test_open_run_reads_both_parts(run):
    """``open_run``: the grid fields over time; with ``windows=True`` the windows too."""
    sim, out, states = run
    ds = open_run(out)
    assert ds["phi"].dims == ("time", "x", "y") and ds["J"].dims == ("time", "xc", "yc")
    assert ds["solid_index"].dtype == np.int32 and "xi_x" not in ds and "phi_window" not in ds
    m = sim.model
    np.testing.assert_array_equal(ds["phi"].values[2], np.asarray(_on_grid(m, states[2]).phi).min(0))
    dw = open_run(out, windows=True)
    assert dw["phi_window"].dims == ("time", "solid", "wx", "wy")
    assert dw["xi_window"].dims == ("time", "solid", "xy", "wx", "wy")
    assert dw["origin"].dims == ("time", "solid", "xy") and dw["origin"].dtype == np.int32
    assert dw["phi_window"].attrs["far"] == m.numerics.phi_max * m.h
    for i in range(3):
        np.testing.assert_array_equal(dw["xi_window"].values[i], np.asarray(states[i].xi))
        np.testing.assert_array_equal(dw["origin"].values[i], np.asarray(states[i].origin))
    only = open_run(out, fields=["u", "origin"], windows=True)
    assert set(only.data_vars) == {"u", "origin"}


def test_pictures_and_postprocess(run, tmp_path):
    """The run's pictures (the union's contour), ``refmap plot`` of the union and of one
    solid's rebuilt level set and map, and a movie of one."""
    sim, out, states = run
    assert (out / "pressure_panels.png").stat().st_size > 0
    assert len(list((out / "pictures").glob("pressure_*.png"))) == 3
    stored, _ = available_fields(out)
    assert {"phi", "solid_index", "J", "xi_x", "xi_y"} <= set(stored)
    t = float(states[2].t)
    fa = field_at(out, "xi_x", t, solid=3)
    np.testing.assert_array_equal(fa["data"], np.asarray(_on_grid(sim.model, states[2]).xi[3, 0]))
    assert fa["phis"].shape == (N, N)
    fa = field_at(out, "phi", t, solid=0)
    np.testing.assert_array_equal(fa["data"], np.asarray(_on_grid(sim.model, states[2]).phi[0]))
    assert field_at(out, "phi", t)["data"].shape == (N, N)
    assert plot_frame(out, "xi_y", t, out=tmp_path / "xi.png", solid=1).stat().st_size > 0
    assert plot_frame(out, "solid_index", t, out=tmp_path / "idx.png").stat().st_size > 0
    with pytest.raises(ValueError, match="per solid"):
        field_at(out, "xi_x", t)
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    try:
        imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError:
        pytest.skip("no ffmpeg")
    movie = make_run_movie(out, "xi_x", out=tmp_path / "xi.mp4", solid=2)
    assert imageio_ffmpeg.count_frames_and_secs(str(movie))[0] == 3


def test_a_run_restarts_from_a_frame(run, tmp_path):
    """``read_state`` gives a frame's State bit for bit (the windows and origins of the
    window group); a run starts from it, and a step from frame 1 reaches frame 2 exactly."""
    sim, out, states = run
    frames = _frames(out)
    for i, state in states.items():
        back = read_state(frames[i])
        for f in STATE_FIELDS:
            a, b = np.asarray(getattr(back, f)), np.asarray(getattr(state, f))
            assert a.dtype == b.dtype and np.array_equal(a, b), f
    start = Simulation(_case().replace(t_end=0.24), tmp_path / "again", progress=False,
                       pictures=False, state=read_state(frames[1])).start_state
    for f in STATE_FIELDS:
        assert np.array_equal(np.asarray(getattr(start, f)), np.asarray(getattr(states[1], f))), f
    new, info = sim._advance(start, sim.params, sim._frame_times[1], speed_limit=sim._speed_limit)
    assert bool(info["ok"])
    for f in STATE_FIELDS:
        assert np.array_equal(np.asarray(getattr(new, f)), np.asarray(getattr(states[2], f))), f
    # checked on its windows, not placed on the grid: a body that outgrew its window, or a
    # window that is no box of the grid, is refused by name
    bad = read_state(frames[1])
    with pytest.raises(CaseError, match="origin must hold each window's first node"):
        _check_start_state(bad.replace(origin=bad.origin.at[2].set(-1)), sim.case, sim.model)
    with pytest.raises(CaseError, match="are no box of the grid"):
        _check_start_state(bad.replace(phi=bad.phi[..., None]), sim.case, sim.model)


def _avals(jaxpr, out):
    """Every shape in ``jaxpr`` and the jaxprs inside it (loops, conditionals, calls)."""
    for eqn in jaxpr.eqns:
        for v in (*eqn.invars, *eqn.outvars):
            if hasattr(v, "aval"):
                out.add(tuple(getattr(v.aval, "shape", ())))
        for p in eqn.params.values():
            for sub in p if isinstance(p, (tuple, list)) else (p,):
                if hasattr(sub, "eqns"):
                    _avals(sub, out)
                elif hasattr(sub, "jaxpr") and hasattr(sub.jaxpr, "eqns"):
                    _avals(sub.jaxpr, out)
    return out


def test_output_fields_form_no_per_solid_grid_array(run):
    """``output_fields`` of a windowed state holds no ``(S, ..., *grid)`` array (nodes or
    corners, padded or not): every array with the solids' axis is a window's.  ``on_grid``,
    which forms them, is seen by the same check."""
    sim, _, states = run
    m, S = sim.model, sim.model.n_solids
    assert S not in (2, 3) and all(w < N for w in m.state_window)

    def per_solid_grid(fn):
        shapes = _avals(jax.make_jaxpr(fn)(states[1]).jaxpr, set())
        return sorted(s for s in shapes if len(s) >= 3 and s[0] == S and all(k >= N for k in s[-2:]))

    assert per_solid_grid(lambda s: m.output_fields(s, sim.params)) == []
    assert per_solid_grid(lambda s: m.on_grid(s).phi) != []


def test_per_solid_fields_keep_their_layout(tmp_path):
    """Frames of solids on the grid (per-solid ``phi``, ``xi_*``, ``J``) are written as
    before: float64, no window group, HyperSlabs in run.xdmf; ``per_solid_fields`` and
    ``read_state`` read them.  A malformed ``windows`` argument is refused."""
    grid = Grid(8, 10)
    X, Y = grid.mesh("node")
    rng = np.random.default_rng(1)
    fields = {"u": rng.normal(size=(8, 10)), "v": rng.normal(size=(8, 10)), "rho_f": 1 + 0 * X,
              "phi": rng.normal(size=(2, 8, 10)), "xi_x": np.stack([X, X + 0.1]),
              "xi_y": np.stack([Y, Y - 0.1]), "J": rng.normal(size=(2, 9, 11))}
    path = tmp_path / "r" / "frames" / "frame_00000.h5"
    with RunWriter(tmp_path / "r", grid) as w:
        w.write_frame(0, 0.5, fields, attrs={"step": 7})
        with pytest.raises(ValueError, match="windows must hold exactly"):
            w.write_frame(1, 0.1, fields, windows={"phi_window": np.zeros((2, 4, 4))})
    with h5py.File(path) as f:
        assert "windows" not in f and all(f["fields"][k].dtype == np.float64 for k in f["fields"])
    back = read_state(path)
    assert back.origin is None and int(back.step) == 7 and float(back.t) == 0.5
    np.testing.assert_array_equal(np.asarray(back.xi[1, 0]), fields["xi_x"][1])
    np.testing.assert_array_equal(np.asarray(back.phi), fields["phi"])
    np.testing.assert_array_equal(per_solid_fields(path, solid=1)["phi"], fields["phi"][1])
    text = (tmp_path / "r" / "run.xdmf").read_text()
    assert 'Name="phi_1"' in text and 'Format="HDF" NumberType="Int"' not in text


def test_integer_fields_round_trip(tmp_path):
    """An integer field is stored int32 and read back as such; in ``open_run`` it stays
    int32 when every frame has it, else becomes float64 with NaN where it is missing."""
    grid = Grid(8, 10)
    idx = np.arange(80, dtype=np.int64).reshape(8, 10) - 1
    with RunWriter(tmp_path / "r", grid) as w:
        w.write_frame(0, 0.0, {"u": np.zeros((8, 10)), "solid_index": idx})
        w.write_frame(1, 1.0, {"u": np.ones((8, 10)), "solid_index": idx + 1})
    _, fields, _ = read_frame(tmp_path / "r" / "frames" / "frame_00000.h5")
    assert fields["solid_index"].dtype == np.int32 and np.array_equal(fields["solid_index"], idx)
    ds = open_run(tmp_path / "r")
    assert ds["solid_index"].dtype == np.int32 and np.array_equal(ds["solid_index"].values[1], idx + 1)
    with RunWriter(tmp_path / "r", grid, overwrite=True) as w:
        w.write_frame(0, 0.0, {"u": np.zeros((8, 10)), "solid_index": idx})
        w.write_frame(1, 1.0, {"u": np.ones((8, 10))})
    ds = open_run(tmp_path / "r")
    assert ds["solid_index"].dtype == np.float64 and np.isnan(ds["solid_index"].values[1]).all()
    with pytest.raises(ValueError, match="does not fit int32"):
        RunWriter(tmp_path / "big", grid).write_frame(0, 0.0, {"n": np.full((8, 10), 2**40)})


def test_frames_of_a_resumed_windowed_run_keep_the_int_number_type(run, tmp_path):
    """A resumed run rewrites run.xdmf from the frames on disk: ``solid_index`` stays
    ``NumberType="Int"`` (the checkpoint's frame records read the dataset's type)."""
    from refmap.checkpoint import reopen_run_writer

    sim, out, _ = run
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    w = reopen_run_writer(copy, sim.case.grid, 3, 3)
    w.close()
    assert (copy / "run.xdmf").read_text() == (out / "run.xdmf").read_text()


def test_dense_suspension_runs_from_the_command_line_as_the_grid_storage_does(tmp_path):
    """``refmap run dense_suspension`` (a thousand discs at its default 1024^2; 16 at 128^2,
    each 20 cells across; at 64^2 a disc's window would be more than half the grid, so
    the model keeps them on the grid there) stores its discs in windows and writes the windowed frames; its
    end state equals the same case run with every disc on the whole grid (``advance`` to
    the same time) to round-off, and its diagnostics table has every disc's row."""
    import dataclasses
    import json

    import jax
    from typer.testing import CliRunner

    from refmap.cli import app
    from refmap.io import read_frame, read_state
    from refmap.scenarios import get_case

    out = tmp_path / "dense"
    r = CliRunner().invoke(app, ["run", "dense_suspension", "--n", "128", "--t-end", "0.02", "--frames", "1",
                                 "--out", str(out), "--no-progress", "--no-pictures"])
    assert r.exit_code == 0, r.output
    case = get_case("dense_suspension", 128)
    assert len(case.solids) == 16 and case.numerics.solid_storage == "window"
    model, params = case.build()
    assert model.state_window is not None
    frame = sorted((out / "frames").glob("frame_*.h5"))[-1]
    assert read_frame(frame)[2]["windows"]
    end = read_state(frame)
    assert end.origin is not None and end.phi.shape[0] == 16
    # the same case with the discs on the grid, advanced to the frame's time
    grid_case = case.replace(numerics=dataclasses.replace(case.numerics, solid_storage="grid"))
    gm, gp = grid_case.build()
    s, info = jax.jit(gm.advance)(gm.initial_state(gp), gp, float(end.t))
    assert bool(info["ok"]) and int(s.step) == int(end.step)
    want, got = s, model.on_grid(end)
    for name in ("v", "rho_f"):
        a, b = np.asarray(getattr(want, name)), np.asarray(getattr(got, name))
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-11 * max(1.0, float(np.max(np.abs(a)))))
    band = np.asarray(want.phi) < model.numerics.phi_max * model.h * (1 - 1e-9)
    np.testing.assert_allclose(np.asarray(got.phi)[band], np.asarray(want.phi)[band], rtol=0, atol=1e-11)
    assert float(np.max(np.abs(np.asarray(want.v)))) > 1e-3  # the discs move
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["case"]["name"] == "dense_suspension"
    header = (out / "diagnostics.csv").read_text().splitlines()[0].split(",")
    assert {f"solid{k}_contact_fy" for k in range(16)} <= set(header)
