"""Tests of refmap.io on a 3D grid (issue 12): frame files, XDMF, reading back, pictures;
and a frozen check that 2D output is what it was before 3D output existed."""

from __future__ import annotations

import hashlib
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest

from refmap.grid import Grid, Grid3D
from refmap.io import RunWriter, grid_from_attrs, open_run, read_frame, read_metadata

# distinct sizes and spacings on every axis, so any transposition or axis mix-up shows
GRID3 = Grid3D(10, 9, 8, -1.0, 1.5, -2.0, 0.7, 0.5, 2.1)
NSOLID = 2
TIMES = [0.0, 0.375]
CENTRES = [(0.2, -0.6, 1.3), (-0.4, -1.2, 1.0)]
RADII = [0.6, 0.35]
STRESS = ("sigma_xx", "sigma_xy", "sigma_xz", "sigma_yy", "sigma_yz", "sigma_zz")


def fields3d(k: int, grid: Grid3D = GRID3) -> dict[str, np.ndarray]:
    """Node, corner and per-solid fields built from the coordinates (value tells position)."""
    X, Y, Z = grid.mesh("node")
    Xc, Yc, Zc = grid.mesh("corner")
    phi = np.stack(
        [
            np.sqrt((X - c[0]) ** 2 + (Y - c[1]) ** 2 + (Z - c[2]) ** 2) - r
            for c, r in zip(CENTRES, RADII, strict=True)
        ]
    )
    out = {
        "u": X + 10 * Y + 100 * Z + k,
        "v": 2 * X - 20 * Y + 300 * Z,
        "w": -X + 7 * Y * Z + k * X,
        "rho_f": 1.0 + 0.01 * k + 0.1 * X * Y * Z,
        "phi": phi,
        "J": np.stack([1.0 + 0.1 * s + 1e-3 * (Xc + 10 * Yc + 100 * Zc) for s in range(NSOLID)]),
    }
    for name, sign in (("xi_x", 1), ("xi_y", 2), ("xi_z", 3)):
        out[name] = np.stack([sign * X + 10 * Y + 100 * Z + 1000 * s for s in range(NSOLID)])
    for m, name in enumerate(STRESS):
        out[name] = Xc + 10 * Yc + 100 * Zc + 1000 * m + k
    return out


def diags3d(k: int) -> dict:
    return {
        "solid_centroid": (("solid", "xyz"), np.array(CENTRES) + 0.01 * k),
        "solid_velocity": (("solid", "xyz"), np.arange(6.0).reshape(2, 3) * (k + 1)),
        "solid_area": (("solid",), np.array([1.5, 0.25])),
    }


@pytest.fixture
def run3(tmp_path):
    run_dir = tmp_path / "run3"
    written = []
    with RunWriter(run_dir, GRID3, {"case": {"name": "ball"}}) as w:
        for k, t in enumerate(TIMES):
            f = fields3d(k)
            written.append(f)
            w.write_frame(k, t, f, attrs={"step": 5 * k}, diagnostics=diags3d(k))
            w.append_diagnostics({"step": 5 * k, "time": t})
    return run_dir, written


