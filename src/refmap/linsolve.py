"""Matrix-free linear solvers for the implicit viscous step (jit-able, differentiable).

* :func:`cg` -- preconditioned conjugate gradients on any array-shaped unknown, inside one
  ``lax.while_loop``; returns the solution and the iteration count and residual.
* :func:`solve_spd` -- the same solve wrapped in ``jax.lax.custom_linear_solve`` with
  ``symmetric=True``: derivatives (forward and reverse) are taken by implicit
  differentiation, i.e. one more solve with the same operator, never through the CG
  iterations.
* :func:`bicgstab`, :func:`solve_general` -- the same for a nonsymmetric operator
  (BiCGSTAB; the transposed system, for reverse mode, is solved the same way).
* :class:`SeparableSolver` -- an exact fast solve of the constant-coefficient operator
  ``a0 - ax Dxx - ay Dyy`` (``- az Dzz`` in 3D) on a node grid, with ``Dxx`` and ``Dyy`` the three-point second
  differences whose first ghost node is the odd (``-f_0``, a Dirichlet condition on the
  cell face) or even (``+f_0``, a Neumann condition) reflection of the first node, or
  periodic.  Each axis is diagonalised by a fast orthogonal transform:

  ========================  ==================  ===================================
  edges (low, high)         transform           eigenvalue of h^2 D, mode k = 0..n-1
  ========================  ==================  ===================================
  periodic                  FFT                 -4 sin^2(pi k / n)
  even, even                DCT-II              -4 sin^2(pi k / (2n))
  odd, odd                  DST-II              -4 cos^2(pi k / (2n))
  odd, even                 DST-IV              -4 sin^2(pi (2k + 1) / (4n))
  even, odd                 DCT-IV              -4 sin^2(pi (2k + 1) / (4n))
  ========================  ==================  ===================================

  DCT-II is ``jax.scipy.fft.dct`` (orthonormal); DST-II is the DCT-II of ``(-1)^j f``
  (mode k of it is the sine mode n - 1 - k, hence the cos^2 eigenvalue); the type-IV
  transforms are built on one complex FFT of length 2n with twiddle factors (both are
  their own inverses).  No dense matrices anywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.fft import dct, idct

AXIS_KINDS = ("periodic", "even", "odd")


def _dot(a, b):
    return jnp.sum(a * b)


def cg(matvec, b, precond=None, x0=None, rtol=1e-10, atol=0.0, maxiter=200):
    """Preconditioned conjugate gradients for ``matvec(x) = b``, matvec symmetric positive
    definite and ``precond`` (default: identity) an SPD approximation of its inverse.

    Stops when ``|r| <= max(rtol |b|, atol)`` (Euclidean norms) or after ``maxiter``
    iterations.  Returns ``(x, info)`` with info = dict(iterations, residual (the final
    |r|), relative_residual (|r| / |b|), converged).
    """
    precond = precond if precond is not None else (lambda r: r)
    x = jnp.zeros_like(b) if x0 is None else x0
    r = b - matvec(x) if x0 is not None else b
    z = precond(r)
    p = z
    rz = _dot(r, z)
    bound = jnp.maximum(rtol * jnp.sqrt(_dot(b, b)), atol)

    def cond(c):
        _, r, _, _, k = c
        return (jnp.sqrt(_dot(r, r)) > bound) & (k < maxiter)

    def body(c):
        x, r, p, rz, k = c
        Ap = matvec(p)
        alpha = rz / _dot(p, Ap)
        x = x + alpha * p
        r = r - alpha * Ap
        z = precond(r)
        rz_new = _dot(r, z)
        p = z + (rz_new / rz) * p
        return x, r, p, rz_new, k + 1

    x, r, _, _, k = jax.lax.while_loop(cond, body, (x, r, p, rz, jnp.asarray(0)))
    res = jnp.sqrt(_dot(r, r))
    rel = res / jnp.maximum(jnp.sqrt(_dot(b, b)), 1e-300)
    return x, dict(iterations=k, residual=res, relative_residual=rel, converged=res <= bound)


def _implicit_solve(iterate, matvec, b, x0, symmetric, **kw):
    """``custom_linear_solve`` of ``matvec(x) = b`` by ``iterate`` (:func:`cg` or
    :func:`bicgstab`, keywords ``kw``): the primal solve starts from ``x0`` (under
    ``stop_gradient``; zero if None), the derivative solves from zero."""

    def solve(mv, rhs):
        return iterate(mv, rhs, **kw)[0]

    primal = solve
    if x0 is not None:
        guess = jax.lax.stop_gradient(x0)

        def primal(mv, rhs):
            return iterate(mv, rhs, x0=guess, **kw)[0]

    return jax.lax.custom_linear_solve(matvec, b, solve=primal, transpose_solve=solve,
                                       symmetric=symmetric)


def solve_spd(matvec, b, precond=None, rtol=1e-10, atol=0.0, maxiter=200, x0=None):
    """``x`` with ``matvec(x) = b`` for a symmetric positive definite linear ``matvec``, by
    :func:`cg`, differentiable by implicit differentiation (``custom_linear_solve``,
    symmetric): the derivative of x with respect to b, or to anything ``matvec`` closes
    over, is one more solve with the same operator.  ``precond`` must not depend on
    traced quantities that need derivatives (it only speeds the solve up).

    ``x0``: a first iterate for the primal solve (a guess of x; it changes the answer
    only within the tolerance, and only the number of iterations otherwise).  The
    derivative solves start from zero: their right-hand sides are not b."""
    return _implicit_solve(cg, matvec, b, x0, True, precond=precond, rtol=rtol, atol=atol,
                           maxiter=maxiter)


def bicgstab(matvec, b, precond=None, x0=None, rtol=1e-10, atol=0.0, maxiter=200):
    """Right-preconditioned BiCGSTAB (van der Vorst 1992) for a general nonsingular linear
    ``matvec``; same stopping rule and return value as :func:`cg`.  Two operator and two
    preconditioner applications per iteration."""
    precond = precond if precond is not None else (lambda r: r)
    x = jnp.zeros_like(b) if x0 is None else x0
    r = b - matvec(x) if x0 is not None else b
    r0 = r
    bound = jnp.maximum(rtol * jnp.sqrt(_dot(b, b)), atol)
    one = jnp.asarray(1.0, dtype=b.dtype)
    zero = jnp.zeros_like(b)

    def cond(c):
        _, r, *_, k, broke = c
        return (jnp.sqrt(_dot(r, r)) > bound) & (k < maxiter) & ~broke

    def body(c):
        x, r, p, v, rho, alpha, omega, k, _ = c
        rho_new = _dot(r0, r)
        beta = (rho_new / rho) * (alpha / omega)
        p = r + beta * (p - omega * v)
        ph = precond(p)
        v = matvec(ph)
        alpha = rho_new / _dot(r0, v)
        s = r - alpha * v
        sh = precond(s)
        t = matvec(sh)
        tt = _dot(t, t)
        omega = jnp.where(tt > 0, _dot(t, s) / jnp.where(tt > 0, tt, 1.0), 0.0)
        x = x + alpha * ph + omega * sh
        r = s - omega * t
        # breakdown (rho or omega zero) ends the loop with the current iterate
        broke = (rho_new == 0) | (omega == 0) | ~jnp.isfinite(alpha)
        return x, r, p, v, rho_new, alpha, omega, k + 1, broke

    init = (x, r, zero, zero, one, one, one, jnp.asarray(0), jnp.asarray(False))
    x, r, *_, k, _ = jax.lax.while_loop(cond, body, init)
    res = jnp.sqrt(_dot(r, r))
    return x, dict(iterations=k, residual=res, converged=res <= bound)


def solve_general(matvec, b, precond=None, rtol=1e-10, atol=0.0, maxiter=200, x0=None):
    """``x`` with ``matvec(x) = b`` for a general (nonsymmetric) nonsingular linear
    ``matvec`` by :func:`bicgstab`, differentiable by implicit differentiation
    (``custom_linear_solve``): reverse mode solves the transposed system (JAX transposes
    ``matvec``), again by BiCGSTAB.  ``precond`` should be symmetric (it is used for the
    transposed system as well) and free of traced quantities that need derivatives.
    ``x0``: a first iterate for the primal solve, as in :func:`solve_spd`."""
    return _implicit_solve(bicgstab, matvec, b, x0, False, precond=precond, rtol=rtol, atol=atol,
                           maxiter=maxiter)


# ---------------------------------------------------------------------- fast transforms
def _move(f, axis):
    return jnp.moveaxis(f, axis, -1)


def _type4(f, kind):
    """Orthonormal DCT-IV (``kind="cos"``) or DST-IV (``"sin"``) along the last axis.

    X_k = sqrt(2/n) sum_j f_j cos|sin(pi (2k+1)(2j+1) / (4n)), evaluated as the real or
    minus imaginary part of exp(-i pi (2k+1) / (4n)) FFT_2n(f_j exp(-i pi j / (2n)))_k
    (the exponents add up to pi (2k+1)(2j+1) / (4n)).  Each is its own inverse.
    """
    n = f.shape[-1]
    j = np.arange(n)
    pre = jnp.asarray(np.exp(-1j * np.pi * j / (2 * n)))
    post = jnp.asarray(np.exp(-1j * np.pi * (2 * j + 1) / (4 * n)) * np.sqrt(2.0 / n))
    z = jnp.fft.fft(f * pre, n=2 * n, axis=-1)[..., :n] * post
    return jnp.real(z) if kind == "cos" else -jnp.imag(z)


def _eigenvalues(n, h, kind):
    """Eigenvalues of the 1D second difference (times 1) in the transform's mode order."""
    k = np.arange(n)
    if kind == "periodic":
        s = np.sin(np.pi * k / n) ** 2
    elif kind == ("even", "even"):
        s = np.sin(np.pi * k / (2 * n)) ** 2
    elif kind == ("odd", "odd"):
        s = np.cos(np.pi * k / (2 * n)) ** 2
    else:
        s = np.sin(np.pi * (2 * k + 1) / (4 * n)) ** 2
    return -4.0 * s / (h * h)


