"""Fluid-solid-solid scenarios (thesis section 4.11): several soft solids in one fluid, with
contact (:class:`refmap.contact.Contact`).

Importing this module registers five scenarios with :func:`refmap.scenarios.scenario`:

* ``two_balls`` -- an anchored ball and a mobile ball pressed together by a flow entering
  from the left (thesis Fig. 4-32);
* ``ball_stick`` -- a ball (density 2) thrown at a stick anchored at its foot; it bends
  the stick, bounces off and falls back under weak gravity (thesis Figs. 4-33 to 4-35);
* ``settle`` -- five soft balls of different sizes and densities 1.5-2 settling under
  gravity onto the floor of a closed box and piling up (in a five times stiffer fluid,
  see the function);
* ``suspension`` -- a hundred small soft discs, half heavier and half lighter than the
  fluid, on a jittered lattice in a closed box: the heavy ones sink, the light ones rise,
  and they pass each other (the many-body case of the peer RMT codes);
* ``dense_suspension`` -- the same at the peer codes' resolution, a thousand discs at the
  default 1024^2, each stored in a window that follows it.

Common parameters are the thesis's: domain [-2, 2]^2, compressible neo-Hookean solids with
G = kappa = 10 (density 1 unless stated), fluid rho_f0 = 1, lambda_f = 1, eta = 0.12, extra
viscosity 0.02 (``settle`` excepted: lambda_f = 5); every scenario uses the default
:class:`Contact` (walls included), implicit viscosity (``Numerics(viscosity="implicit")``:
the explicit step's wave-damping limit, dt = 8.6e-4 at any n, is gone and the solids' wave
limit binds, 3.8x longer at 128^2 and 7.5x at 64^2; docs/fssi.md, "Implicit viscosity in
the FSSI scenarios") and the energy-consistent fluid compression
(``Numerics(compression="corner")``): with the thesis's centred one, a one-node velocity
jet in the fluid film between two pressed bodies pumped the film's density without bound
(``two_balls`` at 96^2: rho_f 12 at t = 9, 118 at t = 12, broken at t ~ 14).

Each returns a plain :class:`refmap.case.Case` whose ``contact`` field holds the default
:class:`Contact`; ``case.replace(contact=None)`` runs the same case without contact.
"""

from __future__ import annotations

import dataclasses
import math

from refmap.anchors import RegionAnchor
from refmap.boundary import Boundary, Segment
from refmap.case import Case
from refmap.contact import Contact
from refmap.geometry import Capsule, Disc
from refmap.grid import Grid
from refmap.materials import NeoHookean
from refmap.model import Solid
from refmap.scenarios import DESCRIPTIONS, scenario
from refmap.state import FluidParams, Numerics

__all__ = ["two_balls", "ball_stick", "settle", "suspension", "dense_suspension", "suspension_discs",
           "SETTLE_BALLS"]


#: every FSSI scenario: energy-consistent compression (the film between pressed bodies) and
#: implicit viscosity (a step set by the solids' wave speed, not the explicit damping limit)
_NUMERICS = Numerics(compression="corner", viscosity="implicit")


def _law(rho0: float = 1.0):
    return NeoHookean(G=10.0, kappa=10.0, rho0=rho0)


