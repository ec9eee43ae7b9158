"""Finite-difference operators of the blurred-interface RMT, in two or three dimensions.

Every operator here is a pure function of arrays (jit-able, differentiable).  Node fields
come in *padded* with ghost layers (see :mod:`refmap.boundary`): in 2D ``fp`` has shape
``(nx + 2g, ny + 2g)``, in 3D ``(nx + 2g, ny + 2g, nz + 2g)``, with ``g`` ghost layers on each
side; any leading axes (components, solids) are free.

The dimension ``d`` is never guessed from an array's shape (leading axes make that
ambiguous).  Operators that take grid spacings read it from their number:
``grad_corner(fp, dx, dy)`` is 2D and ``grad_corner(fp, dx, dy, dz)`` is 3D; the averaging
and slicing helpers take ``ndim`` (default 2).  There is one code path for every ``d``: the
stencils are written as loops over the axes, and for ``d = 2`` they perform exactly the
arithmetic of the original 2D formulas, in the same order, so 2D results are bitwise
unchanged (tested against verbatim copies of the 2D code).

The two stencils that cross between the point sets are the heart of the method's stability
(thesis section 3.8).  With ``e_a`` the unit index step along axis ``a``:

* :func:`grad_corner` -- node -> corner, the "bottom-left triangle" (in 3D: the
  bottom-left-front corner node and its ``d`` neighbours along the axes): at the corner
  whose lowest surrounding node is BL, ``df/dx_a = (f[BL + e_a] - f[BL]) / h_a``.
* :func:`div_node` -- corner -> node, the "top-right triangle" of the node's ``2^d`` corners:
  ``(div s)_a = sum_b (s_ab[TR] - s_ab[TR - e_b]) / h_b`` with TR the node's highest corner.

With zero ghost values the two are exactly minus each other's transpose (tested with
``jax.linear_transpose``), their composition is the standard (2d+1)-point Laplacian, and on
a periodic grid the only zero-energy modes of ``div_node o sym o grad_corner`` are the ``d``
uniform translations: no checkerboard.  The price is a first-order bias (the thesis
measures orders 1.26 to 1.55).

Symmetric corner tensors are passed as their independent components in row-major upper
triangle order, ``SYM_COMPONENTS[d]``: ``(xx, xy, yy)`` in 2D and
``(xx, xy, xz, yy, yz, zz)`` in 3D (``sym_index`` maps ``(a, b)`` to the position).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

#: names of the independent components of a symmetric tensor, in the order used everywhere
SYM_COMPONENTS = {
    2: ("xx", "xy", "yy"),
    3: ("xx", "xy", "xz", "yy", "yz", "zz"),
}

#: the (a, b) index pairs of those components, in the same order
SYM_PAIRS = {d: tuple((a, b) for a in range(d) for b in range(a, d)) for d in (2, 3)}

#: number of positional arguments of div_node -> dimension (d(d+1)/2 components + d spacings)
_DIV_NODE_NARGS = {2: 1, 5: 2, 9: 3}


def sym_index(a: int, b: int, ndim: int) -> int:
    """Position of component (a, b) of a symmetric ``ndim x ndim`` tensor in its stack.

    Row-major upper triangle: 2D (xx, xy, yy), 3D (xx, xy, xz, yy, yz, zz).
    """
    a, b = min(a, b), max(a, b)
    return a * ndim - a * (a - 1) // 2 + (b - a)


def _ndim_of(h, what: str) -> int:
    if len(h) not in (1, 2, 3):
        raise TypeError(f"{what} takes one grid spacing per axis (1 to 3 of them), got {len(h)}")
    return len(h)


def _view(fp, ndim: int, lows):
    """``fp[..., lows[0]:, ...]``-style view: along each of the last ``ndim`` axes keep the
    entries from ``lows[a]`` (0 or 1) on, dropping one entry at the other end."""
    idx = tuple(slice(None, -1) if lo == 0 else slice(1, None) for lo in lows)
    return fp[(Ellipsis, *idx)]


def grad_corner(fp, *h):
    """Bottom-left-triangle gradient of a node field padded with ONE ghost layer.

    ``fp``: (..., nx + 2, ny + 2[, nz + 2]); ``h``: the spacings (dx, dy[, dz]).  Returns the
    tuple of the ``d`` partial derivatives, each (..., nx + 1, ny + 1[, nz + 1]).  Corner i
    sits between nodes i-1 and i along each axis; in padded indices its bottom-left node is
    (i, j[, k]) and ``df/dx_a`` is the difference to the next node along axis ``a``.
    """
    d = _ndim_of(h, "grad_corner")
    bl = _view(fp, d, (0,) * d)
    out = []
    for a in range(d):
        nb = _view(fp, d, tuple(1 if b == a else 0 for b in range(d)))
        out.append((nb - bl) / h[a])
    return tuple(out)


def div_node_vector(q, *h):
    """Top-right-triangle divergence of a corner vector field -> node scalar.

    ``q``: sequence of the ``d`` components, each (..., nx + 1, ny + 1[, nz + 1]); returns
    (..., nx, ny[, nz]): ``sum_b (q_b[TR] - q_b[TR - e_b]) / h_b``.  Exactly minus the
    transpose of :func:`grad_corner` with zero ghost values.
    """
    d = _ndim_of(h, "div_node_vector")
    if len(q) != d:
        raise ValueError(f"div_node_vector: {d} spacings need {d} components, got {len(q)}")
    top = (1,) * d
    acc = None
    for b in range(d):
        low = tuple(0 if c == b else 1 for c in range(d))
        term = (_view(q[b], d, top) - _view(q[b], d, low)) / h[b]
        acc = term if acc is None else acc + term
    return acc


def div_node(*args):
    """Top-right-triangle divergence of a symmetric corner tensor field -> node vector.

    2D: ``div_node(sxx, sxy, syy, dx, dy)``; 3D:
    ``div_node(sxx, sxy, sxz, syy, syz, szz, dx, dy, dz)`` (components in
    ``SYM_COMPONENTS`` order).  Inputs (..., nx + 1, ny + 1[, nz + 1]); returns
    (..., d, nx, ny[, nz]) with ``(div s)_a = sum_b (s_ab[TR] - s_ab[TR - e_b]) / h_b``.
    In 2D, node (i, j) has corners BL = (i, j), BR = (i + 1, j), TL = (i, j + 1),
    TR = (i + 1, j + 1).
    """
    d = _DIV_NODE_NARGS.get(len(args))
    if d is None:
        raise TypeError(
            "div_node takes the d(d+1)/2 symmetric components then d spacings "
            f"(5 arguments in 2D, 9 in 3D), got {len(args)}"
        )
    comps, h = args[:-d], args[-d:]
    rows = [div_node_vector([comps[sym_index(a, b, d)] for b in range(d)], *h) for a in range(d)]
    return jnp.stack(rows, axis=-(d + 1))


def _offsets(ndim: int):
    """The 2^ndim (0/1) offsets of a cell's points, the first axis varying fastest
    (2D: BL, BR, TL, TR -- the order of the original 2D sums)."""
    return [tuple((n >> a) & 1 for a in range(ndim)) for n in range(2**ndim)]


def _cell_mean(f, ndim: int):
    acc = None
    for lows in _offsets(ndim):
        v = _view(f, ndim, lows)
        acc = v if acc is None else acc + v
    return 0.5**ndim * acc


def corner_average(fp, ndim: int = 2):
    """Average of the 2^ndim nodes around each corner; ``fp`` padded with one ghost layer."""
    return _cell_mean(fp, ndim)


def node_average(fc, ndim: int = 2):
    """Average of a corner field over the 2^ndim corners of each node -> (..., nx, ny[, nz])."""
    return _cell_mean(fc, ndim)


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


def _shift(fp, axis, k, g, ndim: int = 2):
    """Interior-sized view of a padded field shifted by k cells along ``axis`` (g ghosts).

    ``axis`` counts the ``ndim`` spatial axes (0 = x); the view has the interior shape.
    """
    idx = []
    for a in range(ndim):
        n = fp.shape[a - ndim] - 2 * g
        lo = g + (k if a == axis else 0)
        idx.append(slice(lo, lo + n))
    return fp[(Ellipsis, *idx)]


def eno_derivatives(fp, vel, *h):
    """Upwind second-order ENO first derivatives (d/dx, d/dy[, d/dz]) of a padded node field.

    ``fp``: (..., nx + 4, ny + 4[, nz + 4]) with two ghost layers; ``vel``: (d, nx, ny[, nz]),
    the advecting velocity, which picks the upwind side at every node.  Returns a tuple.
    """
    d = _ndim_of(h, "eno_derivatives")
    out = []
    for axis in range(d):
        fm2, fm1, f0, f1, f2 = (_shift(fp, axis, k, 2, d) for k in (-2, -1, 0, 1, 2))
        back = _eno2(f1, f0, fm1, fm2) / (2 * h[axis])  # used where the velocity is positive
        fwd = -_eno2(fm1, f0, f1, f2) / (2 * h[axis])
        out.append(jnp.where(vel[axis] > 0, back, fwd))
    return tuple(out)


def advect(fp, vel, *h):
    """-(v . grad) f with ENO upwinding; ``fp`` padded with two ghost layers."""
    grads = eno_derivatives(fp, vel, *h)
    acc = vel[0] * grads[0]
    for a in range(1, len(grads)):
        acc = acc + vel[a] * grads[a]
    return -acc


def _sum_to(x, shape):
    """``x`` summed over the axes that broadcasting ``shape`` to ``x.shape`` added or
    stretched (the transpose of that broadcast)."""
    lead = x.ndim - len(shape)
    if lead:
        x = jnp.sum(x, axis=tuple(range(lead)))
    axes = tuple(i for i, (a, b) in enumerate(zip(x.shape, shape, strict=True)) if a != b)
    return jnp.sum(x, axis=axes, keepdims=True) if axes else x


def _eno_parts(fp, vel, axis, h, d):
    """The masks that pick the stencils of :func:`eno_derivatives` along ``axis`` (the same
    arithmetic as :func:`_eno2`): ``(back_one, fwd_one, pos)``, the backward and forward
    differences one-sided, and the velocity positive (the backward one used)."""
    fm2, fm1, f0, f1, f2 = (_shift(fp, axis, k, 2, d) for k in (-2, -1, 0, 1, 2))

    def one_sided(p0, p1, p2, p3):
        scale = jnp.abs(p0) + jnp.abs(p1) + jnp.abs(p2) + jnp.abs(p3)
        return jnp.abs(p0 - 2 * p1 + p2) > jnp.abs(p1 - 2 * p2 + p3) + _ENO_TIE * scale

    return one_sided(f1, f0, fm1, fm2), one_sided(fm1, f0, f1, f2), vel[axis] > 0


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def _advect_lowmem(fp, vel, h):
    return advect(fp, vel, *h)


def _advect_lowmem_fwd(fp, vel, h):
    return advect(fp, vel, *h), (fp, vel)


def _advect_lowmem_bwd(h, res, ct):
    # out = -sum_a vel_a D_a, D_a = where(pos, back, fwd) (eno_derivatives): linear in fp
    # for fixed stencil choices (the masks, recomputed here from fp and vel), so the
    # cotangent of fp is the transposed stencil applied to the masked cotangent.  It is
    # gathered from shifted slices of one zero-padded cotangent and one padded int8 code
    # of the stencil per axis, in one expression (JAX's own transpose pads each of the 10
    # shifted slices to the padded shape separately, and XLA kept them all live at the
    # peak of a step's backward)
    fp, vel = res
    d = len(h)
    grads = eno_derivatives(fp, vel, *h)
    inner = fp.shape[:-d] + tuple(n - 4 for n in fp.shape[-d:])
    g_fp = None
    g_vel = []
    for a in range(d):
        g_vel.append(_sum_to(-ct * grads[a], vel[a].shape))
        back_one, fwd_one, pos = _eno_parts(fp, vel, a, h, d)
        # 0: backward one-sided, 1: backward centred, 2: forward one-sided, 3: forward centred
        code = jnp.where(pos, jnp.where(back_one, 0, 1), jnp.where(fwd_one, 2, 3)).astype(jnp.int8)
        gd = -ct * vel[a] / (2 * h[a])
        pads = [(0, 0)] * (fp.ndim - d) + [(4, 4) if b == a else (2, 2) for b in range(d)]
        n = fp.shape[a - d]

        def at(x, k, a=a, n=n):  # the slice that lines up shift k's coefficient with fp
            idx = [slice(None)] * fp.ndim
            idx[a - d] = slice(2 - k, 2 - k + n)
            return x[tuple(idx)]

        if gd.shape == inner:
            gp = jnp.pad(gd, pads)
            cp = jnp.pad(code, pads, constant_values=-1)

            def part(k, c, gp=gp, cp=cp, at=at):  # the cotangent at shift k of stencil c
                return jnp.where(at(cp, k) == c, at(gp, k), 0.0)
        else:  # vel broadcasts over more axes than fp's: each stencil's share summed apart
            split = [jnp.pad(_sum_to(jnp.where(code == c, gd, 0.0), inner), pads) for c in range(4)]

            def part(k, c, split=split, at=at):
                return at(split[c], k)

        A = {k: part(k, 0) for k in (-2, -1, 0)}
        B = {k: part(k, 1) for k in (-1, 1)}
        C = {k: part(k, 2) for k in (0, 1, 2)}
        E = {k: part(k, 3) for k in (-1, 1)}
        term = (A[-2] + (-4 * A[-1] - B[-1] - E[-1]) + (3 * A[0] - 3 * C[0])
                + (B[1] + 4 * C[1] + E[1]) - C[2])
        g_fp = term if g_fp is None else g_fp + term
    return g_fp, jnp.stack(g_vel)


_advect_lowmem.defvjp(_advect_lowmem_fwd, _advect_lowmem_bwd)


def advect_lowmem(fp, vel, *h):
    """:func:`advect` (the same values) with a hand-written reverse-mode derivative that
    keeps only ``fp`` and ``vel`` for the backward pass and forms the transposed ENO stencil
    in one expression (less memory in the backward pass of a step; no forward mode)."""
    _ndim_of(h, "advect_lowmem")
    return _advect_lowmem(fp, vel, tuple(float(x) for x in h))


def laplacian(fp, *h, g=1):
    """(2d+1)-point Laplacian of a padded node field (g ghost layers) -> interior shape.

    ``g`` is keyword-only: every positional number after ``fp`` is a grid spacing.
    """
    d = _ndim_of(h, "laplacian")
    c = _shift(fp, 0, 0, g, d)
    acc = None
    for a in range(d):
        term = (_shift(fp, a, 1, g, d) - 2 * c + _shift(fp, a, -1, g, d)) / h[a] ** 2
        acc = term if acc is None else acc + term
    return acc


@functools.partial(jax.custom_vjp, nondiff_argnums=(1, 2))
def _laplacian_lowmem(fp, h, g):
    return laplacian(fp, *h, g=g)


def _laplacian_lowmem_fwd(fp, h, g):
    return laplacian(fp, *h, g=g), None


def _laplacian_lowmem_bwd(h, g, _, ct):
    # the Laplacian is linear and symmetric: its transpose is the same stencil read from
    # the cotangent padded with g + 1 zeros, one expression (JAX's transpose pads each of
    # the 2d + 1 shifted slices to the padded shape apart)
    d = len(h)
    gp = jnp.pad(ct, [(0, 0)] * (ct.ndim - d) + [(g + 1, g + 1)] * d)
    n = [m + 2 * g for m in ct.shape[-d:]]

    def at(a, k):  # shift k along axis a (0: the centre)
        return gp[(Ellipsis,) + tuple(slice(1 + (k if b == a else 0), 1 + (k if b == a else 0) + n[b])
                                      for b in range(d))]

    c = at(0, 0)
    acc = None
    for a in range(d):
        term = (at(a, -1) - 2 * c + at(a, 1)) / h[a] ** 2
        acc = term if acc is None else acc + term
    return (acc,)


_laplacian_lowmem.defvjp(_laplacian_lowmem_fwd, _laplacian_lowmem_bwd)


def laplacian_lowmem(fp, *h, g=1):
    """:func:`laplacian` (the same values) with a hand-written reverse mode that forms its
    transpose in one expression (less memory in a step's backward pass; no forward mode)."""
    _ndim_of(h, "laplacian_lowmem")
    return _laplacian_lowmem(fp, tuple(float(x) for x in h), int(g))


def divergence_centered(*args, g=1):
    """Centred-difference divergence of a padded node vector field (thesis eq. 4.28).

    2D: ``divergence_centered(up, vp, dx, dy, g=1)``; 3D:
    ``divergence_centered(up, vp, wp, dx, dy, dz, g=1)``.
    """
    if len(args) not in (2, 4, 6):
        raise TypeError(
            "divergence_centered takes d padded components then d spacings "
            f"(4 arguments in 2D, 6 in 3D), got {len(args)}"
        )
    d = len(args) // 2
    comps, h = args[:d], args[d:]
    acc = None
    for a in range(d):
        term = (_shift(comps[a], a, 1, g, d) - _shift(comps[a], a, -1, g, d)) / (2 * h[a])
        acc = term if acc is None else acc + term
    return acc


def unpad(fp, g, ndim: int = 2):
    """Drop ``g`` ghost layers on each side of the last ``ndim`` axes."""
    return fp[(Ellipsis, *(slice(g, -g) for _ in range(ndim)))]


def sym_grad(*grads):
    """Symmetric part of a velocity gradient given its corner components.

    2D: ``sym_grad(ux, uy, vx, vy) -> (xx, xy, yy)``; 3D: the nine components
    ``(ux, uy, uz, vx, vy, vz, wx, wy, wz)`` (row a = derivatives of component a) ->
    ``(xx, xy, xz, yy, yz, zz)``.  Diagonal entries are returned as given.
    """
    d = {1: 1, 4: 2, 9: 3}.get(len(grads))
    if d is None:
        raise TypeError(
            f"sym_grad takes d*d gradient components (4 in 2D, 9 in 3D), got {len(grads)}"
        )
    out = []
    for a in range(d):
        for b in range(a, d):
            if a == b:
                out.append(grads[a * d + a])
            else:
                out.append(0.5 * (grads[a * d + b] + grads[b * d + a]))
    return tuple(out)
