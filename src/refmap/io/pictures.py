"""Figures and movies of a run: colour maps of node/corner fields with the solids' interfaces
drawn on top, multi-panel time series, MP4 movies, and a few derived fields.

A 3D run (:class:`~refmap.grid.Grid3D`) is shown without ParaView in two ways: every colour
map (:func:`plot_field`, :func:`save_frame_png`, :func:`save_panel_png`, :func:`make_movie`)
draws one plane of the field, the middle z plane unless ``slice_axis`` / ``slice_index`` /
``slice_at`` say otherwise, with the interfaces cut by that plane and the plane named in the
title; and :func:`save_surface_png` draws each solid's zero level set as a shaded 3D surface,
triangulated by :func:`level_set_triangles` (marching tetrahedra in numpy, no extra
dependency).

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

from refmap.grid import Grid, Grid3D
from refmap.io._common import grid_from_attrs

__all__ = [
    "DERIVED_FIELDS",
    "derived_field",
    "level_set_triangles",
    "make_movie",
    "plot_field",
    "save_frame_png",
    "save_panel_png",
    "save_surface_png",
]

DERIVED_FIELDS = ("speed", "vorticity", "pressure", "von_mises")


# ---------------------------------------------------------------------- helpers
#: Corner fields with more values than this are drawn as one quad per corner
#: (``shading="nearest"``), not Gouraud-shaded: 513^2 and up.
GOURAUD_MAX_POINTS = 512 * 512


def _new_figure(figsize, dpi) -> Figure:
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _location_of(grid: Grid | Grid3D, shape: tuple[int, ...]) -> str:
    d = grid.ndim
    if tuple(shape[-d:]) == tuple(grid.shape("node")):
        return "node"
    if tuple(shape[-d:]) == tuple(grid.shape("corner")):
        return "corner"
    raise ValueError(
        f"array of shape {tuple(shape)} is neither a node nor a corner field of {grid}"
    )


# ---------------------------------------------------------------------- 3D: planes
_AXIS_NAMES = ("x", "y", "z")


def _plane_spec(
    grid: Grid3D, loc: str, slice_axis="z", slice_index=None, slice_at=None
) -> tuple[int, int, float]:
    """``(axis number, index, coordinate)`` of the plane of ``loc`` points to draw.

    ``slice_axis``: "x", "y", "z" (or 0, 1, 2), the axis normal to the plane.
    ``slice_index``: index into the field's own points (nodes or corners) along that axis
    (negative counts from the end); ``slice_at``: a coordinate, the nearest plane of points
    is taken; neither: the middle plane, index ``(n - 1) // 2`` of the ``n`` planes (the
    lower of the two middle ones when n is even: an even number of cells puts a corner
    plane, not a node plane, at the centre).
    """
    if slice_axis in _AXIS_NAMES:
        a = _AXIS_NAMES.index(slice_axis)
    elif isinstance(slice_axis, (int, np.integer)) and 0 <= slice_axis < 3:
        a = int(slice_axis)
    else:
        raise ValueError(f"slice_axis must be 'x', 'y' or 'z', got {slice_axis!r}")
    coords = grid.axes(loc)[a]
    if slice_index is not None and slice_at is not None:
        raise ValueError("give slice_index or slice_at, not both")
    if slice_index is not None:
        n = len(coords)
        k = int(slice_index)
        if not -n <= k < n:
            raise ValueError(
                f"slice_index {slice_index} is outside the {n} {loc} planes along {_AXIS_NAMES[a]}"
            )
        k %= n
    elif slice_at is None:
        k = (len(coords) - 1) // 2
    else:
        lo, hi = grid.lows[a], grid.highs[a]
        at = float(slice_at)
        if not lo <= at <= hi:
            raise ValueError(f"slice_at {at} is outside [{lo}, {hi}] along {_AXIS_NAMES[a]}")
        k = int(np.argmin(np.abs(coords - at)))
    return a, k, float(coords[k])


def _plane_grid(grid: Grid3D, a: int) -> tuple[Grid, tuple[str, str]]:
    """The 2D grid of the plane normal to axis ``a`` (in-plane axes in x, y, z order) and
    the names of its two axes."""
    b, c = (m for m in range(3) if m != a)
    n = grid.shape("node")
    lo, hi = grid.lows, grid.highs
    return Grid(int(n[b]), int(n[c]), lo[b], hi[b], lo[c], hi[c]), (
        _AXIS_NAMES[b],
        _AXIS_NAMES[c],
    )


def _interp_plane(arr: np.ndarray, grid: Grid3D, loc: str, a: int, at: float) -> np.ndarray:
    """``arr`` (``(..., *grid.shape(loc))``) linearly interpolated to the plane at
    coordinate ``at`` normal to axis ``a`` (exactly a plane of points when ``at`` is one;
    clamped to the outermost planes)."""
    coords = grid.axes(loc)[a]
    axis = arr.ndim - 3 + a
    h = grid.spacing[a]
    s = (at - coords[0]) / h
    i0 = int(np.clip(np.floor(s + 1e-9), 0, len(coords) - 2))
    t = float(np.clip(s - i0, 0.0, 1.0))
    lo = np.take(arr, i0, axis=axis)
    if t < 1e-9:  # on a plane of points (up to rounding): its values exactly
        return lo
    hi = np.take(arr, i0 + 1, axis=axis)
    if t > 1.0 - 1e-9:
        return hi
    return (1.0 - t) * lo + t * hi


def _slice_values(grid: Grid3D, data: np.ndarray, loc: str, spec) -> np.ndarray:
    """The plane ``spec`` (from :func:`_plane_spec`) of ``(..., *grid.shape(loc))`` data."""
    a, k, _ = spec
    return np.take(data, k, axis=data.ndim - 3 + a)


def _plane_of(grid: Grid3D, data: np.ndarray, loc: str | None, **plane_kw) -> np.ndarray:
    """The plane of ``data`` that :func:`plot_field` draws with the same keywords."""
    loc = loc or _location_of(grid, data.shape)
    return _slice_values(grid, data, loc, _plane_spec(grid, loc, **plane_kw))


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
    slice_axis: str | int = "z",
    slice_index: int | None = None,
    slice_at: float | None = None,
):
    """Draw one field on ``ax`` in physical coordinates and return the colour mappable.

    ``data`` is a node ``(nx, ny)`` or corner ``(nx+1, ny+1)`` array indexed ``[i, j]``;
    ``loc`` ("node"/"corner") is inferred from the shape when None.  Node values fill their
    cells (flat shading between corners); corner values are interpolated across cells
    (Gouraud shading), so both cover exactly the domain.  ``levels`` (an int or a sequence)
    switches to filled contours.  Without ``vmin``/``vmax`` the range is the data range,
    symmetric about zero if the data change sign.

    ``phis``: level sets of the solids on the nodes, ``(nsolid, nx, ny)`` or ``(nx, ny)``
    (one solid's, or the union of all, which a run whose solids are stored in windows
    writes as ``phi``: one contour for a thousand bodies); each interface phi = 0 is drawn
    as a thin black line.  ``blur_edges=True`` also draws the
    edges of the blur zone, phi = +-2 dx, as thin grey dashed lines (a number gives another
    half-width).  ``velocity=(u, v)`` (node or corner arrays) adds a subsampled quiver plot,
    about 24 arrows across unless ``quiver_every`` sets the stride.

    On a :class:`~refmap.grid.Grid3D` the field (``(nx, ny, nz)`` or ``(nx+1, ny+1, nz+1)``)
    is drawn on one plane of its points normal to ``slice_axis`` ("x", "y" or "z"; default
    "z"): ``slice_index`` picks the plane by index along that axis (among the field's own
    points, nodes or corners), ``slice_at`` by coordinate (the nearest plane), neither the
    middle of the domain.  The interfaces are the phi = 0 lines of the level sets
    ``(nsolid, nx, ny, nz)`` interpolated to that plane, ``velocity=(u, v, w)`` shows the two
    in-plane components, blur edges are at phi = +-2 h, and the title ends with the plane
    (e.g. ``"z = 0.5"``; the plane alone when ``title`` is None).  The plot axes are the two
    in-plane axes in x, y, z order (a y plane shows x across and z up).
    """
    if grid.ndim == 3:
        return _plot_slice(
            ax,
            grid,
            data,
            loc,
            phis,
            title,
            cmap,
            vmin,
            vmax,
            levels,
            velocity,
            blur_edges=blur_edges,
            colorbar=colorbar,
            colorbar_label=colorbar_label,
            quiver_every=quiver_every,
            slice_axis=slice_axis,
            slice_index=slice_index,
            slice_at=slice_at,
        )
    if slice_index is not None or slice_at is not None:
        raise ValueError("slice_index / slice_at are for 3D grids; this grid is 2D")
    return _plot_plane(
        ax,
        grid,
        data,
        loc,
        phis,
        title,
        cmap,
        vmin,
        vmax,
        levels,
        velocity,
        blur_edges=blur_edges,
        colorbar=colorbar,
        colorbar_label=colorbar_label,
        quiver_every=quiver_every,
    )


def _plot_slice(
    ax,
    grid: Grid3D,
    data,
    loc,
    phis,
    title,
    cmap,
    vmin,
    vmax,
    levels,
    velocity,
    *,
    blur_edges,
    colorbar,
    colorbar_label,
    quiver_every,
    slice_axis,
    slice_index,
    slice_at,
):
    """:func:`plot_field` on a 3D grid: cut the plane, then draw it as a 2D field."""
    data = np.asarray(data, dtype=np.float64)
    if loc is None:
        loc = _location_of(grid, data.shape)
    if data.shape != grid.shape(loc):
        raise ValueError(f"{loc} field must have shape {grid.shape(loc)}, got {data.shape}")
    spec = _plane_spec(grid, loc, slice_axis, slice_index, slice_at)
    a, _, at = spec
    plane, labels = _plane_grid(grid, a)
    data2 = _slice_values(grid, data, loc, spec)
    phis2 = None
    if phis is not None:
        phis = np.asarray(phis, dtype=np.float64)
        if phis.ndim == 3:
            phis = phis[None]
        if phis.ndim != 4 or phis.shape[1:] != grid.shape("node"):
            raise ValueError(f"phis must be (nsolid, nx, ny, nz) node arrays, got {phis.shape}")
        phis2 = _interp_plane(phis, grid, "node", a, at)
    vel2 = None
    if velocity is not None:
        comps = [np.asarray(c, dtype=np.float64) for c in velocity]
        if len(comps) != 3:
            raise ValueError(f"velocity on a 3D grid is (u, v, w), got {len(comps)} components")
        vel2 = tuple(
            _interp_plane(comps[m], grid, _location_of(grid, comps[m].shape), a, at)
            for m in range(3)
            if m != a
        )
    if blur_edges is True:
        blur_edges = 2.0 * grid.h
    where = f"{_AXIS_NAMES[a]} = {at:.4g}"
    return _plot_plane(
        ax,
        plane,
        data2,
        loc,
        phis2,
        f"{title},  ${where}$" if title else f"${where}$",
        cmap,
        vmin,
        vmax,
        levels,
        vel2,
        blur_edges=blur_edges,
        colorbar=colorbar,
        colorbar_label=colorbar_label,
        quiver_every=quiver_every,
        labels=labels,
    )


def _plot_plane(
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
    labels: tuple[str, str] = ("x", "y"),
):
    """The 2D drawing of :func:`plot_field` (``labels``: the names of the plot's axes)."""
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
            # Gouraud shading smooths a coarse grid's corners; past GOURAUD_MAX_POINTS the
            # grid has more corners than the picture has pixels, and matplotlib's triangles
            # cost seconds and gigabytes (1025^2: 4 s, 1.3 GB against 0.6 s for quads)
            shading="nearest" if has_nan or data.size > GOURAUD_MAX_POINTS else "gouraud",
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
    ax.set_xlabel(f"${labels[0]}$")
    ax.set_ylabel(f"${labels[1]}$")
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
    keywords go to :func:`plot_field`.  Returns the path.  On a 3D grid the picture is one
    plane of the field (the middle z plane unless ``slice_axis`` / ``slice_index`` /
    ``slice_at`` say otherwise; see :func:`plot_field`), named at the end of the title.
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
    sign).  Other keywords go to :func:`plot_field`.  Returns the path.  On a 3D grid every
    panel shows the same plane (``slice_axis`` / ``slice_index`` / ``slice_at``, default the
    middle z plane) and the colour range covers that plane only.
    """
    if not panels:
        raise ValueError("save_panel_png needs at least one panel")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ncols = max(1, min(int(ncols), len(panels)))
    nrows = -(-len(panels) // ncols)
    shown = [np.asarray(p[1], dtype=np.float64) for p in panels]
    if grid.ndim == 3:
        plane_kw = {k: kw[k] for k in ("slice_axis", "slice_index", "slice_at") if k in kw}
        shown = [_plane_of(grid, d, loc, **plane_kw) for d in shown]
    all_data = np.concatenate([d.ravel() for d in shown])
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


def _solid_field_from_windows(run_dir, ds, grid, field: str, solid: int | None):
    """``(DataArray (time, x, y[, z]), solid)``: one solid's ``phi`` or ``xi_*`` in every
    frame of ``ds`` (a run whose solids are stored in windows), rebuilt from the frames'
    windows by :func:`refmap.io.per_solid_fields`, one frame at a time."""
    from refmap.io.reader import list_frames, per_solid_fields, read_frame

    paths = dict(list_frames(run_dir))
    values = []
    for index in ds["index"].values:
        source = read_frame(paths[int(index)])
        n = source[2]["windows"]["phi_window"].shape[0] if source[2]["windows"] else 0
        if solid is None:
            if n != 1:
                raise ValueError(f"{field!r} is a per-solid field with {n} solids; pass solid=")
            solid = 0
        values.append(per_solid_fields(source, solid)[field])
    dims = ("time", *("x", "y", "z")[: grid.ndim])
    return xr.DataArray(np.stack(values), dims=dims, coords={"time": ds["time"].values}), solid


# ---------------------------------------------------------------------- derived fields
def _unpack_source(source, grid):
    """-> (getter mapping, grid, is_dataset)."""
    if isinstance(source, xr.Dataset):
        g = grid or grid_from_attrs(source.attrs)
        return source, g, True
    if isinstance(source, tuple) and len(source) == 3 and isinstance(source[1], Mapping):
        g = grid or grid_from_attrs(source[2])
        return source[1], g, False
    if isinstance(source, Mapping):
        if grid is None:
            raise ValueError("derived_field on a plain mapping of arrays needs grid=")
        return source, grid, False
    raise TypeError(
        "derived_field expects an xarray.Dataset from open_run, a (time, fields, attrs) "
        f"tuple from read_frame, or a mapping of arrays with grid=; got {type(source)!r}"
    )


def derived_field(source, name: str, grid: Grid | Grid3D | None = None):
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

    On a 3D grid (arrays ``[..., i, j, k]``): ``"speed"`` is sqrt(u^2 + v^2 + w^2),
    ``"vorticity"`` the magnitude of the curl of (u, v, w) (same differences), and
    ``"von_mises"`` sqrt((sxx - syy)^2/2 + (syy - szz)^2/2 + (szz - sxx)^2/2
    + 3 (sxy^2 + syz^2 + sxz^2)) from the six stored stress components.

    A name that is already a stored field is returned unchanged.  Anything else raises
    ValueError listing what is available.
    """
    fields, g, is_ds = _unpack_source(source, grid)
    dx, dy = g.dx, g.dy
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

    if g.ndim == 3 and name in ("speed", "vorticity", "von_mises"):
        return _derived_3d(name, g, need, raw, wrap)
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


