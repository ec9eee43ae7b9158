"""Soft disc in a lid-driven cavity (validation/lid_cavity.py) against Sugiyama et al. 2011.

The reference is a digitized centroid path (x, y) without times, digitizing error about
0.005.  The small version runs 32^2 to t = 3 (the disc's first move round the bottom-left
of the vortex); the slow one the whole first loop.
"""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
REF = ROOT.parent / "shared" / "data" / "lid_cavity_disc_sugiyama2011_1024.csv"

pytestmark = pytest.mark.skipif(not REF.exists(), reason="reference data (shared/data) not present")


def _load():
    spec = importlib.util.spec_from_file_location(
        "lid_cavity", ROOT / "validation" / "lid_cavity.py"
    )
    mod = importlib.util.module_from_spec(spec)
    sys.modules["lid_cavity"] = mod  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


def test_lid_cavity_disc_follows_reference_path_32():
    """32^2 to t = 3.  Measured: RMS distance of the computed centroid samples to the
    reference path 0.0049 (max 0.013: the digitized path starts 0.013 from the initial
    centre); disc area within -1.1 % / +0.1 % of its initial value; max speed 0.879 < 1
    (the lid's).  Bounds: the RMS may grow by the digitizing error (0.005, in quadrature:
    0.007) -> 0.008; area 2 %; speed below the lid speed."""
    L = _load()
    rows, _, _, _ = L.run(32, 3.0, every=0.05)
    ref = L.load_reference()
    d = L.distance_to_reference(rows, ref)
    assert len(d) == len(rows)  # every sample lies within the reference's first turn
    assert np.sqrt(np.mean(d**2)) < 0.008
    area = rows[:, 3] / rows[0, 3] - 1.0
    assert np.abs(area).max() < 0.02
    assert rows[:, 6].max() < 1.0
    # the reference has no times, so check the pace against the grid: at t = 3 the centroid
    # is at (0.328, 0.617) on 32^2 and (0.318, 0.633) on 64^2; a disc lagging by 10 % (the
    # 32^2 path at t = 2.7) is at (0.353, 0.581) and fails, a 3 % lag (0.335, 0.605) passes
    assert rows[-1, 1] < 0.34 and rows[-1, 2] > 0.60


@pytest.mark.slow
def test_lid_cavity_disc_first_loop_32():
    """32^2 to t = 9 (one full turn).  Measured extents errors x_max -0.015, x_min +0.010,
    y_max -0.006, y_min -0.002; RMS loop-matched distance 0.0144; area +11 % after the
    loop.  Bounds: each extent within 0.025 (measured worst 0.015 + digitizing error
    0.005 + margin), RMS < 0.02, area change < 15 %."""
    L = _load()
    rows, _, _, _ = L.run(32, 9.0, every=0.05)
    c = L.compare(rows, L.load_reference())
    for k, v in L.REF_EXTENTS.items():
        assert abs(c[k] - v) < 0.025, (k, c[k], v)
    assert c["rms_first_loop"] < 0.02
    assert c["area_change_loop"] < 0.15


def _load_incompressible():
    _load()  # validation/incompressible.py imports lid_cavity by name
    spec = importlib.util.spec_from_file_location(
        "incompressible_validation", ROOT / "validation" / "incompressible.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_lid_cavity_disc_incompressible_first_loop_32():
    """The same disc in an incompressible fluid (validation/incompressible.py), 32^2 to
    t = 8.5 (one turn at t = 7.8), with the default volume correction (rate 10).
    Measured: area change over the first loop +0.76 % (without the correction +26 %, and
    the run blew up at t = 18.1), RMS loop-matched distance 0.0112 (without: 0.0257),
    extents errors x_max +0.002, x_min +0.016, y_max -0.001, y_min -0.001.  Bounds: area
    over the loop 2 %, RMS 0.016 (the uncorrected run's 0.0257 fails both), each extent
    within 0.025 as for the compressible first loop."""
    inc = _load_incompressible()
    r = inc.cavity(32, 8.5)
    assert r["blew_up_before"] is None
    c = r["compare"]
    assert abs(c["area_change_loop"]) < 0.02
    assert c["rms_first_loop"] < 0.016
    L = sys.modules["lid_cavity"]
    for key, ref in L.REF_EXTENTS.items():
        assert abs(c[key] - ref) < 0.025, (key, c[key])


def test_lid_cavity_disc_fluid_mass_conserved_32():
    """Issue 15 item 4 (swelling), with ``numerics.fluid_mass = "conserved"``: 32^2 to
    t = 6 (past the disc's passes along the left wall and under the lid, where the
    default loses fluid mass).  Measured: area +3.04 % at t = 6 (default: +10.2 %), fluid
    mass constant to round-off (default: -1.6 %).  Bounds: area 5 % (the default fails),
    fluid mass 1e-10."""
    L = _load()
    rows, _, _, _ = L.run(32, 6.0, every=0.5, fluid_mass="conserved")
    area = rows[:, 3] / rows[0, 3] - 1.0
    mass = rows[:, 7] / rows[0, 7] - 1.0
    assert abs(area[-1]) < 0.05 and np.abs(area).max() < 0.06
    assert np.abs(mass).max() < 1e-10
