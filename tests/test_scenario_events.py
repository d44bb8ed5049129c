"""Scenario events beyond behaviour switches (issue 14, Deliver 2): abort (stop and rise at a
rate), loiter (hold position, resume), limit changes; and a current that varies in time and
space and carries the AUVs. Driven through the simulated World with the ASV standing by."""

from __future__ import annotations

import json
import math
import textwrap

import numpy as np
import pandas as pd
import pytest
from refusal import assert_refused_in_one_line

from mpcasv.cli import main
from mpcasv.config import ConfigError
from mpcasv.control.execution import NCMD
from mpcasv.models.behaviours import LOITER_RADIUS
from mpcasv.models.current import CurrentField
from mpcasv.sim.scenario import load_scenario, scenario_from_dict
from mpcasv.sim.uncertainty import realise, without_current
from mpcasv.sim.world import World

STANDBY = np.zeros(NCMD)


def scenario(auv: dict, duration: float = 300.0, **top) -> dict:
    """One AUV going North at 1.5 m/s and 40 m depth (unless ``auv`` says otherwise); the ASV
    stands by 500 m away."""
    a = {"name": "a", "start": {"depth": 40.0, "speed": 1.5},
         "behaviour": {"transit": {"heading_deg": 0.0, "speed": 1.5, "depth": 40.0}}} | auv
    return {"name": "t", "duration": duration, "auv": [a],
            "asv": {"start": {"N": 0.0, "E": 500.0}}} | top  # fmt: skip


def run(data: dict, seed: int = 0):
    """AUV states (5 x n+1: N, E, d, psi, U) at t = 0, 1, ..., duration; and the world."""
    sc = scenario_from_dict(data)
    w = World(sc, seed=seed)
    S = [w.S[:, 0].copy()]
    for _ in range(sc.n_steps):
        w.advance(STANDBY)
        S.append(w.S[:, 0].copy())
    return np.array(S).T, w


# ---------------------------------------------------------------------------- abort


def test_abort_stops_where_it_is_and_rises_at_its_rate():
    S, _ = run(scenario({"events": [{"t": 100.0, "kind": "abort", "rise_rate": 0.25}]}))
    assert S[2, 100] == pytest.approx(40.0)  # still at depth when the abort comes
    assert S[2, 140] == pytest.approx(30.0, abs=0.05)  # 40 s at 0.25 m/s (not the 0.5 limit)
    assert S[2, 250] == pytest.approx(2.5, abs=0.05)  # still rising at 0.25 m/s at t = 250
    assert S[2, 270:].max() < 0.5  # surfaced (0.5 m at t = 258 s, then exponentially) and stays
    drift = np.hypot(S[0, 100:] - S[0, 100], S[1, 100:] - S[1, 100])
    assert drift.max() < 10.0  # stops: 1.5 m/s at 0.2 m/s^2 is ~6 m, not 300 m
    assert S[4, 150:].max() < 1e-6
    assert S[0, 99] == pytest.approx(S[0, 98] + 1.5, abs=1e-6)  # nothing changes before


def test_abort_rise_rate_may_exceed_the_depth_rate_limit_and_defaults_to_the_limit_in_force():
    fast, _ = run(scenario({"events": [{"t": 100.0, "kind": "abort", "rise_rate": 1.0}]}))
    assert fast[2, 110] == pytest.approx(30.0, abs=0.05)  # 1 m/s over limits.depth_rate_max 0.5
    plain, _ = run(scenario({"events": [{"t": 100.0, "kind": "abort"}]}))
    assert plain[2, 110] == pytest.approx(35.0, abs=0.05)  # limits.depth_rate_max = 0.5
    slowed, _ = run(scenario({"events": [{"t": 50.0, "kind": "limits", "depth_rate_max": 0.2},
                                         {"t": 100.0, "kind": "abort"}]}))  # fmt: skip
    assert slowed[2, 110] == pytest.approx(38.0, abs=0.05)  # the limit changed at t = 50


def test_abort_works_for_any_behaviour_pursuer_and_plan():
    pursuer = {"behaviour": {"pursuer": {"speed": 1.5, "depth": 40.0}},
               "events": [{"t": 60.0, "kind": "abort", "rise_rate": 0.5}]}  # fmt: skip
    S, _ = run(scenario(pursuer, duration=200.0))
    assert S[2, 60] == pytest.approx(40.0) and S[2, 200] < 0.5
    assert np.hypot(S[0, 200] - S[0, 60], S[1, 200] - S[1, 60]) < 10.0
    plan = {"behaviour": {"plan": {"speed": 1.5, "route": [
        {"waypoints": [[300.0, 0.0, 40.0], [300.0, 300.0, 40.0]]}]}},
        "events": [{"t": 60.0, "kind": "abort", "rise_rate": 0.5}]}  # fmt: skip
    S, _ = run(scenario(plan, duration=200.0))
    assert S[2, 200] < 0.5 and S[0, 200] < 110.0  # stopped near N = 90, not at the waypoint


