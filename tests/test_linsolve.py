"""Matrix-free solvers of refmap.linsolve against dense numpy solves and finite differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import refmap  # noqa: F401  (float64)
from refmap.linsolve import SeparableSolver, bicgstab, cg, solve_general, solve_spd

rng = np.random.default_rng(3)
KINDS = ["periodic", ("even", "even"), ("odd", "odd"), ("odd", "even"), ("even", "odd")]


def second_difference(n, h, kind):
    """Dense 1D second difference whose first ghost is the edge's reflection of node 0."""
    T = np.diag(-2.0 * np.ones(n)) + np.diag(np.ones(n - 1), 1) + np.diag(np.ones(n - 1), -1)
    if kind == "periodic":
        T[0, -1] = T[-1, 0] = 1.0
    else:
        T[0, 0] += -1.0 if kind[0] == "odd" else 1.0
        T[-1, -1] += -1.0 if kind[1] == "odd" else 1.0
    return T / h**2


@pytest.mark.parametrize("kx", KINDS)
@pytest.mark.parametrize("ky", KINDS)
def test_separable_solver_is_exact_for_its_operator(kx, ky):
    """Fast transforms (FFT, DCT-II, DST-II, DCT-IV, DST-IV) against a dense solve: agree to
    round-off (1e-12 on O(1) values), for odd sizes too."""
    nx, ny, dx, dy = 7, 6, 0.3, 0.2
    a0, ax, ay = 2.0, 0.7, 0.4
    S = SeparableSolver(nx, ny, dx, dy, (kx, ky))
    A = (
        a0 * np.eye(nx * ny)
        - ax * np.kron(second_difference(nx, dx, kx), np.eye(ny))
        - ay * np.kron(np.eye(nx), second_difference(ny, dy, ky))
    )
    b = rng.standard_normal((nx, ny))
    x = np.linalg.solve(A, b.ravel()).reshape(nx, ny)
    assert np.abs(np.asarray(S.solve(jnp.asarray(b), a0, ax, ay)) - x).max() < 1e-12
    Ab = (A @ b.ravel()).reshape(nx, ny)
    assert np.abs(np.asarray(S.apply(jnp.asarray(b), a0, ax, ay)) - Ab).max() < 1e-10 * np.abs(Ab).max()


def test_separable_solver_batches_components_and_rejects_bad_kinds():
    S = SeparableSolver(8, 8, 0.1, 0.1, ("periodic", ("odd", "even")))
    b = jnp.asarray(rng.standard_normal((2, 8, 8)))
    x = S.solve(b, jnp.array([1.0, 2.0]), jnp.array([0.1, 0.2]), 0.3)
    for c, (a0, ax) in enumerate(((1.0, 0.1), (2.0, 0.2))):
        assert np.abs(np.asarray(x[c] - S.solve(b[c], a0, ax, 0.3))).max() < 1e-13
    with pytest.raises(ValueError, match="'dirichlet'"):
        SeparableSolver(8, 8, 0.1, 0.1, ("periodic", ("dirichlet", "odd")))


