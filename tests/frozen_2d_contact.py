"""Verbatim copy of the 2D contact force of ``src/refmap/contact.py`` before it was made
dimension generic (commit 5d6d422): ``contact_stress``, ``contact_force``, the body-force
term ``_total_force``, ``contact_diagnostics`` and the helpers they need.  Used by
tests/test_contact_3d.py to check that every 2D result is bitwise unchanged.  Do not edit
(but for this docstring and the import block); ``contact`` is any object with the
:class:`refmap.contact.Contact` fields.
"""
# ruff: noqa

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from refmap import blend
from refmap.contact import Contact
from refmap.operators import div_node


# ----------------------------------------------------------------------------- pieces
def _stiffness(contact: Contact, params):
    """K = strength * (largest small-strain longitudinal modulus of the solids)."""
    M_max = jnp.asarray(1e-30)
    for law in params.laws:
        M_max = jnp.maximum(M_max, law.moduli()[1])
    return contact.strength * M_max


def _truncated(g, cutoff):
    return jnp.maximum(g - cutoff, 0.0) / (1.0 - cutoff)


def _kernel(p, contact: Contact, h):
    """Truncated Gaussian of phi_ab (thesis eq. 4.33)."""
    return _truncated(jnp.exp(-((p / (contact.width * h)) ** 2)), contact.cutoff)


#: the sine presence's half-width in units of ``reach h``: the support of the truncated erf
#: presence at the default cutoff (erfc(1.65) / 2 = 0.0099), so that contact engages at the
#: same gap with either blend kernel
SINE_REACH = 1.65


def _presence(phi, contact: Contact, h, kernel: str = "erf"):
    """Truncated smoothed indicator of a body: 1 inside, 1/2 on its surface, 0 far out,
    with the model's blend kernel (:func:`refmap.blend.presence`)."""
    if kernel == "erf":
        return blend.presence(phi, "erf", contact.reach * h, contact.cutoff)
    return blend.presence(phi, kernel, SINE_REACH * contact.reach * h)


def _take(field, idx):
    """field (N, ...), idx (...) -> field[idx[...], ...]."""
    return jnp.take_along_axis(field, idx[None], axis=0)[0]


def _two_nearest(phi):
    """Indices of the nearest (a) and second-nearest (b) solid at every point, N >= 2.

    Two ``argmin`` passes over the solid axis: O(N) per point.  (``lax.top_k`` does the same
    but is about 50 times slower on CPU.)  Ties go to the lower index.
    """
    a = jnp.argmin(phi, axis=0)
    k = jnp.arange(phi.shape[0]).reshape((-1,) + (1,) * (phi.ndim - 1))
    b = jnp.argmin(jnp.where(k == a[None], jnp.inf, phi), axis=0)
    return a, b


def _corner_gradient_of(phip, idx, dx, dy):
    """Gradient at the corners of solid ``idx`` (per corner) from the node level sets padded
    with one ghost layer: gathers the four nodes around each corner, O(1) per corner."""
    bl = _take(phip[:, :-1, :-1], idx)
    br = _take(phip[:, 1:, :-1], idx)
    tl = _take(phip[:, :-1, 1:], idx)
    tr = _take(phip[:, 1:, 1:], idx)
    return 0.5 * ((br - bl) + (tr - tl)) / dx, 0.5 * ((tl - bl) + (tr - br)) / dy


def wall_distances(model, loc="corner"):
    """``[(phi_w, inward normal)]`` for every non-periodic domain edge, at ``loc`` points
    (numpy arrays of the grid's ``loc`` shape)."""
    g = model.grid
    X, Y = g.mesh(loc)
    px, py = model.bc.periodic
    out = []
    if not px:
        out += [(X - g.ax, (1.0, 0.0)), (g.bx - X, (-1.0, 0.0))]
    if not py:
        out += [(Y - g.ay, (0.0, 1.0)), (g.by - Y, (0.0, -1.0))]
    return out


