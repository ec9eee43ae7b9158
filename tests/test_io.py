"""Tests of refmap.io: frame files, XDMF index, reading back, diagnostics, pictures."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest

from refmap.grid import Grid
from refmap.io import (
    RunWriter,
    derived_field,
    grid_from_attrs,
    make_movie,
    open_diagnostics,
    open_run,
    read_frame,
    save_frame_png,
    save_panel_png,
)

GRID = Grid(12, 10, -1.0, 2.0, -0.5, 1.5)  # dx = 0.25, dy = 0.2: x and y differ on purpose
NSOLID = 2


def synthetic_fields(k: int, grid: Grid = GRID) -> dict[str, np.ndarray]:
    """Node, corner and per-solid fields whose values identify (frame, solid, i, j)."""
    rng = np.random.default_rng(k)
    X, Y = grid.mesh("node")
    Xc, Yc = grid.mesh("corner")
    centres = [(-0.2, 0.5), (1.0, 0.4)]
    phi = np.stack([np.hypot(X - cx, Y - cy) - 0.4 for cx, cy in centres])
    return {
        "u": -Y + 0.1 * k,
        "v": X + rng.standard_normal(X.shape),
        "rho": 1.0 + 0.01 * k + 0 * X,
        "phi": phi,
        "sigma_xx": Xc * Yc + k,
        "sigma_xy": np.sin(Xc) * np.cos(2 * Yc),
        "sigma_yy": rng.standard_normal(Xc.shape),
        "J": np.stack([1.0 + 0.1 * s + 1e-3 * k * Xc for s in range(NSOLID)]),
    }


TIMES = [0.0, 0.125, 0.3]


@pytest.fixture
def run(tmp_path):
    run_dir = tmp_path / "run"
    meta = {"params": {"nu": 0.01, "solids": ["disc", "disc"]}, "argv": ["refmap", "x"], "n": 3}
    written = []
    with RunWriter(run_dir, GRID, meta) as w:
        for k, t in enumerate(TIMES):
            f = synthetic_fields(k)
            written.append(f)
            w.write_frame(k, t, f, attrs={"step": 10 * k, "note": "synthetic"})
            w.append_diagnostics({"step": 10 * k, "time": t, "energy": 1.0 / (k + 3), "ok": True})
    return run_dir, written


# ---------------------------------------------------------------------- writing and reading
def test_files_and_metadata(run):
    run_dir, _ = run
    names = sorted(p.name for p in (run_dir / "frames").iterdir())
    assert names == ["frame_00000.h5", "frame_00001.h5", "frame_00002.h5"]
    assert not list(run_dir.rglob("*.tmp"))
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert meta["params"]["nu"] == 0.01 and meta["argv"] == ["refmap", "x"]
    assert "created" in meta and meta["grid"]["nx"] == 12


def test_read_frame_exact(run):
    run_dir, written = run
    time, fields, attrs = read_frame(run_dir / "frames" / "frame_00001.h5")
    assert time == TIMES[1]
    assert attrs["index"] == 1 and attrs["step"] == 10 and attrs["note"] == "synthetic"
    assert grid_from_attrs(attrs) == GRID
    assert attrs["locations"]["sigma_xx"] == "corner" and attrs["locations"]["u"] == "node"
    assert set(fields) == set(written[1])
    for name, arr in written[1].items():
        assert fields[name].dtype == np.float64
        np.testing.assert_array_equal(fields[name], arr)
    with h5py.File(run_dir / "frames" / "frame_00001.h5", "r") as f:
        np.testing.assert_array_equal(f["x"][()], GRID.axes("node")[0])
        np.testing.assert_array_equal(f["yc"][()], GRID.axes("corner")[1])
        assert f["fields/J"].attrs["per_solid"] and not f["fields/u"].attrs["per_solid"]
        assert f["fields/J"].attrs["location"] == "corner"
        assert f.attrs["dx"] == GRID.dx and f.attrs["by"] == GRID.by


def test_open_run_roundtrip(run):
    run_dir, written = run
    ds = open_run(run_dir)
    np.testing.assert_array_equal(ds.time.values, TIMES)
    np.testing.assert_array_equal(ds["index"].values, [0, 1, 2])
    assert ds.sizes == {"time": 3, "x": 12, "y": 10, "xc": 13, "yc": 11, "solid": NSOLID}
    assert ds.u.dims == ("time", "x", "y")
    assert ds.phi.dims == ("time", "solid", "x", "y")
    assert ds.sigma_xx.dims == ("time", "xc", "yc")
    assert ds.J.dims == ("time", "solid", "xc", "yc")
    np.testing.assert_array_equal(ds.x.values, GRID.axes("node")[0])
    np.testing.assert_array_equal(ds.yc.values, GRID.axes("corner")[1])
    for k in range(3):
        for name, arr in written[k].items():
            np.testing.assert_array_equal(ds[name].isel(time=k).values, arr)
    assert ds.phi.attrs["location"] == "node" and ds.J.attrs["per_solid"]
    # metadata flattened, grid attached
    assert json.loads(ds.attrs["params"]) == {"nu": 0.01, "solids": ["disc", "disc"]}
    assert ds.attrs["n"] == 3 and ds.attrs["nx"] == 12 and ds.attrs["dy"] == GRID.dy
    assert grid_from_attrs(ds.attrs) == GRID
    # subset of fields
    sub = open_run(run_dir, fields=["u"])
    assert list(sub.data_vars) == ["u"]


def test_rewrite_index_and_out_of_order(tmp_path):
    with RunWriter(tmp_path / "r", GRID, {}) as w:
        w.write_frame(5, 0.5, {"u": np.ones(GRID.shape())})
        w.write_frame(2, 0.2, {"u": np.zeros(GRID.shape())})
        w.write_frame(5, 0.55, {"u": 2 * np.ones(GRID.shape())})
        assert w.frame_indices == [2, 5]
    ds = open_run(tmp_path / "r")
    np.testing.assert_array_equal(ds["index"].values, [2, 5])
    np.testing.assert_array_equal(ds.time.values, [0.2, 0.55])
    assert float(ds.u.isel(time=1).max()) == 2.0
    xdmf = ET.parse(tmp_path / "r" / "run.xdmf").getroot()
    assert [g.get("Name") for g in xdmf.iter("Grid")][1:] == ["frame_00002", "frame_00005"]


def test_bad_field_shape_raises(tmp_path):
    with RunWriter(tmp_path / "r", GRID, {}) as w:
        with pytest.raises(ValueError, match=r"'bad'.*\(12, 11\)"):
            w.write_frame(0, 0.0, {"u": np.zeros((12, 10)), "bad": np.zeros((12, 11))})
        with pytest.raises(ValueError, match="'deep'"):
            w.write_frame(0, 0.0, {"deep": np.zeros((2, 2, 12, 10))})
        with pytest.raises(ValueError, match="reserved"):
            w.write_frame(0, 0.0, {"u": np.zeros((12, 10))}, attrs={"time": 1.0})
    assert not list((tmp_path / "r" / "frames").iterdir())


def test_existing_folder(tmp_path):
    d = tmp_path / "r"
    with RunWriter(d, GRID, {}) as w:
        w.write_frame(0, 0.0, {"u": np.zeros(GRID.shape())})
        w.write_frame(1, 0.1, {"u": np.zeros(GRID.shape())})
    (d / "notes.txt").write_text("keep me")
    with pytest.raises(FileExistsError):
        RunWriter(d, GRID, {})
    with RunWriter(d, GRID, {"second": True}, overwrite=True) as w:
        w.write_frame(0, 1.0, {"u": np.ones(GRID.shape())})
    ds = open_run(d)
    assert ds.sizes["time"] == 1 and float(ds.time[0]) == 1.0
    assert (d / "notes.txt").read_text() == "keep me"
    assert not (d / "diagnostics.csv").exists()


# ---------------------------------------------------------------------- robustness
def test_corrupt_frame_and_leftover_tmp_are_skipped(run):
    run_dir, written = run
    frames = run_dir / "frames"
    good = (frames / "frame_00002.h5").read_bytes()
    (frames / "frame_00003.h5").write_bytes(good[: len(good) // 3])  # truncated
    (frames / ".frame_00004.h5.abc123.tmp").write_bytes(good[:100])  # killed mid-write
    (frames / "frame_00005.h5").write_bytes(b"")  # empty
    with pytest.warns(UserWarning) as record:
        ds = open_run(run_dir)
    messages = " ".join(str(r.message) for r in record)
    assert "frame_00003.h5" in messages and "frame_00005.h5" in messages
    assert ".tmp" in messages
    np.testing.assert_array_equal(ds.time.values, TIMES)
    np.testing.assert_array_equal(ds.J.isel(time=2).values, written[2]["J"])
    with pytest.raises(OSError):
        read_frame(frames / "frame_00003.h5")


def test_no_readable_frame(tmp_path):
    (tmp_path / "r" / "frames").mkdir(parents=True)
    with pytest.raises(FileNotFoundError):
        open_run(tmp_path / "r")


def test_diagnostics_roundtrip(run, tmp_path):
    run_dir, _ = run
    df = open_diagnostics(run_dir)
    assert list(df.columns) == ["step", "time", "energy", "ok"]
    np.testing.assert_array_equal(df["step"].values, [0, 10, 20])
    np.testing.assert_array_equal(df["time"].values, TIMES)  # full precision
    np.testing.assert_array_equal(df["energy"].values, [1 / 3, 1 / 4, 1 / 5])

    with RunWriter(tmp_path / "d", GRID, {}) as w:
        w.append_diagnostics({"a": np.float64(0.1), "b": 1})
        # flushed at once: readable while the writer is still open
        assert open_diagnostics(tmp_path / "d")["a"].tolist() == [0.1]
        w.append_diagnostics({"a": 0.2})  # missing column -> empty
        with pytest.raises(ValueError, match="'c'"):
            w.append_diagnostics({"a": 0.3, "c": 2})
    df = open_diagnostics(tmp_path / "d")
    assert df["a"].tolist() == [0.1, 0.2] and np.isnan(df["b"].iloc[1])


def test_frame_diagnostics_arrays_roundtrip(tmp_path):
    """Small per-solid / per-pair arrays stored with a frame come back exactly, from
    read_frame and from open_run (NaN in frames that lack them, the solid axis shared
    with the per-solid fields, inf and NaN kept), and bad ones are refused by name."""
    gap = np.array([[np.nan, 0.25], [0.25, np.nan]])
    force = np.array([[1.5, -2.0], [-1.5, 2.0]])
    run_dir = tmp_path / "r"
    with RunWriter(run_dir, GRID, {}) as w:
        for k, t in enumerate(TIMES):
            small = {
                "contact_force": (("solid", "xy"), force * (k + 1)),
                "contact_min_gap": (("solid", "other_solid"), gap + k),
                "count": np.array([k, 2 * k]),  # no dims given: count_dim0
            }
            if k == 1:
                small = {"contact_force": (("solid", "xy"), np.full((2, 2), np.inf))}
            w.write_frame(k, t, synthetic_fields(k), diagnostics=small)
        w.write_frame(3, 0.5, synthetic_fields(3))  # none at all
        for bad, match in (
            ({"u": [1.0]}, "also a field name"),
            ({"a": (("solid",), np.zeros((2, 2)))}, "must name each of its 2 axes"),
            ({"a": (("x",), np.zeros(12))}, "reserved"),
            ({"a/b": [1.0]}, "invalid diagnostics name"),
        ):
            with pytest.raises(ValueError, match=match):
                w.write_frame(9, 1.0, synthetic_fields(0), diagnostics=bad)
    _, _, attrs = read_frame(run_dir / "frames" / "frame_00002.h5")
    np.testing.assert_array_equal(attrs["diagnostics"]["contact_force"], 3 * force)
    np.testing.assert_array_equal(attrs["diagnostics"]["contact_min_gap"], gap + 2)
    assert attrs["diagnostic_dims"]["contact_min_gap"] == ("solid", "other_solid")
    assert attrs["diagnostic_dims"]["count"] == ("count_dim0",)
    ds = open_run(run_dir)
    assert ds["contact_force"].dims == ("time", "solid", "xy")
    assert ds["contact_min_gap"].dims == ("time", "solid", "other_solid")
    assert ds.sizes["solid"] == NSOLID and list(ds["xy"].values) == ["x", "y"]
    np.testing.assert_array_equal(ds["contact_force"].values[0], force)
    assert np.all(np.isinf(ds["contact_force"].values[1]))
    assert np.all(np.isnan(ds["contact_min_gap"].values[1]))  # absent from frame 1
    np.testing.assert_array_equal(ds["contact_min_gap"].values[2], gap + 2)
    np.testing.assert_array_equal(ds["count"].values[:, 1], [0.0, np.nan, 4.0, np.nan])
    assert ds["contact_force"].attrs["diagnostic"]
    only = open_run(run_dir, fields=["u", "contact_force"])
    assert set(only.data_vars) == {"u", "contact_force"}
    assert np.all(np.isnan(ds["contact_force"].values[3]))
    _, _, attrs = read_frame(run_dir / "frames" / "frame_00003.h5")
    assert attrs["diagnostics"] == {} and attrs["diagnostic_dims"] == {}


# ---------------------------------------------------------------------- XDMF
def _dims(item) -> tuple[int, ...]:
    return tuple(int(s) for s in item.get("Dimensions").split())


def _check_hdf_item(run_dir: Path, item) -> tuple[int, ...]:
    assert item.get("Format") == "HDF"
    fname, dset = item.text.strip().split(":")
    with h5py.File(run_dir / fname, "r") as f:
        assert dset in f, dset
        assert f[dset].shape == _dims(item), (dset, f[dset].shape, _dims(item))
        assert f[dset].dtype == np.float64
    return _dims(item)


def test_xdmf_valid_and_consistent(run):
    run_dir, written = run
    root = ET.parse(run_dir / "run.xdmf").getroot()
    assert root.tag == "Xdmf" and root.get("Version") == "3.0"
    coll = root.find("Domain/Grid")
    assert coll.get("GridType") == "Collection" and coll.get("CollectionType") == "Temporal"
    frames = coll.findall("Grid")
    assert len(frames) == 3
    nx, ny = GRID.nx, GRID.ny
    for k, g in enumerate(frames):
        assert float(g.find("Time").get("Value")) == TIMES[k]
        topo = g.find("Topology")
        assert topo.get("TopologyType") == "2DCoRectMesh"
        assert _dims(topo) == (ny + 1, nx + 1)
        origin, spacing = g.find("Geometry").findall("DataItem")
        assert [float(s) for s in origin.text.split()] == [GRID.ay, GRID.ax]
        assert [float(s) for s in spacing.text.split()] == [GRID.dy, GRID.dx]
        attrs = {a.get("Name"): a for a in g.findall("Attribute")}
        expected = {"u", "v", "rho", "phi_0", "phi_1", "sigma_xx", "sigma_xy", "sigma_yy"}
        expected |= {"J_0", "J_1", "velocity"}
        assert set(attrs) == expected
        for name, a in attrs.items():
            center = a.get("Center")
            want = (ny, nx) if center == "Cell" else (ny + 1, nx + 1)
            cell_names = {"u", "v", "rho", "phi_0", "phi_1", "velocity"}
            assert center == ("Cell" if name in cell_names else "Node"), name
            item = a.find("DataItem")
            if item.get("ItemType") == "HyperSlab":
                sel, src = item.findall("DataItem")
                start, stride, count = np.array(sel.text.split(), dtype=int).reshape(3, 3)
                shape = _check_hdf_item(run_dir, src)
                assert tuple(count[1:]) == want == _dims(item) == shape[1:]
                assert count[0] == 1 and 0 <= start[0] < shape[0] and tuple(stride) == (1, 1, 1)
                assert start[0] == int(name.rsplit("_", 1)[1])
            elif item.get("ItemType") == "Function":
                assert a.get("AttributeType") == "Vector"
                assert _dims(item) == (*want, 3)
                parts = item.findall("DataItem")
                assert len(parts) == 3
                for p in parts:
                    assert _check_hdf_item(run_dir, p) == want
            else:
                assert _check_hdf_item(run_dir, item) == want


def test_xdmf_layout_is_x_fastest(run):
    """The dataset referenced by the XDMF, read C-order, must run along x first."""
    run_dir, written = run
    root = ET.parse(run_dir / "run.xdmf").getroot()
    g = root.find("Domain/Grid").findall("Grid")[0]
    item = next(a for a in g.findall("Attribute") if a.get("Name") == "sigma_xx").find("DataItem")
    fname, dset = item.text.strip().split(":")
    with h5py.File(run_dir / fname, "r") as f:
        flat = f[dset][()].ravel()
    Xc, Yc = GRID.mesh("corner")
    # XDMF point p = a + (nx+1) * b sits at x = ax + a dx, y = ay + b dy
    a, b = 3, 7
    p = a + (GRID.nx + 1) * b
    np.testing.assert_allclose(flat[p], written[0]["sigma_xx"][a, b])
    assert Xc[a, b] == pytest.approx(GRID.ax + a * GRID.dx)
    assert Yc[a, b] == pytest.approx(GRID.ay + b * GRID.dy)


# ---------------------------------------------------------------------- derived fields
def test_vorticity_of_solid_body_rotation():
    w = 0.7
    X, Y = GRID.mesh("node")
    fields = {"u": -w * Y, "v": w * X}
    vort = derived_field(fields, "vorticity", grid=GRID)
    np.testing.assert_allclose(vort[1:-1, 1:-1], 2 * w, rtol=0, atol=1e-12)
    speed = derived_field(fields, "speed", grid=GRID)
    np.testing.assert_allclose(speed, w * np.hypot(X, Y))


def test_derived_on_dataset_and_frame(run):
    run_dir, written = run
    ds = open_run(run_dir)
    vm = derived_field(ds, "von_mises")
    assert vm.dims == ("time", "xc", "yc")
    f = written[1]
    sxx, sxy, syy = f["sigma_xx"], f["sigma_xy"], f["sigma_yy"]
    np.testing.assert_allclose(
        vm.isel(time=1).values, np.sqrt(sxx**2 - sxx * syy + syy**2 + 3 * sxy**2)
    )
    frame = read_frame(run_dir / "frames" / "frame_00000.h5")
    w0 = derived_field(frame, "vorticity")
    np.testing.assert_allclose(w0, derived_field(ds, "vorticity").isel(time=0).values)
    with pytest.raises(ValueError, match="speed.*vorticity.*von_mises"):
        derived_field(ds, "enstrophy")
    with pytest.raises(ValueError, match="pressure"):
        derived_field(ds, "pressure")
    np.testing.assert_array_equal(derived_field({"p": f["u"]}, "pressure", grid=GRID), f["u"])


# ---------------------------------------------------------------------- pictures
def _is_png(path: Path) -> bool:
    return path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_pngs(run, tmp_path):
    run_dir, written = run
    f = written[0]
    p = save_frame_png(
        tmp_path / "u.png",
        GRID,
        0.0,
        "u",
        f["u"],
        "node",
        f["phi"],
        blur_edges=True,
        velocity=(f["u"], f["v"]),
    )
    assert p.stat().st_size > 1000 and _is_png(p)
    p2 = save_frame_png(tmp_path / "s.png", GRID, 0.1, "sigma_xx", f["sigma_xx"], None, None)
    assert _is_png(p2)
    panels = [(t, w["sigma_xy"], w["phi"]) for t, w in zip(TIMES, written, strict=True)]
    p3 = save_panel_png(tmp_path / "panel.png", GRID, panels, "sigma_xy", "corner", ncols=2)
    assert p3.stat().st_size > 1000 and _is_png(p3)
    with pytest.raises(ValueError):
        save_frame_png(tmp_path / "x.png", GRID, 0.0, "bad", np.zeros((3, 3)), "node")


def test_every_solid_interface_is_drawn():
    """plot_field (and so the run pictures, panels and movies) draws the zero contour of
    every solid's level set: three discs give three contour sets at level 0, each centred
    on its disc."""
    from matplotlib.contour import ContourSet
    from matplotlib.figure import Figure

    from refmap.io import plot_field

    X, Y = GRID.mesh("node")
    centres = [(-0.2, 0.5), (1.0, 0.4), (0.5, 1.0)]
    phis = np.stack([np.hypot(X - cx, Y - cy) - 0.3 for cx, cy in centres])
    ax = Figure().add_subplot()
    plot_field(ax, GRID, X * Y, "node", phis)
    sets = [c for c in ax.collections if isinstance(c, ContourSet)]
    assert len(sets) == 3 and all(list(c.levels) == [0.0] for c in sets)
    for c, centre in zip(sets, centres, strict=True):
        v = np.concatenate([p.vertices for p in c.get_paths()])
        # the polygon's vertex mean lies within a cell of the disc's centre
        assert np.hypot(*(v.mean(axis=0) - centre)) < GRID.dx


def test_fine_corner_fields_are_drawn_one_quad_per_corner():
    """A corner field is Gouraud-shaded (its quad mesh's vertices are the corners
    themselves) on a coarse grid, and drawn as one flat quad per corner past
    GOURAUD_MAX_POINTS values (its vertices then bound each corner's cell: one more per
    axis), where Gouraud triangles cost seconds and gigabytes to draw; the image shows the
    same values either way."""
    from matplotlib.figure import Figure

    from refmap.io import plot_field
    from refmap.io.pictures import GOURAUD_MAX_POINTS

    side = int(np.sqrt(GOURAUD_MAX_POINTS))
    for n, extra in ((32, 0), (side, 1)):
        g = Grid(n, n, 0.0, 1.0, 0.0, 1.0)
        X, Y = g.mesh("corner")
        m = plot_field(Figure().add_subplot(), g, np.sin(3 * X) * Y, "corner")
        assert m.get_coordinates().shape[:2] == (n + 1 + extra, n + 1 + extra)


def _ffmpeg_available() -> bool:
    try:
        import imageio_ffmpeg

        return Path(imageio_ffmpeg.get_ffmpeg_exe()).exists()
    except Exception:
        return False


@pytest.mark.skipif(not _ffmpeg_available(), reason="imageio-ffmpeg has no ffmpeg binary here")
def test_movie(run, tmp_path):
    run_dir, _ = run
    out = make_movie(run_dir, "vorticity", tmp_path / "movies" / "vort.mp4", fps=5)
    assert out == tmp_path / "movies" / "vort.mp4"
    data = out.read_bytes()
    assert len(data) > 0 and data[4:8] == b"ftyp"
    assert not list(out.parent.glob(".*partial*"))
    with pytest.raises(ValueError, match="solid="):
        make_movie(run_dir, "J", tmp_path / "j.mp4")
    out2 = make_movie(run_dir, "J", tmp_path / "j.mp4", solid=1, figsize=(5.03, 4.01), dpi=99)
    assert out2.stat().st_size > 0


def test_no_display_backend_change():
    import matplotlib

    before = matplotlib.get_backend()
    import refmap.io.pictures  # noqa: F401

    assert matplotlib.get_backend() == before


def test_failed_write_leaves_no_file(tmp_path, monkeypatch):
    """An error inside the HDF5 write leaves neither a final file nor a temporary one."""
    with RunWriter(tmp_path / "r", GRID, {}) as w:
        w.write_frame(0, 0.0, {"u": np.zeros(GRID.shape())})
        monkeypatch.setattr(w, "_compression", {"compression": "no-such-filter"})
        with pytest.raises((ValueError, OSError)):
            w.write_frame(1, 0.1, {"u": np.zeros(GRID.shape())})
    names = sorted(p.name for p in (tmp_path / "r" / "frames").iterdir())
    assert names == ["frame_00000.h5"]
    root = ET.parse(tmp_path / "r" / "run.xdmf").getroot()
    assert len(root.find("Domain/Grid").findall("Grid")) == 1


@pytest.mark.parametrize("compression", [None, "gzip", "lzf"])
def test_compression_options(tmp_path, compression):
    f = synthetic_fields(0)
    with RunWriter(tmp_path / "r", GRID, {}, compression=compression) as w:
        w.write_frame(0, 0.0, f)
    _, back, _ = read_frame(tmp_path / "r" / "frames" / "frame_00000.h5")
    for name, arr in f.items():
        np.testing.assert_array_equal(back[name], arr)
    with pytest.raises(ValueError, match="compression"):
        RunWriter(tmp_path / "other", GRID, {}, compression="zstd")