# ---------------------------------------------------------------------- 3D frame files
def test_frame_file_layout(run3):
    run_dir, written = run3
    g = GRID3
    with h5py.File(run_dir / "frames" / "frame_00001.h5", "r") as f:
        for key in ("nx", "ny", "nz", "ax", "bx", "ay", "by", "az", "bz", "dx", "dy", "dz"):
            assert f.attrs[key] == getattr(g, key), key
        assert "[..., k, j, i]" in f.attrs["layout"]
        for a, c in zip("xyz", g.axes("node"), strict=True):
            np.testing.assert_array_equal(f[a][()], c)
        for a, c in zip("xyz", g.axes("corner"), strict=True):
            np.testing.assert_array_equal(f[a + "c"][()], c)
        assert "xdmf" not in f  # no zero component in 3D
        fl = f["fields"]
        assert fl["u"].shape == (g.nz, g.ny, g.nx)
        assert fl["u"].attrs["dims"] == "z y x" and fl["u"].attrs["location"] == "node"
        assert fl["sigma_xz"].shape == (g.nz + 1, g.ny + 1, g.nx + 1)
        assert fl["sigma_xz"].attrs["dims"] == "zc yc xc"
        assert fl["phi"].shape == (NSOLID, g.nz, g.ny, g.nx)
        assert fl["phi"].attrs["dims"] == "solid z y x" and fl["phi"].attrs["per_solid"]
        assert fl["J"].shape == (NSOLID, g.nz + 1, g.ny + 1, g.nx + 1)
        assert fl["J"].attrs["dims"] == "solid zc yc xc"
        # on disk [k, j, i]: u = x + 10 y + 100 z + 1
        i, j, k = 7, 2, 5
        x, y, z = (c[n] for c, n in zip(g.axes("node"), (i, j, k), strict=True))
        assert fl["u"][k, j, i] == pytest.approx(x + 10 * y + 100 * z + 1, rel=1e-15)
        np.testing.assert_array_equal(fl["J"][1, k, j, i], written[1]["J"][1, i, j, k])
        dg = f["diagnostics"]
        assert dg["solid_centroid"].attrs["dims"] == "solid xyz"
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert grid_from_attrs(meta["grid"]) == GRID3
    assert meta["grid"]["nz"] == g.nz and meta["grid"]["dz"] == g.dz


def test_read_frame_exact(run3):
    run_dir, written = run3
    for k, t in enumerate(TIMES):
        time, fields, attrs = read_frame(run_dir / "frames" / f"frame_{k:05d}.h5")
        assert time == t and attrs["step"] == 5 * k
        assert set(fields) == set(written[k])
        for name, arr in written[k].items():
            assert fields[name].shape == arr.shape, name
            np.testing.assert_array_equal(fields[name], arr, err_msg=name)
            want = "corner" if name in STRESS or name == "J" else "node"
            assert attrs["locations"][name] == want
        assert grid_from_attrs(attrs) == GRID3
        for name, (dims, arr) in diags3d(k).items():
            np.testing.assert_array_equal(attrs["diagnostics"][name], arr)
            assert attrs["diagnostic_dims"][name] == dims


def test_open_run_exact(run3):
    run_dir, written = run3
    ds = open_run(run_dir)
    g = GRID3
    assert grid_from_attrs(ds.attrs) == g
    assert ds.sizes["x"] == g.nx and ds.sizes["y"] == g.ny and ds.sizes["z"] == g.nz
    assert ds.sizes["xc"] == g.nx + 1 and ds.sizes["zc"] == g.nz + 1
    for a, c in zip("xyz", g.axes("node"), strict=True):
        np.testing.assert_array_equal(ds[a].values, c)
    for a, c in zip("xyz", g.axes("corner"), strict=True):
        np.testing.assert_array_equal(ds[a + "c"].values, c)
    np.testing.assert_array_equal(ds.time.values, TIMES)
    assert ds["u"].dims == ("time", "x", "y", "z")
    assert ds["sigma_yz"].dims == ("time", "xc", "yc", "zc")
    assert ds["phi"].dims == ("time", "solid", "x", "y", "z")
    assert ds["J"].dims == ("time", "solid", "xc", "yc", "zc")
    for k in range(len(TIMES)):
        for name, arr in written[k].items():
            np.testing.assert_array_equal(ds[name].isel(time=k).values, arr, err_msg=name)
    # label-based selection lands on the right point
    i, j, kk = 3, 6, 1
    x, y, z = (c[n] for c, n in zip(g.axes("node"), (i, j, kk), strict=True))
    val = ds["u"].sel(x=x, y=y, z=z).isel(time=0).item()
    assert val == pytest.approx(x + 10 * y + 100 * z, rel=1e-15)
    # per-solid vectors on the "xyz" axis
    assert list(ds["xyz"].values) == ["x", "y", "z"]
    assert ds["solid_centroid"].dims == ("time", "solid", "xyz")
    for k in range(len(TIMES)):
        np.testing.assert_array_equal(
            ds["solid_velocity"].isel(time=k).values, diags3d(k)["solid_velocity"][1]
        )
        np.testing.assert_array_equal(
            ds["solid_centroid"].isel(time=k).sel(xyz="z").values,
            np.array(CENTRES)[:, 2] + 0.01 * k,
        )
    assert "xy" not in ds.coords
    assert read_metadata(run_dir)["case"] == {"name": "ball"}


