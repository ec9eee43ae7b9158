"""Blend kernels (refmap.blend): shape, moments, and the bending factor of a blended plate."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from refmap import blend
from refmap.state import Numerics


@pytest.mark.parametrize("kernel", blend.KERNELS)
def test_kernel_is_a_monotone_blend_from_solid_to_fluid(kernel):
    x = np.linspace(-20, 20, 4001)
    H = np.asarray(blend.heaviside(x, kernel, 2.0))
    assert H[0] == pytest.approx(0.0, abs=1e-12) and H[-1] == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.diff(H) >= -1e-15)
    # symmetric: H(-x) = 1 - H(x), so s = H - step is odd and its zeroth moment vanishes
    np.testing.assert_allclose(H[::-1], 1 - H, atol=1e-14)
    assert float(blend.heaviside(0.0, kernel, 2.0)) == pytest.approx(0.5, abs=1e-15)


def test_sine_kernel_is_compactly_supported_and_c1():
    eps = 1.5
    assert float(blend.heaviside(-eps, "sine", eps)) == 0.0
    assert float(blend.heaviside(eps, "sine", eps)) == 1.0
    assert float(blend.heaviside(-eps - 1e-9, "sine", eps)) == 0.0
    # slope 0 at both ends, 1 / eps at the centre
    d = 1e-6
    for x0, slope in ((-eps + d, 0.0), (0.0, 1 / eps), (eps - d, 0.0)):
        g = (float(blend.heaviside(x0 + d, "sine", eps)) - float(blend.heaviside(x0 - d, "sine", eps))) / (2 * d)
        assert g == pytest.approx(slope, abs=1e-5)


@pytest.mark.parametrize(("kernel", "width"), [("erf", 2.0), ("erf", 1.0), ("sine", 2.5), ("sine", 1.5), ("sine", 1.0)])
def test_first_moment_matches_quadrature(kernel, width):
    """|m1| / h^2 from the closed form against adaptive quadrature of (H - step) x (h = 1)."""

    def s(x):
        return float(blend.heaviside(x, kernel, width)) - (1.0 if x > 0 else 0.0)

    lim = blend.support(kernel, width) + 1
    m1 = quad(lambda x: s(x) * x, -lim, 0, limit=200)[0] + quad(lambda x: s(x) * x, 0, lim, limit=200)[0]
    assert abs(m1) == pytest.approx(blend.first_moment(kernel, width), rel=1e-8)


def test_bending_constants_quoted_in_the_docs():
    """C = 24 |m1| / h^2: 24 for the thesis's erf at 2h; 9.8, 3.5, 1.6 for sine at 2.5h, 1.5h, h."""
    C = {k: 24 * blend.first_moment(*k) for k in [("erf", 2.0), ("sine", 2.5), ("sine", 1.5), ("sine", 1.0)]}
    assert C[("erf", 2.0)] == pytest.approx(24.0, rel=1e-12)
    assert C[("sine", 2.5)] == pytest.approx(9.80, abs=0.01)
    assert C[("sine", 1.5)] == pytest.approx(3.53, abs=0.01)
    assert C[("sine", 1.0)] == pytest.approx(1.57, abs=0.01)
    assert blend.bending_factor("erf", 2.0, 4.0) == pytest.approx(2.5)
    with pytest.raises(ValueError, match="cells_across"):
        blend.bending_factor("erf", 2.0, 0.0)


