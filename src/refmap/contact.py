"""Solid-solid and solid-wall contact (thesis section 4.11) as a body force.

Several solids share one velocity field.  Nothing in a single-velocity formulation should
let two bodies pass through each other, yet bodies pressed together do interpenetrate
through their *extrapolated* reference maps (thesis Fig. 4-29), and once they overlap no
velocity field separates them again.  :class:`Contact` prevents the overlap with a
repulsive force localised on the mid-surface between two solids; it is a body-force term
of :class:`refmap.model.Model`::

    model = Model(grid, solids, boundary, numerics, body_forces=(Contact(),))

The force
---------
All lengths are in units of the grid spacing h.  For a pair (a, b) the difference
``phi_ab = phi_a - phi_b`` vanishes on the mid-surface between the two bodies (thesis
eq. 4.32) and ``n = grad(phi_ab) / |grad(phi_ab)|`` is its unit normal, pointing from a to
b.  At every grid corner, with a and b the nearest and second-nearest solid there,

    Pi      = K  G(phi_ab)  chi(phi_a)  chi(phi_b),        K = strength * M_max,
    sigma_c = -Pi n (x) n,
    f       = div(sigma_c)    (the model's own top-right-triangle divergence at the nodes)

* ``G(p) = max(exp(-(p / (width h))^2) - cutoff, 0) / (1 - cutoff)`` is the thesis's
  truncated Gaussian of phi_ab (eq. 4.33): 1 on the mid-surface, exactly 0 farther than
  ``width sqrt(ln(1 / cutoff)) / 2 = 3.2`` cells from it (phi_ab is twice the distance to
  the mid-surface);
* ``chi(phi) = max(erfc(phi / (reach h)) / 2 - cutoff, 0) / (1 - cutoff)`` is the presence
  of a body: 1 inside, 1/2 on its surface, exactly 0 more than 1.65 reach cells outside.
  It is ``1 - H`` of the model's blend kernel (:func:`refmap.blend.presence`): with
  ``Numerics.blend = "sine"`` it is the sine kernel of half-width 1.65 reach cells (the
  same support, so contact engages at the same gap);
  The product ``chi_a chi_b`` is nonzero only where the two bodies' surroundings overlap,
  so the force acts only when the mid-surface lies inside both bodies' reach, i.e. for a
  gap below 3.3 reach cells, and grows monotonically as the gap closes (0.25 K at contact,
  K for overlapping bodies): there is no barrier to push through;
* ``sigma_c`` is a uniaxial compression along the contact normal: a contact pressure Pi
  acting across the mid-surface and nothing along it (frictionless, non-sticking: it
  never pulls).  Its divergence pushes the material on each side of the mid-surface back
  into its own body, and vanishes where Pi is uniform;
* ``K = strength * M_max``, M_max the largest small-strain longitudinal modulus of the
  solids (``law.moduli()``).  Pi is a stress, so the force density scales as M / h and the
  same case behaves the same at every resolution (gaps in cells, forces per area); the
  contact is as stiff as a layer of solid about one cell thick, which the explicit step
  already resolves.  Under a load P the pair settles where chi^2 = P / (strength M) at
  the mid-surface: about one cell apart for P ~ M / 20, touching for P ~ M / 4.

Why a stress and not a point-wise body force (the thesis's literal form).  We first used
``f = -K G(phi_ab) (chi_a - chi_b) n`` at the nodes, a narrow Gaussian of width 1.5 h.
It acts on the one or two node layers at the mid-surface, accelerates them relative to the
body behind them and creates grid-scale velocity jumps; the centred divergence of the fluid
density update then grows an odd-even mode (rho_f between -1 and 265 in a head-on test at
48^2, with the fluid-density update of that time, before its compression term was weighted
by the fluid fraction).  As the divergence of a stress, the force

* conserves momentum exactly, pair by pair: every interior corner pushes the two nodes on
  either side of it equally and oppositely, so no correction is needed (the pair pressure
  is set to zero on corners of non-periodic domain edges);
* does work ``sum f.v = -sum sigma_c : grad_h v`` through the same adjoint stencil pair as
  the elastic stress, so it behaves like additional elastic stiffness under the explicit
  step; measured: no odd-even mode and a fluid density within the range of the same run
  without contact;
* varies smoothly over a few cells (widths 3 h and 1 h below).

Many solids.  At each corner only the nearest and the second-nearest solid (the two
smallest phi_k, one pass over the solid axis) form the pair: O(N) work per
corner, not O(N^2).  A corner where three bodies meet sees its two nearest only.

Walls.  Each non-periodic domain edge (face in 3D) is an obstacle whose distance phi_w
is exact.  A
solid near it is treated as a pair with its own mirror image across the wall: then
``phi_ab = -2 phi_w`` (the mid-surface is the wall), the image's level set is
``phi_k + 2 phi_w`` and n is the wall normal.  Summed over all solids (O(N) per corner).
The wall corners carry this pressure, so the wall takes the reaction: the force acts on the
solid only and momentum is not conserved there, as for any wall.  Without it a heavy ball
resting on a no-slip floor sinks through it (its map leaks through the linearly
extrapolated ghost values); with it the ball stays above the floor.

Defaults and their reasons: ``width = 3`` (narrower kernels act on single node layers, see
above; 3 h keeps the pressure within 3 cells of the mid-surface), ``reach = 1`` (with the
blur width 2 the pair stopped 6 cells apart, with 1 it engages at 3 cells and rests about
one apart), ``cutoff = 0.01`` (the thesis's truncation; it makes the force exactly zero
for bodies far apart, so one solid away from the walls runs bit-for-bit as without
contact), ``strength = 1`` (0.3 lets a pair pushed by a body force of 2 per unit volume
close to 0.4 h; 1 keeps it at 1 h and a push of 6 above 0.06 h).

Diagnostics.  :func:`contact_diagnostics` gives, per solid, the contact force integrated
over the nodes, each node's force shared among the solids there in proportion to their
fractions (pair and wall parts); per pair the minimum gap ``min(phi_i + phi_j)`` (for
signed distances exactly the distance between the surfaces, minus the overlap depth if
negative) and the overlap area (volume in 3D); per solid the gap to the walls.

Three dimensions.  The same :class:`Contact` serves 2D and 3D grids (it declares
``supports_3d = True``, which :func:`refmap.model.check_3d_support` reads); nothing above
depends on the dimension d.  The stresses are tuples of the d(d+1)/2 corner components in
:data:`refmap.operators.SYM_COMPONENTS` order (``(xx, xy, yy)``; in 3D ``(xx, xy, xz, yy,
yz, zz)``), ``grad(phi_ab)`` at a corner averages the 2^(d-1) differences along each axis
of the 2^d nodes around it, and the walls are the non-periodic faces of
:data:`refmap.boundary.AXIS_FACES` (left, right, bottom, top, back, front), each with its
own slab of corners.  The force components, the diagnostics (``contact_fz``) and the frame
arrays (axis ``xyz``) gain a z.  A z-invariant 3D state gives the 2D force exactly (to
round-off, tested against a pair of discs), and every 2D result is bit for bit that of the
2D code before the generalisation (tests/test_contact_3d.py against
tests/frozen_2d_contact.py).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from refmap import blend, narrowband, windows
from refmap.materials import law_moduli
from refmap.operators import SYM_PAIRS, corner_average, div_node

__all__ = [
    "PAIR_COLUMNS_MAX_SOLIDS",
    "Contact",
    "contact_stress",
    "contact_force",
    "contact_diagnostics",
    "wall_distances",
    "benchmark",
]


#: the diagnostics table has per-pair columns (min gap, overlap area) up to this many solids
#: (120 pairs); the output frames always hold the full per-pair tables
PAIR_COLUMNS_MAX_SOLIDS = 16


@dataclass(frozen=True)
class Contact:
    """Repulsive contact between solids and against the non-periodic domain edges.

    Parameters (lengths in grid cells h)
    ----------
    width:
        Width of the Gaussian of ``phi_a - phi_b`` (default 3): the pressure acts within
        ``1.07 width`` cells of the mid-surface.
    reach:
        Width of a body's presence ``erfc(phi / (reach h)) / 2`` (default 1): contact engages
        at a gap of ``3.3 reach`` cells.
    cutoff:
        Truncation level of the Gaussian and of the presences (thesis: 0.01).
    strength:
        Contact stiffness in units of the largest longitudinal modulus of the solids
        (default 1): the contact pressure is 0.25 strength M at touching.
    walls:
        Also keep solids off the non-periodic domain edges (default True).
    """

    #: the term works on 2D and 3D grids alike (read by :func:`refmap.model.check_3d_support`)
    supports_3d: ClassVar[bool] = True

    width: float = 3.0
    reach: float = 1.0
    cutoff: float = 0.01
    strength: float = 1.0
    walls: bool = True

    def __post_init__(self):
        self.check()
        for name in ("width", "reach", "cutoff", "strength"):
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "walls", bool(self.walls))

    def check(self) -> Contact:
        """Raise ValueError naming the first bad parameter (and its value); else self."""

        def number(v):
            return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(
                v, (bool, np.bool_)
            )

        for name in ("width", "reach", "strength"):
            v = getattr(self, name)
            if not (number(v) and math.isfinite(v) and v > 0):
                raise ValueError(f"Contact {name} must be a finite number > 0, got {v!r}")
        if not (number(self.cutoff) and 0.0 <= self.cutoff < 1.0):
            raise ValueError(f"Contact cutoff must be in [0, 1), got {self.cutoff!r}")
        if not isinstance(self.walls, (bool, np.bool_)):
            raise ValueError(f"Contact walls must be True or False, got {self.walls!r}")
        return self

    def __call__(self, ctx):
        """Body-force term of :class:`refmap.model.Model`: force density (d, nx, ny[, nz])."""
        return _total_force(self, ctx["model"], ctx["state"], ctx["params"], ctx["derived"])

    def diagnostics(self, model, state, params, derived=None):
        """Flat scalar contact diagnostics, shaped like ``Model.diagnostics`` (which merges
        them into its own): scalars; ``solids``, a list of per-solid dicts (contact force
        ``contact_fx``, ``contact_fy`` (and ``contact_fz`` in 3D) and ``wall_gap``); and, for at most
        :data:`PAIR_COLUMNS_MAX_SOLIDS` solids, ``pairs``: ``{"i_j": {min_gap,
        overlap_area}}`` for every pair i < j (min_gap +inf for pairs farther apart than the
        band, i.e. not in contact).  The diagnostics table gets one column per entry; with
        more solids the per-pair tables are only in the frames (:meth:`frame_arrays`)."""
        d = contact_diagnostics(model, state, params, self, derived=derived)
        N = model.n_solids
        out = dict(
            contact_max_pressure=d["max_contact_pressure"],
            contact_max_wall_pressure=d["max_wall_pressure"],
        )
        if N >= 2:
            iu = np.triu_indices(N, 1)
            out["contact_min_gap"] = jnp.min(d["min_gap"][iu])
            out["contact_overlap_area"] = jnp.sum(d["overlap_area"][iu])
            out["contact_pairs"] = jnp.sum(jnp.isfinite(d["min_gap"][iu]))
            if N <= PAIR_COLUMNS_MAX_SOLIDS:
                out["pairs"] = {
                    f"{i}_{j}": dict(
                        min_gap=d["min_gap"][i, j], overlap_area=d["overlap_area"][i, j]
                    )
                    for i, j in zip(*iu, strict=True)
                }
        if N >= 1:
            out["contact_min_wall_gap"] = jnp.min(d["wall_gap"])
            axes = "xyz"[: model.ndim]
            if model.windowed(state):  # many bodies: columns, not a dict per solid
                from refmap.window_diagnostics import SolidRows

                out["solids"] = SolidRows({**{f"contact_f{a}": d["force"][:, c] for c, a in enumerate(axes)},
                                           "wall_gap": d["wall_gap"]})
                return out
            out["solids"] = [
                {
                    **{f"contact_f{a}": d["force"][k, c] for c, a in enumerate(axes)},
                    "wall_gap": d["wall_gap"][k],
                }
                for k in range(N)
            ]
        return out

    def frame_arrays(self, model, state, params, derived=None):
        """The contact numbers of one state as arrays for the output frames:
        ``contact_force`` (N, d), ``contact_wall_gap`` (N,), ``contact_min_gap`` and
        ``contact_overlap_area`` (N, N; NaN on the diagonal, min_gap +inf for pairs not in
        contact)."""
        if model.n_solids == 0:
            return {}
        d = contact_diagnostics(model, state, params, self, derived=derived)
        return {
            "contact_force": d["force"],
            "contact_wall_gap": d["wall_gap"],
            "contact_min_gap": d["min_gap"],
            "contact_overlap_area": d["overlap_area"],
        }

    def frame_array_dims(self, model):
        """Axis names of :meth:`frame_arrays` (the force's components: ``xy``, in 3D ``xyz``,
        as :meth:`refmap.model.Model.frame_array_dims`)."""
        if model.n_solids == 0:
            return {}
        return {
            "contact_force": ("solid", "xyz"[: model.ndim]),
            "contact_wall_gap": ("solid",),
            "contact_min_gap": ("solid", "other_solid"),
            "contact_overlap_area": ("solid", "other_solid"),
        }

    def to_dict(self):
        return {
            "width": self.width,
            "reach": self.reach,
            "cutoff": self.cutoff,
            "strength": self.strength,
            "walls": self.walls,
        }


# ----------------------------------------------------------------------------- pieces
def _stiffness(contact: Contact, params):
    """K = strength * (largest small-strain longitudinal modulus of the solids)."""
    M_max = jnp.asarray(1e-30)
    if params.laws:  # (batched by law class: the code does not grow with the solids)
        M_max = jnp.maximum(M_max, jnp.max(law_moduli(params.laws)[1]))
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

    One pass over the solids (a ``fori_loop``) that keeps the two smallest values and their
    indices at every point: O(N) per point.  Ties go to the lower index, as with two
    ``argmin`` passes (the second over the values with ``a``'s masked out), which this
    equals for every finite input: a value replaces the smallest only if strictly smaller,
    and the second smallest likewise.  Where every value is +inf both are 0, as there.
    XLA's CPU ``argmin`` over the leading axis is a variadic reduction that it does not
    vectorise: two passes took 98 ms for 100 solids on 301^2 corners, this 28 ms; and
    ``lax.top_k`` is about 50 times slower still.
    """
    phi = lax.stop_gradient(phi)  # indices only: no derivative, and no tangents in the loop
    inf = jnp.full(phi.shape[1:], jnp.inf, dtype=phi.dtype)
    zero = jnp.zeros(phi.shape[1:], dtype=jax.dtypes.canonicalize_dtype(jnp.int64))  # argmin's

    def visit(k, best):
        m1, a, m2, b = best
        v = phi[k]
        first, second = v < m1, v < m2
        return (
            jnp.where(first, v, m1),
            jnp.where(first, k, a),
            jnp.where(first, m1, jnp.where(second, v, m2)),
            jnp.where(first, a, jnp.where(second, k, b)),
        )

    _, a, _, b = lax.fori_loop(0, phi.shape[0], visit, (inf, zero, inf, zero))
    return a, b


