"""Hyperelastic solid laws in 2D plane strain and in 3D, defined by their strain energy.

A solid is described by its strain energy per unit reference volume ``psi(F)``.  In 2D (the
default, ``dim=2``) ``F`` is the 2x2 in-plane block of a plane-strain deformation gradient
(the out-of-plane stretch ``F33`` is 1 and the out-of-plane shears vanish); a law built with
``dim=3`` takes the full 3x3 ``F``.  The built-in 2D laws are exactly the restriction of
their 3D laws to ``F = diag(F2, 1)``: the 2D stress is the in-plane block of the 3D stress
(tested).  The solver evaluates ``F = (grad xi)^-1`` at every grid corner and needs the
Cauchy stress

    sigma = J^-1 P F^T,    P = d psi / d F,    J = det F.

Two routes give ``sigma``:

* ``stress_autodiff``: ``jax.grad`` of ``psi``, vmapped over all leading axes.  It works for
  any energy a user can write with ``jax.numpy`` and is the reference the closed forms are
  tested against.
* ``stress``: the route the solver calls on ~10^6 corners per step.  Built-in laws override
  it with closed forms written component by component (``F[..., 0, 0]`` ...), which is
  jit-friendly and avoids a per-point gradient.  For a user law it falls back to autodiff.

Layouts.  ``F`` is stacked as ``(..., d, d)`` with ``F[..., i, j] = d x_i / d X_j`` (row =
spatial component, column = reference direction), for ``d = 2`` or ``3``; ``stress``
returns the full symmetric ``(..., d, d)`` Cauchy stress, exactly symmetric.  The stencils
take a symmetric tensor as its ``d(d+1)/2`` independent components, in the row-major upper
triangle order of ``refmap.operators.SYM_COMPONENTS``: ``(xx, xy, yy)`` in 2D and
``(xx, xy, xz, yy, yz, zz)`` in 3D; ``sym_components`` and ``sym_from_components`` convert.
The full matrix is kept as the law's output (as in 2D) because rotations, autodiff and the
closed forms are written on it; the 6-component stack is what the corner arrays store.

Every law is a frozen dataclass registered as a JAX pytree (``register_law``): its numeric parameters (moduli
and the reference density ``rho0``) are pytree *data*, so a whole simulation can be
differentiated with respect to them, vmapped over them, or passed through ``jax.jit`` as an
ordinary argument.  Non-numeric configuration (the dimension ``dim`` and the energy function
of an ``EnergyLaw``) is pytree *metadata* and is static under ``jit``.

Parameters are checked when a law is built from plain Python numbers; values that are JAX
arrays (including the tracers seen inside ``jit``/``grad``/``vmap`` and the cotangents that
``jax.grad`` returns in the shape of a law) are left alone, because a gradient with respect
to a modulus may legitimately be zero or negative.  Call ``validate()`` explicitly to check
concrete array values.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "LAWS",
    "EnergyLaw",
    "HyperelasticLaw",
    "LogNeoHookean",
    "NeoHookean",
    "StVenantKirchhoff",
    "law_from_dict",
    "log_neo_hookean_energy",
    "neo_hookean_energy",
    "register_law",
    "svk_energy",
    "sym_components",
    "sym_from_components",
]

# --------------------------------------------------------------------------------------------
# small helpers


def _is_plain_number(v: Any) -> bool:
    """True for Python (and NumPy scalar) ints/floats, False for arrays, tracers, bools."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(
        v, (bool, np.bool_)
    )


def _is_concrete(v: Any) -> bool:
    """True when ``v`` holds values that can be inspected (not an abstract tracer)."""
    if isinstance(v, jax.core.Tracer):
        return False
    try:
        np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def _fmt(v: Any) -> str:
    if _is_plain_number(v):
        return repr(float(v)) if isinstance(v, (float, np.floating)) else repr(v)
    return repr(np.asarray(v).tolist())


def _fmt_params(params: Any) -> str:
    try:
        return repr(jax.tree_util.tree_map(lambda v: float(v) if np.size(v) == 1 else v, params))
    except (TypeError, ValueError):
        return repr(params)


def _require_positive(cls_name: str, name: str, value: Any, what: str = "") -> None:
    """Raise ValueError naming ``name`` unless every entry of ``value`` is finite and > 0."""
    if not _is_concrete(value):
        return
    arr = np.asarray(value, dtype=float)
    if not (np.all(np.isfinite(arr)) and np.all(arr > 0)):
        extra = f" ({what})" if what else ""
        raise ValueError(
            f"{cls_name}: parameter {name!r} must be positive and finite{extra}, "
            f"got {name}={_fmt(value)}"
        )


def _check_dim(law: Any) -> None:
    """``law.dim`` must be 2 or 3 (3.0 from a dict is accepted and stored as 3)."""
    d = law.dim
    ok = _is_plain_number(d) and float(d) in (2.0, 3.0)
    if not ok:
        raise ValueError(
            f"{type(law).__name__}: parameter 'dim' must be 2 (plane strain) or 3, got dim={d!r}"
        )
    object.__setattr__(law, "dim", int(d))