def _derived_3d(name, grid: Grid3D, need, raw, wrap):
    """speed, vorticity magnitude and von Mises stress of a 3D run (see derived_field)."""
    if name == "von_mises":
        comps = need("sigma_xx", "sigma_xy", "sigma_xz", "sigma_yy", "sigma_yz", "sigma_zz")
        sxx, sxy, sxz, syy, syz, szz = (raw(a) for a in comps)
        j2 = ((sxx - syy) ** 2 + (syy - szz) ** 2 + (szz - sxx) ** 2) / 6.0
        j2 = j2 + sxy**2 + syz**2 + sxz**2
        return wrap(np.sqrt(np.maximum(3.0 * j2, 0.0)), comps[0])
    u, v, w = need("u", "v", "w")
    uu, vv, ww = raw(u), raw(v), raw(w)
    if not uu.shape == vv.shape == ww.shape:
        raise ValueError(f"u {uu.shape}, v {vv.shape} and w {ww.shape} live on different points")
    if name == "speed":
        return wrap(np.sqrt(uu**2 + vv**2 + ww**2), u)
    dx, dy, dz = grid.spacing

    def d(f, h, axis):
        return np.gradient(f, h, axis=axis)

    wx = d(ww, dy, -2) - d(vv, dz, -1)
    wy = d(uu, dz, -1) - d(ww, dx, -3)
    wz = d(vv, dx, -3) - d(uu, dy, -2)
    return wrap(np.sqrt(wx**2 + wy**2 + wz**2), u)


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
    slice_axis: str | int = "z",
    slice_index: int | None = None,
    slice_at: float | None = None,
) -> Path:
    """Render one field of a run, frame by frame, into an H.264 MP4 and return its path.

    ``field`` is a stored field or a name known to :func:`derived_field`.  For a per-solid
    field pick the solid with ``solid=`` (needed when there is more than one).  The colour
    range is fixed over the whole movie: ``vmin``/``vmax`` if given, else the 1st/99th
    percentiles over all frames, made symmetric about zero (a field that never changes sign
    gets [0, p99] or [p1, 0] instead, with a sequential colour map unless ``cmap`` is given).
    The interfaces are drawn from the node field ``phi_name`` when the run has it (per solid,
    or the union of the solids' level sets of a run whose solids are stored in windows);
    ``velocity=True`` overlays a quiver of (u, v).  Frames are drawn with the Agg canvas,
    cropped to even width and height, and piped to the ffmpeg shipped with imageio-ffmpeg.
    The movie is written under a temporary name and moved into place when complete.

    A 3D run gives a movie of one plane of the field: the middle z plane unless
    ``slice_axis`` / ``slice_index`` / ``slice_at`` say otherwise (see :func:`plot_field`);
    the colour range is taken over that plane, and ``velocity=True`` shows the in-plane
    components of (u, v, w).
    """
    import imageio_ffmpeg

    from refmap.io.reader import open_run

    ds = open_run(run_dir)
    grid = grid_from_attrs(ds.attrs)
    if "solid_index" in ds and (field.startswith("xi_") or (field == phi_name and solid is not None)):
        # solids stored in windows: one solid's level set or map rebuilt from each frame's
        # windows (the grid holds their union only)
        da, solid = _solid_field_from_windows(run_dir, ds, grid, field, solid)
    else:
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
    plane_kw = {}
    shown = values
    if grid.ndim == 3:
        plane_kw = {"slice_axis": slice_axis, "slice_index": slice_index, "slice_at": slice_at}
        shown = _plane_of(grid, values, loc, **plane_kw)

    lo, hi, signed = _robust_range(shown)
    vmin = lo if vmin is None else float(vmin)
    vmax = hi if vmax is None else float(vmax)
    if cmap is None:
        cmap = "RdBu_r" if signed else "viridis"

    phis = None
    if phi_name in ds and ds[phi_name].attrs.get("location") == "node":
        phis = np.asarray(ds[phi_name].values)
    uv = None
    comps = ("u", "v", "w")[: grid.ndim]
    if velocity and all(c in ds for c in comps):
        uv = tuple(np.asarray(ds[c].values) for c in comps)

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
                velocity=None if uv is None else tuple(c[t] for c in uv),
                blur_edges=blur_edges,
                **plane_kw,
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