def _corner_gradient_of(phip, idx, *spacing):
    """Gradient at the corners of solid ``idx`` (per corner) from the node level sets padded
    with one ghost layer: gathers the 2^d nodes around each corner, O(1) per corner, and
    averages the 2^(d-1) differences along each axis.  In 2D, with the nodes BL, BR, TL, TR,
    ``(0.5 ((BR - BL) + (TR - TL)) / dx, 0.5 ((TL - BL) + (TR - BR)) / dy)``."""
    return _corner_differences(phip, spacing, lambda f: _take(f, idx))


def _corner_differences(phip, spacing, pick):
    """The corner gradient of :func:`_corner_gradient_of` from the 2^d node views of
    ``phip`` (S, n + 2, ...), each passed through ``pick`` (the nearest solid's values, or
    every solid's)."""
    d = len(spacing)
    nodes = {}
    for n in range(2**d):  # the first axis varying fastest: BL, BR, TL, TR in 2D
        off = tuple((n >> a) & 1 for a in range(d))
        view = tuple(slice(None, -1) if o == 0 else slice(1, None) for o in off)
        nodes[off] = pick(phip[(slice(None), *view)])
    out = []
    for a in range(d):
        acc = None
        for off, lo in nodes.items():  # every edge along axis a, by its low end
            if off[a] == 1:
                continue
            hi = nodes[tuple(1 if b == a else o for b, o in enumerate(off))]
            acc = hi - lo if acc is None else acc + (hi - lo)
        out.append(0.5 ** (d - 1) * acc / spacing[a])
    return tuple(out)


