"""Acoustic channel: success curve, range-dependent fix error. (INS drift and the AUV's own
filter: tests/test_auv_nav.py; the reliable-fix rule: tests/test_metrics.py.)"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mpcasv.controllers import make_controller
from mpcasv.models.acoustics import (
    AcousticParams,
    success_probability,
    usbl_fix,
)
from mpcasv.sim.scenario import scenario_from_dict
from mpcasv.sim.simulator import simulate


def _still_scenario(distance: float, depth: float, duration: float) -> object:
    """An AUV holding station ``distance`` m north of a drifting ASV (propeller off)."""
    return scenario_from_dict({
        "name": "still", "duration": duration, "estimator": "acoustic",
        "auv": [{"name": "a", "start": {"N": distance, "depth": depth},
                 "behaviour": {"plan": {"speed": 1.0, "route": [
                     {"waypoints": [[distance, 0.0, depth]]}]}}}],
    })  # fmt: skip


@pytest.mark.parametrize("distance", [300.0, 650.0, 900.0])
def test_usbl_success_rate_matches_the_configured_curve(distance):
    sc = _still_scenario(distance, 20.0, 4000.0)
    # the trivial controller with its waypoint at the ASV's start: it stands by at once
    ctrl = make_controller("goto", 1, None, overrides={"waypoint": [0.0, 0.0]})
    res = simulate(sc, ctrl, seed=11)
    n_pings = int(4000.0 // sc.acoustics.T0)
    p = float(success_probability(math.hypot(distance, 20.0), False, sc.acoustics))
    k = len(res.fix_times[0])
    sd = math.sqrt(n_pings * p * (1 - p))
    assert abs(k - n_pings * p) <= 4 * sd + 1, (k, n_pings * p)


def test_success_probability_curve_and_propeller_factor():
    p = AcousticParams()
    s = np.array([100.0, 499.0, 501.0, 799.0, 801.0])
    assert np.allclose(success_probability(s, False, p), [0.95, 0.95, 0.3, 0.3, 0.0])
    assert np.allclose(success_probability(s, True, p), 0.63 * np.array([0.95, 0.95, 0.3, 0.3, 0]))


def test_fix_error_grows_with_range_as_bearing_error_times_range():
    p = AcousticParams(sigma_bearing_deg=1.0, sigma_range=0.5)
    rng = np.random.default_rng(0)
    for r in (100.0, 400.0):
        fixes = [usbl_fix(0.0, 0, (0.0, 0.0), (r, 0.0, 0.0), p, rng.standard_normal(3))
                 for _ in range(4000)]  # fmt: skip
        across = np.std([f.E for f in fixes])  # transverse to the line of sight (North)
        along = np.std([f.N - r for f in fixes])
        assert abs(across / (math.radians(1.0) * r) - 1) < 0.06  # eq. 2.9
        assert abs(along / 0.5 - 1) < 0.06
        assert abs(math.sqrt(fixes[0].cov[3]) - math.radians(1.0) * r) < 1e-9
