"""State and parameter pytrees.

* :class:`State` -- the prognostic fields (what a checkpoint must hold): clock, step count,
  velocity ``v`` (2, nx, ny), fluid density ``rho_f`` (nx, ny), and for the N solids stacked
  on a leading axis their reference maps ``xi`` (N, 2, nx, ny) and level sets ``phi``
  (N, nx, ny).  Everything else (F, J, sigma, H, mixed density) is recomputed each step.
* :class:`FluidParams` -- traced (differentiable) fluid constants.
* :class:`Numerics` -- static choices: blur width, band widths, pinning and smoothing
  settings, time-step safety factor.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import jax
import jax.numpy as jnp

from refmap.blend import check_kernel
from refmap.projection import PRECONDITIONERS


def _register(cls, data):
    """Register a frozen dataclass as a pytree whose treedef carries the class itself.

    (``jax.tree_util.register_dataclass`` treedefs of two classes with the same number of
    fields can compare equal in the installed JAX, which confuses jit caches.)
    """
    data = list(data)
    meta = [f.name for f in fields(cls) if f.name not in data]

    def flatten(obj):
        return [getattr(obj, n) for n in data], tuple(getattr(obj, n) for n in meta)

    def unflatten(aux, children):
        obj = object.__new__(cls)
        for n, v in zip(data, children, strict=True):
            object.__setattr__(obj, n, v)
        for n, v in zip(meta, aux, strict=True):
            object.__setattr__(obj, n, v)
        return obj

    jax.tree_util.register_pytree_node(cls, flatten, unflatten)
    return cls


@dataclass(frozen=True)
class State:
    t: jax.Array
    step: jax.Array
    v: jax.Array
    rho_f: jax.Array
    xi: jax.Array
    phi: jax.Array
    #: the incompressible fluid's pressure of the last step (nx, ny[, nz]), which the next
    #: step's predictor carries (incremental projection, :meth:`refmap.model.Model.step`);
    #: None for the compressible fluid (its pressure is a function of rho_f) and for a
    #: state made without it (the step is then the non-incremental projection)
    p: jax.Array | None = None
    #: ``Numerics.solid_storage = "window"``: the lower corner (S, d) int32 of the window in
    #: which each solid's map ``xi`` (S, d, *W) and level set ``phi`` (S, *W) are stored
    #: (:attr:`refmap.model.Model.state_window`, docs/design_windows.md); -1 on every axis
    #: once a body's band outgrew its window.  None: the maps and level sets are stored on
    #: the whole grid.
    origin: jax.Array | None = None

    def replace(self, **kw) -> State:
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d.update(kw)
        return State(**d)

    @property
    def n_solids(self) -> int:
        return self.xi.shape[0]


_register(State, ["t", "step", "v", "rho_f", "xi", "phi", "p", "origin"])


@dataclass(frozen=True)
class FluidParams:
    """Compressible Newtonian fluid of the thesis.

    p = lambda_f (rho_f / rho0 - 1); viscous stress eta * sym(grad v) (the thesis's
    convention: a dynamic viscosity mu = eta / 2 in the usual 2 mu D form); an extra
    stabilising term ``extra_viscosity * lap(v) / rho`` in the velocity update everywhere;
    an optional bulk viscosity: the isotropic stress ``bulk_viscosity * div(v) * I``,
    weighted like the rest of the fluid stress by the fluid fraction.

    Sound in the fluid needs damping: the pressure force takes the bottom-left node's
    pressure (one-sided) while the density update uses a centred divergence, and that pair
    amplifies short sound waves unless the longitudinal diffusivity
    ``(eta + extra_viscosity + bulk_viscosity) / rho0`` is at least about ``c h / 2``
    (c the sound speed, h the grid spacing).  The thesis's fluid (c = 1, eta = 0.12) meets
    this on every grid it uses; a fast, nearly inviscid fluid (low Mach number, high
    Reynolds number) does not, and :meth:`refmap.case.Case.validate` warns then and names
    the ``bulk_viscosity`` that meets it.  A bulk viscosity damps only compression, so a
    nearly incompressible flow is hardly affected by it.
    """

    rho0: float = 1.0
    lambda_f: float = 1.0
    eta: float = 0.12
    extra_viscosity: float = 0.02
    bulk_viscosity: float = 0.0

    def __post_init__(self):
        checks = {
            "rho0": True,
            "lambda_f": True,
            "eta": False,
            "extra_viscosity": False,
            "bulk_viscosity": False,
        }
        for name, strict in checks.items():
            v = getattr(self, name)
            if isinstance(v, (int, float)):
                if v != v or (v <= 0 if strict else v < 0):
                    need = "> 0" if strict else ">= 0"
                    raise ValueError(f"fluid {name} must be {need}, got {v!r}")

    @property
    def sound_speed(self):
        return jnp.sqrt(self.lambda_f / self.rho0)

    def to_dict(self):
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


_register(FluidParams, ["rho0", "lambda_f", "eta", "extra_viscosity", "bulk_viscosity"])


@dataclass(frozen=True)
class Numerics:
    """Static numerical settings; lengths are in units of the grid spacing h = min(dx, dy).

    Defaults follow the thesis: blur width 2h (H = (1 + erf(phi / (2h))) / 2), reference map
    extrapolated ~6h out, smoothing
    of extrapolated values with coefficient 0.025 h^2 for at most 80 sweeps.  The
    smoothing's stopping rule is tested every ``smooth_check_every`` sweeps (default 4; 1
    tests before every sweep, as the thesis's Algorithm 3 would): a run of all 80 sweeps,
    the usual case, is then 1.7x cheaper, and a stop comes up to 3 sweeps later
    (:func:`refmap.extrapolation.smooth_extrapolated`).

    Pinning: each step phi = phi0(xi) is copied at the nodes next to the zero contour,
    |phi| < ``pin_copy`` h, so the zero level set is the material's; elsewhere in the zone
    -pin_inner h < phi < (band - 1) h phi is relaxed towards phi0(xi) at rate
    min(pin_rate pin_substeps dt, 1) per step (the thesis's k = 5, 10 sub-steps).  With
    ``pin_copy = 0`` (the thesis's pinning) the zero level set lags |U| / (k n_sub) behind a
    body moving at speed U, a fixed distance that does not shrink with h (docs/method.md).  ``cfl`` scales
    the adaptive time step; ``dt_fixed`` replaces it by a constant (convergence studies,
    differentiable runs), ``dt_max`` caps it.

    ``blend`` picks the blend kernel H(phi) (:mod:`refmap.blend`): ``"erf"`` (the thesis's,
    ``H = (1 + erf(phi / (blur_width h))) / 2``) or ``"sine"`` (the compactly supported
    sine-smoothed Heaviside of half-width ``blur_width h``).  A plate t thick is stiffened in
    bending by ``1 + C (h / t)^2`` with ``C = 6 blur_width^2`` (erf) or
    ``1.568 blur_width^2`` (sine); see :func:`refmap.blend.bending_factor`.

    ``advected_band`` (default 0, the thesis's choice): nodes with ``0 <= phi < advected_band h``
    keep the reference map the advection step gave them instead of receiving the
    extrapolated one; the extrapolation and its smoothing start from them.  Extrapolated
    maps change with the body's interior, not with the velocity at their own nodes, so the
    solid stress there does work that does not match the elastic energy it stores, and a
    vibrating body can gain energy (docs/method.md, "Defects fixed (issue 15)");
    ``advected_band = 1`` removes that source but is less accurate at the interface (same
    page), so it is an option, not the default.  At most ``band - 3`` (the advected zone).

    ``band_force`` says where the solid stress of the extrapolated band pushes:
    ``"local"`` (default, the thesis's) on the band nodes themselves; ``"solid"`` on the
    solid nodes the band's maps were extrapolated from, through the transpose of the
    extrapolation (:meth:`refmap.model.Model.band_force_to_solid`), so that the band's
    stress does exactly the work that changes its stored energy (docs/method.md).

    ``band_sweeps`` says where the extrapolation and smoothing sweeps of each solid's map
    run: ``"band"`` on the grid tiles that solid's band covers (:mod:`refmap.narrowband`,
    gathered once per step; equal to the full-grid sweeps to round-off), ``"grid"`` over
    the whole grid, ``"auto"`` (default) on tiles when the listed tiles are at most
    ``BAND_TILE_FRACTION`` (0.75) of the grid's tiles (and, in 2D, the grid has at least
    ``AUTO_TILE_MIN_NODES_2D`` = 10 000 nodes: below, compile time outweighs the gain) and
    over the whole grid otherwise (a tile sweep costs more per node than a full-grid sweep, measured in
    docs/benchmarks.md, so a band that covers more of the grid is cheaper swept densely; in
    3D such a band is swept in a box round it when the box is small enough).  Tiles are
    about 8 x 8 nodes in 2D and 8 x 8 x 8 in 3D.
    The list holds ``band_capacity`` (>= 1, default 2) times the tiles the solid's band
    covers at t = 0, plus 8; a band that outgrows it (a body stretched to more than that
    perimeter) makes the step fall back on the full-grid sweeps: same result, full cost.
    The same setting places each solid's share of the mixed stress and density (its blend
    weights, deformation gradient and constitutive stress): on the tiles within reach of
    its interface (:mod:`refmap.solid_tiles`; ``"auto"``: when they are at most
    ``SOLID_TILE_FRACTION`` (0.5) of the grid's tiles, so many small bodies, not the rotor)
    or over the whole grid; equal to round-off.

    ``compression`` picks the velocity divergence in the fluid-density update
    ``d rho_f / dt = -v . grad rho_f - w_f rho_f div v``:

    * ``"corner"``: the divergence at the node's top-right corner, i.e. the forward
      difference ``(u[i+1] - u[i]) / dx + (v[j+1] - v[j]) / dy``, weighted by that corner's
      fluid fraction.  The corner pressure is taken from its bottom-left node, so the
      pressure force on a node is the backward difference of p; the forward divergence is
      its negative transpose and the discrete pressure work balances the fluid's
      compression energy exactly (sound waves neither grow nor lose energy to the pairing).
      The price is a one-sided, first-order divergence: on smooth flows its errors are
      larger and its observed orders lower than the centred form's (docs/method.md).
    * ``"centred"`` (default, the thesis's eq. 4.28): the centred divergence, weighted by
      the node's fluid fraction.  Paired with the one-sided pressure gradient it feeds
      grid-scale sound (it needs ``(eta + bulk_viscosity) / rho0 >~ c h / 2`` to stay
      stable) and lets a one-node velocity jet in a thin fluid film between two bodies pump
      the film's density without bound (docs/method.md).

    ``viscosity`` treats the fluid's viscous stress (``eta`` and ``bulk_viscosity``) and the
    ``extra_viscosity`` term ``"explicit"`` (default, forward Euler as everything else,
    limited to dt <= h^2 rho / (4 nu)) or ``"implicit"`` (backward Euler: one linear solve
    per step to relative residual ``viscosity_rtol``, preconditioned by the operator's
    diagonal (``viscosity_preconditioner = "jacobi"``, default) or by a fast
    constant-coefficient FFT/DCT solve (``"fast"``), :mod:`refmap.viscosity`); then the
    adaptive time step drops the viscous limit and reports the next one
    (:meth:`refmap.model.Model.time_step`; docs/method.md, "Implicit viscosity").

    ``fluid_model`` is ``"compressible"`` (default, the thesis's weakly compressible fluid,
    p = lambda_f (rho_f / rho0 - 1)) or ``"incompressible"``: the fluid density stays at
    rho0 and a pressure projection makes the velocity discretely divergence-free each step
    (:mod:`refmap.projection`: conjugate gradients to relative residual
    ``pressure_rtol``, preconditioned by the exact constant-coefficient FFT/DCT solve,
    ``pressure_preconditioner = "fast"``, by the diagonal, ``"jacobi"``, or by a multigrid
    V-cycle that sees held anchors and density jumps, ``"multigrid"``,
    :mod:`refmap.multigrid`; the default ``"auto"`` takes the multigrid cycle when a solid
    has an anchor and the fast solve otherwise, :func:`refmap.projection.resolve_preconditioner`);
    lambda_f is
    then unused and the fluid-sound time-step limit is dropped (docs/method.md,
    "Incompressible fluid").  ``volume_correction`` (incompressible only, default 10, a rate
    per unit of the case's time) takes each solid's volume drift ``ln J`` out through the
    projection (``D v = -min(volume_correction, 1 / dt) ln(J)`` at the material's corners,
    the fluid taking the opposite; :meth:`refmap.model.Model.volume_source`); 0 keeps
    ``D v = 0`` exactly.

    ``fluid_mass`` (compressible fluid in a closed box): ``"advected"`` (default, the
    thesis's non-conservative density update: the fluid's mass drifts where the interface
    moves otherwise than the flow) or ``"conserved"``: after each step the fluid density
    is shifted, in proportion to the fluid fraction, so that the fluid's mass sum(w_f rho_f)
    is what it was before the step (docs/method.md, "Known weaknesses", swelling item
    (d)); refused with an edge through which fluid can flow.

    ``blur_mass``: the mass per node that divides the force in the momentum update (and
    enters the implicit viscous solve, the projection and the kinetic energy).
    ``"node"`` (default, the thesis's): the blend at the node itself, ``w_f rho_f + sum
    w_s rho_s``.  ``"corners"``: where the node's most solid corner holds more than
    ``refmap.model.BLUR_MASS_RATIO`` (4) times the node's own solid fraction, at least
    ``rho_f + w_c (rho_s - rho_f)``, ``w_c`` that corner's fraction and ``rho_s`` the largest
    solid reference density.  A node feels the stress of its corners, weighted by their
    fractions; the outer blur nodes of a compact kernel hold almost no solid while a corner
    next to them holds some, so with ``"node"`` a solid ~1000 times denser than the fluid
    gives them a wave speed ~ sqrt(w_c rho_s / (w_n rho_f)) times the solid's and the
    explicit step lets their velocity grow from round-off.  The price is inertia in that
    layer: a disc of radius 8 h gains 8.6 % of its mass with the sine kernel at 1 h, 4.4 %
    at 1.5 h, 0.08 % with erf (half that at 16 h), so it is opt-in (docs/method.md, "Heavy
    solids in a light fluid").

    ``solid_storage`` (issue 14; docs/design_windows.md): ``"grid"`` (default: every
    solid's map and level set on the whole grid) or ``"window"``: each solid's map and
    level set are stored in a box that follows its body (``State.xi`` ``(S, d, *W)``,
    ``State.phi`` ``(S, *W)``, ``State.origin``; :attr:`refmap.model.Model.state_window`,
    sized at t = 0 round the nodes with ``phi < phi_max h``), where the band work (map
    advection, pinning and re-distancing, extrapolation and smoothing), the stress, blend
    weights and density and the contact run; same results to round-off, for many small
    bodies much faster (100 discs at 300^2: 2.6x per step).  A body that outgrows its box
    stops the run with a message.  Output frames hold the union of the level sets on the
    grid and the windows themselves (docs/restart.md); ``Model.on_grid(state)`` gives the
    whole-grid fields.  The state stays on the whole grid (only the stress,
    weights and density, and where they apply the band work and contact, on boxes cut
    from it each step, falling back on the whole grid in a step where a body outgrew its
    box) for an anchored solid, a solid glued to a wall at t = 0, a body whose box would
    hold more than half the grid (the rotor), the incompressible fluid, ``band_force =
    "solid"`` and ``fluid_mass = "conserved"``.  With the solids in windows the step's
    ``derived`` fields hold the mixed ones only (``s..``, ``rho``, ``wf_c``, ``wf_n``), not
    the per-solid whole-grid fields (``ws_n``, ``phic``, ``J``, ...): a body-force term of
    your own that reads those needs ``"grid"``.  Tested in 2D only.
    """

    blur_width: float = 2.0
    blend: str = "erf"
    band: float = 6.0
    stress_band: float = 5.0
    advected_band: float = 0.0
    pin_rate: float = 5.0
    pin_substeps: int = 10
    pin_inner: float = 5.0
    pin_copy: float = 1.5
    redistance_iters: int = 2
    smooth_coef: float = 0.025
    smooth_max_sweeps: int = 80
    smooth_ratio: float = 0.25
    smooth_atol: float = 1e-3
    smooth_check_every: int = 4
    fixed_smooth_sweeps: int | None = None
    cfl: float = 0.5
    dt_max: float | None = None
    dt_fixed: float | None = None
    phi_max: float = 12.0
    compression: str = "centred"
    band_force: str = "local"
    band_sweeps: str = "auto"
    band_capacity: float = 2.0
    viscosity: str = "explicit"
    viscosity_rtol: float = 1e-6
    viscosity_preconditioner: str = "jacobi"
    fluid_model: str = "compressible"
    pressure_rtol: float = 1e-10
    pressure_preconditioner: str = "auto"
    volume_correction: float = 10.0
    fluid_mass: str = "advected"
    solid_storage: str = "grid"
    blur_mass: str = "node"

    def __post_init__(self):
        try:
            check_kernel(self.blend)
        except ValueError as e:
            raise ValueError(f"numerics {e}") from None
        choices = {
            "compression": ("corner", "centred"),
            "viscosity": ("explicit", "implicit"),
            "viscosity_preconditioner": ("jacobi", "fast"),
            "fluid_model": ("compressible", "incompressible"),
            "pressure_preconditioner": ("auto",) + PRECONDITIONERS,
            "band_force": ("local", "solid"),
            "fluid_mass": ("advected", "conserved"),
            "solid_storage": ("grid", "window"),
            "blur_mass": ("node", "corners"),
        }
        for name, allowed in choices.items():
            value = getattr(self, name)
            if value not in allowed:
                listed = ", ".join(map(repr, allowed[:-1])) + f" or {allowed[-1]!r}"
                raise ValueError(f"numerics {name} must be {listed}, got {value!r}")
        for name in ("viscosity_rtol", "pressure_rtol"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0 < value < 1):
                raise ValueError(f"numerics {name} must be in (0, 1), got {value!r}")
        if self.band_sweeps not in ("auto", "band", "grid"):
            raise ValueError(
                f"numerics band_sweeps must be 'auto', 'band' or 'grid', got {self.band_sweeps!r}"
            )
        if not (isinstance(self.band_capacity, (int, float)) and self.band_capacity >= 1):
            raise ValueError(f"numerics band_capacity must be a number >= 1, got {self.band_capacity!r}")
        pos = ["blur_width", "band", "stress_band", "cfl", "phi_max"]
        for name in pos:
            v = getattr(self, name)
            if not (v > 0):
                raise ValueError(f"numerics {name} must be > 0, got {v!r}")
        if self.cfl > 1.0:
            raise ValueError(f"numerics cfl (time-step safety factor) must be <= 1, got {self.cfl!r}")
        if self.stress_band > self.band:
            raise ValueError(
                f"numerics stress_band ({self.stress_band}) must not exceed band ({self.band}): "
                "solid stress needs an extrapolated reference map"
            )
        if not (0.0 <= self.advected_band <= self.band - 3.0):
            raise ValueError(
                f"numerics advected_band must be in [0, band - 3] = [0, {self.band - 3.0:g}] "
                f"(the reference map is advected only where phi < (band - 3) h), got {self.advected_band!r}"
            )
        for name in ("pin_rate", "pin_copy"):
            if not (getattr(self, name) >= 0):
                raise ValueError(f"numerics {name} must be >= 0, got {getattr(self, name)!r}")
        for name in ("pin_substeps", "redistance_iters", "smooth_max_sweeps"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 0:
                raise ValueError(f"numerics {name} must be an integer >= 0, got {v!r}")
        v = self.smooth_check_every
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            raise ValueError(
                f"numerics smooth_check_every (sweeps per test of the smoothing's stopping rule) "
                f"must be an integer >= 1, got {v!r}"
            )
        vc = self.volume_correction
        if not (isinstance(vc, (int, float)) and 0.0 <= vc < float("inf")):
            raise ValueError(
                f"numerics volume_correction (the rate, per unit time, at which a solid's "
                f"volume drift is taken out) must be a finite number >= 0, got {vc!r}"
            )
        for name in ("dt_max", "dt_fixed"):
            v = getattr(self, name)
            if v is not None and not (v > 0):
                raise ValueError(f"numerics {name} must be > 0, got {v!r}")

    def to_dict(self):
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class Params:
    """Everything traced: fluid constants, solid laws (one per solid), gravity."""

    fluid: FluidParams = field(default_factory=FluidParams)
    laws: tuple = ()
    gravity: tuple = (0.0, 0.0)


_register(Params, ["fluid", "laws", "gravity"])