# ----------------------------------------------------------------------------- the force
def contact_stress(contact: Contact, model, state, params, derived=None):
    """Contact stress at the corners.

    Returns a dict: ``Pi`` and ``Pi_wall`` (pair and wall contact pressures, corner
    arrays), ``pair`` and ``wall`` (their stresses as ``(sxx, sxy, syy)`` corner arrays),
    ``a`` and ``b`` (nearest and second-nearest solid at each corner; None for N < 2).
    """
    d = derived if derived is not None else model.derived(state, params)
    g = model.grid
    h = model.h
    N = model.n_solids
    cshape = g.shape("corner")
    z = jnp.zeros(cshape, dtype=state.v.dtype)
    out = dict(Pi=z, Pi_wall=z, pair=(z, z, z), wall=(z, z, z), a=None, b=None)
    if N == 0:
        return out
    K = _stiffness(contact, params)
    kern = model.numerics.blend
    phic = d["phic"]
    if N >= 2:
        a, b = _two_nearest(phic)
        pa, pb = _take(phic, a), _take(phic, b)
        phip = model.bc.pad_linear(state.phi)[..., 1:-1, 1:-1]
        gxa, gya = _corner_gradient_of(phip, a, g.dx, g.dy)
        gxb, gyb = _corner_gradient_of(phip, b, g.dx, g.dy)
        nx_, ny_ = gxa - gxb, gya - gyb
        nn = nx_ * nx_ + ny_ * ny_
        inv = jnp.where(nn > 1e-12, 1.0 / jnp.where(nn > 1e-12, nn, 1.0), 0.0)
        Pi = (
            K * _kernel(pa - pb, contact, h) * _presence(pa, contact, h, kern) * _presence(pb, contact, h, kern)
        )
        # no pair pressure on the corners of non-periodic edges: their push on the node
        # outside the domain would be lost, and with it the pair's momentum balance
        edge = np.zeros(cshape, dtype=bool)
        px, py = model.bc.periodic
        if not px:
            edge[0, :] = edge[-1, :] = True
        if not py:
            edge[:, 0] = edge[:, -1] = True
        Pi = jnp.where(jnp.asarray(edge), 0.0, Pi)
        q = Pi * inv  # n (x) n = grad(phi_ab) (x) grad(phi_ab) / |grad(phi_ab)|^2
        out.update(Pi=Pi, a=a, b=b, pair=(-q * nx_ * nx_, -q * nx_ * ny_, -q * ny_ * ny_))
    if contact.walls:
        walls = wall_distances(model, "corner")
        if walls:
            # the wall pressure is nonzero only within 1.07 width cells of the wall: work on
            # strips of corners along the edges, not on the whole grid
            if contact.cutoff > 0:
                reach_w = 0.5 * contact.width * h * math.sqrt(math.log(1.0 / contact.cutoff))
            else:
                reach_w = math.inf
            sxx, sxy, syy, Pw_total = z, z, z, z
            for phi_w, (wx, wy) in walls:
                axis = 0 if wx != 0.0 else 1
                spacing = g.dx if axis == 0 else g.dy
                m = min(cshape[axis], int(math.floor(reach_w / spacing)) + 2)
                low = (wx if axis == 0 else wy) > 0
                sl = [slice(None), slice(None)]
                sl[axis] = slice(0, m) if low else slice(cshape[axis] - m, cshape[axis])
                sl = tuple(sl)
                pw = jnp.asarray(phi_w[sl])
                ph = phic[(slice(None),) + sl]
                pres = _presence(ph, contact, h, kern) * _presence(ph + 2.0 * pw, contact, h, kern)
                Pw = K * _kernel(-2.0 * pw, contact, h) * jnp.sum(pres, axis=0)
                sxx = sxx.at[sl].add(-Pw * wx * wx)
                sxy = sxy.at[sl].add(-Pw * wx * wy)
                syy = syy.at[sl].add(-Pw * wy * wy)
                Pw_total = Pw_total.at[sl].add(Pw)
            out.update(Pi_wall=Pw_total, wall=(sxx, sxy, syy))
    return out


def contact_force(contact: Contact, model, state, params, derived=None):
    """Contact force density at the nodes: dict with ``force`` (2, nx, ny), its parts
    ``pair_force`` and ``wall_force``, and everything :func:`contact_stress` returns."""
    cs = contact_stress(contact, model, state, params, derived)
    g = model.grid
    st = _materialised(jnp.stack([*cs["pair"], *cs["wall"]]))
    cs["pair_force"] = div_node(st[0], st[1], st[2], g.dx, g.dy)
    cs["wall_force"] = div_node(st[3], st[4], st[5], g.dx, g.dy)
    cs["force"] = cs["pair_force"] + cs["wall_force"]
    return cs


def _materialised(stress):
    """The stacked stress components as one buffer.  Without the barrier XLA fuses their
    (erfc, exp) producers into each of the shifted reads of the divergence and recomputes
    them there: measured 7x slower on CPU at 256^2."""
    return jax.lax.optimization_barrier(stress)


