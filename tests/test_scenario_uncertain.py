"""A scenario's [uncertain] table: strict validation, one realisation per seed, independent of
the controller, recorded in run.json (issue 12, Deliver 4)."""

from __future__ import annotations

import json
import math
import textwrap
from collections import defaultdict

import numpy as np
import pytest
from refusal import assert_refused_in_one_line

from mpcasv.cli import main
from mpcasv.config import ConfigError
from mpcasv.experiments.suite import expand
from mpcasv.sim.realisation import Realisation, apply
from mpcasv.sim.scenario import load_scenario, scenario_from_dict
from mpcasv.sim.uncertainty import distributions, draw, realise

BASE = """
name = "t"
duration = 30.0
controller = "goto"
preset = "goto"
current = [0.1, 0.0]
[[auv]]
name = "a"
[auv.behaviour.plan]
speed = 1.5
route = [ { lawnmower = { origin = [0.0, 0.0], length = 100.0, spacing = 20.0, legs = 2 } } ]
[[auv.events]]
t = 50.0
pursuer = { speed = 1.8, update_period = 20.0 }
[[auv.events]]
t = 100.0
transit = { heading_deg = 90.0, speed = 1.0 }
"""

GOOD = BASE + """
[uncertain.current]
speed = { dist = "uniform", low = 0.0, high = 0.3 }
direction_deg = { dist = "uniform", low = 0.0, high = 360.0 }
[uncertain.asv]
start_N = { dist = "normal", mean = 0.0, sd = 10.0, low = -20.0, high = 20.0 }
[uncertain.acoustics]
p_good = { dist = "normal", mean = 0.9, sd = 0.05, low = 0.8, high = 1.0 }
[uncertain.auv.a]
rotation_deg = { dist = "uniform", low = -20.0, high = 20.0 }
offset_N = { dist = "normal", mean = 0.0, sd = 10.0, low = -30.0, high = 30.0 }
event_time_s = { dist = "uniform", low = -10.0, high = 10.0 }
update_period_s = { dist = "choice", values = [10.0, 20.0, 30.0], p = [0.2, 0.5, 0.3] }
speed_factor = { dist = "uniform", low = 0.9, high = 1.1 }
"""


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


# ------------------------------------------------------------------ the paper suite's jobs


@pytest.fixture(scope="module")
def paper():
    return expand("paper")


def test_paper_suite_jobs_have_pairwise_different_realisations(paper):
    """No two jobs of one controller simulate the same world: every (case, seed) draws values,
    and no two seeds of a case draw the same values."""
    by_label = defaultdict(list)
    for j in paper.jobs:
        by_label[j.label].append(j)
    assert set(by_label) == {"hybrid", "mpc"}
    for label, jobs in by_label.items():
        assert len({j.realisation for j in jobs}) == len(jobs), label
    for sc_name in {j.scenario for j in paper.jobs}:
        values = [job.realised_scenario()[1].values for job in
                  [j for j in paper.jobs if j.scenario == sc_name and j.label == "hybrid"]]
        assert all(values), sc_name  # something is drawn in every case
        rows = {tuple(sorted(v.items())) for v in values}
        assert len(rows) == len(values), sc_name


def test_same_seed_same_realisation_for_every_controller(paper):
    groups = defaultdict(set)
    for j in paper.jobs:
        groups[(j.scenario, j.current_axis, j.estimator, j.seed)].add((j.label, j.realisation))
    for key, members in groups.items():
        assert {label for label, _ in members} == {"hybrid", "mpc"}, key
        assert len({real for _, real in members}) == 1, key


def test_case7_is_no_longer_a_copy_of_case6(scenarios_dir):
    """Case 7 (field, physical Gretha): the unknown environmental loads are a current drawn per
    seed (0.05-0.3 m/s, any direction); Case 6 (simulation) has none."""
    c6, c7 = (load_scenario(scenarios_dir / f"case{i}.toml") for i in (6, 7))
    speeds = []
    for seed in range(10):
        r6, r7 = realise(c6, seed)[0], realise(c7, seed)[0]
        assert r6.current == (0.0, 0.0)
        speeds.append(math.hypot(*r7.current))
        assert r6.asv.start != r7.asv.start or r6.auv != r7.auv
    assert all(0.05 <= s <= 0.3 for s in speeds)
    assert len(set(speeds)) == 10


