"""The blurred-interface RMT step (thesis chapter 4, Algorithm 1) for N solids.

:class:`Model` holds the static description of a case (grid, solids' shapes and anchors,
edge conditions, numerics); :meth:`Model.step` is a pure function
``(State, Params) -> (State, StepInfo)`` and :meth:`Model.advance` runs it inside
``lax.while_loop`` up to a target time.  One step:

1. ENO advection of every reference map (inside each solid and its band);
2. blend weights H_k = H(phi_k) on nodes and corners (:mod:`refmap.blend`: the thesis's
   (1 + erf(phi_k / (w h))) / 2 by default);
3. solid stress sigma_k = law_k(F), F = (grad xi_k)^-1, at corners where xi_k is defined;
4. fluid pressure lambda_f (rho_f / rho0 - 1) everywhere;
5. fluid viscous stress; mixing sigma = w_f sigma_f + sum_k (1 - H_k) sigma_k and likewise
   the density (fluid fraction w_f = 1 - sum_k (1 - H_k), see :func:`solid_fractions`);
6. velocity update (ENO advection, div(sigma) / rho, extra viscosity, body forces,
   gravity) and fluid-density update (ENO advection and -rho div v);
7. apply the updates;
8. edge conditions (ghost nodes, next step) and anchors;
9. pin each level set to phi0_k(xi_k), extrapolate xi_k into the band and smooth the
   extrapolated values.

With ``Numerics.viscosity = "implicit"`` the viscous terms of step 6 are taken by backward
Euler (:mod:`refmap.viscosity`) and the transported fields (fluid density, reference maps)
are advanced with the updated velocity; the explicit default is unchanged bit for bit.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from refmap import blend, extrapolation, geometry, levelset, narrowband, solid_tiles, windows
from refmap.boundary import AXIS_FACES, Boundary, BoundaryConditions
from refmap.grid import Grid
from refmap.materials import law_groups, law_moduli, map_laws
from refmap.operators import (
    SYM_COMPONENTS,
    SYM_PAIRS,
    advect,
    advect_lowmem,
    corner_average,
    div_node,
    divergence_centered,
    grad_corner,
    laplacian,
    laplacian_lowmem,
    node_average,
)
from refmap.projection import Projection, resolve_preconditioner
from refmap.state import FluidParams, Numerics, Params, State
from refmap.viscosity import ImplicitViscosity

# band_sweeps = "auto": sweep the band on tiles only when its listed tiles (the capacity) are
# at most this fraction of the grid's, in 2D and 3D alike (one core, 80 smoothing sweeps,
# docs/benchmarks.md).  2D, with the leaner tile sweeps: at a capacity of 50 % of the tiles
# the whole step is 1.8x (two_balls 128^2) and 2.3x (rotor 256^2) faster on tiles; at 100 %
# (rotor 128^2) 0.92x.  3D (8^3 tiles): the band operator on tiles beat the full grid 1.9x
# at 70 % (sphere_relax 48^3) and was even at 100 % (spheres_settle 32^3).  (2D used 0.35,
# set from the first, slower tile sweeps.)
BAND_TILE_FRACTION = 0.75
# a first, tighter band capacity (this times the tiles at t = 0, plus 8) tried before
# Numerics.band_capacity's: the band work is proportional to the capacity
BAND_TIGHT = 1.25
# 3D, where the band is not tiled: sweep each band in a box (Model._initial_band_window)
# only when the box is at most this fraction of the grid (the box's cut and write-back cost
# a little)
BAND_WINDOW_FRACTION = 0.6
# nodes added to the band box's extent at t = 0 for the window's size (the window follows
# the body; the slack is for its deformation, beyond which the step sweeps the full grid)
BAND_WINDOW_SLACK = 8
# band_sweeps = "auto": compute each solid's stress, blend weights and density on the tiles
# that hold it (refmap.solid_tiles) only when its listed tiles are at most this fraction of
# the grid's (a tile's window of T + 2 nodes a side and the sum into the grid cost more per
# node than the full-grid computation; docs/benchmarks.md, "Solids' stress on tiles")
SOLID_TILE_FRACTION = 0.5
#: nodes a side of the tiles on which the extension and smoothing sweep a band window
#: (``Numerics.solid_storage = "window"``): 3 in 2D, where a band of 6 cells round a small
#: body covers far fewer of them than of the grid's 8-node tiles (100 discs at 300^2, 80
#: smoothing sweeps, all at once: 167 against 239 ms with 4 x 4 tiles, the same values bit
#: for bit; whole steps with the band work one solid at a time: 223 ms on 3 x 3 tiles, 226
#: on 2 x 2, 236 on 4 x 4, 279 on 8 x 8; 16 larger discs: 99 against 102 ms on 4 x 4);
#: 3D keeps the grid's size (a 4^3 tile with its halo reads 3.4 times its nodes)
WINDOW_TILE_TARGET = {2: 3, 3: extrapolation.TILE_TARGET[3]}

#: ``Numerics.blur_mass = "corners"``: a node is given the mass of its most solid corner
#: where that corner's solid fraction is more than this many times the node's own (the
#: outer blur, where the node's corners' stress acts on a node of little mass)
BLUR_MASS_RATIO = 4.0

#: solids worked on together in the windowed band work (``"band"``:
#: ``Model._band_on_state_windows``) and stress mixing (``"mix"``:
#: ``Model._mixed_on_state_windows``), by JAX backend; more are worked on in equal batches
#: of at most this many, one after the other.  On a CPU the band work goes one solid at a
#: time: its tile arrays then stay in the core's L1/L2 caches (100 discs at 300^2, 80
#: sweeps, one core: 230 ms per step one at a time, 279 in batches of 16, 321 all at once;
#: 1000 discs at 1024^2: 3.23 against 3.60 s; the same values bit for bit;
#: docs/benchmarks.md).  The mixing goes in batches of 4 there (216 against 224 ms in
#: batches of 16; one at a time changes its sums in the last bit).  A GPU needs many solids at
#: once to fill it: batches of ``"other"`` there (not measured on a GPU yet), which still
#: bounds the sweeps' temporaries (1000 discs at 1024^2: about 1 GB all at once).
SOLID_BATCH = {"band": {"cpu": 1, "other": 1024}, "mix": {"cpu": 4, "other": 1024}}


def solid_batch(work: str) -> int:
    """The number of solids :class:`Model` works on together in its windowed ``work``
    (``"band"`` or ``"mix"``): the backend's entry of :data:`SOLID_BATCH`."""
    table = SOLID_BATCH[work]
    b = table.get(jax.default_backend(), table["other"])
    if isinstance(b, bool) or not isinstance(b, int) or b < 1:
        raise ValueError(f"SOLID_BATCH[{work!r}]: the batch size must be an integer >= 1, got {b!r}")
    return b

#: nodes a solid's window (``Numerics.solid_storage = "window"``) holds beyond its
#: blend's reach at t = 0 and the placement's margins: room to move and deform
SOLID_WINDOW_SLACK = 8
#: nodes between the box of a solid's level set below ``phi_max h`` and the edge of its
#: band window (:meth:`Model._band_on_windows`): the re-distancing's two sweeps and the body's
#: motion within the step reach two of them; the window's own edge ghosts never reach the box
BAND_WINDOW_MARGIN = 4
#: a band window larger than this fraction of the grid's nodes is not used (the whole grid
#: is then as cheap): the rotor's body fills most of its box
BAND_WINDOW_FRACTION = 0.5


def _pack_mixed(s_mix, rho, wf_c, wf_n):
    """The four mixed results of :meth:`Model.derived` in one vector: each branch of the
    tiles' and windows' conditionals returns them so (XLA split a conditional with four
    outputs into four, each redoing the part of the branch that its output needs; an
    optimization barrier did not stop it)."""
    return jnp.concatenate([a.reshape(-1) for a in (*s_mix, rho, wf_c, wf_n)])


def _unpack_mixed(flat, n_comp: int, nshape):
    """:func:`_pack_mixed` undone: ``(s_mix, rho, wf_c, wf_n)`` on a grid of ``nshape`` nodes."""
    cshape = tuple(s + 1 for s in nshape)
    sizes = [math.prod(cshape)] * n_comp + [math.prod(nshape), math.prod(cshape), math.prod(nshape)]
    shapes = [cshape] * n_comp + [nshape, cshape, nshape]
    parts = jnp.split(flat, np.cumsum(sizes)[:-1].tolist())
    out = [p.reshape(sh) for p, sh in zip(parts, shapes, strict=True)]
    return out[:n_comp], out[-3], out[-2], out[-1]


# band_sweeps = "auto" in 2D: the full grid below this many nodes, whatever the fractions.
# There a whole step takes a few ms either way, and the tiles' extra branches (the capacity
# ladder) triple the compile time (64^2, 4 discs: 7 s -> 20 s for a step 10 % faster;
# docs/benchmarks.md, "Smaller tiles in 2D")
AUTO_TILE_MIN_NODES_2D = 10_000

LIMIT_NAMES = ("viscous", "solid wave", "wave damping", "fluid sound", "convective", "output", "dt_max", "fixed")


@dataclass(frozen=True)
class Solid:
    """One solid: its shape in reference coordinates and its material law.

    The initial reference map is ``xi(x, 0) = A (x - c) + c`` with ``A = strain`` (the
    identity for an unstrained body) and ``c = strain_center``: the body starts in the
    region {x : shape(xi(x, 0)) < 0}, deformed by F = A^-1.  ``velocity`` is its initial
    velocity; ``anchor`` an optional :mod:`refmap.anchors` constraint.

    The dimension d is the law's (``law.dim``, 2 unless built with ``dim=3``); ``strain``,
    ``strain_center`` and ``velocity`` left unset are the d x d identity and d zeros, and
    given ones must have d entries (the shape must be d-dimensional too).
    """

    shape: Any
    law: Any
    strain: tuple | None = None
    strain_center: tuple | None = None
    velocity: tuple | None = None
    anchor: Any = None
    name: str = "solid"

    @property
    def ndim(self) -> int:
        return int(getattr(self.law, "dim", 2))

    def __post_init__(self):
        d = self.ndim
        shape_d = getattr(self.shape, "ndim", 2)
        if isinstance(shape_d, (int, np.integer)) and shape_d != d:
            hint = " (build the law with dim=3, or use law.with_dim(3))" if shape_d == 3 else ""
            raise ValueError(
                f"solid {self.name!r}: its shape {type(self.shape).__name__} is {shape_d}D but "
                f"its law {type(self.law).__name__} is {d}D{hint}"
            )
        A = np.eye(d) if self.strain is None else np.asarray(self.strain, dtype=float)
        if A.shape != (d, d) or not np.all(np.isfinite(A)):
            raise ValueError(f"solid {self.name!r}: strain must be a finite {d}x{d} matrix, got {self.strain!r}")
        if np.linalg.det(A) <= 0:
            raise ValueError(f"solid {self.name!r}: strain must have a positive determinant, got det={np.linalg.det(A):.4g}")
        for key in ("strain_center", "velocity"):
            val = getattr(self, key)
            vec = np.zeros(d) if val is None else np.asarray(val, dtype=float)
            if vec.shape != (d,) or not np.all(np.isfinite(vec)):
                raise ValueError(f"solid {self.name!r}: {key} must be {d} finite numbers, got {val!r}")
            object.__setattr__(self, key, tuple(float(c) for c in vec))
        object.__setattr__(self, "strain", tuple(tuple(float(a) for a in r) for r in A))

    def node_span(self, grid, pad: int):
        """``(first, last)`` (d,) int: the node indices (unwrapped: they may lie past the
        grid) of the box that holds the body at t = 0, its shape's ``bbox()`` carried
        through the inverse of the initial strain (``xi = A (x - c) + c``), with ``pad``
        nodes to spare on each side; None for a shape without ``bbox()`` (or a singular
        strain).  ``Case.validate`` and ``Model._initial_boxes`` evaluate the body there
        instead of on the whole grid."""
        d = grid.ndim
        try:
            bb = np.asarray(self.shape.bbox(), dtype=float).reshape(d, 2)
            A = np.asarray(self.strain, dtype=float)
            c = np.asarray(self.strain_center, dtype=float)
            corners = np.stack(np.meshgrid(*bb, indexing="ij"), axis=-1).reshape(-1, d)
            x = c + np.linalg.solve(A, (corners - c).T).T
        except (AttributeError, NotImplementedError, TypeError, ValueError, np.linalg.LinAlgError):
            return None
        lows, sp = np.asarray(grid.lows), np.asarray(grid.spacing)
        first = np.floor((x.min(axis=0) - lows) / sp - 0.5).astype(int) - pad
        last = np.ceil((x.max(axis=0) - lows) / sp - 0.5).astype(int) + pad
        return first, last

    def initial_map(self, *X):
        """The initial map's components at the coordinates ``X`` (d arrays)."""
        A = self.strain
        c = self.strain_center
        if len(X) == 2:  # the original 2D arithmetic, bit for bit
            (a, b), (e, f) = A
            cx, cy = c
            x, y = X
            return a * (x - cx) + b * (y - cy) + cx, e * (x - cx) + f * (y - cy) + cy
        out = []
        for i in range(len(X)):
            acc = c[i]
            for j in range(len(X)):
                acc = acc + A[i][j] * (X[j] - c[j])
            out.append(acc)
        return tuple(out)


class StepInfo(NamedTuple):
    dt: jax.Array
    limit: jax.Array  # index into LIMIT_NAMES


def _solid_stresses(laws, F):
    """Stress of every solid, (N, ..., 2, 2), and the reference densities (N,).

    Solids sharing one law class are stacked into one pytree and processed with ``vmap``
    (one traced code path whatever their number); mixed classes fall back to a loop.
    """
    sig = map_laws(lambda law, f: law.stress(f), laws, F)
    return sig, jnp.stack([jnp.asarray(law.rho0, dtype=F.dtype) for law in laws])


def solid_fractions(H):
    """Solid fractions (1 - H_k) and fluid fraction for stacked blend weights H (N, ...).

    Where blur zones of several solids overlap, sum_k (1 - H_k) can exceed 1; the solid
    fractions are then renormalised to sum to 1 (and the fluid fraction is 0), so the
    weights always form a partition of unity with every weight in [0, 1].
    """
    ws = 1.0 - H
    total = jnp.sum(ws, axis=0)
    # 1 / max(total, 1) is 1 / total where the zones overlap and exactly 1 elsewhere; unlike
    # a guarded 1 / total inside a where, its derivative is finite everywhere (no 0 * inf
    # NaN in reverse mode where no solid is near)
    scale = 1.0 / jnp.maximum(total, 1.0)
    ws = ws * scale
    wf = jnp.clip(1.0 - jnp.sum(ws, axis=0), 0.0, 1.0)
    return ws, wf


def _stress_keys(components, nd: int) -> dict:
    """The mixed stress's corner components as a dict: ``s`` (the tuple, in
    ``SYM_COMPONENTS`` order) and ``sxx``, ``sxy``, ... by name."""
    out = {"s": tuple(components)}
    for name, c in zip(SYM_COMPONENTS[nd], components, strict=True):
        out["s" + name] = c
    return out


def _solid_batches(S: int, m: int):
    """``(B, pad, batched)``: ``S`` solids in ``m`` equal batches of ``B = ceil(S / m)``
    (:func:`solid_batch`), the last padded with ``pad`` copies of the last solid;
    ``batched(a)`` gives a per-solid array ``a`` (S, ...) as (m, B, ...)."""
    B = -(-S // m)
    pad = m * B - S

    def batched(a):
        if pad:
            a = jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)], axis=0)
        return a.reshape((m, B) + a.shape[1:])

    return B, pad, batched