# ---------------------------------------------------------------------- 3D surfaces
# Marching tetrahedra.  Each cell of the point lattice (8 points, point m at offset
# (m & 1, m >> 1 & 1, m >> 2 & 1) along x, y, z) is cut into the 6 tetrahedra around its
# main diagonal 0-7 (Kuhn's triangulation).  Every cell is cut the same way, so neighbouring
# cells split their shared face along the same diagonal and the surface has no cracks.
# Inside phi is linear, so its zero set is one triangle (1 or 3 vertices inside) or a quad
# (2 inside), its vertices where phi changes sign along the edges.
_CELL_POINTS = np.array([[m & 1, (m >> 1) & 1, (m >> 2) & 1] for m in range(8)])
_TETS = np.array(
    [[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]]
)


def _tet_cases() -> dict[int, list[tuple[tuple[int, int], ...]]]:
    """For each sign pattern (bit v set: vertex v inside, phi < 0) the triangles of the
    zero set, each as three edges (vertex pairs) of the tetrahedron."""
    cases = {}
    for code in range(1, 15):
        inside = [v for v in range(4) if code >> v & 1]
        outside = [v for v in range(4) if not code >> v & 1]
        if len(inside) in (1, 3):
            lone, rest = (inside, outside) if len(inside) == 1 else (outside, inside)
            a = lone[0]
            cases[code] = [tuple((a, b) for b in rest)]
        else:
            (a, b), (c, d) = inside, outside
            # the quad's corners on edges ac, ad, bd, bc, in order around it
            cases[code] = [((a, c), (a, d), (b, d)), ((a, c), (b, d), (b, c))]
    return cases