def test_the_realisation_does_not_use_the_worlds_stream(scenarios_dir):
    """Drawing a realisation leaves numpy's default_rng(seed) (the world's acoustics) alone, and
    the same seed gives the same values however often it is drawn."""
    sc = load_scenario(scenarios_dir / "case8.toml")
    before = np.random.default_rng(5).random(3)
    a, b = draw(sc, 5), draw(sc, 5)
    assert a == b and a.id == b.id
    assert np.array_equal(np.random.default_rng(5).random(3), before)
    assert draw(sc, 6).values != a.values


# ------------------------------------------------------------------ what a draw does


def test_a_realisation_applies_each_drawn_value(tmp_path):
    sc = load_scenario(write(tmp_path, GOOD))
    assert len(distributions(sc)) == 10  # two events: one event_time_s each
    done, real = realise(sc, 3)
    v = real.values
    assert done.uncertain.is_empty()
    chi = math.radians(v["current.direction_deg"])
    assert done.current == pytest.approx((v["current.speed"] * math.cos(chi),
                                          v["current.speed"] * math.sin(chi)))  # fmt: skip
    assert done.asv.start.N == pytest.approx(v["asv.start_N"])
    assert done.acoustics.p_good == pytest.approx(v["acoustics.p_good"])
    auv = done.auv[0]
    lm = auv.behaviour.plan.route[0].lawnmower
    assert lm.origin == pytest.approx((v["auv.a.offset_N"], 0.0))  # origin = start: pivot
    assert lm.heading_deg == pytest.approx(v["auv.a.rotation_deg"])
    assert auv.start.psi_deg == pytest.approx(v["auv.a.rotation_deg"])
    f = v["auv.a.speed_factor"]
    assert auv.behaviour.plan.speed == pytest.approx(1.5 * f)
    assert [ev.t for ev in auv.events] == pytest.approx(
        [50.0 + v["auv.a.event_time_s.0"], 100.0 + v["auv.a.event_time_s.1"]])
    assert auv.events[0].pursuer.update_period == v["auv.a.update_period_s"] in (10, 20, 30)
    assert auv.events[0].pursuer.speed == pytest.approx(1.8 * f)
    assert auv.events[1].transit.heading_deg == pytest.approx(90.0 + v["auv.a.rotation_deg"])


def test_draws_stay_in_their_support_and_follow_their_distribution(tmp_path):
    sc = load_scenario(write(tmp_path, GOOD))
    vals = defaultdict(list)
    for seed in range(400):
        for k, x in draw(sc, seed).values.items():
            vals[k].append(x)
    p_good = np.array(vals["acoustics.p_good"])
    assert p_good.min() >= 0.8 and p_good.max() <= 1.0
    assert p_good.mean() == pytest.approx(0.9, abs=0.01)  # symmetric truncation
    speed = np.array(vals["current.speed"])
    assert 0.0 <= speed.min() and speed.max() <= 0.3
    assert speed.mean() == pytest.approx(0.15, abs=0.02)
    period = np.array(vals["auv.a.update_period_s"])
    assert set(period) == {10.0, 20.0, 30.0}
    assert np.mean(period == 20.0) == pytest.approx(0.5, abs=0.08)


def test_one_more_uncertain_quantity_leaves_the_others_draws_alone(tmp_path):
    sc = load_scenario(write(tmp_path, GOOD))
    fewer = load_scenario(write(tmp_path, GOOD.replace(
        'start_N = { dist = "normal", mean = 0.0, sd = 10.0, low = -20.0, high = 20.0 }\n', ""),
        "fewer.toml"))  # fmt: skip
    a, b = draw(sc, 1).values, draw(fewer, 1).values
    assert set(a) - set(b) == {"asv.start_N"}
    assert {k: a[k] for k in b} == b


