"""The manoeuvring envelope bounds the explicit integrators' steps (mpcasv.models.envelope).

Fossen's Otter (../shared/cases/vessels/otter.toml, case mpc-ignores-scenario-vessel; and
the shipped ``otter``) is slow straight ahead (3.6 1/s) but stiff in a full-steering turn
(16.5-18 1/s: its quadratic yaw damping ``N_rr |r| r``). The plan's sub-steps were chosen from
the straight-line trims only (6 for the Otter): a turning stage returned NaN, fatrop met the
NaNs and hung (`mpcasv simulate case3-otter.toml --controller mpc-single`: 29 of 40 s in
10 min, hundreds of CasADi NaN warnings).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from shared_data import CASES

from mpcasv.controllers import Boat, load_preset
from mpcasv.estimation.current import CurrentObserver, MotionMeasurement
from mpcasv.models import envelope
from mpcasv.models.acoustics import AcousticParams
from mpcasv.models.vessel import VesselModel
from mpcasv.mpc.problem import NXV, OCP, channel_vector

CASE_OTTER = CASES / "vessels" / "otter.toml"
VESSELS = ["gretha", "dune-otter", "otter",
           pytest.param(str(CASE_OTTER), id="case-otter",
                        marks=pytest.mark.skipif(not CASE_OTTER.exists(),
                                                 reason=f"{CASE_OTTER} not present"))]  # fmt: skip


def _ocp(vessel: str, steering: str = "auto") -> OCP:
    P = load_preset("mpc-single", "mpc-single", {"horizon.steering": steering})
    return OCP(P, 1, outer=True, boat=Boat.load(vessel))


def test_a_full_steering_turn_is_part_of_the_envelope():
    """The Otter's fastest pole is in its turns, not on its straight line; Gretha's is close
    to her straight-line one (2.7 against 2.4 1/s, so her plan keeps 4 sub-steps)."""
    otter, gretha = VesselModel(Boat.load("otter").vessel), VesselModel(Boat.load("gretha").vessel)
    assert otter.fastest_trim_pole == pytest.approx(3.63, abs=0.01)
    assert otter.fastest_pole > 4 * otter.fastest_trim_pole
    assert gretha.fastest_trim_pole <= gretha.fastest_pole < 1.2 * gretha.fastest_trim_pole
    assert _ocp("gretha").n_sub == 4 and _ocp("dune-otter").n_sub == 4


@pytest.mark.parametrize("vessel", VESSELS)
def test_the_plans_stage_follows_a_fine_integration_through_full_steering_turns(vessel):
    """``OCP.F`` (the plan's stage, rates zero) from states of the envelope's full-steering
    turns against the shared model integrated in 0.02-s RK4 steps: finite and close. With the
    Otter's sub-steps chosen from its straight-line trims (6) the same stages are NaN."""
    ocp = _ocp(vessel, "rudder")
    model = ocp.model
    fine = model.rk4(ocp.dt, round(ocp.dt / 0.02))
    ch = channel_vector(AcousticParams())
    nav = ocp.F.size1_in(2) - (2 + 7 + len(ch))
    q = np.r_[0.0, 0.0, 300.0, 0.0, 0.0, 0.0, 0.0, 0.0, 70.0, ch, np.zeros(nav)]
    old = model.rk4(ocp.dt,
                   max(4, math.ceil(ocp.dt * model.fastest_trim_pole / envelope.RK4_LAMBDA_H)))
    errs, old_bad = [], 0
    for x in np.vstack([envelope.trim_states(model), envelope.turn_states(model)])[::6]:
        x = np.r_[0.0, 0.0, x[2:]]
        got = np.asarray(ocp.F(np.r_[x, 100.0], [0.0, 0.0], q)).ravel()[:NXV]
        ref = np.asarray(fine(x, x[6:8], [0.0, 0.0])).ravel()
        assert np.all(np.isfinite(got))
        errs.append(np.abs(got - ref))
        o = np.asarray(old(x, x[6:8], [0.0, 0.0])).ravel()
        old_bad += int(not np.all(np.isfinite(o)) or np.abs(o - ref)[3:6].max() > 0.1)
    err = np.max(errs, axis=0)
    # Gretha's 4 sub-steps in a turn from top speed: 0.013 rad/s; the Otter's 26: 2e-4 m
    assert err[0:2].max() < 0.05 and err[2:6].max() < 0.02, err  # m; rad, m/s, rad/s
    assert np.all(ocp.dt / ocp.n_sub * model.fastest_pole < envelope.RK4_STABLE)
    assert (old_bad > 0) == ("otter" in vessel and "dune" not in vessel), old_bad


def test_the_plant_integrates_a_stiff_hull_in_sub_steps_of_a_long_plant_step():
    """The simulator's plant step takes RK4 sub-steps from the same envelope: one for every
    shipped vessel at the default 0.1 s; the Otter at 0.2 s takes two, where single RK4 steps
    (|lambda h| = 3.3, outside RK4's stability bound) end a full-steering turn from top speed
    0.2 m/s and 0.4 rad/s off (the quadratic damping keeps it from diverging)."""
    otter = VesselModel(Boat.load("otter").vessel)
    assert envelope.rk4_sub_steps(VesselModel(Boat.load("gretha").vessel), 0.1) == 1
    assert envelope.rk4_sub_steps(otter, 0.1) == 1
    assert envelope.rk4_sub_steps(otter, 0.2) == 2
    P = otter.params
    u = [P.T_max, P.delta_max]
    fine, one, two = otter.rk4(0.2, 20), otter.rk4(0.2, 1), otter.rk4(0.2)
    x_f = x_1 = x_2 = otter.trim(otter.top_speed * 0.999)[0]
    for _ in range(150):  # 30 s
        x_f = np.asarray(fine(x_f, u, [0, 0])).ravel()
        x_1 = np.asarray(one(x_1, u, [0, 0])).ravel()
        x_2 = np.asarray(two(x_2, u, [0, 0])).ravel()
    assert np.abs(x_2 - x_f)[3:6].max() < 0.01
    assert not np.all(np.isfinite(x_1)) or np.abs(x_1 - x_f)[3:6].max() > 0.1


def test_the_simulators_closed_loop_takes_those_sub_steps(monkeypatch):
    """``closed_loop`` (the simulator's plant with the execution level, 5 plant steps of 0.2
    s) for the Otter at top speed sent to a waypoint behind it (full steering): its states
    over 30 s against the same loop with 20 sub-steps per plant step: 0.05 off in u, v, r
    (the sub-steps it takes, 2); with one sub-step 0.42 off."""
    from mpcasv.control import execution
    from mpcasv.control.params import load_execution

    otter, ep = VesselModel(Boat.load("otter").vessel), load_execution("gretha")
    cmd = np.array([1.0, -200.0, 60.0, 3.0])  # transit to (-200, 60) m at 3 m/s

    def run(k):
        with monkeypatch.context() as m:
            if k is not None:
                m.setattr(execution, "rk4_sub_steps", lambda model, dt: k)
            CL = execution.closed_loop(otter, ep, 0.2, 5)
        x, z, X = otter.trim(otter.top_speed * 0.999)[0], np.zeros(execution.NZ), []
        for _ in range(30):
            out = CL(x, z, cmd, [0.0, 0.0])
            x, z = np.asarray(out[0]).ravel(), np.asarray(out[1]).ravel()
            X.append(x)
        return np.array(X)

    fine, auto, one = run(20), run(None), run(1)
    assert np.abs(fine[:, 7]).max() == pytest.approx(otter.params.delta_max, rel=1e-3)
    err_auto, err_one = np.abs(auto - fine)[:, 3:6].max(), np.abs(one - fine)[:, 3:6].max()
    assert err_auto < 0.1 and err_one > 4 * err_auto, (err_auto, err_one)


def test_the_current_observer_follows_a_stiff_hull_through_a_full_steering_turn():
    """The current observer's motion model (C1) takes its RK4 sub-steps from the envelope too:
    the Otter turning at full steering from top speed in still water, observed once a second
    with its actuators known, gives a finite current estimate, near zero after 10 s. With
    sub-steps of 0.5 s only (``h_max``) its prediction went NaN and the update raised
    "Singular matrix" (the MPC's run of case3-otter with a 1-s horizon stage crashed on it)."""
    otter = VesselModel(Boat.load("otter").vessel)
    assert envelope.rk4_sub_steps(otter, 1.0, lags=False) > 2  # more than h_max = 0.5 s gives
    P = otter.params
    u = [P.T_max, P.delta_max]
    F = otter.rk4(1.0)
    obs = CurrentObserver(otter)
    x = otter.trim(otter.top_speed * 0.999)[0]
    for k in range(60):
        c = obs.update(MotionMeasurement(float(k), x[2], x[3], x[4], x[5], True,
                                         (float(x[6]), float(x[7]))))  # fmt: skip
        assert np.all(np.isfinite(c)), k
        if k >= 10:  # after the first seconds' actuator transient (0.13 m/s at 1 s)
            assert np.hypot(*c) < 0.03, (k, c)
        x = np.asarray(F(x, u, [0.0, 0.0])).ravel()


def test_the_mpc_says_once_that_it_steers_a_straight_line_unstable_hull_open_loop(monkeypatch):
    """Fossen's Otter has no linear sway damping: straight-line unstable at every speed (up to
    +2.6 1/s). Planned with its steering angle (``steering = "rudder"``) the MPC steers it
    open loop over 4-s stages and does not hold it (docs/mpc.md, Known problems): building
    such an MPC says so in one line, once per vessel. By default (``"auto"``) the plan closes
    the yaw loop for it (M1h, tests/test_mpc_heading.py) and nothing is said; Gretha and
    dune-otter are course-stable and nothing is said either."""
    import io

    from mpcasv.mpc import dynamics

    monkeypatch.setattr(dynamics, "_WARNED", set())
    assert envelope.course_instability(VesselModel(Boat.load("gretha").vessel)) is None
    assert envelope.course_instability(VesselModel(Boat.load("dune-otter").vessel)) is None
    u, lam = envelope.course_instability(VesselModel(Boat.load("otter").vessel))
    assert u < 0.3 and lam == pytest.approx(2.61, abs=0.01)
    out = io.StringIO()
    dynamics.warn_course_unstable(_ocp("otter"), file=out)
    assert out.getvalue() == ""  # "auto": the plan closes the yaw loop (M1h)
    for vessel in ("gretha", "dune-otter", "otter", "otter"):
        dynamics.warn_course_unstable(_ocp(vessel, "rudder"), file=out)
    lines = out.getvalue().splitlines()
    assert len(lines) == 1 and "'otter' is straight-line unstable" in lines[0], lines
    assert "+2.6 1/s" in lines[0] and "4-s stages" in lines[0]
