"""2D results of the dimension-generic boundary padding and level-set code (issue 12, step
two) are bitwise those of the 2D code it replaced: every output is compared with
``np.array_equal`` to the frozen verbatim copy in ``tests/frozen_2d.py``, eagerly and under
``jax.jit``, on random arrays and every edge kind (wall, moving wall, slip, velocity segment
with a parabolic profile, ramp and omega, outflow, periodic)."""

import frozen_2d as old
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap import levelset as new_ls
from refmap.boundary import Boundary, BoundaryConditions, Segment
from refmap.grid import Grid

GRID = Grid(12, 9, ax=-1.0, bx=2.0, ay=0.0, by=1.5)

BOUNDARIES = {
    "mixed": Boundary(
        left=(Segment("velocity", 0.0, 0.5, (0.3, 0.1), profile="parabolic", ramp=1.0),
              Segment("wall", 0.5, 1.0)),
        right=(Segment("outflow", 0.0, 0.4), Segment("velocity", 0.4, 1.0, (0.2, -0.1))),
        bottom="slip",
        top=(Segment("wall", velocity=(1.0, 0.0)),),
    ),
    "x_periodic": Boundary(
        left="periodic", right="periodic",
        bottom=(Segment("velocity", velocity=(0.1, 0.4), omega=2.0, ramp=0.5),),
        top="outflow",
    ),
    "y_periodic": Boundary(left="slip", right="wall", bottom="periodic", top="periodic"),
    "all_periodic": Boundary(*(("periodic",) * 4)),
    "walls": Boundary(),
}


def _pair(name):
    b = BOUNDARIES[name]
    return BoundaryConditions(GRID, b, rho_f0=1.3), old.BoundaryConditions(GRID, b, rho_f0=1.3)


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    assert np.array_equal(a, b)


@pytest.mark.parametrize("name", list(BOUNDARIES))
def test_padding_2d_bitwise(name):
    bn, bo = _pair(name)
    rng = np.random.default_rng(7)
    nx, ny = GRID.shape()
    vel = jnp.asarray(rng.normal(size=(2, nx, ny)))
    rho = jnp.asarray(1 + 0.1 * rng.normal(size=(nx, ny)))
    f = jnp.asarray(rng.normal(size=(3, 2, nx, ny)))
    assert bn.periodic == bo.periodic and isinstance(bn.periodic, tuple)
    _same(bn.padded_coords(2), bo.padded_coords(2))
    _same(bn.padded_coords(1), bo.padded_coords(1))
    for t in (0.0, 0.3, 2.0):
        _same(bn.pad_velocity(vel, t), bo.pad_velocity(vel, t))
        _same(bn.pad_density(rho, t), bo.pad_density(rho, t))
        _same(bn.pad_density(rho, t, rho0=0.7), bo.pad_density(rho, t, rho0=0.7))
    t = jnp.asarray(0.3)
    _same(jax.jit(bn.pad_velocity)(vel, t), jax.jit(bo.pad_velocity)(vel, t))
    _same(jax.jit(bn.pad_density)(rho, t), jax.jit(bo.pad_density)(rho, t))
    _same(bn.pad_linear(f), bo.pad_linear(f))
    _same(jax.jit(bn.pad_linear)(f), jax.jit(bo.pad_linear)(f))
    xi = f + jnp.asarray(GRID.mesh())
    _same(bn.pad_affine(xi), bo.pad_affine(xi))
    # glued solids: one covering the bottom-left corner, one the top edge, one nowhere
    X, Y = GRID.mesh()
    solid0 = np.stack([(X < 0.3) & (Y < 0.5), Y > 1.0, np.zeros_like(X, bool)])
    disp0 = 0.05 * rng.normal(size=(3, 2, nx, ny))
    bn.glue(disp0, solid0)
    bo.glue(disp0, solid0)
    assert len(bn._glue) == len(bo._glue)
    for rn, ro in zip(bn._glue, bo._glue, strict=True):
        assert rn[:2] == ro[:2]
        for a, b in zip(rn[2:], ro[2:], strict=True):
            _same(a, b)
    _same(bn.pad_affine(xi), bo.pad_affine(xi))
    _same(jax.jit(bn.pad_affine)(xi), jax.jit(bo.pad_affine)(xi))
    # the coefficient tables (refmap.differentiable rewrites them) are the same
    assert list(bn._rules) == list(bo._rules)
    for key, rn in bn._rules.items():
        ro = bo._rules[key]
        for a in ("alpha", "beta", "gamma"):
            _same(getattr(rn, a), getattr(ro, a))
        assert len(rn.dirichlet) == len(ro.dirichlet)
        for dn, do in zip(rn.dirichlet, ro.dirichlet, strict=True):
            assert dn[0] == do[0] and dn[3] == do[3]
            _same(dn[1], do[1])
            _same(dn[2], do[2])


