"""Blend weights: how much of a node or corner belongs to a solid's blurred interface.

A solid k contributes to the mixed stress and density with its fraction ``1 - H(phi_k)``;
``H`` rises from 0 deep inside the solid (phi < 0) to 1 in the fluid.  Two kernels:

* ``"erf"`` (the thesis's): ``H = (1 + erf(phi / w)) / 2`` with ``w = width * h``
  (``width = 2`` in the thesis).  Not compactly supported: its tails reach every node, but
  fall below 1e-12 beyond ``|phi| > 5.1 w``.
* ``"sine"`` (the sine-smoothed Heaviside of the later RMT codes):
  ``H = 1/2 + phi / (2 eps) + sin(pi phi / eps) / (2 pi)`` for ``|phi| < eps``, 0 below and
  1 above, with ``eps = width * h``.  Compactly supported, continuous with a continuous
  first derivative (zero at both ends).

**Bending error of a blended plate.**  With ``s(x) = H(x) - step(x)`` (an odd function for a
symmetric kernel), a plate of thickness ``t`` blended at both faces has the second moment
``t^3 / 12 + 2 t |m1|`` to leading order, where ``m1 = integral s(x) x dx`` is the kernel's
first moment (the zeroth moment vanishes, and the odd symmetry kills the second).  The
bending stiffness is therefore too large by the factor ``1 + C (h / t)^2`` with
``C = 24 |m1| / h^2``:

* erf, ``w = width h``:  ``|m1| = w^2 / 4``, so ``C = 6 width^2`` (24 at the thesis's 2);
* sine, ``eps = width h``:  ``|m1| = 2 eps^2 (1/12 - 1/(2 pi^2)) = 0.0653 eps^2``, so
  ``C = 1.568 width^2`` (9.80 at 2.5, 3.53 at 1.5, 1.57 at 1).

:func:`first_moment` and :func:`bending_factor` return these; the tests check them against
quadrature of the kernels and against the second moment of a sampled blended plate.

**Thin-body correction** (opt-in, ``Solid.thin_thickness``).  Blending at ``phi + delta``
instead of ``phi`` moves both blurred faces of the plate inward by ``delta``: the plate is
then the blend of a sharp plate ``tau = t - 2 delta`` thick, with the second moment
``tau^3 / 12 + 2 tau |m1|``.  Asking for ``t^3 / 12`` gives ``tau^3 + 24 |m1| tau = t^3``,
i.e. ``delta = 4 |m1| / t`` to leading order.  The zeroth moment (mass, stretching
stiffness) is then ``tau`` instead of ``t``: the density is scaled by ``t / tau`` to keep
the mass, the stretching stiffness stays ``tau / t`` too soft.  :func:`thin_shift` solves
the condition on the exact blended profile (the faces' blurs overlap at a few cells
across, where the leading-order formula is 5 % off for erf at 4 cells).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erf, erfc

KERNELS = ("erf", "sine")


def check_kernel(kernel: str) -> str:
    if kernel not in KERNELS:
        raise ValueError(f"blend kernel must be one of {KERNELS}, got {kernel!r}")
    return kernel


def heaviside(phi, kernel: str, width):
    """Blend weight ``H(phi)`` (0 in the solid, 1 in the fluid) for ``kernel`` at absolute
    width ``width`` (the erf scale ``w`` or the sine half-width ``eps``, in length units).

    Works on any array shape; ``width`` may be traced, ``kernel`` is static.
    """
    phi = jnp.asarray(phi)
    if check_kernel(kernel) == "erf":
        return 0.5 * (1.0 + erf(phi / width))
    x = jnp.clip(phi / width, -1.0, 1.0)
    inner = 0.5 + 0.5 * x + jnp.sin(jnp.pi * x) / (2.0 * jnp.pi)
    # exactly 0 and 1 outside the support (sin(pi) is 1e-16, not 0, in floating point)
    return jnp.where(x <= -1.0, 0.0, jnp.where(x >= 1.0, 1.0, inner))


def presence(phi, kernel: str, width, cutoff: float = 0.0):
    """A body's presence ``1 - H(phi)`` (1 inside, 1/2 on the surface, 0 far outside) for
    the contact force, truncated at ``cutoff``: ``max(1 - H - cutoff, 0) / (1 - cutoff)``.

    ``"erf"``: ``erfc(phi / width) / 2`` (computed as erfc, accurate in the far tail);
    exactly 0 beyond ``erfc^-1(2 cutoff) width`` (1.65 width at cutoff 0.01).  ``"sine"``:
    the sine kernel of half-width ``width``; compactly supported already, so ``cutoff``
    is not applied (it would only shrink the support).
    """
    phi = jnp.asarray(phi)
    if check_kernel(kernel) == "erf":
        return jnp.maximum(0.5 * erfc(phi / width) - cutoff, 0.0) / (1.0 - cutoff)
    return 1.0 - heaviside(phi, kernel, width)


def support(kernel: str, width_h: float) -> float:
    """Half-width, in cells, outside which ``H`` is 0 or 1 to 1e-12 (erf) or exactly (sine)."""
    if check_kernel(kernel) == "erf":
        return 5.1 * width_h  # erfc(5.1) / 2 < 1e-12
    return float(width_h)


def first_moment(kernel: str, width_h: float) -> float:
    """``|m1| / h^2`` of the kernel at width ``width_h`` cells (see the module docstring)."""
    if check_kernel(kernel) == "erf":
        return width_h**2 / 4.0
    return 2.0 * width_h**2 * (1.0 / 12.0 - 1.0 / (2.0 * math.pi**2))


def bending_factor(kernel: str, width_h: float, cells_across: float) -> float:
    """Predicted bending stiffening ``1 + C (h / t)^2`` of a plate ``cells_across`` cells
    thick, ``C = 24 |m1| / h^2``."""
    if not cells_across > 0:
        raise ValueError(f"cells_across must be > 0, got {cells_across!r}")
    return 1.0 + 24.0 * first_moment(kernel, width_h) / cells_across**2


def _plate_moments(kernel: str, width_h: float, cells_across: float, shift: float, n: int):
    """Zeroth and second moments (h = 1) of the plate ``cells_across`` thick blended at
    ``|x| - t / 2 + shift``: midpoint rule on ``n`` points over the half-plate and its blur."""
    half = 0.5 * cells_across + support(kernel, width_h) + 1.0
    dx = half / n
    x = (np.arange(n) + 0.5) * dx
    chi = 1.0 - np.asarray(heaviside(x - 0.5 * cells_across + shift, kernel, width_h))
    return 2.0 * float(np.sum(chi)) * dx, 2.0 * float(np.sum(chi * x**2)) * dx


def thin_shift(kernel: str, width_h: float, cells_across: float, n: int = 100_000):
    """The thin-body correction for a plate ``cells_across`` cells thick: ``(delta, scale)``.

    ``delta`` (in cells) is the inward shift of the blend, ``H(phi + delta h)``, that gives
    the blended plate the sharp plate's second moment ``t^3 / 12`` (bisection on the
    sampled profile; ``4 |m1| / t`` to leading order), and ``scale = t / M0`` the density
    factor that gives it back the sharp plate's mass (``M0`` the shifted profile's zeroth
    moment; ``scale - 1`` is also how much too soft in stretching the shifted plate is,
    ``1 / scale`` being its stretching stiffness over the sharp plate's)."""
    t = cells_across
    if not (isinstance(t, (int, float)) and math.isfinite(t) and t > 0):
        raise ValueError(f"cells_across must be a finite number > 0, got {cells_across!r}")
    target = t**3 / 12.0
    lo, hi = 0.0, 0.5 * t + support(kernel, width_h)
    if _plate_moments(kernel, width_h, t, lo, n)[1] <= target:
        return 0.0, t / _plate_moments(kernel, width_h, t, lo, n)[0]
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _plate_moments(kernel, width_h, t, mid, n)[1] > target:
            lo = mid
        else:
            hi = mid
    delta = 0.5 * (lo + hi)
    return delta, t / _plate_moments(kernel, width_h, t, delta, n)[0]


__all__ = [
    "KERNELS",
    "bending_factor",
    "check_kernel",
    "first_moment",
    "heaviside",
    "presence",
    "support",
    "thin_shift",
]
