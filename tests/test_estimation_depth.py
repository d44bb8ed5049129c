"""The AUVs' depth: the reports' pressure depths and the fixes' USBL depths weighed by their
variances (``mpcasv.estimation.depth``), and the MPC's vertical speed and 60-s depth forecast
from that estimate (``mpcasv.mpc.worldview``). Session 50, a reviewer: with each fix's depth
(its 3-D error's vertical part, ``sigma_b r_h``: 1.7 m at 100 m, 7 m at 400 m) copied into
the estimate, a steady AUV at 28 m got a 60-s forecast of 0-157 m (p5-p95) at 400 m, and a
surface AUV one 78 m deep (its collision radius 0)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mpcasv.interface import ASVState, Observation
from mpcasv.mpc.worldview import WorldView
from mpcasv.sim.scenario import scenario_from_dict
from mpcasv.sim.world import World


class _Tracker(WorldView):
    """The MPC's depth tracking alone (``WorldView._track_depth``, ``depth_forecast``)."""

    def __init__(self):
        self._depth_hist = [[]]
        self.w_depth = np.zeros(1)


def _run(behaviour, start, seed, duration=600.0):
    """(t, true depth, estimated depth, tracked vertical speed, 60-s forecast) per 1-s step:
    the kalman estimator, the ASV standing at the origin."""
    auv = {"name": "a", "start": start, "behaviour": behaviour}
    sc = scenario_from_dict({"name": "d", "duration": duration, "estimator": "kalman",
                             "auv": [auv]})  # fmt: skip
    w, tr = World(sc, seed=seed), _Tracker()
    rows = []
    for _ in range(int(duration)):
        w.advance(np.zeros(4))
        a = w.estimators[0].estimate(w.t)
        if not math.isfinite(a.depth):
            continue
        obs = Observation(w.t, ASVState(0.0, 0.0, 0.0), False, (a,))
        tr._track_depth(obs)
        fc = float(tr.depth_forecast(obs, np.array([60.0]))[0, 0])
        rows.append((w.t, w.auv_truth(0)[2], a.depth, float(tr.w_depth[0]), fc))
    return np.array(rows)


def _holding(r_h, depth):
    return ({"plan": {"speed": 1.0, "route": [{"waypoints": [[r_h, 0.0, depth]]}]}},
            {"N": r_h, "depth": depth})  # fmt: skip


@pytest.mark.parametrize("r_h", [100.0, 400.0])
def test_a_steady_auvs_depth_forecast_is_not_thrown_about_by_the_fix_depths(r_h):
    """AUV holding 28 m, r_h 100 / 400 m, seeds 0-2: the 60-s forecast's p5-p95 was 0-81 /
    0-157 m with the fix depths copied in (13-43 m at 400 m with the fix depth's old 0.5 m
    noise); now 15-41 / 14-41 m."""
    fc = np.concatenate([_run(*_holding(r_h, 28.0), seed=s)[:, 4] for s in range(3)])
    p5, p50, p95 = np.percentile(fc, [5, 50, 95])
    assert 10.0 < p5 and p95 < 46.0 and abs(p50 - 28.0) < 2.0, (p5, p50, p95)


def test_a_surface_auvs_depth_forecast_stays_near_the_surface():
    """A surface AUV 150 m off (fix depth noise 2.6 m): p95 of the forecast 78 m before, 7 m
    now (its collision radius is that of an AUV at the surface, not 0)."""
    fc = np.concatenate([_run(*_holding(150.0, 0.0), seed=s)[:, 4] for s in range(3)])
    assert np.percentile(fc, 95) < 12.0


def test_a_rising_auvs_depth_and_vertical_speed_are_followed():
    """From 60 m to the surface at the AUV's climb rate, 100 m off: the estimate follows the
    depth (within the 5 s a held estimate lags) and the tracked vertical speed is the climb's
    (with the fix depths copied in it jumped by +-0.5 m/s from fix to fix)."""
    beh = {"transit": {"heading_deg": 0.0, "speed": 0.2, "depth": 0.0}}
    rows = _run(beh, {"N": 100.0, "depth": 60.0, "speed": 0.2}, seed=0, duration=240.0)
    t, true, est, w = rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3]
    climbing = (true > 5.0) & (true < 50.0) & (t > 30.0)
    rate = np.gradient(true, t)[climbing]
    assert np.median(rate) < -0.3  # the AUV climbs
    err = np.abs(est - true)[climbing]
    assert np.percentile(err, 90) < 4.0, np.percentile(err, 90)
    dw = np.abs(w[climbing] - rate)
    assert np.median(dw) < 0.15 and np.percentile(dw, 90) < 0.35, np.percentile(dw, [50, 90])
    assert true[-1] < 0.5 and est[-1] < 1.5  # and at the surface, the estimate with it