@scenario(
    "two_balls",
    "an anchored and a mobile soft ball pressed together by a flow entering from the left",
)
def two_balls(n: int = 128) -> Case:
    # The anchored ball is held by its centre (radius 0.2 of 0.5), so its rim deforms freely.
    # The flow (u = 0.3, ramped up over t = 1, prescribed on the left and right edges as in
    # the thesis's stick case, free slip top and bottom) carries the mobile ball, 0.3 away,
    # onto it head-on.  The deformation stays moderate: the flow's stresses (~ rho U^2,
    # eta U / R) are small next to G = 10, and a much faster flow is transonic in this
    # fluid (sound speed 1).
    # Measured with the energy-consistent compression (the thesis's centred one let the
    # film between the balls pump its density and broke the 96^2 run at t ~ 14) and the
    # explicit viscous step (the implicit one follows its paths within 0.02 h): at 128^2
    # contact from t ~ 2.7, gap 0.045 (1.4 cells) from t = 4 to t = 20 under a contact
    # pressure of 0.2-0.3, no overlap, J in [0.93, 1.03]; at 64^2 gap 0.09 (1.4 cells),
    # and the mobile ball slowly slides off sideways (frictionless; centroid y -0.07 by
    # t = 16, against -0.003 at 128^2).
    fixed = Solid(
        shape=Disc(center=(0.55, 0.0), radius=0.5),
        law=_law(),
        anchor=RegionAnchor(Disc(center=(0.55, 0.0), radius=0.2)),
        name="anchored ball",
    )
    mobile = Solid(shape=Disc(center=(-0.75, 0.0), radius=0.5), law=_law(), name="mobile ball")
    flow = Segment("velocity", velocity=(0.3, 0.0), ramp=1.0)
    return Case(
        name="two_balls",
        grid=Grid(n, n, -2.0, 2.0, -2.0, 2.0),
        solids=(fixed, mobile),
        boundary=Boundary(left=(flow,), right=(flow,), bottom="slip", top="slip"),
        fluid=FluidParams(),
        numerics=_NUMERICS,
        t_end=20.0,
        frames=40,
        description=DESCRIPTIONS["two_balls"],
        contact=Contact(),
    )


@scenario(
    "ball_stick",
    "a soft ball thrown at a stick anchored at its foot; bends it, bounces off, falls back",
)
def ball_stick(n: int = 128) -> Case:
    # A stick (capsule, half-length 0.95, radius 0.25, the thesis's G = kappa = 10) anchored
    # at its foot near the floor of a closed box; a ball of radius 0.4 thrown at its upper
    # half at speed 1.2 from 0.25 away; weak gravity g = 0.2 brings it back down.  The ball
    # is twice as dense as the fluid: a ball of density 1 shares half its momentum with the
    # fluid it sets moving at once (added mass) and the viscous fluid (eta = 0.12) stops it
    # about two cells short of the stick at 64^2, so it pushes the stick only through the
    # fluid film; with density 2 it reaches it, the contact pressure acts (closest gap 1.1
    # cells), the top of the stick is pushed 0.43 sideways, springs back and throws the
    # ball off (measured at 64^2 with the explicit viscous step, which the implicit one
    # follows within 0.06 h: ball centre x -0.3 -> 0.20 at t = 2.5 -> -0.14 at t = 6,
    # y 0.5 -> -0.15 at t = 6).
    stick = Solid(
        shape=Capsule(center=(0.6, -0.5), half_length=0.95, radius=0.25, angle=math.pi / 2),
        law=_law(),
        anchor=RegionAnchor(Disc(center=(0.6, -1.45), radius=0.22)),
        name="stick",
    )
    ball = Solid(
        shape=Disc(center=(-0.3, 0.5), radius=0.4), law=_law(2.0), velocity=(1.2, 0.0), name="ball"
    )
    return Case(
        name="ball_stick",
        grid=Grid(n, n, -2.0, 2.0, -2.0, 2.0),
        solids=(stick, ball),
        boundary=Boundary(),
        fluid=FluidParams(),
        numerics=_NUMERICS,
        gravity=(0.0, -0.2),
        t_end=12.0,
        frames=60,
        description=DESCRIPTIONS["ball_stick"],
        contact=Contact(),
    )


# (centre, radius, density) of the settling balls: a bottom row of three just above the
# floor and two balls above them that fall into the gaps and pile up
SETTLE_BALLS = (
    ((-0.95, -1.2), 0.55, 2.0),
    ((0.3, -1.25), 0.5, 1.8),
    ((1.35, -0.95), 0.4, 1.5),
    ((-0.3, -0.05), 0.45, 2.0),
    ((0.8, 0.55), 0.35, 1.7),
)