def test_reserved_names_3d(tmp_path):
    X = fields3d(0)["u"]
    with RunWriter(tmp_path / "r", GRID3) as w:
        with pytest.raises(ValueError, match="reserved"):
            w.write_frame(0, 0.0, {"u": X}, attrs={"dz": 1.0})
        with pytest.raises(ValueError, match="reserved"):
            w.write_frame(0, 0.0, {"u": X}, diagnostics={"d": (("zc",), np.zeros(3))})
        with pytest.raises(ValueError, match=r"\(nx, ny, nz\)"):
            w.write_frame(0, 0.0, {"u": np.zeros((10, 9))})
        with pytest.raises(ValueError, match="'u'"):
            w.write_frame(0, 0.0, {"u": np.zeros((8, 9, 10))})  # transposed: refused


# ---------------------------------------------------------------------- 3D XDMF
def _dims(el) -> tuple[int, ...]:
    return tuple(int(s) for s in el.get("Dimensions").split())


def _h5_shape(run_dir, item) -> tuple[int, ...]:
    assert item.get("Format") == "HDF"
    fname, dset = item.text.strip().split(":")
    with h5py.File(run_dir / fname, "r") as f:
        shape = f[dset].shape
    assert shape == _dims(item)
    return shape


def test_xdmf_3d(run3):
    run_dir, _ = run3
    g = GRID3
    root = ET.parse(run_dir / "run.xdmf").getroot()
    frames = root.find("Domain/Grid").findall("Grid")
    assert len(frames) == len(TIMES)
    cdims, ndims = (g.nz + 1, g.ny + 1, g.nx + 1), (g.nz, g.ny, g.nx)
    for k, fr in enumerate(frames):
        assert float(fr.find("Time").get("Value")) == TIMES[k]
        topo = fr.find("Topology")
        assert topo.get("TopologyType") == "3DCoRectMesh" and _dims(topo) == cdims
        geo = fr.find("Geometry")
        assert geo.get("GeometryType") == "ORIGIN_DXDYDZ"
        origin, spacing = geo.findall("DataItem")
        assert _dims(origin) == (3,) and _dims(spacing) == (3,)
        assert [float(s) for s in origin.text.split()] == [g.az, g.ay, g.ax]
        assert [float(s) for s in spacing.text.split()] == [g.dz, g.dy, g.dx]
        attrs = {a.get("Name"): a for a in fr.findall("Attribute")}
        per_solid = ("phi", "xi_x", "xi_y", "xi_z", "J")
        expected = {"u", "v", "w", "rho_f", "velocity", *STRESS}
        expected |= {f"{n}_{s}" for n in per_solid for s in range(NSOLID)}
        assert set(attrs) == expected
        for name, a in attrs.items():
            corner = name in STRESS or name.startswith("J_")
            assert a.get("Center") == ("Node" if corner else "Cell"), name
            want = cdims if corner else ndims
            item = a.find("DataItem")
            if item.get("ItemType") == "HyperSlab":
                sel, src = item.findall("DataItem")
                assert _dims(sel) == (3, 4)
                start, stride, count = np.array(sel.text.split(), dtype=int).reshape(3, 4)
                shape = _h5_shape(run_dir, src)
                assert shape == (NSOLID, *want) and _dims(item) == want
                assert tuple(count) == (1, *want) and tuple(stride) == (1, 1, 1, 1)
                assert tuple(start) == (int(name.rsplit("_", 1)[1]), 0, 0, 0)
            elif item.get("ItemType") == "Function":
                assert name == "velocity" and a.get("AttributeType") == "Vector"
                assert _dims(item) == (*ndims, 3)
                parts = item.findall("DataItem")
                assert [p.text.rsplit("/", 1)[1] for p in parts] == ["u", "v", "w"]
                for p in parts:
                    assert _h5_shape(run_dir, p) == ndims
            else:
                assert _h5_shape(run_dir, item) == want


