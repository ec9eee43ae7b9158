"""Solid-solid and solid-wall contact (thesis section 4.11): a repulsive body force.

Several solids share one velocity field.  Nothing in the single-velocity formulation lets
two bodies pass through each other, yet bodies pressed together do interpenetrate through
their *extrapolated* reference maps (thesis Fig. 4-29), and once they overlap no velocity
field can separate them again.  :class:`Contact` prevents the overlap with a narrow
repulsive body force centred on the mid-surface between two solids, usable as a
:class:`refmap.model.Model` body force::

    model = Model(grid, solids, boundary, numerics, body_forces=(Contact(),))

The force (all lengths in units of the grid spacing h)
------------------------------------------------------
For a pair (a, b), ``p = phi_a - phi_b`` vanishes on the mid-surface between the two
bodies (thesis eq. 4.32) and ``n = grad(p) / |grad(p)|`` is the unit normal of that
surface pointing from a towards b.  At a node on a's side (p < 0)

    f = -K G(p) [w_a - w_b] n,

* ``G(p) = max(exp(-(p / (width h))^2) - cutoff, 0) / (1 - cutoff)``: the truncated
  Gaussian of the thesis (eq. 4.33), 1 on the mid-surface, exactly 0 farther than
  ``width h sqrt(ln(1 / cutoff)) / 2`` from it (p is twice the distance to the mid-surface);
* ``w_k = max(ws_k - cutoff, 0)``: the solid fraction of body k at the node (the
  renormalised ``ws_n`` of :func:`refmap.model.solid_fractions`) less the cutoff, so that
  the force is exactly zero unless the mid-surface lies inside *both* bodies' blur zones
  (the thesis's "only acting where it overlaps the solids' blur zones");
* ``[w_a - w_b]``: the force is the push on each body's own material, ``-K G w_a n`` on
  a's fraction and ``+K G w_b n`` on b's, summed at the node.  On a's side w_a > w_b, so the
  net force points back into a; on the mid-surface the two materials are present in equal
  amounts and the net force is zero, so f is continuous and odd about the mid-surface
  (a localised contact pressure pushing the two bodies apart).  Its size grows as the gap
  closes: with half-gap s and distance y from the mid-surface,
  ``w_a - w_b ~ erf-difference ~ (2 y / (sqrt(pi) w_blur)) exp(-s^2 / w_blur^2)``.
* ``K = strength * M_max / h`` with ``M_max`` the largest small-strain longitudinal modulus
  of the solids (``law.moduli()``): a force density of M/h acting over a layer of about
  one cell gives a contact traction of order ``strength * M``, the stress at which the
  solid itself deforms by O(1); the same case therefore behaves the same at every
  resolution, and the added stiffness stays below the grid-scale elastic stiffness M/h^2
  that the time step already resolves (see ``docs/fssi.md``).

Equal and opposite.  The discrete force of a pair does not sum to zero exactly (the two
sides of a curved contact are sampled by different nodes), so each pair's net force F is
removed again with the weights ``W = G (w_a + w_b)``, localised at the contact:
``f <- f - W F / sum(W)``.  Every pair then exchanges momentum only with itself, to
round-off.

Many solids.  At each node only the nearest and the second-nearest solid (the two smallest
phi_k, by ``lax.top_k`` over the solid axis) form the pair: O(N) work per node, not
O(N^2).  A node where three bodies meet sees only its two nearest; the pair sums are
segment sums keyed by the pair index ``min(a, b) N + max(a, b)``.

Walls.  Each non-periodic domain edge is an obstacle whose distance ``phi_w`` is known
exactly.  A solid near it is treated as a pair with its own mirror image across the wall:
then ``p = -2 phi_w`` (the mid-surface is the wall) and the image's fraction is
``ws(phi_k + 2 phi_w)``.  The force acts on the solid only (the wall takes the reaction, so
momentum is not conserved there, as for any wall).  It is summed over all solids (O(N) per
node) and, by the cutoff, is exactly zero for a solid more than about four cells from
every wall.

Diagnostics.  :func:`contact_diagnostics` gives, per solid, the integrated contact force on
its side of each pair and the wall force; per pair (i < j) the minimum gap
``min(phi_i + phi_j)`` (for signed distances this is exactly the distance between the two
surfaces, and minus the overlap depth when they overlap) and the overlap area (nodes where
both phi_i and phi_j are negative, times the cell area).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erfc

from refmap.operators import div_node

__all__ = ["Contact", "contact_force", "contact_diagnostics", "benchmark"]


@dataclass(frozen=True)
class Contact:
    """Repulsive contact body force between solids and against domain walls.

    Parameters
    ----------
    width:
        Width of the Gaussian of ``phi_ij = phi_i - phi_j`` in units of h (default 1.5, the
        thesis's ``sqrt(dx / 16)`` at 128^2 is 1.41 h).  With the 0.01 cutoff the force acts
        within ``1.07 * width`` h of the mid-surface: about three node layers, enough that
        the force summed across the contact varies by < 1 % as the mid-surface moves
        through the grid, narrow enough to stay inside the blur zones.
    cutoff:
        Truncation level of the Gaussian and of the solid fractions (thesis: 0.01).
    strength:
        ``K = strength * M_max / h``; default 2.  Larger is stiffer (smaller equilibrium gap)
        but above about 8 the contact stiffness exceeds what the explicit step resolves.
    walls:
        Also push solids away from the non-periodic domain edges.
    """

    width: float = 3.0
    cutoff: float = 0.01
    strength: float = 1.0
    reach: float = 1.0
    walls: bool = True

    def __post_init__(self):
        for name in ("width", "strength"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"Contact {name} must be a finite number > 0, got {v!r}")
        if not (isinstance(self.cutoff, (int, float)) and 0.0 <= self.cutoff < 1.0):
            raise ValueError(f"Contact cutoff must be in [0, 1), got {self.cutoff!r}")

    def __call__(self, ctx):
        return contact_force(self, ctx["model"], ctx["state"], ctx["params"], ctx["derived"])["force"]

    def to_dict(self):
        return {"width": self.width, "cutoff": self.cutoff, "strength": self.strength, "walls": self.walls}


# ----------------------------------------------------------------------------- pieces
def _stiffness(contact: Contact, params):
    M_max = jnp.asarray(1e-30)
    for law in params.laws:
        M_max = jnp.maximum(M_max, law.moduli()[1])
    return contact.strength * M_max


def _kernel(p, width_h, cutoff):
    g = jnp.exp(-((p / width_h) ** 2))
    return jnp.maximum(g - cutoff, 0.0) / (1.0 - cutoff)


def _take(field, idx):
    """field (N, nx, ny), idx (nx, ny) -> field[idx[i, j], i, j]."""
    return jnp.take_along_axis(field, idx[None], axis=0)[0]


def _top2(phi):
    """Indices of the nearest (a) and second-nearest (b) solid at every node."""
    _, idx = jax.lax.top_k(-jnp.moveaxis(phi, 0, -1), 2)
    return idx[..., 0], idx[..., 1]


def _corner_gradient(fp, dx, dy):
    """Corner gradient of a node field padded with one ghost layer (4-node average)."""
    gx = 0.5 * ((fp[..., 1:, :-1] - fp[..., :-1, :-1]) + (fp[..., 1:, 1:] - fp[..., :-1, 1:])) / dx
    gy = 0.5 * ((fp[..., :-1, 1:] - fp[..., :-1, :-1]) + (fp[..., 1:, 1:] - fp[..., 1:, :-1])) / dy
    return gx, gy


def _presence(phi, contact, h):
    chi = 0.5 * erfc(phi / (contact.reach * h))
    c = contact.cutoff
    return jnp.maximum(chi - c, 0.0) / (1.0 - c)


def wall_distances(model, loc="corner"):
    """[(phi_w, inward normal (2,))] for every non-periodic domain edge, at ``loc`` points."""
    g = model.grid
    X, Y = g.mesh(loc)
    px, py = model.bc.periodic
    out = []
    if not px:
        out += [(X - g.ax, (1.0, 0.0)), (g.bx - X, (-1.0, 0.0))]
    if not py:
        out += [(Y - g.ay, (0.0, 1.0)), (g.by - Y, (0.0, -1.0))]
    return out


def contact_stress(contact: Contact, model, state, params, derived=None):
    """Contact stress at the corners and its parts.

    Returns a dict with the pair pressure ``Pi`` and wall pressure ``Pi_wall`` (nx+1, ny+1),
    the corner stress components ``sxx, sxy, syy``, and ``a``, ``b`` (nearest and second-
    nearest solid at each corner; None for fewer than two solids).
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
    Ks = _stiffness(contact, params)
    phic = d["phic"]
    if N >= 2:
        a, b = _top2(phic)
        pa, pb = _take(phic, a), _take(phic, b)
        phip = model.bc.pad_linear(state.phi)[..., 1:-1, 1:-1]
        gx, gy = _corner_gradient(phip, g.dx, g.dy)
        nx_ = _take(gx, a) - _take(gx, b)
        ny_ = _take(gy, a) - _take(gy, b)
        nn = nx_ * nx_ + ny_ * ny_
        inv = jnp.where(nn > 1e-12, 1.0 / jnp.where(nn > 1e-12, nn, 1.0), 0.0)
        Pi = Ks * _kernel(pa - pb, contact.width * h, contact.cutoff) * _presence(pa, contact, h) * _presence(pb, contact, h)
        # no pair pressure on the domain edge: every interior corner pushes its two
        # neighbouring nodes equally and oppositely, so each pair conserves momentum exactly
        edge = np.zeros(cshape, dtype=bool)
        edge[0, :] = edge[-1, :] = edge[:, 0] = edge[:, -1] = True
        Pi = jnp.where(jnp.asarray(edge), 0.0, Pi)
        q = Pi * inv
        out.update(Pi=Pi, a=a, b=b, pair=(-q * nx_ * nx_, -q * nx_ * ny_, -q * ny_ * ny_))
    if contact.walls:
        sxx = sxy = syy = Pw_total = z
        for phi_w, (wx, wy) in wall_distances(model, "corner"):
            phi_w = jnp.asarray(phi_w)
            pres = _presence(phic, contact, h) * _presence(phic + 2.0 * phi_w, contact, h)
            Pw = Ks * _kernel(-2.0 * phi_w, contact.width * h, contact.cutoff) * jnp.sum(pres, axis=0)
            sxx, sxy, syy = sxx - Pw * wx * wx, sxy - Pw * wx * wy, syy - Pw * wy * wy
            Pw_total = Pw_total + Pw
        out.update(Pi_wall=Pw_total, wall=(sxx, sxy, syy))
    return out


def contact_force(contact: Contact, model, state, params, derived=None):
    """Contact force density (2, nx, ny) = div(contact stress), with the stress parts."""
    cs = contact_stress(contact, model, state, params, derived)
    g = model.grid
    cs["pair_force"] = div_node(*cs["pair"], g.dx, g.dy)
    cs["wall_force"] = div_node(*cs["wall"], g.dx, g.dy)
    cs["force"] = cs["pair_force"] + cs["wall_force"]
    return cs


def contact_diagnostics(model, state, params, contact: Contact | None = None, gap_band: float = 6.0):
    """Contact numbers at one state (jit-able with ``model`` and ``contact`` static).

    Returns a dict of arrays:

    * ``force`` (N, 2): the integral of the contact force density over the nodes on each
      solid's side of its pairs (the nodes where it is the nearest solid), plus its wall
      force; ``pair_force`` (N, 2) and ``wall_force`` (N, 2) separately;
    * ``pair_net`` (N, N, 2): the net force of each pair (i <= j), zero to round-off;
    * ``min_gap`` (N, N): for i != j, ``min(phi_i + phi_j)`` over the nodes where both
      |phi| < ``gap_band`` h (where the level sets are signed distances and not clipped):
      the distance between the two surfaces, negative when they overlap (minus the overlap
      depth); +inf when the two bodies are farther apart than that band can see;
    * ``overlap_area`` (N, N): area of the nodes where phi_i < 0 and phi_j < 0;
    * ``wall_gap`` (N,): ``min(phi_k + phi_w)`` over the nodes and non-periodic walls
      (distance from solid k to the nearest wall, negative if it crossed it), +inf if none.
    """
    contact = contact if contact is not None else Contact()
    g = model.grid
    dA = g.cell_area
    N = model.n_solids
    h = model.h
    phi = state.phi
    cf = contact_force(contact, model, state, params)
    out = {}
    nearest = jnp.argmin(phi, axis=0).ravel()

    def per_solid(f):
        return jnp.stack([jax.ops.segment_sum(f[i].ravel(), nearest, num_segments=N) for i in range(2)], axis=-1) * dA

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
        a, b = _top2(phi)
        pa, pb = _take(phi, a), _take(phi, b)
        key = (jnp.minimum(a, b) * N + jnp.maximum(a, b)).ravel()
        ok = (jnp.abs(pa) < L) & (jnp.abs(pb) < L)
        gk = jax.ops.segment_min(jnp.where(ok, pa + pb, jnp.inf).ravel(), key, num_segments=N * N)
        ak = jax.ops.segment_sum(((pa < 0) & (pb < 0)).astype(phi.dtype).ravel(), key, num_segments=N * N) * dA
        gap = gk.reshape(N, N)
        area = ak.reshape(N, N)
        gap = jnp.minimum(gap, gap.T)
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


# ----------------------------------------------------------------------------- benchmark
def benchmark(counts=(1, 2, 4, 8, 32), n: int = 256, steps: int = 5, reps: int = 2, contact: Contact | None = None):
    """Wall-clock cost per step (ms) of the full step with contact, and of the contact
    force alone, for ``counts`` solids (small discs on a lattice) on an n x n grid.

    Returns a list of dicts (n_solids, step_ms, contact_ms, compile_s).
    """
    from refmap.boundary import Boundary
    from refmap.geometry import Disc
    from refmap.grid import Grid
    from refmap.materials import NeoHookean
    from refmap.model import Model, Solid

    contact = contact if contact is not None else Contact()
    rows = []
    for N in counts:
        m = int(np.ceil(np.sqrt(N)))
        r = 0.35 * 3.2 / m
        solids = []
        for k in range(N):
            i, j = divmod(k, m)
            cx = -1.6 + (i + 0.5) * 3.2 / m
            cy = -1.6 + (j + 0.5) * 3.2 / m
            solids.append(Solid(shape=Disc(center=(cx, cy), radius=r), law=NeoHookean(G=10.0, kappa=10.0),
                                name=f"disc{k}"))
        model = Model(Grid(n, n), tuple(solids), Boundary(), body_forces=(contact,))
        params = model.default_params(gravity=(0.0, -0.2))
        state = model.initial_state(params)
        dt = model.time_step(state, params)[0]
        run = jax.jit(lambda s, model=model, params=params: model.run_steps(s, params, steps, dt=dt))
        t0 = time.perf_counter()
        jax.block_until_ready(run(state))
        comp = time.perf_counter() - t0
        best = np.inf
        for _ in range(reps):
            t0 = time.perf_counter()
            jax.block_until_ready(run(state))
            best = min(best, time.perf_counter() - t0)
        d = jax.jit(model.derived)(state, params)

        def cfo(s, d, model=model, params=params):
            return contact_force(contact, model, s, params, d)["force"]

        cf = jax.jit(cfo)
        jax.block_until_ready(cf(state, d))
        bc = np.inf
        for _ in range(max(reps, 3)):
            t0 = time.perf_counter()
            jax.block_until_ready(cf(state, d))
            bc = min(bc, time.perf_counter() - t0)
        rows.append(dict(n_solids=N, step_ms=best / steps * 1e3, contact_ms=bc * 1e3, compile_s=comp))
    return rows