def wall_distances(model, loc="corner"):
    """``[(phi_w, inward normal)]`` for every non-periodic domain edge (face in 3D), at
    ``loc`` points (numpy arrays of the grid's ``loc`` shape); the normal is a d-tuple.
    Ordered by axis, low face first (left, right, bottom, top, back, front)."""
    g = model.grid
    d = g.ndim
    X = g.mesh(loc)
    out = []
    for axis, periodic in enumerate(model.bc.periodic):
        if periodic:
            continue
        lo, hi = g.lows[axis], g.highs[axis]
        e = tuple(1.0 if b == axis else 0.0 for b in range(d))
        out += [(X[axis] - lo, e), (hi - X[axis], tuple(-c if c else 0.0 for c in e))]
    return out


# ----------------------------------------------------------------------------- the force
def contact_stress(contact: Contact, model, state, params, derived=None):
    """Contact stress at the corners.

    Returns a dict: ``Pi`` and ``Pi_wall`` (pair and wall contact pressures, corner
    arrays), ``pair`` and ``wall`` (their stresses as tuples of the d(d+1)/2 corner arrays
    in ``SYM_COMPONENTS`` order: ``(sxx, sxy, syy)`` in 2D, ``(sxx, sxy, sxz, syy, syz,
    szz)`` in 3D), ``a`` and ``b`` (nearest and second-nearest solid at each corner; None
    for N < 2).
    """
    d = derived if derived is not None else model.derived(state, params)
    win = _windows_for(contact, model, d)

    def grid(_):
        # the corner level sets made here (inside the branch below: the windowed branch
        # needs none of the solids' whole-grid fields), of the solids on the whole grid
        on_grid = model.on_grid(state)
        phip = model.bc.pad_linear(on_grid.phi)[model._core(1)]
        return _contact_stress_grid(contact, model, on_grid, params, corner_average(phip, model.ndim))

    if win is None and model.windowed(state):
        # solids stored in windows but the contact not on them (one solid, or a presence
        # that reaches past phi_max h)
        return grid(None)
    if win is None:  # (no "phic" without solids: nothing to touch)
        return _contact_stress_grid(contact, model, state, params, d.get("phic"))
    origins, fits = win
    if model.windowed(state):  # the solids stored in windows: no whole-grid level sets
        return _contact_stress_windows(contact, model, state, params, jnp.maximum(origins, 0))

    def windowed(_):
        return _contact_stress_windows(contact, model, state, params, origins)

    return narrowband.switch(jnp.where(jnp.all(fits), 0, 1), [windowed, grid], None)


