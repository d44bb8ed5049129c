"""AUV kinematics and behaviours follow their plans within tolerance and respect limits."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mpcasv.models.auv import AUVLimits, auv_step_function
from mpcasv.models.behaviours import Plan, Pursuer, Scripted, Transit, lawnmower

DEFAULT_LIMITS = AUVLimits()


def drive(behaviour, s0, seconds, limits=DEFAULT_LIMITS, asv=lambda t: np.zeros(2), period=1.0,
          current=None):
    """Run one AUV with a behaviour; return times and states (5 x n) at 0.1 s. ``current``
    ``(V_N, V_E)`` (m/s): a water current carrying the AUV (None: still water)."""
    step = auv_step_function(0.1, int(period / 0.1), 1, drift=current is not None)
    drift = () if current is None else (np.reshape(np.asarray(current, float), (2, 1)),)
    S = np.asarray(s0, float).reshape(5, 1)
    lim = limits.vector().reshape(4, 1)
    out, t = [S[:, 0].copy()], 0.0
    for _ in range(int(seconds / period)):
        sp = np.array(behaviour.setpoint(t, S[:, 0], asv(t)), float).reshape(4, 1)
        S, traj = step(S, sp, lim, *drift)
        S = np.array(S)
        out.extend(np.array(traj).T)
        t += period
    return np.array(out).T


def test_lawnmower_geometry():
    wp = lawnmower((0, 0), 0.0, 100.0, 20.0, 3, depth=5.0)
    assert wp.shape == (6, 3)
    assert np.allclose(wp[:, 2], 5.0)
    legs = np.hypot(*(wp[1::2, :2] - wp[::2, :2]).T)
    assert np.allclose(legs, 100.0)
    assert np.allclose(wp[:, 1], [0, 0, 20, 20, 40, 40])  # stepping right (East) of North


def test_waypoint_plan_visits_every_waypoint_within_acceptance():
    wp = lawnmower((0, 0), 30.0, 150.0, 40.0, 4, depth=10.0)
    plan = Plan(wp, speed=1.5, acceptance=5.0)
    S = drive(plan, [0, 0, 0, math.radians(30), 0], 900)
    for w in wp:
        assert np.min(np.hypot(S[0] - w[0], S[1] - w[1])) < 5.0 + 0.2
    assert plan.finished
    assert S[4].max() <= 1.5 + 1e-9
    assert abs(S[2, -1] - 10.0) < 0.5


@pytest.mark.parametrize("period", [1.0, 20.0])
def test_lawnmower_tighter_than_the_turn_radius_is_followed_to_its_end(period):
    """Legs 10 m apart, turn radius 1.5 m/s / 10 deg/s = 8.6 m, acceptance 5 m: the AUV
    cannot turn into the next corner's circle of acceptance. After a full circle going for
    it, it moves on and finishes the plan (before, it circled the fourth corner for the rest
    of the run: session 38's sweep, five AUVs on lawnmowers 10 m apart). With set-points
    every second and every 20 s (more than a half turn of heading between two)."""
    wp = lawnmower((0, 0), 0.0, 100.0, 10.0, 6)
    plan = Plan(wp, speed=1.5, acceptance=5.0)
    S = drive(plan, [0, 0, 0, 0, 0], 900, period=period)
    assert plan.finished
    # every corner passed close: within the turn's diameter plus the acceptance
    r_turn = 1.5 / math.radians(DEFAULT_LIMITS.turn_rate_max_deg)
    for w in wp:
        assert np.min(np.hypot(S[0] - w[0], S[1] - w[1])) < 2 * r_turn + 5.0
    # the whole route (650 m) in well under twice its time at 1.5 m/s
    done = np.argmax(np.hypot(S[0] - wp[-1, 0], S[1] - wp[-1, 1]) < 5.0) * 0.1
    assert 0 < done < 2 * 650.0 / 1.5


@pytest.mark.parametrize("current", [(0.9, 0.5), (1.2, 0.3), (0.7, 0.7), (0.0, -1.0)])
def test_waypoints_reached_across_a_current_are_not_skipped(current):
    """A square route in a current of up to 1.2 m/s (the AUV 1.5 m/s): each corner is
    reached within the circle of acceptance, as without the full-circle rule (a rule
    switching on the line normal to the track, tried first, skipped corners 16-34 m off:
    the current carries a pure-pursuit AUV across that line before the corner)."""
    wp = np.array([[100.0, 0, 0], [100.0, 100, 0], [0.0, 100, 0], [0.0, 0, 0]])
    plan = Plan(wp, speed=1.5, acceptance=5.0)
    S = drive(plan, [0, 0, 0, 0, 0], 1500, current=current)
    assert plan.finished
    for w in wp:
        assert np.min(np.hypot(S[0] - w[0], S[1] - w[1])) < 5.0 + 0.3


def test_a_waypoint_behind_is_reached_not_skipped():
    """A waypoint behind the AUV (a half turn and more) and one across a sharp turn are
    reached within the circle: less than a full circle of heading."""
    plan = Plan([[-60.0, 0, 0], [100.0, 0, 0], [88.0, 3.0, 0], [138.0, 53.0, 0]], speed=1.5)
    S = drive(plan, [0, 0, 0, 0, 0], 900)
    assert plan.finished
    for w in plan.waypoints:
        assert np.min(np.hypot(S[0] - w[0], S[1] - w[1])) < 5.0 + 0.2


def test_a_plan_resumed_after_a_pause_goes_back_for_its_waypoint():
    """A loiter of 150 s away from the plan's first waypoint, then the plan resumes: the
    AUV goes back for the waypoint it had not reached (the turn is counted afresh after the
    pause, not across it)."""
    from mpcasv.models.behaviours import Loiter, Pause

    plan = Plan([[100.0, 0, 0], [100.0, 100, 0], [0.0, 100, 0]], speed=1.5)
    beh = Scripted(plan, [(20.0, Pause(Loiter(at=(130.0, 40.0)), 150.0))])
    S = drive(beh, [0, 0, 0, 0, 0], 600)
    assert plan.finished
    for w in plan.waypoints:
        assert np.min(np.hypot(S[0] - w[0], S[1] - w[1])) < 5.0 + 0.2


def test_limits_are_respected():
    lim = AUVLimits(speed_max=2.0, turn_rate_max_deg=10.0, depth_rate_max=0.5, accel_max=0.2)
    plan = Plan([[0, -200, 40], [200, 0, 0]], speed=2.0)
    S = drive(plan, [0, 0, 0, 0, 0], 400, lim)
    dt = 0.1
    assert S[4].max() <= 2.0 + 1e-9
    assert np.abs(np.diff(S[4])).max() <= 0.2 * dt + 1e-9
    assert np.abs(np.diff(S[2])).max() <= 0.5 * dt + 1e-9
    dpsi = np.angle(np.exp(1j * np.diff(S[3])))
    assert np.abs(dpsi).max() <= math.radians(10.0) * dt + 1e-9


def test_yoyo_stays_between_its_depths_and_reaches_both():
    plan = Plan([[2000, 0, 30]], speed=1.5, yoyo=(10.0, 50.0))
    S = drive(plan, [0, 0, 10, 0, 0], 900)
    d = S[2, 600:]
    assert d.min() >= 10.0 - 0.6 and d.max() <= 50.0 + 1e-9
    assert d.max() > 49.0 and d.min() < 11.0


def test_surface_interval_brings_the_auv_up():
    plan = Plan([[2000, 0, 30]], speed=1.5, surface=((200.0, 400.0),), surface_speed=0.5)
    S = drive(plan, [0, 0, 30, 0, 0], 500)
    i = int(390 / 0.1)
    assert S[2, i] < 0.5 and abs(S[4, i] - 0.5) < 0.05
    assert S[2, int(190 / 0.1)] > 29


def test_a_finished_plan_stays_stopped_through_a_surface_interval():
    """The plan "stops at the last" waypoint; a surface interval after that rose it and then
    drove it at surface_speed round the waypoint it had reached (38 m of circles in 40 s: a
    new user's scenario, session 44)."""
    plan = Plan([[30, 0, 20]], speed=1.5, surface=((60.0, 200.0),), surface_speed=1.0)
    S = drive(plan, [0, 0, 20, 0, 0], 200)
    during = slice(int(150 / 0.1), int(200 / 0.1))  # (risen by then)
    assert S[2, during].max() < 0.5  # at the surface
    assert np.abs(S[4, during]).max() < 0.05  # not moving
    assert np.hypot(*np.ptp(S[0:2, during], axis=1)) < 1.0


def test_transit_goes_straight():
    S = drive(Transit(heading_deg=60.0, speed=1.0, depth=5.0), [0, 0, 0, math.radians(60), 0], 200)
    bearing = math.degrees(math.atan2(S[1, -1], S[0, -1]))
    assert abs(bearing - 60.0) < 0.5
    assert abs(np.hypot(S[0, -1], S[1, -1]) - 200 * 1.0) < 15  # minus acceleration time


@pytest.mark.parametrize("period", [0.0, 20.0])
def test_pursuer_closes_on_the_asv(period):
    asv = lambda t: np.array([300.0, 100.0 + 0.5 * t])  # noqa: E731
    S = drive(Pursuer(speed=2.0, update_period=period), [0, 0, 0, 0, 0], 150, asv=asv)
    dist = np.hypot(S[0] - 300.0, S[1] - (100.0 + 0.5 * np.arange(S.shape[1]) * 0.1))
    assert dist[-1] < 0.2 * dist[0]


def test_scripted_switch_happens_at_the_given_time():
    beh = Scripted(Transit(0.0, 1.0), [(100.0, Transit(90.0, 1.0))])
    S = drive(beh, [0, 0, 0, 0, 1.0], 200)
    assert beh.switches == [100.0]
    i = int(99 / 0.1)
    assert abs(S[1, i]) < 1e-6 and S[1, -1] > 50  # East only after the switch
