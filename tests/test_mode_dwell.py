"""The MPC's dwell rule (``min_dwell``, docs/mpc.md "Mode dwell") and the chatter metrics
(``mode_switches_short``, ``propeller_toggles``): a commanded mode is kept ``min_dwell`` s
before the plan may change it, except a TRANSIT for AVOIDANCE, the escape manoeuvre and
fallback steps; the metrics count what a propulsion system would see."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from mpcasv.controllers import load_preset, make_controller
from mpcasv.experiments.metrics import SHORT_STAY_S, compute_metrics, short_switches
from mpcasv.interface import Command, Mode, Reason
from mpcasv.mpc.plan_output import PlanOutput
from mpcasv.sim.scenario import scenario_from_dict
from mpcasv.sim.simulator import simulate


def _out(min_dwell: float) -> PlanOutput:
    out = PlanOutput()
    out.params = load_preset("mpc-single", "mpc-single", {"min_dwell": min_dwell})
    out._diag = {}
    out.target = 0  # the controller's target (one AUV): the commands name it
    out._reset_dwell()
    return out


def test_a_mode_is_held_for_min_dwell_unless_an_auv_must_be_left():
    out = _out(5.0)
    assert not out._dwell(0.0, True, Reason.TRACKING, "plan")  # nothing commanded yet
    out._issued(10.0, Command.standby(0))
    out._issued(12.0, Command.standby(0))  # the same mode: the dwell counts from 10 s
    assert out.t_mode == 10.0
    assert out._dwell(12.0, False, Reason.TRACKING, "plan")  # held: 2 s of standby
    assert out._diag["mpc_dwell_held"] == 1
    assert out._dwell(14.0, False, Reason.TRACKING, "rescue")
    assert not out._dwell(14.0, True, Reason.TRACKING, "plan")  # the same mode: nothing held
    assert not out._dwell(12.0, False, Reason.AVOIDANCE, "plan")  # leaving an AUV's way
    assert not out._dwell(12.0, False, Reason.TRACKING, "escape")
    assert not out._dwell(12.0, False, Reason.TRACKING, "as-escape")
    assert not out._dwell(15.0, False, Reason.TRACKING, "plan")  # 5 s: over
    out._issued(15.0, Command(Mode.TRANSIT, (0.0, 100.0), 1.0, 0, Reason.TRACKING))
    assert out._dwell(16.0, True, Reason.TRACKING, "plan")  # a transit is held too
    assert not _out(0.0)._dwell(0.0, False, Reason.TRACKING, "plan")


def test_a_new_run_starts_without_a_dwell():
    """The controller's ``reset`` (each run's start) forgets the last run's mode: a run
    after one that ended in a transit at 100 s may stand by at once."""
    ctrl = make_controller("mpc-single", 1, "mpc-single")
    assert ctrl.params.min_dwell == 5.0  # the presets' default
    ctrl._issued(100.0, Command(Mode.TRANSIT, (0.0, 100.0), 1.0, 0, Reason.TRACKING))
    assert ctrl._dwell(101.0, True, Reason.TRACKING, "plan")
    ctrl.reset(1)
    assert (ctrl.cmd_out, ctrl.t_mode) == (None, -math.inf)
    assert not ctrl._dwell(1.0, True, Reason.TRACKING, "plan")


def _hand_result(modes, props, dt=1.0):
    """A real run's result with the commanded mode and the propeller state replaced, one
    row per ``dt`` s (the first at ``dt``)."""
    sc = scenario_from_dict({
        "name": "still", "duration": dt * len(modes), "controller": "goto",
        "auv": [{"name": "a", "start": {"N": 100.0, "E": 0.0},
                 "behaviour": {"transit": {"heading_deg": 90.0, "speed": 0.5}}}],
    })  # fmt: skip
    res = simulate(sc, make_controller("goto", 1, None, overrides={"waypoint": [0.0, 0.0]}),
                   seed=0)
    ts = res.timeseries.copy()
    assert len(ts) == len(modes)
    ts["mode"], ts["propeller_on"] = modes, props
    return dataclasses.replace(res, timeseries=ts)


def test_short_switches_and_propeller_toggles_counted_by_hand():
    # mode changes at t = 4 (first: not counted), 6 (2 s later: short), 11 (5 s: not short),
    # 12 (1 s: short); the propeller toggles with it
    s, x = "standby", "transit"
    modes = [s] * 3 + [x] * 2 + [s] * 5 + [x] + [s] * 4
    props = [m == x for m in modes]
    m = compute_metrics(_hand_result(modes, props))
    assert SHORT_STAY_S == 5.0
    assert m["mode_switches"] == 4
    assert m["mode_switches_short"] == 2
    assert m["propeller_toggles"] == 4
    m = compute_metrics(_hand_result([s] * 15, [False] * 15))
    assert (m["mode_switches"], m["mode_switches_short"], m["propeller_toggles"]) == (0, 0, 0)


_SUITE = """
name = "dwell"
scenarios = ["case6"]
seeds = [3]
duration = 480.0
plots = "none"