def _windows_for(contact: Contact, model, d):
    """``(origins, fits)`` of the solids' band windows this step (``d["band_windows"]``,
    made by ``Model.derived`` with ``Numerics.solid_storage = "window"``), or None (the
    whole grid): without them, with fewer than two solids, or when a body's presence does
    not vanish at ``phi_max h`` (``cutoff = 0``, a very wide ``reach``), because a window
    leaves out a solid's corners beyond that level."""
    win = d.get("band_windows")
    if win is None or model.n_solids < 2:
        return None
    phi_max = model.numerics.phi_max * model.h
    with jax.ensure_compile_time_eval():
        far = float(_presence(jnp.asarray(0.99 * phi_max), contact, model.h, model.numerics.blend))
    return win if far == 0.0 else None


def _pair_pressure(contact: Contact, model, K, pa, pb, ga, gb):
    """The pair pressure Pi and its stress components from the two nearest solids' corner
    level sets ``pa``, ``pb`` and gradients ``ga``, ``gb``."""
    g = model.grid
    nd = g.ndim
    h = model.h
    cshape = g.shape("corner")
    kern = model.numerics.blend
    n_ = [u - w for u, w in zip(ga, gb, strict=True)]  # grad(phi_ab), not normalised
    nn = n_[0] * n_[0]
    for c in range(1, nd):
        nn = nn + n_[c] * n_[c]
    inv = jnp.where(nn > 1e-12, 1.0 / jnp.where(nn > 1e-12, nn, 1.0), 0.0)
    Pi = K * _kernel(pa - pb, contact, h) * _presence(pa, contact, h, kern) * _presence(pb, contact, h, kern)
    # no pair pressure on the corners of non-periodic edges (faces): their push on the
    # node outside the domain would be lost, and with it the pair's momentum balance
    edge = np.zeros(cshape, dtype=bool)
    for axis, periodic in enumerate(model.bc.periodic):
        if not periodic:
            for i in (0, -1):
                sl = [slice(None)] * nd
                sl[axis] = i
                edge[tuple(sl)] = True
    Pi = jnp.where(jnp.asarray(edge), 0.0, Pi)
    q = Pi * inv  # n (x) n = grad(phi_ab) (x) grad(phi_ab) / |grad(phi_ab)|^2
    return Pi, tuple(-q * n_[i] * n_[j] for i, j in SYM_PAIRS[nd])


def _wall_stress(contact: Contact, model, K, presences, out, zeros):
    """The wall pressure and stress into ``out``: ``presences(sl, pw)`` is the sum over the
    solids of ``chi(phi_k) chi(phi_k + 2 phi_w)`` on the corners ``sl`` of a wall's strip,
    ``pw`` the wall's distance there."""
    g = model.grid
    nd = g.ndim
    h = model.h
    cshape = g.shape("corner")
    comps = SYM_PAIRS[nd]
    walls = wall_distances(model, "corner")
    if not walls:
        return
    z = zeros[0]
    # the wall pressure is nonzero only within 1.07 width cells of the wall: work on strips
    # (slabs) of corners along the edges (faces), not on the whole grid
    if contact.cutoff > 0:
        reach_w = 0.5 * contact.width * h * math.sqrt(math.log(1.0 / contact.cutoff))
    else:
        reach_w = math.inf
    sw, Pw_total = list(zeros), z
    for phi_w, w in walls:
        axis = next(c for c in range(nd) if w[c] != 0.0)
        spacing = g.spacing[axis]
        m = min(cshape[axis], int(math.floor(reach_w / spacing)) + 2)
        low = w[axis] > 0
        sl = [slice(None)] * nd
        sl[axis] = slice(0, m) if low else slice(cshape[axis] - m, cshape[axis])
        sl = tuple(sl)
        pw = jnp.asarray(phi_w[sl])
        Pw = K * _kernel(-2.0 * pw, contact, h) * presences(sl, phi_w)
        # -Pw w (x) w; the zero off-axis products are added too (as the 2D code always
        # did: bitwise the same results)
        for k, (i, j) in enumerate(comps):
            sw[k] = sw[k].at[sl].add(-Pw * w[i] * w[j])
        Pw_total = Pw_total.at[sl].add(Pw)
    out.update(Pi_wall=Pw_total, wall=tuple(sw))


