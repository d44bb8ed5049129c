"""Paper 2's multi-AUV supervisory switching controller: selection, timers, modes."""

from __future__ import annotations

import dataclasses
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
        if np.any(r < r_avoid):  # the deepest breach (issue 14, S1)
            assert c.state.i == int(np.argmin(r - r_avoid)) and cmd.mode is Mode.TRANSIT
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


# --- issue 14: Eq. 8 with the thesis's intent at mixed depths --------------------------------
# paper2-field: r_avoid = alpha T0 rdot_max = 50 m, delta_r = 20 m, eps = 10 m.
DEEP_SURFACE = [(0.0, 0.0, 45.0), (65.0, 0.0, 0.0)]  # r_avoid,0 = sqrt(50^2 - 45^2) = 21.8 m


def ctrl_n(n):
    c = make_controller("hybrid-multi", n, "paper2-field")
    c.reset(n)
    return c


def domains(auvs, d):
    """Centres (K, 2) and the papers' r_avoid,k (K,) of AUVs [(N, E, depth), ...]."""
    a = np.asarray(auvs, float)
    return a[:, :2], np.asarray(d.avoid(a[:, 2]), float)


@pytest.mark.parametrize("standing_by", [False, True])
def test_mixed_depths_the_breached_surface_auv_is_avoided_not_the_nearer_deep_one(standing_by):
    """The issue's case: ASV at (25, 0), 25 m from a 45 m-deep AUV (domain 21.8 m: not
    breached) and 40 m from a surface AUV (domain 50 m: breached). The printed eq. 8 picks
    the deep AUV (nearest) and stays in standby, or transits to (41.8, 0), 23 m from the
    surface AUV."""
    c = ctrl_n(2)
    if standing_by:
        c.state = dataclasses.replace(c.state, q=Q1, tau=8.0)
    cmd = c.step(obs_at(0.0, (25.0, 0.0), DEEP_SURFACE))
    assert cmd.mode is Mode.TRANSIT and cmd.reason is Reason.AVOIDANCE
    assert cmd.auv == 1 and c.state.i == 1
    centres, r_avoid = domains(DEEP_SURFACE, c.domain)
    gap = np.hypot(*(np.asarray(cmd.waypoint) - centres).T) - r_avoid
    # eq. 12 alone would give (-5, 0): outside the surface AUV's domain by delta_r but 5 m
    # from the deep AUV, inside its 21.8 m domain; S2 keeps delta_r clear of both
    assert np.all(gap >= c.domain.delta_r - 1e-9), gap
    assert gap[1] < c.domain.delta_r + 20.0  # and it stays near the target circle


def test_eq12_point_kept_when_clear_of_the_other_domains():
    """S2 changes nothing when eq. 12's point is clear (the AUVs are far apart)."""
    c = ctrl()
    cmd = c.step(obs_at(0.0, (10.0, 0.0), AUVS))
    r_t = float(c.domain.target(0.0))
    assert cmd.waypoint == pytest.approx((r_t, 0.0))


close_auvs = st.lists(
    st.tuples(st.floats(-60.0, 60.0), st.floats(-60.0, 60.0), st.floats(0.0, 60.0)),
    min_size=2, max_size=4,
)  # fmt: skip
asv_walk = st.lists(
    st.tuples(st.floats(-90.0, 90.0), st.floats(-90.0, 90.0), st.booleans()),
    min_size=1, max_size=25,
)  # fmt: skip


@settings(max_examples=300, deadline=None)
@given(auvs=close_auvs, walk=asv_walk, start_in_standby=st.booleans())
def test_inside_a_domain_the_next_command_leaves_every_domain(auvs, walk, start_in_standby):
    """Issue 14 property: AUVs close together at mixed depths, random ASV positions. Whenever
    the ASV is inside some AUV's anti-collision domain, the command is an avoidance transit
    serving the deepest breach, to a waypoint >= delta_r outside every domain (so never a
    standby inside a domain). Standby is commanded only outside every domain."""
    c = ctrl_n(len(auvs))
    if start_in_standby:
        c.state = dataclasses.replace(c.state, q=Q1, tau=c.params.T_standby)
    centres, r_avoid = domains(auvs, c.domain)
    for t, (n, e, prop) in enumerate(walk):
        cmd = c.step(obs_at(float(t), (n, e), auvs, propeller_on=prop))
        r = np.hypot(n - centres[:, 0], e - centres[:, 1])
        inside = r < r_avoid
        if not np.any(inside):
            continue
        assert cmd.mode is Mode.TRANSIT and cmd.reason is Reason.AVOIDANCE
        assert cmd.auv == int(np.argmin(np.where(inside, r - r_avoid, np.inf)))
        wp = np.asarray(cmd.waypoint)
        gap = np.hypot(*(wp - centres).T) - r_avoid
        assert np.all(gap >= c.domain.delta_r - 1e-6), (wp, gap)


@settings(max_examples=60, deadline=None)
@given(auvs=close_auvs, n=st.floats(-90.0, 90.0), e=st.floats(-90.0, 90.0),
       kind=st.sampled_from(["uncertainty", "reachable"]))  # fmt: skip
def test_inside_an_uncertainty_aware_domain_the_waypoint_leaves_every_domain(auvs, n, e, kind):
    """S1/S2 with the issue-8 domains (discs grown by the uncertainty; reach-set polygons):
    inside any domain, the waypoint is outside every domain, >= delta_r outside the others."""
    from mpcasv.hybrid.avoidance import estimate_shape

    c = make_controller("hybrid-multi", len(auvs), "paper2-field",
                        overrides={"avoidance.kind": kind})  # fmt: skip
    c.reset(len(auvs))
    obs = obs_at(0.0, (n, e), auvs)
    cmd = c.step(obs)
    shape = estimate_shape(c.params.avoidance, c.domain, obs.auvs, 0.0)
    if not np.any(shape.inside(np.array([n, e]))):
        return
    assert cmd.mode is Mode.TRANSIT and cmd.reason is Reason.AVOIDANCE
    sd = shape.signed_distance(np.asarray(cmd.waypoint))
    # the served AUV's target circle is delta_r out along the bearing (eq. 6), which for a
    # polygon is a signed distance between 0 and delta_r; every other domain >= delta_r
    assert sd[cmd.auv] > 0.0
    assert np.all(np.delete(sd, cmd.auv) >= c.domain.delta_r - 1e-6), sd
