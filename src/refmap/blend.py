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
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jax.scipy.special import erf, erfc

KERNELS = ("erf", "sine")


def check_kernel(kernel: str) -> str:
    if kernel not in KERNELS:
        raise ValueError(f"blend kernel must be one of {KERNELS}, got {kernel!r}")
    return kernel


def parse_kernel(spec: str) -> tuple[str, float]:
    """``"sine:1"`` -> ``("sine", 1.0)``: a kernel and its width in cells, as the validation
    drivers and ``blend_sweep`` take them on the command line."""
    kernel, sep, width = str(spec).partition(":")
    check_kernel(kernel)
    try:
        w = float(width)
    except ValueError:
        w = float("nan")
    if not sep or not w > 0 or not math.isfinite(w):
        raise ValueError(f"kernel spec must be KERNEL:WIDTH with WIDTH > 0 cells (e.g. 'sine:1'), got {spec!r}")
    return kernel, w


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


__all__ = ["KERNELS", "bending_factor", "check_kernel", "first_moment", "heaviside", "parse_kernel", "presence", "support"]