def test_xdmf_3d_x_fastest(run3):
    """The dataset, read flat in C order, runs along x first, then y, then z."""
    run_dir, written = run3
    g = GRID3
    root = ET.parse(run_dir / "run.xdmf").getroot()
    fr = root.find("Domain/Grid").findall("Grid")[1]
    item = next(a for a in fr.findall("Attribute") if a.get("Name") == "sigma_xy").find("DataItem")
    fname, dset = item.text.strip().split(":")
    with h5py.File(run_dir / fname, "r") as f:
        flat = f[dset][()].ravel()
    a, b, c = 4, 7, 2
    p = a + (g.nx + 1) * (b + (g.ny + 1) * c)
    assert flat[p] == written[1]["sigma_xy"][a, b, c]


def test_velocity_needs_w_in_3d(tmp_path):
    f = fields3d(0)
    with RunWriter(tmp_path / "r", GRID3) as w:
        w.write_frame(0, 0.0, {"u": f["u"], "v": f["v"]})
    root = ET.parse(tmp_path / "r" / "run.xdmf").getroot()
    names = [a.get("Name") for a in root.iter("Attribute")]
    assert names == ["u", "v"]


# ---------------------------------------------------------------------- 2D unchanged
GRID2 = Grid(10, 9, -1.0, 1.5, -2.0, 0.7)


def _h5_digests(path) -> dict[str, str]:
    """A short digest of every object of an HDF5 file: its attributes (names, dtypes,
    values) and, for datasets, dtype, shape, filters and data."""

    def canon(v):
        if isinstance(v, np.ndarray):
            return f"{v.dtype.str}{v.shape}{v.tolist()!r}"
        if isinstance(v, np.generic):
            return f"{v.dtype.str}:{v.item()!r}"
        return f"{type(v).__name__}:{v!r}"

    def attrs(obj):
        return ";".join(f"{k}={canon(obj.attrs[k])}" for k in sorted(obj.attrs))

    out = {}
    with h5py.File(path, "r") as f:
        out["/"] = hashlib.sha256(attrs(f).encode()).hexdigest()[:16]

        def visit(name, obj):
            s = attrs(obj)
            if isinstance(obj, h5py.Dataset):
                d = obj[()]
                s += f"|{d.dtype.str}|{d.shape}|{obj.compression}|{obj.compression_opts}|"
                s += f"{obj.shuffle}|"
                s += hashlib.sha256(np.ascontiguousarray(d).tobytes()).hexdigest()
            out[name] = hashlib.sha256(s.encode()).hexdigest()[:16]

        f.visititems(visit)
    return out


def _write_2d(run_dir):
    X, Y = GRID2.mesh("node")
    Xc, Yc = GRID2.mesh("corner")
    fields = {
        "u": X + 10 * Y,
        "v": X * Y - 0.3,
        "phi": np.stack([np.hypot(X, Y) - 0.5, np.hypot(X - 1, Y) - 0.3]),
        "sigma_xx": Xc - 3 * Yc,
        "J": np.stack([1 + 0 * Xc, 1 + 0.1 * Xc * Yc]),
    }
    with RunWriter(run_dir, GRID2, {"a": 1}) as w:
        w.write_frame(
            3,
            0.25,
            fields,
            attrs={"dt": 0.01, "note": "x", "arr": [1, 2], "cfg": {"k": 1}},
            diagnostics={
                "solid_centroid": (("solid", "xy"), np.array([[0.0, 0.1], [1.0, 0.0]])),
                "gap": np.array([0.5]),
            },
        )
        w.write_frame(1, 0.125, {"u": X, "v": Y})
    return fields


# captured from the code at commit fc32f5b (before 3D output), with the same _write_2d
FROZEN_2D_DIGESTS_3 = {
    "/": "6b46f0e641de4667",
    "diagnostics": "e3b0c44298fc1c14",
    "diagnostics/gap": "dcd75878daa2a784",
    "diagnostics/solid_centroid": "c0d9a88c33900a5b",
    "fields": "e3b0c44298fc1c14",
    "fields/J": "41433c9b39fb115d",
    "fields/phi": "e584223f8ff8737f",
    "fields/sigma_xx": "1cd2afd42a27a1a1",
    "fields/u": "79466e5f89a420f1",
    "fields/v": "0cbf3feb4c182c7f",
    "x": "7d0ae9948605ef83",
    "xc": "cba612c205c03341",
    "xdmf": "e3b0c44298fc1c14",
    "xdmf/zero_node": "e63f316c86e9e689",
    "y": "147a340b5cab4fb4",
    "yc": "2c0f1920d9161e74",
}
FROZEN_2D_DIGESTS_1 = {
    "/": "00c29f5f43dfbdd4",
    "fields": "e3b0c44298fc1c14",
    "fields/u": "05efee42e9c2972f",
    "fields/v": "181f15df0f63b288",
    "x": "7d0ae9948605ef83",
    "xc": "cba612c205c03341",
    "xdmf": "e3b0c44298fc1c14",
    "xdmf/zero_node": "e63f316c86e9e689",
    "y": "147a340b5cab4fb4",
    "yc": "2c0f1920d9161e74",
}
FROZEN_2D_GRID = {
    "nx": 10,
    "ny": 9,
    "ax": -1.0,
    "bx": 1.5,
    "ay": -2.0,
    "by": 0.7,
    "dx": 0.25,
    "dy": 0.30000000000000004,
}