def _contact_stress_grid(contact: Contact, model, state, params, phic):
    """:func:`contact_stress` from every solid's corner level sets ``phic`` (S, *corners)
    on the whole grid."""
    g = model.grid
    nd = g.ndim
    h = model.h
    N = model.n_solids
    cshape = g.shape("corner")
    z = jnp.zeros(cshape, dtype=state.v.dtype)
    zeros = (z,) * len(SYM_PAIRS[nd])
    out = dict(Pi=z, Pi_wall=z, pair=zeros, wall=zeros, a=None, b=None)
    if N == 0:
        return out
    K = _stiffness(contact, params)
    kern = model.numerics.blend
    if N >= 2:
        a, b = _two_nearest(phic)
        pa, pb = _take(phic, a), _take(phic, b)
        phip = model.bc.pad_linear(state.phi)[model._core(1)]
        ga = _corner_gradient_of(phip, a, *g.spacing)
        gb = _corner_gradient_of(phip, b, *g.spacing)
        Pi, pair = _pair_pressure(contact, model, K, pa, pb, ga, gb)
        out.update(Pi=Pi, a=a, b=b, pair=pair)
    if contact.walls:
        def presences(sl, phi_w):
            ph = phic[(slice(None),) + sl]
            pw = jnp.asarray(phi_w[sl])
            return jnp.sum(_presence(ph, contact, h, kern) * _presence(ph + 2.0 * pw, contact, h, kern), axis=0)

        _wall_stress(contact, model, K, presences, out, zeros)
    return out


def _contact_stress_windows(contact: Contact, model, state, params, origins):
    """:func:`contact_stress` from the solids' band windows (``origins`` (S, d), size
    ``model.solid_band_window``; ``Numerics.solid_storage = "window"``): every solid's
    corner level sets and gradients on its window, then at every corner the nearest and
    second-nearest solid by scatter-min over the windows (the lower index wins a tie, as in
    :func:`_two_nearest`), their gradients by scatter-add, and the walls' presence sums by
    scatter-add.  A window holds every corner of its solid below ``phi_max h``; a solid
    left out at a corner is there at ``phi_max h`` on the grid too, where its presence is
    zero, so the pressures are the whole grid's."""
    g = model.grid
    nd = g.ndim
    h = model.h
    N = model.n_solids
    W = model.solid_band_window
    per = model.bc.periodic
    shape = g.shape()
    cshape = g.shape("corner")
    K = _stiffness(contact, params)
    kern = model.numerics.blend
    far = jnp.asarray(model.numerics.phi_max * h, state.v.dtype)
    size = tuple(w + 2 for w in W)  # nodes origin - 1 .. origin + W: corners origin .. origin + W
    if model.windowed(state):  # the windows themselves, one linear ghost layer round them
        phiw = jax.vmap(lambda p: windows.ghosted(p, 1, 1, nd))(state.phi)
    else:
        phiw = jax.vmap(lambda p, o: windows.gather_ghosted(p, o, size, per, offset=-1))(state.phi, origins)
    phic = corner_average(phiw, nd)  # (S, W + 1, ...)
    grads = _corner_gradients(phiw, *g.spacing)
    # the windows' corners on a grid of n corners along a periodic axis (corner n is corner
    # 0's copy, appended below) and n + 1 along a walled one
    base = tuple(n if p else n + 1 for n, p in zip(shape, per, strict=True))
    k = jnp.arange(N, dtype=jnp.int32).reshape((N,) + (1,) * nd)

    def at(f):  # every window's values of the corner field f (on the windows' base grid)
        return windows.blocks(f, origins, tuple(w + 1 for w in W), per)

    def close(f):  # corner n of a periodic axis from corner 0
        for a in range(nd):
            if per[a]:
                f = jnp.concatenate([f, lax.slice_in_dim(f, 0, 1, axis=a)], axis=a)
        return f

    def smallest(vals, skip=None):
        """(value, index) of the smallest of ``vals`` (S, *window) at every corner, the
        solid ``skip`` (per corner) left out; index N where no window is left."""
        if skip is not None:
            vals = jnp.where(k == at(skip), far, vals)
        m = windows.accumulate(jnp.full(base, far, vals.dtype), vals, origins, per, "min")
        pick = vals == at(m)
        if skip is not None:
            pick = pick & (k != at(skip))
        i = windows.accumulate(jnp.full(base, N, jnp.int32), jnp.where(pick, k, N).astype(jnp.int32),
                               origins, per, "min")
        return m, i

    z = jnp.zeros(cshape, dtype=state.v.dtype)
    zeros = (z,) * len(SYM_PAIRS[nd])
    out = dict(Pi=z, Pi_wall=z, pair=zeros, wall=zeros, a=None, b=None)
    stopped = lax.stop_gradient(phic)
    _, a = smallest(stopped)  # N where no window holds the corner
    _, b = smallest(stopped, skip=a)

    def of(i, f):  # solid i's values of the window fields f (per corner; 0 where i is N)
        return close(windows.accumulate(jnp.zeros(base, f.dtype), jnp.where(k == at(i), f, 0.0), origins, per))

    # the level sets with their derivative (the indices above carry none); a solid is found
    # only among the windows that hold the corner, so N means "far" there
    pa = jnp.where(close(a) == N, far, of(a, phic))
    pb = jnp.where(close(b) == N, far, of(b, phic))
    Pi, pair = _pair_pressure(contact, model, K, pa, pb, tuple(of(a, gc) for gc in grads),
                              tuple(of(b, gc) for gc in grads))
    # the indices as _two_nearest gives them where every solid is far: 0 and 1 (0 if a is not)
    a_out = jnp.where(a == N, 0, a)
    b_out = jnp.where(b == N, jnp.where(a_out == 0, 1, 0), b)
    idx_t = jax.dtypes.canonicalize_dtype(jnp.int64)  # _two_nearest's (argmin's) index type
    out.update(Pi=Pi, a=close(a_out).astype(idx_t), b=close(b_out).astype(idx_t), pair=pair)
    if contact.walls:
        def presences(sl, phi_w):
            # only a window's rows (columns, layers) next to the wall can lie in its strip of
            # m corners: the first m of a window at a low wall (its corner r is corner
            # origin + r >= r of the grid), the last m at a high wall (a window ends at or
            # before the grid's last corner); the others add exact zeros
            axis = next(a for a in range(nd) if sl[a] != slice(None))
            m = min(sl[axis].stop - sl[axis].start, W[axis] + 1)
            first = 0 if sl[axis].start == 0 else W[axis] + 1 - m
            part = (slice(None),) + tuple(slice(first, first + m) if a == axis else slice(None)
                                          for a in range(nd))
            o = origins.at[:, axis].add(first)
            size = tuple(m if a == axis else W[a] + 1 for a in range(nd))
            pw = close_periodic_corners(jnp.asarray(phi_w), per)  # the wall's distance
            pw_w = windows.blocks(pw, o, size, per)
            ph = phic[part]
            terms = _presence(ph, contact, h, kern) * _presence(ph + 2.0 * pw_w, contact, h, kern)
            return close(windows.accumulate(jnp.zeros(base, phic.dtype), terms, o, per))[sl]

        _wall_stress(contact, model, K, presences, out, zeros)
    return out