[[controllers]]
label = "mpc"
single = "mpc-single"
multi = "mpc-multi"
preset = "default"
domain_from = "scenario"
overrides = { "min_dwell" = 0.0 }

[[controllers]]
label = "dwell"
single = "mpc-single"
multi = "mpc-multi"
preset = "default"
domain_from = "scenario"
"""


def test_in_closed_loop_no_mode_is_shorter_than_the_dwell_unless_an_auv_must_be_left(tmp_path):
    """Case 6 (three AUVs), realisation 3, its first 480 s, as the paper suite runs it: the
    MPC without the rule (``min_dwell = 0``) switches mode less than 5 s after the previous
    switch 10 times (measured, session 46; realisation 5, this test's until then, had 11, and
    has 1 since the current observer takes the actuators through each period: it had read
    each start of a transit as a current of a few cm/s, after which, in the Case 3 run of
    ``tests/test_mpc_between_steps.py``, the plan stood by again; the Case 6 runs were not
    analysed), with the default
    ``min_dwell = 5`` every such switch is a TRANSIT for AVOIDANCE, the escape manoeuvre or
    a fallback step, and there are fewer of them."""
    from mpcasv.experiments.runner import run_suite

    suite = tmp_path / "dwell.toml"
    suite.write_text(_SUITE)
    out = tmp_path / "out"
    results = run_suite(suite, out, workers=1, quiet=True, report=False, job_timeout=0)[2]
    assert (results["status"] == "ok").all()
    short = dict(zip(results["label"], results["mode_switches_short"], strict=True))
    assert short["mpc"] >= 3, short  # the scenario chatters without the rule
    assert short["dwell"] < short["mpc"], short
    (run,) = (out / "runs").glob("case6-dwell-*")
    ts = pd.read_parquet(run / "timeseries.parquet")
    quick = short_switches(ts["t"].to_numpy(), ts["mode"].to_numpy())
    assert len(quick) == short["dwell"]
    assert ts["mpc_dwell_held"].sum() > 0  # the rule held modes back
    for i in quick:
        row = ts.iloc[i]
        exempt = ((row["mode"] == "transit" and row["reason"] == "avoidance")
                  or row["mpc_source"] in ("escape", "as-escape") or row["reason"] == "fallback")
        assert exempt, f"a {row['mode']} at {row['t']} s, less than {SHORT_STAY_S} s after " \
                       f"the previous switch, not exempt ({row['reason']}, {row['mpc_source']})"


def test_a_held_mode_hands_over_the_last_command_or_a_standby_for_the_dwell_left():
    """The Otter's plan turning east from 2 m/s north (an AUV 150 m north, no threat): its
    TRANSIT at 0 s; at 2 s a plan with the thrust off throughout (a standby plan) gives the
    same TRANSIT again (waypoint and speed as commanded, not the standby plan's point);
    from 5 s the STANDBY. Then the moving plan at 7 s gives a STANDBY for the 3 s of dwell
    left, and at 10 s the TRANSIT."""
    from test_mpc_heading import _turn_east

    from mpcasv.controllers import Boat
    from mpcasv.interface import ASVState, AUVEstimate, Observation
    from mpcasv.mpc.problem import OCP

    P = load_preset("mpc-single", "mpc-single")
    ocp = OCP(P, 1, outer=True, boat=Boat.load("otter"))
    out = _out(P.min_dwell)
    out.ocp, out.domain, out.u_plan, out.t_depart = ocp, P.domain, None, None
    out.current = np.zeros(2)
    x0, p, go = _turn_east(ocp)
    Z, V = ocp.split(go)
    Z[:, 6] = 0.0
    stop = ocp.join(Z, V)
    out._store_plan(0.0, go)

    def at(t, w):
        obs = Observation(t, ASVState(*x0[0:6]), True, (AUVEstimate(150.0, 0.0, 0.0, 0.0, 0.0),))
        return out._issued(t, out._command(obs, w, p))

    first = at(0.0, go)
    assert first.mode is Mode.TRANSIT and first.reason is Reason.TRACKING
    held = at(2.0, stop)
    assert out._diag["mpc_dwell_held"] == 1
    assert (held.mode, held.waypoint, held.speed) == (Mode.TRANSIT, first.waypoint, first.speed)
    assert at(5.0, stop).mode is Mode.STANDBY
    assert out._diag["mpc_dwell_held"] == 0
    kept = at(7.0, go)
    assert kept.mode is Mode.STANDBY and kept.standby_time == pytest.approx(3.0)
    assert at(10.0, go).mode is Mode.TRANSIT
