"""Uniform Cartesian grid with the two point sets of the method.

* nodes ("regular grid"): the m x n cell centres, x_i = ax + (i + 1/2) dx.  They hold the
  prognostic fields: velocity, fluid density, reference maps and level sets.
* corners ("staggered grid"): the (m+1) x (n+1) cell corners, x_i = ax + i dx.  They hold
  what is derived each step: grad xi, F, J, stresses and blend weights.

Arrays are indexed ``[i, j]`` with i along x and j along y ("ij" indexing), so a node field
has shape ``(nx, ny)`` and a corner field ``(nx + 1, ny + 1)``.  Vector fields put their
components first: ``(2, nx, ny)``; solids are stacked on a leading axis before that.

:class:`Grid3D` is the same in three dimensions (a box cut into nx x ny x nz cells, fields
``(nx, ny, nz)`` and ``(3, nx, ny, nz)``).  It is a separate class so that :class:`Grid`, whose
fields are serialised by the case and output code, stays exactly as it is.  Both expose
``ndim`` and ``spacing`` (the tuple the dimension-generic operators take:
``grad_corner(fp, *grid.spacing)``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np

Location = Literal["node", "corner"]


@dataclass(frozen=True)
class Grid:
    """A rectangle [ax, bx] x [ay, by] cut into nx x ny square-ish cells (hashable, static)."""

    ndim: ClassVar[int] = 2

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

    @property
    def spacing(self) -> tuple[float, float]:
        return (self.dx, self.dy)

    @property
    def lows(self) -> tuple[float, float]:
        """The box's low end along each axis, ``(ax, ay)``."""
        return (self.ax, self.ay)

    @property
    def highs(self) -> tuple[float, float]:
        """The box's high end along each axis, ``(bx, by)``."""
        return (self.bx, self.by)

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


@dataclass(frozen=True)
class Grid3D:
    """A box [ax, bx] x [ay, by] x [az, bz] cut into nx x ny x nz cells (hashable, static).

    Nodes are the cell centres, shape ``(nx, ny, nz)``; corners the cell vertices, shape
    ``(nx + 1, ny + 1, nz + 1)``; arrays are indexed ``[i, j, k]`` along (x, y, z).  The
    3D step, state and output do not exist yet (see docs/method.md, "Three dimensions").
    """

    ndim: ClassVar[int] = 3

    nx: int
    ny: int
    nz: int
    ax: float = -2.0
    bx: float = 2.0
    ay: float = -2.0
    by: float = 2.0
    az: float = -2.0
    bz: float = 2.0

    def __post_init__(self):
        for name in ("nx", "ny", "nz"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 8:
                raise ValueError(f"Grid3D.{name} must be an integer >= 8, got {v!r}")
        for a in "xyz":
            lo, hi = getattr(self, "a" + a), getattr(self, "b" + a)
            if not (hi > lo):
                raise ValueError(f"Grid3D needs b{a} > a{a}, got a{a}={lo!r}, b{a}={hi!r}")

    @property
    def dx(self) -> float:
        return (self.bx - self.ax) / self.nx

    @property
    def dy(self) -> float:
        return (self.by - self.ay) / self.ny

    @property
    def dz(self) -> float:
        return (self.bz - self.az) / self.nz

    @property
    def spacing(self) -> tuple[float, float, float]:
        return (self.dx, self.dy, self.dz)

    @property
    def lows(self) -> tuple[float, float, float]:
        """The box's low end along each axis, ``(ax, ay, az)``."""
        return (self.ax, self.ay, self.az)

    @property
    def highs(self) -> tuple[float, float, float]:
        """The box's high end along each axis, ``(bx, by, bz)``."""
        return (self.bx, self.by, self.bz)

    @property
    def h(self) -> float:
        """The smallest spacing."""
        return min(self.spacing)

    def shape(self, loc: Location = "node") -> tuple[int, int, int]:
        n = (self.nx, self.ny, self.nz)
        return n if loc == "node" else tuple(m + 1 for m in n)

    def axes(self, loc: Location = "node") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """1D coordinates (x, y, z) of the given point set."""
        if loc not in ("node", "corner"):
            raise ValueError(f"unknown grid location {loc!r}; use 'node' or 'corner'")
        out = []
        for n, a, h in zip(
            self.shape("node"), self.lows, self.spacing, strict=True
        ):
            out.append(a + (np.arange(n) + 0.5) * h if loc == "node" else a + np.arange(n + 1) * h)
        return tuple(out)

    def mesh(self, loc: Location = "node") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """3D coordinate arrays (X, Y, Z), each of ``self.shape(loc)``."""
        return tuple(np.meshgrid(*self.axes(loc), indexing="ij"))

    @property
    def cell_volume(self) -> float:
        return self.dx * self.dy * self.dz

    def contains(self, x: float, y: float, z: float) -> bool:
        return self.ax <= x <= self.bx and self.ay <= y <= self.by and self.az <= z <= self.bz
