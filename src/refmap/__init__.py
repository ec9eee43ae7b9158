"""refmap: a fully Eulerian fluid-structure solver (blurred-interface Reference Map Technique).

Importing refmap switches JAX to float64: the method differentiates the reference map
twice (F = (grad xi)^-1, then div sigma), and single precision loses the small strains
that drive the elastic waves.
"""

import jax

jax.config.update("jax_enable_x64", True)

from refmap.grid import Grid  # noqa: E402

__version__ = "0.1.0"

__all__ = ["Grid", "__version__"]


def __getattr__(name):  # lazy heavy imports keep `import refmap` fast
    if name == "open_run":
        from refmap.io.reader import open_run

        return open_run
    if name in ("Simulation", "run_scenario"):
        from refmap import simulation

        return getattr(simulation, name)
    raise AttributeError(name)
