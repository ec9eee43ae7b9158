"""Built-in 3D scenarios (issue 12): the same ``refmap run NAME --n N`` as in 2D.

Importing this module registers them with :func:`refmap.scenarios.scenario`:

* ``sphere_relax`` -- a sphere released from an isochoric stretch in a closed box: it
  springs back, overshoots and rings down in the viscous fluid, sending out sound.
* ``sphere_cavity`` -- a soft sphere in a lid-driven cube (the 2D lid-driven cavity's
  set-up, ``validation/lid_cavity.py``, extruded: Re = 100, a neo-Hookean solid as soft as
  the fluid's dynamic pressure, G = 0.1 rho U^2).
* ``cross`` -- the thesis's rotor in 3D: a soft cross, a slab 0.8 thick, on an axle along
  z through its centre, turned by a flow that enters through the left face and leaves
  through the top face (3D faces take whole-face conditions, so the 2D rotor's half-edge
  inflow and outflow become two whole faces at right angles).
* ``spheres_collide`` -- two soft spheres thrown at each other, slightly off-axis, in a
  light fluid in a closed box, with contact (:class:`refmap.contact.Contact`).
* ``spheres_settle`` -- four soft spheres of different sizes and densities settling under
  gravity (along -y) onto the floor of a closed box and piling up, with contact (the 2D
  ``settle`` in 3D).

``n`` is the number of cells along x.  Every scenario takes the incompressible fluid too
(``case.replace(numerics=dataclasses.replace(case.numerics, fluid_model="incompressible"))``,
or ``fluid_model = "incompressible"`` in a case file; docs/method.md, "Three dimensions").
"""

from __future__ import annotations

import math

from refmap.anchors import PivotAnchor
from refmap.boundary import Boundary, Segment
from refmap.case import Case
from refmap.contact import Contact
from refmap.geometry import Box, Sphere, Union
from refmap.grid import Grid3D
from refmap.materials import LogNeoHookean, NeoHookean
from refmap.model import Solid
from refmap.scenarios import DESCRIPTIONS, scenario
from refmap.state import FluidParams, Numerics

CLOSED_BOX = dict(back="wall", front="wall")


@scenario("sphere_relax", "3D: a sphere released from a 25 % isochoric stretch in a closed box rings down")
def sphere_relax(n: int = 32) -> Case:
    # F = A^-1 = diag(1.25, 1/sqrt(1.25), 1/sqrt(1.25)): stretched along x, J = 1; the
    # thesis's solid (G = kappa = 10) and fluid, as the 2D "circle"
    a = 1.25
    A = ((1.0 / a, 0.0, 0.0), (0.0, math.sqrt(a), 0.0), (0.0, 0.0, math.sqrt(a)))
    solid = Solid(shape=Sphere(center=(0.0, 0.0, 0.0), radius=0.6),
                  law=NeoHookean(G=10.0, kappa=10.0, rho0=1.0, dim=3), strain=A, name="sphere")
    return Case(
        name="sphere_relax",
        grid=Grid3D(n, n, n, -1.5, 1.5, -1.5, 1.5, -1.5, 1.5),
        solids=(solid,),
        boundary=Boundary(**CLOSED_BOX),
        fluid=FluidParams(),
        t_end=2.0,
        frames=20,
        description=DESCRIPTIONS["sphere_relax"],
    )


@scenario("sphere_cavity", "3D: a soft sphere carried round a lid-driven cube (Re = 100)")
def sphere_cavity(n: int = 32) -> Case:
    h = 1.0 / n
    c = 10.0  # sound speed: lid Mach number 0.1
    solid = Solid(shape=Sphere(center=(0.6, 0.5, 0.5), radius=0.2),
                  law=LogNeoHookean(G=0.1, kappa=10.0, rho0=1.0, dim=3), name="sphere")
    lid = Segment("velocity", velocity=(1.0, 0.0, 0.0))
    return Case(
        name="sphere_cavity",
        grid=Grid3D(n, n, n, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0),
        solids=(solid,),
        boundary=Boundary(top=(lid,), **CLOSED_BOX),
        # viscosity 0.01 (Re = 100) in fluid and solid; the bulk viscosity c h damps the
        # shortest sound waves (the 2D cavity's choice, docs/validation_lid_cavity.md)
        fluid=FluidParams(rho0=1.0, lambda_f=c * c, eta=0.0, extra_viscosity=0.01, bulk_viscosity=c * h),
        numerics=Numerics(cfl=0.5),
        t_end=4.0,
        frames=40,
        description=DESCRIPTIONS["sphere_cavity"],
    )


