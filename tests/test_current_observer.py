"""The on-board current observer (mpcasv/estimation/current.py, issue 16 item 1): driven by the
simulated World's observations while the ASV alternates transits (propeller on) and standby
(drifting), it converges to a constant current, tracks a step, and is zero-mean in still
water; it is deterministic."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mpcasv.control.execution import NCMD
from mpcasv.estimation.current import (
    CurrentObserver,
    MotionMeasurement,
    _segments,
    measurement,
    measurement_from_estimated_state,
)
from mpcasv.sim.scenario import scenario_from_dict
from mpcasv.sim.world import World

#: transit legs (waypoints N, E; m) and standby in turn, 150 s each
LEGS = ((400.0, 0.0), (400.0, 400.0), (0.0, 400.0), (0.0, 0.0))


def scenario(duration: float, **top) -> dict:
    """The ASV at the origin, one AUV far away at depth (it plays no part)."""
    return {"name": "obs", "duration": duration,
            "auv": [{"name": "a", "start": {"N": 3000.0, "depth": 40.0},
                     "behaviour": {"transit": {"heading_deg": 0.0, "speed": 1.0,
                                               "depth": 40.0}}}],
            "asv": {"start": {"N": 0.0, "E": 0.0}}} | top  # fmt: skip


def held_world(data: dict) -> World:
    """The World of ``data`` with the ASV held at rest over ground at the start (through the
    water it moves against the current). The simulator starts it carried by the current
    (since session 34); these tests are of an observer that must find a current the boat
    does not yet move with, the harder start."""
    w = World(scenario_from_dict(data), seed=0)
    w.x[3:6] = 0.0  # u, v, r over ground
    return w


def drive(data: dict, noise: float = 0.0, seed: int = 0, period: float = 150.0,
          samples: bool = True):
    """Run the World for the scenario's duration, transit (2 m/s to the next leg's waypoint)
    and standby alternating every ``period`` s; the observer takes every observation (with
    white noise of ``noise`` m/s on the measured velocities, seeded; without the actuators'
    samples through the period unless ``samples``), from the ASV held at rest over ground
    (:func:`held_world`). Returns (t, estimate (n x 2), true current at the ASV (n x 2),
    propeller on (n,))."""
    w = held_world(data)
    ob = CurrentObserver(w.model)
    rng = np.random.default_rng(seed)
    out_t, est, truth, prop = [], [], [], []
    leg = 0
    for k in range(int(data["duration"])):
        m = measurement(w.observation())
        if noise or not samples:
            du, dv = noise * rng.standard_normal(2) if noise else (0.0, 0.0)
            m = MotionMeasurement(m.t, m.psi, m.u + du, m.v + dv, m.r, m.propeller_on,
                                  m.actuators, m.actuator_samples if samples else None)
        out_t.append(m.t)
        est.append(ob.update(m))
        truth.append(w.current_at_asv())
        prop.append(m.propeller_on)
        phase = int(k // period)
        cmd = np.zeros(NCMD)
        if phase % 2 == 0:
            leg = (phase // 2) % len(LEGS)
            cmd = np.array([1.0, *LEGS[leg], 2.0])
        w.advance(cmd)
    return np.array(out_t), np.array(est), np.array(truth), np.array(prop)


def test_converges_to_a_constant_current_with_the_propeller_on_and_off():
    t, est, truth, prop = drive(scenario(900.0, current=[0.12, -0.1]))
    err = np.hypot(*(est - truth).T)
    assert prop.any() and (~prop).any()  # both regimes are in the run
    late = t >= 120.0
    assert err[late].max() < 0.01  # within 1 cm/s after 2 minutes, in both regimes
    assert err[late & prop].max() < 0.01 and err[late & ~prop].max() < 0.01
    assert err[0] > 0.15  # it starts at zero: the convergence is the observer's work


def test_converges_with_noisy_velocities():
    """GNSS-like white noise (0.05 m/s per axis, seeded): the error after convergence stays
    within 0.03 m/s (the filter's own 1-sigma is about 0.015-0.03 m/s)."""
    t, est, truth, _ = drive(scenario(900.0, current=[0.12, -0.1]), noise=0.05, seed=1)
    err = np.hypot(*(est - truth).T)
    assert np.sqrt(np.mean(err[t >= 200.0] ** 2)) < 0.03


def test_tracks_a_step_in_the_current():
    """0.15 m/s East from t = 400 s on (a step between two knots 1 s apart): within 0.02 m/s of
    the new current 120 s after the step."""
    data = scenario(800.0, current=[0.0, 0.0], current_field={
        "knots": [[400.0, 0.0, 0.0], [401.0, 0.0, 0.15]], "auv_factor": 0.0})  # fmt: skip
    t, est, truth, _ = drive(data)
    assert truth[-1] == pytest.approx([0.0, 0.15])
    err = np.hypot(*(est - truth).T)
    assert err[(t > 300.0) & (t < 400.0)].max() < 0.01  # before: still water, found
    assert err[(t > 401.0) & (t < 410.0)].max() > 0.1  # the step is news to it
    assert err[t >= 521.0].max() < 0.02


@pytest.mark.parametrize("noise", [0.0, 0.05])
def test_zero_mean_in_still_water(noise):
    t, est, truth, _ = drive(scenario(900.0), noise=noise, seed=2)
    assert np.all(truth == 0.0)
    late = est[t >= 120.0]
    assert np.abs(late.mean(axis=0)).max() < 0.005
    # noise-free: the model is the plant's and the actuators' samples are the plant steps'
    # (0.1 mm/s; from the period's two ends alone, transients of up to 7 mm/s when the thrust
    # changed within a period)
    tol = 0.001 if noise == 0.0 else 0.03
    assert np.abs(late).max() < tol


@pytest.mark.parametrize("current", [(0.0, 0.0), (0.12, -0.1)])
def test_an_otter_steering_hard_within_its_periods_is_not_read_as_a_current(current):
    """Fossen's Otter (course-unstable) flips its steering between about +-0.44 rad from one
    1-s period to the next in a transit: the observer given the actuators at the period's two
    ends only held their mean, near 0, and read the turns as a current of up to 0.52 m/s
    (a tester's pursuer scenario, session 45: 0.49 m/s in still water); through the plant
    steps' samples it is within 3 mm/s (session 46)."""
    data = scenario(600.0, current=list(current))
    data["asv"]["vessel"] = "otter"
    for samples, lo, hi in ((True, 0.0, 0.005), (False, 0.3, math.inf)):
        t, est, truth, prop = drive(data, samples=samples)
        assert prop.any() and (~prop).any()
        err = np.hypot(*(est - truth).T)[t >= 120.0]
        assert lo < err.max() < hi, (samples, err.max())


def test_deterministic_and_refuses_bad_input():
    data = scenario(300.0, current=[0.1, 0.05])
    a = drive(data, noise=0.05, seed=3)[1]
    b = drive(data, noise=0.05, seed=3)[1]
    assert np.array_equal(a, b)
    ob = CurrentObserver(World(scenario_from_dict(data)).model)
    ob.update(MotionMeasurement(10.0, 0.0, 1.0, 0.0, 0.0, False))
    with pytest.raises(ValueError, match="time went back"):
        ob.update(MotionMeasurement(9.0, 0.0, 1.0, 0.0, 0.0, False))
    with pytest.raises(ValueError, match="non-finite"):
        ob.update(MotionMeasurement(11.0, 0.0, math.nan, 0.0, 0.0, False))
    ob.update(MotionMeasurement(11.0, 0.0, 1.0, 0.0, 0.0, True, (10.0, 0.0),
                                ((10.0, 10.0, 0.0), (11.0, 10.0, 0.0))))  # fmt: skip
    early = ((10.5, 10.0, 0.0), (12.0, 10.0, 0.0))  # from before the previous measurement
    with pytest.raises(ValueError, match="do not lie in time order between"):
        ob.update(MotionMeasurement(12.0, 0.0, 1.0, 0.0, 0.0, True, (10.0, 0.0), early))
    backwards = ((11.8, 10.0, 0.0), (11.2, 10.0, 0.0))
    with pytest.raises(ValueError, match="do not lie in time order between"):
        ob.update(MotionMeasurement(12.0, 0.0, 1.0, 0.0, 0.0, True, (10.0, 0.0), backwards))
    with pytest.raises(ValueError, match="non-finite actuator samples"):
        ob.update(MotionMeasurement(12.0, 0.0, 1.0, 0.0, 0.0, True, (10.0, 0.0),
                                    ((11.0, 10.0, 0.0), (12.0, math.inf, 0.0))))  # fmt: skip


def test_samples_inside_the_interval_run_to_the_measurements_actuators_at_its_ends():
    """Samples that do not reach the interval's ends: the signal is linear from the previous
    measurement's actuators at its time, through the samples, to this measurement's at its
    time; the same prediction as those two written out as samples, another than either end
    held (the last sample's held to the end ignored this measurement's actuators before
    session 47), and a held source written as two samples per change is held."""
    model = World(scenario_from_dict(scenario(10.0))).model

    def predicted(samples, ends=(0.0, 0.0)):
        ob = CurrentObserver(model)
        ob.update(MotionMeasurement(0.0, 0.0, 1.0, 0.0, 0.0, True, (50.0, 0.0)))
        ob.update(MotionMeasurement(1.0, 0.0, 1.0, 0.0, 0.0, True, ends, samples))
        return ob.s.copy()

    inside = ((0.3, 200.0, 0.2), (0.6, 200.0, 0.2))
    ends = (300.0, 0.3)
    full = ((0.0, 50.0, 0.0), *inside, (1.0, *ends))
    np.testing.assert_array_equal(predicted(inside, ends), predicted(full, ends))
    last_held = ((0.0, 50.0, 0.0), *inside, (1.0, 200.0, 0.2))
    assert not np.allclose(predicted(inside, ends), predicted(last_held, ends), atol=1e-9)
    first_held = ((0.0, 200.0, 0.2), *inside, (1.0, *ends))
    assert not np.allclose(predicted(inside, ends), predicted(first_held, ends), atol=1e-9)
    assert not np.allclose(predicted(inside, ends), predicted(None, ends))
    held = ((0.0, 50.0, 0.0), (0.3, 50.0, 0.0), (0.3, 200.0, 0.2), (1.0, 200.0, 0.2))
    steps = _segments(MotionMeasurement(0.0, 0.0, 1.0, 0.0, 0.0, True, (50.0, 0.0)),
                      MotionMeasurement(1.0, 0.0, 1.0, 0.0, 0.0, True, None, held))
    assert [(round(h, 9), tuple(a)) for h, a in steps] == [(0.3, (50.0, 0.0)),
                                                           (0.7, (200.0, 0.2))]


def test_drifting_without_actuator_feedback_still_finds_the_current():
    """Deploy without thruster feedback (actuators None): while the propeller runs the motion
    says nothing (q_blind), while drifting it does."""
    data = scenario(600.0, current=[-0.1, 0.1])
    w = held_world(data)
    ob = CurrentObserver(w.model)
    for k in range(600):
        m = measurement(w.observation())
        ob.update(MotionMeasurement(m.t, m.psi, m.u, m.v, m.r, m.propeller_on, None))
        on = k < 150 or 300 <= k < 450
        w.advance(np.array([1.0, 400.0, 400.0, 2.0]) if on else np.zeros(NCMD))
        if k == 149:
            blind = ob.current.copy()
    assert np.hypot(*(blind - [-0.1, 0.1])) > 0.05  # a transit alone did not teach it
    assert ob.current == pytest.approx([-0.1, 0.1], abs=0.01)  # the drifts did


def test_estimated_state_measurement_rotates_the_ground_velocity_into_body_axes():
    m = measurement_from_estimated_state(5.0, math.pi / 2, vx=0.3, vy=1.5, r=0.01,
                                         propeller_on=True, thrust=120.0, delta=0.1)
    assert (m.u, m.v) == pytest.approx((1.5, -0.3))
    assert m.actuators == (120.0, 0.1)
    partial = measurement_from_estimated_state(5.0, 0.0, 1.0, 0.0, 0.0, True, thrust=120.0)
    assert partial.actuators is None  # steering unknown: actuators unknown


# The start (C0): how the first ground velocity splits between the boat's motion through the
# water and the current is not known. Before session 30 the observer took it as known (all
# through the water, to within sigma_v) and only the slow random walk of the current could
# move it: the convergence times below were 120-200 s and more.

def settle_time(t: np.ndarray, est: np.ndarray, c: np.ndarray) -> float:
    """The time (s) after which the estimate stays within 10 % of the current ``c`` (at least
    0.03 m/s); ``inf`` if it is not there at the end."""
    err = np.hypot(*(est - c).T)
    bad = np.nonzero(err > max(0.1 * np.hypot(*c), 0.03))[0]
    if len(bad) and bad[-1] == len(t) - 1:
        return math.inf
    return float(t[bad[-1] + 1] - t[0]) if len(bad) else 0.0


def observe(c, cmd, duration: int, start: int = 0, blind: bool = False):
    """The World in the constant current ``c`` from the ASV at rest over ground
    (:func:`held_world`), commanded ``cmd(k)`` each second; a new observer takes the
    observations from second ``start`` on (without the actuators' values if ``blind``).
    Returns (t, estimate (n x 2))."""
    w = held_world(scenario(float(duration), current=list(c)))
    ob = CurrentObserver(w.model)
    t, est = [], []
    for k in range(duration):
        if k >= start:
            m = measurement(w.observation())
            if blind:
                m = MotionMeasurement(m.t, m.psi, m.u, m.v, m.r, m.propeller_on, None)
            t.append(m.t)
            est.append(ob.update(m))
        w.advance(cmd(k))
    return np.array(t), np.array(est)


CURRENTS = ([0.15, 0.0], [0.0, 0.5], [1.0, 0.0], [2.0, 0.0], [-1.4, 1.4])
STANDBY = staticmethod(lambda k: np.zeros(NCMD))
TRANSIT = staticmethod(lambda k: np.array([1.0, 400.0, 400.0, 2.0]))


@pytest.mark.parametrize("c", CURRENTS)
def test_a_drifting_boat_finds_the_current_within_seconds(c):
    """A boat drifting with the water (propeller off, its ground velocity the current, heading
    0.3 rad): within 10 % after at most 5 s (measured 0 s: the prior centres the drifting
    boat's speed through the water on zero; before: 121-200 s and more)."""
    ob = CurrentObserver(World(scenario_from_dict(scenario(10.0))).model)
    psi = 0.3
    rot = np.array([[math.cos(psi), math.sin(psi)], [-math.sin(psi), math.cos(psi)]])
    u, v = rot @ np.asarray(c)  # NED -> body
    t = np.arange(120.0)
    est = np.array([ob.update(MotionMeasurement(tk, psi, u, v, 0.0, False, (0.0, 0.0)))
                    for tk in t])  # fmt: skip
    assert settle_time(t, est, np.asarray(c)) <= 5.0


@pytest.mark.parametrize("c", CURRENTS)
def test_a_boat_started_at_rest_over_ground_finds_the_current(c):
    """A start at rest over ground (:func:`held_world`, propeller off: through the water it moves
    against the current, and the drag carries it away): standing by, within 10 % after at
    most 25 s (measured 1-20 s, the longest for 0.15 m/s; before: 14-200 s and more);
    transiting from the start, within 20 s (1-10 s; before 12-40 s)."""
    c = np.asarray(c)
    assert settle_time(*observe(c, STANDBY, 120), c) <= 25.0
    assert settle_time(*observe(c, TRANSIT, 120), c) <= 20.0


@pytest.mark.parametrize("c", [[0.0, 0.0], [0.5, -0.5]])
def test_an_observer_started_under_way_takes_the_ground_velocity_as_the_boats_own(c):
    """Started 60 s into a transit (propeller on, 2 m/s): with the actuators known the current
    is found within 20 s; without them (a deploy without thruster feedback) the motion says
    nothing while the propeller runs, and the estimate must stay at the prior's zero, not take
    part of the boat's own 2 m/s for a current."""
    c = np.asarray(c)
    t, est = observe(c, TRANSIT, 180, start=60)
    assert settle_time(t, est, c) <= 20.0
    _, est = observe(c, TRANSIT, 180, start=60, blind=True)
    assert np.abs(est).max() < 0.02


@pytest.mark.parametrize("c", CURRENTS)
def test_the_start_does_not_overshoot_the_current(c):
    """After the first sample the estimate's speed stays within 0.35 m/s of the current's,
    standing by and transiting from a start at rest over ground (measured: at most 0.24 m/s;
    with the prior's sigma_nu0 = 1 m/s up to 1.8 m/s, which the MPC met with hung solves)."""
    c = np.asarray(c)
    for cmd in (STANDBY, TRANSIT):
        t, est = observe(c, cmd, 60)
        over = np.hypot(*est.T)[t >= 2.0] - np.hypot(*c)
        assert over.max() <= 0.35, f"{over.max():.2f} m/s above the current's speed"


def test_a_scenario_can_give_the_actuators_at_the_period_ends_only():
    """``[sim] actuator_samples = false``: the observation carries the actuators at the
    period's ends only, as ``mpcasv deploy`` gives them (the field's path, to simulate)."""
    for flag in (True, False):
        w = World(scenario_from_dict(scenario(5.0, sim={"actuator_samples": flag})))
        assert w.observation().actuator_samples is None  # none before the first period
        w.advance(np.array([1.0, 400.0, 0.0, 2.0]))
        smp = w.observation().actuator_samples
        assert (smp is None) is (not flag)
        if flag:
            assert len(smp) == w.n_sub + 1 and smp[0][0] == 0.0 and smp[-1][0] == w.t
            assert smp[-1][1:] == w.observation().actuators
