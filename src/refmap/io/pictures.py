"""Figures and movies of a run: colour maps of node/corner fields with the solids' interfaces
drawn on top, multi-panel time series, MP4 movies, and a few derived fields.

Everything renders through matplotlib's Agg canvas directly (``Figure`` +
``FigureCanvasAgg``), never through pyplot, so it works without a display (CI, clusters)
and does not change the backend of an interactive session that imports this module.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import xarray as xr
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from refmap.grid import Grid
from refmap.io._common import grid_from_attrs

__all__ = [
    "DERIVED_FIELDS",
    "derived_field",
    "make_movie",
    "plot_field",
    "save_frame_png",
    "save_panel_png",
]

DERIVED_FIELDS = ("speed", "vorticity", "pressure", "von_mises")


# ---------------------------------------------------------------------- helpers
def _new_figure(figsize, dpi) -> Figure:
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _location_of(grid: Grid, shape: tuple[int, ...]) -> str:
    if tuple(shape[-2:]) == (grid.nx, grid.ny):
        return "node"
    if tuple(shape[-2:]) == (grid.nx + 1, grid.ny + 1):
        return "corner"
    raise ValueError(
        f"array of shape {tuple(shape)} is neither a node nor a corner field of {grid}"
    )


def color_range(data, vmin=None, vmax=None) -> tuple[float, float]:
    """Colour limits: the given ones, else the data range, made symmetric about 0 when the
    data change sign (so 0 sits at the centre of a diverging map)."""
    if vmin is not None and vmax is not None:
        return float(vmin), float(vmax)
    arr = np.asarray(data, dtype=np.float64)
    finite = arr[np.isfinite(arr)]
    if finite.size == 0:
        lo, hi = -1.0, 1.0
    else:
        lo, hi = float(finite.min()), float(finite.max())
        if lo < 0.0 < hi:
            a = max(-lo, hi)
            lo, hi = -a, a
    if vmin is not None:
        lo = float(vmin)
    if vmax is not None:
        hi = float(vmax)
    if not hi > lo:
        pad = max(abs(lo), 1.0) * 1e-6
        lo, hi = lo - pad, hi + pad
    return lo, hi


def _robust_range(values: np.ndarray) -> tuple[float, float, bool]:
    """(vmin, vmax, signed) from the 1st/99th percentiles: symmetric about 0 unless the
    field never goes below 0 (then [0, p99]) or above 0 (then [p1, 0])."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return -1.0, 1.0, True
    p1, p99 = np.percentile(finite, [1.0, 99.0])
    if finite.min() >= 0.0:
        lo, hi, signed = 0.0, float(p99), False
    elif finite.max() <= 0.0:
        lo, hi, signed = float(p1), 0.0, False
    else:
        a = float(max(abs(p1), abs(p99)))
        lo, hi, signed = -a, a, True
    if not hi > lo:
        pad = max(abs(lo), abs(hi), 1.0) * 1e-6
        lo, hi = lo - pad, hi + pad
    return lo, hi, signed