def _as_float_stack(F: Any, dim: int = 2) -> jax.Array:
    """``F`` as a floating JAX array of shape (..., dim, dim)."""
    F = jnp.asarray(F)
    if not jnp.issubdtype(F.dtype, jnp.floating):
        F = F.astype(jnp.result_type(float))
    if F.ndim < 2 or F.shape[-2:] != (dim, dim):
        hint = "" if dim == 3 else " (a law built with dim=3 takes 3x3 F)"
        raise ValueError(f"F must have shape (..., {dim}, {dim}), got {F.shape}{hint}")
    return F


def _components(F: jax.Array):
    return F[..., 0, 0], F[..., 0, 1], F[..., 1, 0], F[..., 1, 1]


def _entries(F: jax.Array) -> list[list[jax.Array]]:
    """The d x d entries ``F[..., i, j]`` of a stack of square matrices, as nested lists."""
    d = F.shape[-1]
    return [[F[..., i, j] for j in range(d)] for i in range(d)]


def _det3(f: list[list[jax.Array]]) -> jax.Array:
    """Determinant of a 3x3 stack given by its entries (cofactor expansion on row 0)."""
    return (
        f[0][0] * (f[1][1] * f[2][2] - f[1][2] * f[2][1])
        - f[0][1] * (f[1][0] * f[2][2] - f[1][2] * f[2][0])
        + f[0][2] * (f[1][0] * f[2][1] - f[1][1] * f[2][0])
    )


def _det(F: jax.Array) -> jax.Array:
    """det F of a (..., 2, 2) or (..., 3, 3) stack (2D: the formula the 2D laws use)."""
    if F.shape[-1] == 2:
        F00, F01, F10, F11 = _components(F)
        return F00 * F11 - F01 * F10
    return _det3(_entries(F))


def _gram(f: list[list[jax.Array]], rows: bool) -> dict[tuple[int, int], jax.Array]:
    """Upper triangle of ``F F^T`` (rows=True, i.e. B) or ``F^T F`` (rows=False, i.e. C)."""
    d = len(f)
    out = {}
    for a in range(d):
        for b in range(a, d):
            terms = [f[a][k] * f[b][k] if rows else f[k][a] * f[k][b] for k in range(d)]
            acc = terms[0]
            for t in terms[1:]:
                acc = acc + t
            out[a, b] = acc
    return out


def _sym_matrix(upper: dict[tuple[int, int], jax.Array], d: int) -> jax.Array:
    """Assemble an exactly symmetric (..., d, d) stack from its upper triangle."""
    rows = [jnp.stack([upper[min(a, b), max(a, b)] for b in range(d)], axis=-1) for a in range(d)]
    return jnp.stack(rows, axis=-2)


def sym_components(sigma: jax.Array) -> tuple[jax.Array, ...]:
    """The independent components of a symmetric (..., d, d) stack, in the stencils' order.

    2D: ``(xx, xy, yy)``; 3D: ``(xx, xy, xz, yy, yz, zz)`` (``refmap.operators.SYM_COMPONENTS``),
    ready for ``refmap.operators.div_node(*sym_components(sigma), *spacings)``.
    """
    d = sigma.shape[-1]
    return tuple(sigma[..., a, b] for a in range(d) for b in range(a, d))


def sym_from_components(components, dim: int) -> jax.Array:
    """Inverse of ``sym_components``: the (..., dim, dim) symmetric stack."""
    pairs = [(a, b) for a in range(dim) for b in range(a, dim)]
    if len(components) != len(pairs):
        raise ValueError(
            f"a symmetric {dim}x{dim} tensor has {len(pairs)} components, got {len(components)}"
        )
    return _sym_matrix(dict(zip(pairs, components, strict=True)), dim)


def _scaled_plus_pressure(g: jax.Array, D: jax.Array, p: jax.Array) -> jax.Array:
    """``g D + p I`` for node scalars ``g``, ``p`` (...) and a stack ``D`` (..., d, d).

    Written as a product with the broadcast scalars rather than as a stack of the entries
    ``g D_ij + p delta_ij``: XLA fuses a stack's arithmetic into one loop over its ``d x d``
    entries, so each entry would recompute the node's scalars (the cube root of J costs
    about 20 ns on a CPU core, ``d^2`` times per node); it does not fuse an expensive
    scalar into a broadcast, so here they are computed once per node.  The entries are the
    same numbers (off the diagonal ``g D_ij + 0 p``)."""
    d = D.shape[-1]
    return g[..., None, None] * D + p[..., None, None] * jnp.eye(d, dtype=D.dtype)


def _sym2(s00: jax.Array, s01: jax.Array, s11: jax.Array) -> jax.Array:
    """Assemble a symmetric (..., 2, 2) tensor from its three independent components."""
    row0 = jnp.stack([s00, s01], axis=-1)
    row1 = jnp.stack([s01, s11], axis=-1)
    return jnp.stack([row0, row1], axis=-2)