def _forward(f, kind):
    """Transform along the last axis (real in, real out except periodic: complex)."""
    if kind == "periodic":
        return jnp.fft.fft(f, axis=-1)
    if kind == ("even", "even"):
        return dct(f, type=2, norm="ortho", axis=-1)
    if kind == ("odd", "odd"):
        sign = jnp.asarray((-1.0) ** np.arange(f.shape[-1]))
        return dct(f * sign, type=2, norm="ortho", axis=-1)
    return _type4(f, "sin" if kind == ("odd", "even") else "cos")


def _inverse(F, kind):
    if kind == "periodic":
        return jnp.fft.ifft(F, axis=-1)
    if kind == ("even", "even"):
        return idct(F, type=2, norm="ortho", axis=-1)
    if kind == ("odd", "odd"):
        sign = jnp.asarray((-1.0) ** np.arange(F.shape[-1]))
        return idct(F, type=2, norm="ortho", axis=-1) * sign
    return _type4(F, "sin" if kind == ("odd", "even") else "cos")


def _check_kind(kind):
    if kind == "periodic":
        return kind
    k = tuple(kind) if isinstance(kind, (tuple, list)) else None
    if k is None or len(k) != 2 or any(s not in ("even", "odd") for s in k):
        raise ValueError(
            f"axis kind must be 'periodic' or a pair of 'even'/'odd' (low, high edge), got {kind!r}"
        )
    return k