# ---------------------------------------------------------------------------- limits


def test_limits_event_changes_speed_and_depth_rate_from_its_time_on():
    data = scenario({"start": {"depth": 0.0, "speed": 1.5},
                     "behaviour": {"transit": {"heading_deg": 0.0, "speed": 1.5, "depth": 60.0}},
                     "events": [{"t": 20.0, "kind": "limits", "speed_max": 0.5,
                                 "depth_rate_max": 0.1}]}, duration=100.0)  # fmt: skip
    S, w = run(data)
    assert S[2, 20] == pytest.approx(10.0, abs=0.05)  # 0.5 m/s for 20 s
    assert S[2, 60] - S[2, 40] == pytest.approx(2.0, abs=0.05)  # then 0.1 m/s
    assert S[4, 15] == pytest.approx(1.5) and S[4, 60:].max() == pytest.approx(0.5, abs=1e-6)
    assert w.LIM[:, 0] == pytest.approx([0.5, math.radians(10.0), 0.1, 0.2])


def test_turn_rate_limit_event_slows_the_turn():
    turn = {"behaviour": {"transit": {"heading_deg": 0.0, "speed": 1.0, "depth": 40.0}},
            "start": {"depth": 40.0, "speed": 1.0},
            "events": [{"t": 10.0, "transit": {"heading_deg": 90.0, "speed": 1.0, "depth": 40.0}}]}
    S, _ = run(scenario(turn, duration=20.0))
    slow = dict(turn, events=[{"t": 5.0, "kind": "limits", "turn_rate_max_deg": 2.0},
                              *turn["events"]])  # fmt: skip
    S2, _ = run(scenario(slow, duration=20.0))
    assert math.degrees(S[3, 15]) == pytest.approx(50.0, abs=0.5)  # 10 deg/s for 5 s
    assert math.degrees(S2[3, 15]) == pytest.approx(10.0, abs=0.5)  # 2 deg/s for 5 s


# ---------------------------------------------------------------------------- loiter


def test_loiter_event_holds_position_then_resumes():
    data = scenario({"start": {"depth": 40.0, "speed": 1.0},
                     "behaviour": {"transit": {"heading_deg": 0.0, "speed": 1.0, "depth": 40.0}},
                     "events": [{"t": 50.0, "kind": "loiter", "duration": 100.0}]},
                    duration=250.0)  # fmt: skip
    S, _ = run(data)
    p50 = S[:2, 50]
    held = np.hypot(S[0, 60:150] - p50[0], S[1, 60:150] - p50[1])
    assert held.max() < 6.0 and held[-20:].max() < LOITER_RADIUS + 0.5
    assert S[0, 250] - S[0, 150] > 85.0  # resumed the transit at 1 m/s
    forever = dict(data["auv"][0], events=[{"t": 50.0, "kind": "loiter", "depth": 10.0}])
    S, _ = run(scenario(forever, duration=250.0))
    assert abs(S[0, 250] - S[0, 50]) < LOITER_RADIUS + 0.5 and S[2, 250] == pytest.approx(10.0,
                                                                                          abs=0.1)


def test_loiter_behaviour_goes_to_its_point_and_holds_it_against_a_current():
    data = scenario({"start": {"depth": 20.0},
                     "behaviour": {"loiter": {"at": [30.0, 0.0], "depth": 20.0, "speed": 1.0}}},
                    duration=400.0, current=[0.0, 0.2],
                    current_field={"auv_factor": 1.0})  # fmt: skip
    S, _ = run(data)
    dist = np.hypot(S[0] - 30.0, S[1])
    assert dist[0] == pytest.approx(30.0) and dist[200:].max() < 5.0  # 2 m + 0.2 m/s / 0.1/s
    plain, _ = run(dict(data, current_field={"auv_factor": 1.0},
                        auv=[dict(data["auv"][0], behaviour={"transit": {
                            "heading_deg": 0.0, "speed": 1.0, "depth": 20.0}},
                                  events=[{"t": 0.0, "kind": "abort"}])]))  # fmt: skip
    assert plain[1, 400] == pytest.approx(0.2 * 400, rel=0.02)  # a stopped AUV drifts


# ---------------------------------------------------------------------------- current