def test_padding_2d_gradient_bitwise():
    bn, bo = _pair("mixed")
    rng = np.random.default_rng(3)
    vel = jnp.asarray(rng.normal(size=(2, *GRID.shape())))
    w = jnp.asarray(rng.normal(size=(2, GRID.nx + 4, GRID.ny + 4)))
    gn = jax.grad(lambda v: jnp.sum(w * bn.pad_velocity(v, 0.4)))(vel)
    go = jax.grad(lambda v: jnp.sum(w * bo.pad_velocity(v, 0.4)))(vel)
    _same(gn, go)


def _levelsets():
    g = Grid(24, 20, ax=-1.0, bx=1.0, ay=-0.8, by=0.9)
    X, Y = g.mesh()
    rng = np.random.default_rng(11)
    r = np.hypot(X - 0.1, Y + 0.05)
    phi = (r - 0.5) * (1 + 0.4 * X) + 0.01 * rng.normal(size=X.shape)
    phi[3, 4] = 0.0  # an exact zero
    return g, jnp.asarray(np.stack([phi, np.cos(3 * X) * np.sin(2 * Y) + 0.1]))


@pytest.mark.parametrize("periodic", [(False, False), (True, False), (False, True), (True, True)])
def test_levelset_2d_bitwise(periodic):
    g, phis = _levelsets()
    for freeze in (False, True):
        a = new_ls.redistance(phis, g.dx, g.dy, 7, periodic, freeze)
        b = old.redistance(phis, g.dx, g.dy, 7, periodic, freeze)
        _same(a, b)
    _same(new_ls.unit_normal(phis, g.dx, g.dy, periodic), old.unit_normal(phis, g.dx, g.dy, periodic))
    if periodic == (True, False):  # compiled too (once: compiling is the slow part here)
        f_new = jax.jit(new_ls.redistance, static_argnums=(3, 4, 5))
        f_old = jax.jit(old.redistance, static_argnums=(3, 4, 5))
        _same(f_new(phis, g.dx, g.dy, 7, periodic, False), f_old(phis, g.dx, g.dy, 7, periodic, False))
        _same(jax.jit(new_ls.unit_normal, static_argnums=3)(phis, g.dx, g.dy, periodic),
              jax.jit(old.unit_normal, static_argnums=3)(phis, g.dx, g.dy, periodic))
    if periodic != (True, False):
        return  # the rest once (each call compiles its loop: seconds on a busy machine)
    psi = phis * 1.1 + 0.01
    args = (phis, psi, g.dx, g.dy, 0.5, 3 * g.h, 4 * g.h, 6, 6 * g.h, periodic)
    _same(new_ls.pin_levelset(*args), old.pin_levelset(*args))
    for axis in (-2, -1, 0):
        for per in (False, True):
            for edge, fill in (("linear", 0), ("fill", 0.5)):
                for a, b in zip(new_ls._neighbours(phis, axis, per, edge, fill),
                                old._neighbours(phis, axis, per, edge, fill), strict=True):
                    _same(a, b)
    # derivatives too
    w = jnp.asarray(np.random.default_rng(5).normal(size=phis.shape))
    gn = jax.grad(lambda p: jnp.sum(w * new_ls.redistance(p, g.dx, g.dy, 5, periodic)))(phis)
    go = jax.grad(lambda p: jnp.sum(w * old.redistance(p, g.dx, g.dy, 5, periodic)))(phis)
    _same(gn, go)
    wn = w[:, None]
    gn = jax.grad(lambda p: jnp.sum(wn * new_ls.unit_normal(p, g.dx, g.dy, periodic)))(phis)
    go = jax.grad(lambda p: jnp.sum(wn * old.unit_normal(p, g.dx, g.dy, periodic)))(phis)
    _same(gn, go)


def test_levelset_2d_defaults_bitwise():
    g, phis = _levelsets()
    _same(new_ls.redistance(phis, g.dx, g.dy, 5), old.redistance(phis, g.dx, g.dy, 5))
    _same(new_ls.unit_normal(phis, g.dx, g.dy), old.unit_normal(phis, g.dx, g.dy))
