"""Material-point probes: where is the material point X0 now?

In the reference map technique a material point is not a grid node: it sits wherever the
reference map takes the value X0, i.e. at the root x of ``xi(x) = X0``.  The map is known at
the nodes (cell centres); :func:`bilinear` interpolates it between them and
:func:`material_point` solves ``xi(x) = X0`` by Newton's iteration with the exact
derivative of the bilinear interpolant.  For an affine map the interpolant is exact, so one
Newton step lands on the exact answer (tested); for a smooth map the error is that of
bilinear interpolation, O(h^2).

The map is read wherever it is defined, including the extrapolated band outside the solid,
so a point on the solid's boundary (the Turek--Hron point A at the tip of the flag) is
found without special treatment.  Pure jnp functions (jit-able, vectorised over points).
"""

from __future__ import annotations

import jax.numpy as jnp

from refmap.grid import Grid


def _cell(grid: Grid, x, y):
    """Lower-left node index (clipped to the grid) and fractional offsets of point(s) (x, y)."""
    sx = (x - grid.ax) / grid.dx - 0.5
    sy = (y - grid.ay) / grid.dy - 0.5
    i = jnp.clip(jnp.floor(sx), 0, grid.nx - 2).astype(jnp.int32)
    j = jnp.clip(jnp.floor(sy), 0, grid.ny - 2).astype(jnp.int32)
    return i, j, sx - i, sy - j


def bilinear(f, grid: Grid, x, y):
    """Bilinear interpolant of node field(s) ``f`` (..., nx, ny) at (x, y) and its gradient.

    Returns ``(value, d/dx, d/dy)``, each of shape ``f.shape[:-2] + jnp.shape(x)``.  Points
    outside the node range are extrapolated from the nearest cell (linearly).
    """
    i, j, fx, fy = _cell(grid, x, y)
    f00 = f[..., i, j]
    f10 = f[..., i + 1, j]
    f01 = f[..., i, j + 1]
    f11 = f[..., i + 1, j + 1]
    val = f00 * (1 - fx) * (1 - fy) + f10 * fx * (1 - fy) + f01 * (1 - fx) * fy + f11 * fx * fy
    ddx = ((f10 - f00) * (1 - fy) + (f11 - f01) * fy) / grid.dx
    ddy = ((f01 - f00) * (1 - fx) + (f11 - f10) * fx) / grid.dy
    return val, ddx, ddy


def nearest_node(xi, grid: Grid, X0, phi, reach: float = 2.0):
    """Position of the node whose map value is nearest to X0, among the nodes with
    ``phi < reach h`` (the solid and the part of its band where the extrapolated map is
    reliable).  A starting point for :func:`material_point` that does not depend on how
    far the material has moved: elsewhere the map holds whatever the band left behind.

    ``X0``: (2,) or (2, P); returns the same shape."""
    X0 = jnp.asarray(X0, dtype=xi.dtype)
    pts = X0.reshape(2, -1)
    X, Y = grid.mesh()
    ok = (phi < reach * grid.h).ravel()
    d2 = (xi[0].ravel()[:, None] - pts[0]) ** 2 + (xi[1].ravel()[:, None] - pts[1]) ** 2
    k = jnp.argmin(jnp.where(ok[:, None], d2, jnp.inf), axis=0)
    x = jnp.stack([jnp.asarray(X).ravel()[k], jnp.asarray(Y).ravel()[k]])
    return x.reshape(X0.shape)


def material_point(xi, grid: Grid, X0, x_guess=None, iters: int = 12, phi=None,
                   reach: float = 2.0):
    """Current position x of the material point(s) X0, the root of ``xi(x) = X0``.

    ``xi``: (2, nx, ny) reference map of one solid; ``X0``: (2,) or (2, P) reference
    coordinates; ``x_guess``: starting point.  Without it the iteration starts from X0
    (small displacements), or, when the solid's level set ``phi`` is given, from
    :func:`nearest_node` (any displacement: a start at X0 fails once the material has moved
    further than the band, where the map is not kept up to date).
    Newton's iteration on the bilinear interpolant; returns ``(x, residual)`` with the
    residual ``|xi(x) - X0|`` at the returned point (a convergence check for the caller).
    """
    X0 = jnp.asarray(X0, dtype=xi.dtype)
    if x_guess is not None:
        x = jnp.asarray(x_guess, dtype=xi.dtype)
    elif phi is not None:
        x = nearest_node(xi, grid, X0, phi, reach)
    else:
        x = X0
    for _ in range(iters):
        val, gx, gy = bilinear(xi, grid, x[0], x[1])
        r = val - X0
        # Jacobian [[dX/dx, dX/dy], [dY/dx, dY/dy]]; solve J dx = -r by Cramer's rule
        a, b, c, d = gx[0], gy[0], gx[1], gy[1]
        det = a * d - b * c
        det = jnp.where(jnp.abs(det) > 1e-300, det, 1.0)
        step_x = (d * r[0] - b * r[1]) / det
        step_y = (-c * r[0] + a * r[1]) / det
        x = x - jnp.stack([step_x, step_y])
    val, _, _ = bilinear(xi, grid, x[0], x[1])
    res = jnp.sqrt(jnp.sum((val - X0) ** 2, axis=0))
    return x, res


__all__ = ["bilinear", "material_point", "nearest_node"]
