"""A complete, validated description of one run: :class:`Case`.

A case bundles the grid, the fluid, the solids, the edge conditions, the numerics, gravity,
the time span and the output plan.  :meth:`Case.validate` checks every value *before*
anything is compiled and raises :class:`CaseError` naming the offending value.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from refmap.boundary import AXIS_FACES, Boundary
from refmap.grid import Grid
from refmap.state import FluidParams, Numerics


def _inside_at_t0(grid, solid, Xn, boundary) -> np.ndarray:
    """The grid's nodes inside ``solid`` at t = 0 (bool, the node shape): its shape evaluated
    at the initial map, on the nodes of a box round the shape's ``bbox()`` (carried through
    the inverse of the initial strain, two nodes to spare; wrapped round a periodic axis)
    when it has one, else on every node (``Xn``).  The box keeps the check of many small
    bodies cheap (1000 discs at 1024^2: 1000 evaluations of a few thousand nodes, not of
    a million)."""
    d = grid.ndim
    shape = grid.shape()
    span = solid.node_span(grid, 2)
    if span is None:
        return np.asarray(solid.shape(*solid.initial_map(*Xn))) < 0
    first, last = span
    periodic = [getattr(boundary, names[0]) == "periodic" for names in AXIS_FACES[:d]]
    idx = []
    for a in range(d):
        i = np.arange(first[a], last[a] + 1)
        if periodic[a]:
            i = np.unique(i % shape[a]) if i.size < shape[a] else np.arange(shape[a])
        else:
            i = i[(i >= 0) & (i < shape[a])]
        idx.append(i)
    axes = grid.axes("node")
    inside = np.zeros(shape, dtype=bool)
    if all(i.size for i in idx):
        Xb = np.meshgrid(*(axes[a][idx[a]] for a in range(d)), indexing="ij")
        inside[np.ix_(*idx)] = np.asarray(solid.shape(*solid.initial_map(*Xb))) < 0
    return inside


class CaseError(ValueError):
    """An invalid case value (raised before any compilation)."""


class CaseWarning(UserWarning):
    """A valid but risky case value (issued before any compilation)."""


@dataclass(frozen=True)
class Case:
    name: str
    grid: Grid
    solids: tuple = ()
    boundary: Boundary = field(default_factory=Boundary)
    fluid: FluidParams = field(default_factory=FluidParams)
    numerics: Numerics = field(default_factory=Numerics)
    #: the body force per unit mass, one component per axis (None: zero)
    gravity: tuple | None = None
    t_end: float = 1.0
    frames: int = 10
    picture_field: str = "pressure"
    description: str = ""
    #: contact between the solids and against the walls: a :class:`refmap.contact.Contact`
    #: (passed to the model as a body force), or None for no contact
    contact: Any = None
    #: the velocity at t = 0 on every node, fluid and solids alike: None (at rest), a
    #: callable ``f(x, y) -> (u, v)`` on the node coordinate arrays, an array of shape
    #: ``(2, nx, ny)``, or a :mod:`refmap.initial` field (a formula or a file); on a 3D
    #: grid ``f(x, y, z) -> (u, v, w)``, ``(3, nx, ny, nz)``, formulas u, v, w.  Each
    #: ``Solid.velocity`` is added to it, weighted by the solid's fraction (see
    #: :meth:`refmap.model.Model.initial_state`).  Stored as a :mod:`refmap.initial` field.
    initial_velocity: Any = None

    def __post_init__(self):
        from refmap.initial import InitialVelocityError, as_initial_velocity

        if self.gravity is None:
            object.__setattr__(self, "gravity", (0.0,) * getattr(self.grid, "ndim", 2))

        try:
            object.__setattr__(self, "initial_velocity", as_initial_velocity(
                self.initial_velocity, getattr(self.grid, "ndim", 2)))
        except InitialVelocityError as e:
            key = f"initial_velocity.{e.key}" if e.key else "initial_velocity"
            raise CaseError(f"case {self.name!r}: {key}: {e.msg}") from None
        # checked at construction (and on every replace), before anything is compiled
        if self.contact is not None:
            from refmap.contact import Contact

            if not isinstance(self.contact, Contact):
                raise CaseError(
                    f"case {self.name!r}: contact must be a refmap.contact.Contact or None, "
                    f"got {self.contact!r}"
                )
            try:
                self.contact.check()
            except ValueError as e:
                raise CaseError(f"case {self.name!r}: contact: {e}") from None

    def replace(self, **kw) -> Case:
        return replace(self, **kw)

    # ------------------------------------------------------------------ validation
    def validate(self) -> Case:
        def bad(msg):
            raise CaseError(f"case {self.name!r}: {msg}")

        if not (isinstance(self.t_end, (int, float)) and math.isfinite(self.t_end) and self.t_end > 0):
            bad(f"t_end must be a finite number > 0, got {self.t_end!r}")
        if not (isinstance(self.frames, int) and self.frames >= 1):
            bad(f"frames must be an integer >= 1, got {self.frames!r}")
        nd = self.grid.ndim
        if len(self.gravity) != nd or not all(math.isfinite(float(g)) for g in self.gravity):
            bad(f"gravity must be {('two', 'three')[nd - 2]} finite numbers on a {nd}D grid, "
                f"got {self.gravity!r}")
        if nd == 3:
            from refmap.model import check_3d_support

            try:
                check_3d_support(self.numerics, self.solids, () if self.contact is None else (self.contact,))
            except ValueError as e:
                bad(str(e))
        from refmap.resources import check_memory

        check_memory(self)  # before any grid-sized array is made
        g = self.grid
        if self.numerics.fluid_model == "incompressible":
            from refmap.projection import check_boundary

            try:  # the edge conditions the projection supports, the fluxes' balance
                check_boundary(self.boundary, g)
            except ValueError as e:
                bad(f"boundary: {e}")
        if self.numerics.fluid_mass == "conserved":
            from refmap.model import _check_closed

            try:  # a constant fluid mass needs a closed box
                _check_closed(self.boundary)
            except ValueError as e:
                bad(f"boundary: {e}")
        Xn = g.mesh("node")
        lows = g.lows
        highs = g.highs
        covered = np.zeros(Xn[0].shape, dtype=bool)  # nodes inside some solid
        for k, s in enumerate(self.solids):
            label = f"solids[{k}] ({s.name!r})"
            if s.ndim != nd:
                bad(f"{label}: the solid is {s.ndim}D (its law's dim) but the grid is {nd}D"
                    + (" (build its law with dim=3, or law.with_dim(3))" if nd == 3 else ""))
            try:
                s.law.validate()
            except ValueError as e:
                bad(f"{label}: {e}")
            inside = _inside_at_t0(g, s, Xn, self.boundary)
            covered |= inside
            if not inside.any():
                bad(f"{label}: the shape covers no grid node (too small for n={g.nx}, or outside the domain)")
            # A solid may touch (or extend beyond) wall, slip and tangential velocity edges: it
            # is glued to a resting wall (BoundaryConditions.glue) and dragged by a moving one.
            # It may not touch an edge through which material would flow (outflow, or a
            # velocity segment with a normal component): nothing defines the map of material
            # entering from outside (measured: a disc at an inflow edge blew up by t = 2),
            # and a body leaving through an outflow left a few strained nodes behind.
            for axis, names in enumerate(AXIS_FACES[:nd]):
                for ename, rows in zip(names, (slice(0, 2), slice(-2, None)), strict=True):
                    edge = getattr(self.boundary, ename)
                    if edge == "periodic":
                        continue
                    index = [slice(None)] * nd
                    index[axis] = rows
                    hits = inside[tuple(index)].any(axis=axis)  # per node of the face
                    # segments run along the face's first tangential axis (whole faces in 3D)
                    b = 1 if axis == 0 else 0
                    along = (Xn[b] - lows[b]) / (highs[b] - lows[b])
                    along = np.take(along, 0, axis=axis)
                    for seg in edge:
                        on = (along >= seg.start) & ((along < seg.end) | (seg.end >= 1.0))
                        through = seg.kind == "outflow" or (
                            seg.kind == "velocity" and seg.velocity[axis] != 0.0
                        )
                        if through and (hits & on).any():
                            ext = ", ".join(
                                f"{'xyz'[c]} in [{Xn[c][inside].min():.3g}, {Xn[c][inside].max():.3g}]"
                                for c in range(nd)
                            )
                            dom = " x ".join(f"[{lo}, {hi}]" for lo, hi in zip(lows, highs, strict=True))
                            bad(
                                f"{label}: the shape reaches the {ename} edge where it is a "
                                f"{seg.kind!r} segment with flow through it ({ext}; "
                                f"domain {dom}); a solid may touch wall, slip and tangential "
                                "velocity edges only"
                            )
            if inside.sum() < 4:
                bad(f"{label}: only {int(inside.sum())} grid nodes inside; refine the grid (n={g.nx})")
            check = getattr(s.anchor, "check", None)
            if check is not None:
                try:
                    check(g, inside)
                except ValueError as e:
                    bad(f"{label}: {e}")
        if not covered.all():  # a box filled with solid has no fluid to damp
            self._check_sound_damping()
            self._check_hydrostatic()
        self._check_dt_fixed()
        self.initial_velocity_field()
        return self

    def initial_velocity_field(self):
        """The ``(d, nx, ny[, nz])`` node values of :attr:`initial_velocity` (None when it is
        None), checked: shape against the grid, finite values; a callable that raises or
        returns something else is a :class:`CaseError` naming it."""
        from refmap.initial import InitialVelocityError

        if self.initial_velocity is None:
            return None
        try:
            return self.initial_velocity.sample(self.grid)
        except InitialVelocityError as e:
            key = f"initial_velocity.{e.key}" if e.key else "initial_velocity"
            raise CaseError(f"case {self.name!r}: {key}: {e.msg}") from None

    def velocity_scales(self) -> dict[str, float]:
        """The speeds this case can set up, by name: the fluid's sound speed (not with an
        incompressible fluid, unless nothing else sets a speed), the fastest solid wave, the fastest boundary velocity, the fastest initial solid velocity and
        the free-fall speed sqrt(2 |g| L) over the domain.  The run's growth checks
        (:mod:`refmap.simulation`) and the dt_fixed warning measure against them."""
        fl = self.fluid
        out = {"sound speed": math.sqrt(float(fl.lambda_f) / float(fl.rho0))}
        waves = []
        seen: dict = {}  # one differentiation of the stress per distinct law, not per solid
        for s in self.solids:
            law = s.law
            try:
                waves.append(seen[law])
                continue
            except KeyError:
                cacheable = True
            except TypeError:  # a law holding arrays (a traced or differentiated case)
                cacheable = False
            try:
                _, M = law.moduli()
                wave = math.sqrt(float(M) / float(law.rho0))
            except (AttributeError, TypeError, ValueError):
                continue
            if cacheable:
                seen[law] = wave
            waves.append(wave)
        if waves:
            out["solid wave speed"] = max(waves)
        edge_speeds = [0.0]
        for name in self.boundary.faces:
            e = getattr(self.boundary, name)
            if isinstance(e, str):
                continue
            for seg in e:
                edge_speeds.append(math.hypot(*seg.velocity))
        if max(edge_speeds) > 0:
            out["boundary speed"] = max(edge_speeds)
        vs = [math.hypot(*s.velocity) for s in self.solids]
        if vs and max(vs) > 0:
            out["initial solid speed"] = max(vs)
        if self.initial_velocity is not None:
            try:
                v0 = np.asarray(self.initial_velocity_field(), dtype=float)
                vmax = float(np.sqrt(np.sum(v0**2, axis=0)).max())
            except (CaseError, TypeError, ValueError):
                vmax = 0.0
            if vmax > 0:
                # a solid's own velocity adds to the field (Model.initial_state)
                out["initial speed"] = vmax + (max(vs) if vs else 0.0)
        gmag = math.hypot(*(float(x) for x in self.gravity))
        if gmag > 0:
            out["free fall"] = math.sqrt(2.0 * gmag * max(self._extents()))
        if self.numerics.fluid_model == "incompressible" and len(out) > 1:
            del out["sound speed"]  # lambda_f is unused: an incompressible fluid has no sound
        return out

    def _extents(self) -> tuple[float, ...]:
        """The domain's length along each axis."""
        g = self.grid
        return tuple(hi - lo for lo, hi in zip(g.lows, g.highs, strict=True))

    def hydrostatic_mach(self):
        """``(M, rho0, |g|, L, lambda_f)`` with M = rho0 |g| L / lambda_f, L the domain's
        height along g (see :meth:`_check_hydrostatic`); None without gravity or with
        traced fluid parameters or an incompressible fluid."""
        if self.numerics.fluid_model == "incompressible":
            return None
        gvec = [float(x) for x in self.gravity]
        gmag = math.hypot(*gvec)
        if gmag == 0:
            return None
        fl = self.fluid
        try:
            rho0, lam = float(fl.rho0), float(fl.lambda_f)
        except (TypeError, ValueError):
            return None
        L = sum(abs(gc) * e for gc, e in zip(gvec, self._extents(), strict=True)) / gmag  # height along g
        return rho0 * gmag * L / lam, rho0, gmag, L, lam

    def sound_damping_shortfall(self):
        """``(nu, need, c, h)`` when sound is under-damped with the centred compression
        (``(eta + extra_viscosity + bulk_viscosity) / rho0 = nu < need = c h / 2``; see
        :meth:`_check_sound_damping`), else None."""
        if self.numerics.compression != "centred" or self.numerics.fluid_model == "incompressible":
            return None
        fl = self.fluid
        try:
            c = math.sqrt(float(fl.lambda_f) / float(fl.rho0))
            nu = (float(fl.eta) + float(fl.extra_viscosity) + float(fl.bulk_viscosity)) / float(
                fl.rho0
            )
        except (TypeError, ValueError):  # traced or symbolic parameters: nothing to check
            return None
        h = self.grid.h
        need = 0.5 * c * h
        return None if nu >= need else (nu, need, c, h)

    def _check_hydrostatic(self):
        """Warn when gravity compresses the fluid by more than its stiffness can hold.

        The fluid starts at uniform density; under gravity it settles towards hydrostatic
        balance, dp/dy = -rho g with p = lambda_f (rho / rho0 - 1).  The settling flow
        reaches speeds of about g L / c (c the sound speed, L the domain's height along g),
        i.e. a Mach number M = rho0 |g| L / lambda_f, and the balanced density varies as
        exp(M) from top to bottom.  Measured (a neutrally buoyant disc in the 4 x 4 box,
        32^2): M = 0.1 moves it by 0.09 by t = 2, M = 0.4 by 0.28, M = 4 (g = 1 with the
        default fluid) sinks it by 1.4 and loses 28 % of the fluid mass to the vacuum at
        the top, M = 39 (g = 9.81) blows up at t = 0.85.  Above M = 1 the settling flow is
        supersonic, which this scheme does not capture (see docs/method.md).
        """
        hm = self.hydrostatic_mach()
        if hm is None:
            return
        mach, rho0, gmag, L, lam = hm
        if mach <= 1.0:
            return
        warnings.warn(
            f"case {self.name!r}: gravity compresses the fluid more than it can hold: "
            f"rho0 |g| L / lambda_f = {mach:.3g} > 1 (rho0 = {rho0:g}, |g| = {gmag:g}, height "
            f"L = {L:g}, lambda_f = {lam:g}); the fluid settles at about {mach:.2g} times its "
            f"sound speed and its density varies by a factor exp({mach:.2g}) from top to "
            f"bottom, so buoyancy is wrong and the run may blow up.  Raise fluid.lambda_f to "
            f">= {10 * rho0 * gmag * L:.3g} (rho0 |g| L / lambda_f <= 0.1; mind the "
            "sound-damping condition, or use numerics.compression = 'corner'), or lower the "
            "gravity",
            CaseWarning,
            stacklevel=3,
        )

    def _check_dt_fixed(self):
        """Warn when ``numerics.dt_fixed`` exceeds the adaptive step at t = 0.

        The adaptive step (:meth:`refmap.model.Model.time_step`) is evaluated on the
        case's parameters with the fastest initial speed the case sets up (boundary and
        initial solid velocities); the step limits do not depend on anything else, so this
        is the limit the first step would get without ``dt_fixed`` (cfl included)."""
        dt = self.numerics.dt_fixed
        if dt is None:
            return
        from types import SimpleNamespace

        from refmap.model import LIMIT_NAMES, Model
        from refmap.state import Params

        sc = self.velocity_scales()
        v0 = max(sc.get("boundary speed", 0.0), sc.get("initial solid speed", 0.0),
                 sc.get("initial speed", 0.0))
        nd = self.grid.ndim
        fake_model = SimpleNamespace(h=self.grid.h, ndim=nd,
                                     numerics=replace(self.numerics, dt_fixed=None, dt_max=None))
        fake_state = SimpleNamespace(v=np.full((nd,) + (1,) * nd, v0 / nd))
        params = Params(fluid=self.fluid, laws=tuple(s.law for s in self.solids),
                        gravity=tuple(float(x) for x in self.gravity))
        try:
            lim, i = Model.time_step(fake_model, fake_state, params)
            lim, name = float(lim), LIMIT_NAMES[int(i)]
        except Exception:  # noqa: BLE001 - traced or unusual laws: nothing to check
            return
        if float(dt) <= lim:
            return
        warnings.warn(
            f"case {self.name!r}: numerics.dt_fixed = {float(dt):g} is {float(dt) / lim:.3g} "
            f"times the adaptive step at t = 0, {lim:.3g} (limited by {name}, cfl = "
            f"{self.numerics.cfl:g}); the run will likely blow up.  Use dt_fixed <= {lim:.3g} "
            "or leave it out (adaptive step)",
            CaseWarning,
            stacklevel=3,
        )

    def _check_sound_damping(self):
        """Warn when sound in the fluid is too little damped for this grid.

        With ``numerics.compression = "centred"`` (the thesis's, the default) the fluid's
        pressure force is one-sided and its compression centred, a pair that amplifies the
        shortest sound waves unless (eta + extra_viscosity + bulk_viscosity) / rho0 >=
        c h / 2 (see :class:`refmap.state.FluidParams`).  Measured: a 32^2 lid-driven
        cavity with c = 10 and viscosity 0.01 reached |v| = 12 by t = 0.1 with a lid speed
        of 1, at any dt.  The energy-consistent ``compression = "corner"`` has no such
        condition (the same cavity stays at |v| = 0.67 without bulk viscosity), so there is
        nothing to warn about.
        """
        short = self.sound_damping_shortfall()
        if short is None:
            return
        nu, need, c, h = short
        zeta = (need - nu) * float(self.fluid.rho0)
        warnings.warn(
            f"case {self.name!r}: sound in the fluid is under-damped on this grid: "
            f"(eta + extra_viscosity + bulk_viscosity) / rho0 = {nu:.3g} < c h / 2 = {need:.3g} "
            f"(c = {c:.3g}, h = {h:.3g}); short sound waves will grow.  Set "
            f"fluid.bulk_viscosity >= {zeta:.3g}, or numerics.compression = 'corner' (the "
            "energy-consistent pairing, no such condition), or more viscosity, a finer grid, "
            "or a lower lambda_f",
            CaseWarning,
            stacklevel=3,
        )

    def to_dict(self):
        return {
            "name": self.name,
            "grid": {f.name: getattr(self.grid, f.name) for f in fields(self.grid)},
            "fluid": self.fluid.to_dict(),
            "numerics": self.numerics.to_dict(),
            "boundary": self.boundary.to_dict(),
            "gravity": list(self.gravity),
            "t_end": self.t_end,
            "frames": self.frames,
            "picture_field": self.picture_field,
            **({} if self.contact is None else {"contact": self.contact.to_dict()}),
            **({} if self.initial_velocity is None
               else {"initial_velocity": self.initial_velocity.to_dict()}),
            "solids": [
                {
                    "name": s.name,
                    "shape": s.shape.to_dict(),
                    "law": s.law.to_dict(),
                    "strain": [list(r) for r in s.strain],
                    "strain_center": list(s.strain_center),
                    "velocity": list(s.velocity),
                    "anchor": None if s.anchor is None else s.anchor.to_dict(),
                }
                for s in self.solids
            ],
        }

    def build(self):
        """Validated (model, params) pair; the model carries ``contact`` (if any) as a body
        force."""
        from refmap.model import Model
        from refmap.state import Params

        self.validate()
        forces = () if self.contact is None else (self.contact,)
        model = Model(self.grid, self.solids, self.boundary, self.numerics, body_forces=forces,
                      initial_velocity=self.initial_velocity_field())
        params = Params(fluid=self.fluid, laws=tuple(s.law for s in self.solids),
                        gravity=tuple(float(x) for x in self.gravity))
        return model, params