_TET_CASES = _tet_cases()


def level_set_triangles(phi, grid: Grid3D, level: float = 0.0, loc: str | None = None):
    """Triangles of the surface ``phi = level`` of one 3D field, shape ``(ntri, 3, 3)``
    (triangle, vertex, xyz) in physical coordinates.

    ``phi`` is a node ``(nx, ny, nz)`` (or corner) array indexed ``[i, j, k]``; ``loc`` is
    inferred from the shape when None.  Marching tetrahedra with linear interpolation along
    the edges: the surface is closed wherever it does not reach the outermost points, its
    vertices lie on the lattice edges, and each triangle is oriented with its normal
    (vertices counter-clockwise) pointing to increasing phi, i.e. out of a solid whose phi
    is negative inside.  Cells touching a non-finite value are left out.  Vectorised: only
    the cells the surface crosses are processed, with no Python loop over them.
    """
    phi = np.asarray(phi, dtype=np.float64)
    if grid.ndim != 3:
        raise ValueError(f"level_set_triangles needs a Grid3D, got {grid}")
    if loc is None:
        loc = _location_of(grid, phi.shape)
    if phi.shape != grid.shape(loc):
        raise ValueError(f"{loc} field must have shape {grid.shape(loc)}, got {phi.shape}")
    f = phi - float(level)
    n = f.shape
    vals = np.stack(
        [f[i : n[0] - 1 + i, j : n[1] - 1 + j, k : n[2] - 1 + k] for i, j, k in _CELL_POINTS],
        axis=-1,
    )  # (nx-1, ny-1, nz-1, 8)
    crossing = np.all(np.isfinite(vals), axis=-1)
    crossing &= (vals.min(axis=-1) < 0.0) & (vals.max(axis=-1) >= 0.0)
    cells = np.argwhere(crossing)  # (m, 3)
    if cells.size == 0:
        return np.zeros((0, 3, 3))
    axes = grid.axes(loc)
    lattice = cells[:, None, :] + _CELL_POINTS[None]  # (m, 8, 3) point indices
    pos = np.stack([axes[d][lattice[..., d]] for d in range(3)], axis=-1)  # (m, 8, 3)
    tv = vals[crossing][:, _TETS].reshape(-1, 4)  # (6m, 4)
    tp = pos[:, _TETS].reshape(-1, 4, 3)  # (6m, 4, 3)
    code = ((tv < 0.0) * (1 << np.arange(4))).sum(axis=-1)
    out = []
    for c, tris in _TET_CASES.items():
        sel = code == c
        if not sel.any():
            continue
        sv, sp = tv[sel], tp[sel]
        # a vector along grad phi in each tetrahedron (exact direction for linear phi up to
        # a positive definite factor), to orient the triangles
        grad = np.einsum("kv,kvd->kd", sv, sp - sp.mean(axis=1, keepdims=True))
        for tri in tris:
            pts = []
            for a, b in tri:
                va, vb = sv[:, a], sv[:, b]
                t = (va / (va - vb))[:, None]
                pts.append(sp[:, a] + t * (sp[:, b] - sp[:, a]))
            tri_xyz = np.stack(pts, axis=1)  # (k, 3, 3)
            normal = np.cross(tri_xyz[:, 1] - tri_xyz[:, 0], tri_xyz[:, 2] - tri_xyz[:, 0])
            flip = np.einsum("kd,kd->k", normal, grad) < 0.0
            tri_xyz[flip] = tri_xyz[flip][:, ::-1]
            out.append(tri_xyz)
    return np.concatenate(out)