def register_law(cls: type) -> type:
    """Class decorator: make ``cls`` a frozen dataclass and register it as a JAX pytree.

    Fields are pytree data (differentiable leaves) unless declared with
    ``field(metadata={"static": True})``, which makes them static metadata -- the same
    convention as ``jax.tree_util.register_dataclass``.  Use it for your own
    ``HyperelasticLaw`` subclasses that provide a closed-form ``stress``::

        @register_law
        class MyLaw(HyperelasticLaw):
            name: ClassVar[str] = "my_law"
            G: float
            rho0: float = 1.0

            def psi(self, F): ...
            def stress(self, F): ...   # optional: closed form

    Why not ``register_dataclass`` itself: in the installed jaxlib, treedefs of two
    *different* classes registered that way compare equal whenever they have the same number
    of data fields and equal static metadata (their hashes differ, their ``==`` does not).
    ``jax.jit``'s cache can then, on a hash-bucket collision, reuse the compiled function of
    ``NeoHookean`` for a ``LogNeoHookean`` argument -- silently wrong stresses.  A custom
    node's treedef includes its type, which rules this out.

    Unflattening bypasses ``__init__`` (and so ``__post_init__`` validation): pytrees of
    gradients, zeros or placeholders shaped like a law are legitimate and must not be checked
    as material parameters.
    """
    cls = dataclass(frozen=True)(cls)
    all_fields = dataclasses.fields(cls)
    data = tuple(f.name for f in all_fields if not f.metadata.get("static", False))
    meta = tuple(f.name for f in all_fields if f.metadata.get("static", False))
    keys = tuple(jax.tree_util.GetAttrKey(n) for n in data)

    def flatten_with_keys(x):
        children = tuple((k, getattr(x, n)) for k, n in zip(keys, data, strict=True))
        return children, tuple(getattr(x, n) for n in meta)

    def flatten(x):
        return tuple(getattr(x, n) for n in data), tuple(getattr(x, n) for n in meta)

    def unflatten(aux, children):
        obj = object.__new__(cls)
        for n, v in zip(meta, aux, strict=True):
            object.__setattr__(obj, n, v)
        for n, v in zip(data, children, strict=True):
            object.__setattr__(obj, n, v)
        return obj

    jax.tree_util.register_pytree_with_keys(cls, flatten_with_keys, unflatten, flatten)
    return cls


# --------------------------------------------------------------------------------------------
# the base class


@dataclass(frozen=True)
class HyperelasticLaw(abc.ABC):
    """Abstract hyperelastic solid, defined by an energy ``psi(F)``.

    Concrete laws are frozen dataclasses registered as pytrees (see ``register_law``) with a
    ``rho0`` field (reference density) and their moduli as data fields.  Subclasses must
    implement ``psi``; they may override ``stress`` with a closed form and ``validate`` with
    checks that name their own parameters.

    ``dim`` (keyword only, static): 2 (default) for plane strain on 2x2 ``F``, 3 for the full
    3x3 ``F``; ``stress`` refuses the other size.  ``law.with_dim(3)`` is the same material
    in 3D.
    """

    #: key of the law in ``LAWS`` / in ``to_dict()`` output (None: not serialisable).
    name: ClassVar[str | None] = None

    dim: int = field(default=2, kw_only=True, metadata={"static": True})

    # ---- construction-time checks ------------------------------------------------------------

    def __post_init__(self) -> None:
        _check_dim(self)
        # Python ints become floats so every leaf is differentiable.
        for f in dataclasses.fields(self):
            if f.metadata.get("static", False):
                continue
            v = getattr(self, f.name)
            if isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)):
                object.__setattr__(self, f.name, float(v))
        if self._params_are_plain():
            self.validate()

    def with_dim(self, dim: int) -> HyperelasticLaw:
        """The same law (same parameters) for ``dim``-dimensional ``F``."""
        return dataclasses.replace(self, dim=dim)

    def _data_leaves(self) -> list[Any]:
        return jax.tree_util.tree_leaves(self)

    def _params_are_plain(self) -> bool:
        leaves = self._data_leaves()
        return bool(leaves) and all(_is_plain_number(v) for v in leaves)

    def validate(self) -> None:
        """Raise ValueError if the density or a small-strain modulus is not positive.

        The generic check computes ``moduli()``; built-in laws check their parameters
        directly.  Tracer values cannot be inspected and are skipped.
        """
        cls = type(self).__name__
        _require_positive(cls, "rho0", self.rho0, "reference density")
        if not all(_is_concrete(v) for v in self._data_leaves()):
            return
        mu, M = self.moduli()
        _require_positive(cls, "mu", mu, "small-strain shear modulus d sigma_12 / d gamma")
        _require_positive(cls, "M", M, "small-strain longitudinal modulus d sigma_11 / d eps")

    # ---- energy and stress -------------------------------------------------------------------

    @abc.abstractmethod
    def psi(self, F: jax.Array) -> jax.Array:
        """Strain energy per unit reference volume for one ``dim x dim`` deformation gradient."""

    def stress(self, F: jax.Array) -> jax.Array:
        """Cauchy stress (..., d, d) for F of shape (..., d, d), ``d = self.dim``.

        The default is the autodiff route; built-in laws override it with a closed form.
        """
        return self.stress_autodiff(F)

    def stress_autodiff(self, F: jax.Array) -> jax.Array:
        """Cauchy stress from ``jax.grad`` of ``psi``: sigma = J^-1 (d psi/d F) F^T.

        Always the autodiff route, whatever ``stress`` does; useful to check a closed form.
        """
        d = self.dim
        F = _as_float_stack(F, d)
        batch = F.shape[:-2]
        Ff = F.reshape((-1, d, d))
        P = jax.vmap(jax.grad(self.psi))(Ff)
        J = _det(Ff)
        sigma = jnp.einsum("nik,njk->nij", P, Ff) / J[:, None, None]
        return sigma.reshape(batch + (d, d))

    # ---- small-strain properties -------------------------------------------------------------

    def moduli(self) -> tuple[jax.Array, jax.Array]:
        """Small-strain moduli ``(mu, M)`` obtained by differentiating ``stress`` at F = I.

        mu = d sigma_12 / d gamma for F = I + gamma e1 (x) e2 (simple shear), and
        M = d sigma_11 / d eps for F = I + eps e1 (x) e1 (uniaxial strain): the shear and
        longitudinal (P-wave) moduli that set the linear wave speeds.
        """
        eye = jnp.eye(self.dim)
        shear = jnp.zeros((self.dim, self.dim)).at[0, 1].set(1.0)
        stretch = jnp.zeros((self.dim, self.dim)).at[0, 0].set(1.0)
        zero = jnp.zeros((), dtype=eye.dtype)
        mu = jax.jacfwd(lambda g: self.stress(eye + g * shear)[0, 1])(zero)
        M = jax.jacfwd(lambda e: self.stress(eye + e * stretch)[0, 0])(zero)
        return mu, M

    def wave_speeds(self) -> tuple[jax.Array, jax.Array]:
        """Linear wave speeds ``(c_T, c_L) = (sqrt(mu / rho0), sqrt(M / rho0))``."""
        mu, M = self.moduli()
        return jnp.sqrt(mu / self.rho0), jnp.sqrt(M / self.rho0)

    # ---- serialisation -----------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """``{"law": name, <parameter>: float, ...}``; inverse of ``law_from_dict``."""
        if self.name is None:
            raise ValueError(f"{type(self).__name__} has no registry name and cannot be serialised")
        out: dict[str, Any] = {"law": self.name}
        for f in dataclasses.fields(self):
            if f.name == "dim":  # written only for 3D, so 2D dicts are unchanged
                if self.dim != 2:
                    out["dim"] = self.dim
                continue
            v = getattr(self, f.name)
            arr = np.asarray(v, dtype=float)
            out[f.name] = float(arr) if arr.ndim == 0 else arr.tolist()
        return out


