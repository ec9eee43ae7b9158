"""Small versions of validation/turek_hron.py (Turek--Hron CSM/CFD/FSI), failing if the
accuracy regresses.  The full runs (minutes each) are marked slow; their bounds are the
measured numbers of docs/validation_turek_hron.md with a little headroom."""

import importlib.util
import math
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load():
    spec = importlib.util.spec_from_file_location(
        "turek_hron", ROOT / "validation" / "turek_hron.py"
    )
    mod = importlib.util.module_from_spec(spec)
    sys.modules["turek_hron"] = mod  # dataclasses look their module up while it executes
    spec.loader.exec_module(mod)
    return mod


def test_flag_falls_freely_before_the_clamp_is_felt():
    """CSM1 set-up at 2 cells across the flag, t = 0.004 s: no elastic signal has yet come
    from the clamped root to the tip (0.35 m at c_L = 55 m/s takes 0.0064 s), so point A,
    found through the reference map, falls as a free body with the mass damping,
    u_y = -(g / gamma) (t - (1 - exp(-gamma t)) / gamma).  Checks gravity on the solid's
    mass only, the damping term and the material-point probe.  Measured: -1.6 % (the
    light fluid, rho_f = 1, adds ~1.4 % of the flag's mass); bound 3 %."""
    th = _load()
    model, params, info = th.make_csm("csm1", 2, rho_f=1.0, gamma_factor=2.0, damp_all=True)
    s = model.initial_state(params)
    T = 0.004
    s, st = jax.jit(model.advance)(s, params, T)
    assert bool(st["ok"])
    u = np.asarray(th.probe(model, s)[0])
    g, gam = th.GRAV, info["gamma"]
    exact = -(g / gam) * (T - (1 - math.exp(-gam * T)) / gam)
    assert abs(u[1] / exact - 1) < 0.03
    assert abs(u[0]) < 1e-3 * abs(exact)  # falls straight down


def test_blurred_flag_bending_stiffness_model():
    """The numbers the docs use to explain the CSM error: with the blend weight
    1 - H = erfc(phi / 2h) / 2 the flag's second moment of solid fraction is that of a
    sharp flag times 1 + 24 (h / t)^2 (the blur kernel has variance 2 h^2), its mass exact."""
    from scipy.special import erfc

    for nt in (4, 6, 8):
        s = np.linspace(-40.0, 40.0, 160001)
        ds = s[1] - s[0]
        ws = erfc((np.abs(s) - nt / 2) / 2) / 2
        assert abs(ws.sum() * ds / nt - 1) < 0.03
        # exact for a slab convolved with the kernel; the erfc of |s| differs from that only
        # where the two faces' tails overlap (0.4 % at 4 cells)
        assert abs((ws * s**2).sum() * ds / (nt**3 / 12) / (1 + 24 / nt**2) - 1) < 0.01


@pytest.mark.slow
def test_csm2_static_deflection_4_cells(tmp_path):
    """CSM2 at 4 cells across the flag (about 4 CPU-minutes).  Measured u_y(A) = -7.25e-3 m
    against -16.97e-3: the blurred flag is 2.5x too stiff in bending (see the test above;
    beam prediction 0.41 x the reference), so u_y / u_y,ref = 0.427.  Bounds: 0.40 - 0.46."""
    th = _load()
    r = th.run_csm(
        "csm2", 4, out=tmp_path, verbose=False, rho_f=10.0, gamma_factor=1.2649, damp_all=True
    )
    assert r["ok"]
    ratio = r["uy"] / r["ref_uy"]
    assert 0.40 < ratio < 0.46
    assert r["uy_spread_last"] < 0.01 * abs(r["uy"])  # at rest


