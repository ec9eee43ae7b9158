"""Finite-difference operators of the blurred-interface RMT.

Every operator here is a pure function of arrays (jit-able, differentiable).  Node fields
come in *padded* with ghost layers (see :mod:`refmap.boundary`): ``fp`` has shape
``(nx + 2g, ny + 2g)`` with ``g`` ghost layers on each side.

The two stencils that cross between the point sets are the heart of the method's stability
(thesis section 3.8):

* :func:`grad_corner` -- node -> corner, the "bottom-left triangle": at the corner between
  nodes (i-1, i) x (j-1, j), ``d/dx = (f[BR] - f[BL]) / dx`` and ``d/dy = (f[TL] - f[BL]) / dy``.
* :func:`div_node` -- corner -> node, the "top-right triangle" of the node's four corners:
  ``d s_x./dx = (s[TR] - s[TL]) / dx`` and ``d s_.y/dy = (s[TR] - s[BR]) / dy``.

With zero ghost values the two are exactly minus each other's transpose (tested), so the
discrete elastic energy has no zero-energy checkerboard mode.  The price is a first-order
bias (the thesis measures orders 1.26 to 1.55).
"""

from __future__ import annotations

import jax.numpy as jnp


def grad_corner(fp, dx, dy):
    """Bottom-left-triangle gradient of a node field padded with ONE ghost layer.

    ``fp``: (..., nx + 2, ny + 2).  Returns ``(df/dx, df/dy)``, each (..., nx + 1, ny + 1).
    Corner (i, j) sits between nodes i-1 and i; in padded indices its bottom-left node is
    (i, j), bottom-right (i + 1, j), top-left (i, j + 1).
    """
    bl = fp[..., :-1, :-1]
    fx = (fp[..., 1:, :-1] - bl) / dx
    fy = (fp[..., :-1, 1:] - bl) / dy
    return fx, fy


def div_node(sxx, sxy, syy, dx, dy):
    """Top-right-triangle divergence of a symmetric corner tensor field -> node vector.

    Inputs (..., nx + 1, ny + 1); returns (..., 2, nx, ny).  Node (i, j) has corners
    BL = (i, j), BR = (i + 1, j), TL = (i, j + 1), TR = (i + 1, j + 1).
    """
    tr = (slice(1, None), slice(1, None))
    tl = (slice(None, -1), slice(1, None))
    br = (slice(1, None), slice(None, -1))
    fx = (sxx[..., tr[0], tr[1]] - sxx[..., tl[0], tl[1]]) / dx + (
        sxy[..., tr[0], tr[1]] - sxy[..., br[0], br[1]]
    ) / dy
    fy = (sxy[..., tr[0], tr[1]] - sxy[..., tl[0], tl[1]]) / dx + (
        syy[..., tr[0], tr[1]] - syy[..., br[0], br[1]]
    ) / dy
    return jnp.stack([fx, fy], axis=-3)


def corner_average(fp):
    """Average of the four nodes around each corner; ``fp`` padded with one ghost layer."""
    return 0.25 * (fp[..., :-1, :-1] + fp[..., 1:, :-1] + fp[..., :-1, 1:] + fp[..., 1:, 1:])


def node_average(fc):
    """Average of a corner field over the four corners of each node -> (..., nx, ny)."""
    return 0.25 * (fc[..., :-1, :-1] + fc[..., 1:, :-1] + fc[..., :-1, 1:] + fc[..., 1:, 1:])


#: relative margin below which the two ENO smoothness indicators count as tied (see _eno2)
_ENO_TIE = 1e-11


def _eno2(p0, p1, p2, p3):
    """Second-order ENO difference at p1 towards p2 (times 2h), as in the thesis's code.

    Takes the one-sided second-order difference 3 p1 - 4 p2 + p3 when the data on that side
    is smoother, and the centred p0 - p2 otherwise.
    """
    # Ties go to the centred difference.  Ties are structural, not rare: next to a wall or a
    # prescribed-velocity edge the odd ghost values make both second differences equal in
    # exact arithmetic, so a plain ``>`` lets round-off pick the stencil, and the two
    # stencils differ by O(1) there.  A margin of _ENO_TIE times the data's magnitude makes
    # such near-ties centred whatever the rounding (e.g. of a sum split over devices).
    scale = jnp.abs(p0) + jnp.abs(p1) + jnp.abs(p2) + jnp.abs(p3)
    one_sided = jnp.abs(p0 - 2 * p1 + p2) > jnp.abs(p1 - 2 * p2 + p3) + _ENO_TIE * scale
    return jnp.where(one_sided, 3 * p1 - 4 * p2 + p3, p0 - p2)


def _shift(fp, axis, k, g):
    """Interior-sized view of a padded field shifted by k cells along ``axis`` (g ghosts)."""
    nx = fp.shape[-2] - 2 * g
    ny = fp.shape[-1] - 2 * g
    if axis == 0:
        return fp[..., g + k : g + k + nx, g : g + ny]
    return fp[..., g : g + nx, g + k : g + k + ny]


def eno_derivatives(fp, vel, dx, dy):
    """Upwind second-order ENO first derivatives (d/dx, d/dy) of a padded node field.

    ``fp``: (..., nx + 4, ny + 4) with two ghost layers; ``vel``: (2, nx, ny), the advecting
    velocity, which picks the upwind side at every node.
    """
    out = []
    for axis, h in ((0, dx), (1, dy)):
        fm2, fm1, f0, f1, f2 = (_shift(fp, axis, k, 2) for k in (-2, -1, 0, 1, 2))
        back = _eno2(f1, f0, fm1, fm2) / (2 * h)  # used where the velocity is positive
        fwd = -_eno2(fm1, f0, f1, f2) / (2 * h)
        out.append(jnp.where(vel[axis] > 0, back, fwd))
    return out[0], out[1]


def advect(fp, vel, dx, dy):
    """-(v . grad) f with ENO upwinding; ``fp`` padded with two ghost layers."""
    fx, fy = eno_derivatives(fp, vel, dx, dy)
    return -(vel[0] * fx + vel[1] * fy)


def laplacian(fp, dx, dy, g=1):
    """Five-point Laplacian of a padded node field (g ghost layers) -> interior shape."""
    c = _shift(fp, 0, 0, g)
    return (_shift(fp, 0, 1, g) - 2 * c + _shift(fp, 0, -1, g)) / dx**2 + (
        _shift(fp, 1, 1, g) - 2 * c + _shift(fp, 1, -1, g)
    ) / dy**2


def divergence_centered(up, vp, dx, dy, g=1):
    """Centred-difference divergence of a padded node vector field (thesis eq. 4.28)."""
    return (_shift(up, 0, 1, g) - _shift(up, 0, -1, g)) / (2 * dx) + (
        _shift(vp, 1, 1, g) - _shift(vp, 1, -1, g)
    ) / (2 * dy)


def unpad(fp, g):
    return fp[..., g:-g, g:-g]


def sym_grad(ux, uy, vx, vy):
    """Symmetric part of a velocity gradient given its corner components -> (xx, xy, yy)."""
    return ux, 0.5 * (uy + vx), vy