# --------------------------------------------------------------------------------------------
# user law from an energy function


@register_law
class EnergyLaw(HyperelasticLaw):
    """A law given only by its energy ``psi_fn(F, params)``; stress comes from autodiff.

    ``psi_fn`` takes one ``dim x dim`` ``F`` (2x2 unless built with ``dim=3``) and the
    ``params`` dict and returns a scalar written with ``jax.numpy``.  The function is static pytree metadata (changing it retraces a jitted
    caller); ``params`` (any pytree of numbers, typically a dict of floats) and ``rho0`` are
    data, so they can be differentiated.  Example::

        law = EnergyLaw(neo_hookean_energy, {"G": 1.0, "kappa": 5.0}, rho0=1.2)

    Building it from plain numbers checks ``rho0 > 0`` and that the small-strain moduli
    (computed by differentiating the stress at F = I) are positive.  It cannot be
    serialised with ``to_dict``: a Python function has no portable representation.
    """

    psi_fn: Callable[[jax.Array, Any], jax.Array] = field(metadata={"static": True})
    params: Mapping[str, Any] = field(default_factory=dict)
    rho0: float = 1.0

    def __post_init__(self) -> None:
        _check_dim(self)
        if not callable(self.psi_fn):
            raise TypeError(f"EnergyLaw: psi_fn must be callable, got {self.psi_fn!r}")
        if isinstance(self.rho0, (int, np.integer)) and not isinstance(self.rho0, bool):
            object.__setattr__(self, "rho0", float(self.rho0))
        if isinstance(self.params, dict):
            fixed = {
                k: float(v)
                if isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))
                else v
                for k, v in self.params.items()
            }
            object.__setattr__(self, "params", fixed)
        if self._params_are_plain():
            self.validate()

    def validate(self) -> None:
        """Check ``rho0 > 0`` and that the autodiff small-strain moduli are positive."""
        _require_positive("EnergyLaw", "rho0", self.rho0, "reference density")
        if not all(_is_concrete(v) for v in self._data_leaves()):
            return
        mu, M = self.moduli()
        for label, value in (("shear modulus mu", mu), ("longitudinal modulus M", M)):
            arr = np.asarray(value, dtype=float)
            if not (np.all(np.isfinite(arr)) and np.all(arr > 0)):
                raise ValueError(
                    f"EnergyLaw: the small-strain {label} computed from psi_fn must be positive "
                    f"and finite, got {_fmt(arr)} with params={_fmt_params(self.params)}"
                )

    def psi(self, F: jax.Array) -> jax.Array:
        return self.psi_fn(F, self.params)

    def to_dict(self) -> dict[str, Any]:
        raise ValueError(
            "EnergyLaw wraps an arbitrary Python function (psi_fn) and cannot be serialised "
            "to a dict; use a built-in law (see refmap.materials.LAWS) for configs that must "
            "be saved, or rebuild the EnergyLaw in code."
        )


