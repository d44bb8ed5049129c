"""Paper 1's single-AUV hybrid controller: flow and jump sets at their boundaries, invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hybrid_helpers import obs_at, polar
from hypothesis import given, settings
from hypothesis import strategies as st

from mpcasv.controllers import load_preset, make_controller
from mpcasv.hybrid.single import Q1, Q2
from mpcasv.interface import Mode, Reason

AUV = (100.0, -50.0)


def ctrl(preset="paper1-field"):
    c = make_controller("hybrid-single", 1, preset)
    c.reset(1)
    return c


def step_at(c, t, r, beta, depth, propeller_on=False):
    return c.step(obs_at(t, polar(AUV, r, beta), [(AUV[0], AUV[1], depth)], propeller_on))


def test_standby_inside_the_donut_from_the_start():
    c = ctrl()
    d = c.domain
    cmd = step_at(c, 0.0, 0.5 * (d.inner(0) + d.outer(0)), 1.0, 0.0)
    assert cmd.mode is Mode.STANDBY and c.state.q == Q1
    assert c.jump_log().empty


@pytest.mark.parametrize("depth", [0.0, 30.0, 60.0])
def test_jump_to_avoidance_just_inside_r_inner_and_not_at_it(depth):
    c = ctrl()
    r_in = float(c.domain.inner(depth))
    if r_in == 0:  # deeper than the collision sphere: no inner boundary at all
        assert step_at(c, 0, 0.0, 0.3, depth).mode is Mode.STANDBY
        return
    assert step_at(c, 0, r_in * (1 + 1e-9), 0.3, depth).mode is Mode.STANDBY
    cmd = step_at(c, 1, r_in * (1 - 1e-9), 0.3, depth)
    assert cmd.mode is Mode.TRANSIT and cmd.reason is Reason.AVOIDANCE
    wp = np.array(cmd.waypoint)
    assert math.hypot(*(wp - AUV)) == pytest.approx(float(c.domain.target(depth)))
    assert math.atan2(wp[1] - AUV[1], wp[0] - AUV[0]) == pytest.approx(0.3)  # eq. 7, beta_wp = beta
    assert list(c.jump_log()["cause"]) == ["collision avoidance"]


def test_jump_to_tracking_just_outside_r_outer_and_not_at_it():
    c = ctrl()
    r_out = float(c.domain.outer(10.0))
    assert step_at(c, 0, r_out, 2.0, 10.0).mode is Mode.STANDBY
    cmd = step_at(c, 1, r_out * (1 + 1e-9), 2.0, 10.0)
    assert cmd.mode is Mode.TRANSIT and cmd.reason is Reason.TRACKING


def test_back_to_standby_only_inside_the_target_domain():
    c = ctrl()
    d = c.domain
    r_t = float(d.target(0.0))
    step_at(c, 0, 500.0, 0.0, 0.0)  # tracking
    eps = d.eps_plus
    assert step_at(c, 1, r_t + eps, 0.0, 0.0).mode is Mode.TRANSIT  # |e| = eps: not < eps
    assert step_at(c, 2, r_t + eps * 0.999, 0.0, 0.0).mode is Mode.STANDBY
    assert list(c.jump_log()["cause"]) == ["tracking", "target reached"]


def test_transit_relabelled_when_it_crosses_into_r_inner():
    c = ctrl()
    step_at(c, 0, 500.0, 0.0, 0.0)
    cmd = step_at(c, 1, 10.0, 0.0, 0.0)
    assert cmd.reason is Reason.AVOIDANCE and c.state.q == Q2


def test_standby_waypoint_follows_the_asv():
    c = ctrl()
    step_at(c, 0, 100.0, 0.4, 0.0)
    assert (c.state.r_wp, c.state.beta_wp) == pytest.approx((100.0, 0.4))  # F1


@settings(max_examples=200, deadline=None)
@given(
    preset=st.sampled_from(["paper1-sim", "paper1-field"]),
    steps=st.lists(
        st.tuples(st.floats(0.0, 400.0), st.floats(-math.pi, math.pi), st.floats(0.0, 80.0)),
        min_size=1, max_size=25,
    ),
)  # fmt: skip
def test_invariants_over_random_geometries(preset, steps):
    """Inside r_inner: transit with the waypoint outside r_inner. Never standby outside
    r_outer. Every jump is logged with a cause."""
    c = ctrl(preset)
    d = load_preset("hybrid-single", preset).domain
    for t, (r, beta, depth) in enumerate(steps):
        cmd = step_at(c, float(t), r, beta, depth)
        r_inner, r_outer = float(d.inner(depth)), float(d.outer(depth))
        if r < r_inner:
            assert cmd.mode is Mode.TRANSIT
            assert math.hypot(cmd.waypoint[0] - AUV[0], cmd.waypoint[1] - AUV[1]) > r_inner
        if r > r_outer:
            assert cmd.mode is Mode.TRANSIT
    log = c.jump_log()
    assert log["cause"].isin(["collision avoidance", "tracking", "target reached"]).all()
    assert (log["from_mode"] != log["to_mode"]).sum() + (log["from_mode"] == Q2).sum() >= len(log)
