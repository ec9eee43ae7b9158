"""The Python API in a few lines: build a case, run it, open the run, plot a field.

    python examples/api_quickstart.py            # 96^2, a few seconds of simulated time
CI runs it at a tiny resolution (REFMAP_EXAMPLE_N=32, REFMAP_EXAMPLE_T=0.1).
"""

import os
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import refmap  # noqa: E402
from refmap.boundary import Boundary, Segment  # noqa: E402
from refmap.case import Case  # noqa: E402
from refmap.geometry import Disc, Rectangle  # noqa: E402
from refmap.grid import Grid  # noqa: E402
from refmap.materials import NeoHookean  # noqa: E402
from refmap.model import Solid  # noqa: E402
from refmap.simulation import Simulation  # noqa: E402

n = int(os.environ.get("REFMAP_EXAMPLE_N", 96))
t_end = float(os.environ.get("REFMAP_EXAMPLE_T", 3.0))
out = Path(os.environ.get("REFMAP_EXAMPLE_OUT", tempfile.mkdtemp())) / "holed_block"

# 1. a soft block with a hole (CSG in reference coordinates), in a channel flow
block = Solid(
    shape=Rectangle(center=(0.0, 0.0), half_size=(0.6, 0.4), corner_radius=0.1) - Disc((0.0, 0.0), 0.2),
    law=NeoHookean(G=5.0, kappa=10.0),
    velocity=(0.1, 0.0),
    name="holed block",
)
inflow = Segment("velocity", velocity=(0.1, 0.0))
case = Case(
    name="holed_block",
    grid=Grid(n, n // 2, -2.0, 2.0, -1.0, 1.0),
    solids=(block,),
    boundary=Boundary(left=(inflow,), right=(inflow,), bottom="slip", top="slip"),
    t_end=t_end,
    frames=3,
)

# 2. run it (HDF5 frames, XDMF, diagnostics, pictures)
Simulation(case, out, progress=False).run()

# 3. open the run as an xarray Dataset and plot the horizontal velocity at the end
ds = refmap.open_run(out)
print(ds)
fig, ax = plt.subplots()
ds["u"].isel(time=-1).plot(x="x", y="y", ax=ax)
ax.contour(ds.x, ds.y, ds["phi"].isel(time=-1, solid=0).T, [0], colors="k")
fig.savefig(out / "u_final.png")
print("final time:", float(ds.time[-1]), "grid:", ds.attrs["nx"], "x", ds.attrs["ny"])