def test_current_field_interpolates_in_time_and_clips_the_gradient():
    cf = CurrentField(knots=((0.0, 0.0, 0.0), (100.0, 0.4, 0.0), (200.0, 0.0, -0.2)),
                      gradient=((0.0, 1e-4), (0.0, 0.0)), origin=(0.0, 0.0), radius=1000.0)
    ev = cf.evaluator((0.1, 0.0))
    assert ev(50.0, np.zeros(2)) == pytest.approx([0.3, 0.0])
    assert ev(150.0, np.zeros(2)) == pytest.approx([0.3, -0.1])
    assert ev(500.0, np.zeros(2)) == pytest.approx([0.1, -0.2])  # held after the last knot
    assert ev(0.0, np.array([0.0, 500.0])) == pytest.approx([0.15, 0.0])
    assert ev(0.0, np.array([0.0, 5000.0])) == pytest.approx([0.2, 0.0])  # held at 1000 m
    P = np.array([[0.0, 0.0], [500.0, -500.0]])
    assert ev(0.0, P) == pytest.approx(np.array([[0.15, 0.05], [0.0, 0.0]]))
    assert cf.extra_max() == pytest.approx(math.hypot(0.4, 0) + 0.1)


def test_the_world_passes_the_field_at_mid_period_and_at_the_asv():
    data = scenario({}, duration=20.0, current=[0.1, 0.0], current_field={
        "knots": [[0.0, 0.0, 0.0], [20.0, 0.0, 0.4]], "gradient": [[0.0, 0.0], [1e-4, 0.0]],
        "auv_factor": 0.5})  # fmt: skip
    sc = scenario_from_dict(data)
    w = World(sc, seed=0)
    for k in range(5):
        N_asv = w.x[0]
        w.advance(STANDBY)
        assert w.current == pytest.approx([0.1, 0.02 * (k + 0.5) + 1e-4 * N_asv])
    # the AUV (at the period's start position) is carried by half of the same field
    N_auv = w.S[0, 0] - 1.5  # position at the start of the last period
    assert w.C_auv[:, 0] == pytest.approx(0.5 * np.array([0.1, 0.02 * 4.5 + 1e-4 * N_auv]),
                                          abs=2e-4)


def test_without_a_current_field_the_auvs_are_not_carried():
    """The model of every existing scenario: ``current = [...]`` acts on the ASV only."""
    data = scenario({"events": [{"t": 0.0, "kind": "abort"}]}, duration=100.0,
                    current=[0.0, 0.3])  # fmt: skip
    S, w = run(data)
    assert abs(S[1, -1]) < 1e-9 and w._CL is not None
    S2, _ = run(dict(data, current_field={"auv_factor": 1.0}))
    assert S2[1, -1] == pytest.approx(30.0, rel=0.01)


def test_new_features_are_deterministic():
    data = scenario({"events": [{"t": 30.0, "kind": "loiter", "duration": 20.0},
                                {"t": 80.0, "kind": "abort", "rise_rate": 0.3}]},
                    duration=150.0, current=[0.1, 0.0],
                    current_field={"knots": [[0.0, 0.0, 0.0], [150.0, 0.2, 0.1]]})  # fmt: skip
    a, _ = run(data, seed=3)
    b, _ = run(data, seed=3)
    assert np.array_equal(a, b)


def test_uncertain_current_draws_the_base_and_keeps_the_field():
    data = scenario({}, duration=10.0, current=[0.1, 0.0],
                    current_field={"knots": [[0.0, 0.0, 0.0], [100.0, 0.3, 0.0]]},
                    uncertain={"current": {"speed": {"dist": "uniform", "low": 0.0,
                                                     "high": 0.5}}})  # fmt: skip
    sc = scenario_from_dict(data)
    done, real = realise(sc, 4)
    s = real.values["current.speed"]
    assert done.current == pytest.approx((s, 0.0)) and done.current_field == sc.current_field
    fixed = without_current(sc)  # a suite fixing the current drops the variation too
    assert fixed.current_field.knots == () and fixed.current_field.auv_factor == 1.0
    too_fast = dict(data, uncertain={"current": {"speed": {"dist": "uniform", "low": 0.0,
                                                           "high": 1.9}}})  # fmt: skip
    with pytest.raises(ConfigError, match="current_field"):
        scenario_from_dict(too_fast)


# ------------------------------------------------------------------- bad input refused

BASE = """
name = "t"
duration = 30.0
controller = "goto"
preset = "goto"
[[auv]]
name = "a"
start = { depth = 20.0 }
[auv.behaviour.transit]
heading_deg = 0.0
speed = 1.5
"""

