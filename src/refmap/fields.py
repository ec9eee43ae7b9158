"""Located fields: arrays that know whether they live on nodes or on corners.

The numerical core works on bare arrays for speed, but the two stencils that cross between
the point sets are exposed here on :class:`Field` values, which check the location of their
input and stamp the location of their output (the jax-cfd ``GridArray.offset`` idea).  A
node field has trailing shape ``(nx, ny)``, a corner field ``(nx + 1, ny + 1)``; leading
axes (components, solids) are free.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from refmap.grid import Grid, Location
from refmap.operators import div_node, grad_corner, node_average


@dataclass(frozen=True)
class Field:
    data: jax.Array
    loc: Location
    grid: Grid

    def __post_init__(self):
        want = self.grid.shape(self.loc)
        shape = tuple(jnp.shape(self.data)[-2:])
        if shape != want:
            raise ValueError(
                f"a {self.loc} field on a {self.grid.nx}x{self.grid.ny} grid must end in shape {want}, got {shape}"
            )


def _flatten(f):
    return (f.data,), (f.loc, f.grid)


def _unflatten(aux, children):
    obj = object.__new__(Field)
    object.__setattr__(obj, "data", children[0])
    object.__setattr__(obj, "loc", aux[0])
    object.__setattr__(obj, "grid", aux[1])
    return obj


jax.tree_util.register_pytree_node(Field, _flatten, _unflatten)


def _require(f: Field, loc: Location, what: str):
    if f.loc != loc:
        raise ValueError(f"{what} needs a {loc} field, got a {f.loc} field")


def gradient(f: Field, padded: jax.Array) -> tuple[Field, Field]:
    """Bottom-left-triangle gradient of a node field -> two corner fields.

    ``padded`` is ``f.data`` with one ghost layer (from :mod:`refmap.boundary`)."""
    _require(f, "node", "gradient")
    gx, gy = grad_corner(padded, f.grid.dx, f.grid.dy)
    return Field(gx, "corner", f.grid), Field(gy, "corner", f.grid)


def divergence(sxx: Field, sxy: Field, syy: Field) -> Field:
    """Top-right-triangle divergence of a symmetric corner tensor -> node vector field."""
    for s in (sxx, sxy, syy):
        _require(s, "corner", "divergence")
    g = sxx.grid
    return Field(div_node(sxx.data, sxy.data, syy.data, g.dx, g.dy), "node", g)


def to_nodes(f: Field) -> Field:
    """Average a corner field over each node's four corners."""
    _require(f, "corner", "to_nodes")
    return Field(node_average(f.data), "node", f.grid)


def locate(grid: Grid, data) -> Field:
    """Wrap an array, inferring its location from its trailing shape."""
    shape = tuple(jnp.shape(data)[-2:])
    for loc in ("node", "corner"):
        if shape == grid.shape(loc):
            return Field(data, loc, grid)
    raise ValueError(f"shape {jnp.shape(data)} is neither a node {grid.shape('node')} nor a corner {grid.shape('corner')} field")
