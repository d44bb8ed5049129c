"""Paper 2's multi-AUV supervisory switching controller: selection, timers, modes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hybrid_helpers import obs_at
from hypothesis import given, settings
from hypothesis import strategies as st

from mpcasv.controllers import make_controller
from mpcasv.hybrid.multi import Q1, Q2
from mpcasv.interface import Mode, Reason

AUVS = [(0.0, 0.0, 0.0), (400.0, 0.0, 0.0), (0.0, 400.0, 0.0)]


def ctrl(**over):
    c = make_controller("hybrid-multi", 3, "paper2-field", overrides=over or None)
    c.reset(3)
    return c


def test_nominal_choice_is_the_oldest_fix_and_transit_goes_to_its_target_circle():
    c = ctrl()
    c.tau_k[:] = [5.0, 50.0, 20.0]
    cmd = c.step(obs_at(0.0, (200.0, 200.0), AUVS))
    assert cmd.mode is Mode.TRANSIT and cmd.auv == 1
    r_t = float(c.domain.target(0.0))
    assert math.hypot(cmd.waypoint[0] - 400.0, cmd.waypoint[1]) == pytest.approx(r_t)


def test_argmin_range_as_soon_as_any_auv_is_inside_its_avoid_radius():
    c = ctrl()
    c.tau_k[:] = [0.0, 500.0, 500.0]
    cmd = c.step(obs_at(0.0, (10.0, 0.0), AUVS))
    assert cmd.auv == 0 and cmd.reason is Reason.AVOIDANCE


def test_timers_follow_eq_9():
    c = ctrl()
    r_t, eps = float(c.domain.target(0.0)), c.domain.eps_plus
    c.step(obs_at(0.0, (r_t + eps - 1.0, 0.0), AUVS, propeller_on=False))
    assert c.tau_k[0] == 0.0 and c.tau_k[1] == 1.0 and c.tau_k[2] == 1.0
    c.step(obs_at(1.0, (r_t + eps - 1.0, 0.0), AUVS, propeller_on=True))
    assert c.tau_k[0] == 1.0  # propeller on: no reset
    c.step(obs_at(2.0, (r_t + eps + 1.0, 0.0), AUVS, propeller_on=False))
    assert c.tau_k[0] == 2.0  # outside the outer limit of the target domain


def test_standby_lasts_T_then_transit_to_the_next_auv():
    c = ctrl()
    c.tau_k[:] = [100.0, 10.0, 5.0]
    cmd = c.step(obs_at(0.0, (-200.0, -200.0), AUVS, propeller_on=True))
    assert cmd.mode is Mode.TRANSIT and cmd.auv == 0
    r_t = float(c.domain.target(0.0))
    # arriving in transit the propeller still runs (n_p != 0: no timer reset yet)
    modes = [c.step(obs_at(float(t), (r_t, 0.0), AUVS, propeller_on=(t == 1))).mode
             for t in range(1, 20)]  # fmt: skip
    assert modes[0] is Mode.STANDBY  # |e| < eps: jump to Q1, tau := T
    n_standby = modes.index(Mode.TRANSIT)
    assert n_standby == int(c.params.T_standby)  # T periods of 1 s: tau = T-1, ..., 0, then D2
    assert c.state.i == 1  # argmax tau once AUV 0's timer has been reset


def test_after_avoidance_it_waits_for_that_fix_before_the_nominal_choice():
    c = ctrl()
    c.tau_k[:] = [0.0, 900.0, 0.0]
    c.step(obs_at(0.0, (20.0, 0.0), AUVS))  # inside AUV 0's r_avoid
    assert c.latch == 0
    r_t = float(c.domain.target(0.0))
    cmd = c.step(obs_at(1.0, (r_t + 30.0, 0.0), AUVS, propeller_on=True))  # out, not yet there
    assert cmd.auv == 0  # still AUV 0 although AUV 1's fix is much older
    for t in range(2, 20):
        cmd = c.step(obs_at(float(t), (r_t, 0.0), AUVS))
    assert c.latch is None and cmd.mode is Mode.TRANSIT and cmd.auv == 1


obs_strategy = st.lists(
    st.tuples(
        st.floats(-100.0, 500.0), st.floats(-100.0, 500.0), st.booleans(),
        st.lists(st.floats(0.0, 60.0), min_size=3, max_size=3),
    ),
    min_size=1, max_size=40,
)  # fmt: skip


@settings(max_examples=150, deadline=None)
@given(seq=obs_strategy)
def test_invariants_over_random_sequences(seq):
    """argmin when inside any r_avoid; tau_k resets only under the rule; standby >= T
    unless cut short by collision avoidance."""
    c = ctrl()
    d, T = c.domain, c.params.T_standby
    standby_len, prev_tau = 0, np.zeros(3)
    for t, (n, e, prop, depths) in enumerate(seq):
        auvs = [(a[0], a[1], dd) for a, dd in zip(AUVS, depths, strict=True)]
        cmd = c.step(obs_at(float(t), (n, e), auvs, propeller_on=prop))
        r = np.array([math.hypot(n - a[0], e - a[1]) for a in AUVS])
        r_avoid, r_t = d.avoid(np.array(depths)), d.target(np.array(depths))
        if np.any(r < r_avoid):
            assert c.state.i == int(np.argmin(r)) and cmd.mode is Mode.TRANSIT
        rule = (r < r_t + d.eps_plus) & (not prop)
        assert np.all(c.tau_k[rule] == 0.0)
        assert np.allclose(c.tau_k[~rule], prev_tau[~rule] + 1.0)  # tau_dot = 1 (dt = 1 s)
        prev_tau = c.tau_k.copy()
        if cmd.mode is Mode.STANDBY:
            standby_len += 1
        else:
            if standby_len and cmd.reason is not Reason.AVOIDANCE:
                assert standby_len >= T
            standby_len = 0
    assert set(c.jump_log()["to_mode"]) <= {Q1, Q2}