@scenario(
    "settle",
    "five soft balls of different sizes and densities settling under gravity and piling up",
)
def settle(n: int = 128) -> Case:
    # The fluid is five times stiffer than the thesis's (lambda_f = 5, sound speed 2.2) and
    # gravity is g = 0.5.  In the thesis's fluid (lambda_f = 1) the scale height
    # lambda_f / (rho g) is 1 / g, comparable with the 4-high box: under g = 1 the fluid at
    # the top rarefied to rho_f = 0.08 by t = 3 (32^2) and the 64^2 run broke down before
    # t = 3; under g = 0.2 the fluid near the floor grew as dense as the balls (1.6-1.8) and
    # the balls hovered at mid-height instead of settling (64^2, t = 16).  With g H / lambda_f
    # = 0.4 the stratification is mild and every ball (1.5-2) is heavier than the fluid;
    # lambda_f = 20 (g = 1) grew an odd-even mode in the fluid density next to the walls,
    # with or without contact (amplitude 0.6 at 32^2; 0.02-0.04 for lambda_f = 5).  The dt
    # is set by the solids either way.  The fluid starts uniform, so switching on gravity
    # first makes the whole column oscillate (period ~ 2 H / c ~ 4) and the balls bob with
    # it.  Measured at 64^2 to t = 16: the bottom row rests one cell above the floor and is
    # pushed apart by ball 3, which settles into the notch between balls 0 and 1 (contact
    # pressure up to 0.38, no overlap); ball 4 is still on its way down into the notch
    # between balls 1 and 2; fluid mass -6.0 % (non-conservative density update).
    solids = tuple(
        Solid(shape=Disc(center=c, radius=r), law=_law(rho), name=f"ball{k} (r={r:g}, rho={rho:g})")
        for k, (c, r, rho) in enumerate(SETTLE_BALLS)
    )
    return _settling_box("settle", n, solids, t_end=16.0, frames=60)


def _settling_box(name: str, n: int, solids, t_end: float, frames: int) -> Case:
    """Solids in the closed [-2, 2]^2 box of ``settle`` (and ``suspension``): lambda_f = 5,
    g = 0.5 downwards, energy-consistent compression, implicit viscosity, default contact.

    Implicit viscosity (since 2026-12-06): the explicit viscous and wave-damping limits
    held these cases at a 5-11x shorter step than the solids' wave (5.8x at 64^2, 11x at
    300^2, growing with n); at 64^2 the two modes' centroids agree within 0.02 h and the
    kinetic energy within 3 % (settle to t = 8, 16 suspension discs to t = 4;
    docs/fssi.md, "Implicit viscosity in the FSSI scenarios")."""
    return Case(
        name=name,
        grid=Grid(n, n, -2.0, 2.0, -2.0, 2.0),
        solids=solids,
        boundary=Boundary(),
        fluid=FluidParams(lambda_f=5.0),
        numerics=_NUMERICS,
        gravity=(0.0, -0.5),
        t_end=t_end,
        frames=frames,
        description=DESCRIPTIONS[name],
        contact=Contact(),
    )