def _frozen_2d_xdmf() -> str:
    def item(dims, text, fmt="HDF", num="Float", prec=' Precision="8"'):
        return (
            f'<DataItem Format="{fmt}" NumberType="{num}"{prec} Dimensions="{dims}">'
            f"{text}</DataItem>"
        )

    def scalar(fr, name, center, dims):
        return [
            f'        <Attribute Name="{name}" AttributeType="Scalar" Center="{center}">',
            "          " + item(dims, f"frames/frame_{fr}.h5:/fields/{name}"),
            "        </Attribute>",
        ]

    def slab(fr, field, k, center, dims):
        return [
            f'        <Attribute Name="{field}_{k}" AttributeType="Scalar" Center="{center}">',
            f'          <DataItem ItemType="HyperSlab" Type="HyperSlab" Dimensions="{dims}">',
            "            " + item("3 3", f"{k} 0 0  1 1 1  1 {dims}", "XML", "Int", ""),
            "            " + item(f"2 {dims}", f"frames/frame_{fr}.h5:/fields/{field}"),
            "          </DataItem>",
            "        </Attribute>",
        ]

    def velocity(fr):
        return [
            '        <Attribute Name="velocity" AttributeType="Vector" Center="Cell">',
            '          <DataItem ItemType="Function" Function="JOIN($0, $1, $2)" '
            'Dimensions="9 10 3">',
            "            " + item("9 10", f"frames/frame_{fr}.h5:/fields/u"),
            "            " + item("9 10", f"frames/frame_{fr}.h5:/fields/v"),
            "            " + item("9 10", f"frames/frame_{fr}.h5:/xdmf/zero_node"),
            "          </DataItem>",
            "        </Attribute>",
        ]

    def head(fr, t):
        return [
            f'      <Grid Name="frame_{fr}" GridType="Uniform">',
            f'        <Time Value="{t}" />',
            '        <Topology TopologyType="2DCoRectMesh" Dimensions="10 11" />',
            '        <Geometry GeometryType="ORIGIN_DXDY">',
            "          " + item("2", "-2.0 -1.0", "XML"),
            "          " + item("2", "0.30000000000000004 0.25", "XML"),
            "        </Geometry>",
        ]

    lines = [
        '<?xml version="1.0" ?>',
        '<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>',
        '<Xdmf Version="3.0">',
        "  <Domain>",
        '    <Grid Name="run" GridType="Collection" CollectionType="Temporal">',
    ]
    lines += head("00001", "0.125")
    lines += scalar("00001", "u", "Cell", "9 10") + scalar("00001", "v", "Cell", "9 10")
    lines += velocity("00001") + ["      </Grid>"]
    lines += head("00003", "0.25")
    lines += scalar("00003", "u", "Cell", "9 10") + scalar("00003", "v", "Cell", "9 10")
    lines += slab("00003", "phi", 0, "Cell", "9 10") + slab("00003", "phi", 1, "Cell", "9 10")
    lines += scalar("00003", "sigma_xx", "Node", "10 11")
    lines += slab("00003", "J", 0, "Node", "10 11") + slab("00003", "J", 1, "Node", "10 11")
    lines += velocity("00003") + ["      </Grid>"]
    lines += ["    </Grid>", "  </Domain>", "</Xdmf>", ""]
    return "\n".join(lines)


