"""Our Cases 1-8 have the shape of the papers' results (issue acceptance, seed 0)."""

from __future__ import annotations

import pytest

from mpcasv.controllers import make_controller
from mpcasv.experiments.metrics import compute_metrics
from mpcasv.sim.scenario import load_scenario
from mpcasv.sim.simulator import simulate


def run_case(scenarios_dir, name, seed=0):
    sc = load_scenario(scenarios_dir / f"{name}.toml")
    res = simulate(sc, make_controller(sc.controller, len(sc.auv), sc.preset), seed)
    return res, compute_metrics(res)


@pytest.mark.parametrize("case", ["case1", "case2"])
def test_simulation_cases_move_little_and_mostly_stand_by(scenarios_dir, case):
    _, m = run_case(scenarios_dir, case)
    assert m["distance_ratio"] <= 0.30
    assert m["standby_fraction"] >= 0.75


def test_case3_range_stays_in_the_published_band(scenarios_dir):
    res, m = run_case(scenarios_dir, "case3")
    r_outer = float(res.domain.outer(0.0))
    ts = res.timeseries
    assert m["min_range_m"] >= 15.0
    assert ts["range0"].max() <= r_outer + 40.0


@pytest.mark.parametrize("case", ["case4", "case8"])
def test_pursuers_never_get_closer_than_10_m(scenarios_dir, case):
    _, m = run_case(scenarios_dir, case)
    assert m["min_range_m"] >= 10.0
    assert m["label_avoidance_s"] > 0  # the pursuers really did threaten


@pytest.mark.parametrize("case", ["case6", "case7"])
def test_multi_auv_cases_revisit_every_auv_within_500_s(scenarios_dir, case):
    res, m = run_case(scenarios_dir, case)
    assert m["revisit_interval_max_s"] <= 500.0
    assert all(n > 0 for n in m["reliable_fixes_auv"])
    assert len(res.jumps) > 10  # it really cycled between the AUVs