@pytest.mark.parametrize(("kernel", "width", "cells"), [("erf", 2.0, 6.0), ("erf", 2.0, 12.0), ("sine", 1.5, 4.0), ("sine", 2.5, 8.0)])
def test_blended_plate_second_moment(kernel, width, cells):
    """A plate ``cells`` cells thick, its solid fraction sampled on a fine grid (h = 1) with
    the blend at both faces: the second moment about the mid-plane divided by t^3 / 12 is the
    predicted factor 1 + C (h / t)^2.  The neglected terms are of higher order in h / t: for
    the odd kernels the next correction is O((h/t)^4) from the third moment, so the tolerance
    is a few (h/t)^4."""
    t = cells
    x = np.linspace(-t / 2 - 15, t / 2 + 15, 600001)
    dxs = x[1] - x[0]
    phi = np.abs(x) - t / 2  # signed distance to the plate's faces, negative inside
    chi = 1.0 - np.asarray(blend.heaviside(phi, kernel, width))
    I = np.sum(chi * x**2) * dxs
    ratio = I / (t**3 / 12)
    pred = blend.bending_factor(kernel, width, t)
    assert ratio == pytest.approx(pred, abs=3 * (width / t) ** 4 + 1e-6)
    # its mass is t plus the two inner tails of the kernel cut off at the mid-plane, where
    # phi switches to the distance to the other face (zero for the sine kernel, 0.3 % for
    # erf at 6 cells across)
    tail = quad(lambda u: float(blend.heaviside(u, kernel, width)), -60, -t / 2)[0]
    assert np.sum(chi) * dxs == pytest.approx(t + 2 * tail, rel=1e-6)


def test_numerics_rejects_an_unknown_kernel():
    with pytest.raises(ValueError, match="blend.*'gauss'"):
        Numerics(blend="gauss")


def test_sine_blend_rigid_translation_stays_stress_free():
    """A disc in a periodic box translating with the fluid at uniform velocity (equal
    densities) under the sine blend: a rigid motion, so after 30 steps the velocity is
    uniform and the solid stress is zero to round-off (the kernel only weighs stresses)."""
    import jax
    import jax.numpy as jnp

    from refmap.boundary import Boundary
    from refmap.geometry import Disc
    from refmap.grid import Grid
    from refmap.materials import NeoHookean
    from refmap.model import Model, Solid

    g = Grid(32, 32, 0.0, 1.0, 0.0, 1.0)
    m = Model(
        g,
        (Solid(Disc(center=(0.5, 0.5), radius=0.2), NeoHookean(G=10.0, kappa=10.0, rho0=1.0)),),
        boundary=Boundary(left="periodic", right="periodic", bottom="periodic", top="periodic"),
        numerics=Numerics(blend="sine", blur_width=1.5),
    )
    p = m.default_params()
    s = m.initial_state(p)
    U = jnp.asarray([0.3, 0.2])
    s = s.replace(v=jnp.broadcast_to(U[:, None, None], s.v.shape))
    s = jax.jit(lambda s: m.run_steps(s, p, 30, dt=1e-3))(s)
    np.testing.assert_allclose(np.asarray(s.v[0]), 0.3, atol=1e-10)
    np.testing.assert_allclose(np.asarray(s.v[1]), 0.2, atol=1e-10)
    d = m.derived(s, p)
    assert float(jnp.max(jnp.abs(d["sigma_s"]))) < 1e-9
    assert math.isfinite(float(jnp.sum(d["rho"])))


def test_kernel_spec_parses_and_names_bad_values():
    assert blend.parse_kernel("sine:1") == ("sine", 1.0)
    assert blend.parse_kernel("erf:2.5") == ("erf", 2.5)
    for bad in ("sine", "sine:", "sine:0", "sine:-1", "sine:x", "sine:nan", "box:1"):
        with pytest.raises(ValueError, match="sine|box"):
            blend.parse_kernel(bad)


def test_lid_cavity_script_takes_a_kernel_and_caches_its_runs_apart():
    # validation/lid_cavity.py --kernel: the kernel reaches the model, and its runs are
    # cached apart from the erf runs (whose file names stay those of the runs made before)
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "validation" / "lid_cavity.py"
    spec = importlib.util.spec_from_file_location("lid_cavity", path)
    L = importlib.util.module_from_spec(spec)
    sys.modules["lid_cavity"] = L  # dataclasses look their module up there
    spec.loader.exec_module(L)
    model, *_ = L.build(32, blend="sine", blur_width=1.0)
    assert (model.numerics.blend, model.numerics.blur_width) == ("sine", 1.0)
    model, *_ = L.build(32)
    assert (model.numerics.blend, model.numerics.blur_width) == ("erf", 2.0)
    assert L.cache_name(32) == "lid_n32.npz"
    assert L.cache_name(32, blend="sine", blur_width=1.0) == "lid_n32_blendsine_blur_width1.npz"
