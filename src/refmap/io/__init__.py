"""Output of refmap runs: HDF5 frames + XDMF index + metadata + diagnostics, reading them
back as xarray, and pictures/movies.

Writing::

    with RunWriter("runs/disc", grid, metadata={"params": ..., "argv": sys.argv}) as w:
        w.write_frame(0, 0.0, {"u": u, "v": v, "phi": phis, "sigma_xx": sxx})
        w.append_diagnostics({"step": 0, "time": 0.0, "kinetic_energy": ke})

Reading::

    ds = open_run("runs/disc")            # xarray.Dataset over all frames
    df = open_diagnostics("runs/disc")    # pandas.DataFrame
    w = derived_field(ds, "vorticity")
    make_movie("runs/disc", "vorticity", "runs/disc/vorticity.mp4")

A run whose solids are stored in windows (``Numerics.solid_storage = "window"``) writes the
union of their level sets (``phi``), ``solid_index`` and the nearest solid's ``J`` on the grid
and the windows in a group of their own (:mod:`refmap.io.writer`); ``per_solid_fields(path)``
rebuilds each solid's whole-grid ``phi`` and ``xi_*``, ``read_state(path)`` the State to
start a run from.

A run on a :class:`~refmap.grid.Grid3D` is written and read the same way (arrays
``[i, j, k]``, a 3DCoRectMesh in run.xdmf); its pictures and movies show a plane of the
field (``slice_axis=``, ``slice_index=``, ``slice_at=``; default the middle z plane), and
``save_surface_png`` draws the solids' interfaces in 3D.
"""

from refmap.io._common import grid_from_attrs
from refmap.io.pictures import (
    DERIVED_FIELDS,
    derived_field,
    level_set_triangles,
    make_movie,
    plot_field,
    save_frame_png,
    save_panel_png,
    save_surface_png,
)
from refmap.io.reader import (
    list_frames,
    open_diagnostics,
    open_run,
    per_solid_fields,
    read_frame,
    read_metadata,
    read_state,
)
from refmap.io.writer import RunWriter

__all__ = [
    "DERIVED_FIELDS",
    "RunWriter",
    "derived_field",
    "grid_from_attrs",
    "level_set_triangles",
    "list_frames",
    "make_movie",
    "open_diagnostics",
    "open_run",
    "per_solid_fields",
    "plot_field",
    "read_frame",
    "read_metadata",
    "read_state",
    "save_frame_png",
    "save_panel_png",
    "save_surface_png",
]