@scenario("cross", "3D: a soft cross on an axle, turned by a flow entering on the left and leaving at the top")
def cross(n: int = 32) -> Case:
    # the thesis's rotor (arm half length 1.1, half width 0.4, G = kappa = 10) as a slab of
    # half thickness 0.4 with rounded edges, on an axle along z held over its thickness
    arm = dict(center=(0.0, 0.0, 0.0), corner_radius=0.15)
    shape = Union(Box(half_size=(1.1, 0.4, 0.4), **arm), Box(half_size=(0.4, 1.1, 0.4), **arm))
    solid = Solid(shape=shape, law=NeoHookean(G=10.0, kappa=10.0, rho0=1.0, dim=3), name="cross",
                  anchor=PivotAnchor(center=(0.0, 0.0, 0.0), fit_radius=0.4, hold_radius=0.3,
                                     half_length=0.4))
    # inflow u = 0.2 through the left face, the same flux out through the top face (equal
    # areas, 4 x 2), slip on the others
    boundary = Boundary(left=(Segment("velocity", velocity=(0.2, 0.0, 0.0)),), right="slip",
                        bottom="slip", top=(Segment("velocity", velocity=(0.0, 0.2, 0.0)),),
                        back="slip", front="slip")
    return Case(
        name="cross",
        grid=Grid3D(n, n, max(8, n // 2), -2.0, 2.0, -2.0, 2.0, -1.0, 1.0),
        solids=(solid,),
        boundary=boundary,
        numerics=Numerics(cfl=0.3),
        t_end=10.0,
        frames=40,
        description=DESCRIPTIONS["cross"],
    )


@scenario("spheres_collide", "3D: two soft spheres thrown at each other, slightly off-axis, bounce off (contact)")
def spheres_collide(n: int = 32) -> Case:
    # Two spheres of radius 0.3 (the thesis's solid, G = kappa = 10, twice as dense as
    # water-like 1) thrown at each other at speed 1 from 0.24 apart, the left one 0.05 off
    # the axis in y and z so that the contact is oblique.  The fluid is light (rho 0.2) so
    # that it takes little of the spheres' momentum, and stiff (lambda_f = 5, sound speed 5,
    # the spheres at Mach 0.2: with the thesis's sound speed 1 the spheres are transonic and
    # the fluid behind them cavitates); eta 0.02 and extra viscosity 0.05 (the solid waves'
    # damping, see Model.time_step) keep the sound damped (diffusivity 0.35 >= c h / 2 for
    # n >= 16).  The energy-consistent compression, as in the 2D contact scenarios.
    # Measured at 32^3 (radius 4.8 cells) to t = 1: the squeezed film between the blur
    # zones brakes the pair from 3 cells apart (mean velocity 0.46 -> 0.10 by t = 0.15, 2.5
    # cells apart); it closes to 1.7 cells at t = 0.35 under a contact pressure of 0.18 (M
    # = 23), then rests about 2 cells apart; no overlap, J_min >= 0.83.  At 16^3 (2.4
    # cells) the contact acts from the start: smallest gap 0.9 cells, pressure up to 1.1.
    # Denser spheres in less damping (rho 5, extra viscosity 0.02) broke down at 24^3 near
    # t = 0.4 with or without contact (level sets crossing, |v| ~ 20-40): not a default.
    law = NeoHookean(G=10.0, kappa=10.0, rho0=2.0, dim=3)
    a = Solid(shape=Sphere(center=(-0.42, 0.05, 0.05), radius=0.3), law=law,
              velocity=(1.0, 0.0, 0.0), name="left sphere")
    b = Solid(shape=Sphere(center=(0.42, 0.0, 0.0), radius=0.3), law=law,
              velocity=(-1.0, 0.0, 0.0), name="right sphere")
    return Case(
        name="spheres_collide",
        grid=Grid3D(n, n, n, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0),
        solids=(a, b),
        boundary=Boundary(**CLOSED_BOX),
        fluid=FluidParams(rho0=0.2, lambda_f=5.0, eta=0.02, extra_viscosity=0.05),
        numerics=Numerics(compression="corner"),
        t_end=1.0,
        frames=20,
        description=DESCRIPTIONS["spheres_collide"],
        contact=Contact(),
    )


# (centre, radius, density) of the settling spheres: three a little above the floor (at
# least two node rows clear of it from 16 cells on: a solid touching a resting wall at
# t = 0 is glued to it), not touching
# each other, and a fourth, heavier, above the hollow between them (over the centre of
# the circle through the three centres, -0.03, -0.07 in x, z)
SETTLE_SPHERES = (
    ((-0.45, -0.42, -0.3), 0.32, 2.0),
    ((0.35, -0.45, -0.35), 0.3, 1.8),
    ((0.0, -0.42, 0.4), 0.3, 1.6),
    ((-0.03, 0.1, -0.07), 0.28, 3.0),
)


@scenario("spheres_settle", "3D: four soft spheres settling under gravity onto the floor of a box and piling up (contact)")
def spheres_settle(n: int = 32) -> Case:
    # The 2D ``settle`` (scenarios_fssi) in a [-1, 1]^3 box: the thesis's solid (G = kappa =
    # 10, densities 1.6-2), its fluid made five times stiffer (lambda_f = 5) as in 2D, so
    # that under g = 0.5 along -y the fluid's stratification g H / lambda_f = 0.2 is mild,
    # and the extra viscosity of spheres_collide (0.05) so that the solids' wave-damping
    # step limit (2 extra_viscosity / M, Model.time_step) is not the smallest.  Energy-
    # consistent compression and the default contact (walls included), as every contact
    # scenario.  The fluid starts uniform: switching gravity on first sets the column
    # oscillating, and the spheres bob with it.
    solids = tuple(
        Solid(shape=Sphere(center=c, radius=r), law=NeoHookean(G=10.0, kappa=10.0, rho0=rho, dim=3),
              name=f"sphere{k} (r={r:g}, rho={rho:g})")
        for k, (c, r, rho) in enumerate(SETTLE_SPHERES)
    )
    return Case(
        name="spheres_settle",
        grid=Grid3D(n, n, n, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0),
        solids=solids,
        boundary=Boundary(**CLOSED_BOX),
        fluid=FluidParams(lambda_f=5.0, extra_viscosity=0.05),
        numerics=Numerics(compression="corner", fluid_mass="conserved"),
        gravity=(0.0, -0.5, 0.0),
        t_end=8.0,
        frames=32,
        description=DESCRIPTIONS["spheres_settle"],
        contact=Contact(),
    )
