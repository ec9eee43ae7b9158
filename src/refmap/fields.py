"""Located fields: arrays that know whether they live on nodes or on corners.

The numerical core works on bare arrays for speed, but the two stencils that cross between
the point sets are exposed here on :class:`Field` values, which check the location of their
input and stamp the location of their output (the jax-cfd ``GridArray.offset`` idea).  A
node field has trailing shape ``(nx, ny)``, a corner field ``(nx + 1, ny + 1)``; leading
axes (components, solids) are free.  On a :class:`refmap.grid.Grid3D` the same functions
work with trailing shapes ``(nx, ny, nz)`` / ``(nx + 1, ny + 1, nz + 1)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from refmap.grid import Grid, Grid3D, Location
from refmap.operators import div_node, grad_corner, node_average


@dataclass(frozen=True)
class Field:
    data: jax.Array
    loc: Location
    grid: Grid | Grid3D

    def __post_init__(self):
        want = self.grid.shape(self.loc)
        shape = tuple(jnp.shape(self.data)[-len(want):])
        if shape != want:
            cells = "x".join(str(n) for n in self.grid.shape("node"))
            raise ValueError(
                f"a {self.loc} field on a {cells} grid must end in shape {want}, got {shape}"
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


def gradient(f: Field, padded: jax.Array) -> tuple[Field, ...]:
    """Bottom-left-triangle gradient of a node field -> one corner field per axis.

    ``padded`` is ``f.data`` with one ghost layer (from :mod:`refmap.boundary`)."""
    _require(f, "node", "gradient")
    return tuple(Field(g, "corner", f.grid) for g in grad_corner(padded, *f.grid.spacing))


def divergence(*s: Field) -> Field:
    """Top-right-triangle divergence of a symmetric corner tensor -> node vector field.

    2D: ``divergence(sxx, sxy, syy)``; 3D: ``divergence(sxx, sxy, sxz, syy, syz, szz)``."""
    for c in s:
        _require(c, "corner", "divergence")
    g = s[0].grid
    d = g.ndim
    if len(s) != d * (d + 1) // 2:
        raise ValueError(
            f"divergence on a {d}D grid needs the {d * (d + 1) // 2} components of a "
            f"symmetric tensor, got {len(s)}"
        )
    return Field(div_node(*(c.data for c in s), *g.spacing), "node", g)


def to_nodes(f: Field) -> Field:
    """Average a corner field over each node's 2^d corners."""
    _require(f, "corner", "to_nodes")
    return Field(node_average(f.data, ndim=f.grid.ndim), "node", f.grid)


def locate(grid: Grid | Grid3D, data) -> Field:
    """Wrap an array, inferring its location from its trailing shape."""
    shape = tuple(jnp.shape(data)[-grid.ndim :])
    for loc in ("node", "corner"):
        if shape == grid.shape(loc):
            return Field(data, loc, grid)
    raise ValueError(f"shape {jnp.shape(data)} is neither a node {grid.shape('node')} nor a corner {grid.shape('corner')} field")