@dataclass(frozen=True)
class SeparableSolver:
    """Exact fast solve of ``(a0 - ax Dxx - ay Dyy [- az Dzz]) x = b`` on an ``nx x ny``
    (``x nz``) node grid.

    ``kinds``: per axis ``"periodic"`` or ``(low, high)`` with each ``"even"`` or ``"odd"``
    (see the module docstring); ``dx``, ``dy`` (``dz``) the spacings; ``nz > 0`` makes it
    3D (then give three kinds and one more coefficient to every method).  ``a0``, ``ax``,
    ``ay`` (``az``) may be traced scalars (or arrays broadcasting against the leading axes
    of b, e.g. one value per velocity component); ``a0 - sum_k a_k lam_k`` must not vanish
    (a0 > 0 and a_k >= 0 suffice).
    """

    nx: int
    ny: int
    dx: float
    dy: float
    kinds: tuple
    nz: int = 0
    dz: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "kinds", tuple(_check_kind(k) for k in self.kinds))
        if len(self.kinds) != self.ndim:
            raise ValueError(
                f"SeparableSolver needs one kind per axis ({self.ndim}), got {self.kinds!r}"
            )

    @classmethod
    def on_grid(cls, grid, kinds):
        """The solver for a :class:`refmap.grid.Grid` or :class:`~refmap.grid.Grid3D`'s
        nodes (one kind per axis)."""
        extra = {"nz": grid.nz, "dz": grid.dz} if grid.ndim == 3 else {}
        return cls(grid.nx, grid.ny, grid.dx, grid.dy, kinds, **extra)

    @property
    def ndim(self) -> int:
        return 3 if self.nz else 2

    def eigenvalues(self):
        """Per axis the eigenvalues of its second difference in transform order, shaped to
        broadcast over the grid: (lam_x (nx, 1), lam_y (1, ny)) in 2D, (nx, 1, 1) ... in 3D."""
        sizes = (self.nx, self.ny, self.nz)[: self.ndim]
        steps = (self.dx, self.dy, self.dz)[: self.ndim]
        out = []
        for a, (n, h, kind) in enumerate(zip(sizes, steps, self.kinds, strict=True)):
            shape = [1] * self.ndim
            shape[a] = n
            out.append(jnp.asarray(_eigenvalues(n, h, kind).reshape(shape)))
        return tuple(out)

    def apply(self, x, a0, *coefs):
        """``(a0 - ax Dxx - ay Dyy [- az Dzz]) x`` by the transforms (the operator it inverts)."""
        return self._diag(x, lambda d: d, a0, coefs)

    def solve(self, b, a0, *coefs):
        return self._diag(b, lambda d: 1.0 / d, a0, coefs)

    def solve_semidefinite(self, b, *coefs):
        """The pseudo-inverse of ``-ax Dxx - ay Dyy [- az Dzz]`` (``a0 = 0``) applied to
        ``b``: the operator's null modes (the constant, where every axis is periodic or
        even-even) are set to zero; every coefficient > 0."""

        def inv(d):
            pos = d > 0
            return jnp.where(pos, 1.0 / jnp.where(pos, d, 1.0), 0.0)

        return self._diag(b, inv, 0.0, coefs)

    def _diag(self, b, fn, a0, coefs):
        nd = self.ndim
        if len(coefs) != nd:
            raise ValueError(f"SeparableSolver ({nd}D) needs {nd} axis coefficients, got {len(coefs)}")
        lams = self.eigenvalues()
        grid_axes = (None,) * nd
        d = jnp.asarray(a0)[(..., *grid_axes)]
        for c, lam in zip(coefs, lams, strict=True):
            d = d - jnp.asarray(c)[(..., *grid_axes)] * lam
        d = fn(d)
        # the real transforms first, the periodic (complex) ones last, inverted in reverse
        order = sorted(range(nd), key=lambda a: self.kinds[a] == "periodic")
        B = b
        for a in order:
            B = jnp.moveaxis(_forward(_move(B, a - nd), self.kinds[a]), -1, a - nd)
        B = B * d
        n_periodic = sum(k == "periodic" for k in self.kinds)
        for i, a in enumerate(reversed(order)):
            B = jnp.moveaxis(_inverse(_move(B, a - nd), self.kinds[a]), -1, a - nd)
            if i + 1 == n_periodic:  # every complex transform undone: back to real
                B = jnp.real(B)
        return B


__all__ = ["cg", "bicgstab", "solve_spd", "solve_general", "SeparableSolver", "AXIS_KINDS"]