# --------------------------------------------------------------------------------------------
# energies of the built-in laws (usable directly with EnergyLaw)


def neo_hookean_energy(F: jax.Array, params: Mapping[str, Any]) -> jax.Array:
    """Valkov's compressible neo-Hookean energy, plane strain (params: ``G``, ``kappa``).

    psi = G/2 (J^(-2/3) tr3(B) - 3) + kappa/2 (J - 1)^2, with tr3 B = tr(F F^T) + 1
    (the out-of-plane stretch is 1).  Works elementwise on (..., 2, 2); on (..., 3, 3) it is
    the 3D energy with tr3 B = tr(F F^T), of which the 2D one is the restriction.
    """
    G, kappa = params["G"], params["kappa"]
    if F.shape[-1] == 3:
        J = _det(F)
        I1 = jnp.sum(F * F, axis=(-2, -1))
        return 0.5 * G * (I1 / jnp.cbrt(J) ** 2 - 3.0) + 0.5 * kappa * (J - 1.0) ** 2
    F00, F01, F10, F11 = _components(F)
    J = F00 * F11 - F01 * F10
    I1 = F00 * F00 + F01 * F01 + F10 * F10 + F11 * F11 + 1.0
    return 0.5 * G * (I1 / jnp.cbrt(J) ** 2 - 3.0) + 0.5 * kappa * (J - 1.0) ** 2


def log_neo_hookean_energy(F: jax.Array, params: Mapping[str, Any]) -> jax.Array:
    """2D neo-Hookean energy with a logarithmic volume term (params: ``G``, ``kappa``).

    psi = G/2 (tr C - 2 - 2 ln J) + kappa/2 (J - 1)^2.  Works elementwise on (..., 2, 2); on
    (..., 3, 3) it is the 3D energy G/2 (tr C - 3 - 2 ln J) + kappa/2 (J - 1)^2, whose
    restriction to F = diag(F2, 1) is the 2D one (tr C gains the 1 of C33).
    """
    G, kappa = params["G"], params["kappa"]
    if F.shape[-1] == 3:
        J = _det(F)
        trC = jnp.sum(F * F, axis=(-2, -1))
        return 0.5 * G * (trC - 3.0 - 2.0 * jnp.log(J)) + 0.5 * kappa * (J - 1.0) ** 2
    F00, F01, F10, F11 = _components(F)
    J = F00 * F11 - F01 * F10
    trC = F00 * F00 + F01 * F01 + F10 * F10 + F11 * F11
    return 0.5 * G * (trC - 2.0 - 2.0 * jnp.log(J)) + 0.5 * kappa * (J - 1.0) ** 2


def svk_energy(F: jax.Array, params: Mapping[str, Any]) -> jax.Array:
    """Saint Venant-Kirchhoff energy, plane strain (params: ``mu``, ``lam``).

    psi = lam/2 (tr E)^2 + mu tr(E^2), E = (F^T F - I)/2.  Works elementwise on (..., 2, 2)
    (plane strain: E33 = 0) and on (..., 3, 3).
    """
    mu, lam = params["mu"], params["lam"]
    if F.shape[-1] == 3:
        C = _gram(_entries(F), rows=False)
        E = {k: 0.5 * (v - 1.0) if k[0] == k[1] else 0.5 * v for k, v in C.items()}
        trE = E[0, 0] + E[1, 1] + E[2, 2]
        trE2 = sum(v * v if k[0] == k[1] else 2.0 * v * v for k, v in E.items())
        return 0.5 * lam * trE**2 + mu * trE2
    F00, F01, F10, F11 = _components(F)
    E00 = 0.5 * (F00 * F00 + F10 * F10 - 1.0)
    E01 = 0.5 * (F00 * F01 + F10 * F11)
    E11 = 0.5 * (F01 * F01 + F11 * F11 - 1.0)
    trE = E00 + E11
    return 0.5 * lam * trE**2 + mu * (E00 * E00 + 2.0 * E01 * E01 + E11 * E11)


# --------------------------------------------------------------------------------------------
# built-in laws