def test_2d_output_unchanged(tmp_path):
    """A 2D run's XDMF text, frame contents (every dataset and attribute) and metadata grid
    are exactly what the code wrote before 3D output was added."""
    run_dir = tmp_path / "r2"
    _write_2d(run_dir)
    assert (run_dir / "run.xdmf").read_text() == _frozen_2d_xdmf()
    assert _h5_digests(run_dir / "frames" / "frame_00003.h5") == FROZEN_2D_DIGESTS_3
    assert _h5_digests(run_dir / "frames" / "frame_00001.h5") == FROZEN_2D_DIGESTS_1
    assert json.loads((run_dir / "metadata.json").read_text())["grid"] == FROZEN_2D_GRID


def test_2d_still_reads_as_2d(tmp_path):
    run_dir = tmp_path / "r2"
    fields = _write_2d(run_dir)
    _, got, attrs = read_frame(run_dir / "frames" / "frame_00003.h5")
    assert grid_from_attrs(attrs) == GRID2
    for name, arr in fields.items():
        np.testing.assert_array_equal(got[name], arr)
    ds = open_run(run_dir)
    assert grid_from_attrs(ds.attrs) == GRID2
    assert "z" not in ds.coords and "zc" not in ds.coords and "nz" not in ds.attrs
    assert ds["u"].dims == ("time", "x", "y") and ds["J"].dims == ("time", "solid", "xc", "yc")
    assert list(ds["xy"].values) == ["x", "y"]


def test_2d_caller_attr_named_nz_stays_2d(tmp_path):
    """A 2D frame may carry a caller attribute called nz (allowed before 3D existed); it
    must still read as 2D."""
    X, _ = GRID2.mesh("node")
    with RunWriter(tmp_path / "r", GRID2) as w:
        w.write_frame(0, 0.0, {"u": X}, attrs={"nz": 4})
    _, got, attrs = read_frame(tmp_path / "r" / "frames" / "frame_00000.h5")
    assert got["u"].shape == X.shape and grid_from_attrs(attrs) == GRID2
    assert open_run(tmp_path / "r")["u"].dims == ("time", "x", "y")


# ---------------------------------------------------------------------- 3D pictures
def _is_png(p) -> bool:
    return p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plot_field_draws_the_chosen_plane():
    from matplotlib.contour import ContourSet
    from matplotlib.figure import Figure

    from refmap.io import plot_field

    g = GRID3
    f = fields3d(0)
    z = g.axes("node")[2]
    # default: the middle z plane; nz = 8 nodes -> index 3 (of 0..7)
    ax = Figure().add_subplot()
    m = plot_field(ax, g, f["u"], None, f["phi"], title="u", velocity=(f["u"], f["v"], f["w"]))
    np.testing.assert_array_equal(np.asarray(m.get_array()), f["u"][:, :, 3])
    assert ax.get_title() == f"u,  $z = {z[3]:.4g}$"
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("$x$", "$y$")
    assert ax.get_xlim() == (g.ax, g.bx) and ax.get_ylim() == (g.ay, g.by)
    # both spheres cross that plane: two interface contours at level 0
    sets = [c for c in ax.collections if isinstance(c, ContourSet)]
    assert len(sets) == 2 and all(list(c.levels) == [0.0] for c in sets)
    # a corner field: 9 corner planes -> the middle one, index 4, at the centre of the box
    ax = Figure().add_subplot()
    m = plot_field(ax, g, f["sigma_xz"])
    assert np.asarray(m.get_array()).shape == (g.nx + 1, g.ny + 1)  # Gouraud: point values
    np.testing.assert_array_equal(np.asarray(m.get_array()), f["sigma_xz"][:, :, 4])
    assert ax.get_title() == f"$z = {0.5 * (g.az + g.bz):.4g}$"
    # an x plane by index (negative from the end): plot axes y across, z up
    ax = Figure().add_subplot()
    m = plot_field(ax, g, f["u"], slice_axis="x", slice_index=-1)
    np.testing.assert_array_equal(np.asarray(m.get_array()), f["u"][-1])
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("$y$", "$z$")
    assert ax.get_xlim() == (g.ay, g.by) and ax.get_ylim() == (g.az, g.bz)
    # a y plane by coordinate: the nearest node plane
    y = g.axes("node")[1]
    ax = Figure().add_subplot()
    m = plot_field(ax, g, f["u"], slice_axis="y", slice_at=y[5] + 0.4 * g.dy)
    np.testing.assert_array_equal(np.asarray(m.get_array()), f["u"][:, 5, :])
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("$x$", "$z$")
    with pytest.raises(ValueError, match="slice_axis"):
        plot_field(Figure().add_subplot(), g, f["u"], slice_axis="q")
    with pytest.raises(ValueError, match="outside"):
        plot_field(Figure().add_subplot(), g, f["u"], slice_index=g.nz)
    with pytest.raises(ValueError, match="2D"):
        plot_field(Figure().add_subplot(), GRID2, GRID2.mesh("node")[0], slice_index=1)


