"""Uniform Cartesian grid with the two point sets of the method.

* nodes ("regular grid"): the m x n cell centres, x_i = ax + (i + 1/2) dx.  They hold the
  prognostic fields: velocity, fluid density, reference maps and level sets.
* corners ("staggered grid"): the (m+1) x (n+1) cell corners, x_i = ax + i dx.  They hold
  what is derived each step: grad xi, F, J, stresses and blend weights.

Arrays are indexed ``[i, j]`` with i along x and j along y ("ij" indexing), so a node field
has shape ``(nx, ny)`` and a corner field ``(nx + 1, ny + 1)``.  Vector fields put their
components first: ``(2, nx, ny)``; solids are stacked on a leading axis before that.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Location = Literal["node", "corner"]


@dataclass(frozen=True)
class Grid:
    """A rectangle [ax, bx] x [ay, by] cut into nx x ny square-ish cells (hashable, static)."""

    nx: int
    ny: int
    ax: float = -2.0
    bx: float = 2.0
    ay: float = -2.0
    by: float = 2.0

    def __post_init__(self):
        for name in ("nx", "ny"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 8:
                raise ValueError(f"Grid.{name} must be an integer >= 8, got {v!r}")
        if not (self.bx > self.ax):
            raise ValueError(f"Grid needs bx > ax, got ax={self.ax!r}, bx={self.bx!r}")
        if not (self.by > self.ay):
            raise ValueError(f"Grid needs by > ay, got ay={self.ay!r}, by={self.by!r}")

    @property
    def dx(self) -> float:
        return (self.bx - self.ax) / self.nx

    @property
    def dy(self) -> float:
        return (self.by - self.ay) / self.ny

    @property
    def h(self) -> float:
        """The smaller spacing: the length every band width and blur width is measured in."""
        return min(self.dx, self.dy)

    def shape(self, loc: Location = "node") -> tuple[int, int]:
        return (self.nx, self.ny) if loc == "node" else (self.nx + 1, self.ny + 1)

    def axes(self, loc: Location = "node") -> tuple[np.ndarray, np.ndarray]:
        """1D coordinates (x, y) of the given point set."""
        if loc == "node":
            x = self.ax + (np.arange(self.nx) + 0.5) * self.dx
            y = self.ay + (np.arange(self.ny) + 0.5) * self.dy
        elif loc == "corner":
            x = self.ax + np.arange(self.nx + 1) * self.dx
            y = self.ay + np.arange(self.ny + 1) * self.dy
        else:
            raise ValueError(f"unknown grid location {loc!r}; use 'node' or 'corner'")
        return x, y

    def mesh(self, loc: Location = "node") -> tuple[np.ndarray, np.ndarray]:
        """2D coordinate arrays (X, Y), each of ``self.shape(loc)``."""
        x, y = self.axes(loc)
        return np.meshgrid(x, y, indexing="ij")

    @property
    def cell_area(self) -> float:
        return self.dx * self.dy

    def contains(self, x: float, y: float) -> bool:
        return self.ax <= x <= self.bx and self.ay <= y <= self.by