def _total_force(contact: Contact, model, state, params, derived):
    """Contact force density (2, nx, ny): ``div`` of the summed pair and wall stresses."""
    cs = contact_stress(contact, model, state, params, derived)
    st = _materialised(jnp.stack([p + w for p, w in zip(cs["pair"], cs["wall"], strict=True)]))
    return div_node(st[0], st[1], st[2], model.grid.dx, model.grid.dy)


# ----------------------------------------------------------------------------- diagnostics
def contact_diagnostics(
    model, state, params, contact: Contact | None = None, gap_band: float = 6.0, derived=None
):
    """Contact numbers at one state (jit-able; ``model`` and ``contact`` are static).

    Returns a dict of arrays (N solids):

    * ``force`` (N, 2): the contact force on each solid: the force density integrated over
      the nodes, each node's force shared among the solids in proportion to their solid
      fractions ``ws_n`` there; ``pair_force`` and
      ``wall_force`` (N, 2) its two parts.  For an isolated pair the two pair forces are
      equal and opposite to round-off;
    * ``net_pair_force`` (2,): the sum of all pair forces (zero to round-off);
    * ``max_contact_pressure``, ``max_wall_pressure``: the largest Pi on the corners;
    * ``min_gap`` (N, N): ``min(phi_i + phi_j)`` over the nodes where i and j are the two
      nearest solids and both |phi| < ``gap_band`` h (where the level sets are distances,
      not clipped): the distance between the two surfaces, negative when they overlap
      (minus the overlap depth); +inf when they are farther apart than that; NaN on the
      diagonal;
    * ``overlap_area`` (N, N): area of the nodes inside both i and j (phi_i < 0 and
      phi_j < 0, counted where they are the two nearest solids);
    * ``wall_gap`` (N,): ``min(phi_k + phi_w)`` over the nodes within the band and the
      non-periodic edges: the distance from solid k to the nearest wall, negative once it
      crossed it; +inf if none.
    """
    contact = contact if contact is not None else Contact()
    g = model.grid
    dA = g.cell_area
    N = model.n_solids
    h = model.h
    phi = state.phi
    d = derived if derived is not None else model.derived(state, params)
    cf = contact_force(contact, model, state, params, d)
    out = {}
    if N == 0:
        return out
    # the force on a node is shared among the solids in proportion to their fractions
    # there (smooth, so that it respects the symmetries of the state to round-off)
    ws = d["ws_n"]
    tot = jnp.sum(ws, axis=0, keepdims=True)
    owner = jnp.where(tot > 1e-300, ws / jnp.where(tot > 1e-300, tot, 1.0), 0.0)

    def per_solid(f):
        return jnp.einsum("kij,cij->kc", owner, f) * dA

    out["pair_force"] = per_solid(cf["pair_force"])
    out["wall_force"] = per_solid(cf["wall_force"])
    out["force"] = out["pair_force"] + out["wall_force"]
    out["net_pair_force"] = jnp.sum(cf["pair_force"], axis=(-2, -1)) * dA
    out["max_contact_pressure"] = jnp.max(cf["Pi"])
    out["max_wall_pressure"] = jnp.max(cf["Pi_wall"])
    L = gap_band * h
    near = jnp.abs(phi) < L
    gap = jnp.full((N, N), jnp.inf)
    area = jnp.zeros((N, N))
    if N >= 2:
        a, b = _two_nearest(phi)
        pa, pb = _take(phi, a), _take(phi, b)
        key = (jnp.minimum(a, b) * N + jnp.maximum(a, b)).ravel()
        ok = (jnp.abs(pa) < L) & (jnp.abs(pb) < L)
        gk = jax.ops.segment_min(jnp.where(ok, pa + pb, jnp.inf).ravel(), key, num_segments=N * N)
        ak = jax.ops.segment_sum(
            ((pa < 0) & (pb < 0)).astype(phi.dtype).ravel(), key, num_segments=N * N
        )
        gap = gk.reshape(N, N)
        gap = jnp.minimum(gap, gap.T)
        area = ak.reshape(N, N) * dA
        area = area + area.T
    eye = jnp.eye(N, dtype=bool)
    out["min_gap"] = jnp.where(eye, jnp.nan, gap)
    out["overlap_area"] = jnp.where(eye, jnp.nan, area)
    wg = jnp.full((N,), jnp.inf)
    for phi_w, _ in wall_distances(model, "node"):
        sw = phi + jnp.asarray(phi_w)[None]
        wg = jnp.minimum(wg, jnp.min(jnp.where(near, sw, jnp.inf), axis=(-2, -1)))
    out["wall_gap"] = wg
    return out