def test_slice_pngs(run3, tmp_path):
    from refmap.io import save_frame_png, save_panel_png

    run_dir, written = run3
    f = written[1]
    p = save_frame_png(
        tmp_path / "u.png",
        GRID3,
        0.375,
        "u",
        f["u"],
        "node",
        f["phi"],
        blur_edges=True,
        velocity=(f["u"], f["v"], f["w"]),
    )
    assert p.stat().st_size > 5000 and _is_png(p)
    p2 = save_frame_png(tmp_path / "s.png", GRID3, 0.1, "J", f["J"][1], slice_axis="y")
    assert p2.stat().st_size > 5000 and _is_png(p2)
    # panels from open_run, as Simulation.make_pictures builds them
    ds = open_run(run_dir)
    panels = [
        (float(ds.time[i]), ds["sigma_yy"].isel(time=i).values, ds["phi"].isel(time=i).values)
        for i in range(ds.sizes["time"])
    ]
    p3 = save_panel_png(tmp_path / "panel.png", GRID3, panels, "sigma_yy", "corner", ncols=2)
    assert p3.stat().st_size > 5000 and _is_png(p3)


def test_level_set_triangles_sphere():
    """A sphere's triangulated zero set: vertices on the sphere, closed and consistently
    oriented (every edge used once in each direction), outward, enclosing its volume."""
    from refmap.io import level_set_triangles

    g = Grid3D(24, 22, 20, -1.0, 1.4, -1.1, 1.1, -0.9, 1.1)
    X, Y, Z = g.mesh("node")
    c, r = np.array([0.15, 0.05, 0.1]), 0.7
    phi = np.sqrt((X - c[0]) ** 2 + (Y - c[1]) ** 2 + (Z - c[2]) ** 2) - r
    tris = level_set_triangles(phi, g)
    assert tris.shape[1:] == (3, 3) and len(tris) > 500
    assert np.abs(np.linalg.norm(tris - c, axis=-1) - r).max() < 0.1 * g.h
    # closed and consistently oriented
    key = np.round(tris * 1e8).astype(np.int64)
    edges = np.concatenate([key[:, [0, 1]], key[:, [1, 2]], key[:, [2, 0]]]).reshape(-1, 6)
    directed = {tuple(e) for e in edges.tolist()}
    assert len(directed) == len(edges)  # no directed edge twice
    assert all((e[3:] + e[:3]) in directed for e in directed)  # each has its reverse
    # outward normals: the divergence theorem gives + the volume
    vol = np.einsum("kd,kd->k", tris[:, 0], np.cross(tris[:, 1], tris[:, 2])).sum() / 6.0
    assert vol == pytest.approx(4.0 / 3.0 * np.pi * r**3, rel=0.02)
    # nothing where phi keeps one sign; NaN cells are left out
    assert level_set_triangles(phi + 5.0, g).shape == (0, 3, 3)
    holed = phi.copy()
    holed[12:, :, :] = np.nan
    assert 0 < len(level_set_triangles(holed, g)) < len(tris)


