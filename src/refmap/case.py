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

from refmap.boundary import Boundary
from refmap.grid import Grid
from refmap.state import FluidParams, Numerics


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
    gravity: tuple = (0.0, 0.0)
    t_end: float = 1.0
    frames: int = 10
    picture_field: str = "pressure"
    description: str = ""
    #: contact between the solids and against the walls: a :class:`refmap.contact.Contact`
    #: (passed to the model as a body force), or None for no contact
    contact: Any = None
    #: the velocity at t = 0 on every node, fluid and solids alike: None (at rest), a
    #: callable ``f(x, y) -> (u, v)`` on the node coordinate arrays, an array of shape
    #: ``(2, nx, ny)``, or a :mod:`refmap.initial` field (a formula or a file).  Each
    #: ``Solid.velocity`` is added to it, weighted by the solid's fraction (see
    #: :meth:`refmap.model.Model.initial_state`).  Stored as a :mod:`refmap.initial` field.
    initial_velocity: Any = None

    def __post_init__(self):
        from refmap.initial import InitialVelocityError, as_initial_velocity

        try:
            object.__setattr__(self, "initial_velocity", as_initial_velocity(self.initial_velocity))
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
        if len(self.gravity) != 2 or not all(math.isfinite(float(g)) for g in self.gravity):
            bad(f"gravity must be two finite numbers, got {self.gravity!r}")
        g = self.grid
        X, Y = g.mesh("node")
        h = g.h
        covered = np.zeros(X.shape, dtype=bool)  # nodes inside some solid
        for k, s in enumerate(self.solids):
            label = f"solids[{k}] ({s.name!r})"
            try:
                s.law.validate()
            except ValueError as e:
                bad(f"{label}: {e}")
            xi_x, xi_y = s.initial_map(X, Y)
            phi = np.asarray(s.shape(xi_x, xi_y))
            inside = phi < 0
            covered |= inside
            if not inside.any():
                bad(f"{label}: the shape covers no grid node (too small for n={g.nx}, or outside the domain)")
            # A solid may touch (or extend beyond) wall, slip and tangential velocity edges: it
            # is glued to a resting wall (BoundaryConditions.glue) and dragged by a moving one.
            # It may not touch an edge through which material would flow (outflow, or a
            # velocity segment with a normal component): nothing defines the map of material
            # entering from outside (measured: a disc at an inflow edge blew up by t = 2),
            # and a body leaving through an outflow left a few strained nodes behind.
            rows = {
                "left": inside[:2, :],
                "right": inside[-2:, :],
                "bottom": inside[:, :2],
                "top": inside[:, -2:],
            }
            for ename, hits in rows.items():
                edge = getattr(self.boundary, ename)
                if edge == "periodic":
                    continue
                axis = 0 if ename in ("left", "right") else 1
                hit = hits.any(axis=axis)  # per node along the edge
                if axis == 0:
                    along = (Y[0, :] - g.ay) / (g.by - g.ay)
                else:
                    along = (X[:, 0] - g.ax) / (g.bx - g.ax)
                for seg in edge:
                    on = (along >= seg.start) & ((along < seg.end) | (seg.end >= 1.0))
                    through = seg.kind == "outflow" or (
                        seg.kind == "velocity" and seg.velocity[axis] != 0.0
                    )
                    if through and (hit & on).any():
                        xb = f"[{X[inside].min():.3g}, {X[inside].max():.3g}]"
                        yb = f"[{Y[inside].min():.3g}, {Y[inside].max():.3g}]"
                        dom = f"[{g.ax}, {g.bx}] x [{g.ay}, {g.by}]"
                        bad(
                            f"{label}: the shape reaches the {ename} edge where it is a "
                            f"{seg.kind!r} segment with flow through it (x in {xb}, y in {yb}; "
                            f"domain {dom}); a solid may touch wall, slip and tangential "
                            "velocity edges only"
                        )
            if inside.sum() < 4:
                bad(f"{label}: only {int(inside.sum())} grid nodes inside; refine the grid (n={g.nx})")
            _ = h
        if not covered.all():  # a box filled with solid has no fluid to damp
            self._check_sound_damping()
        self.initial_velocity_field()
        return self

    def initial_velocity_field(self):
        """The ``(2, nx, ny)`` node values of :attr:`initial_velocity` (None when it is
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
        if self.numerics.compression != "centred":
            return
        fl = self.fluid
        try:
            c = math.sqrt(float(fl.lambda_f) / float(fl.rho0))
            nu = (float(fl.eta) + float(fl.extra_viscosity) + float(fl.bulk_viscosity)) / float(
                fl.rho0
            )
        except (TypeError, ValueError):  # traced or symbolic parameters: nothing to check
            return
        h = min(self.grid.dx, self.grid.dy)
        need = 0.5 * c * h
        if nu >= need:
            return
        zeta = (need - nu) * float(fl.rho0)
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