def save_surface_png(
    path: str | os.PathLike,
    phi,
    grid: Grid3D,
    *,
    time: float | None = None,
    title: str | None = None,
    level: float = 0.0,
    colors: Sequence | None = None,
    alpha: float = 1.0,
    elev: float = 24.0,
    azim: float = -56.0,
    dpi: int = 120,
    figsize: tuple[float, float] = (6.0, 5.0),
    vertical: str = "z",
) -> Path:
    """Save a 3D view of each solid's interface ``phi = level`` (default 0) as a PNG.

    ``phi``: the level sets of a 3D run, ``(nsolid, nx, ny, nz)`` or one solid's
    ``(nx, ny, nz)`` (nodes; corners work too).  Each surface is triangulated by
    :func:`level_set_triangles` and drawn with matplotlib's mplot3d ``Poly3DCollection``
    in its own colour (``colors``, default the tab10 cycle), lit from one fixed direction;
    the box is the domain, at true aspect ratio, seen from ``elev``/``azim`` (degrees),
    with the axis ``vertical`` ("x", "y" or "z") drawn upwards (e.g. "y" for a case whose
    gravity points along -y).
    The title is ``title``, else ``"phi = 0 surfaces"`` plus ``t = time`` when given.  A
    solid whose phi does not change sign is left out (noted in the title).  Returns the path.
    """
    from matplotlib.colors import to_rgba
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    if grid.ndim != 3:
        raise ValueError(f"save_surface_png needs a Grid3D, got {grid}")
    phis = np.asarray(phi, dtype=np.float64)
    if phis.ndim == 3:
        phis = phis[None]
    if phis.ndim != 4:
        raise ValueError(f"phi must be (nsolid, nx, ny, nz) or (nx, ny, nz), got {phis.shape}")
    if colors is None:
        colors = [f"C{k}" for k in range(10)]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig = _new_figure(figsize, dpi)
    ax = fig.add_subplot(projection="3d")
    light = np.array([-0.4, -0.6, 1.0])
    light /= np.linalg.norm(light)
    missing = []
    for s, one in enumerate(phis):
        tris = level_set_triangles(one, grid, level)
        if len(tris) == 0:
            missing.append(s)
            continue
        normal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        norm = np.linalg.norm(normal, axis=-1, keepdims=True)
        normal = normal / np.where(norm > 0.0, norm, 1.0)
        shade = 0.35 + 0.65 * np.clip(normal @ light, 0.0, 1.0)
        rgba = np.empty((len(tris), 4))
        rgba[:, :3] = np.asarray(to_rgba(colors[s % len(colors)])[:3]) * shade[:, None]
        rgba[:, 3] = alpha
        ax.add_collection3d(Poly3DCollection(tris, facecolors=rgba, edgecolors="none"))
    ax.set_xlim(grid.ax, grid.bx)
    ax.set_ylim(grid.ay, grid.by)
    ax.set_zlim(grid.az, grid.bz)
    ax.set_box_aspect((grid.bx - grid.ax, grid.by - grid.ay, grid.bz - grid.az))
    ax.set_xlabel("$x$")
    ax.set_ylabel("$y$")
    ax.set_zlabel("$z$")
    if vertical not in ("x", "y", "z"):
        raise ValueError(f"vertical must be 'x', 'y' or 'z', got {vertical!r}")
    ax.view_init(elev=elev, azim=azim, vertical_axis=vertical)
    if title is None:
        title = f"$\\phi = {level:g}$ surfaces"
        if time is not None:
            title += f",  $t = {time:.4g}$"
        if missing:
            title += f"  (no interface: solid {', '.join(map(str, missing))})"
    ax.set_title(title)
    fig.savefig(path, dpi=dpi)
    return path
