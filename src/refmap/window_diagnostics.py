"""Per-solid diagnostics of solids stored in windows (docs/design_windows.md, landing 3b).

With ``Numerics(solid_storage = "window")`` each solid's map and level set live in a window
that follows its body (``State.xi`` ``(S, d, *W)``, ``State.phi`` ``(S, *W)``,
``State.origin``).  :meth:`refmap.model.Model.diagnostics` and ``frame_arrays`` used to
rebuild every solid on the whole grid first (:meth:`refmap.model.Model.on_grid`) and to take
each solid's fractions, deformation gradient and Jacobian there: ``S`` whole-grid arrays
per field, 8 GB each for 1000 discs at 1024^2.  Here every per-solid number comes from the
solid's own window, one traced computation for all solids (``vmap`` over the windows):

* the node fractions ``ws_n`` and corner fractions ``ws_c`` of :func:`refmap.model.solid_fractions`:
  the solid's ``1 - H`` on its window, renormalised by the sum over all solids, that sum
  a single grid field (:func:`refmap.windows.accumulate`) read back on each window
  (:func:`refmap.windows.blocks`), as :func:`refmap.solid_tiles.mixed_from_windows` mixes the
  stress;
* ``F``, ``J`` and where the stress is taken (``valid``) at the window's corners ``origin ..
  origin + W`` from the map with one linear ghost layer (:meth:`refmap.model.Model._window_maps`,
  continuous across a periodic edge), the arithmetic of ``Model._solids_full``;
* area, mean velocity (the grid velocity read on the window), centroid (the node
  coordinates of the window unwrapped by ``phi0``'s periodic shift, as
  :meth:`refmap.model.Model._centroid`), ``J`` range over the corners inside the solid and
  elastic energy ``sum ws_c psi(F) / J dA`` where the stress is taken.

Why these are the whole grid's numbers.  :meth:`~refmap.model.Model.on_grid` puts
``phi = phi_max h`` and the identity map outside a solid's window; there its fraction
``1 - H`` is exactly 0 (:func:`applies` checks it: the erf kernel rounds to 1 beyond
``5.92 w``, so at ``phi_max = 12`` cells with the default blur of 2), so the whole grid's
sums over those nodes and corners add exact zeros, and no corner there is inside the
solid.  The windows keep a margin round the band, so their edge nodes are at ``phi_max h``
too and their linear ghosts (:func:`refmap.windows.ghosted`) equal the grid's values; at a
wall they are the grid's ``pad_linear`` and ``pad_affine`` ghosts.  The numbers differ from
the grid's only by the order of the additions (and ``(xi - x) + x`` on a periodic grid):
round-off (tests/test_window_diagnostics.py).

A window's corners are read with their indices wrapped round a periodic axis, so each
corner of the grid is counted once; the whole grid's sum leaves out corner ``n`` of a
periodic axis, the copy of corner 0 (until 2026-12-07 it counted it, so the elastic energy
of a body across a periodic edge was counted twice along the edge: 8 % too high for a disc
across the x edge at 96^2).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from refmap import blend, windows
from refmap.materials import law_groups
from refmap.operators import corner_average, grad_corner


def applies(model) -> bool:
    """Whether a solid's fraction ``1 - H`` is exactly 0 at ``phi = phi_max h`` (the value
    :meth:`refmap.model.Model.on_grid` gives a solid outside its window): then the
    whole grid's per-solid sums and extrema are those over the windows.  False for a blend
    that reaches past ``phi_max h`` (a wide blur or a small ``phi_max``); the callers then
    take the whole-grid fields, as before."""
    n = model.numerics
    with jax.ensure_compile_time_eval():
        far = 1.0 - blend.heaviside(jnp.asarray(n.phi_max * model.h), n.blend, n.blur_width * model.h)
    return float(far) == 0.0


#: Solids whose corner fields (``F``, ``J``, the strain energy and their intermediates)
#: are formed at once in :func:`fields`: a thousand windows of 62^2 corners at once held
#: about 1 GB of temporaries (``lax.map`` in batches of this size instead).
SOLID_BATCH = 64


def fields(model, state, laws=None):
    """Every solid's fields on its window (``state`` windowed): a dict of

    * ``origin`` (S, d): the windows' first nodes (an outgrown window, origin -1, read at 0);
    * ``phi`` (S, *W): the level sets, NaN in a window its body outgrew (as ``on_grid``);
    * ``X`` (S, d, *W): the node coordinates of each window (wrapped round a periodic axis);
    * ``ws_n`` (S, *W): the node fractions of :func:`refmap.model.solid_fractions`;
    * ``phic``, ``ws_c``, ``J``, ``valid`` (S, *(W + 1)): at the corners ``origin .. origin +
      W`` (those round the window's nodes), as ``Model._solids_full`` makes them on the
      whole grid;
    * with ``laws`` (one per solid): ``elastic_energy`` (S,), ``sum ws_c psi(F) / J dA``
      over the corners where the stress is taken.

    ``F``, ``J`` and the strain energy are made :data:`SOLID_BATCH` solids at a time
    (``lax.map``), so their temporaries do not grow with the number of solids; the values
    are those of the whole batch at once (the same arithmetic per corner)."""
    from refmap.model import _det_adjugate

    g = model.grid
    nd = model.ndim
    n = model.numerics
    h = model.h
    per = model.bc.periodic
    shape = g.shape()
    W = tuple(state.phi.shape[1:])
    C = tuple(w + 1 for w in W)
    ok = jnp.all(state.origin >= 0, axis=1)
    o = jnp.maximum(state.origin, 0)
    phi = jnp.where(ok.reshape((-1,) + (1,) * nd), state.phi, jnp.nan)
    width = n.blur_width * h

    # node fractions: 1 - H renormalised by the sum over the solids where it passes 1
    wn = 1.0 - blend.heaviside(phi, n.blend, width)
    Tn = windows.blocks(windows.accumulate(jnp.zeros(shape, phi.dtype), wn, o, per), o, W, per)
    ws_n = wn * (1.0 / jnp.maximum(Tn, 1.0))

    # corners origin .. origin + W from the nodes origin - 1 .. origin + W (one ghost layer);
    # their sum over the solids on a grid of n corners along a periodic axis (corner n is
    # corner 0 there) and n + 1 along a walled one
    phic = corner_average(jax.vmap(lambda p: windows.ghosted(p, 1, 1, nd))(phi), nd)
    wc = 1.0 - blend.heaviside(phic, n.blend, width)
    base = tuple(m if p else m + 1 for m, p in zip(shape, per, strict=True))
    Tc = windows.blocks(windows.accumulate(jnp.zeros(base, phi.dtype), wc, o, per), o, C, per)
    ws_c = wc * (1.0 / jnp.maximum(Tc, 1.0))
    dA = g.cell_area if nd == 2 else g.cell_volume

    def corners(law, xi_k, o_k, phic_k, wsc_k):
        """One solid's ``J``, ``valid`` (and strain energy with a law) at its corners."""
        xig = model._window_maps(xi_k, o_k, 1, 1)
        dxi = [grad_corner(xig[a], *model.spacing) for a in range(nd)]  # dxi[a][b] = d xi_a / d x_b
        det, adj = _det_adjugate(dxi)
        valid = (phic_k < n.stress_band * h) & (det > 1e-12)
        safe_det = jnp.where(valid, det, 1.0)
        J = jnp.where(valid, 1.0 / safe_det, 1.0)
        if law is None:
            return J, valid
        F = adj / safe_det[..., None, None]
        F = jnp.where(valid[..., None, None], F, jnp.eye(nd))
        psi = _psi(law, F, nd)
        return J, valid, jnp.sum(jnp.where(valid, wsc_k * psi / J, 0.0)) * dA

    out = _by_law(corners, laws, state.xi, o, phic, ws_c)
    X = jax.vmap(lambda oo: windows.coordinates(oo, W, g.lows, model.spacing, shape, per))(o)
    f = dict(origin=o, phi=phi, X=X, ws_n=ws_n, phic=phic, ws_c=ws_c, J=out[0], valid=out[1])
    if laws is not None:
        f["elastic_energy"] = out[2]
    return f


def _by_law(fn, laws, *per_solid):
    """``fn(law, *(a[k] for a in per_solid))`` for every solid k (``law`` None when ``laws``
    is), stacked along a new first axis, :data:`SOLID_BATCH` solids at a time
    (``lax.map``): the solids grouped by law class and pytree structure, each group's laws
    stacked into one pytree (:func:`refmap.materials.law_groups`), one traced code path
    per group whatever the number of solids."""
    S = per_solid[0].shape[0]
    if laws is None:
        groups = [(list(range(S)), None)]
    else:
        if len(laws) != S:
            raise ValueError(f"{len(laws)} laws for {S} solids")
        groups = law_groups(laws)
    parts, order = [], []
    for members, stacked in groups:
        whole = len(members) == S
        args = tuple(a if whole else a[np.asarray(members)] for a in per_solid)
        if stacked is None:
            res = lax.map(lambda xs: fn(None, *xs), args, batch_size=SOLID_BATCH)
        else:
            res = lax.map(lambda xs: fn(xs[0], *xs[1:]), (stacked,) + args, batch_size=SOLID_BATCH)
        parts.append(res)
        order += members
    if len(parts) == 1:
        return parts[0]
    inv = np.argsort(np.asarray(order))
    return tuple(jnp.concatenate(cols, axis=0)[inv] for cols in zip(*parts, strict=True))


def solid_numbers(model, state, params, f=None):
    """The per-solid numbers of :meth:`refmap.model.Model.diagnostics` from the windows
    (``f``: :func:`fields` with the laws, made here when None), as arrays over the solids:
    ``area`` (S,) (the d-dimensional measure), ``centroid`` and ``velocity`` (S, d),
    ``J_min``, ``J_max`` and ``elastic_energy`` (S,)."""
    if f is None or "elastic_energy" not in f:
        f = fields(model, state, params.laws)
    g = model.grid
    nd = model.ndim
    dA = g.cell_area if nd == 2 else g.cell_volume
    space = tuple(range(-nd, 0))
    ws = f["ws_n"]
    total = jnp.sum(ws, axis=space)
    area = total * dA

    # centroid: each node unwrapped by the period phi0 finds between its material and the
    # reference shape (Model._centroid), the weighted mean reduced back into the box
    shift = model._phi0_all(state.xi, return_shift=True)[1]
    cen = []
    for c, (a, b) in enumerate(zip(g.lows, g.highs, strict=True)):
        mean = jnp.sum(ws * (f["X"][:, c] + shift[:, c]), axis=space) / total
        if model.bc.periodic[c]:
            mean = a + jnp.mod(mean - a, b - a)
        cen.append(mean)
    v = windows.blocks(state.v, f["origin"], tuple(ws.shape[1:]), model.bc.periodic)  # (S, d, *W)
    vel = [jnp.sum(ws * v[:, c], axis=space) / total for c in range(nd)]

    inside = f["phic"] < 0
    J = f["J"]
    return dict(
        area=area,
        centroid=jnp.stack(cen, axis=-1),
        velocity=jnp.stack(vel, axis=-1),
        J_min=jnp.min(jnp.where(inside, J, jnp.inf), axis=space),
        J_max=jnp.max(jnp.where(inside, J, -jnp.inf), axis=space),
        elastic_energy=f["elastic_energy"],
    )


@jax.tree_util.register_pytree_node_class
class SolidRows:
    """The per-solid numbers of ``Model.diagnostics`` (``out["solids"]``) held as columns:
    one ``(S,)`` array per name, read as a list of per-solid dicts (``len``, indexing and
    iteration give ``{name: value}`` of one solid).  A pytree of its columns, so that a
    jitted diagnostics returns a dozen arrays, not a dozen scalars per solid: with 1000
    solids the 13 000 outputs of the list took minutes to compile."""

    def __init__(self, columns: dict):
        self.columns = dict(columns)

    def tree_flatten(self):
        keys = tuple(self.columns)
        return tuple(self.columns[k] for k in keys), keys

    @classmethod
    def tree_unflatten(cls, keys, children):
        return cls(dict(zip(keys, children, strict=True)))

    def __len__(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def __getitem__(self, k: int) -> dict:
        if not -len(self) <= k < len(self):
            raise IndexError(f"solid {k} of {len(self)}")
        return {name: col[k] for name, col in self.columns.items()}

    def __iter__(self):
        return (self[k] for k in range(len(self)))

    def merged(self, extra) -> SolidRows:
        """These columns and those of ``extra`` (a :class:`SolidRows` or a list of per-solid
        dicts, as body-force terms give), the latter after."""
        more = extra.columns if isinstance(extra, SolidRows) else {
            name: jnp.stack([row[name] for row in extra]) for name in (extra[0] if extra else {})}
        return SolidRows({**self.columns, **more})


def rows(model, numbers) -> SolidRows:
    """:func:`solid_numbers` as the per-solid rows of ``Model.diagnostics`` (``area``,
    ``centroid_x`` .., ``velocity_x`` .., ``J_min``, ``J_max``, ``elastic_energy``, in
    that order), held as columns (:class:`SolidRows`)."""
    axes = "xyz"[: model.ndim]
    cols = {"area": numbers["area"]}
    for c, name in enumerate(axes):
        cols["centroid_" + name] = numbers["centroid"][:, c]
    for c, name in enumerate(axes):
        cols["velocity_" + name] = numbers["velocity"][:, c]
    for key in ("J_min", "J_max", "elastic_energy"):
        cols[key] = numbers[key]
    return SolidRows(cols)


def _psi(law, F, nd: int):
    """The strain-energy density ``psi(F)`` over a window's corners (``F`` (*corners, d,
    d)): ``law.psi`` with one ``vmap`` per axis, as ``Model.diagnostics`` takes it on the
    grid."""
    fn = law.psi
    for _ in range(nd):
        fn = jax.vmap(fn)
    return fn(F)


__all__ = ["applies", "fields", "rows", "solid_numbers"]