def close_periodic_corners(f, periodic):
    """A corner field (n + 1 corners per axis) cut to n corners along its periodic axes
    (corner n is corner 0 there), so that a periodic window's corner indices (taken modulo
    n) read it."""
    return f[tuple(slice(0, -1) if p else slice(None) for p in periodic)]


def _corner_gradients(phip, *spacing):
    """Every solid's gradient at the corners from its node level set padded with one ghost
    layer (``phip`` (S, n + 2, ...)): the arithmetic of :func:`_corner_gradient_of`, for all
    solids at once."""
    return _corner_differences(phip, spacing, lambda f: f)


def contact_force(contact: Contact, model, state, params, derived=None):
    """Contact force density at the nodes: dict with ``force`` (d, nx, ny[, nz]), its parts
    ``pair_force`` and ``wall_force``, and everything :func:`contact_stress` returns."""
    cs = contact_stress(contact, model, state, params, derived)
    sp = model.grid.spacing
    nc = len(cs["pair"])
    st = _materialised(jnp.stack([*cs["pair"], *cs["wall"]]))
    cs["pair_force"] = div_node(*st[:nc], *sp)
    cs["wall_force"] = div_node(*st[nc:], *sp)
    cs["force"] = cs["pair_force"] + cs["wall_force"]
    return cs


def _materialised(stress):
    """The stacked stress components as one buffer.  Without the barrier XLA fuses their
    (erfc, exp) producers into each of the shifted reads of the divergence and recomputes
    them there: measured 7x slower on CPU at 256^2."""
    return jax.lax.optimization_barrier(stress)


def _total_force(contact: Contact, model, state, params, derived):
    """Contact force density (d, nx, ny[, nz]): ``div`` of the summed pair and wall
    stresses."""
    cs = contact_stress(contact, model, state, params, derived)
    st = _materialised(jnp.stack([p + w for p, w in zip(cs["pair"], cs["wall"], strict=True)]))
    return div_node(*st, *model.grid.spacing)


# ----------------------------------------------------------------------------- diagnostics
def contact_diagnostics(
    model, state, params, contact: Contact | None = None, gap_band: float = 6.0, derived=None
):
    """Contact numbers at one state (jit-able; ``model`` and ``contact`` are static).

    Returns a dict of arrays (N solids):

    * ``force`` (N, d): the contact force on each solid: the force density integrated over
      the nodes (cells of area dx dy, volume dx dy dz in 3D), each node's force shared
      among the solids in proportion to their solid fractions ``ws_n`` there;
      ``pair_force`` and ``wall_force`` (N, d) its two parts.  For an isolated pair the two
      pair forces are equal and opposite to round-off;
    * ``net_pair_force`` (d,): the sum of all pair forces (zero to round-off);
    * ``max_contact_pressure``, ``max_wall_pressure``: the largest Pi on the corners;
    * ``min_gap`` (N, N): ``min(phi_i + phi_j)`` over the nodes where i and j are the two
      nearest solids and both |phi| < ``gap_band`` h (where the level sets are distances,
      not clipped): the distance between the two surfaces, negative when they overlap
      (minus the overlap depth); +inf when they are farther apart than that; NaN on the
      diagonal;
    * ``overlap_area`` (N, N): area (in 3D: volume) of the nodes inside both i and j
      (phi_i < 0 and phi_j < 0, counted where they are the two nearest solids);
    * ``wall_gap`` (N,): ``min(phi_k + phi_w)`` over the nodes within the band and the
      non-periodic edges (faces): the distance from solid k to the nearest wall, negative once it
      crossed it; +inf if none.
    """
    contact = contact if contact is not None else Contact()
    if model.windowed(state):
        if _on_windows(model, gap_band):  # from the windows: no solid's whole-grid field
            return _diagnostics_on_windows(model, state, params, contact, gap_band, derived)
        state, derived = model.on_grid(state), None  # the numbers of the grid's fields
    g = model.grid
    nd = g.ndim
    dA = g.cell_area if nd == 2 else g.cell_volume  # the cell's d-dimensional measure
    space = tuple(range(-nd, 0))  # the spatial axes
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

    ijk = "ijl"[:nd]

    def per_solid(f):
        return jnp.einsum(f"k{ijk},c{ijk}->kc", owner, f) * dA

    out.update(_force_numbers(cf, per_solid, dA, space))
    L = gap_band * h
    near = jnp.abs(phi) < L
    gap = jnp.full((N, N), jnp.inf)
    area = jnp.zeros((N, N))
    if N >= 2:
        a, b = _two_nearest(phi)
        gap, area = _pair_tables(a, b, _take(phi, a), _take(phi, b), N, L, dA)
    eye = jnp.eye(N, dtype=bool)
    out["min_gap"] = jnp.where(eye, jnp.nan, gap)
    out["overlap_area"] = jnp.where(eye, jnp.nan, area)
    wg = jnp.full((N,), jnp.inf)
    for phi_w, _ in wall_distances(model, "node"):
        sw = phi + jnp.asarray(phi_w)[None]
        wg = jnp.minimum(wg, jnp.min(jnp.where(near, sw, jnp.inf), axis=space))
    out["wall_gap"] = wg
    return out