@pytest.mark.parametrize(
    "kinds",
    [
        (("even", "even"), "periodic", ("odd", "even")),
        ("periodic", ("odd", "odd"), ("even", "odd")),
        (("even", "even"), ("even", "even"), ("even", "even")),
    ],
)
def test_separable_solver_3d_is_exact_for_its_operator(kinds):
    """The 3D solver (``nz > 0``, three kinds, three coefficients) against a dense solve of
    ``a0 - ax Dxx - ay Dyy - az Dzz`` built by Kronecker products: round-off agreement, real
    and complex transforms mixed, on a 5 x 4 x 6 grid; the semidefinite solve (a0 = 0) of a
    mean-free right-hand side on the all-Neumann box inverts the operator up to a constant."""
    n, h = (5, 4, 6), (0.3, 0.2, 0.25)
    a0, c = 1.5, (0.7, 0.4, 0.9)
    S = SeparableSolver(n[0], n[1], h[0], h[1], kinds, nz=n[2], dz=h[2])
    eye = [np.eye(k) for k in n]
    D = [second_difference(n[a], h[a], kinds[a]) for a in range(3)]
    terms = [np.kron(np.kron(D[0], eye[1]), eye[2]), np.kron(np.kron(eye[0], D[1]), eye[2]),
             np.kron(np.kron(eye[0], eye[1]), D[2])]
    L = sum(ca * t for ca, t in zip(c, terms, strict=True))
    b = rng.standard_normal(n)
    x = np.linalg.solve(a0 * np.eye(L.shape[0]) - L, b.ravel()).reshape(n)
    assert np.abs(np.asarray(S.solve(jnp.asarray(b), a0, *c)) - x).max() < 1e-12
    Ab = ((a0 * np.eye(L.shape[0]) - L) @ b.ravel()).reshape(n)
    assert np.abs(np.asarray(S.apply(jnp.asarray(b), a0, *c)) - Ab).max() < 1e-10 * np.abs(Ab).max()
    if all(k == ("even", "even") for k in kinds):
        r = b - b.mean()
        y = np.asarray(S.solve_semidefinite(jnp.asarray(r), *c))
        assert np.abs((-L @ y.ravel()).reshape(n) - r).max() < 1e-10
    with pytest.raises(ValueError, match="3 axis coefficients"):
        S.solve(jnp.asarray(b), a0, 1.0, 1.0)
    with pytest.raises(ValueError, match="one kind per axis"):
        SeparableSolver(4, 4, 0.1, 0.1, ("periodic", "periodic"), nz=4, dz=0.1)


def _diffusion(n, seed):
    """A variable-coefficient SPD stencil operator rho x - div(k grad x) (periodic) and its
    dense matrix."""
    r = np.random.default_rng(seed)
    rho = jnp.asarray(r.uniform(1.0, 3.0, (n, n)))
    kx = jnp.asarray(r.uniform(0.5, 2.0, (n, n)))  # on the face between i and i + 1
    ky = jnp.asarray(r.uniform(0.5, 2.0, (n, n)))

    def A(x, rho=rho, kx=kx, ky=ky):
        fx = kx * (jnp.roll(x, -1, 0) - x)
        fy = ky * (jnp.roll(x, -1, 1) - x)
        return rho * x - (fx - jnp.roll(fx, 1, 0)) - (fy - jnp.roll(fy, 1, 1))

    M = np.asarray(jax.jacfwd(lambda z: A(z.reshape(n, n)).ravel())(jnp.zeros(n * n)))
    return A, M, (rho, kx, ky)


def test_cg_residual_and_dense_solve():
    """CG on a variable-coefficient SPD operator: stops at the asked relative residual
    (checked against the operator itself) and matches numpy's dense solve."""
    n = 9
    A, M, _ = _diffusion(n, 0)
    assert np.abs(M - M.T).max() < 1e-13
    b = jnp.asarray(rng.standard_normal((n, n)))
    x, info = cg(A, b, rtol=1e-12, maxiter=500)
    r = float(jnp.linalg.norm(A(x) - b) / jnp.linalg.norm(b))
    assert bool(info["converged"]) and r < 1e-11
    xd = np.linalg.solve(M, np.asarray(b).ravel()).reshape(n, n)
    assert np.abs(np.asarray(x) - xd).max() < 1e-10
    # a preconditioner cuts the iterations (Jacobi here) and keeps the answer
    diag = jnp.asarray(np.diag(M).reshape(n, n))
    x2, info2 = cg(A, b, precond=lambda r: r / diag, rtol=1e-12, maxiter=500)
    assert int(info2["iterations"]) <= int(info["iterations"])
    assert np.abs(np.asarray(x2) - xd).max() < 1e-10


def test_bicgstab_nonsymmetric_dense_solve():
    """BiCGSTAB on the diffusion operator plus an upwind advection (nonsymmetric)."""
    n = 9
    A0, _, _ = _diffusion(n, 1)

    def A(x):
        return A0(x) + 0.8 * (x - jnp.roll(x, 1, 0))

    M = np.asarray(jax.jacfwd(lambda z: A(z.reshape(n, n)).ravel())(jnp.zeros(n * n)))
    assert np.abs(M - M.T).max() > 0.1
    b = jnp.asarray(rng.standard_normal((n, n)))
    x, info = bicgstab(A, b, rtol=1e-12, maxiter=500)
    assert bool(info["converged"])
    assert float(jnp.linalg.norm(A(x) - b) / jnp.linalg.norm(b)) < 1e-11
    xd = np.linalg.solve(M, np.asarray(b).ravel()).reshape(n, n)
    assert np.abs(np.asarray(x) - xd).max() < 1e-10