@register_law
class NeoHookean(HyperelasticLaw):
    """Valkov's compressible neo-Hookean solid under plane strain.

    Energy ``psi = G/2 (J^(-2/3) tr3(B) - 3) + kappa/2 (J - 1)^2`` with ``B = F F^T`` (2x2)
    and ``tr3 B = tr B + 1``: the isochoric part uses the full 3D first invariant with the
    out-of-plane stretch equal to one.  Differentiating (d tr3B/dF = 2F, dJ/dF = J F^-T) and
    pushing forward gives

        sigma = G J^(-5/3) (B - tr3(B)/3 I) + kappa (J - 1) I.

    Small-strain moduli: ``mu = G``, ``M = kappa + 4G/3`` (3D bulk modulus ``kappa``).
    Under finite simple shear this law produces a normal stress ``sigma_22 = -G gamma^2/3``,
    so a large-amplitude shear wave couples to longitudinal motion.
    """

    name: ClassVar[str] = "neo_hookean"

    G: float
    kappa: float
    rho0: float = 1.0

    def validate(self) -> None:
        _require_positive("NeoHookean", "G", self.G, "shear modulus")
        _require_positive("NeoHookean", "kappa", self.kappa, "bulk modulus")
        _require_positive("NeoHookean", "rho0", self.rho0, "reference density")

    def psi(self, F: jax.Array) -> jax.Array:
        return neo_hookean_energy(F, {"G": self.G, "kappa": self.kappa})

    def stress(self, F: jax.Array) -> jax.Array:
        F = _as_float_stack(F, self.dim)
        if self.dim == 3:  # sigma = G J^(-5/3) (B - tr(B)/3 I) + kappa (J - 1) I
            f = _entries(F)
            J = _det3(f)
            B = _gram(f, rows=True)
            third_tr = (B[0, 0] + B[1, 1] + B[2, 2]) / 3.0
            c = jnp.cbrt(J)
            g = self.G / (J * c * c)
            p = self.kappa * (J - 1.0)
            dev = {k: v - third_tr if k[0] == k[1] else v for k, v in B.items()}
            return _scaled_plus_pressure(g, _sym_matrix(dev, 3), p)
        F00, F01, F10, F11 = _components(F)
        J = F00 * F11 - F01 * F10
        B00 = F00 * F00 + F01 * F01
        B01 = F00 * F10 + F01 * F11
        B11 = F10 * F10 + F11 * F11
        third_tr3 = (B00 + B11 + 1.0) / 3.0
        c = jnp.cbrt(J)
        g = self.G / (J * c * c)  # G J^(-5/3)
        p = self.kappa * (J - 1.0)
        return _scaled_plus_pressure(g, _sym2(B00 - third_tr3, B01, B11 - third_tr3), p)


@register_law
class LogNeoHookean(HyperelasticLaw):
    """Two-dimensional neo-Hookean solid with a logarithmic volumetric correction.

    Energy ``psi = G/2 (tr C - 2 - 2 ln J) + kappa/2 (J - 1)^2`` with ``C = F^T F`` (2x2).
    Derivation of the stress: d(tr C)/dF = 2F and d(ln J)/dF = F^-T, so the first
    Piola-Kirchhoff stress is ``P = G (F - F^-T) + kappa (J - 1) J F^-T``; then
    ``sigma = J^-1 P F^T`` with ``F F^T = B`` and ``F^-T F^T = I`` gives

        sigma = (G / J) (B - I) + kappa (J - 1) I.

    The ``-2 ln J`` term makes the stress vanish at F = I.  Linearising at F = I
    (B - I ~ 2 eps, J - 1 ~ tr eps) gives ``mu = G`` and ``M = 2G + kappa``.

    Why this law: for a plane shear wave ``u1 = u(x2, t)``, F = I + gamma e1 (x) e2 with
    ``gamma = du/dx2`` and J = 1, so ``sigma_12 = G gamma`` exactly (linear at any
    amplitude), ``sigma_22 = 0`` and ``sigma_11 = G gamma^2`` depends only on x2.  The
    momentum balance reduces to ``rho0 u_tt = G u_x2x2`` with no longitudinal forcing, so a
    finite-amplitude shear wave travelling at ``c_T = sqrt(G / rho0)`` is an exact
    solution: a clean benchmark for the nonlinear solver.
    """

    name: ClassVar[str] = "log_neo_hookean"

    G: float
    kappa: float
    rho0: float = 1.0

    def validate(self) -> None:
        _require_positive("LogNeoHookean", "G", self.G, "shear modulus")
        _require_positive("LogNeoHookean", "kappa", self.kappa, "bulk modulus")
        _require_positive("LogNeoHookean", "rho0", self.rho0, "reference density")

    def psi(self, F: jax.Array) -> jax.Array:
        return log_neo_hookean_energy(F, {"G": self.G, "kappa": self.kappa})

    def stress(self, F: jax.Array) -> jax.Array:
        F = _as_float_stack(F, self.dim)
        if self.dim == 3:  # sigma = (G / J) (B - I) + kappa (J - 1) I
            f = _entries(F)
            J = _det3(f)
            B = _gram(f, rows=True)
            g = self.G / J
            p = self.kappa * (J - 1.0)
            return _sym_matrix(
                {k: g * (v - 1.0) + p if k[0] == k[1] else g * v for k, v in B.items()}, 3
            )
        F00, F01, F10, F11 = _components(F)
        J = F00 * F11 - F01 * F10
        g = self.G / J
        p = self.kappa * (J - 1.0)
        return _sym2(
            g * (F00 * F00 + F01 * F01 - 1.0) + p,
            g * (F00 * F10 + F01 * F11),
            g * (F10 * F10 + F11 * F11 - 1.0) + p,
        )


