"""Will a run fit in memory?  :func:`estimate_memory` and :func:`check_memory`.

A run that cannot fit used to die in the middle of :meth:`Case.validate` with a
``MemoryError`` traceback (``refmap run rotor --n 100000`` tried to allocate a 74.5 GiB
array), or later inside XLA.  :func:`check_memory` compares an estimate with the memory
available *before* any grid-sized array is made and raises :class:`~refmap.case.CaseError`
with both figures.

The estimate is ``BASE_BYTES + nx ny (BYTES_PER_NODE + n_solids BYTES_PER_SOLID_NODE)``,
fitted to the peak resident memory of one-frame CPU runs (``ru_maxrss``; JAX 0.4, float64):

=========  =====  ============  ============  =============
scenario   solids  128^2 (MiB)  384^2 (MiB)   640^2 (MiB)
=========  =====  ============  ============  =============
circle     1      643           799           1100  (1150-1190 bytes per node)
two_balls  2      767           1031          1603  (2100-2290 bytes per node)
=========  =====  ============  ============  =============

Per node that is about 150 float64 numbers for one solid and 285 for two: the state
(3 + 3 per solid), the derived corner fields and the step's temporaries (XLA's own memory
analysis of the step: 32 numbers per node of temporaries for one solid, 63-84 for two, 172
for five), the output fields of a frame on the device and again on the host, and the
per-solid constants (initial maps, masks) that every compiled function carries.  The
estimate is a lower bound of what a run needs, so only runs that clearly cannot fit are
refused.  On a GPU the device's free memory is the budget.
"""

from __future__ import annotations

import math
import os

#: the interpreter, JAX, the compiled functions of a small run (measured: ~600 MiB at 128^2)
BASE_BYTES = 600 * 2**20
#: bytes per grid node without solids, and per node per solid (fitted to the table above)
BYTES_PER_NODE = 100
BYTES_PER_SOLID_NODE = 1100

GiB = 2.0**30


def solid_nodes(case) -> int:
    """Nodes summed over the solids on which each keeps its fields: the whole grid per
    solid, or with ``Numerics.solid_storage = "window"`` a window round each body, about
    its ``bbox()`` widened by ``phi_max`` cells, the band window's margins and slack (the
    model keeps a solid on the grid where windows do not apply: then this is a lower
    bound, as the estimate is meant to be)."""
    grid = case.grid
    shape = tuple(int(n) for n in grid.shape())
    nodes = math.prod(shape)
    if getattr(case.numerics, "solid_storage", "grid") != "window":
        return len(case.solids) * nodes
    from refmap.model import BAND_WINDOW_MARGIN, SOLID_WINDOW_SLACK

    pad = 2 * (math.ceil(case.numerics.phi_max) + BAND_WINDOW_MARGIN) + SOLID_WINDOW_SLACK
    total = 0
    for s in case.solids:
        try:
            bb = s.shape.bbox()
        except (AttributeError, NotImplementedError):
            total += nodes
            continue
        ext = [(bb[2 * a + 1] - bb[2 * a]) / h + pad for a, h in enumerate(grid.spacing)]
        total += min(nodes, math.prod(min(n, math.ceil(e)) for n, e in zip(shape, ext, strict=True)))
    return total


def estimate_memory(case) -> int:
    """Bytes a run of ``case`` needs, about (see the module docstring for the fit)."""
    nodes = math.prod(int(n) for n in case.grid.shape())  # nx ny (nz): no 3D fit yet
    return int(BASE_BYTES + nodes * BYTES_PER_NODE + solid_nodes(case) * BYTES_PER_SOLID_NODE)


def _meminfo_available() -> int | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def available_memory() -> tuple[int | None, str]:
    """``(bytes, where)``: the free memory of the accelerator JAX runs on, or the host's
    available memory (``MemAvailable`` of /proc/meminfo, else ``os.sysconf``) on a CPU;
    ``(None, ...)`` when neither can be read."""
    try:
        import jax

        dev = jax.devices()[0]
        if dev.platform != "cpu":
            stats = dev.memory_stats() or {}
            limit = stats.get("bytes_limit")
            if limit:
                return int(limit) - int(stats.get("bytes_in_use", 0)), f"free on {dev.device_kind}"
    except Exception:  # noqa: BLE001 - no device information: fall back to the host
        pass
    return _meminfo_available(), "available on this machine"


def check_memory(case, available: tuple[int | None, str] | None = None) -> None:
    """Raise :class:`~refmap.case.CaseError` if ``case`` clearly cannot fit in memory.

    ``available`` overrides :func:`available_memory` (``(bytes, where)``; for tests).
    """
    from refmap.case import CaseError

    need = estimate_memory(case)
    have, where = available if available is not None else available_memory()
    if have is None or need <= have:
        return
    g = case.grid
    per_node = BYTES_PER_NODE + solid_nodes(case) / math.prod(g.shape()) * BYTES_PER_SOLID_NODE
    fit_nodes = max(0.0, (have - BASE_BYTES) / per_node)
    shape = g.shape()
    # keep the aspect ratio: n = nx at the largest grid of this shape that fits
    fit_n = int((fit_nodes * g.nx ** len(shape) / math.prod(shape)) ** (1.0 / len(shape)))
    hint = f"; at most about n = {fit_n} fits" if fit_n >= 16 else ""
    raise CaseError(
        f"case {case.name!r}: a {' x '.join(str(n) for n in shape)} grid with {len(case.solids)} solid(s) needs "
        f"about {need / GiB:.3g} GiB of memory, more than the {have / GiB:.3g} GiB {where}"
        f"{hint}"
    )


__all__ = ["available_memory", "check_memory", "estimate_memory", "solid_nodes"]