# ---------------------------------------------------------------------- plotting
def plot_field(
    ax,
    grid: Grid,
    data,
    loc: str | None = None,
    phis=None,
    title: str | None = None,
    cmap: str = "RdBu_r",
    vmin: float | None = None,
    vmax: float | None = None,
    levels=None,
    velocity=None,
    *,
    blur_edges: bool | float = False,
    colorbar: bool = True,
    colorbar_label: str | None = None,
    quiver_every: int | None = None,
):
    """Draw one field on ``ax`` in physical coordinates and return the colour mappable.

    ``data`` is a node ``(nx, ny)`` or corner ``(nx+1, ny+1)`` array indexed ``[i, j]``;
    ``loc`` ("node"/"corner") is inferred from the shape when None.  Node values fill their
    cells (flat shading between corners); corner values are interpolated across cells
    (Gouraud shading), so both cover exactly the domain.  ``levels`` (an int or a sequence)
    switches to filled contours.  Without ``vmin``/``vmax`` the range is the data range,
    symmetric about zero if the data change sign.

    ``phis``: level sets of the solids on the nodes, ``(nsolid, nx, ny)`` or ``(nx, ny)``;
    each interface phi = 0 is drawn as a thin black line.  ``blur_edges=True`` also draws the
    edges of the blur zone, phi = +-2 dx, as thin grey dashed lines (a number gives another
    half-width).  ``velocity=(u, v)`` (node or corner arrays) adds a subsampled quiver plot,
    about 24 arrows across unless ``quiver_every`` sets the stride.
    """
    data = np.asarray(data, dtype=np.float64)
    if loc is None:
        loc = _location_of(grid, data.shape)
    if data.shape != grid.shape(loc):
        raise ValueError(f"{loc} field must have shape {grid.shape(loc)}, got {data.shape}")
    vmin, vmax = color_range(data, vmin, vmax)

    if levels is not None:
        if np.ndim(levels) == 0:
            levels = np.linspace(vmin, vmax, int(levels) + 1)
        X, Y = grid.mesh(loc)
        mappable = ax.contourf(
            X, Y, np.ma.masked_invalid(data), levels=levels, cmap=cmap, extend="both"
        )
    elif loc == "node":
        Xc, Yc = grid.mesh("corner")
        mappable = ax.pcolormesh(
            Xc,
            Yc,
            np.ma.masked_invalid(data),
            shading="flat",
            cmap=cmap,
            vmin=vmin,
            vmax=vmax,
            rasterized=True,
        )
    else:
        Xc, Yc = grid.mesh("corner")
        has_nan = not np.all(np.isfinite(data))
        mappable = ax.pcolormesh(
            Xc,
            Yc,
            np.ma.masked_invalid(data) if has_nan else data,
            shading="nearest" if has_nan else "gouraud",
            cmap=cmap,
            vmin=vmin,
            vmax=vmax,
            rasterized=True,
        )

    if phis is not None:
        phis = np.asarray(phis, dtype=np.float64)
        if phis.ndim == 2:
            phis = phis[None]
        if phis.shape[1:] != grid.shape("node"):
            raise ValueError(f"phis must be (nsolid, nx, ny) node arrays, got {phis.shape}")
        Xn, Yn = grid.mesh("node")
        width = None
        if blur_edges is True:
            width = 2.0 * grid.dx
        elif blur_edges is not False and blur_edges is not None:
            width = float(blur_edges)
        for phi in phis:
            lo, hi = np.nanmin(phi), np.nanmax(phi)
            if lo < 0.0 < hi:
                ax.contour(Xn, Yn, phi, levels=[0.0], colors="k", linewidths=0.9)
            if width is not None:
                lv = [v for v in (-width, width) if lo < v < hi]
                if lv:
                    ax.contour(
                        Xn, Yn, phi, levels=lv, colors="0.45", linewidths=0.6, linestyles="--"
                    )

    if velocity is not None:
        u, v = (np.asarray(c, dtype=np.float64) for c in velocity)
        X, Y = grid.mesh(_location_of(grid, u.shape))
        s = quiver_every or max(1, int(round(max(u.shape) / 24)))
        sl = (slice(s // 2, None, s), slice(s // 2, None, s))
        ax.quiver(X[sl], Y[sl], u[sl], v[sl], color="k", alpha=0.75, width=0.0025)

    ax.set_xlim(grid.ax, grid.bx)
    ax.set_ylim(grid.ay, grid.by)
    ax.set_aspect("equal")
    ax.set_xlabel("$x$")
    ax.set_ylabel("$y$")
    if title:
        ax.set_title(title)
    if colorbar:
        cb = ax.figure.colorbar(mappable, ax=ax, shrink=0.9)
        if colorbar_label:
            cb.set_label(colorbar_label)
    return mappable


def save_frame_png(
    path: str | os.PathLike,
    grid: Grid,
    time: float,
    field_name: str,
    data,
    loc: str | None = None,
    phis=None,
    *,
    dpi: int = 120,
    figsize: tuple[float, float] = (6.0, 5.0),
    **kw,
) -> Path:
    """Save one field at one time as a PNG (6 x 5 inches at 120 dpi by default).

    The title reads ``"<field_name>,  t = <time>"`` unless ``title=`` is given; other
    keywords go to :func:`plot_field`.  Returns the path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig = _new_figure(figsize, dpi)
    ax = fig.add_subplot()
    kw.setdefault("title", f"{field_name},  $t = {time:.4g}$")
    plot_field(ax, grid, data, loc, phis, **kw)
    fig.savefig(path, dpi=dpi)
    return path


def save_panel_png(
    path: str | os.PathLike,
    grid: Grid,
    panels: Sequence[tuple],
    field_name: str,
    loc: str | None = None,
    ncols: int = 3,
    *,
    vmin: float | None = None,
    vmax: float | None = None,
    dpi: int = 120,
    panel_size: tuple[float, float] = (3.2, 2.9),
    **kw,
) -> Path:
    """Save several times of one field side by side, sharing one colour range and bar.

    ``panels`` is a sequence of ``(time, data)`` or ``(time, data, phis)``.  Without
    ``vmin``/``vmax`` the range covers all panels (symmetric about 0 if the data change
    sign).  Other keywords go to :func:`plot_field`.  Returns the path.
    """
    if not panels:
        raise ValueError("save_panel_png needs at least one panel")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ncols = max(1, min(int(ncols), len(panels)))
    nrows = -(-len(panels) // ncols)
    all_data = np.concatenate([np.asarray(p[1], dtype=np.float64).ravel() for p in panels])
    vmin, vmax = color_range(all_data, vmin, vmax)
    fig = _new_figure((panel_size[0] * ncols + 0.8, panel_size[1] * nrows + 0.4), dpi)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    used = []
    mappable = None
    for k, panel in enumerate(panels):
        time, data = panel[0], panel[1]
        phis = panel[2] if len(panel) > 2 else None
        ax = axes[k // ncols][k % ncols]
        mappable = plot_field(
            ax,
            grid,
            data,
            loc,
            phis,
            title=f"$t = {time:.4g}$",
            vmin=vmin,
            vmax=vmax,
            colorbar=False,
            **kw,
        )
        used.append(ax)
    for k in range(len(panels), nrows * ncols):
        axes[k // ncols][k % ncols].set_axis_off()
    fig.colorbar(mappable, ax=used, shrink=0.9, label=field_name)
    fig.suptitle(field_name)
    fig.savefig(path, dpi=dpi)
    return path


# ---------------------------------------------------------------------- derived fields
def _unpack_source(source, grid):
    """-> (getter mapping, dx, dy, is_dataset)."""
    if isinstance(source, xr.Dataset):
        g = grid or grid_from_attrs(source.attrs)
        return source, g.dx, g.dy, True
    if isinstance(source, tuple) and len(source) == 3 and isinstance(source[1], Mapping):
        g = grid or grid_from_attrs(source[2])
        return source[1], g.dx, g.dy, False
    if isinstance(source, Mapping):
        if grid is None:
            raise ValueError("derived_field on a plain mapping of arrays needs grid=")
        return source, grid.dx, grid.dy, False
    raise TypeError(
        "derived_field expects an xarray.Dataset from open_run, a (time, fields, attrs) "
        f"tuple from read_frame, or a mapping of arrays with grid=; got {type(source)!r}"
    )


def derived_field(source, name: str, grid: Grid | None = None):
    """Compute a derived quantity from stored fields.

    ``source``: the Dataset from :func:`refmap.io.open_run` (result: an ``xarray.DataArray``
    over all times), the ``(time, fields, attrs)`` tuple of :func:`refmap.io.read_frame` or a
    dict of ``[i, j]`` arrays together with ``grid=`` (result: a numpy array).

    Names:

    * ``"speed"``: sqrt(u^2 + v^2);
    * ``"vorticity"``: dv/dx - du/dy with ``np.gradient`` (second-order central differences
      inside, one-sided at the edges) on the points u and v live on;
    * ``"pressure"``: the stored ``pressure`` (or ``p``) field;
    * ``"von_mises"``: sqrt(sxx^2 - sxx syy + syy^2 + 3 sxy^2) from the stored corner
      fields ``sigma_xx``, ``sigma_xy``, ``sigma_yy`` (sigma_zz of plane strain left out).

    A name that is already a stored field is returned unchanged.  Anything else raises
    ValueError listing what is available.
    """
    fields, dx, dy, is_ds = _unpack_source(source, grid)
    stored = list(fields.data_vars) if is_ds else list(fields)

    def need(*names):
        missing = [n for n in names if n not in fields]
        if missing:
            raise ValueError(
                f"derived field {name!r} needs stored fields {list(names)}; missing {missing} "
                f"(stored: {stored})"
            )
        return [fields[n] for n in names]

    def raw(a):
        return np.asarray(a.values if is_ds else a, dtype=np.float64)

    def wrap(values, like, location=None):
        if not is_ds:
            return values
        da = xr.DataArray(values, dims=like.dims, coords=like.coords, name=name)
        da.attrs = dict(like.attrs)
        if location:
            da.attrs["location"] = location
        return da

    if name == "speed":
        u, v = need("u", "v")
        return wrap(np.sqrt(raw(u) ** 2 + raw(v) ** 2), u)
    if name == "vorticity":
        u, v = need("u", "v")
        uu, vv = raw(u), raw(v)
        if uu.shape != vv.shape:
            raise ValueError(f"u {uu.shape} and v {vv.shape} live on different points")
        w = np.gradient(vv, dx, axis=-2) - np.gradient(uu, dy, axis=-1)
        return wrap(w, u)
    if name == "pressure":
        for cand in ("pressure", "p"):
            if cand in fields:
                return fields[cand] if not is_ds else fields[cand].rename(name)
        raise ValueError(f"pressure is not stored in this run (stored: {stored})")
    if name == "von_mises":
        sxx, sxy, syy = (raw(a) for a in need("sigma_xx", "sigma_xy", "sigma_yy"))
        vm = np.sqrt(np.maximum(sxx**2 - sxx * syy + syy**2 + 3.0 * sxy**2, 0.0))
        return wrap(vm, fields["sigma_xx"])
    if name in fields:
        return fields[name]
    raise ValueError(
        f"unknown field {name!r}: derived fields are {list(DERIVED_FIELDS)}, stored fields are "
        f"{stored}"
    )


# ---------------------------------------------------------------------- movies
def make_movie(
    run_dir: str | os.PathLike,
    field: str,
    out_path: str | os.PathLike,
    fps: int = 15,
    vmin: float | None = None,
    vmax: float | None = None,
    *,
    solid: int | None = None,
    cmap: str | None = None,
    phi_name: str = "phi",
    blur_edges: bool | float = False,
    velocity: bool = False,
    dpi: int = 100,
    figsize: tuple[float, float] = (6.4, 5.0),
    quality: float = 7,
) -> Path:
    """Render one field of a run, frame by frame, into an H.264 MP4 and return its path.

    ``field`` is a stored field or a name known to :func:`derived_field`.  For a per-solid
    field pick the solid with ``solid=`` (needed when there is more than one).  The colour
    range is fixed over the whole movie: ``vmin``/``vmax`` if given, else the 1st/99th
    percentiles over all frames, made symmetric about zero (a field that never changes sign
    gets [0, p99] or [p1, 0] instead, with a sequential colour map unless ``cmap`` is given).
    The interfaces are drawn from the per-solid node field ``phi_name`` when the run has it;
    ``velocity=True`` overlays a quiver of (u, v).  Frames are drawn with the Agg canvas,
    cropped to even width and height, and piped to the ffmpeg shipped with imageio-ffmpeg.
    The movie is written under a temporary name and moved into place when complete.
    """
    import imageio_ffmpeg

    from refmap.io.reader import open_run

    ds = open_run(run_dir)
    grid = grid_from_attrs(ds.attrs)
    da = derived_field(ds, field)
    if "solid" in da.dims:
        if solid is None:
            if da.sizes["solid"] != 1:
                raise ValueError(
                    f"{field!r} is a per-solid field with {da.sizes['solid']} solids; pass solid="
                )
            solid = 0
        da = da.isel(solid=solid)
    loc = "corner" if "xc" in da.dims else "node"
    values = np.asarray(da.transpose("time", ...).values, dtype=np.float64)
    if values.shape[0] == 0:
        raise ValueError(f"run {run_dir} has no frames")

    lo, hi, signed = _robust_range(values)
    vmin = lo if vmin is None else float(vmin)
    vmax = hi if vmax is None else float(vmax)
    if cmap is None:
        cmap = "RdBu_r" if signed else "viridis"

    phis = None
    if phi_name in ds and ds[phi_name].attrs.get("location") == "node":
        phis = np.asarray(ds[phi_name].values)
    uv = None
    if velocity and "u" in ds and "v" in ds:
        uv = (np.asarray(ds["u"].values), np.asarray(ds["v"].values))

    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp_path = out_path.with_name(f".{out_path.stem}.partial{out_path.suffix or '.mp4'}")
    fig = _new_figure(figsize, dpi)
    canvas = fig.canvas
    writer = None
    label = field if solid is None else f"{field} (solid {solid})"
    try:
        for t in range(values.shape[0]):
            fig.clear()
            ax = fig.add_subplot()
            plot_field(
                ax,
                grid,
                values[t],
                loc,
                None if phis is None else phis[t],
                title=f"{label},  $t = {float(ds.time[t]):.4g}$",
                cmap=cmap,
                vmin=vmin,
                vmax=vmax,
                velocity=None if uv is None else (uv[0][t], uv[1][t]),
                blur_edges=blur_edges,
            )
            canvas.draw()
            rgb = np.asarray(canvas.buffer_rgba())[:, :, :3]
            h, w = rgb.shape[0] // 2 * 2, rgb.shape[1] // 2 * 2
            rgb = np.ascontiguousarray(rgb[:h, :w])
            if writer is None:
                size = (w, h)
                writer = imageio_ffmpeg.write_frames(
                    str(tmp_path),
                    size,
                    fps=fps,
                    codec="libx264",
                    pix_fmt_in="rgb24",
                    pix_fmt_out="yuv420p",
                    quality=quality,
                    macro_block_size=1,
                    ffmpeg_log_level="error",
                )
                writer.send(None)
            elif (w, h) != size:
                raise RuntimeError(f"frame size changed from {size} to {(w, h)}")
            writer.send(rgb)
        writer.close()
        writer = None
        os.replace(tmp_path, out_path)
    finally:
        if writer is not None:
            writer.close()
        if tmp_path.exists():
            tmp_path.unlink()
    return out_path