@register_law
class StVenantKirchhoff(HyperelasticLaw):
    """Saint Venant-Kirchhoff solid under plane strain, with 3D Lame constants.

    Energy ``psi = lam/2 (tr E)^2 + mu tr(E^2)`` with the Green-Lagrange strain
    ``E = (C - I)/2``.  Plane strain means E33 = 0, so the 2D traces are the 3D ones.  The
    second Piola-Kirchhoff stress ``S = lam tr(E) I + 2 mu E`` is pushed forward as
    ``sigma = J^-1 F S F^T``.  Small-strain moduli: ``mu``, ``M = lam + 2 mu``.

    ``lam`` may be negative (auxetic materials) as long as the 3D bulk modulus
    ``lam + 2 mu / 3`` is positive.  The law is only sensible for moderate strains: it
    softens and loses stability under strong compression.
    """

    name: ClassVar[str] = "svk"

    mu: float
    lam: float
    rho0: float = 1.0

    @classmethod
    def from_E_nu(
        cls, E: float, nu: float, rho0: float = 1.0, *, dim: int = 2
    ) -> StVenantKirchhoff:
        """From Young's modulus and Poisson's ratio (3D relations, -1 < nu < 1/2)."""
        if _is_concrete(E) and not np.all(np.asarray(E, dtype=float) > 0):
            raise ValueError(f"StVenantKirchhoff: parameter 'E' must be positive, got E={_fmt(E)}")
        if _is_concrete(nu):
            a = np.asarray(nu, dtype=float)
            if not np.all((a > -1.0) & (a < 0.5)):
                raise ValueError(
                    f"StVenantKirchhoff: parameter 'nu' must lie in (-1, 0.5), got nu={_fmt(nu)}"
                )
        mu = E / (2.0 * (1.0 + nu))
        lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
        return cls(mu, lam, rho0, dim=dim)

    @classmethod
    def from_G_kappa(
        cls, G: float, kappa: float, rho0: float = 1.0, *, dim: int = 2
    ) -> StVenantKirchhoff:
        """From shear and 3D bulk moduli: ``mu = G``, ``lam = kappa - 2G/3``."""
        _require_positive("StVenantKirchhoff", "G", G, "shear modulus")
        _require_positive("StVenantKirchhoff", "kappa", kappa, "bulk modulus")
        return cls(G, kappa - 2.0 * G / 3.0, rho0, dim=dim)

    def validate(self) -> None:
        _require_positive("StVenantKirchhoff", "mu", self.mu, "shear modulus")
        _require_positive("StVenantKirchhoff", "rho0", self.rho0, "reference density")
        if _is_concrete(self.lam) and _is_concrete(self.mu):
            kappa = np.asarray(self.lam, dtype=float) + 2.0 * np.asarray(self.mu, dtype=float) / 3
            if not (np.all(np.isfinite(kappa)) and np.all(kappa > 0)):
                raise ValueError(
                    f"StVenantKirchhoff: parameter 'lam' is too small, got lam={_fmt(self.lam)}: "
                    f"the bulk modulus lam + 2 mu/3 = {_fmt(kappa)} must be positive"
                )

    def psi(self, F: jax.Array) -> jax.Array:
        return svk_energy(F, {"mu": self.mu, "lam": self.lam})

    def stress(self, F: jax.Array) -> jax.Array:
        F = _as_float_stack(F, self.dim)
        if self.dim == 3:  # sigma = J^-1 F S F^T, S = lam tr(E) I + 2 mu E
            f = _entries(F)
            J = _det3(f)
            C = _gram(f, rows=False)
            E = {k: 0.5 * (v - 1.0) if k[0] == k[1] else 0.5 * v for k, v in C.items()}
            ltr = self.lam * (E[0, 0] + E[1, 1] + E[2, 2])
            S = {
                k: ltr + 2.0 * self.mu * v if k[0] == k[1] else 2.0 * self.mu * v
                for k, v in E.items()
            }

            def s(a, b):
                return S[min(a, b), max(a, b)]

            A = [[sum(f[i][k] * s(k, j) for k in range(3)) for j in range(3)] for i in range(3)]
            inv_J = 1.0 / J
            sigma = {
                (a, b): sum(A[a][k] * f[b][k] for k in range(3)) * inv_J
                for a in range(3)
                for b in range(a, 3)
            }
            return _sym_matrix(sigma, 3)
        F00, F01, F10, F11 = _components(F)
        J = F00 * F11 - F01 * F10
        E00 = 0.5 * (F00 * F00 + F10 * F10 - 1.0)
        E01 = 0.5 * (F00 * F01 + F10 * F11)
        E11 = 0.5 * (F01 * F01 + F11 * F11 - 1.0)
        ltr = self.lam * (E00 + E11)
        S00 = ltr + 2.0 * self.mu * E00
        S01 = 2.0 * self.mu * E01
        S11 = ltr + 2.0 * self.mu * E11
        # A = F S, then sigma = A F^T / J
        A00 = F00 * S00 + F01 * S01
        A01 = F00 * S01 + F01 * S11
        A10 = F10 * S00 + F11 * S01
        A11 = F10 * S01 + F11 * S11
        inv_J = 1.0 / J
        return _sym2(
            (A00 * F00 + A01 * F01) * inv_J,
            (A00 * F10 + A01 * F11) * inv_J,
            (A10 * F10 + A11 * F11) * inv_J,
        )


