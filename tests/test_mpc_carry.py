"""Issue 16 item 8: a bounded step (``solver.step_iter``, mpcasv/mpc/carry.py). A warm-started
solve that stops at the step's iteration budget is finished after the command; the step
follows the previous plan moved one period on, if the safety check lets it. The budget may
change when a plan is used, never what it is: a solve that converges within it gives the
plan it gives without one, the work done after the command is the step's work without a
budget, and a carry the check refuses leaves the run as it is without a budget.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest
from test_mpc_between_steps import _NoHook, _same_decisions
from test_mpc_deadline import WALL_COLUMNS

from mpcasv.controllers import make_controller
from mpcasv.mpc.solver_params import SolverParams
from mpcasv.sim.scenario import load_scenario, scenario_with
from mpcasv.sim.simulator import simulate

CAP = 15
#: Case 6 (three AUVs, seed 0) to just past the arrival at the first AUV (t = 98-105 s),
#: where the warm-started solves need 17 to more than 50 iterations (measured with the budget off)
DURATION = 110.0


def _case6(scenarios_dir, duration=DURATION):
    return scenario_with(load_scenario(scenarios_dir / "case6.toml"), duration=duration)


def _instrument(ctrl) -> dict:
    """Record every plan stored (by step time: its times, positions and source), the steps
    after which an exploration's plan became the warm start, and for every carried step's
    work done after the command: its start and the warm start it left for the next step."""
    log = {"plans": {}, "deferred": [], "adopted": set()}
    store, finish, between = ctrl._store_plan, ctrl._finish_deferred, ctrl.between_steps

    def stored(t, w):
        store(t, w)
        log["t"] = round(t, 6)
        log["plans"][log["t"]] = (ctrl.plan.t.copy(), ctrl.plan.N.copy(), ctrl.plan.E.copy(),
                                  ctrl._diag["mpc_source"])  # fmt: skip

    def finished():
        d, explored = ctrl.deferred, ctrl.explored
        finish()
        source = ctrl._diag.get("mpc_deferred_source")
        if ctrl.explored > explored:  # the work explored (a target change, a threat): its
            source = "explored"  # plan may be the exploration's, not the warm solve's
        log["deferred"].append((d, ctrl.w_prev, source))

    def between_logged():
        n = ctrl.explore_adopted
        between()
        if ctrl.explore_adopted > n:
            log["adopted"].add(log.get("t"))

    ctrl._store_plan, ctrl._finish_deferred = stored, finished
    ctrl.between_steps = between_logged
    return log


@pytest.fixture(scope="module")
def carried(scenarios_dir):
    ctrl = make_controller("mpc-multi", 3, "mpc-multi", {"solver.step_iter": CAP})
    log = _instrument(ctrl)
    ts = simulate(_case6(scenarios_dir), ctrl, seed=0).timeseries
    return ctrl, ts, log


def test_a_solve_within_the_budget_gives_the_plan_it_gives_without_one(scenarios_dir):
    """The premise: the solver's iterates do not depend on its iteration limit. Every main
    solve of 40 s of Case 6 (no budget) that converged within ``CAP`` iterations, solved
    again with ``max_iter = CAP``: the same plan, cost and iterations, bit for bit."""
    ctrl = make_controller("mpc-multi", 3, "mpc-multi", {"solver.hang_s": 0.0,
                                                        "solver.step_iter": None})  # fmt: skip
    solve, seen = ctrl.solver.solve, []

    def twice(p, w0, lam_x=None, lam_g=None, max_iter=None, **kw):
        res = solve(p, w0, lam_x, lam_g, max_iter, **kw)
        if max_iter is None and res.ok and res.iters <= CAP:
            seen.append((res, solve(p, w0, lam_x, lam_g, CAP, **kw)))
        return res

    ctrl.solver.solve = twice
    simulate(_case6(scenarios_dir, 40.0), ctrl, seed=0)
    assert len(seen) >= 20
    for full, capped in seen:
        assert capped.ok and capped.iters == full.iters and capped.f == full.f
        np.testing.assert_array_equal(capped.w, full.w)


def test_a_slow_solve_carries_the_previous_plan(carried):
    """Steps whose warm-started solve stopped at the budget (fatrop counts ``CAP + 1``)
    followed the previous step's plan moved one period on: the same positions at the same
    times (stages 1 to N-1; the first is the state now, as in every solved plan, the last is
    held by the shift). That plan is the one the previous step commanded, or, when that step
    was carried too, the one its work after the command found. No target change is carried
    (its exploration belongs in the step)."""
    ctrl, ts, log = carried
    steps = [t for t, (*_, source) in log["plans"].items() if source == "carried"]
    assert len(steps) >= 2, "no step carried its plan: the test sees nothing"
    assert (ts["mpc_source"] == "carried").sum() == len(steps)
    assert ctrl.fallbacks == 0
    iters = dict(zip((ts["t"] - 1.0).round(6), ts["mpc_iter"], strict=True))  # rows: t + Tc
    found = {round(d.obs.t, 6): w for d, w, _ in log["deferred"]}
    checked = 0
    for t in steps:
        assert iters[t] >= CAP
        before = round(t - 1.0, 6)
        if before in log["adopted"]:  # an exploration's plan started this step: not compared
            continue
        if before in found:
            Z, _ = ctrl.ocp.split(found[before])
            t_prev = before + ctrl.ocp.dt * np.arange(Z.shape[0])
            N_prev, E_prev = Z[:, 0], Z[:, 1]
        else:
            t_prev, N_prev, E_prev, _ = log["plans"][before]
        t_now, N_now, E_now, _ = log["plans"][t]
        np.testing.assert_allclose(N_now[1:-1], np.interp(t_now[1:-1], t_prev, N_prev),
                                   atol=1e-6)  # fmt: skip
        np.testing.assert_allclose(E_now[1:-1], np.interp(t_now[1:-1], t_prev, E_prev),
                                   atol=1e-6)  # fmt: skip
        checked += 1
    assert checked >= 2
    switched = ts["mpc_target_switches"].diff().fillna(0).to_numpy() > 0
    assert not np.any(switched & (ts["mpc_source"] == "carried").to_numpy())
    # the commands serve the target (the AUV the metric target_switches follows); before
    # session 46 they named the AUV whose target circle the plan's end was nearest
    np.testing.assert_array_equal(ts["auv_served"], ts["mpc_target"])


def test_the_work_after_a_carried_step_is_the_step_without_a_budget(carried):
    """After each carried step's command: the warm-started solve from the same start with the
    full iteration limit (a plan that needed no exploration or rescue: exactly that solve's
    plan warm-starts the next step)."""
    ctrl, _, log = carried
    plain = [(d, w) for d, w, source in log["deferred"] if source == "plan"]
    assert plain, "no carried step's work ended in a plain plan"
    for d, w_next in plain:
        full = ctrl.solver.solve(d.p_s, d.w0, *d.lam)
        if full.iters <= CAP:
            pytest.fail(f"the work after a carried step converged within the budget: {full.iters}")
        np.testing.assert_array_equal(w_next, full.w)


def test_the_decisions_do_not_depend_on_who_runs_the_work_after_the_command(scenarios_dir,
                                                                            carried):  # fmt: skip
    ctrl, ts, _ = carried
    lazy = make_controller("mpc-multi", 3, "mpc-multi", {"solver.step_iter": CAP})
    ts_lazy = simulate(_case6(scenarios_dir), _NoHook(lazy), seed=0).timeseries
    _same_decisions(ctrl, ts, lazy, ts_lazy)


def test_a_carry_the_check_refuses_leaves_the_run_as_without_a_budget(scenarios_dir,
                                                                      monkeypatch):  # fmt: skip
    """With every carried plan refused by the safety check, a solve stopped at the budget is
    solved again in full in the step: the run is the run without a budget (but for the
    iterations the stopped solves took, counted in ``mpc_iter``)."""
    from mpcasv.mpc.safety import Safety

    check = Safety._check
    refused = []

    def no_carry(self, res, p):
        if res.status == "carried":
            refused.append(res)
            return "refused (test)"
        return check(self, res, p)

    monkeypatch.setattr(Safety, "_check", no_carry)
    runs = {}
    for cap in (None, CAP):
        ctrl = make_controller("mpc-multi", 3, "mpc-multi",
                               {"solver.step_iter": cap})
        runs[cap] = simulate(_case6(scenarios_dir), ctrl, seed=0).timeseries
    assert refused, "no carry was asked for: the test sees nothing"
    drop = [*WALL_COLUMNS, "mpc_iter"]
    pd.testing.assert_frame_equal(runs[None].drop(columns=drop), runs[CAP].drop(columns=drop))
    assert (runs[CAP]["mpc_iter"] >= runs[None]["mpc_iter"]).all()
    assert (runs[CAP]["mpc_iter"] > runs[None]["mpc_iter"]).sum() == len(refused)


def test_step_iter_is_refused_where_it_means_nothing():
    with pytest.raises(ValueError, match="step_iter"):
        dataclasses.replace(SolverParams(), solver="qp", step_iter=CAP)
    with pytest.raises(ValueError, match="step_iter"):
        SolverParams(step_iter=-1)


@pytest.mark.parametrize(("controller", "preset", "expected"), [
    ("mpc-multi", "mpc-multi", 20), ("mpc-multi", "mpc-multi-order", 20),
    ("mpc-multi", "mpc-multi-variance", 20), ("mpc-single", "mpc-single", None),
    ("mpc-single", "mpc-single-sim", None),
])  # fmt: skip
def test_the_presets_budget_the_step_with_several_auvs_and_0_turns_it_off(controller, preset,
                                                                          expected):
    """Session 16: the several-AUV presets set ``step_iter = 20`` (item 8's whole-step p99;
    docs/mpc.md "Closed loop ... session 16"), the one-AUV presets none. A suite or preset
    says "off" with 0 (TOML has no null), read as None: the same controller, the same job."""
    from mpcasv.controllers.registry import load_preset

    assert load_preset(controller, preset).solver.step_iter == expected
    off = load_preset(controller, preset, {"solver.step_iter": 0})
    assert off.solver.step_iter is None
    assert off == load_preset(controller, preset, {"solver.step_iter": None})


def test_no_carry_at_a_target_change_or_from_a_plan_that_is_not_a_converged_one(scenarios_dir):
    """The rule itself: the budget applies only when the warm start is a converged plan the
    check let through (``w_ok``) and the target did not just change (``t_explore`` None:
    its exploration runs in the step, and deferring it cost Case 8 39 s of fix age in
    session 8)."""
    ctrl = make_controller("mpc-multi", 3, "mpc-multi", {"solver.step_iter": CAP})
    ctrl.w_prev, ctrl.w_ok, ctrl.t_explore = np.zeros(3), True, 10.0
    assert ctrl._step_limit() == CAP
    ctrl.t_explore = None
    assert ctrl._step_limit() is None
    ctrl.t_explore, ctrl.w_ok = 10.0, False
    assert ctrl._step_limit() is None
    with pytest.raises(ValueError, match="below max_iter"):
        dataclasses.replace(SolverParams(), step_iter=50, max_iter=50)


def test_work_cut_short_after_a_carried_step_leaves_a_warm_start_in_step(scenarios_dir):
    """The deploy loop swallows an exception in ``between_steps`` (the command was sent).
    If a carried step's work is cut short so, the next step starts from the carried plan
    (moved one period on, as any warm start), not from the plan of two steps before, and may
    not carry it again without a solve."""
    ctrl = make_controller("mpc-multi", 3, "mpc-multi", {"solver.step_iter": CAP,
                                                         "solver.hang_s": 0.0})  # fmt: skip
    finish, between, cut = ctrl._finish_deferred, ctrl.between_steps, []

    def cut_short():
        if not cut:
            d, ctrl.deferred = ctrl.deferred, None
            cut.append((d, ctrl.w_prev, ctrl.w_ok))
            raise RuntimeError("cut short (test)")
        finish()

    def swallowing():
        try:
            between()
        except RuntimeError:
            pass

    ctrl._finish_deferred, ctrl.between_steps = cut_short, swallowing
    ts = simulate(_case6(scenarios_dir), ctrl, seed=0).timeseries
    assert cut, "no step carried its plan: the test sees nothing"
    d, w_prev, w_ok = cut[0]
    assert w_prev is d.w0 and not w_ok
    row = ts.index[np.isclose(ts["t"] - 1.0, d.obs.t)][0]  # rows at t + Tc
    assert ts.loc[row, "mpc_source"] == "carried"
    assert ts.loc[row + 1, "mpc_source"] != "carried"
