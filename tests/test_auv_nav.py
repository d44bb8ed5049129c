"""Each AUV's own navigation filter (mpcasv/models/auv_nav.py; thesis §2.5 eq. 2.7, eq. 2.9):
dead reckoning grows as 1/2 eps_a t^2, periodic fixes keep it bounded, a far fix moves it
less than a near one, and the filter's covariance matches its error."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mpcasv.controllers import make_controller
from mpcasv.models.acoustics import AcousticParams, NavParams, usbl_fix
from mpcasv.models.auv_nav import AUVNavFilter
from mpcasv.sim.scenario import scenario_from_dict
from mpcasv.sim.simulator import simulate
from mpcasv.sim.streams import ins_draws

EPS_A = 0.002  # MRU 5 (PAPER-FACTS §1)
AC = AcousticParams()


def _fix_R(slant: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """(error, covariance) of a USBL fix of an AUV ``slant`` m north of the ASV, at depth 0."""
    fix = usbl_fix(0.0, 0, (0.0, 0.0), (slant, 0.0, 0.0), AC, rng.standard_normal(3))
    return np.array([fix.N - slant, fix.E]), np.reshape(fix.cov, (2, 2))


def test_without_fixes_the_error_grows_as_half_eps_a_t_squared():
    t = 100.0
    errs = []
    for seed in range(400):
        nav = AUVNavFilter(1, NavParams(eps_a=EPS_A), ins_draws(np.random.default_rng(seed)))
        errs.append(np.hypot(*nav.error(t)[0]))
        # the filter knows it: its own 1-sigma radius per axis is 1/2 eps_a t^2 / sqrt(2)
        assert nav.sigma(t)[0] == pytest.approx(0.5 * EPS_A * t**2 / math.sqrt(2))
    rms = math.sqrt(np.mean(np.square(errs)))
    assert abs(rms / (0.5 * EPS_A * t**2) - 1) < 0.12  # eq. 2.7, RMS over seeds


def test_periodic_fixes_keep_the_error_bounded_and_the_filter_consistent():
    """A fix from 200 m every 5 s for an hour: the error stays at the metre level (without
    fixes it would reach 1/2 eps_a t^2 = 12960 m), the filter's sigma settles, and its
    covariance matches the error (NEES ~ chi-square with 2 degrees of freedom)."""
    worst, nees, sig = [], [], []
    for seed in range(60):
        rng = np.random.default_rng(seed)
        nav = AUVNavFilter(1, NavParams(eps_a=EPS_A), ins_draws(rng))
        err = []
        for j in range(1, 721):
            t = 5.0 * j
            v, R = _fix_R(200.0, rng)
            nav.update(0, t, v, R, ins_draws(rng))
            e = nav.error(t + 4.9)[0]  # just before the next fix: the largest error
            err.append(np.hypot(*e))
            P = nav.cov(t + 4.9)[0]
            if j > 100:
                nees.append(e @ np.linalg.solve(P, e))
            if j in (360, 720):  # half-way and at the end
                sig.append(nav.sigma(t + 4.9)[0])
        worst.append(max(err))
    s_bearing = math.radians(AC.sigma_bearing_deg) * 200.0  # eq. 2.9: 3.5 m across
    assert max(worst) < 3.0 * s_bearing
    assert abs(np.mean(nees) - 2.0) < 0.25
    half, end = np.array(sig).reshape(-1, 2).T
    np.testing.assert_allclose(end, half, rtol=0.05)  # settled (bounded, not growing)
    assert end[0] < s_bearing  # fusing many fixes beats any single one


def test_a_far_fix_moves_the_estimate_less_than_a_near_one():
    """Same prior (100 s of dead reckoning), same measurement residual: the fix from 700 m
    (bearing error 12 m across) moves the estimate less than the one from 100 m (1.7 m)."""
    moves = {}
    for slant in (100.0, 700.0):
        nav = AUVNavFilter(1, NavParams(eps_a=EPS_A), ins_draws(np.random.default_rng(7)))
        e_prior = nav.error(100.0)[0].copy()
        _, R = _fix_R(slant, np.random.default_rng(0))
        ins = ins_draws(np.random.default_rng(8))
        moves[slant] = np.hypot(*nav.update(0, 100.0, np.zeros(2), R, ins))  # z = truth
        assert np.hypot(*nav.error(100.0)[0]) < np.hypot(*e_prior)
    assert moves[700.0] < moves[100.0]
    # not a reset: the far fix leaves a visible share of the prior error in the estimate
    nav = AUVNavFilter(1, NavParams(eps_a=EPS_A), ins_draws(np.random.default_rng(7)))
    e_prior = nav.error(100.0)[0].copy()
    _, R = _fix_R(700.0, np.random.default_rng(0))
    nav.update(0, 100.0, np.zeros(2), R, ins_draws(np.random.default_rng(8)))
    assert np.hypot(*nav.error(100.0)[0]) > 0.05 * np.hypot(*e_prior)


def _deep_auv(usbl: bool, duration: float = 300.0):
    """An AUV holding 30 m deep 100 m from a standing ASV (no GPS)."""
    return scenario_from_dict({
        "name": "deep", "duration": duration, "acoustics": {"usbl": usbl},
        "auv": [{"name": "a", "start": {"N": 100.0, "depth": 30.0},
                 "behaviour": {"plan": {"speed": 1.0, "route": [
                     {"waypoints": [[100.0, 0.0, 30.0]]}]}}}],
    })  # fmt: skip


def test_in_the_simulator_fixes_bound_the_auvs_error_and_none_lets_it_drift():
    ctrl = make_controller("goto", 1, None, overrides={"waypoint": [0.0, 0.0]})
    drift = simulate(_deep_auv(usbl=False), ctrl, seed=2).timeseries
    t = drift["t"].to_numpy()
    np.testing.assert_allclose(drift["nav_sigma0"], 0.5 * EPS_A * t**2 / math.sqrt(2))
    aided = simulate(_deep_auv(usbl=True), ctrl, seed=2).timeseries
    assert aided["nav_err0"].max() < 5.0  # fixes from ~104 m: 1.8 m across
    assert drift["nav_err0"].iloc[-1] > 10 * aided["nav_err0"].iloc[-1]