@pytest.mark.parametrize("solver", ["spd", "general"])
def test_gradient_through_solve_matches_finite_differences(solver):
    """d/dtheta of a scalar of x(theta), where theta scales the operator's coefficients and
    the right-hand side: custom_linear_solve's implicit derivative (one transposed solve)
    against central differences (step 1e-5: truncation ~1e-10, solves converged to 1e-13)."""
    n = 8
    A0, _, (rho, kx, ky) = _diffusion(n, 2)
    b0 = jnp.asarray(rng.standard_normal((n, n)))
    w = jnp.asarray(rng.standard_normal((n, n)))
    solve = solve_spd if solver == "spd" else solve_general

    def f(theta):
        def A(x):
            return A0(x, rho=rho * (1.0 + theta), kx=kx * jnp.exp(theta), ky=ky)

        x = solve(A, b0 * jnp.cos(theta), rtol=1e-14, maxiter=1000)
        return jnp.sum(w * x**2)

    th = 0.3
    g = float(jax.grad(f)(th))
    eps = 1e-5
    fd = (float(f(th + eps)) - float(f(th - eps))) / (2 * eps)
    assert abs(g - fd) < 1e-7 * max(1.0, abs(fd))
    # forward mode agrees too
    assert abs(float(jax.jvp(f, (th,), (1.0,))[1]) - fd) < 1e-7 * max(1.0, abs(fd))


@pytest.mark.parametrize("solver", ["spd", "general"])
def test_first_iterate_saves_iterations_and_keeps_the_answer(solver):
    """A first iterate ``x0`` (the implicit viscosity's warm start): the solve stops at the
    same residual bound ``rtol |b|`` whatever x0, so the answer is the cold one within the
    tolerance; a guess with 1e-3 relative error saves iterations, the exact solution
    needs none, and the derivatives (which start from zero) are the cold ones."""
    n = 9
    A0, _, (rho, kx, ky) = _diffusion(n, 4)
    if solver == "spd":
        A, iterate, solve = A0, cg, solve_spd
    else:

        def A(x):
            return A0(x) + 0.8 * (x - jnp.roll(x, 1, 0))

        iterate, solve = bicgstab, solve_general
    b = jnp.asarray(rng.standard_normal((n, n)))
    exact, _ = iterate(A, b, rtol=1e-14, maxiter=1000)
    rtol = 1e-8
    x_cold, info_cold = iterate(A, b, rtol=rtol, maxiter=1000)
    guess = exact * (1.0 + 1e-3 * jnp.asarray(rng.standard_normal((n, n))))
    x_warm, info_warm = iterate(A, b, x0=guess, rtol=rtol, maxiter=1000)
    assert bool(info_warm["converged"])
    assert int(info_warm["iterations"]) < int(info_cold["iterations"])
    scale = float(jnp.linalg.norm(exact))
    # both within the bound's worth of the exact answer (the operator's inverse is O(1) here)
    assert float(jnp.linalg.norm(x_warm - exact)) < 1e-6 * scale
    assert float(jnp.linalg.norm(x_cold - exact)) < 1e-6 * scale
    assert int(iterate(A, b, x0=exact, rtol=1e-8, maxiter=1000)[1]["iterations"]) == 0
    # the differentiable wrapper: same value, same derivative
    w = jnp.asarray(rng.standard_normal((n, n)))

    def f(theta, x0):
        x = solve(lambda z: A(z) * (1.0 + theta), b * jnp.cos(theta), rtol=1e-13, maxiter=1000, x0=x0)
        return jnp.sum(w * x**2)

    th = 0.2
    assert abs(float(f(th, guess)) - float(f(th, None))) < 1e-9 * abs(float(f(th, None)))
    g_cold, g_warm = float(jax.grad(f)(th, None)), float(jax.grad(f)(th, guess))
    assert abs(g_warm - g_cold) < 1e-9 * abs(g_cold)
    assert abs(float(jax.jvp(lambda t: f(t, guess), (th,), (1.0,))[1]) - g_cold) < 1e-8 * abs(g_cold)