# --------------------------------------------------------------------------------------------
# registry and (de)serialisation

LAWS: dict[str, type[HyperelasticLaw]] = {
    "neo_hookean": NeoHookean,
    "log_neo_hookean": LogNeoHookean,
    "svk": StVenantKirchhoff,
}


def map_laws(fn, laws, *per_solid):
    """``fn(law, *(a[k] for a in per_solid))`` for every solid k, stacked along a new first
    axis: the laws of one class stacked into one pytree and ``fn`` taken with one ``vmap``
    over them (one traced code path whatever the number of solids), one by one when the
    classes differ or the laws do not stack."""
    if len({type(law) for law in laws}) == 1 and len(laws) > 1:
        try:
            stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *laws)
        except (ValueError, TypeError):
            stacked = None
        if stacked is not None:
            return jax.vmap(fn)(stacked, *per_solid)
    return jnp.stack([fn(law, *(a[k] for a in per_solid)) for k, law in enumerate(laws)])


def law_groups(laws) -> list[tuple[list[int], Any]]:
    """The laws grouped by class and pytree structure, in the order of each group's first
    law: ``(members, stacked)`` with ``members`` the indices of the group's laws and
    ``stacked`` their pytree with every leaf stacked along a new first axis (one ``vmap``
    over a group is one traced code path whatever the number of solids)."""
    groups: dict[Any, list[int]] = {}
    for k, law in enumerate(laws):
        groups.setdefault((type(law), jax.tree_util.tree_structure(law)), []).append(k)
    return [(members, jax.tree_util.tree_map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]),
                                             *(laws[k] for k in members)))
            for members in groups.values()]


def law_moduli(laws) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(mu, M, rho0)``, each ``(N,)``: the small-strain moduli (:meth:`HyperelasticLaw.moduli`)
    and reference densities of the laws ``laws``, in their order.  The laws of one class and
    one pytree structure are stacked (:func:`law_groups`) and their moduli taken with one
    ``vmap``, so that the traced code does not grow with the number of solids (a thousand
    discs of two densities are one such group, not a thousand differentiations of the
    stress)."""
    if not laws:
        empty = jnp.zeros((0,))
        return empty, empty, empty
    parts, order = [], []
    for members, stacked in law_groups(laws):
        mu, M = jax.vmap(lambda law: law.moduli())(stacked)
        parts.append(jnp.stack([mu, M, jnp.asarray(stacked.rho0, dtype=M.dtype)]))
        order += members
    out = jnp.concatenate(parts, axis=1)
    if order != sorted(order):
        out = out[:, np.argsort(order)]
    return out[0], out[1], out[2]


def law_from_dict(d: Mapping[str, Any]) -> HyperelasticLaw:
    """Build a law from ``{"law": <key of LAWS>, <parameter>: value, ...}``.

    The parameters are the constructor's fields (e.g. ``G``, ``kappa``, ``rho0`` for
    ``neo_hookean``).  For ``svk`` the pairs ``E, nu`` or ``G, kappa`` are accepted in place
    of ``mu, lam``.  Inverse of ``HyperelasticLaw.to_dict``.
    """
    if not isinstance(d, Mapping) or "law" not in d:
        raise ValueError(f"a material dict needs a 'law' key (one of {sorted(LAWS)}), got {d!r}")
    key = d["law"]
    if key not in LAWS:
        raise ValueError(f"unknown material law {key!r}; known laws: {sorted(LAWS)}")
    cls = LAWS[key]
    kwargs = {k: v for k, v in d.items() if k != "law"}
    if cls is StVenantKirchhoff:
        rest = {k: v for k, v in kwargs.items() if k not in ("rho0", "dim")}
        extra = {k: kwargs[k] for k in ("rho0", "dim") if k in kwargs}
        if set(rest) == {"E", "nu"}:
            return StVenantKirchhoff.from_E_nu(rest["E"], rest["nu"], **extra)
        if set(rest) == {"G", "kappa"}:
            return StVenantKirchhoff.from_G_kappa(rest["G"], rest["kappa"], **extra)
    names = [f.name for f in dataclasses.fields(cls)]
    required = [
        f.name
        for f in dataclasses.fields(cls)
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    unknown = sorted(set(kwargs) - set(names))
    missing = [n for n in required if n not in kwargs]
    if unknown or missing:
        raise ValueError(
            f"bad parameters for law {key!r}: unknown {unknown}, missing {missing}; "
            f"expected {names}"
        )
    return cls(**{k: float(v) if _is_plain_number(v) else v for k, v in kwargs.items()})