def test_surface_png(tmp_path):
    from refmap.io import save_surface_png

    f = fields3d(0)
    p = save_surface_png(tmp_path / "surf.png", f["phi"], GRID3, time=0.25)
    assert p.stat().st_size > 5000 and _is_png(p)
    one = save_surface_png(tmp_path / "pics" / "one.png", f["phi"][0], GRID3, title="ball")
    assert one.stat().st_size > 5000 and _is_png(one)
    # a solid without an interface is left out, not an error
    none = np.stack([f["phi"][0], f["phi"][1] + 10.0])
    assert _is_png(save_surface_png(tmp_path / "none.png", none, GRID3))
    with pytest.raises(ValueError, match="Grid3D"):
        save_surface_png(tmp_path / "x.png", np.zeros((10, 9)), GRID2)
    # y drawn upwards (gravity along -y): a different picture of the same surfaces
    up_y = save_surface_png(tmp_path / "y.png", f["phi"], GRID3, time=0.25, vertical="y")
    assert _is_png(up_y) and up_y.read_bytes() != p.read_bytes()
    with pytest.raises(ValueError, match="vertical must be"):
        save_surface_png(tmp_path / "q.png", f["phi"], GRID3, vertical="up")


def test_derived_fields_3d(run3):
    from refmap.io import derived_field

    run_dir, written = run3
    ds = open_run(run_dir)
    f = written[1]
    speed = derived_field(ds, "speed")
    assert speed.dims == ("time", "x", "y", "z")
    np.testing.assert_allclose(
        speed.isel(time=1).values, np.sqrt(f["u"] ** 2 + f["v"] ** 2 + f["w"] ** 2), rtol=1e-14
    )
    g = GRID3
    X, Y, Z = g.mesh("node")
    om = 0.7
    about_z = {"u": -om * Y, "v": om * X, "w": 0 * X}
    about_x = {"u": 0 * X, "v": -om * Z, "w": om * Y}
    for rot in (about_z, about_x):
        np.testing.assert_allclose(derived_field(rot, "vorticity", grid=g), 2 * om, rtol=1e-12)
    Xc, _, _ = g.mesh("corner")
    zero = 0 * Xc
    uniaxial = {n: zero for n in STRESS} | {"sigma_xx": -3.0 + zero}
    np.testing.assert_allclose(derived_field(uniaxial, "von_mises", grid=g), 3.0, rtol=1e-14)
    shear = {n: zero for n in STRESS} | {"sigma_yz": 2.0 + zero}
    np.testing.assert_allclose(
        derived_field(shear, "von_mises", grid=g), 2.0 * np.sqrt(3.0), rtol=1e-14
    )


def _ffmpeg_available() -> bool:
    try:
        import imageio_ffmpeg

        return Path(imageio_ffmpeg.get_ffmpeg_exe()).exists()
    except Exception:
        return False


@pytest.mark.skipif(not _ffmpeg_available(), reason="imageio-ffmpeg has no ffmpeg binary here")
def test_movie_3d(run3, tmp_path):
    from refmap.io import make_movie

    run_dir, _ = run3
    out = make_movie(run_dir, "u", tmp_path / "u.mp4", fps=5, velocity=True, blur_edges=True)
    data = out.read_bytes()
    assert len(data) > 0 and data[4:8] == b"ftyp"
    out2 = make_movie(run_dir, "J", tmp_path / "j.mp4", solid=1, slice_axis="x", slice_index=2)
    assert out2.stat().st_size > 0
    assert not list(tmp_path.glob(".*partial*"))


def test_reopened_3d_writer_keeps_the_xdmf(run3):
    """A resumed run (refmap.checkpoint.reopen_run_writer) lists the kept 3D frames again,
    velocity included, and goes on writing 3D frames."""
    from refmap.checkpoint import reopen_run_writer

    def attributes(path):  # {frame: {name: XML}}; the reopened writer lists them by name
        frames = ET.parse(path).getroot().find("Domain/Grid").findall("Grid")
        return {
            fr.get("Name"): {a.get("Name"): ET.tostring(a) for a in fr.findall("Attribute")}
            for fr in frames
        }

    run_dir, _ = run3
    before = attributes(run_dir / "run.xdmf")
    w = reopen_run_writer(run_dir, GRID3, next_frame=2, diag_rows=2)
    assert attributes(run_dir / "run.xdmf") == before
    w.write_frame(2, 0.5, fields3d(2), diagnostics=diags3d(2))
    w.close()
    ds = open_run(run_dir)
    assert ds.sizes["time"] == 3
    np.testing.assert_array_equal(ds["u"].isel(time=2).values, fields3d(2)["u"])
    root = ET.parse(run_dir / "run.xdmf").getroot()
    last = root.find("Domain/Grid").findall("Grid")[-1]
    assert "velocity" in [a.get("Name") for a in last.findall("Attribute")]