def _det_adjugate(dxi):
    """Determinant and adjugate (..., d, d) of the matrix A with A[a][b] = ``dxi[a][b]``.

    2D: the thesis's closed form (bit for bit the original arithmetic); 3D: cofactors.
    """
    if len(dxi) == 2:
        (Xx, Xy), (Yx, Yy) = dxi
        det = Xx * Yy - Xy * Yx
        adj = jnp.stack([jnp.stack([Yy, -Xy], axis=-1), jnp.stack([-Yx, Xx], axis=-1)], axis=-2)
        return det, adj
    A = dxi
    # cofactor C[i][j] = (-1)^(i+j) minor(i, j); adj = C^T
    C = [[None] * 3 for _ in range(3)]
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            C[i][j] = A[i1][j1] * A[i2][j2] - A[i1][j2] * A[i2][j1]
    det = A[0][0] * C[0][0] + A[0][1] * C[0][1] + A[0][2] * C[0][2]
    adj = jnp.stack([jnp.stack([C[j][i] for j in range(3)], axis=-1) for i in range(3)], axis=-2)
    return det, adj


class Model:
    """Static description of a case and the pure step function built from it."""

    #: the step's ENO advection and extra-viscosity Laplacian with hand-written reverse
    #: modes (:func:`refmap.operators.advect_lowmem`, ``laplacian_lowmem``: the same values,
    #: less memory in a step's backward pass, but no forward mode).  Set on the copies
    #: that :func:`refmap.differentiable.differentiable_model` makes for reverse mode.
    hand_transposes: bool = False

    def __init__(
        self,
        grid: Grid,
        solids: tuple[Solid, ...] = (),
        boundary: Boundary | None = None,
        numerics: Numerics | None = None,
        body_forces: tuple = (),
        initial_velocity=None,
    ):
        self.grid = grid
        self.ndim = d = grid.ndim
        self.spacing = tuple(grid.spacing)
        self.solids = tuple(solids)
        for s in self.solids:
            if s.ndim != d:
                raise ValueError(
                    f"solid {s.name!r} is {s.ndim}D (its law's dim) but the grid is {d}D"
                    + (" (build its law with dim=3, or law.with_dim(3))" if d == 3 else "")
                )
        self.boundary = boundary if boundary is not None else Boundary()
        self.numerics = numerics if numerics is not None else Numerics()
        self.body_forces = tuple(body_forces)
        self.bc = BoundaryConditions(grid, self.boundary)
        self.h = grid.h
        if d == 3:
            check_3d_support(self.numerics, self.solids, self.body_forces)
        self.implicit_viscosity = (
            ImplicitViscosity(self, rtol=self.numerics.viscosity_rtol,
                              preconditioner=self.numerics.viscosity_preconditioner)
            if self.numerics.viscosity == "implicit" else None
        )
        # the pressure projection of an incompressible fluid (refmap.projection); building it
        # checks the edge conditions
        self.projection = (
            Projection(self, rtol=self.numerics.pressure_rtol,
                       preconditioner=resolve_preconditioner(
                           self.numerics.pressure_preconditioner, self.solids))
            if self.numerics.fluid_model == "incompressible" else None
        )
        if self.numerics.fluid_mass == "conserved":
            _check_closed(self.boundary)
        # 1 - the velocity weights of the anchors that have one (region anchors, the pivot's
        # ramp): the projection's correction weight (incompressible: every anchor needs
        # one) and the implicit viscous solve's free weight (their nodes enter the solve
        # with the anchor's velocity and keep it, as in the explicit step; anchors without
        # a weight act after the solve)
        free = np.ones(grid.shape())
        for s in self.solids:
            weight = getattr(s.anchor, "velocity_weight", None)
            if s.anchor is not None and weight is None and self.projection is not None:
                raise ValueError(
                    f"solid {s.name!r}: fluid_model 'incompressible' needs the anchor's "
                    f"velocity_weight(grid) (the nodes it holds); {type(s.anchor).__name__} "
                    "has none"
                )
            if weight is not None:
                free = free * (1.0 - np.asarray(weight(grid)))
        held = not np.all(free == 1.0)
        self._anchor_free = free if held and self.projection is not None else None
        self._viscous_free = None  # per node, or per component with the projection's mask
        if self.implicit_viscosity is not None and (held or self.projection is not None):
            # the edges' normal components that the projection prescribes are held in the
            # solve too (set by Projection.prescribe before it)
            self._viscous_free = (free if self.projection is None
                                  else np.asarray(self.projection.mask) * free[None])
        self._anchors_in_solve = held and self.implicit_viscosity is not None
        if initial_velocity is not None:  # node values (d, nx, ny[, nz]), see initial_state
            v0 = np.asarray(initial_velocity, dtype=np.float64)
            if v0.shape != (d,) + grid.shape():
                raise ValueError(f"initial_velocity must have the node shape {(d,) + grid.shape()}, "
                                 f"got {v0.shape}")
            if not np.all(np.isfinite(v0)):
                raise ValueError(f"initial_velocity has {int((~np.isfinite(v0)).sum())} non-finite values")
            initial_velocity = v0
        self.initial_velocity = initial_velocity
        # the solids at t = 0 on a box round each body only (no whole-grid array per
        # solid), where the model can store its solids in windows; else on the whole grid
        self._boxes = self._initial_boxes()
        if self._boxes is not None:
            self._xi0 = self._phi_t0 = None
            self.band_capacity = self._initial_band_capacity()  # None: no grid band work
            self.solid_tiles = None
            self.solid_window = self._initial_solid_window()
            self.solid_band_window = self._initial_solid_band_window()
            self.state_window = self._initial_state_window()
            if self.state_window is None:  # windows too large after all: the grid's way
                self._boxes = None
        if self._boxes is None:
            Xn = grid.mesh("node")
            self._xi0 = np.stack(
                [np.stack(s.initial_map(*Xn)) for s in self.solids]
            ) if self.solids else np.zeros((0, d) + grid.shape())
            # phi0 of the initial maps (S, ...): where each solid is at t = 0, computed once
            # for the wall glue and the static band and tile sizes below
            with jax.ensure_compile_time_eval():
                self._phi_t0 = np.stack([np.asarray(self.phi0(k, self._xi0[k])) for k in range(self.n_solids)]) \
                    if self.solids else np.zeros((0,) + grid.shape())
            if self.solids:  # solids touching a resting wall at t = 0 stay glued to it
                self.bc.glue(self._xi0 - np.stack(Xn), self._phi_t0 < 0)
            self.band_capacity = self._initial_band_capacity()
            self.solid_tiles = self._initial_solid_tiles()
            self.solid_window = self._initial_solid_window()
            self.solid_band_window = self._initial_solid_band_window()
            self.state_window = self._initial_state_window()

    def _initial_boxes(self):
        """The solids at t = 0 on one box of nodes per solid, for a model that can store its
        solids in windows (``Numerics.solid_storage = "window"``, none of the settings that
        :meth:`_initial_state_window` keeps on the grid): ``(box, origins (S, d) int,
        xi (S, d, *box), phi (S, *box))``, the initial maps and ``phi0`` of them on each
        solid's box, the values the whole grid has at those nodes.  The box (one size for
        all) is the shape's ``bbox()`` carried into the current configuration by the
        inverse of the initial strain, widened on each side by ``phi_max`` cells (the band
        box), the band window's margin and slack and two nodes, so that the band window
        placed round the body at t = 0 lies inside it.

        None (the whole grid's arrays are formed, as for grid storage) where this cannot be
        done exactly: a shape without ``bbox()``, a box as long as a grid axis, a body whose
        nodes with ``phi <= phi_max h`` reach a side of its box inside the grid (a shape
        whose level set is not a distance), or a body on the first node row next to a
        non-periodic edge (the wall glue of :meth:`BoundaryConditions.glue` is formed on the
        whole grid; such a model keeps grid storage anyway)."""
        n = self.numerics
        if n.solid_storage != "window" or not self.solids or self.projection is not None:
            return None
        if n.band_force == "solid" or n.fluid_mass == "conserved":
            return None
        if any(s.anchor is not None for s in self.solids):
            return None
        g = self.grid
        d = self.ndim
        shape = g.shape()
        per = self.bc.periodic
        pad = math.ceil(n.phi_max) + BAND_WINDOW_MARGIN + SOLID_WINDOW_SLACK + 2
        lo_hi = [s.node_span(g, pad) for s in self.solids]
        if any(span is None for span in lo_hi):
            return None
        box = tuple(int(max(last[a] - first[a] + 1 for first, last in lo_hi)) for a in range(d))
        if any(b >= m for b, m in zip(box, shape, strict=True)):
            return None
        origins = []
        for first, last in lo_hi:
            o = []
            for a in range(d):
                start = (first[a] + last[a] + 1) // 2 - box[a] // 2
                o.append(start % shape[a] if per[a] else min(max(start, 0), shape[a] - box[a]))
            origins.append(o)
        origins = np.asarray(origins, dtype=np.int32)
        axes = g.axes("node")
        idx = [(origins[:, a, None] + np.arange(box[a])) % shape[a] for a in range(d)]  # (S, B_a)
        xi = np.stack([np.stack(s.initial_map(*np.meshgrid(*(axes[a][idx[a][k]] for a in range(d)),
                                                           indexing="ij")))
                       for k, s in enumerate(self.solids)])  # the grid's node coordinates
        with jax.ensure_compile_time_eval():
            phi = np.asarray(self._phi0_all(jnp.asarray(xi)))
            reach = self._band_reach
            _, inside = jax.vmap(lambda p, o: windows.place_from(p, o, reach, box, shape, per, margin=0))(
                jnp.asarray(phi), jnp.asarray(origins))
        if not bool(np.all(np.asarray(inside))):
            return None
        for a in range(d):  # a body on the first node row in from a wall: glue (grid)
            if per[a]:
                continue
            rows = [phi.take(0, axis=1 + a)[origins[:, a] == 0],
                    phi.take(-1, axis=1 + a)[origins[:, a] + box[a] == shape[a]]]
            if any(bool(np.any(r < 0)) for r in rows):
                return None
        return box, origins, xi, phi

    def _initial_solid_tiles(self):
        """``(tile, blend capacities, stress capacities)`` for computing each solid's
        stress, weights and density on its tiles (:mod:`refmap.solid_tiles`), or None (the
        full grid).  A solid lists the tiles within its blend's reach
        (:func:`refmap.solid_tiles.cutoff`) for its weights and, a subset, those within
        ``stress_band`` for its stress.  Each list's capacities are a ladder (the work is
        proportional to the capacity): ``BAND_TIGHT`` times the most tiles a solid holds
        at t = 0, plus 8, then ``band_capacity`` times them plus 8; the step takes the
        first rung that holds every solid's tiles, and the full grid past the last.  None
        with ``band_sweeps = "grid"`` or without solids, and with ``"auto"`` when the blend
        list's last capacity is more than ``SOLID_TILE_FRACTION`` of the grid's tiles or a
        2D grid has fewer than ``AUTO_TILE_MIN_NODES_2D`` nodes."""
        n = self.numerics
        if n.band_sweeps == "grid" or not self.solids:
            return None
        nd = self.ndim
        tile = (extrapolation.TILE_TARGET[nd],) * nd
        cuts = (solid_tiles.cutoff(n.blend, n.blur_width * self.h), n.stress_band * self.h)
        with jax.ensure_compile_time_eval():
            phi = jnp.minimum(jnp.asarray(self._phi_t0), n.phi_max * self.h)
            phip = self.bc.pad_linear(phi)[self._core(1)]
            counts = [np.asarray(jnp.sum(solid_tiles.tile_flags(phip, cut, tile),
                                         axis=tuple(range(1, nd + 1)))).tolist() for cut in cuts]
        total = math.prod(solid_tiles.n_tiles(self.grid.shape(), tile))
        ladders = []
        for c in counts:
            capacity = narrowband.capacity_for(c, n.band_capacity, total)
            tight = min(narrowband.capacity_for(c, BAND_TIGHT, total), capacity)
            ladders.append((tight, capacity))
        if n.band_sweeps == "auto" and (ladders[0][1] > SOLID_TILE_FRACTION * total or self._auto_too_small()):
            return None
        return tile, ladders[0], ladders[1]

    def _initial_solid_window(self):
        """``Numerics.solid_storage = "window"``: the static box (nodes per axis) in which
        each solid's stress, blend weights and density are computed
        (:func:`refmap.solid_tiles.mixed_on_windows`): the largest extent, over the solids
        at t = 0, of the nodes within the blend's reach (:func:`refmap.solid_tiles.cutoff`),
        plus ``2 * windows.MARGIN + SOLID_WINDOW_SLACK`` nodes for the body to move and
        deform before the step falls back on the whole grid; at most the grid on a walled
        axis and one node less than it on a periodic one.  None with ``"grid"`` or without
        solids."""
        n = self.numerics
        if n.solid_storage != "window" or not self.solids:
            return None
        ext = self._largest_box(solid_tiles.cutoff(n.blend, n.blur_width * self.h))
        shape = self.grid.shape()
        return tuple(
            min(e + 2 * windows.MARGIN + SOLID_WINDOW_SLACK, m - 1 if p else m)
            for e, m, p in zip(ext, shape, self.bc.periodic, strict=True)
        )

    def _largest_box(self, reach):
        """The largest extent (nodes per axis), over the solids at t = 0, of the box of a
        solid's nodes with ``phi < reach`` (the shortest box round a periodic axis)."""
        if self._boxes is not None:  # each body's box holds all its nodes below phi_max h
            m = self._boxes[3] < reach
            ext = []
            for a in range(self.ndim):
                line = m.any(axis=tuple(b for b in range(1, self.ndim + 1) if b != a + 1))  # (S, B_a)
                idx = np.arange(line.shape[1])
                first = np.where(line, idx, line.shape[1]).min(axis=1)
                last = np.where(line, idx, -1).max(axis=1)
                ext.append(int(np.max(np.where(line.any(axis=1), last - first + 1, 0))))
            return ext
        ext = [0] * self.ndim
        for k in range(self.n_solids):
            m = self._phi_t0[k] < reach
            for a in range(self.ndim):
                line = m.any(axis=tuple(b for b in range(self.ndim) if b != a))
                with jax.ensure_compile_time_eval():
                    length = windows.axis_box(jnp.asarray(line), self.bc.periodic[a])[1]
                ext[a] = max(ext[a], int(length))
        return ext

    def _initial_solid_band_window(self):
        """``Numerics.solid_storage = "window"``: the static box (nodes per axis) in which each
        solid's band work of a step runs (:meth:`_band_on_windows`: map advection, pinning
        and re-distancing, extrapolation and smoothing): the largest extent, over the solids
        at t = 0, of the nodes with ``phi < phi_max h`` (beyond them the clipped level set
        and the maps do not change), plus ``2 * BAND_WINDOW_MARGIN + SOLID_WINDOW_SLACK``;
        at most the grid on a walled axis and one node less on a periodic one.  None (the
        band work on the whole grid, as with ``"grid"``) without solids, with an anchor (its
        region and weights are full-grid fields), with a solid glued to a wall (its ghosts
        are not the linear ones :func:`refmap.windows.gather_ghosted` forms), or when the
        box holds more than ``BAND_WINDOW_FRACTION`` of the grid's nodes."""
        n = self.numerics
        self._band_window_tiles = None
        if n.solid_storage != "window" or not self.solids or self.bc._glue:
            return None
        if any(s.anchor is not None for s in self.solids):
            return None
        ext = self._largest_box(n.phi_max * self.h)
        shape = self.grid.shape()
        window = tuple(
            min(e + 2 * BAND_WINDOW_MARGIN + SOLID_WINDOW_SLACK, m - 1 if p else m)
            for e, m, p in zip(ext, shape, self.bc.periodic, strict=True)
        )
        if math.prod(window) > BAND_WINDOW_FRACTION * math.prod(shape):
            return None
        self._band_window_tiles = self._initial_band_window_tiles(window)
        return window

    def _initial_state_window(self):
        """The window in which each solid's map and level set are stored (``State.xi``
        ``(S, d, *W)``, ``State.phi`` ``(S, *W)``, ``State.origin``): the band window
        :attr:`solid_band_window`, or None (stored on the whole grid) where that is None or
        the step reads a solid's whole-grid fields: the incompressible fluid (the volume
        correction's J and fractions), ``band_force = "solid"``, ``fluid_mass =
        "conserved"`` (the new fluid fractions on the grid)."""
        n = self.numerics
        if self.solid_band_window is None or self.projection is not None:
            return None
        if n.band_force == "solid" or n.fluid_mass == "conserved":
            return None
        return self.solid_band_window

    def _initial_band_window_tiles(self, window):
        """``(tile, (tight, capacity))``: the extrapolation and smoothing on each band
        window sweep only its band's tiles (:func:`refmap.extrapolation.extend` with a
        capacity ladder, as on the grid), sized from the windows placed on the bodies at
        t = 0; None (the whole window) with ``band_sweeps = "grid"`` or when the band holds
        more than ``BAND_TILE_FRACTION`` of a window's tiles."""
        n = self.numerics
        if n.band_sweeps == "grid":
            return None
        nd = self.ndim
        tile = (WINDOW_TILE_TARGET[nd],) * nd
        shift = n.advected_band * self.h
        with jax.ensure_compile_time_eval():
            if self._boxes is not None:
                origins = self._box_placement(self._boxes[3], window)[0]
                phi_w = jnp.asarray(self._cut_boxes(self._boxes[3], origins, window))
            else:
                phi = jnp.asarray(self._phi_t0)
                origins, _ = self._band_placement(phi, window)
                phi_w = jax.vmap(lambda p, o: windows.gather(p, o, window, self.bc.periodic))(phi, origins)
            counts = np.asarray(extrapolation.band_tiles(phi_w - shift, n.band * self.h - shift, tile,
                                                         (False,) * nd))
        total = math.prod(narrowband.n_tiles(window, tile))
        capacity = narrowband.capacity_for(counts.tolist(), n.band_capacity, total)
        if capacity > BAND_TILE_FRACTION * total:
            return None
        tight = min(narrowband.capacity_for(counts.tolist(), BAND_TIGHT, total), capacity)
        return tile, (tight, capacity)

    def _box_placement(self, phi_b, window):
        """``(origins (S, d), fits)``: the band windows of ``window`` nodes placed round each
        solid's nodes with ``phi < phi_max h``, from its level set ``phi_b`` on its box of
        :meth:`_initial_boxes` (as :meth:`_band_placement` places them from the grid's)."""
        reach = self._band_reach
        origins_b = jnp.asarray(self._boxes[1])
        g = self.grid
        return jax.vmap(lambda p, o: windows.place_from(
            p, o, reach, window, g.shape(), self.bc.periodic, margin=BAND_WINDOW_MARGIN))(
            lax.stop_gradient(jnp.asarray(phi_b)), origins_b)

    def _cut_boxes(self, values, origins, window):
        """The windows of ``window`` nodes at ``origins`` (S, d) cut from per-solid values on
        the boxes of :meth:`_initial_boxes` (``(S, ..., *box)``), as numpy arrays; each
        window lies in its solid's box (the box is sized for that)."""
        values = np.asarray(values)
        origins = np.asarray(origins)
        box, origins_b = self._boxes[0], self._boxes[1]
        shape = self.grid.shape()
        d = self.ndim
        out = []
        for k in range(values.shape[0]):
            sl = []
            for a in range(d):
                off = int(origins[k, a] - origins_b[k, a])
                if self.bc.periodic[a]:
                    off %= shape[a]
                if not 0 <= off <= box[a] - window[a]:
                    raise RuntimeError(f"solid {self.solids[k].name!r}: its window at {origins[k].tolist()} "
                                       f"leaves its box at {origins_b[k].tolist()} of {box} nodes")
                sl.append(slice(off, off + window[a]))
            out.append(values[k][(Ellipsis, *sl)])
        return np.stack(out)

    def _auto_too_small(self) -> bool:
        """``band_sweeps = "auto"``: a 2D grid too small for tiles to pay
        (:data:`AUTO_TILE_MIN_NODES_2D`)."""
        return self.ndim == 2 and math.prod(self.grid.shape()) < AUTO_TILE_MIN_NODES_2D

    def _initial_band_capacity(self):
        """Static number of band tiles per solid (``Numerics.band_sweeps = "band"``).

        ``band_capacity`` times the largest number of tiles a solid's band covers at t = 0
        (from ``phi0`` of the initial maps), plus 8, but not more than the grid's tiles;
        None (full-grid sweeps) with ``band_sweeps = "grid"``, without solids, when the
        grid cannot be tiled (:func:`refmap.narrowband.tile_shape`), or with
        ``band_sweeps = "auto"`` when that is more than ``BAND_TILE_FRACTION`` of the
        grid's tiles (the full-grid sweeps are then the cheaper) or a 2D grid has fewer than
        ``AUTO_TILE_MIN_NODES_2D`` nodes.
        A band that outgrows it makes the step fall back on the full-grid sweeps (same
        result, full cost).  A tighter capacity, ``BAND_TIGHT`` times those tiles plus 8,
        is tried first.  Tiles are squares of about 8 nodes a side in 2D and cubes of
        about 8 in 3D (:data:`refmap.extrapolation.TILE_TARGET`); a 3D band that is not
        tiled is swept in a box round it where that pays (:meth:`_initial_band_window`)."""
        n = self.numerics
        self._band_tight = None
        self.band_window = None
        nd = self.ndim
        self.band_tile = narrowband.tile_shape(
            self.grid.shape(), self.bc.periodic, target=extrapolation.TILE_TARGET[nd]
        )
        if n.band_sweeps == "grid" or not self.solids or self._boxes is not None:
            return None  # (solids in windows: no band work on the grid)
        capacity = None
        if self.band_tile is not None:
            shift = n.advected_band * self.h
            with jax.ensure_compile_time_eval():
                phi = jnp.asarray(self._phi_t0)
                counts = np.asarray(extrapolation.band_tiles(
                    phi - shift, n.band * self.h - shift, self.band_tile, self.bc.periodic))
            total = math.prod(narrowband.n_tiles(self.grid.shape(), self.band_tile))
            capacity = narrowband.capacity_for(counts.tolist(), n.band_capacity, total)
            if n.band_sweeps == "auto" and (capacity > BAND_TILE_FRACTION * total or self._auto_too_small()):
                capacity = None
        if capacity is None:
            if nd == 3:  # a box round each band, where it is small enough
                self.band_window = self._initial_band_window()
            return None
        self._band_tight = min(narrowband.capacity_for(counts.tolist(), BAND_TIGHT, total), capacity)
        return capacity

    def _initial_band_window(self):
        """3D: the static box (nodes per axis) in which each solid's band is swept
        (:func:`refmap.extrapolation.extend`'s ``window``): the largest extent of a band box
        at t = 0 plus ``BAND_WINDOW_SLACK`` nodes, the whole length of periodic axes; None
        (the full grid) with ``band_sweeps = "grid"``, without solids, or when the box
        would hold more than ``BAND_WINDOW_FRACTION`` of the grid."""
        n = self.numerics
        if n.band_sweeps == "grid" or not self.solids:
            return None
        shift = n.advected_band * self.h
        phi = self._phi_t0
        ext = extrapolation.band_window_extent(phi - shift, n.band * self.h - shift)
        shape = self.grid.shape()
        window = tuple(
            m if p else min(m, e + BAND_WINDOW_SLACK)
            for e, m, p in zip(ext, shape, self.bc.periodic, strict=True)
        )
        if math.prod(window) > BAND_WINDOW_FRACTION * math.prod(shape):
            return None
        return window

    # ------------------------------------------------------------------ helpers
    @property
    def n_solids(self) -> int:
        return len(self.solids)

    def _dz(self) -> dict:
        """``{"dz": dz}`` in 3D, ``{}`` in 2D: the keyword that makes the level-set and
        extrapolation functions 3D."""
        return {"dz": self.grid.dz} if self.ndim == 3 else {}

    def _core(self, g: int = 1):
        """Index dropping ``g`` layers on each side of the ``ndim`` grid axes."""
        return (Ellipsis,) + (slice(g, -g),) * self.ndim

    def _vec(self, a):
        """A d-vector (d,) as (d, 1, ..., 1), to broadcast against node fields."""
        return jnp.asarray(a).reshape((self.ndim,) + (1,) * self.ndim)

    def _images(self, xi_k):
        """The periodic images of reference points ``xi_k`` (2, ...) that phi0 examines.

        On a periodic axis a body that crossed an edge carries a map that jumps by the period
        there (``xi - x`` is what stays continuous, see ``BoundaryConditions.pad_affine``),
        so the material at a node may hold ``xi = Xi - m L`` for its true reference point Xi
        and any integer m (one per crossing, either way; m grows without bound for a body
        that keeps travelling).  Each periodic component is first reduced into the box's
        window [a, b), then shifted by -L, 0 and +L; with both axes periodic that is all
        nine combinations, so a body straddling a corner of the box (its map shifted along
        both axes at once at the diagonally opposite corner) is recognised too.  This finds
        every reference point of a shape that lies within one period of the box.

        Returns a list of ``(X, shift)``: the image (a tuple of d coordinate arrays) and its
        shift from ``xi_k`` (a tuple of d arrays, a whole number of periods per axis),
        ``X[c] = xi_k[c] + shift[c]``.
        """
        g = self.grid
        lows = g.lows
        highs = g.highs
        per_axis = []
        for c, (a, b, periodic) in enumerate(zip(lows, highs, self.bc.periodic, strict=True)):
            x = xi_k[c]
            if not periodic:
                per_axis.append([(x, jnp.zeros_like(x))])
                continue
            L = b - a
            base = a + jnp.mod(x - a, L) - x  # a whole number of periods (to round-off)
            per_axis.append([(x + base + m * L, base + m * L) for m in (0, -1, 1)])
        out = []
        for combo in itertools.product(*per_axis):
            out.append((tuple(X for X, _ in combo), tuple(sh for _, sh in combo)))
        return out

    def phi0(self, k: int, xi_k, return_shift: bool = False):
        """phi0_k(xi_k): where solid k's material says its boundary is (thesis eq. 4.27).

        On periodic axes the reference shape is repeated with the period: the minimum over
        the images of :meth:`_images` (shifts along each periodic axis and along several at
        once), so a body that crossed an edge or a corner, any number of times, is still
        recognised.  With ``return_shift`` also the shift (d, ...) of the image that gave
        the minimum, i.e. ``xi_k + shift`` is the material's reference point within the
        reference shape's own image (used to unwrap the positions of a body cut by a
        periodic edge).
        """
        return self._least_image(xi_k, self.solids[k].shape, return_shift)

    def _least_image(self, xi_k, level, return_shift: bool = False):
        """The least of ``level(*X)`` over the periodic images ``X`` of ``xi_k``
        (:meth:`_images`), with ``return_shift`` also the shift of the image that gave it
        (:meth:`phi0`, for a shape or a shape's level set with traced parameters)."""
        out = best = None
        for X, shift in self._images(xi_k):
            val = level(*X)
            if out is None:
                out, best = val, list(shift)
                continue
            better = val < out
            out = jnp.where(better, val, out)
            best = [jnp.where(better, sh, b) for sh, b in zip(shift, best, strict=True)]
        if return_shift:
            return out, jnp.stack(best)
        return out

    def extrapolate(self, xi, phi):
        """Extrapolate each solid's map into its band and smooth the extrapolated values.

        The extrapolation starts from the nodes with ``phi < advected_band h``
        (:class:`Numerics`): by default the solid's own nodes; with ``advected_band > 0``
        also the nearest band nodes, which then keep their advected map."""
        if not self.n_solids:
            return xi
        Xn = jnp.asarray(self.grid.mesh("node"))
        # extrapolate the displacement-like xi - x: identical for affine maps, and continuous
        # across periodic edges; both components share one phi (and so the geometric
        # pre-pass of the extrapolation)
        return self._extend_all(xi - Xn, phi) + Xn

    def _extend(self, f, phi_k, fixed_sweeps=None):
        """The band operator M of :meth:`extrapolate` on one solid's node field(s) ``f``
        (c, nx, ny): extrapolation from the nodes with ``phi < advected_band h`` and
        smoothing of the extrapolated values.  ``fixed_sweeps`` overrides the smoothing's
        sweep rule (``Numerics.fixed_smooth_sweeps``, else the adaptive stop)."""
        return self._extend_all(f[None], phi_k[None], fixed_sweeps)[0]

    def _extend_all(self, f, phi, fixed_sweeps=None, windowed: bool = False):
        """:meth:`_extend` for every solid at once: ``f`` (S, c, nx, ny), ``phi`` (S, nx, ny).
        ``windowed``: the arrays are windows (:meth:`_band_on_windows`): swept whole, no
        axis wrapping round."""
        n = self.numerics
        shift = n.advected_band * self.h  # 0 by default: phi - 0.0 is phi, bit for bit
        smooth = dict(
            coef=n.smooth_coef,
            max_sweeps=n.smooth_max_sweeps,
            ratio=n.smooth_ratio,
            atol=n.smooth_atol,
            check_every=n.smooth_check_every,
            fixed_sweeps=n.fixed_smooth_sweeps if fixed_sweeps is None else fixed_sweeps,
        )
        return extrapolation.extend(
            f,
            phi - shift,
            self.grid.dx,
            self.grid.dy,
            n.band * self.h - shift,
            **({"dz": self.grid.dz, "window": None if windowed else self.band_window}
               if self.ndim == 3 else {}),
            capacity=(None if self._band_window_tiles is None else self._band_window_tiles[1])
            if windowed else self.band_capacity
            if self.band_capacity is None or self._band_tight is None
            else (self._band_tight, self.band_capacity),
            tile=(None if self._band_window_tiles is None else self._band_window_tiles[0])
            if windowed else self.band_tile,
            periodic=(False,) * self.ndim if windowed else self.bc.periodic,
            smooth=smooth,
        )

    def band_force_to_solid(self, state: State, d):
        """Correction to div(sigma) that moves each solid's force off its extrapolated nodes.

        The band nodes' maps are ``x + M(xi_s - x)``, M the extrapolation and smoothing of
        :meth:`extrapolate` (linear for a given phi), so the elastic energy stored at the
        band's corners changes with the solid nodes' velocity, not the band nodes'.  For the
        solid stress to do exactly the work that changes that energy, its force on the band
        nodes, ``f_b = div(w_s sigma_s)`` there, is applied to the solid nodes as ``M^T f_b``
        (the vector-Jacobian product of M).  M reproduces affine fields, so the total force
        and torque are unchanged.  The transpose uses ``smooth_max_sweeps`` fixed sweeps (the
        stopping rule of the forward smoothing is not differentiable; it seldom stops early).
        Returns the (2, nx, ny) correction: ``sum_k (M_k^T f_b,k - f_b,k)``.
        """
        n = self.numerics
        h = self.h
        g = self.grid
        shift = n.advected_band * h
        sweeps = n.fixed_smooth_sweeps if n.fixed_smooth_sweeps is not None else n.smooth_max_sweeps
        out = jnp.zeros_like(state.v)
        for k in range(self.n_solids):
            ws = d["ws_c"][k]
            sig = d["sigma_s"][k]
            fs = div_node(ws * sig[..., 0, 0], ws * sig[..., 0, 1], ws * sig[..., 1, 1], g.dx, g.dy)
            phi_k = state.phi[k]
            band = (phi_k - shift >= 0) & (phi_k - shift <= n.band * h - shift)
            fb = jnp.where(band[None], fs, 0.0)

            def M(f, phi_k=phi_k):
                return self._extend(f, phi_k, fixed_sweeps=sweeps)

            _, vjp = jax.vjp(M, jnp.zeros_like(fb))
            out = out + vjp(fb)[0] - fb
        return out

    def pin(self, phi, xi, dt, periodic=None, table=None):
        """The level sets ``phi`` (S, ...) pinned to the maps ``xi`` (S, d, ...) and
        re-distanced (:func:`refmap.levelset.pin_levelset`); ``periodic``: the wrap flags
        of the arrays' axes (default the grid's; windows pass none); ``table``: the shape
        parameters of these solids (:meth:`_shape_table`'s rows) when they are a batch of
        the solids, not all of them."""
        n = self.numerics
        h = self.h
        # phi = phi0(xi) at the nodes next to the contour (|phi| < pin_copy h), so the contour
        # is the material's (no lag); elsewhere in the zone the thesis's relaxation at rate
        # k n_sub dt (alone, pin_copy = 0, it trails a moving body by U / (k n_sub))
        relax = jnp.minimum(n.pin_rate * n.pin_substeps * dt, 1.0)

        def one(phi_k, psi):
            return levelset.pin_levelset(
                phi_k,
                psi,
                self.grid.dx,
                self.grid.dy,
                rate=jnp.where(jnp.abs(phi_k) < n.pin_copy * h, 1.0, relax),
                inner=n.pin_inner * h,
                outer=(n.band - 1.0) * h,
                redistance_iters=n.redistance_iters,
                phi_max=n.phi_max * h,
                periodic=self.bc.periodic if periodic is None else periodic,
                **self._dz(),
            )

        if self.n_solids == 0:
            return phi
        if self.state_window is not None and periodic is not None:
            # the solids stored in windows (many small bodies): one traced pinning for all
            # (vmap), the level sets phi0 of the solids of one shape kind batched too, so
            # that the step's code and its compile time do not grow with the solids
            return jax.vmap(one)(phi, self._phi0_all(xi, table=table))
        return jnp.stack([one(phi[k], self.phi0(k, xi[k])) for k in range(self.n_solids)])

    def _shape_table(self):
        """``(skeleton, table)`` when every solid's shape is one skeleton
        (:func:`refmap.geometry._flatten`) that differs only in its numbers, ``table`` (S,
        P) their numbers in the solids' order (numpy); else None.  Then :meth:`_phi0_all`
        of any batch of the solids is one ``vmap`` over the batch's rows."""
        if self.n_solids < 2:
            return None
        skeletons, rows = set(), []
        for s in self.solids:
            if not dataclasses.is_dataclass(s.shape):
                return None
            skeleton, params = geometry._flatten(s.shape)
            skeletons.add(skeleton)
            rows.append(list(params))
        if len(skeletons) != 1:
            return None
        return skeletons.pop(), np.asarray(rows, dtype=np.float64)

    def _phi0_all(self, xi, return_shift: bool = False, table=None):
        """:meth:`phi0` of every solid (S, ...) from its map ``xi`` (S, d, ...): the solids
        whose shapes differ only in their numbers (:func:`refmap.geometry._flatten`'s
        skeleton) evaluated with one ``vmap`` over their parameters, the others one by one.
        With ``return_shift`` also the periodic shifts (S, d, ...) of :meth:`phi0`.
        ``table``: for a batch of the solids (``xi`` theirs), their rows of
        :meth:`_shape_table` (which must not be None)."""
        if table is not None:
            skeleton = self._shape_table()[0]

            def batch_phi(p, xi_k):
                params = tuple(p[i] for i in range(p.shape[0]))
                return self._least_image(xi_k, lambda *X: geometry._evaluate(X, params, skeleton), return_shift)

            return jax.vmap(batch_phi)(table.astype(xi.dtype), xi)
        groups = {}
        for k, s in enumerate(self.solids):
            if dataclasses.is_dataclass(s.shape):
                skeleton, params = geometry._flatten(s.shape)
                groups.setdefault(skeleton, []).append((k, params))
            else:
                groups.setdefault(("solid", k), []).append((k, None))
        parts = [None] * self.n_solids
        for skeleton, members in groups.items():
            ks = [k for k, _ in members]
            if len(members) == 1 or members[0][1] is None:
                for k in ks:
                    parts[k] = self.phi0(k, xi[k], return_shift)
                continue
            table = jnp.asarray([list(p) for _, p in members], dtype=xi.dtype)  # (G, P)

            def shape_phi(p, xi_k, skeleton=skeleton):
                params = tuple(p[i] for i in range(p.shape[0]))
                return self._least_image(xi_k, lambda *X: geometry._evaluate(X, params, skeleton), return_shift)

            if ks == list(range(self.n_solids)):  # one kind of shape: the solids in order
                return jax.vmap(shape_phi)(table, xi)
            vals = jax.vmap(shape_phi)(table, xi[jnp.asarray(ks)])
            for j, k in enumerate(ks):
                parts[k] = jax.tree_util.tree_map(lambda a, j=j: a[j], vals)
        return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *parts)

    # ------------------------------------------------------------------ initial state
    def initial_state(self, params: Params, redistance_iters: int = 40) -> State:
        """The state at t = 0: the solids' initial maps and level sets, the fluid density
        uniform at ``rho0``, and the velocity

            v(x, 0) = v0(x) + sum_k (1 - H_k(x)) V_k,

        with ``v0`` the model's ``initial_velocity`` (zero when None) and ``V_k`` solid k's
        uniform ``Solid.velocity``, weighted by its solid fraction (see
        :func:`solid_fractions`).  ``V_k`` is thus the solid's velocity relative to the
        field.  Without a field the fluid starts at rest: a solid given a velocity is an
        impulsively started body whose velocity jump is spread over the blur zone:
        (1 - H) V = erfc(phi / (w h)) V / 2 is 0.92 V at phi = -w h inside, V / 2 on the zero
        level set, 0.079 V at phi = w h and 0.002 V at phi = 2 w h outside (w = blur_width,
        2 by default); the fluid farther out is at rest and is set moving by viscosity and
        by the pressure waves the body sends out.  A field ``v0`` moves the
        fluid and the solids together (a rotating body with the fluid around it, a uniform
        stream, a vibration mode); it is taken as given, so a field that is not
        divergence-free (or a body's rigid rotation next to resting fluid) also starts
        sound waves, as the fluid density starts uniform.
        """
        g = self.grid
        shape = g.shape()
        if self._boxes is not None:
            return self._initial_state_windows(params, redistance_iters)
        xi = jnp.asarray(self._xi0)
        phis = []
        for k in range(self.n_solids):
            psi = self.phi0(k, xi[k])
            phi_k = levelset.redistance(psi, g.dx, g.dy, redistance_iters, periodic=self.bc.periodic,
                                        **self._dz())
            phis.append(jnp.clip(phi_k, -self.numerics.phi_max * self.h, self.numerics.phi_max * self.h))
        phi = jnp.stack(phis) if phis else jnp.zeros((0, *shape))
        v = (jnp.zeros((self.ndim, *shape)) if self.initial_velocity is None
             else jnp.asarray(self.initial_velocity))
        if self.n_solids:
            H = blend.heaviside(phi, self.numerics.blend, self.numerics.blur_width * self.h)
            ws, _ = solid_fractions(H)
            for k, s in enumerate(self.solids):
                v = v + ws[k][None] * self._vec(s.velocity)
        rho_f = jnp.full(shape, params.fluid.rho0, dtype=jnp.float64)
        return self.to_windows(State(
            t=jnp.asarray(0.0, dtype=jnp.float64),
            step=jnp.asarray(0, dtype=jnp.int64),
            v=v,
            rho_f=rho_f,
            xi=xi,
            phi=phi,
            p=jnp.zeros(shape, dtype=jnp.float64) if self.projection is not None else None,
        ))

    def _initial_state_windows(self, params: Params, redistance_iters: int) -> State:
        """:meth:`initial_state` for solids stored in windows, formed on the windows alone
        (no whole-grid array per solid): each window placed round its body's nodes with
        ``phi < phi_max h`` (from the boxes of :meth:`_initial_boxes`), the maps and
        ``phi0`` cut from the boxes, the level sets re-distanced in the windows (their
        edges not periodic: the re-distancing carries information outwards from the
        contour, and the band box lies ``BAND_WINDOW_MARGIN`` nodes and more inside the
        edges) and clipped; re-placed round the re-distanced level sets if that moves a
        window (a shape whose ``phi0`` is not a distance).  The solids' velocities enter
        through their fractions summed over the windows (:func:`refmap.windows.accumulate`).
        The same state as the whole grid's cut to windows, to round-off."""
        g = self.grid
        d = self.ndim
        shape = g.shape()
        per = self.bc.periodic
        n = self.numerics
        W = self.state_window
        far = n.phi_max * self.h
        _, _, xi_b, phi_b = self._boxes
        reach = self._band_reach

        def redistanced(psi):
            phi = levelset.redistance(psi, g.dx, g.dy, redistance_iters, periodic=(False,) * d, **self._dz())
            return jnp.clip(phi, -far, far)

        with jax.ensure_compile_time_eval():  # geometry only: evaluated now, also under jit
            origins = np.asarray(self._box_placement(phi_b, W)[0])
        for _ in range(3):
            with jax.ensure_compile_time_eval():
                xi = jnp.asarray(self._cut_boxes(xi_b, origins, W))
                phi = jax.vmap(redistanced)(jnp.asarray(self._cut_boxes(phi_b, origins, W)))
                new, fits = jax.vmap(lambda p, o: windows.place_from(
                    p, o, reach, W, shape, per, margin=BAND_WINDOW_MARGIN))(phi, jnp.asarray(origins))
                new, fits = np.asarray(new), np.asarray(fits)
            if not np.all(fits):
                bad = [self.solids[k].name for k in np.flatnonzero(~fits)]
                raise ValueError(
                    f"solid(s) {bad}: the band does not fit the window of {W} nodes "
                    "(Numerics.solid_storage = 'window' sizes it from t = 0); use solid_storage = 'grid'")
            if np.array_equal(new, origins):
                break
            origins = new
        o = jnp.asarray(origins, dtype=jnp.int32)
        v = (jnp.zeros((d, *shape)) if self.initial_velocity is None
             else jnp.asarray(self.initial_velocity))
        V = np.stack([np.asarray(s.velocity, dtype=float) for s in self.solids])
        if np.any(V != 0.0):
            H = blend.heaviside(phi, n.blend, n.blur_width * self.h)
            total = windows.accumulate(jnp.zeros(shape), 1.0 - H, o, per)
            ws = (1.0 - H) * (1.0 / jnp.maximum(windows.blocks(total, o, W, per), 1.0))  # solid_fractions
            ws_v = ws[:, None] * jnp.asarray(V).reshape((-1, d) + (1,) * d)
            v = windows.accumulate(v, ws_v, o, per)
        return State(
            t=jnp.asarray(0.0, dtype=jnp.float64),
            step=jnp.asarray(0, dtype=jnp.int64),
            v=v,
            rho_f=jnp.full(shape, params.fluid.rho0, dtype=jnp.float64),
            xi=xi,
            phi=phi,
            p=None,
            origin=o,
        )

    # ------------------------------------------------------------------ window storage
    def windowed(self, state: State) -> bool:
        """Whether ``state`` stores its solids in windows (``State.origin`` set)."""
        return state.origin is not None

    def to_windows(self, state: State) -> State:
        """``state`` with its solids' maps and level sets cut to the windows of
        :attr:`state_window` (placed on each body's band, as each step places them); the
        state itself when the model stores them on the grid or it already has windows.
        ValueError (outside ``jit``) when a body's band does not fit its window."""
        if self.state_window is None or self.windowed(state):
            return state
        W = self.state_window
        per = self.bc.periodic
        origins, fits = self._band_placement(state.phi, W)
        if not isinstance(fits, jax.core.Tracer) and not bool(np.all(np.asarray(fits))):
            bad = [self.solids[k].name for k in np.flatnonzero(~np.asarray(fits))]
            raise ValueError(
                f"solid(s) {bad}: the band does not fit the window of {W} nodes "
                "(Numerics.solid_storage = 'window' sizes it from t = 0); use solid_storage = 'grid'")
        cut = jax.vmap(lambda f, o: windows.gather(f, o, W, per))
        return state.replace(xi=cut(state.xi, origins), phi=cut(state.phi, origins), origin=origins)

    def adopt(self, state: State) -> State:
        """``state`` in this model's storage of the solids: on the whole grid, or in windows
        of :attr:`state_window` (a state stored otherwise, e.g. a checkpoint or frame of a
        run with the other ``solid_storage``, is converted; a windowed state of the right
        window size is returned as it is)."""
        if self.state_window is None:
            return self.on_grid(state)
        if self.windowed(state) and tuple(state.phi.shape[1:]) == tuple(self.state_window):
            return state
        return self.to_windows(self.on_grid(state))

    def on_grid(self, state: State) -> State:
        """``state`` with its solids on the whole grid (the state itself when it is): each
        window's values where it lies, ``phi_max h`` (far) and the identity map ``xi = x``
        elsewhere.  Output, diagnostics and post-processing read this."""
        if not self.windowed(state):
            return state
        per = self.bc.periodic
        shape = self.grid.shape()
        far = self.numerics.phi_max * self.h
        X = jnp.asarray(self.grid.mesh("node"))
        ok = jnp.all(state.origin >= 0, axis=1)
        o = jnp.maximum(state.origin, 0)
        phi = jax.vmap(lambda p, oo: windows.to_grid(p, oo, shape, per, far))(state.phi, o)
        xi = jax.vmap(lambda x, oo: windows.put(X, x, oo, per))(state.xi, o)
        # a body that outgrew its window (origin -1): no values to show
        phi = jnp.where(ok.reshape((-1,) + (1,) * self.ndim), phi, jnp.nan)
        return state.replace(xi=xi, phi=phi, origin=None)

    def _window_maps(self, xi_w, origin, before: int, after: int):
        """A solid's map on its window (``(d, *W)``) made continuous across a periodic edge
        (``xi - x`` is what is periodic: the wrapped node's ``xi - x`` plus the unwrapped
        coordinates) with ``before`` and ``after`` linear ghost layers
        (:func:`refmap.windows.ghosted`; at a wall those of ``pad_affine``)."""
        W = xi_w.shape[1:]
        g = self.grid
        X = functools.partial(windows.coordinates, origin, W, g.lows, self.spacing, g.shape(), self.bc.periodic)
        cont = xi_w if not any(self.bc.periodic) else (xi_w - X()) + X(wrap=False)
        return windows.ghosted(cont, before, after, self.ndim)

    def default_params(self, fluid: FluidParams | None = None, gravity=None) -> Params:
        if gravity is None:
            gravity = (0.0,) * self.ndim
        if len(gravity) != self.ndim:
            raise ValueError(f"gravity must have {self.ndim} components on a {self.ndim}D grid, got {gravity!r}")
        return Params(
            fluid=fluid if fluid is not None else FluidParams(),
            laws=tuple(s.law for s in self.solids),
            gravity=tuple(float(x) for x in gravity),
        )

    # ------------------------------------------------------------------ time step
    def time_step(self, state: State, params: Params):
        """Adaptive dt = cfl * min(limits); returns (dt, index into LIMIT_NAMES).

        * viscous: h^2 rho_min / (4 (eta + extra_viscosity + bulk_viscosity)), explicit
          diffusion in 2D with the largest effective kinematic viscosity;
        * solid wave: h / c_L, the fastest small-strain wave of every law;
        * wave damping: 2 extra_viscosity / M (M the longitudinal modulus).  Forward Euler
          amplifies an undamped elastic wave; with the damping nu k^2 of the extra viscosity
          it multiplies a mode's energy by 1 - dt nu k^2 + (c k dt)^2 per step, which is
          <= 1 for dt <= nu / c^2 = extra_viscosity / M whatever the wavenumber, i.e. at
          the default cfl = 0.5 of the limit listed here (measured: the thesis's circle at
          64^2 blows up at 2x the listed limit and runs at 0.6x; the exact shear wave of
          validation/shear_wave.py stays at round-off for eight periods at 1x the energy
          bound); likewise 2 (eta + extra_viscosity) / lambda_f for sound in the fluid.
          A limit whose viscosity is zero is skipped (forward Euler then slowly amplifies
          waves at any dt, so inviscid runs need some viscosity);
        * fluid sound: h / sqrt(lambda_f / rho0);
        * convective: h / max(|u| + |v|).

        With ``Numerics.fluid_model = "incompressible"`` there is no sound in the fluid: the
        fluid-sound limit and the fluid's wave-damping bound are dropped (the solids' stay).

        With ``Numerics.viscosity = "implicit"`` the viscous limit is dropped (backward
        Euler), and so is the wave-damping limit: the transported fields (reference maps,
        fluid density) are then updated with the new velocity (symplectic Euler), under
        which an undamped elastic or sound wave is stable up to its own CFL limit (solid
        wave, fluid sound).  Implicit damping alone would not lift it: for a mode u' = v,
        rho v' = -M k^2 u - nu k^2 v, forward Euler for u with backward Euler for the
        damping multiplies the energy by (1 + dt^2 c^2 k^2) / (1 + dt nu k^2) per step,
        stable only for dt <= nu / c^2, as explicit (measured: the circle at 64^2 gains
        energy at 1.0x the limit either way; the lid-driven cavity at dt = h / (2 c) blows
        up unless the density moves with the new velocity too).
        """
        h = self.h
        fl = params.fluid
        # from the numerics alone (Case._check_dt_fixed calls this on a stand-in model)
        implicit = self.numerics.viscosity == "implicit"
        rho_min = fl.rho0
        c_solid = jnp.asarray(1e-30)
        M_max = jnp.asarray(1e-30)
        if params.laws:  # (the laws of one class batched: the code does not grow with them)
            _, M, rho0 = law_moduli(params.laws)
            rho_min = jnp.minimum(rho_min, jnp.min(rho0))
            c_solid = jnp.maximum(c_solid, jnp.max(jnp.sqrt(M / rho0)))
            M_max = jnp.maximum(M_max, jnp.max(M))
        nu = (fl.eta + fl.extra_viscosity + fl.bulk_viscosity) / rho_min
        speed = jnp.abs(state.v[0]) + jnp.abs(state.v[1])
        for a in range(2, self.ndim):
            speed = speed + jnp.abs(state.v[a])
        vmax = jnp.max(speed)
        damping = jnp.where(
            (fl.extra_viscosity > 0) & (len(params.laws) > 0),
            2.0 * fl.extra_viscosity / M_max,
            jnp.inf,
        )
        incompressible = self.numerics.fluid_model == "incompressible"
        if not incompressible:
            # the same bound for sound waves in the fluid, damped by eta and the extra
            # viscosity (an incompressible fluid has no sound: only the solids' bound)
            nu_f = fl.eta + fl.extra_viscosity + fl.bulk_viscosity
            damping = jnp.minimum(damping, jnp.where(nu_f > 0, 2.0 * nu_f / fl.lambda_f, jnp.inf))
        if implicit:  # symplectic transport: no damping limit
            damping = jnp.asarray(jnp.inf)
        sound = jnp.asarray(jnp.inf) if incompressible else h / fl.sound_speed
        # explicit diffusion: h^2 / (2 d nu)
        viscous = h * h / ((4.0 if self.ndim == 2 else 6.0) * jnp.maximum(nu, 1e-30))
        if implicit:  # backward Euler: no viscous limit
            viscous = jnp.asarray(jnp.inf)
        limits = jnp.stack(
            [
                viscous,
                h / c_solid,
                damping,
                sound,
                h / jnp.maximum(vmax, 1e-30),
            ]
        )
        i = jnp.argmin(limits)
        dt = self.numerics.cfl * limits[i]
        if self.numerics.dt_fixed is not None:
            return jnp.asarray(self.numerics.dt_fixed, dtype=jnp.float64), jnp.asarray(LIMIT_NAMES.index("fixed"))
        if self.numerics.dt_max is not None:
            use_max = dt > self.numerics.dt_max
            dt = jnp.where(use_max, self.numerics.dt_max, dt)
            i = jnp.where(use_max, LIMIT_NAMES.index("dt_max"), i)
        return dt, i

    # ------------------------------------------------------------------ derived fields
    def _blur_mass(self, rho, wf_c, wf_n, rho_f, params):
        """The node mass of the momentum update (``Numerics.blur_mass``): ``rho`` itself
        (``"node"``), or (``"corners"``) at least ``rho_f + w_c (rho_s - rho_f)`` where
        ``w_c``, the largest solid fraction ``1 - wf_c`` among the node's ``2^d`` corners,
        is more than :data:`BLUR_MASS_RATIO` times the node's own ``1 - wf_n``; ``rho_s``
        the largest solid reference density."""
        if self.numerics.blur_mass == "node" or not self.n_solids:
            return rho
        nd = self.ndim
        ws_c = 1.0 - wf_c
        w_max = None
        for offset in itertools.product((0, 1), repeat=nd):
            corner = ws_c[tuple(slice(o, ws_c.shape[a] - 1 + o) for a, o in enumerate(offset))]
            w_max = corner if w_max is None else jnp.maximum(w_max, corner)
        rho_s = jnp.max(jnp.stack([jnp.asarray(law.rho0, dtype=rho.dtype) for law in params.laws]))
        lifted = jnp.maximum(rho, rho_f + w_max * (rho_s - rho_f))
        return jnp.where(BLUR_MASS_RATIO * (1.0 - wf_n) < w_max, lifted, rho)

    def derived(self, state: State, params: Params, viscous: bool = True):
        """Corner and node fields recomputed from the state (stresses, weights, density).

        ``viscous=False`` leaves the fluid's viscous stress out of the mixed stress (the
        implicit viscous step adds it separately, :mod:`refmap.viscosity`)."""
        sp = self.spacing
        nd = self.ndim
        fl = params.fluid
        bc = self.bc
        core = self._core(1)
        vp = bc.pad_velocity(state.v, state.t)
        rp = bc.pad_density(state.rho_f, state.t, fl.rho0)
        vp1 = vp[core]
        rp1 = rp[core]

        # fluid stress at corners: pressure from the bottom-left node (as the thesis's code),
        # viscous part eta * sym(grad v) with the bottom-left-triangle gradient
        p = fl.lambda_f * (rp1[(Ellipsis,) + (slice(None, -1),) * nd] / fl.rho0 - 1.0)
        dv = [grad_corner(vp1[a], *sp) for a in range(nd)]  # dv[a][b] = d v_a / d x_b
        div_corner = dv[0][0] + dv[1][1]  # corner divergence of v (bottom-left triangle)
        for a in range(2, nd):
            div_corner = div_corner + dv[a][a]
        if viscous:
            bulk = fl.bulk_viscosity * div_corner
            s_f = []
            for a, b in SYM_PAIRS[nd]:
                if a == b:
                    s_f.append(-p + fl.eta * dv[a][a] + bulk)
                else:
                    s_f.append(0.5 * fl.eta * (dv[a][b] + dv[b][a]))
        else:
            s_f = [-p if a == b else jnp.zeros_like(p) for a, b in SYM_PAIRS[nd]]

        out = dict(p_corner=p, div_corner=div_corner)
        N = self.n_solids
        if N == 0:
            out.update(_stress_keys(s_f, nd), rho=state.rho_f,
                       wf_c=jnp.ones_like(p), wf_n=jnp.ones_like(state.rho_f))
            return out

        if self.windowed(state):
            # the solids stored in windows (Numerics.solid_storage "window"): the mixed
            # fields from the windows themselves, no solid's field on the whole grid (the
            # per-solid fields of diagnostics and output come from on_grid(state))
            s_mix, rho, wf_c, wf_n = self._mixed_on_state_windows(s_f, state, params)
            rho = self._blur_mass(rho, wf_c, wf_n, state.rho_f, params)
            out.update(_stress_keys(s_mix, nd), rho=rho, wf_c=wf_c, wf_n=wf_n,
                       band_windows=(state.origin, jnp.all(state.origin >= 0, axis=1)))
            return out

        # two ghost layers, as the map advection of the step pads them (one pad for both);
        # the tiles read them in place, the full-grid fields from one layer
        phip2 = bc.pad_linear(state.phi)
        xip2 = bc.pad_affine(state.xi)
        phip, xip = phip2[core], xip2[core]
        f = self._solids_full(s_f, state.rho_f, state.phi, phip, xip, params)
        s_mix, rho, wf_c, wf_n = f.pop("mixed")
        if self.solid_window is not None:
            # the mixed fields from one window per solid (Numerics.solid_storage "window")
            s_mix, rho, wf_c, wf_n = self._mixed_on_windows(
                s_f, state.rho_f, state.phi, state.xi, params,
                lambda: self._solids_full(s_f, state.rho_f, state.phi, phip2[core], xip2[core], params)["mixed"])
        elif self.solid_tiles is not None:
            # the mixed fields from each solid's tiles (the per-solid fields stay the
            # full-grid ones, for diagnostics and output; inside the step nothing reads them
            # in the default configuration and XLA drops them)
            s_mix, rho, wf_c, wf_n = self._mixed_on_tiles(
                s_f, state.rho_f, phip2, xip2, params,
                lambda: self._solids_full(s_f, state.rho_f, state.phi, phip2[core], xip2[core], params)["mixed"])
        rho = self._blur_mass(rho, wf_c, wf_n, state.rho_f, params)
        out.update(_stress_keys(s_mix, nd), rho=rho, wf_c=wf_c, wf_n=wf_n, **f)
        if self.solid_band_window is not None:
            # where each solid's band window goes this step: the band work and the contact
            # (refmap.contact) use them
            out["band_windows"] = self._band_placement(state.phi)
        return out

    def _solids_full(self, s_f, rho_f, phi, phip, xip, params):
        """Every solid's fields of :meth:`derived` on the whole grid, and under ``"mixed"``
        the mixed stress components, density and fluid fractions made from them."""
        h = self.h
        sp = self.spacing
        nd = self.ndim
        n = self.numerics
        phic = corner_average(phip, nd)
        w = n.blur_width * h
        Hc = blend.heaviside(phic, n.blend, w)
        Hn = blend.heaviside(phi, n.blend, w)
        ws_c, wf_c = solid_fractions(Hc)
        ws_n, wf_n = solid_fractions(Hn)

        dxi = [grad_corner(xip[:, a], *sp) for a in range(nd)]  # dxi[a][b] = d xi_a / d x_b
        det, adj = _det_adjugate(dxi)  # det(grad xi) = 1 / J; F = (grad xi)^-1 = adj / det
        valid = (phic < n.stress_band * h) & (det > 1e-12)
        safe_det = jnp.where(valid, det, 1.0)
        F = adj / safe_det[..., None, None]
        F = jnp.where(valid[..., None, None], F, jnp.eye(nd))
        sig, rho0 = _solid_stresses(params.laws, F)
        sig = jnp.where(valid[..., None, None], sig, 0.0)
        rho0 = rho0.reshape((-1,) + (1,) * nd)
        rho_s = jnp.where(valid, rho0 * det, rho0)

        # the components by one split (its transpose is one concatenation; indexing each
        # component pads its cotangent to the whole tensor, three such buffers at the peak
        # of a step's backward pass)
        parts = jnp.split(sig.reshape(sig.shape[:-2] + (nd * nd,)), nd * nd, axis=-1)
        s_mix = [wf_c * sf + jnp.sum(ws_c * parts[a * nd + b][..., 0], axis=0)
                 for sf, (a, b) in zip(s_f, SYM_PAIRS[nd], strict=True)]
        rho = wf_n * rho_f + jnp.sum(ws_n * node_average(rho_s, nd), axis=0)
        return dict(
            mixed=(s_mix, rho, wf_c, wf_n), F=F, J=jnp.where(valid, 1.0 / safe_det, 1.0),
            valid=valid, sigma_s=sig, Hc=Hc, Hn=Hn, ws_c=ws_c, ws_n=ws_n, phic=phic,
        )

    def _mixed_on_windows(self, s_f, rho_f, phi, xi, params, full):
        """The mixed stress components, density and fluid fractions of :meth:`derived`
        from one window per solid (:func:`refmap.solid_tiles.mixed_from_windows`, windows of
        :attr:`solid_window` nodes placed on each solid's blend zone this step, cut from the
        unpadded level sets ``phi`` and maps ``xi`` by
        :func:`refmap.solid_tiles.cut_windows`, or from the padded grid fields when a solid
        is glued to a wall); ``full()`` (the same four on the whole grid)
        in a step where a solid's zone does not fit its window."""
        n = self.numerics
        W = self.solid_window
        periodic = self.bc.periodic
        # 1 - H is exactly 0 from the cutoff on; which nodes: no derivative
        reach = solid_tiles.cutoff(n.blend, n.blur_width * self.h) * (1.0 - 1e-12)
        origins, fits = jax.vmap(lambda p: windows.placement(p, reach, W, periodic))(
            lax.stop_gradient(phi))
        rho0 = jnp.stack([jnp.asarray(law.rho0, dtype=rho_f.dtype) for law in params.laws])

        def win(_):
            if self.bc._glue:  # a glued solid's wall ghosts are not the linear ones
                return _pack_mixed(*solid_tiles.mixed_on_windows(
                    s_f, rho_f, self.bc.pad_linear(phi), self.bc.pad_affine(xi), self.spacing,
                    origins, W, periodic, params.laws, rho0, _solid_stresses, self.h, n))
            phiw, xiw = solid_tiles.cut_windows(phi, xi, origins, W, self.grid.lows, self.spacing,
                                                periodic)
            return _pack_mixed(*solid_tiles.mixed_from_windows(
                s_f, rho_f, phiw, xiw, self.spacing, origins, W, periodic,
                params.laws, rho0, _solid_stresses, self.h, n, self.grid.shape()))

        def dense(_):
            return _pack_mixed(*full())

        flat = narrowband.switch(jnp.where(jnp.all(fits), 0, 1), [win, dense], None)
        return _unpack_mixed(flat, len(s_f), self.grid.shape())

    def _mixed_on_state_windows(self, s_f, state, params):
        """The mixed stress components, density and fluid fractions of :meth:`derived`
        from the windows in which the solids are stored (:attr:`state_window`):
        :func:`refmap.solid_tiles.mixed_from_windows` on each window with one ghost layer
        before it and two after (:func:`refmap.windows.ghosted`), the map continuous in it.
        The window holds every node within the blend's reach (``cutoff = phi_max h`` by
        default) with a margin, so nothing is left out."""
        nd = self.ndim
        o = jnp.maximum(state.origin, 0)
        S = o.shape[0]
        m = -(-S // solid_batch("mix"))
        laws = self._stacked_laws(params.laws) if m > 1 else None
        if laws is None:  # all at once
            phiw = jax.vmap(lambda p: windows.ghosted(p, 1, 2, nd))(state.phi)
            xiw = jax.vmap(lambda x, oo: self._window_maps(x, oo, 1, 2))(state.xi, o)
            rho0 = jnp.stack([jnp.asarray(law.rho0, dtype=state.rho_f.dtype) for law in params.laws])
            return solid_tiles.mixed_from_windows(
                s_f, state.rho_f, phiw, xiw, self.spacing, o, self.state_window, self.bc.periodic,
                params.laws, rho0, _solid_stresses, self.h, self.numerics, self.grid.shape())

        # in batches of the solids (as the band work): each batch's contributions added to
        # the padded sums window after window in the solids' order (windows.add_windows),
        # so the sums are those of all at once; the last batch is padded with copies of the
        # last solid whose contributions are multiplied by 0 (adding +-0: the same sums)
        B, pad, batches = _solid_batches(S, m)
        live = jnp.arange(m * B) < S

        def stress(law, F):  # the stacked laws of one batch (as _solid_stresses' vmap)
            return jax.vmap(lambda lw, f: lw.stress(f))(law, F), law.rho0

        def one(sums, batch):
            xi_b, phi_b, o_b, live_b, law_b = batch
            phiw = jax.vmap(lambda p: windows.ghosted(p, 1, 2, nd))(phi_b)
            xiw = jax.vmap(lambda x, oo: self._window_maps(x, oo, 1, 2))(xi_b, o_b)
            rho0 = jnp.asarray(law_b.rho0, dtype=state.rho_f.dtype)
            parts = solid_tiles.window_contributions(phiw, xiw, law_b, rho0, stress, self.h, self.spacing,
                                                     self.numerics)
            if pad:
                parts = tuple(jnp.where(live_b.reshape((-1,) + (1,) * (v.ndim - 1)), v, 0.0) for v in parts)
            return tuple(windows.add_windows(a, v, o_b) for a, v in zip(sums, parts, strict=True)), None

        sums = solid_tiles.window_sums(self.state_window, self.bc.periodic, self.grid.shape(), state.rho_f.dtype)
        sums, _ = lax.scan(one, sums, tuple(batches(a) for a in (state.xi, state.phi, o))
                           + (live.reshape(m, B), jax.tree_util.tree_map(batches, laws)))
        return solid_tiles.mix_window_sums(s_f, state.rho_f, sums, self.state_window, self.bc.periodic,
                                           self.grid.shape())

    def _stacked_laws(self, laws):
        """The laws stacked into one pytree (S, ...) when they are of one class and pytree
        structure (:func:`refmap.materials.law_groups`; the solids' stresses one ``vmap``,
        as ``materials.map_laws``), else None."""
        try:
            groups = law_groups(laws)
        except (ValueError, TypeError):  # leaves that do not stack
            return None
        return groups[0][1] if len(groups) == 1 else None

    def _mixed_on_tiles(self, s_f, rho_f, phip, xip, params, full):
        """The mixed stress components, density and fluid fractions of :meth:`derived`
        summed from each solid's tiles (:mod:`refmap.solid_tiles`); ``full()`` (the same
        four from the full grid) where a solid holds more tiles than the static capacity.
        ``phip``, ``xip``: the level sets and maps padded with two ghost layers."""
        n = self.numerics
        tile, caps_b, caps_s = self.solid_tiles
        cut = solid_tiles.cutoff(n.blend, n.blur_width * self.h)
        least = solid_tiles.window_min(lax.stop_gradient(phip), tile, 1)  # which tiles: no derivative
        flags_b, flags_s = least < cut, least < n.stress_band * self.h
        cshape = tuple(s + 1 for s in self.grid.shape())
        nshape = self.grid.shape()
        rho0 = jnp.stack([jnp.asarray(law.rho0, dtype=rho_f.dtype) for law in params.laws])

        def tiled(cap_b, cap_s):
            def run(_):
                lb = solid_tiles.Listed(flags_b, cap_b)
                wc, wn = solid_tiles.blend_contributions(
                    solid_tiles.gather(phip, lb, tile, jnp.inf, 1), rho0, self.h, n)
                ls = solid_tiles.Listed(flags_s, cap_s)
                sig, drho = solid_tiles.stress_contributions(
                    solid_tiles.gather(phip, ls, tile, jnp.inf, 1), solid_tiles.gather(xip, ls, tile, 0.0, 1),
                    params.laws, _solid_stresses, self.h, self.spacing, n)
                Tc = solid_tiles.scatter_add(wc, lb, tile, cshape)[0]
                Bn, Tn = solid_tiles.scatter_add(wn, lb, tile, nshape)
                A = solid_tiles.scatter_add(sig, ls, tile, cshape)
                Bn = Bn + solid_tiles.scatter_add(drho, ls, tile, nshape)[0]
                return _pack_mixed(*solid_tiles.mix(s_f, rho_f, tuple(A), Tc, Bn, Tn))
            return run

        def dense(_):
            return _pack_mixed(*full())

        # the first rung that holds every solid's tiles of both lists; past the last: full grid
        level = jnp.maximum(narrowband.ladder_level(flags_b, caps_b), narrowband.ladder_level(flags_s, caps_s))
        branches = [tiled(b, c) for b, c in zip(caps_b, caps_s, strict=True)] + [dense]
        flat = narrowband.switch(level, branches, None)
        return _unpack_mixed(flat, len(s_f), nshape)

    @property
    def _advect(self):
        """The ENO advection of the step: :func:`refmap.operators.advect`, or with
        :attr:`hand_transposes` :func:`refmap.operators.advect_lowmem`, the same values with
        a hand-written reverse mode that holds less memory in a step's backward pass."""
        return advect_lowmem if self.hand_transposes else advect

    def _advect_maps(self, xi, xip, vel, phi, dt):
        """Step 1: the maps advected (ENO) where ``phi < (band - 3) h``, kept elsewhere.
        With solids on tiles (:attr:`solid_tiles`) on each solid's node tiles that hold
        such a node (:func:`refmap.solid_tiles.advect_maps`, same values), in the stress
        list's capacities (a tile with a node within ``(band - 3) h`` is within
        ``stress_band`` when ``band - 3 <= stress_band``, as by default); the full grid
        where a solid holds more tiles or an axis is shorter than a tile."""
        limit = (self.numerics.band - 3.0) * self.h

        def dense(_):
            return jnp.where((phi < limit)[:, None], xi + dt * self._advect(xip, vel, *self.spacing), xi)

        if self.solid_tiles is None:
            return dense(None)
        tile, _, caps = self.solid_tiles
        if any(n < t for n, t in zip(self.grid.shape(), tile, strict=True)):
            return dense(None)
        flags = jax.vmap(lambda p: narrowband.tile_flags(p < limit, tile))(lax.stop_gradient(phi))
        level = narrowband.ladder_level(flags, caps)

        def tiled(cap):
            return lambda _: solid_tiles.advect_maps(xi, xip, vel, phi, limit, flags, cap, tile,
                                                     self.spacing, dt, advect=self._advect)

        return narrowband.switch(level, [tiled(c) for c in caps] + [dense], None)

    @property
    def _band_reach(self) -> float:
        """The level below which a node is in a band window's box: just under ``phi_max h``
        (the clipped nodes stay out)."""
        return self.numerics.phi_max * self.h * (1.0 - 1e-9)

    def _band_placement(self, phi, window=None):
        """``(origins (S, d), fits)``: the band windows of :meth:`_band_on_windows` (of
        ``window`` nodes, default :attr:`solid_band_window`) placed on the level sets
        ``phi``, round each solid's nodes with ``phi < phi_max h``."""
        reach = self._band_reach
        W = self.solid_band_window if window is None else window
        return jax.vmap(lambda p: windows.placement(p, reach, W, self.bc.periodic, margin=BAND_WINDOW_MARGIN))(
            lax.stop_gradient(phi))

    def _advect_window(self, xi_w, phi_w, xip, v_w, dt):
        """Step 1 on one solid's window: the map ``xi_w`` advected (ENO, from ``xip``, the
        map continuous with two ghost layers) with the window's velocity ``v_w`` where
        ``phi_w < (band - 3) h``, kept elsewhere."""
        limit = (self.numerics.band - 3.0) * self.h
        return jnp.where(phi_w < limit, xi_w + dt * self._advect(xip, v_w, *self.spacing), xi_w)

    def _pin_and_extend_windows(self, xi_w, phi_w, X, dt, table=None):
        """Step 9 on every solid's window: the level sets pinned to the maps and
        re-distanced, then the maps (less the windows' node coordinates ``X``) extended and
        smoothed in the windows.  Returns ``(xi_w, phi_w)``."""
        phi_w = self.pin(phi_w, xi_w, dt, periodic=(False,) * self.ndim, table=table)
        return self._extend_all(xi_w - X, phi_w, windowed=True) + X, phi_w

    def _band_on_windows(self, xi, phi, vel, dt, placed=None):
        """Steps 1 and 9 of :meth:`step` (map advection, pinning and re-distancing,
        extrapolation and smoothing) on one window of :attr:`solid_band_window` nodes per
        solid, placed round the nodes with ``phi < phi_max h`` (``Numerics.solid_storage =
        "window"``).  The maps and level sets are gathered from the grid (on a periodic axis
        the window wraps round and the map is made continuous in it; at a wall its ghosts
        are :func:`refmap.windows.gather_ghosted`'s linear ones, as ``pad_affine``'s), the
        phases run on the windows as they run on the grid, and the windows are written
        back.  Outside a window nothing changes in the grid's phases either (the level set
        is clipped at ``phi_max h`` there and the maps are neither advected nor extended), so
        the result is the whole grid's to round-off.  A step in which a body's box does not
        fit its window runs the phases on the whole grid."""
        W = self.solid_band_window
        per = self.bc.periodic
        g = self.grid
        shape = g.shape()
        sp = self.spacing
        origins, fits = self._band_placement(phi) if placed is None else placed
        padded = tuple(w + 4 for w in W)

        def cut(xi_k, phi_k, o):
            X = windows.coordinates(o, W, g.lows, sp, shape, per)  # the nodes gather reads
            xi_w = windows.gather(xi_k, o, W, per)
            phi_w = windows.gather(phi_k, o, W, per)
            v_w = windows.gather(vel, o, W, per)
            # two ghost layers, the map continuous across a periodic edge: as
            # BoundaryConditions.pad_affine on the grid
            xip = solid_tiles.cut_map(xi_k, o, padded, g.lows, sp, per, offset=-2)
            return self._advect_window(xi_w, phi_w, xip, v_w, dt), phi_w, X

        def win(_):
            xi_w, phi_w, X = jax.vmap(cut)(xi, phi, origins)
            xi_w, phi_w = self._pin_and_extend_windows(xi_w, phi_w, X, dt)
            put = functools.partial(windows.put, periodic=per)
            return jax.vmap(put)(xi, xi_w, origins), jax.vmap(put)(phi, phi_w, origins)

        def dense(_):
            xi_new = self._advect_maps(xi, self.bc.pad_affine(xi), vel, phi, dt)
            phi_new = self.pin(phi, xi_new, dt)
            return self.extrapolate(xi_new, phi_new), phi_new

        return narrowband.switch(jnp.where(jnp.all(fits), 0, 1), [win, dense], None)

    def _band_on_state_windows(self, state: State, vel, dt):
        """Steps 1 and 9 of :meth:`step` on the windows in which the solids are stored
        (:attr:`state_window`): the work of :meth:`_band_on_windows` without a gather or a
        write-back, then each window moved to where :func:`refmap.windows.placement` puts
        it round the new level set (:func:`refmap.windows.follow`), the nodes that enter it
        taking the far level set ``phi_max h`` and the identity map (beyond the band: no
        phase reads them).  A body whose band no longer fits its window gets the origin -1
        (:meth:`advance` stops there and says so).

        Each solid's band work reads only its own window and the grid's velocity, so more
        than ``solid_batch("band")`` solids of one shape kind are worked on in equal
        batches of at most that many (``lax.map``; the last batch padded with copies of the
        last solid, dropped after), with the same values bit for bit: the temporaries of
        the sweeps' tiles then do not grow with the number of solids (1000 discs at 1024^2:
        0.99 GB for all at once), and a batch's arrays stay in the caches."""
        S = state.xi.shape[0]
        m = -(-S // solid_batch("band"))
        shapes = self._shape_table() if m > 1 else None
        if shapes is None:  # one batch (or solids of several shape kinds: not batched)
            return self._band_on_windows_batch(state.xi, state.phi, state.origin, None, vel, dt)
        B, _, batched = _solid_batches(S, m)
        table = jnp.asarray(shapes[1])
        out = lax.map(lambda a: self._band_on_windows_batch(*a, vel, dt),
                      tuple(batched(a) for a in (state.xi, state.phi, state.origin, table)))
        return tuple(a.reshape((m * B,) + a.shape[2:])[:S] for a in out)

    def _band_on_windows_batch(self, xi, phi, origin, table, vel, dt):
        """:meth:`_band_on_state_windows` for the solids whose windows are ``xi`` (S, d,
        *W), ``phi`` (S, *W), ``origin`` (S, d); ``table``: their rows of
        :meth:`_shape_table` when they are a batch of the solids (None: all of them)."""
        W = self.state_window
        per = self.bc.periodic
        g = self.grid
        shape = g.shape()
        sp = self.spacing
        o = jnp.maximum(origin, 0)

        def advect_one(xi_k, phi_k, oo):
            v_w = windows.gather(vel, oo, W, per)
            return self._advect_window(xi_k, phi_k, self._window_maps(xi_k, oo, 2, 2), v_w, dt)

        xi_w = jax.vmap(advect_one)(xi, phi, o)
        X = jax.vmap(lambda oo: windows.coordinates(oo, W, g.lows, sp, shape, per))(o)
        xi_w, phi_w = self._pin_and_extend_windows(xi_w, phi, X, dt, table)

        reach = self._band_reach
        new, fits = jax.vmap(lambda p, oo: windows.follow(p, oo, reach, shape, per, margin=BAND_WINDOW_MARGIN))(
            lax.stop_gradient(phi_w), o)
        far = jnp.asarray(self.numerics.phi_max * self.h, phi_w.dtype)

        def move(xi_k, phi_k, old, oo):
            kept = windows.shift(jnp.ones(W, phi_k.dtype), old, oo, shape, per, 0.0) > 0.5
            X_new = windows.coordinates(oo, W, g.lows, sp, shape, per)
            xi_k = jnp.where(kept, windows.shift(xi_k, old, oo, shape, per, 0.0), X_new)
            return xi_k, windows.shift(phi_k, old, oo, shape, per, far)

        xi_w, phi_w = jax.vmap(move)(xi_w, phi_w, o, new)
        ok = jnp.all(origin >= 0, axis=1) & fits
        return xi_w, phi_w, jnp.where(ok[:, None], new, -1)

    def conserve_fluid_mass(self, rho_f, wf_old, rho_new, phi_new):
        """``rho_new`` shifted so that the fluid's mass ``sum(w_f rho_f)`` is the one before
        the step (``Numerics.fluid_mass = "conserved"``, closed boxes only).

        The shift is ``c w_f`` with ``c = dm / sum(w_f^2)``: the mass goes where the fluid
        is, in proportion to its fraction, and none into the solids.  In the thesis's
        update the fluid density is advected (not a conservation law) and the fluid
        fraction follows the pinned level set: where the interface moves otherwise than the
        flow, fluid mass is made or lost, and a closed box's solids stretch or shrink to
        make up the pressure (the lid-driven cavity's disc: +21 % area by t = 12 at 32^2;
        docs/method.md, "Known weaknesses", swelling item (d))."""
        n = self.numerics
        w = n.blur_width * self.h
        wf_new = solid_fractions(blend.heaviside(phi_new, n.blend, w))[1]
        dm = jnp.sum(wf_old * rho_f) - jnp.sum(wf_new * rho_new)
        return rho_new + dm * wf_new / jnp.maximum(jnp.sum(wf_new**2), 1e-300)

    def volume_source(self, derived, dt):
        """The divergence the projection imposes (incompressible fluid), or None.

        With ``Numerics.volume_correction = r > 0`` each solid's volume error is taken out
        at the rate ``D v = -min(r, 1 / dt) ln(J)`` where it is (the top-right corner of each
        node, where ``D`` is taken, weighted by the solid's blend fraction there): ln J
        relaxes like exp(-r t).  ``J`` drifts because the maps are advected with the node
        velocities, whose ENO divergence is not the projection's ``D`` (docs/method.md,
        "Incompressible fluid").  Without an outflow edge the sources must cancel: the
        fluid takes the opposite volume change, spread in proportion to its fraction (it is
        the volume the fluid lost to the solids' drift)."""
        rate = self.numerics.volume_correction
        if rate == 0.0 or self.n_solids == 0 or self.projection is None:
            return None
        rate = jnp.minimum(rate, 1.0 / dt)  # at most the whole error in one step
        # only the material's own nodes (phi < 0 at the corner): the extrapolated band's J
        # is re-made from the interior every step and does not respond to a divergence
        # there (correcting it too made the lid cavity's disc vanish at 32^2 by t = 6)
        top = (slice(1, None),) * self.ndim  # each node's top-right corner
        inside = derived["phic"][(slice(None),) + top] < 0.0
        ws = derived["ws_c"][(slice(None),) + top]
        logJ = jnp.where(inside, jnp.log(derived["J"][(slice(None),) + top]), 0.0)
        src = -rate * jnp.sum(ws * logJ, axis=0)
        keep = self.projection.keep
        wf = derived["wf_c"][top] * keep
        if self._anchor_free is not None:
            # nodes an anchor holds take no source: their rows of A can be null (all four
            # velocities held), and even a round-off source there made CG diverge (rotor at
            # 96^2, third step); the anchors hold J = 1 there anyway
            src = src * self._anchor_free
            wf = wf * self._anchor_free
        if self.projection.has_outflow:
            return src
        total = jnp.sum(src * keep)
        return src - total * wf / jnp.maximum(jnp.sum(wf), 1e-300)

    # ------------------------------------------------------------------ the step
    def step(self, state: State, params: Params, dt, return_pressure: bool = False,
             first_iterates=None):
        """One step of size dt.  ``return_pressure`` (incompressible fluid only): return
        the projection's pressure (nx, ny) of this step instead of the new state (for
        output, :meth:`output_fields`; plain CG, not differentiable); ``"info"``: the
        pressure and the CG solver's info (iterations, residual, converged).

        ``first_iterates``: a dict of first iterates for the step's linear solves, keyed as
        :meth:`solver_keys` (``"viscous"``: the implicit viscous solve's increment
        ``v^{n+1} - v*``, shaped like ``state.v``; ``"pressure"``: the projection's
        pressure, shaped like ``state.rho_f``); the step then returns ``(state,
        solutions)`` with this step's solutions under the same keys.  :meth:`advance`
        passes the solutions of the last two steps extrapolated, which saves iterations
        and changes the answer only within the solvers' tolerances."""
        g = self.grid
        sp = self.spacing
        nd = self.ndim
        n = self.numerics
        fl = params.fluid
        bc = self.bc
        t = state.t
        v, rho_f = state.v, state.rho_f

        implicit = self.implicit_viscosity is not None
        d = self.derived(state, params, viscous=not implicit)
        vp = bc.pad_velocity(v, t)
        rp = bc.pad_density(rho_f, t, fl.rho0)

        # 6. updates of v and rho_f (with implicit viscosity: every term but the viscous
        # ones here, then the backward-Euler viscous solve, refmap.viscosity)
        divs = div_node(*d["s"], *sp)
        if n.band_force == "solid" and self.n_solids:
            divs = divs + self.band_force_to_solid(state, d)
        lap = laplacian_lowmem if self.hand_transposes else laplacian
        force = divs if implicit else divs + fl.extra_viscosity * lap(vp, *sp, g=2)
        ctx = dict(state=state, params=params, derived=d, model=self)
        for term in self.body_forces:
            force = force + term(ctx)
        acc = self._advect(vp, v, *sp) + force / d["rho"][None] + self._vec(params.gravity)
        # rho_f is the fluid's density; inside a solid there is no fluid to compress, so the
        # compression term is weighted by the fluid fraction and rho_f is only carried
        # there.  (Unweighted, a steady converging solid velocity -- at the edge of the
        # stick's anchor -- grows rho_f exponentially inside the solid, where no fluid
        # pressure pushes back: the thesis's stick at 128^2 blew up at t ~ 9.)
        v_new = v + dt * acc
        # incremental projection: the predictor carries the last step's pressure gradient
        # and the projection solves for the increment (zero at a steady state), so the
        # implicit viscous solve acts on a velocity that already has it; the steady state
        # then no longer depends on dt (method.md, "Incremental projection")
        incremental = self.projection is not None and state.p is not None
        if incremental:
            v_new = self.projection.correct(v_new, state.p, d["rho"], dt, self._anchor_free)
        guesses = first_iterates if first_iterates is not None else {}
        solutions = {}
        xi0 = None if self._xi0 is None else jnp.asarray(self._xi0)  # (anchors only)
        if implicit:
            if self.projection is not None:
                # the edges' normal components that the projection prescribes are held in
                # the solve too: solved free, the solve moved them and the projection then
                # reset them, so a steady state still depended on dt next to the edges
                v_new = self.projection.prescribe(v_new, t + dt)
            if self._anchors_in_solve:
                # region anchors first: their nodes enter the solve with the held velocity
                # and keep it (the free nodes' viscous force sees the body at rest; solved
                # free, the held nodes' predictor velocity dt a, which is the body's load,
                # leaked into the fluid's wall shear: CFD1's steady drag moved with dt)
                for k, s in enumerate(self.solids):
                    if getattr(s.anchor, "velocity_weight", None) is not None:
                        v_new, _ = s.anchor.apply(g, v_new, state.xi[k], xi0[k])
            v_star = v_new
            v_new = self.implicit_viscosity.solve(v_new, d["rho"], d["wf_c"], fl, t + dt, dt,
                                                  guess=guesses.get("viscous"),
                                                  free=self._viscous_free)
            solutions["viscous"] = v_new - v_star

        def done(new_state):
            return new_state if first_iterates is None else (new_state, solutions)

        # the anchors' velocities come before anything that moves with the new velocity:
        # the projection (incompressible: their nodes keep them, correction weight
        # 1 - w_anchor, so the projected velocity is divergence-free with them) and the
        # symplectic transport of implicit viscosity (the maps of a held hub must move
        # with the held velocity, not with the free one the solve gives)
        anchors_first = implicit or self.projection is not None
        if anchors_first:
            for k, s in enumerate(self.solids):
                if s.anchor is not None:
                    v_new, _ = s.anchor.apply(g, v_new, state.xi[k], xi0[k])
        if implicit:
            # the transported fields move with the updated velocity (symplectic Euler, see
            # time_step): the fluid density here, the reference maps below
            vq, vqp = v_new, bc.pad_velocity(v_new, t + dt)
        else:
            vq, vqp = v, vp
        if self.projection is not None:
            # incompressible: the fluid pressure is the projection's (rho_f stays rho0, so
            # the pressure lambda_f (rho_f / rho0 - 1) in the stress above is zero)
            warm = first_iterates is not None and not return_pressure
            projected = self.projection.project(v_new, d["rho"], t + dt, dt,
                                                weight=self._anchor_free,
                                                source=self.volume_source(d, dt),
                                                return_info=return_pressure,
                                                guess=guesses.get("pressure"),
                                                return_solution=warm or incremental)
            base = state.p if incremental else 0.0
            if return_pressure == "info":
                return base + projected[1], projected[2]
            if return_pressure:
                return base + projected[1]
            if warm or incremental:
                projected, increment = projected
                if warm:
                    solutions["pressure"] = increment
                if incremental:
                    p_new = state.p + increment
            v_new = projected
            if implicit:
                vq = v_new
            rho_new = rho_f
        elif n.compression == "corner":
            # the divergence at each node's top-right corner (a forward difference): the
            # negative transpose of the backward pressure gradient that div_node makes of
            # the bottom-left-node corner pressure (see Numerics), with that corner's fluid
            # fraction
            if implicit:
                vq1 = vqp[self._core(1)]
                div_c = grad_corner(vq1[0], *sp)[0] + grad_corner(vq1[1], *sp)[1]
                for a in range(2, nd):
                    div_c = div_c + grad_corner(vq1[a], *sp)[a]
            else:
                div_c = d["div_corner"]
            top = (Ellipsis,) + (slice(1, None),) * nd
            compression = d["wf_c"][top] * div_c[top]
        else:
            compression = d["wf_n"] * divergence_centered(*vqp, *sp, g=2)
        if self.projection is None:
            drho = self._advect(rp, vq, *sp) - rho_f * compression
            rho_new = rho_f + dt * drho

        if incremental:
            state = state.replace(p=p_new)
        if self.n_solids == 0:
            return done(state.replace(t=t + dt, step=state.step + 1, v=v_new, rho_f=rho_new))

        origin_new = state.origin
        if self.windowed(state):
            # steps 1 and 9 below on the windows in which the solids are stored, which then
            # follow their bodies
            xi_new, phi_new, origin_new = self._band_on_state_windows(state, vq, dt)
        elif self.solid_band_window is not None:
            # steps 1 and 9 below on one window per solid (Numerics.solid_storage "window";
            # no anchors there)
            xi_new, phi_new = self._band_on_windows(state.xi, state.phi, vq, dt, d.get("band_windows"))
        else:
            # 1. reference-map advection inside each solid and the inner part of its band
            # with implicit viscosity the maps move with the updated velocity (symplectic
            # Euler for the elastic waves: no damping needed for their stability, see
            # time_step)
            xi_new = self._advect_maps(state.xi, bc.pad_affine(state.xi), vq, state.phi, dt)

            # 8. anchors
            xi0 = None if self._xi0 is None else jnp.asarray(self._xi0)  # (anchors only)
            for k, s in enumerate(self.solids):
                if s.anchor is not None:
                    v_k, xk = s.anchor.apply(g, v_new, xi_new[k], xi0[k])
                    if not anchors_first:  # else applied to the velocity above
                        v_new = v_k
                    xi_new = xi_new.at[k].set(xk)

            # 9. pin the level sets, then extrapolate and smooth the maps
            phi_new = self.pin(state.phi, xi_new, dt)
            xi_new = self.extrapolate(xi_new, phi_new)
        if n.fluid_mass == "conserved" and self.projection is None:
            rho_new = self.conserve_fluid_mass(rho_f, d["wf_n"], rho_new, phi_new)
        return done(state.replace(t=t + dt, step=state.step + 1, v=v_new, rho_f=rho_new, xi=xi_new,
                                  phi=phi_new, origin=origin_new))

    def solver_keys(self) -> tuple:
        """The step's linear solves that :meth:`advance` warm-starts: ``"viscous"`` with
        implicit viscosity, ``"pressure"`` with the incompressible fluid."""
        return (("viscous",) if self.implicit_viscosity is not None else ()) + (
            ("pressure",) if self.projection is not None else ())

    # ------------------------------------------------------------------ loops
    def advance(self, state: State, params: Params, t_target, max_steps: int = 10**9,
                speed_limit=jnp.inf):
        """Step until ``t_target`` (the last step is shortened to land on it exactly).

        Stops early if any prognostic field stops being finite, dt collapses or the largest
        speed exceeds ``speed_limit`` (the Simulation passes 10 times the fastest speed
        the case sets up; see :mod:`refmap.simulation`).  Returns ``(state, info)`` with
        info = dict(steps, ok, dt, limit, dt_min, dt_max).
        """

        def finite(s):
            return (
                jnp.all(jnp.isfinite(s.v))
                & jnp.all(jnp.isfinite(s.rho_f))
                & jnp.all(jnp.isfinite(s.xi))
                & jnp.all(jnp.isfinite(s.phi))
            )

        def cond(c):
            s, k, ok, *_ = c
            return (s.t < t_target - 1e-12) & ok & (k < max_steps)

        keys = self.solver_keys()

        def body(c):
            s, k, ok, dt_last, lim_last, dtmin, dtmax, history = c
            dt, lim = self.time_step(s, params)
            rem = t_target - s.t
            short = rem < dt * (1 + 1e-9)
            dt = jnp.where(short, rem, dt)
            lim = jnp.where(short, LIMIT_NAMES.index("output"), lim)
            if keys:
                # each solve starts from its solution of the last two steps extrapolated
                # linearly in time (after the first step only the last, before it zero);
                # the viscous increment scales with dt, so it is carried per unit time
                last, before, dt1 = history
                slope = jnp.where(k >= 2, dt / jnp.where(dt1 > 0, dt1, 1.0), 0.0)
                # the incremental projection solves for the pressure's increment (State.p
                # carries the pressure): a time difference, carried per unit time and
                # continued at its last rate, which is the linear extrapolation of the
                # pressure itself; extrapolating the increment linearly too made the
                # guess worse than none (incompressible rotor 128^2: 23.6 against 15.3 ms
                # per step)
                incremental = s.p is not None
                scale = {"viscous": dt, "pressure": dt if incremental else 1.0}
                slopes = {"viscous": slope, "pressure": 0.0 if incremental else slope}
                guess = {key: scale[key] * (last[key] + slopes[key] * (last[key] - before[key]))
                         for key in keys}
                s2, solved = self.step(s, params, dt, first_iterates=guess)
                history = ({key: solved[key] / scale[key] for key in keys}, last, dt)
            else:
                s2 = self.step(s, params, dt)
            v2 = s2.v[0] ** 2 + s2.v[1] ** 2
            for a in range(2, self.ndim):
                v2 = v2 + s2.v[a] ** 2
            speed = jnp.sqrt(jnp.max(v2))
            ok2 = finite(s2) & (dt > 1e-14) & ~(speed > speed_limit)
            if s2.origin is not None:  # a body outgrew its window (solid_storage "window")
                ok2 = ok2 & jnp.all(s2.origin >= 0)
            # report the last full step (the landing step is only a remainder)
            keep = short & (k > 0)
            dt_rep = jnp.where(keep, dt_last, dt)
            lim_rep = jnp.where(keep, lim_last, lim)
            dtmin = jnp.where(short, dtmin, jnp.minimum(dtmin, dt))
            return (s2, k + 1, ok2, dt_rep, lim_rep, dtmin, jnp.maximum(dtmax, dt), history)

        z = jnp.asarray(0.0)
        shapes = {"viscous": state.v, "pressure": state.rho_f}
        zeros = {key: jnp.zeros_like(shapes[key]) for key in keys}
        history = (zeros, zeros, z) if keys else ()
        init = (state, jnp.asarray(0), jnp.asarray(True), z, jnp.asarray(0), jnp.asarray(jnp.inf), z, history)
        s, k, ok, dt, lim, dtmin, dtmax, _ = jax.lax.while_loop(cond, body, init)
        return s, dict(steps=k, ok=ok, dt=dt, limit=lim, dt_min=dtmin, dt_max=dtmax)

    def run_steps(self, state: State, params: Params, n_steps: int, dt=None):
        """Fixed number of steps with ``lax.scan`` (reverse-differentiable when the
        smoothing uses fixed sweeps).  ``dt=None`` uses the adaptive step."""

        def body(s, _):
            d = self.time_step(s, params)[0] if dt is None else dt
            return self.step(s, params, d), None

        s, _ = jax.lax.scan(body, state, None, length=n_steps)
        return s

    # ------------------------------------------------------------------ diagnostics
    def _centroid(self, k, xi_k, ws):
        """Centroid of solid k, weighted by its node fractions ``ws``, on a periodic domain.

        A body cut by a periodic edge lies partly at each side of the box, and the plain mean
        of the node coordinates falls between its pieces.  Each node's position is unwrapped
        with its material instead: the node holds ``xi = Xi - shift`` with ``Xi`` in the
        reference shape (:meth:`phi0` finds the shift, a whole number of periods), and
        ``x + shift`` is where that material lies in the frame where the body is in one
        piece (``xi - x``, the displacement, has no jump).  The weighted mean of the
        unwrapped positions is reduced back into the box.  Exact for any shape, any number
        of crossings (a circular mean of the coordinates would be exact only for bodies
        symmetric about their centroid); on non-periodic axes it is the plain weighted mean.
        Valid while the body is smaller than the box.
        """
        g = self.grid
        Xn = [jnp.asarray(a) for a in g.mesh("node")]
        lows = g.lows
        highs = g.highs
        _, shift = self.phi0(k, xi_k, return_shift=True)
        total = jnp.sum(ws)
        out = []
        for c, (x, a, b) in enumerate(zip(Xn, lows, highs, strict=True)):
            mean = jnp.sum(ws * (x + shift[c])) / total
            if self.bc.periodic[c]:
                mean = a + jnp.mod(mean - a, b - a)
            out.append(mean)
        return tuple(out)

    def diagnostics(self, state: State, params: Params, solve=None):
        """Scalar diagnostics and per-solid numbers at the current state (jit-able).

        ``solve``: the :meth:`frame_pressure` of this state, ``(p, info)``, when the caller
        has it (incompressible fluid; solved here otherwise).

        Solids stored in windows (``Numerics.solid_storage = "window"``): the per-solid
        numbers come from each solid's window (:mod:`refmap.window_diagnostics`), no solid's
        field on the whole grid (S of them would not fit for a thousand bodies); the same
        numbers as from :meth:`on_grid`'s state to round-off."""
        from refmap import window_diagnostics

        windowed = self.windowed(state) and window_diagnostics.applies(self)
        if not windowed:
            state = self.on_grid(state)
        g = self.grid
        nd = self.ndim
        dA = g.cell_area if nd == 2 else g.cell_volume  # "area" below is the d-dim. measure
        d = self.derived(state, params)
        v = state.v
        v2 = v[0] ** 2 + v[1] ** 2
        for a in range(2, nd):
            v2 = v2 + v[a] ** 2
        mean_p = self._mean_pressure(d)
        out = dict(
            kinetic_energy=0.5 * jnp.sum(d["rho"] * v2) * dA,
            fluid_mass=jnp.sum(d["wf_n"] * state.rho_f) * dA,
            max_speed=jnp.max(jnp.sqrt(v2)),
            max_pressure=jnp.max(mean_p),
            min_pressure=jnp.min(mean_p),
        )
        if self.projection is not None:
            # the pressure solve of a step from this state (the same as the frame's
            # p_fluid): a solve that stops at maxiter leaves a divergence above
            # pressure_rtol, which refmap.simulation reports
            if solve is None:
                solve = self.frame_pressure(state, params)
            info = solve[1]
            out.update(pressure_cg_iterations=info["iterations"],
                       pressure_cg_residual=info["relative_residual"],
                       pressure_cg_converged=info["converged"])
        if self.n_solids and windowed:
            f = window_diagnostics.fields(self, state, params.laws)
            num = window_diagnostics.solid_numbers(self, state, params, f)
            out["elastic_energy"] = jnp.sum(num["elastic_energy"])
            out["solid_area"] = jnp.sum(num["area"])
            out["J_min"] = jnp.min(num["J_min"])
            out["J_max"] = jnp.max(num["J_max"])
            out["solids"] = window_diagnostics.rows(self, num)
            d = dict(d, solid_windows=f)  # the body forces' diagnostics read them too
        elif self.n_solids:
            inside_c = d["phic"] < 0
            Jk = d["J"]
            # each corner once: on a periodic axis corner n is corner 0 again
            once = np.ones(tuple(m + 1 for m in g.shape()), dtype=bool)
            for a, p in enumerate(self.bc.periodic):
                if p:
                    once[(slice(None),) * a + (-1,)] = False
            e_el = 0.0
            per = []
            for k, law in enumerate(params.laws):
                psi_fn = law.psi
                for _ in range(nd):
                    psi_fn = jax.vmap(psi_fn)
                psi = psi_fn(d["F"][k])
                e_k = jnp.sum(jnp.where(d["valid"][k] & once, d["ws_c"][k] * psi / Jk[k], 0.0)) * dA
                e_el = e_el + e_k
                ws = d["ws_n"][k]
                area = jnp.sum(ws) * dA
                centroid = self._centroid(k, state.xi[k], ws)
                row = dict(area=area)
                for c, name in enumerate("xyz"[:nd]):
                    row["centroid_" + name] = centroid[c]
                for c, name in enumerate("xyz"[:nd]):
                    row["velocity_" + name] = jnp.sum(ws * v[c]) / jnp.sum(ws)
                row.update(
                    J_min=jnp.min(jnp.where(inside_c[k], Jk[k], jnp.inf)),
                    J_max=jnp.max(jnp.where(inside_c[k], Jk[k], -jnp.inf)),
                    elastic_energy=e_k,
                )
                per.append(row)
            out["elastic_energy"] = e_el
            out["solid_area"] = sum(p["area"] for p in per)
            out["J_min"] = jnp.min(jnp.stack([p["J_min"] for p in per]))
            out["J_max"] = jnp.max(jnp.stack([p["J_max"] for p in per]))
            out["solids"] = per
        # body-force terms with diagnostics of their own (refmap.contact.Contact): their
        # scalars, their per-solid numbers (merged into "solids") and per-pair numbers
        for term in self.body_forces:
            more = getattr(term, "diagnostics", None)
            if more is None:
                continue
            more = dict(more(self, state, params, d))
            extra = more.pop("solids", [])
            if isinstance(out.get("solids"), window_diagnostics.SolidRows):
                out["solids"] = out["solids"].merged(extra)
            else:
                for p, e in zip(out.get("solids", []), extra, strict=False):
                    p.update(e)
            if "pairs" in more:
                out.setdefault("pairs", {}).update(more.pop("pairs"))
            out.update(more)
        return out

    def frame_arrays(self, state: State, params: Params):
        """Per-solid and per-pair numbers stored in each output frame (jit-able): a dict of
        arrays whose axes :meth:`frame_array_dims` names.  Per solid its centroid and mean
        velocity (N, 2), area, min and max J (N,); plus the arrays of body-force terms that
        have them (:meth:`refmap.contact.Contact.frame_arrays`: contact forces, gaps and
        overlap areas).  Solids stored in windows: from each solid's window, as in
        :meth:`diagnostics`."""
        from refmap import window_diagnostics

        out = {}
        if not self.n_solids:
            return out
        if self.windowed(state) and window_diagnostics.applies(self):
            f = window_diagnostics.fields(self, state, params.laws)
            num = window_diagnostics.solid_numbers(self, state, params, f)
            out["solid_centroid"] = num["centroid"]
            out["solid_velocity"] = num["velocity"]
            for key in ("area", "J_min", "J_max"):
                out[f"solid_{key}"] = num[key]
            d = dict(self.derived(state, params), solid_windows=f)
        else:
            state = self.on_grid(state)
            diag = self.diagnostics(state, params)
            per = diag["solids"]

            def col(key):
                return jnp.stack([p[key] for p in per])

            axes = "xyz"[: self.ndim]
            out["solid_centroid"] = jnp.stack([col("centroid_" + a) for a in axes], axis=-1)
            out["solid_velocity"] = jnp.stack([col("velocity_" + a) for a in axes], axis=-1)
            for key in ("area", "J_min", "J_max"):
                out[f"solid_{key}"] = col(key)
            d = self.derived(state, params)
        for term in self.body_forces:
            more = getattr(term, "frame_arrays", None)
            if more is not None:
                out.update(more(self, state, params, d))
        return out

    def frame_array_dims(self) -> dict[str, tuple[str, ...]]:
        """Names of the axes of each :meth:`frame_arrays` entry (``solid``: the solids,
        ``other_solid``: the second solid of a pair, ``xy``: the x and y components; ``xyz``
        in 3D)."""
        if not self.n_solids:
            return {}
        comp = "xy" if self.ndim == 2 else "xyz"
        out = {"solid_centroid": ("solid", comp), "solid_velocity": ("solid", comp)}
        out.update({f"solid_{k}": ("solid",) for k in ("area", "J_min", "J_max")})
        for term in self.body_forces:
            dims = getattr(term, "frame_array_dims", None)
            if dims is not None:
                out.update(dims(self))
        return out

    def frame_pressure(self, state: State, params: Params):
        """The incompressible fluid's projection pressure for a step of the adaptive size
        from ``state``, and the CG solver's info: what each output frame reports
        (:meth:`output_fields`, and in :meth:`diagnostics` the iterations and whether CG
        converged)."""
        dt, _ = self.time_step(state, params)
        return self.step(state, params, dt, return_pressure="info")

    def output_fields(self, state: State, params: Params, solve=None):
        """Fields written to each frame (numpy-convertible), with physical names.
        ``solve`` as in :meth:`diagnostics`.

        Solids on the whole grid: per solid ``phi``, ``xi_x``, ``xi_y`` (nodes) and ``J``
        (corners, NaN where the solid's stress is not taken), each ``(S, *grid)``.  Solids
        stored in windows (:meth:`windowed`, whatever their number, so that a run's files
        have one layout however large it is): no ``(S, *grid)`` array, which at 1000 discs
        on 1024^2 would be 8 GB a field and frame, but the fields of
        :meth:`_window_output` (the union level set ``phi``, ``solid_index`` and the
        nearest solid's ``J`` on the grid; the windows ``phi_window``, ``xi_window`` and
        their ``origin``, from which :meth:`on_grid` rebuilds the per-solid fields
        exactly; :class:`refmap.simulation.Simulation` writes these three in a group of
        their own)."""
        windowed = self.windowed(state)
        d = self.derived(state, params)
        p_fluid = params.fluid.lambda_f * (state.rho_f / params.fluid.rho0 - 1.0)
        pressure = self._mean_pressure(d)
        if self.projection is not None:
            # incompressible: the fluid pressure is the projection's, solved for a step of
            # the adaptive size from this state (its mean over the grid set to zero unless
            # an outflow fixes the level); it acts on fluid and solids alike, so the mean
            # stress's pressure gains it everywhere (each corner takes its bottom-left node's)
            if solve is None:
                solve = self.frame_pressure(state, params)
            p_fluid = solve[0]
            if not self.projection.has_outflow:
                p_fluid = p_fluid - jnp.mean(p_fluid)
            pc = jnp.pad(p_fluid, ((1, 0),) * self.ndim, mode="edge")
            pressure = pressure + pc
        nd = self.ndim
        out = {name: state.v[a] for a, name in enumerate("uvw"[:nd])}
        out.update(rho_f=state.rho_f, rho=d["rho"], p_fluid=p_fluid, pressure=pressure)
        for name in SYM_COMPONENTS[nd]:
            out["sigma_" + name] = d["s" + name]
        if self.n_solids and windowed:
            out.update(self._window_output(state))
        elif self.n_solids:
            out["phi"] = state.phi
            for a, name in enumerate("xyz"[:nd]):
                out["xi_" + name] = state.xi[:, a]
            out["J"] = jnp.where(d["valid"], d["J"], jnp.nan)
        return out

    def _window_output(self, state: State) -> dict:
        """The solids' part of :meth:`output_fields` for solids stored in windows, made from
        the windows one after the other (:func:`refmap.windows.accumulate`), no
        ``(S, *grid)`` array formed:

        * ``phi`` (nodes): the union level set, the least of every solid's ``phi`` at each
          node, ``phi_max h`` (the far value of :meth:`on_grid`) where no window lies:
          the minimum over solids of ``on_grid(state).phi``, exactly;
        * ``solid_index`` (nodes, int32): the solid whose ``phi`` is that least value (the
          lowest index on a tie, as ``argmin``), -1 where it is not below ``phi_max h``;
        * ``J`` (corners): ``1 / det(grad xi)`` of the nearest solid among those whose
          stress is taken at the corner (``phic < stress_band h`` and ``det > 1e-12``, as
          :meth:`derived`), the nearest by the corner level set ``phic`` (lowest index on a
          tie), NaN where none is: the per-solid ``J`` of the grid layout merged (equal to
          round-off, the maps read continuous across a periodic edge as the step reads
          them);
        * ``phi_window`` ``(S, *W)``, ``xi_window`` ``(S, d, *W)``, ``origin`` ``(S, d)``:
          the state's own windows.

        A solid that outgrew its window (origin -1) is left out of the three grid fields
        (:meth:`on_grid` shows it as NaN; a run stops before writing such a frame)."""
        from refmap import window_diagnostics

        nd = self.ndim
        per = self.bc.periodic
        shape = tuple(self.grid.shape())
        W = tuple(state.phi.shape[1:])
        h = self.h
        far = self.numerics.phi_max * h
        S = self.n_solids
        ok = jnp.all(state.origin >= 0, axis=1)
        o = jnp.maximum(state.origin, 0)
        lead = (-1,) + (1,) * nd
        k = jnp.arange(S, dtype=jnp.int32).reshape(lead)

        # nodes: the union level set and which solid gives it
        phi_w = jnp.where(ok.reshape(lead), state.phi, jnp.inf)
        union = windows.accumulate(jnp.full(shape, far, phi_w.dtype), phi_w, o, per, "min")
        least = windows.blocks(union, o, W, per)
        cand = jnp.where((phi_w == least) & (least < far), k, S)
        idx = windows.accumulate(jnp.full(shape, S, jnp.int32), cand, o, per, "min")

        # corners origin .. origin + W of each window: the windows' phic, J and where the
        # stress is taken, as the diagnostics make them (window_diagnostics.fields); a
        # periodic axis holds n distinct corners (corner n is corner 0's copy, appended
        # after the sums), a walled one n + 1
        f = window_diagnostics.fields(self, state)
        C = tuple(f["phic"].shape[1:])
        cshape = tuple(n if p else n + 1 for n, p in zip(shape, per, strict=True))
        valid = f["valid"]
        key = jnp.where(valid, f["phic"], jnp.inf)
        near = windows.accumulate(jnp.full(cshape, jnp.inf, key.dtype), key, o, per, "min")
        cand_c = jnp.where(valid & (key == windows.blocks(near, o, C, per)), k, S)
        idx_c = windows.accumulate(jnp.full(cshape, S, jnp.int32), cand_c, o, per, "min")
        mine = windows.blocks(idx_c, o, C, per) == k
        J = windows.accumulate(jnp.full(cshape, jnp.inf, key.dtype), jnp.where(mine, f["J"], jnp.inf),
                               o, per, "min")
        J = jnp.where(idx_c < S, J, jnp.nan)
        for a in range(nd):
            if per[a]:
                J = jnp.concatenate([J, lax.slice_in_dim(J, 0, 1, axis=a)], axis=a)
        return {
            "phi": union, "solid_index": jnp.where(idx < S, idx, -1), "J": J,
            "phi_window": state.phi, "xi_window": state.xi, "origin": state.origin,
        }

    def _mean_pressure(self, d):
        """Minus the mean normal stress at the corners, -tr(sigma) / d."""
        if self.ndim == 2:
            return -0.5 * (d["sxx"] + d["syy"])
        return -(d["sxx"] + d["syy"] + d["szz"]) / 3.0


def check_3d_support(numerics: Numerics, solids, body_forces=()) -> None:
    """ValueError naming the first settings of a 3D case that the 3D step does not have yet.

    The 3D step (issue 12) covers the compressible fluid with explicit viscosity, any
    number of solids without anchors, and body forces written for 3D; the pieces below
    are 2D-only so far."""
    n = numerics
    todo = []
    if n.band_force != "local":
        todo.append(f"numerics.band_force {n.band_force!r}")
    for s in solids:
        if s.anchor is not None and not getattr(s.anchor, "supports_3d", False):
            todo.append(f"the anchor of solid {s.name!r} ({type(s.anchor).__name__})")
    for term in body_forces:
        if not (getattr(term, "supports_3d", False) or getattr(term, "ndim", 2) == 3):
            todo.append(f"the body force {type(term).__name__} (2D only; a term written for 3D "
                        "sets supports_3d = True)")
    if todo:
        raise ValueError("not available in 3D yet: " + "; ".join(todo))


def _check_closed(boundary: Boundary) -> None:
    """ValueError naming the edge through which fluid can flow (``fluid_mass =
    "conserved"`` keeps the fluid's mass constant, which only a closed box does)."""
    for axis, names in enumerate(AXIS_FACES[: boundary.ndim]):
        for name in names:
            edge = getattr(boundary, name)
            for seg in () if edge == "periodic" else edge:
                un = seg.velocity[axis] if seg.kind in ("velocity", "wall") else 0.0
                if seg.kind == "outflow":
                    what = "an 'outflow' segment"
                elif not (isinstance(un, (int, float)) and un == 0.0):
                    what = f"a {seg.kind!r} segment with normal velocity {un!r}"
                else:
                    continue
                raise ValueError(
                    f"numerics fluid_mass 'conserved' needs a closed box, but the {name} edge "
                    f"has {what}, through which fluid can flow; use fluid_mass = 'advected' there"
                )


def check_finite_fields(state: State) -> list[str]:
    """Names of prognostic fields holding non-finite values (host-side helper); also
    ``"origin"`` when a solid's band outgrew the window it is stored in
    (``Numerics.solid_storage = "window"``)."""
    bad = []
    if state.origin is not None and not np.all(np.asarray(state.origin) >= 0):
        bad.append("origin")
    for name in ("v", "rho_f", "xi", "phi"):
        a = np.asarray(getattr(state, name))
        if not np.all(np.isfinite(a)):
            bad.append(name)
    return bad


__all__ = ["Model", "Solid", "StepInfo", "LIMIT_NAMES", "solid_fractions", "check_finite_fields"]