def test_a_suite_that_fixes_the_current_drops_its_uncertainty(tmp_path):
    sc_path = write(tmp_path, GOOD)
    suite = write(tmp_path, f"""
        name = "u"
        scenarios = ["{sc_path}"]
        seeds = [0, 1]
        current = ["scenario", "off", [0.2, 0.0]]
        [[controllers]]
        label = "goto"
        name = "goto"
    """, "suite.toml")  # fmt: skip
    jobs = expand(suite).jobs
    assert [j.current_axis for j in jobs] == ["scenario"] * 2 + ["off"] * 2 + ["0.2,0"] * 2
    for j in jobs:
        sc, real = j.realised_scenario()
        assert real.id == j.realisation
        if j.current_axis == "scenario":
            assert "current.speed" in real.values
        else:
            assert not any(k.startswith("current.") for k in real.values)
            assert sc.current == j.current
    assert len({j.realisation for j in jobs}) == 6


# ------------------------------------------------------------------ run.json


def test_a_realisation_round_trips_through_run_json(tmp_path):
    path = write(tmp_path, GOOD)
    out = tmp_path / "run"
    assert main(["simulate", str(path), "--seed", "4", "--out", str(out),
                 "--quiet", "--no-plots"]) == 0  # fmt: skip
    recorded = json.loads((out / "run.json").read_text())["realisation"]
    sc = load_scenario(path)
    want_sc, want = realise(sc, 4)
    assert recorded == want.as_dict()
    back = Realisation.from_dict(recorded)
    assert back == want
    assert apply(sc, back) == want_sc
    recorded["values"]["current.speed"] += 0.01
    with pytest.raises(ConfigError, match="do not match"):
        Realisation.from_dict(recorded)


def test_the_runner_records_the_realisation_of_its_job(tmp_path):
    from mpcasv.experiments.job_worker import run_job

    suite = write(tmp_path, f"""
        name = "u"
        scenarios = ["{write(tmp_path, GOOD)}"]
        seeds = [2]
        [[controllers]]
        label = "goto"
        name = "goto"
    """, "suite.toml")  # fmt: skip
    (job,) = expand(suite).jobs
    row = run_job(job, str(tmp_path / "out"))
    assert row["status"] == "ok", row["error"]
    assert row["realisation"] == job.realisation
    sc, _ = job.realised_scenario()
    assert sc.current != (0.1, 0.0)  # drawn, not the file's nominal current
    assert (row["current_N"], row["current_E"]) == sc.current  # the current simulated
    run = json.loads((tmp_path / "out" / row["run_dir"] / "run.json").read_text())
    assert run["realisation"]["id"] == job.realisation
    assert run["realisation"]["seed"] == 2


def test_nominal_simulation_draws_nothing(tmp_path):
    path = write(tmp_path, GOOD)
    out = tmp_path / "run"
    assert main(["simulate", str(path), "--nominal", "--out", str(out),
                 "--quiet", "--no-plots"]) == 0  # fmt: skip
    assert json.loads((out / "run.json").read_text())["realisation"]["values"] == {}


# ------------------------------------------------------------------ bad tables refused

