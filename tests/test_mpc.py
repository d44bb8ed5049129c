"""The CasADi MPC on the published cases: safety, standby, fallback, QP variant agreement.

The compiled NLP is cached on disk (``$MPCASV_CACHE`` or ``~/.cache/mpcasv``): the first run
on a machine compiles the single- and multi-AUV problems once (about a minute each).
"""

from __future__ import annotations

import pytest

from mpcasv.experiments.metrics import compute_metrics
from mpcasv.sim.controllers import make_controller
from mpcasv.sim.scenario import load_scenario, scenario_with
from mpcasv.sim.simulator import simulate


def run(scenarios_dir, case, overrides=None, duration=None, seed=0):
    sc = load_scenario(scenarios_dir / f"{case}.toml")
    if duration is not None:
        sc = scenario_with(sc, duration=duration)
    name = "mpc-multi" if len(sc.auv) > 1 else "mpc-single"
    ctrl = make_controller(name, len(sc.auv), name, overrides=overrides)
    res = simulate(sc, ctrl, seed)
    return res, compute_metrics(res)


@pytest.mark.parametrize("case", ["case4", "case8"])
def test_mpc_keeps_pursuers_at_least_10_m_away(scenarios_dir, case):
    res, m = run(scenarios_dir, case)
    assert m["min_range_m"] >= 10.0
    assert m["duration_s"] == pytest.approx(res.scenario.duration)


def test_mpc_mostly_stands_by_in_case1(scenarios_dir):
    _, m = run(scenarios_dir, "case1")
    assert m["standby_fraction"] >= 0.7


def test_forced_solver_failure_engages_the_fallback_and_stays_safe(scenarios_dir):
    res, m = run(scenarios_dir, "case4", overrides={"solver.max_iter": 0}, duration=400.0)
    assert m["fallbacks"] > 0
    assert m["min_range_m"] >= 10.0
    assert m["duration_s"] == pytest.approx(400.0)
    assert (res.timeseries["reason"] == "fallback").any() or m["fallbacks"] > 0


@pytest.mark.xfail(
    strict=True,
    reason="known bug: the QP variant's linearisation diverges within a few steps on case3 "
    "(OSQP refuses bounds of order 1e107); see the closing note of issue 4",
)
def test_qp_variant_and_default_agree_on_a_simple_case(scenarios_dir):
    _, m_nlp = run(scenarios_dir, "case3", duration=400.0)
    _, m_qp = run(scenarios_dir, "case3", overrides={"solver.solver": "qp"}, duration=400.0)
    assert m_qp["time_outside_outer_s"] <= m_nlp["time_outside_outer_s"] + 20.0
    assert m_qp["min_range_m"] >= 10.0
    assert m_qp["standby_fraction"] == pytest.approx(m_nlp["standby_fraction"], abs=0.15)
    assert m_qp["asv_distance_m"] == pytest.approx(m_nlp["asv_distance_m"], rel=0.25)
