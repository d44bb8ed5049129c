"""Metrics (issue 12): one ground-truth account for every controller, the reliable-fix age of
Paper 2 eq. 9 by hand, the one reliable-fix / target-domain rule, the evaluation domain."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mpcasv.controllers import make_controller
from mpcasv.estimation.evaluate import estimator_figures
from mpcasv.experiments.metrics import (
    HEADLINE,
    METRIC_INFO,
    METRIC_NAMES,
    age_stats,
    compute_metrics,
    served_switches,
)
from mpcasv.hybrid.domains import (
    DomainParams,
    in_reliable_range,
    in_target_domain,
    reliable_fix_possible,
    target_reached,
)
from mpcasv.interface import Reason
from mpcasv.sim.account import evaluation_domain, stay_lengths
from mpcasv.sim.scenario import load_scenario, scenario_from_dict, scenario_with
from mpcasv.sim.simulator import simulate

FIELD = DomainParams(alpha_outer=17.5, alpha_inner=5.0, delta_r=20.0, eps_minus=10.0,
                     eps_plus=10.0)  # fmt: skip  # paper1-field: r_inner(0) = 50, r_t = 70


def _pass_by(duration=400.0, **extra):
    """The ASV stands still at the origin (propeller off); a surface AUV passes 60 m north of
    it eastwards at exactly 1 m/s, from E = -200 m. Judged with paper1-field's domain
    (r_t + eps = 80 m) and a channel that never loses a ping."""
    return scenario_from_dict({
        "name": "pass", "duration": duration, "controller": "hybrid-single",
        "preset": "paper1-field", "acoustics": {"p_good": 1.0},
        "auv": [{"name": "a", "start": {"N": 60.0, "E": -200.0, "psi_deg": 90.0, "speed": 1.0},
                 "behaviour": {"transit": {"heading_deg": 90.0, "speed": 1.0}}}],
    } | extra)  # fmt: skip


def _standing():
    return make_controller("goto", 1, None, overrides={"waypoint": [0.0, 0.0]})


# --- the reliable-fix age tau_k (Paper 2 eq. 9) ----------------------------------------------


def test_age_stats_of_hand_built_fix_times():
    # gaps 100, 5, 295, 100 over 500 s
    mx, p95, mean = age_stats([100.0, 105.0, 400.0], 500.0)
    assert mx == 295.0
    assert mean == pytest.approx((100**2 + 5**2 + 295**2 + 100**2) / (2 * 500))
    # time with age <= x is 5 + 100 + 100 + x (x in [100, 295]); 95 % of 500 s at x = 270
    assert p95 == pytest.approx(270.0)
    assert age_stats([], 60.0) == (60.0, 57.0, 30.0)  # one ramp from the known start


def test_reliable_fix_age_of_a_hand_built_trajectory():
    """A fix is reliable while hypot(60, E) < r_t + eps = 80 m, i.e. |E| < 52.9 m: for
    t in (147.1, 252.9) s. Pings every 5 s all arrive: reliable fixes at 150, 155, ..., 250 s;
    tau_k is a saw-tooth with gaps 150, twenty of 5, 150 over 400 s."""
    res = simulate(_pass_by(), _standing(), seed=3)
    assert res.reliable_fix_times[0] == [150.0 + 5 * j for j in range(21)]
    m = compute_metrics(res)
    assert m["reliable_fix_age_max_s"] == 150.0
    assert m["reliable_fix_age_mean_s"] == pytest.approx((2 * 150**2 + 20 * 5**2) / 800)
    assert m["reliable_fix_age_p95_s"] == pytest.approx(140.0)  # 100 + 2 x = 380
    assert m["reliable_fixes"] == 21 and m["fixes"] == 80
    assert m["fix_age_max_s"] == 5.0
    assert m["revisit_interval_max_s"] is None  # one AUV: Paper 1 has no such notion
    # a reliable fix was possible for 2 sqrt(80^2 - 60^2) / (1 m/s) = 105.83 s (plant steps)
    assert m["fix_possible_s"] == pytest.approx(2 * math.sqrt(80**2 - 60**2), abs=0.11)
    assert m["fix_possible_s_auv"] == [m["fix_possible_s"]]
    ts = res.timeseries
    np.testing.assert_allclose(ts["rfix_age0"].iloc[149], 0.0)  # t = 150: reset
    np.testing.assert_allclose(ts["rfix_age0"].iloc[148], 149.0)


def test_a_fix_is_reliable_only_with_the_propeller_off():
    """The same pass with the ASV motoring slowly towards the AUV and past it: fixes arrive,
    in reach too, none is reliable, and a reliable fix was never possible."""
    ctrl = make_controller("goto", 1, None, overrides={"waypoint": [0.0, -2000.0],
                                                       "speed": 0.6})  # fmt: skip
    res = simulate(_pass_by(duration=160.0), ctrl, seed=3)
    ts = res.timeseries
    assert ts["propeller_on"].iloc[20:].all()
    assert (ts["range0"] < 80.0).sum() >= 30  # within r_t + eps_plus for 30 s or more
    assert len(res.fix_times[0]) > 10 and res.reliable_fix_times[0] == []
    m = compute_metrics(res)
    assert m["reliable_fix_age_max_s"] == 160.0
    assert m["fix_possible_s"] == 0.0  # in reach only while motoring


# --- one geometric account, whatever the controller's labels --------------------------------


class _Relabelled:
    """The goto controller with another reason on every command and a domain of its own."""

    def __init__(self, reason: Reason, domain: DomainParams | None):
        self.inner = make_controller("goto", 1, None, overrides={"waypoint": [0.0, 300.0]})
        self.name, self.reason, self.domain = f"goto-{reason}", reason, domain

    def reset(self, n_auv: int) -> None:
        self.inner.reset(n_auv)

    def step(self, obs):
        return dataclasses.replace(self.inner.step(obs), reason=self.reason)


def test_same_trajectory_gives_the_same_geometric_metrics_whatever_the_labels():
    """The ASV runs East through the collision domain of an AUV waiting 20 m off its track;
    one controller calls it 'avoidance' and carries a huge domain of its own, the other
    'tracking' and none. Safety, liveness and navigation metrics are those of the scenario's
    domain for both. The labels do not reach the plant either: Gretha's power turn acts in
    escapes decided from the true ranges (docs/tuning.md), so the hard initial turn is the
    same under both labels."""
    sc = scenario_from_dict({
        "name": "through", "duration": 200.0, "controller": "hybrid-single",
        "preset": "paper1-field", "estimator": "perfect",
        "auv": [{"name": "a", "start": {"N": 20.0, "E": 150.0},
                 "behaviour": {"plan": {"speed": 1.0, "route": [
                     {"waypoints": [[20.0, 150.0, 0.0]]}]}}}],
    })  # fmt: skip
    huge = DomainParams(alpha_outer=2.0, alpha_inner=20.0, delta_r=50.0, eps_minus=10.0,
                        eps_plus=10.0)  # fmt: skip
    a = compute_metrics(simulate(sc, _Relabelled(Reason.AVOIDANCE, huge), seed=1))
    b = compute_metrics(simulate(sc, _Relabelled(Reason.TRACKING, None), seed=1))
    assert a["collision_domain_s"] > 5.0 and a["transit_escape_s"] > 5.0  # it did go through
    assert a["label_avoidance_s"] > 100 and b["label_avoidance_s"] == 0.0  # labels differ
    assert b["label_tracking_s"] == a["label_avoidance_s"]
    labels = {"label_avoidance_s", "label_tracking_s", "controller_step_ms_median",
              "controller_step_ms_p99"}  # fmt: skip
    for name in METRIC_NAMES:
        if name not in labels:
            np.testing.assert_equal(a[name], b[name], err_msg=name)  # NaN == NaN here


def _stationary_auv(name: str, duration: float, every_step: bool):
    """One AUV held at (20, 150) m at the surface; ``every_step``: one log row per plant
    step (``log_every_step``)."""
    return scenario_from_dict({
        "name": name, "duration": duration, "controller": "hybrid-single",
        "preset": "paper1-field", "sim": {"log_every_step": every_step},
        "auv": [{"name": "a", "start": {"N": 20.0, "E": 150.0},
                 "behaviour": {"plan": {"speed": 1.0, "route": [
                     {"waypoints": [[20.0, 150.0, 0.0]]}]}}}],
    })  # fmt: skip


def test_path_lengths_start_at_the_start():
    """The time series begins at the first period's end; the path lengths begin at the
    scenario's start (t = 0): an AUV at exactly 1 m/s for 10 s has covered 10 m, and an ASV
    started at 2 m/s straight north its displacement (the first second's leg was left out:
    9 m, and 2 m short; a new user's finding, session 47)."""
    sc = _pass_by(10.0, asv={"start": {"speed": 2.0}})
    res = simulate(sc, make_controller("goto", 1, None, overrides={"waypoint": [500.0, 0.0]}),
                   seed=0)  # fmt: skip
    ts = res.timeseries
    assert ts["t"].iloc[0] == 1.0 and ts["auv0_E"].iloc[-1] == pytest.approx(-190.0)
    m = compute_metrics(res)
    assert m["auv_distance_m"] == pytest.approx(10.0, rel=1e-9)
    assert np.abs(ts["E"]).max() < 1e-6  # straight north: the path is the displacement
    assert m["asv_distance_m"] == pytest.approx(ts["N"].iloc[-1], rel=1e-9)
    assert ts["N"].iloc[0] > 1.5  # the first leg is not negligible


def test_collision_time_is_counted_at_plant_step_resolution():
    """A stationary AUV; the ASV passes it. The account's time inside r_inner equals the
    plant steps logged inside (an independent count from the per-step log), and a single
    pass is one stay."""
    sc = _stationary_auv("through", 150.0, every_step=True)
    res = simulate(sc, make_controller("goto", 1, None, overrides={"waypoint": [0.0, 300.0]}),
                   seed=0)  # fmt: skip
    ts = res.timeseries
    assert (ts["auv0_N"] == 20.0).all() and (ts["auv0_E"] == 150.0).all()
    inside = np.hypot(ts["N"] - 20.0, ts["E"] - 150.0) < 50.0  # r_inner at the surface
    m = compute_metrics(res)
    assert m["collision_domain_s"] == pytest.approx(inside.sum() * 0.1)
    assert 91.65 / 3.0 < m["collision_domain_s"] < 91.65 / 1.5  # chord 2 sqrt(50^2 - 20^2)
    assert m["collision_domain_longest_s"] == pytest.approx(m["collision_domain_s"])
    assert m["transit_escape_s"] == pytest.approx(m["collision_domain_s"])  # motoring through
    assert m["propeller_on_s"] == pytest.approx(
        m["transit_escape_s"] + m["transit_tracking_s"] + m["transit_reposition_s"])


def test_stay_lengths_carry_across_periods():
    x = np.array([True, True, False, True])
    np.testing.assert_allclose(stay_lengths(x, 0.5, 0.1), [0.6, 0.7, 0.0, 0.1])


# --- the evaluation domain is the scenario's ---------------------------------------------------


def test_evaluation_domain_is_the_scenarios_published_one(scenarios_dir: Path):
    case1 = load_scenario(scenarios_dir / "case1.toml")
    dom = evaluation_domain(case1)
    assert (dom.alpha_inner, dom.delta_r, dom.eps_plus) == (3.0, 125.0, 30.0)  # paper1-sim
    res = simulate(scenario_with(case1, duration=5.0), _standing(), seed=0)
    assert res.domain == dom  # the goto controller has no domain; the world has the case's
    demo = load_scenario(scenarios_dir / "demo.toml")
    assert evaluation_domain(demo) is None  # the goto preset has no [domain]


def test_without_an_evaluation_domain_the_domain_metrics_are_null(scenarios_dir: Path):
    demo = load_scenario(scenarios_dir / "demo.toml")
    sc = scenario_with(demo, duration=20.0)
    m = compute_metrics(simulate(sc, make_controller("goto", len(sc.auv), "goto"), seed=0))
    for name in ("collision_domain_s", "beyond_outer_s", "transit_escape_s",
                 "reliable_fix_age_max_s", "reliable_fix_age_p95_s",
                 "fix_possible_s"):  # fmt: skip
        assert m[name] is None, name
    assert m["fix_age_max_s"] is not None and m["nav_error_rms_m"] is not None


# --- one reliable-fix / target-domain rule --------------------------------------------------


def test_reliable_fix_rule_is_strict_at_r_t_plus_eps_and_needs_the_propeller_off():
    r_t, eps = 70.0, 10.0
    assert reliable_fix_possible(79.999, r_t, eps, False)
    assert not reliable_fix_possible(80.0, r_t, eps, False)  # r_k < r_t,k + eps (eq. 9)
    assert not reliable_fix_possible(50.0, r_t, eps, True)  # n_p != 0
    assert reliable_fix_possible(5.0, r_t, eps, False)  # no lower limit in eq. 9
    got = reliable_fix_possible(np.array([50.0, 85.0, 50.0]), r_t, eps,
                                np.array([False, False, True]))  # fmt: skip
    assert list(got) == [True, False, False]
    assert FIELD.reliable_fix_possible(79.0, 70.0, False) and not FIELD.in_reliable_range(80, 70)
    assert in_reliable_range(79.0, r_t, eps) and not in_reliable_range(80.0, r_t, eps)


def test_target_domain_is_closed_and_the_jump_set_open():
    r_t = 70.0
    assert in_target_domain(60.0, r_t, 10.0, 10.0) and in_target_domain(80.0, r_t, 10.0, 10.0)
    assert not target_reached(60.0, r_t, 10.0, 10.0) and not target_reached(80.0, r_t, 10, 10)
    assert target_reached(60.001, r_t, 10.0, 10.0) and target_reached(79.999, r_t, 10, 10)


# --- the definitions ----------------------------------------------------------------------------


def test_every_metric_is_defined_once_with_unit_direction_and_definition():
    res = simulate(_pass_by(duration=30.0), _standing(), seed=0)
    assert set(compute_metrics(res)) == set(METRIC_INFO)
    assert set(HEADLINE) <= set(METRIC_INFO)
    for name, info in METRIC_INFO.items():
        assert info.unit and info.definition, name
        assert info.better in ("lower", "higher", None), name
    doc = (Path(__file__).parents[1] / "docs" / "metrics.md").read_text()
    for name in METRIC_INFO:
        assert f"`{name}`" in doc, name


def test_nothing_in_the_geometry_module_imports_upward():
    import mpcasv.hybrid.domains as d

    src = Path(d.__file__).read_text()
    imports = [ln for ln in src.splitlines() if ln.startswith(("import ", "from "))]
    assert all("mpcasv" not in ln or "mpcasv.config" in ln for ln in imports), imports
    assert math.isfinite(FIELD.r_in)


def test_revisit_interval_is_between_real_reliable_fixes_with_several_auvs():
    """Paper 2's 'time between consecutive visits' (Cases 6-7): once the ASV has begun its
    visits (the first reliable fix of any AUV), the wait for each AUV's first fix, the gaps
    between reliable fixes and the wait from the last one to the end (censored); not the
    ASV's first approach from t = 0; an AUV without a reliable fix has no finite interval
    (null)."""
    sc = scenario_from_dict({
        "name": "two", "duration": 60.0, "controller": "hybrid-multi", "preset": "paper2-field",
        "auv": [{"name": n, "start": {"N": N}, "behaviour": {"transit": {
            "heading_deg": 90.0, "speed": 1.0}}} for n, N in (("a", 60.0), ("b", -60.0))],
    })  # fmt: skip
    res = simulate(sc, make_controller("goto", 2, None, overrides={"waypoint": [0.0, 0.0]}), 0)
    hand = dataclasses.replace(res, reliable_fix_times=[[10.0, 15.0, 40.0], [5.0, 40.0]])
    m = compute_metrics(hand)
    assert m["revisit_interval_max_s"] == 35.0  # AUV b: 5 -> 40 (AUV a: at most 25)
    assert m["reliable_fix_age_max_s_auv"] == [25.0, 35.0]  # a: 0-10, 40-60 (end) count too
    hand = dataclasses.replace(res, reliable_fix_times=[[10.0, 15.0, 50.0], [5.0]])
    m = compute_metrics(hand)
    assert m["revisit_interval_max_s"] == 55.0  # b: 5 -> 60 (the end) without a revisit
    assert m["reliable_fix_age_max_s"] == 55.0
    # one visit each, two fixes 5 s apart in it, then none (a new user's suite, session 45:
    # it scored 5 s, the best value, for never revisiting either AUV)
    hand = dataclasses.replace(res, reliable_fix_times=[[12.0, 17.0], [30.0, 35.0]])
    assert compute_metrics(hand)["revisit_interval_max_s"] == 43.0  # a: 17 -> 60
    # b left unvisited until near the end, once (a review, session 45: it scored 2 s, the
    # time that remained, where it had waited from the ASV's first visit at 10 s to 58 s)
    hand = dataclasses.replace(res, reliable_fix_times=[[10.0, 25.0, 40.0, 55.0], [58.0]])
    assert compute_metrics(hand)["revisit_interval_max_s"] == 48.0
    hand = dataclasses.replace(res, reliable_fix_times=[[10.0, 15.0, 50.0], []])
    m = compute_metrics(hand)
    assert m["revisit_interval_max_s"] == math.inf  # b never visited; null in metrics.json


def test_between_steps_ms_max_is_null_when_no_solve_ran_between_steps(tmp_path):
    """New-user check: a run without an exploration solve after a step's command (a hybrid
    controller; an MPC whose exploration never came due) had ``between_steps_ms_max`` = 0,
    read as "took 0 ms". It is null (not measured), as the other undefined metrics; the
    results table, the summary and the paired statistics take it as missing."""
    import json

    from mpcasv.experiments.job_worker import _metric_columns
    from mpcasv.experiments.report import summary_table
    from mpcasv.experiments.stats import paired_table
    from mpcasv.experiments.store import read_parts, write_part
    from mpcasv.sim.record import write_run

    res = simulate(_pass_by(duration=30.0), _standing(), seed=0)
    m = compute_metrics(res)
    assert "mpc_explore_ms" not in res.timeseries and m["between_steps_ms_max"] is None
    nan = np.full(len(res.timeseries), np.nan)  # an MPC's column, no exploration ran
    m = compute_metrics(dataclasses.replace(res, timeseries=res.timeseries.assign(
        mpc_explore_ms=nan)))  # fmt: skip
    assert m["between_steps_ms_max"] is None
    some = nan.copy()
    some[[3, 7]] = [4.5, 2.0]
    m = compute_metrics(dataclasses.replace(res, timeseries=res.timeseries.assign(
        mpc_explore_ms=some)))  # fmt: skip
    assert m["between_steps_ms_max"] == 4.5
    written = write_run(res, tmp_path / "run", compute_metrics(res), plots=False)
    assert written["between_steps_ms_max"] is None
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())[
        "between_steps_ms_max"] is None  # fmt: skip
    # the results store: rows of hybrid runs (missing) and MPC runs (a value) side by side
    for i, (variant, value) in enumerate([("H", None), ("M", 4.5)] * 5):
        row = {"job_id": f"j{i}", "scenario": "s", "variant": variant, "current": "off",
               "estimator": "perfect", "seed": i // 2, "status": "ok"}  # fmt: skip
        write_part(tmp_path / "sweep", row | _metric_columns({"between_steps_ms_max": value}))
    df = read_parts(tmp_path / "sweep")
    col = df["between_steps_ms_max"]
    assert col.dtype == float and col.isna().sum() == 5 and (col.dropna() == 4.5).all()
    summ = summary_table(df).set_index("variant")
    assert summ.loc["H", "n"] == 0 and math.isnan(summ.loc["H", "mean"])
    assert summ.loc["M", "n"] == 5 and summ.loc["M", "mean"] == 4.5
    stat = paired_table(df, ["between_steps_ms_max"], {"between_steps_ms_max": "lower"})
    assert stat.loc[0, "n"] == 0 and stat.loc[0, "note"] == "no pairs", stat


class _Flagged:
    """A go-to controller whose diagnostics flag every third step as carried, hung, over
    budget and planned in an untested current (as an MPC's ``mpc_source``, ``mpc_hung``,
    ``mpc_over_budget``, ``mpc_cur_untested``)."""

    name = "goto"

    def __init__(self):
        self._c = make_controller("goto", 1, None, overrides={"waypoint": [0.0, 300.0]})
        self.k = 0

    def reset(self, n_auv):
        self._c.reset(n_auv)
        self.k = 0

    def step(self, obs):
        self.k += 1
        return self._c.step(obs)

    def diagnostics(self):
        f = self.k % 3 == 0
        return {"mpc_source": "carried" if f else "plan", "mpc_hung": int(f),
                "mpc_over_budget": int(f), "mpc_cur_untested": float(f)}  # fmt: skip


@pytest.mark.parametrize("every_step", [False, True])
def test_step_counts_count_controller_steps_whatever_the_log(every_step):
    """``carried_steps``, ``solver_hangs`` and ``over_budget_steps`` count controller steps:
    the same with one row per plant step (``log_every_step``, 10 rows per step here) as with
    one per step (they counted rows before session 14: ten times too many);
    ``current_untested_s`` is those steps' control periods (1 s each here)."""
    res = simulate(_stationary_auv("flags", 30.0, every_step), _Flagged(), seed=0)
    assert len(res.timeseries) == (300 if every_step else 30)
    m = compute_metrics(res)
    assert m["carried_steps"] == m["solver_hangs"] == m["over_budget_steps"] == 10
    assert m["current_untested_s"] == 10.0


def test_a_run_gives_the_same_metrics_however_it_was_logged():
    """A hybrid multi-AUV run of two moving AUVs logged once per period and once per plant
    step: every metric but the wall-clock ones is the same (the path lengths counted every
    plant step's before session 46: 0.03-0.06 % longer, an auditor's finding), and a plant
    step's row holds that step's AUV truth, range and propeller (they stayed the period
    end's)."""
    def run(every: bool):
        sc = scenario_from_dict({
            "name": "two", "duration": 120.0, "controller": "hybrid-multi",
            "preset": "paper2-field", "estimator": "perfect", "sim": {"log_every_step": every},
            "auv": [{"name": n, "start": {"N": N, "E": E, "depth": 10.0},
                     "behaviour": {"transit": {"heading_deg": h, "speed": 1.5, "depth": 10.0}}}
                    for n, N, E, h in (("a", 150.0, 0.0, 90.0), ("b", -100.0, 200.0, 0.0))],
        })  # fmt: skip
        return simulate(sc, make_controller("hybrid-multi", 2, "paper2-field"), seed=3)

    per_period, per_step = run(False), run(True)
    a, b = compute_metrics(per_period), compute_metrics(per_step)
    assert a["asv_distance_m"] > 50.0 and a["propeller_toggles"] > 0  # it moved, it switched
    assert a["target_switches"] >= 2  # the hybrid's AUV served changed (the metric was 0)
    for name in METRIC_NAMES:
        if name not in {"controller_step_ms_median", "controller_step_ms_p99"}:
            same = b[name] if b[name] is None else pytest.approx(b[name], rel=1e-12)  # sums
            assert a[name] == same, name
    ts = per_step.timeseries
    for k in range(2):
        np.testing.assert_allclose(ts[f"range{k}"], np.hypot(ts["N"] - ts[f"auv{k}_N"],
                                                             ts["E"] - ts[f"auv{k}_E"]))
    assert ts["auv0_E"].diff().iloc[601:610].gt(0.1).all()  # moving within a period
    np.testing.assert_array_equal(ts["propeller_on"], ts["prop_on_s"] > 0)
    # the estimators' figures too set the belief against the truth at the period ends (with
    # the plant steps' truth beside the period end's belief, a perfect estimator was 0.7 m
    # off: a reviewer's finding)
    fa, fb = estimator_figures(per_period), estimator_figures(per_step)
    assert fa["pos_error_rms_m"] < 1e-9
    assert fa == pytest.approx(fb, rel=1e-12, nan_ok=True)


def test_target_switches_count_the_changes_of_the_auv_served_for_every_controller():
    """The commands' AUV (``auv_served``, -1: none) changes twice here: 2 -> 0 -> 1; the
    first AUV served is no change, nor are the steps that serve none. Before session 46 the
    metric was the MPC's own counter: 0 for a hybrid controller whatever it served, and the
    MPC's first choice counted when it was not AUV 0."""
    steps = pd.DataFrame({"auv_served": [-1, 2, 2, -1, 2, 0, 0, -1, 1, 1]})
    assert served_switches(steps) == 2
    assert served_switches(pd.DataFrame({"auv_served": [0] * 5})) == 0