U = '{ dist = "uniform", low = 0.0, high = 1.0 }'
BAD = {
    "unknown key": ("[uncertain.current]\nsped = " + U, "uncertain.current.sped"),
    "unknown table": ("[uncertain.wind]\nspeed = " + U, "uncertain.wind"),
    "unknown distribution": ('[uncertain.current]\nspeed = { dist = "gauss", low = 0.0, '
                             'high = 1.0 }', "gauss"),
    "no dist": ("[uncertain.current]\nspeed = { low = 0.0, high = 1.0 }",
                "uncertain.current.speed"),
    "uniform low >= high": ('[uncertain.current]\nspeed = { dist = "uniform", low = 0.3, '
                            'high = 0.1 }', "low < high"),
    "normal without bounds": ('[uncertain.asv]\nstart_N = { dist = "normal", mean = 0.0, '
                              'sd = 1.0, low = -1.0 }', "uncertain.asv.start_N.normal.high"),
    "normal sd 0": ('[uncertain.asv]\nstart_N = { dist = "normal", mean = 0.0, sd = 0.0, '
                    'low = -1.0, high = 1.0 }', "sd"),
    "string number": ('[uncertain.asv]\nstart_N = { dist = "uniform", low = "0", high = 1.0 }',
                      "uncertain.asv.start_N"),
    "choice probabilities": ('[uncertain.auv.a]\nupdate_period_s = { dist = "choice", values = '
                             '[10.0, 20.0], p = [0.5] }', "probabilities"),
    "unknown AUV": ("[uncertain.auv.b]\noffset_N = " + U, "uncertain.auv.b"),
    "probability above 1": ('[uncertain.acoustics]\np_good = { dist = "uniform", low = 0.9, '
                            'high = 1.2 }', "uncertain.acoustics.p_good"),
    "d1 above d2": ('[uncertain.acoustics]\nd1 = { dist = "uniform", low = 500.0, '
                    'high = 900.0 }', "d2"),
    "current above 2 m/s": ('[uncertain.current]\nspeed = { dist = "uniform", low = 0.0, '
                            'high = 2.5 }', "uncertain.current.speed"),
    "speed beyond the AUV's limit": ('[uncertain.auv.a]\nspeed_factor = { dist = "uniform", '
                                     'low = 1.0, high = 1.2 }', "speed_max"),
    "events reordered": ('[uncertain.auv.a]\nevent_time_s = { dist = "uniform", low = -30.0, '
                         'high = 30.0 }', "in order"),
    "said twice": ("[uncertain.auv.a]\noffset_N = " + U + "\n[uncertain.auv.all]\noffset_N = " + U,
                   "say it once"),
    "acoustic entry of a field that is not the channel's": (
        "[uncertain.acoustics]\nT0 = " + U, "uncertain.acoustics.T0"),
}  # fmt: skip

NO_EVENTS = {
    "event time without events": ("[uncertain.auv.a]\nevent_time_s = " + U, "no events"),
    "update period without a pursuer": ("[uncertain.auv.a]\nupdate_period_s = " + U,
                                        "never pursues"),
    "bearing error without USBL": ("[acoustics]\nusbl = false\n[uncertain.acoustics]\n"
                                   "sigma_bearing_deg = " + U, "changes nothing"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BAD) + sorted(NO_EVENTS))
def test_bad_uncertain_tables_are_refused_with_one_line(tmp_path, capsys, case):
    table, word = BAD.get(case) or NO_EVENTS[case]
    base = BASE if case in BAD else BASE.split("[[auv.events]]")[0]
    path = write(tmp_path, base + "\n" + table + "\n")
    assert_refused_in_one_line(path, word, tmp_path / "o", capsys)


def test_scenarios_without_uncertainty_draw_the_empty_realisation(scenarios_dir):
    sc = scenario_from_dict({"name": "n", "duration": 10.0, "auv": [{
        "name": "a", "behaviour": {"transit": {"heading_deg": 0.0, "speed": 1.0}}}]})
    done, real = realise(sc, 7)
    assert real.values == {} and done == sc


@pytest.mark.parametrize(("name", "word"), [("lauv.v2", "no '.' or ','"),
                                            ("lauv, roald", "no '.' or ','"),
                                            ("all", "every AUV")])  # fmt: skip
def test_an_auv_name_that_cannot_be_a_key_is_refused(tmp_path, capsys, name, word):
    """A '.' left every value drawn for ``lauv.v2`` unapplied (run.json listed them), a ','
    crashed compare's report (the results' comma-joined AUV list read three AUVs for two), and
    an AUV called ``all`` took [uncertain.auv.all] for its own (a new user, session 44)."""
    path = write(tmp_path, BASE.replace('name = "a"', f'name = "{name}"', 1))
    assert_refused_in_one_line(path, word, tmp_path / "o", capsys)