BAD = {
    "unknown kind": ('[[auv.events]]\nt = 5.0\nkind = "explode"', "auv[0].events[0].kind"),
    "field of another kind": ('[[auv.events]]\nt = 5.0\nkind = "abort"\nduration = 3.0',
                              "duration belongs to kind = 'loiter'"),
    "switch without a behaviour": ("[[auv.events]]\nt = 5.0", "needs exactly one"),
    "abort with a plan": ('[[auv.events]]\nt = 5.0\nkind = "abort"\n'
                          "transit = { heading_deg = 0.0, speed = 1.0 }", "transit belongs"),
    "limits without a limit": ('[[auv.events]]\nt = 5.0\nkind = "limits"', "at least one"),
    "zero rise rate": ('[[auv.events]]\nt = 5.0\nkind = "abort"\nrise_rate = 0.0',
                       "auv[0].events[0].rise_rate"),
    "string rise rate": ('[[auv.events]]\nt = 5.0\nkind = "abort"\nrise_rate = "0.5"',
                         "auv[0].events[0].rise_rate"),
    "negative time": ('[[auv.events]]\nt = -5.0\nkind = "abort"', "auv[0].events[0].t"),
    "loiter faster than the limit": ('[[auv.events]]\nt = 5.0\nkind = "loiter"\nspeed = 3.0',
                                     "exceeds limits.speed_max"),
    "switch faster than a lowered limit": (
        '[[auv.events]]\nt = 5.0\nkind = "limits"\nspeed_max = 1.0\n[[auv.events]]\nt = 9.0\n'
        "transit = { heading_deg = 0.0, speed = 1.2 }", "speed_max of events[0]"),
    "two behaviours": ("[auv.behaviour.loiter]\n", "exactly one of plan, pursuer, transit, loiter"),
    "knots out of order": ("[current_field]\nknots = [[10.0, 0.1, 0.0], [5.0, 0.0, 0.0]]",
                           "knots: times must increase"),
    "knot of two numbers": ("[current_field]\nknots = [[10.0, 0.1]]", "current_field.knots[0]"),
    "current field too strong": ("[current_field]\ngradient = [[0.0, 0.003], [0.0, 0.0]]",
                                 "may reach 3 m/s"),
    "auv factor above 1": ("[current_field]\nauv_factor = 1.5", "current_field.auv_factor"),
    "unknown current field key": ("[current_field]\nknot = []", "current_field.knot"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_events_and_currents_are_refused_with_one_line(tmp_path, capsys, case):
    text, word = BAD[case]
    if text.startswith("[current_field]"):
        body = BASE + "\n" + text + "\n"
    elif text.startswith("[auv.behaviour.loiter]"):
        body = BASE.replace("[auv.behaviour.transit]", text + "[auv.behaviour.transit]")
    else:
        body = BASE + text + "\n"
    path = tmp_path / "s.toml"
    path.write_text(textwrap.dedent(body))
    assert_refused_in_one_line(path, word, tmp_path / "o", capsys)


def test_every_shipped_scenario_still_loads_and_the_abort_example_rises_under_the_asv(
        scenarios_dir):  # fmt: skip
    for path in sorted(scenarios_dir.glob("*.toml")):
        load_scenario(path)
    sc = load_scenario(scenarios_dir / "abort-under-asv.toml")
    w = World(sc, seed=0)
    kinds = [ev.kind for ev in sc.auv[0].events]
    assert "abort" in kinds
    t_abort = next(ev.t for ev in sc.auv[0].events if ev.kind == "abort")
    for _ in range(int(t_abort) + 200):
        w.advance(STANDBY)
    assert w.S[2, 0] < 0.5  # surfaced within 200 s of the abort
    assert math.hypot(w.S[0, 0] - w.x[0], w.S[1, 0] - w.x[1]) < 30.0  # under the ASV


def test_scripted_loiter_resumes_the_interrupted_behaviour_and_a_switch_cancels_the_resume():
    from mpcasv.models.behaviours import Loiter, Pause, Scripted, Transit

    s = np.array([0.0, 0.0, 10.0, 0.0, 1.0])
    north, east = Transit(0.0, 1.0, 10.0), Transit(90.0, 1.0, 10.0)
    b = Scripted(north, [(10.0, Pause(Loiter(), 20.0)), (15.0, Pause(Loiter(), 10.0))])
    assert isinstance(b.current, Transit)
    b.setpoint(10.0, s, np.zeros(2))
    b.setpoint(15.0, s, np.zeros(2))  # a second loiter inside the first
    assert isinstance(b.current, Loiter)
    b.setpoint(25.0, s, np.zeros(2))
    assert b.current is north  # the behaviour interrupted first, not the first loiter
    b = Scripted(north, [(10.0, Pause(Loiter(), 20.0)), (15.0, east)])
    for t in (10.0, 15.0, 40.0):
        b.setpoint(t, s, np.zeros(2))
    assert b.current is east and b.switches == [10.0, 15.0]


def test_uncertain_rotation_and_offset_move_loiter_points_with_the_routes():
    data = scenario({"start": {"N": 0.0, "E": 0.0, "depth": 20.0},
                     "behaviour": {"loiter": {"at": [100.0, 0.0]}},
                     "events": [{"t": 10.0, "kind": "loiter", "at": [0.0, 50.0]}]},
                    duration=10.0,
                    uncertain={"auv": {"a": {
                        "rotation_deg": {"dist": "uniform", "low": 80.0, "high": 100.0},
                        "offset_N": {"dist": "uniform", "low": 5.0, "high": 10.0}}}})  # fmt: skip
    done, real = realise(scenario_from_dict(data), 2)
    rot = math.radians(real.values["auv.a.rotation_deg"])
    dN = real.values["auv.a.offset_N"]
    a = done.auv[0]
    assert a.behaviour.loiter.at == pytest.approx((100 * math.cos(rot) + dN, 100 * math.sin(rot)))
    assert a.events[0].at == pytest.approx((-50 * math.sin(rot) + dN, 50 * math.cos(rot)))


def test_hybrid_single_on_abort_under_asv_is_caught_inside_then_escapes(tmp_path, scenarios_dir):
    """Pins today's behaviour on the example: the standing-by ASV (10 m off) is inside the
    rising AUV's collision domain for a few seconds, then the avoidance transit leaves it."""
    out = tmp_path / "run"
    assert main(["simulate", str(scenarios_dir / "abort-under-asv.toml"), "--out", str(out),
                 "--quiet", "--no-plots"]) == 0  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert m["min_range_m"] == pytest.approx(10.0, abs=0.01)
    assert 0.0 < m["collision_domain_s"] < 30.0  # measured 9.5 s (seed 0)
    ts = pd.read_parquet(out / "timeseries.parquet")
    rising = ts[(ts["t"] > 300) & (ts["t"] < 362)]
    assert (rising["reason"] == "avoidance").any()
    assert ts["range0"].iloc[-1] > ts["r_inner0"].iloc[-1]  # outside the domain at the end


def test_the_ground_truth_velocity_includes_the_drift_from_the_start():
    data = scenario({"start": {"depth": 40.0, "speed": 1.5}}, duration=10.0, current=[0.0, 0.3],
                    current_field={"auv_factor": 0.5})  # fmt: skip
    w = World(scenario_from_dict(data), seed=0)
    assert w.auv_truth(0)[3:] == pytest.approx((1.5, 0.15))
    w.advance(STANDBY)  # (the transit's heading corrects the drift a little)
    assert w.auv_truth(0)[3:] == pytest.approx((1.5, 0.15), abs=1e-4)
    plain = World(scenario_from_dict(dict(data, current_field=None)), seed=0)
    assert plain.auv_truth(0)[3:] == pytest.approx((1.5, 0.0))


def test_simulate_says_what_is_scheduled_after_the_run_ends(tmp_path, capsys):
    """An abort at 500 s of a 60-s run and a surface interval from 100 s were accepted and
    never happened, unsaid (a new user's scenario); now each is a warning line. The run
    goes on (a suite's duration may cut a scenario short on purpose)."""
    from mpcasv.cli import main

    path = tmp_path / "ev.toml"
    path.write_text(
        'name = "ev"\nduration = 60.0\ncontroller = "hybrid-single"\npreset = "paper1-field"\n'
        '[[auv]]\nname = "a"\nstart = { N = 100.0, E = 0.0, depth = 10.0 }\n'
        '[auv.behaviour.plan]\nspeed = 1.0\nsurface = [[100.0, 200.0]]\n'
        'route = [ { waypoints = [[200.0, 0.0, 10.0]] } ]\n'
        '[[auv.events]]\nt = 500.0\nkind = "abort"\n')  # fmt: skip
    assert main(["simulate", str(path), "--out", str(tmp_path / "r"), "--quiet",
                 "--no-plots"]) == 0  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"warning: {path}: AUV 'a' events[0] (abort) at t = 500 s: at or after the run's end "
        "(60 s), it never happens",
        f"warning: {path}: AUV 'a' behaviour.plan.surface from t = 100 s: at or after the "
        "run's end (60 s), it never happens"], err