def _force_numbers(cf, per_solid, dA, space) -> dict:
    """The force entries of :func:`contact_diagnostics` from :func:`contact_force`'s ``cf``:
    each solid's pair, wall and total force (``per_solid`` shares a grid force density out
    among the solids), the net pair force and the largest pair and wall pressures."""
    out = {"pair_force": per_solid(cf["pair_force"]), "wall_force": per_solid(cf["wall_force"])}
    out["force"] = out["pair_force"] + out["wall_force"]
    out["net_pair_force"] = jnp.sum(cf["pair_force"], axis=space) * dA
    out["max_contact_pressure"] = jnp.max(cf["Pi"])
    out["max_wall_pressure"] = jnp.max(cf["Pi_wall"])
    return out


def _pair_tables(a, b, pa, pb, N: int, L, dA):
    """``(min_gap, overlap_area)`` (N, N) of :func:`contact_diagnostics`, symmetric (the
    diagonal as it comes: the caller sets it), from the nearest and second-nearest solid
    ``a``, ``b`` at every node and their level sets ``pa``, ``pb`` there (grid arrays): per
    pair the least ``pa + pb`` over its nodes where both are below ``L`` in magnitude, and
    ``dA`` times the count of its nodes inside both."""
    key = (jnp.minimum(a, b) * N + jnp.maximum(a, b)).ravel()
    ok = (jnp.abs(pa) < L) & (jnp.abs(pb) < L)
    gk = jax.ops.segment_min(jnp.where(ok, pa + pb, jnp.inf).ravel(), key, num_segments=N * N)
    ak = jax.ops.segment_sum(
        ((pa < 0) & (pb < 0)).astype(pa.dtype).ravel(), key, num_segments=N * N
    )
    gap = gk.reshape(N, N)
    gap = jnp.minimum(gap, gap.T)
    area = ak.reshape(N, N) * dA
    area = area + area.T
    return gap, area


def _on_windows(model, gap_band: float) -> bool:
    """Whether :func:`contact_diagnostics` of solids stored in windows can read the windows
    alone (:func:`_diagnostics_on_windows`): a solid's fraction is exactly 0 at
    ``phi_max h`` (:func:`refmap.window_diagnostics.applies`) and ``phi_max h`` is outside
    the gap band, so that a node outside a solid's window (at ``phi_max h`` on the grid)
    adds nothing to its forces, gaps or overlaps."""
    from refmap import window_diagnostics

    return window_diagnostics.applies(model) and model.numerics.phi_max >= gap_band


def _diagnostics_on_windows(model, state, params, contact: Contact, gap_band: float, derived=None):
    """:func:`contact_diagnostics` of solids stored in windows (``state.origin`` set), from
    the windows and grid fields only: no array of S whole-grid fields.

    * the forces: the contact force density on the grid (:func:`contact_force`, on the
      windows), read on each solid's window and weighted by its owner share ``ws_n / sum_k
      ws_n`` there (the fractions of :func:`refmap.window_diagnostics.fields`, their sum over
      the solids one grid field by :func:`refmap.windows.accumulate`);
    * the gaps and overlaps: the nearest solid at every node by a scatter-min of all windows
      into a grid at ``phi_max h`` and its index by a scatter-min of the solid index where a
      window holds that least value (the lowest index wins a tie, as in
      :func:`_two_nearest`); the second-nearest by the same two passes with the nearest left
      out (as ``_contact_stress_windows`` does at the corners).  Then per pair the grid
      path's segment minimum and sum (:func:`_pair_tables`): an (N, N) table filled from
      grid arrays, O(N^2 + grid) and not O(N^2 grid); a pair whose windows share no node is
      never the two nearest at a node and keeps +inf and 0, as on the grid.  The least
      values are the windows' own, so the gaps and overlap areas are the grid's bit for bit.
      Where fewer than two windows hold a node the grid has ``phi_max h`` (outside the gap
      band, :func:`_on_windows`) for the missing ones: no pair counts there, on either;
    * the wall gaps: over each window's nodes (the grid's nodes outside it are at
      ``phi_max h``, outside the gap band)."""
    from refmap import window_diagnostics

    g = model.grid
    nd = g.ndim
    dA = g.cell_area if nd == 2 else g.cell_volume
    space = tuple(range(-nd, 0))
    N = model.n_solids
    h = model.h
    per = model.bc.periodic
    shape = g.shape()
    d = derived if derived is not None else model.derived(state, params)
    f = d.get("solid_windows")
    if f is None:
        f = window_diagnostics.fields(model, state)
    o, phi = f["origin"], f["phi"]
    W = tuple(phi.shape[1:])

    def at(field):  # every window's values of a grid field
        return windows.blocks(field, o, W, per)

    cf = contact_force(contact, model, state, params, d)
    ws = f["ws_n"]
    tot = at(windows.accumulate(jnp.zeros(shape, ws.dtype), ws, o, per))
    owner = jnp.where(tot > 1e-300, ws / jnp.where(tot > 1e-300, tot, 1.0), 0.0)

    def per_solid(field):  # (d, *grid) -> (N, d)
        return jnp.sum(owner[:, None] * at(field), axis=space) * dA

    out = {}
    out.update(_force_numbers(cf, per_solid, dA, space))
    L = gap_band * h
    far = jnp.asarray(model.numerics.phi_max * h, phi.dtype)
    gap = jnp.full((N, N), jnp.inf)
    area = jnp.zeros((N, N))
    if N >= 2:
        k = jnp.arange(N, dtype=jnp.int32).reshape((N,) + (1,) * nd)

        def least(vals, fill):
            return windows.accumulate(jnp.full(shape, fill, vals.dtype), vals, o, per, "min")

        def nearest(vals, skip=None):
            """(least value, its lowest solid index; N where no window holds the node)."""
            m = least(vals, far)
            pick = vals == at(m)
            if skip is not None:
                pick = pick & (k != at(skip))
            return m, least(jnp.where(pick, k, N), N)

        pa, a = nearest(phi)
        pb, b = nearest(jnp.where(k == at(a), far, phi), skip=a)
        # the indices _two_nearest gives where every solid is at phi_max h: 0 and 1
        a = jnp.where(a == N, 0, a)
        b = jnp.where(b == N, jnp.where(a == 0, 1, 0), b)
        gap, area = _pair_tables(a, b, pa, pb, N, L, dA)
    eye = jnp.eye(N, dtype=bool)
    out["min_gap"] = jnp.where(eye, jnp.nan, gap)
    out["overlap_area"] = jnp.where(eye, jnp.nan, area)
    near = jnp.abs(phi) < L
    X = f["X"]  # the windows' node coordinates, as wall_distances takes the grid's
    wg = jnp.full((N,), jnp.inf)
    for axis, periodic in enumerate(per):
        if periodic:
            continue
        lo, hi = g.lows[axis], g.highs[axis]
        for phi_w in (X[:, axis] - lo, hi - X[:, axis]):
            wg = jnp.minimum(wg, jnp.min(jnp.where(near, phi + phi_w, jnp.inf), axis=space))
    out["wall_gap"] = wg
    return out


