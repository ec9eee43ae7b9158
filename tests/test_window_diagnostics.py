"""Diagnostics and frame arrays of solids stored in windows (docs/design_windows.md, landing
3b; refmap.window_diagnostics): every per-solid and per-pair number from the solids' windows,
equal to the whole grid's (``Model.on_grid`` and the grid path) to round-off, with discs
across a periodic edge and corner, next to walls, a pair pressed into each other (contact
gaps, overlaps and forces), the windows placed off their bodies' centres; and no array of
every solid's field on the whole grid in the traced computation."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap import window_diagnostics, windows
from refmap.boundary import Boundary
from refmap.contact import Contact
from refmap.geometry import Disc
from refmap.grid import Grid
from refmap.materials import NeoHookean
from refmap.model import Model, Solid
from refmap.state import Numerics

PERIODIC = Boundary(left="periodic", right="periodic", bottom="periodic", top="periodic")

CASES = {
    # a disc across the x edge, one across the corner, a pair pressed 2.4 cells into each
    # other (h = 1/24), each moving
    "periodic": (PERIODIC, [((1.9, 0.2), (0.4, 0.0)), ((-1.95, -1.9), (0.0, -0.3)),
                            ((-0.25, 0.9), (0.5, 0.0)), ((0.25, 0.9), (-0.5, 0.0))]),
    # walls: a disc 3.6 cells from the left wall (its window at the wall), one 1.4 cells
    # from the bottom (2.9 cells from its mirror image: the wall contact pushes), neither
    # glued; a pair pressed 2.4 cells into each other
    "walls": (Boundary(), [((-1.55, 0.0), (-0.5, 0.0)), ((0.5, -1.64), (0.0, -0.5)),
                           ((0.3, 0.6), (0.5, 0.0)), ((0.8, 0.6), (-0.5, 0.0))]),
}


def _model(boundary, discs, n=96, body_forces=(Contact(),)):
    solids = tuple(
        Solid(shape=Disc(center=c, radius=0.3), law=NeoHookean(G=10.0, kappa=10.0, rho0=1.0 + 0.3 * k),
              velocity=v, name=f"d{k}")
        for k, (c, v) in enumerate(discs)
    )
    return Model(Grid(n, n), solids, boundary, Numerics(solid_storage="window"), body_forces=body_forces)


def _strained(m, s, moves=None):
    """``s`` with a smooth shear and stretch added to every map (a strained body, ``J != 1``),
    its windows cut again at ``origin + moves`` (``(S, d)`` nodes; a window at a wall
    stays there): a body off its window's centre, as after it travelled, and a window whose
    nodes the old one did not hold (far and the identity map there, as ``on_grid`` has
    them).  Checked to be a state the step could make: a window's edge nodes are far
    from its body, except at a wall."""
    g = m.on_grid(s)
    X, Y = (jnp.asarray(a) for a in m.grid.mesh("node"))
    q = jnp.pi / 2
    g = g.replace(xi=g.xi + jnp.stack([0.04 * jnp.sin(q * Y) * jnp.cos(q * X), 0.03 * jnp.sin(q * X)])[None])
    W, shape, per = m.state_window, m.grid.shape(), m.bc.periodic
    o = np.asarray(s.origin)
    if moves is not None:
        o = o + np.asarray(moves)
        for a, p in enumerate(per):
            at_wall = (np.asarray(s.origin)[:, a] == 0) | (np.asarray(s.origin)[:, a] == shape[a] - W[a])
            o[:, a] = o[:, a] % shape[a] if p else np.where(at_wall, np.asarray(s.origin)[:, a], o[:, a])
    o = jnp.asarray(o, jnp.int32)
    cut = jax.vmap(lambda f, oo: windows.gather(f, oo, W, per))
    out = g.replace(xi=cut(g.xi, o), phi=cut(g.phi, o), origin=o)
    far = m.numerics.phi_max * m.h
    for k in range(m.n_solids):
        for a, p in enumerate(per):
            for end, side in ((0, 0), (W[a] - 1, shape[a] - W[a])):
                if p or int(o[k, a]) != side:
                    assert np.all(np.take(np.asarray(out.phi[k]), end, axis=a) == far), (k, a, end)
    return out


def _leaves(tree):
    """``{path: value}`` of a diagnostics dict (scalars, ``solids`` rows, ``pairs``) and
    the group of each path: the last key without its component (``centroid_x`` and
    ``centroid_y`` are one group, ``contact_fx`` and ``contact_fy`` another), whose largest
    value is the scale of its round-off."""
    out = {}
    if "solids" in tree:  # windowed: the rows held as columns (SolidRows); compare per solid
        tree = dict(tree, solids=[dict(row) for row in tree["solids"]])
    for path, v in jax.tree_util.tree_flatten_with_path(tree)[0]:
        key = path[-1].key if hasattr(path[-1], "key") else str(path[-1])
        group = key[:-1] if key[-2:] in ("_x", "_y", "_z", "fx", "fy", "fz") else key
        out[jax.tree_util.keystr(path)] = (group, np.asarray(v, dtype=np.float64))
    return out


def _arrays(frame):
    """Frame arrays in the form of :func:`_leaves`, each array its own group."""
    return {k: (k, np.asarray(v, dtype=np.float64)) for k, v in frame.items()}


def _compare(got, ref, rtol):
    """``got`` equal to ``ref`` (dicts of arrays or :func:`_leaves`): the same entries, the
    same non-finite values, the finite ones within ``rtol`` of their group's scale (the
    largest magnitude of the group in ``ref``); returns the largest difference relative
    to that scale and its entry."""
    assert got.keys() == ref.keys()
    scale = {}
    for group, r in ref.values():
        fin = r[np.isfinite(r)]
        scale[group] = max(scale.get(group, 0.0), float(np.max(np.abs(fin))) if fin.size else 0.0)
    worst = (0.0, None)
    for key, (group, r) in ref.items():
        g = got[key][1]
        assert g.shape == r.shape, key
        fin = np.isfinite(r)
        np.testing.assert_array_equal(np.isfinite(g), fin, err_msg=key)
        np.testing.assert_array_equal(g[~fin], r[~fin], err_msg=key)
        err = float(np.max(np.abs(g[fin] - r[fin]), initial=0.0))
        s = scale[group]
        assert err <= rtol * s, f"{key}: {err:.3g} against the scale {s:.3g}"
        worst = max(worst, (err / s if s > 0 else 0.0, key), key=lambda w: w[0])
    return worst


@functools.cache
def _case(name):
    boundary, discs = CASES[name]
    m = _model(boundary, discs)
    params = m.default_params()
    s = jax.jit(m.initial_state)(params)
    moves = [(2, -1), (-1, 2), (1, 1), (-2, 0)]
    return m, params, _strained(m, s, moves)


def _both(m, params, s):
    """Diagnostics and frame arrays of the windowed state and of its whole-grid form (the
    grid path), in one compilation."""
    def run(s):
        g = m.on_grid(s)
        return ((m.diagnostics(s, params), m.frame_arrays(s, params)),
                (m.diagnostics(g, params), m.frame_arrays(g, params)))

    return jax.device_get(jax.jit(run)(s))


# measured, as a fraction of each group's scale: 1.1e-14 at most with periodic edges (J_min
# and J_max of the discs across an edge, as strained or after 3 steps: their maps are made
# continuous in the window as (xi - x) + x unwrapped, whose round-off, ~eps |x + L| / h,
# enters F), 4e-16 at walls (the contact forces); sums otherwise differ in their order
# only, and the gaps, overlap areas and wall gaps are the windows' own values, bit for bit
# the grid's
RTOL = 1e-12


@pytest.mark.parametrize("name", sorted(CASES))
def test_diagnostics_on_windows_equal_the_grid(name):
    """``Model.diagnostics`` and ``frame_arrays`` of a windowed state (from the windows, no
    solid on the whole grid) equal those of ``on_grid(state)`` (the grid path) to
    round-off: the scalars, each solid's area, centroid (a body across a periodic edge and
    corner unwrapped), velocity, J range and elastic energy (the corners of a periodic edge
    counted twice, as the whole grid's corner arrays hold them), the contact forces, pair
    gaps and overlaps and wall gaps."""
    m, params, s = _case(name)
    (dw, fw), (dg, fg) = _both(m, params, s)
    assert window_diagnostics.applies(m) and m.windowed(s)
    worst = max(_compare(_leaves(dw), _leaves(dg), RTOL), _compare(_arrays(fw), _arrays(fg), RTOL),
                key=lambda w: w[0])
    assert set(fw) == set(m.frame_array_dims())
    # the cases test what they claim: strained, moving bodies; the pair pressed together
    # (a negative gap, an overlap, opposite contact forces); a wall within reach
    rows = dg["solids"]
    assert all(r["J_max"] - r["J_min"] > 1e-3 for r in rows)
    assert all(abs(r["velocity_x"]) + abs(r["velocity_y"]) > 0.1 for r in rows)
    assert dg["pairs"]["2_3"]["min_gap"] < 0 < dg["pairs"]["2_3"]["overlap_area"]
    assert rows[2]["contact_fx"] < -0.1 and rows[3]["contact_fx"] > 0.1
    assert dg["contact_pairs"] == 1 and np.isinf(dg["pairs"]["0_1"]["min_gap"])
    if name == "periodic":  # the centroids of the bodies cut by the edge, unwrapped
        np.testing.assert_allclose([rows[0]["centroid_x"], rows[1]["centroid_y"]], [1.9, -1.9], atol=0.01)
        np.testing.assert_allclose(rows[1]["centroid_x"], -1.95, atol=0.01)
    else:
        assert np.isfinite(dg["contact_min_wall_gap"]) and dg["contact_max_wall_pressure"] > 0
    print(f"{name}: largest difference {worst[0]:.2g} of its scale, {worst[1]}")


def test_diagnostics_on_windows_after_steps():
    """A few steps from strained discs across a periodic edge and corner (no body force):
    the windows' numbers still equal the grid's."""
    boundary, discs = CASES["periodic"]
    m = _model(boundary, [discs[0], discs[1], ((0.1, 0.3), (0.0, 0.2))], body_forces=())
    params = m.default_params()
    s = _strained(m, jax.jit(m.initial_state)(params))
    s = jax.jit(lambda s: m.run_steps(s, params, 3))(s)
    (dw, fw), (dg, fg) = _both(m, params, s)
    worst = max(_compare(_leaves(dw), _leaves(dg), RTOL), _compare(_arrays(fw), _arrays(fg), RTOL),
                key=lambda w: w[0])
    print(f"after steps: largest difference {worst[0]:.2g} of its scale, {worst[1]}")
    assert dg["elastic_energy"] > 0 and all(r["J_max"] - r["J_min"] > 1e-3 for r in dg["solids"])


def _shapes(jaxpr):
    """Every value's shape in a jaxpr and the jaxprs inside it (loops, conditionals, calls)."""
    out = []
    for v in list(jaxpr.invars) + list(jaxpr.constvars):
        out.append(tuple(v.aval.shape))
    for eqn in jaxpr.eqns:
        out += [tuple(v.aval.shape) for v in eqn.outvars]
        for p in eqn.params.values():
            for sub in p if isinstance(p, (tuple, list)) else (p,):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    out += _shapes(inner)
    return out


@pytest.mark.parametrize("name", sorted(CASES))
def test_no_solid_field_on_the_whole_grid(name):
    """With the solids in windows, the traced diagnostics and frame arrays hold no array of
    every solid's field on the whole grid: no value of shape ``(S, ..., *grid)`` with the
    grid's node or corner counts (or padded by up to two ghost layers a side) along the
    last axes.  Five solids (no other axis of that length: 1, 2, 3 or 6 stress components,
    2 axes, 4 corners round a node) so that the check is unambiguous; the grid path of
    the same state forms such arrays (the check sees them).  Traced only, not compiled."""
    boundary, discs = CASES[name]
    five = discs + [((-1.0, 1.2), (0.0, 0.0))]
    m = _model(boundary, five)
    params = m.default_params()
    S, grid = len(five), m.grid.shape()
    state = jax.eval_shape(m.initial_state, params)
    assert state.phi.shape == (S, *m.state_window)

    def per_solid_grid(shape):
        nd = len(grid)
        return (len(shape) > nd and S in shape[:-nd]
                and all(0 <= a - n <= 4 for a, n in zip(shape[-nd:], grid, strict=True)))

    def found(fn):
        return sorted({sh for sh in _shapes(jax.make_jaxpr(fn)(state).jaxpr) if per_solid_grid(sh)})

    assert found(lambda s: (m.diagnostics(s, params), m.frame_arrays(s, params))) == []
    assert (S, *grid) in found(lambda s: m.diagnostics(m.on_grid(s), params))