@pytest.mark.slow
def test_csm2_sine_blend_bends_as_its_first_moment_predicts(tmp_path):
    """CSM2 at 4 cells across with the sine kernel of half-width 1.5 h and the corner
    compression (about 3 CPU-minutes).  The kernel's bending factor there is
    1 + 3.53 / 16 = 1.22 (erf: 2.5), so the flag must deflect about twice as far as with
    the thesis's blend.  Measured (2026-12-06): u_y(A) = -12.53e-3 against -16.97e-3, 0.738
    of the reference, at rest at t = 0.82 s (the beam estimate 1 / 1.22 = 0.82; the erf
    flag in the same set-up gives 0.396 against 0.408).  Bounds 0.70 - 0.78, about 5 %
    round the measured value; the erf flag is far below them.  With the thesis's centred compression
    this run blows up at t = 0.6 (docs/validation_turek_hron.md)."""
    th = _load()
    r = th.run_csm(
        "csm2", 4, out=tmp_path, verbose=False, blend_kernel="sine", blur_width=1.5,
        compression="corner",
    )
    assert r["ok"]
    ratio = r["uy"] / r["ref_uy"]
    assert 0.70 < ratio < 0.78
    assert r["uy_spread_last"] < 0.005 * abs(r["uy"])  # at rest


@pytest.mark.slow
def test_cfd1_drag_coarse(tmp_path):
    """CFD1 (rigid flag) at 41 cells across the channel to t = 8 (~2 CPU-minutes), forces
    averaged over the last 3.6 s (one period of the sound sloshing along the channel).
    Measured: drag 13.24 (-7.4 %), control-volume box drag 12.23 (the box also holds the
    still-changing momentum round the body).  Bounds: 12 % and 10 % of the reference.  The
    lift is not checked: at this resolution it has the wrong sign (-4.1 against 1.12)."""
    th = _load()
    r = th.run_cfd1(41, t_end=8.0, out=tmp_path, keep_state=False)
    assert abs(r["err_drag"]) < 0.12
    assert abs(r["drag"] - r["drag_box"]) < 0.10 * r["ref_drag"]


def test_cfd1_incompressible_channel_coarse():
    """CFD1 with the incompressible fluid (projection) at 41 cells across the channel, to
    t = 2 (the end of the inflow ramp; 320 steps).  Measured: held drag 13.41 (-6.2 %),
    control-volume box drag 13.32, lift +1.90 (the full run settles at 12.70 and +2.59,
    docs/validation_turek_hron.md); bounds: drag within 12 % of the reference, the box
    form within 3 % of the held force, the drag's pressure part (sum_held -G p dA, the
    projection pressure) between 50 and 80 % of it (measured 65 %), and a positive lift."""
    th = _load()
    model, params, info = th.make_incompressible_channel(41, ubar=0.2)
    s = model.initial_state(params)
    s, st = jax.jit(model.advance)(s, params, 2.0)
    assert bool(st["ok"])
    fh, fb, _, fp = (np.asarray(a) for a in th._forces_fn(model, params)(s))
    ref = th.REFERENCE["cfd1"]
    assert abs(fh[0] / ref["drag"] - 1.0) < 0.12
    assert abs(fb[0] - fh[0]) < 0.03 * fh[0]
    assert 0.5 * fh[0] < fp[0] < 0.8 * fh[0]
    assert fh[1] > 0.0


def test_oscillation_measures_mean_amplitude_and_frequency():
    """CSM3's answer is read from the sampled u_y(A)(t) by ``oscillation``: extrema from
    parabolas through the sampled ones, the frequency from their spacing.  On the
    reference's own motion, u = m - a cos(2 pi f t) sampled every 5 ms over three periods
    (the run's sampling), it returns m, a and f within 1e-4 relative (a parabola through
    three samples of a cosine errs by ~(2 pi f dt)^2 / 12 at worst in the vertex height, i.e.
    1e-4); with a 1 % decay per period the last period's amplitude is the one reported.
    A history shorter than a period is refused."""
    th = _load()
    m, a, f = -63.607e-3, 65.160e-3, 1.0995
    t = np.arange(0.0, 3.1 / f, 0.005)
    for phase in (0.0, 0.3):
        osc = th.oscillation(t, m - a * np.cos(2 * np.pi * f * t + phase))
        assert abs(osc["mean"] / m - 1) < 1e-4
        assert abs(osc["amp"] / a - 1) < 1e-4
        assert abs(osc["freq"] / f - 1) < 1e-4
    decay = np.exp(-0.01 * f * t)
    osc = th.oscillation(t, m * decay - a * decay * np.cos(2 * np.pi * f * t))
    last_period = t[-1] - 1.0 / f
    assert 0.97 * a < osc["amp"] < a * np.exp(-0.01 * f * last_period) * 1.01
    with pytest.raises(ValueError, match="fewer than two"):
        th.oscillation(t[:100], m - a * np.cos(2 * np.pi * f * t[:100]))