# ----------------------------------------------------------------------------- benchmark
def _lattice_of_discs(N: int, law):
    from refmap.geometry import Disc
    from refmap.model import Solid

    m = int(math.ceil(math.sqrt(N)))
    pitch = 3.4 / m
    r = 0.38 * pitch
    out = []
    for k in range(N):
        i, j = divmod(k, m)
        c = (-1.7 + (i + 0.5) * pitch, -1.7 + (j + 0.5) * pitch)
        out.append(
            Solid(
                shape=Disc(center=c, radius=r),
                law=law,
                velocity=(0.1 * (-1) ** k, 0.0),
                name=f"disc{k}",
            )
        )
    return tuple(out)


def benchmark(
    counts=(1, 2, 4, 8, 32),
    n: int = 256,
    steps: int = 5,
    reps: int = 2,
    contact: Contact | None = None,
    compare: bool = True,
    verbose: bool = True,
    cpu_time: bool = True,
    numerics=None,
):
    """Wall-clock cost per step for N discs on a lattice in a closed n x n box.

    For each N in ``counts``: the whole step with contact (``step_ms``), the contact force
    alone (``contact_ms``, from given derived fields), the compile time of the stepping
    function and, with ``compare``, the same step without contact
    (``step_no_contact_ms``).  Times are the process's CPU time (``cpu_time=True``; run
    single-threaded, see benchmarks/bench_contact.py) or wall time.  Returns the rows as
    dicts; prints a table when ``verbose``.

    The discs sit on a lattice with gaps of 0.24 pitch (26 cells for N = 4 at 256^2, 9 for
    N = 32): the pair pressure is evaluated everywhere but is exactly zero, so the steps
    with and without contact do the same data-dependent work (the adaptive smoothing of
    the maps) and their difference is the cost of the contact term.  ``numerics`` (a
    :class:`refmap.state.Numerics`) replaces the defaults, e.g. ``fixed_smooth_sweeps=80``
    for the worst case of the map smoothing (every solid smoothed the full 80 sweeps).
    """
    from refmap.boundary import Boundary
    from refmap.grid import Grid
    from refmap.materials import NeoHookean
    from refmap.model import Model

    contact = contact if contact is not None else Contact()
    law = NeoHookean(G=10.0, kappa=10.0)

    # CPU time of this process, not wall time: on a shared machine the wall time of a
    # single-threaded run varies by factors of 2 with the other jobs, its CPU time does not
    clock = time.process_time if cpu_time else time.perf_counter

    def best_of(fn, *args):
        t0 = clock()
        jax.block_until_ready(fn(*args))
        first = clock() - t0
        best = math.inf
        for _ in range(reps):
            t0 = clock()
            jax.block_until_ready(fn(*args))
            best = min(best, clock() - t0)
        return first, best

    def step_cost(solids, forces):
        model = Model(Grid(n, n), solids, Boundary(), numerics=numerics, body_forces=forces)
        params = model.default_params(gravity=(0.0, -0.2))
        state = jax.jit(model.initial_state)(params)
        dt = model.time_step(state, params)[0]

        def run(s):
            return model.run_steps(s, params, steps, dt=dt)

        first, best = best_of(jax.jit(run), state)
        return model, params, state, best / steps * 1e3, first - best

    rows = []
    if verbose:
        what = "CPU time" if cpu_time else "wall time"
        print(f"backend {jax.default_backend()}, {n}x{n}, {steps} steps, best of {reps}, {what}")
        print(
            f"{'N':>4} {'step [ms]':>10} {'no contact':>11} {'contact [ms]':>13} {'compile [s]':>12}"
        )
    for N in counts:
        solids = _lattice_of_discs(N, law)
        model, params, state, step_ms, compile_s = step_cost(solids, (contact,))
        d = jax.jit(model.derived)(state, params)

        def force(s, d, model=model, params=params):
            return contact_force(contact, model, s, params, d)["force"]

        row = dict(n_solids=N, step_ms=step_ms, compile_s=compile_s)
        row["contact_ms"] = best_of(jax.jit(force), state, d)[1] * 1e3
        row["step_no_contact_ms"] = step_cost(solids, ())[3] if compare else math.nan
        rows.append(row)
        if verbose:
            print(
                f"{N:>4} {row['step_ms']:>10.2f} {row['step_no_contact_ms']:>11.2f} "
                f"{row['contact_ms']:>13.2f} {row['compile_s']:>12.1f}",
                flush=True,
            )
    return rows