def suspension_discs(count: int = 100, seed: int = 7, box: float = 2.0, fill: float = 0.3):
    """(centre, radius, density) of the ``suspension`` discs: ``count`` equal discs covering
    the fraction ``fill`` of the [-box, box]^2 box, on a square lattice (the nearest square
    number of sites at or above ``count``, the extra sites left empty at random), each
    centre moved by up to a quarter of the free space between neighbours (so the closest
    pair is at least half that space apart); the lattice fills 90 % of the box, leaving the
    discs off the walls; densities alternate 1.5 / 0.6 in a
    random order (equal numbers).  Deterministic for a given seed."""
    import numpy as np

    if not (isinstance(count, int) and count >= 1):
        raise ValueError(f"suspension count must be an integer >= 1, got {count!r}")
    rng = np.random.default_rng(seed)
    side = math.ceil(math.sqrt(count))
    L = 2.0 * box
    r = math.sqrt(fill * L * L / (count * math.pi))
    spacing = 0.9 * L / side
    if 2.0 * r > 0.8 * spacing:
        raise ValueError(f"suspension: {count} discs filling {fill} of the box do not fit")
    sites = [(i, j) for i in range(side) for j in range(side)]
    keep = sorted(rng.choice(len(sites), size=count, replace=False))
    jitter = rng.uniform(-1.0, 1.0, size=(count, 2)) * 0.25 * (spacing - 2.0 * r)
    dens = np.array([1.5, 0.6] * ((count + 1) // 2))[:count]
    rng.shuffle(dens)
    out = []
    for k, s in enumerate(keep):
        i, j = sites[s]
        x0 = -0.9 * box
        c = (x0 + (i + 0.5) * spacing + jitter[k, 0], x0 + (j + 0.5) * spacing + jitter[k, 1])
        out.append(((float(c[0]), float(c[1])), r, float(dens[k])))
    return tuple(out)


@scenario(
    "suspension",
    "a hundred soft discs, half heavier and half lighter than the fluid, sinking and rising past each other",
)
def suspension(n: int = 128, count: int = 100) -> Case:
    # 100 discs of radius 0.124 (30 % of the 4 x 4 box) on a jittered 10 x 10 lattice
    # (closest pair 0.06 apart, 0.23 from the walls),
    # densities 1.5 and 0.6 in the fluid of ``settle`` (lambda_f = 5, g = 0.5: mild
    # stratification, see there).  At the default 128^2 a disc is 8 cells across (19 at
    # 300^2, the peer codes' size).  Each disc keeps its reference map and level set in a
    # window that follows it (Numerics.solid_storage = "window", docs/design_windows.md):
    # at 128^2 a step takes 0.65 of the time with every disc on the whole grid, at 300^2
    # 0.40 (docs/fssi.md).  At 48^2 and below a window would hold more than half the grid,
    # and the discs are kept on the grid.
    solids = tuple(
        Solid(shape=Disc(center=c, radius=r), law=_law(rho), name=f"disc{k} (rho={rho:g})")
        for k, (c, r, rho) in enumerate(suspension_discs(count))
    )
    case = _settling_box("suspension", n, solids, t_end=10.0, frames=50)
    return case.replace(numerics=dataclasses.replace(case.numerics, solid_storage="window"))


#: ``dense_suspension``: discs at the default grid (1024^2), and the grid size they scale with
DENSE_COUNT, DENSE_N = 1000, 1024


@scenario(
    "dense_suspension",
    "a thousand soft discs (at 1024^2; fewer on coarser grids, each 20 cells across) "
    "sinking and rising in a closed box, each stored in a window that follows it",
)
def dense_suspension(n: int = DENSE_N) -> Case:
    # the suspension's discs (30 % of the box, densities 1.5 and 0.6, settle's fluid) at
    # the peer codes' resolution of about 20 cells across (19 at 300^2 in `suspension`):
    # round(1000 (n / 1024)^2) discs, so 1000 at the default 1024^2, 16 at 128^2 and 4 at
    # 64^2 (at least 4: fewer do not fit the lattice at 30 %; at 64^2 a disc's window would
    # be more than half the grid, so the model keeps the discs on the grid there).  Every
    # disc keeps its reference map and level set in a window of about 61^2 nodes that
    # follows it (Numerics.solid_storage = "window", docs/design_windows.md): on the
    # whole grid the 1000 discs would need about 1 TB; in windows the run peaks at about
    # 3.4 GB and a step takes about 2.2 s on one core (docs/benchmarks.md, "A thousand
    # discs" and "One solid at a time").  The default end time is short for that cost (~2900 steps to t = 1).
    count = max(4, round(DENSE_COUNT * (n / DENSE_N) ** 2))
    solids = tuple(
        Solid(shape=Disc(center=c, radius=r), law=_law(rho), name=f"disc{k} (rho={rho:g})")
        for k, (c, r, rho) in enumerate(suspension_discs(count))
    )
    case = _settling_box("dense_suspension", n, solids, t_end=1.0, frames=20)
    return case.replace(numerics=dataclasses.replace(case.numerics, solid_storage="window"))
