"""The MPC rarely hands a step to the hybrid controller (issue 16 item 7; docs/mpc.md,
"Fallbacks"): a plan that cannot be used is first rescued (solves from the unconverged
iterate, an escape guess and the hybrid's command, within ``rescue_iter`` iterations); a plan
that goes no deeper into an anti-collision radius than the escape manoeuvre is used; else the
escape manoeuvre is flown; the hybrid takes the step only when no AUV is near."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from mpcasv.controllers import make_controller
from mpcasv.interface import ASVState, AUVEstimate, Mode, Observation, Reason
from mpcasv.mpc.rescue import command_guess, escape_guess
from mpcasv.mpc.solvers import SolveResult


@pytest.fixture
def ctrl():
    c = make_controller("mpc-single", 1, "mpc-single")
    c.reset(1)
    return c


def test_a_failed_warm_solve_is_rescued_with_the_larger_budget(ctrl, monkeypatch):
    """The warm-started solve stops at its iteration limit: the rescue solves (with
    ``rescue_iter``) find a plan; no fallback."""
    real, calls = ctrl.solver.solve, []

    def solve(p, w0, lx=None, lg=None, max_iter=None):
        calls.append(max_iter)
        if max_iter is None:  # the main and exploration solves: at the iteration limit
            return SolveResult(np.asarray(w0, float), None, None, 1.0, False, "1", 50, 1.0)
        return real(p, w0, lx, lg, max_iter)

    monkeypatch.setattr(ctrl.solver, "solve", solve)
    obs = Observation(0.0, ASVState(0.0, 0.0, 0.0, 1.0), True,
                      (AUVEstimate(120.0, 0.0, 0.0, 0.5, 0.0),))  # fmt: skip
    cmd = ctrl.step(obs)
    assert ctrl.rescues == 1 and ctrl.sources == {"rescue": 1}
    assert ctrl.params.solver.rescue_iter in calls
    assert ctrl.fallbacks == 0 and cmd.reason != Reason.FALLBACK
    assert ctrl.diagnostics()["mpc_source"] == "rescue" and ctrl.diagnostics()["mpc_ok"] == 1


def test_a_failed_warm_solve_tries_the_due_exploration_in_the_step_before_a_rescue(
        ctrl, monkeypatch):  # fmt: skip
    """A periodic exploration is due (the last one 10 s ago; it would otherwise wait until
    after the command, ``between_steps``) and the warm-started solve stops at its iteration
    limit: the exploration runs in the step, first; its converged plan is used, so no rescue
    is needed and nothing is left for after the command."""
    real, calls = ctrl.solver.solve, []

    def solve(p, w0, lx=None, lg=None, max_iter=None):
        calls.append(max_iter)
        if len(calls) == 1:  # the warm-started solve: at the iteration limit
            return SolveResult(np.asarray(w0, float), None, None, 1.0, False, "1", 50, 1.0)
        return real(p, w0, lx, lg, max_iter)

    monkeypatch.setattr(ctrl.solver, "solve", solve)
    ctrl.t_explore = -10.0
    obs = Observation(0.0, ASVState(0.0, 0.0, 0.0), False, (AUVEstimate(400.0, 0.0, 0.0),))
    ctrl.step(obs)
    assert ctrl.explored == 1 and calls == [None, None] and ctrl.rescues == 0
    assert ctrl.sources == {"plan": 1} and ctrl._pending is None
    assert ctrl.diagnostics()["mpc_ok"] == 1 and ctrl.diagnostics()["mpc_iter"] > 50


def _always(monkeypatch, ctrl, plan):
    """Every solve 'converges' to ``plan(p)``."""
    monkeypatch.setattr(ctrl.solver, "solve", lambda p, w0, *a: SolveResult(
        plan(p), None, None, 1.0, True, "0", 5, 1.0))


def _pursued() -> Observation:
    """An AUV 60 m north of the ASV coming straight at it at 3 m/s (within r_inner +
    margin in 8 s whatever the ASV does); the ASV heads east at 1 m/s."""
    return Observation(0.0, ASVState(0.0, 0.0, math.pi / 2, 1.0), True,
                       (AUVEstimate(60.0, 0.0, 0.0, -3.0, 0.0),))  # fmt: skip


def test_a_plan_deeper_than_the_escape_is_replaced_by_the_escape(ctrl, monkeypatch):
    """Every solve returns the plan that turns towards the AUV at full thrust: it goes deeper
    than the escape manoeuvre (full thrust away) by more than ``check_margin``, so the escape
    manoeuvre is flown instead, not the hybrid's command."""
    obs = _pursued()
    p = ctrl.parameters(obs)
    towards = command_guess(ctrl.ocp, p, (60.0, 0.0), 2.5)
    esc = escape_guess(ctrl.ocp, p, ctrl.params.margin)
    cm = ctrl.params.solver.check_margin
    assert ctrl._depth(towards, p) > ctrl._depth(esc, p) + cm
    _always(monkeypatch, ctrl, lambda q: command_guess(ctrl.ocp, q, (60.0, 0.0), 2.5))
    cmd = ctrl.step(obs)
    assert ctrl.sources == {"escape": 1} and ctrl.fallbacks == 0 and ctrl.rescues == 1
    assert ctrl.diagnostics()["mpc_source"] == "escape"
    assert cmd.mode == Mode.TRANSIT and cmd.reason != Reason.FALLBACK
    assert cmd.waypoint[0] < 0.0  # south: away from the AUV
    np.testing.assert_allclose(ctrl.w_prev, esc)  # the next step starts from the escape


def test_a_refused_plan_no_deeper_than_the_escape_is_used(ctrl, monkeypatch):
    """The same AUV cannot be escaped: the escape manoeuvre itself goes deeper than the check
    allows; a converged plan going no deeper than it is the best there is and is used."""
    obs = _pursued()
    p = ctrl.parameters(obs)
    esc = escape_guess(ctrl.ocp, p, ctrl.params.margin)
    assert ctrl._check(SolveResult(esc, None, None, 1.0, True, "0", 5, 1.0), p) is not None
    _always(monkeypatch, ctrl, lambda q: escape_guess(ctrl.ocp, q, ctrl.params.margin))
    cmd = ctrl.step(obs)
    assert ctrl.sources == {"as-escape": 1} and ctrl.fallbacks == 0 and ctrl.rescues == 1
    assert cmd.reason != Reason.FALLBACK and ctrl.diagnostics()["mpc_ok"] == 1


def test_an_auv_the_current_carries_the_asv_to_is_a_threat(ctrl):
    """A still AUV 80 m north of an ASV at rest (anti-collision radius 50 m, margin 5 m:
    beyond its radius plus the 20 m buffer): no threat in still water; a 0.5 m/s current
    towards it carries the stopped ASV within 50 m in the 60 s horizon, so it is one (and the
    escape guess exists); the same current across the line is not. Before session 34 the
    ASV was held where it was and the AUV was no threat in any current."""
    from mpcasv.mpc.rescue import threats

    obs = Observation(0.0, ASVState(0.0, 0.0, 0.0, 0.0), False,
                      (AUVEstimate(80.0, 0.0, 0.0, 0.0, 0.0),))  # fmt: skip
    p = ctrl.parameters(obs)
    par = ctrl.ocp.unpack_par(p)  # views into p
    assert par["r_lo"][0, 0] == 55.0 and ctrl.ocp.t_stage[-1] == 60.0
    m = ctrl.params.margin
    assert not threats(ctrl.ocp, p, m).any() and escape_guess(ctrl.ocp, p, m) is None
    par["current"][:] = (0.5, 0.0)
    assert threats(ctrl.ocp, p, m).all() and escape_guess(ctrl.ocp, p, m) is not None
    par["current"][:] = (0.0, 0.5)
    assert not threats(ctrl.ocp, p, m).any()


def test_far_from_every_auv_a_refused_plan_goes_to_the_hybrid(ctrl, monkeypatch):
    """No AUV near (no escape to compare with) and no solve converges: the hybrid controller
    takes the step, with the solver's reason."""
    monkeypatch.setattr(ctrl.solver, "solve", lambda p, w0, *a: SolveResult(
        np.asarray(w0, float), None, None, 1.0, False, "1", 50, 1.0))
    obs = Observation(0.0, ASVState(0.0, 0.0, 0.0, 1.0), True,
                      (AUVEstimate(120.0, 0.0, 0.0, 0.5, 0.0),))  # fmt: skip
    cmd = ctrl.step(obs)
    assert ctrl.sources == {"fallback": 1} and cmd.reason == Reason.FALLBACK
    assert ctrl.fallback_log[0].reason == "solver: 1"


def test_case8_needs_the_fallback_at_most_once(scenarios_dir):
    """Case 8 (nominal, pursuers re-aimed at the ASV): before issue 16 item 7 the MPC handed
    73 steps to the hybrid controller and spent 92.2 s inside r_avoid (min range 26.0 m;
    measured at commit 0e06b82 with ``mpcasv simulate experiments/scenarios/case8.toml
    --nominal --controller mpc-multi --params mpc-multi``); now at most one fallback and no
    more time inside."""
    from mpcasv.experiments.metrics import compute_metrics
    from mpcasv.sim.scenario import load_scenario
    from mpcasv.sim.simulator import simulate

    sc = load_scenario(scenarios_dir / "case8.toml")
    c = make_controller("mpc-multi", len(sc.auv), "mpc-multi")
    m = compute_metrics(simulate(sc, c, 0))
    assert m["fallbacks"] <= 1
    assert m["collision_domain_s"] <= 92.2
    # the pursuers kept at least 10 m away, over the whole run (this run was also
    # test_mpc.py's test_mpc_keeps_pursuers_at_least_10_m_away[case8]: run once, 45 s)
    assert m["min_range_m"] >= 10.0
    assert m["duration_s"] == pytest.approx(sc.duration)


def test_after_a_hung_solve_in_simulation_the_step_is_still_planned(tmp_path):
    """Simulation's hang guard (``hang_s``): a solve that never returns is abandoned (as the
    recorded Case 4 problem that hangs fatrop, docs/mpc.md "Known problems"); the step is then
    planned by the exploration or rescue solves on a new worker (that Case 4 problem
    converges from the escape guess and from a rollout), not handed to the hybrid. As
    use_hang_guard: no spare worker, the successor is started by the next solve."""
    from test_mpc_deadline import hang_once_solver

    c = make_controller("mpc-single", 1, "mpc-single", overrides={"solver.hang_s": 5.0})
    flag = tmp_path / "hang"
    c.use_deadline(functools.partial(hang_once_solver, str(flag), c.params, 1, False),
                   spare=False)  # fmt: skip
    c._hang_guard = True  # as use_hang_guard, with the hanging solver
    try:
        assert not c.deadline.wait_spare(0.0)  # no spare process in simulation
        obs = Observation(0.0, ASVState(0.0, 0.0, 0.0, 1.0), True,
                          (AUVEstimate(120.0, 0.0, 30.0, 0.5, 0.0),))  # fmt: skip
        flag.touch()
        cmd = c.step(obs)
        assert not flag.exists()  # the worker did start the hanging solve
        assert c.deadline.abandoned == 1
        assert c.fallbacks == 0 and cmd.reason != Reason.FALLBACK
        assert c.diagnostics()["mpc_ok"] == 1
        assert c.diagnostics()["mpc_hung"] == 1  # counted (metric solver_hangs), not hidden
    finally:
        c.close()


def test_the_benchmark_records_wall_and_cpu_time_of_each_whole_step():
    """``mpcasv bench mpc`` (issue 16 item 8): the recorded run's whole controller steps are
    timed on the wall clock and in CPU time of this process (its solves in-process), one each
    per step; the summary gives both and the run's plan sources."""
    from mpcasv.mpc.bench import record_run, step_summary

    params, ctrl, seq, times = record_run("case3", "mpc-single", False, steps=12)
    assert params.solver.hang_s == 0.0 and ctrl.deadline is None  # solves in this process
    assert len(seq) == len(times["wall"]) == len(times["cpu"]) == 12
    assert np.all(times["cpu"] > 0.0)
    assert np.all(times["cpu"] <= times["wall"] + 5.0)  # one thread: CPU <= wall (+ clock ticks)
    s = step_summary(times, ctrl)
    assert s["steps"] == 12 and sum(s["sources"].values()) == 12
    assert s["cpu_p99_ms"] >= s["cpu_median_ms"] > 0.0 and s["wall_p99_ms"] >= s["wall_median_ms"]
    # each step is classified once: the warm-started solve alone, with exploration, rescued
    assert len(times["kind"]) == 12
    by = s["by_kind"]
    assert sum(v["steps"] for v in by.values()) == 11  # the cold first step left out


@pytest.mark.parametrize("step_iter", [0, 15])
def test_the_benchmark_classifies_each_step_by_what_it_did(step_iter):
    """Case 6 with three AUVs for 110 s (measured: the first step explores, the target being
    new; the ASV arrives at its first AUV at t = 98-106 s, where the warm-started solves
    need 17 to more than 50 iterations). Without a step budget (``step_iter`` 0) two steps
    there need a rescue; with ``step_iter`` 15 the steps whose solve stops at it carry the
    previous plan, and their work runs after the command. "rescue" exactly on the steps
    whose plan came from neither the warm-started or exploration solve nor the carried plan,
    "carried" on the carried ones, "explore" on the steps that ran the exploration solve
    inside the step, "solve" on the rest; the solves run between steps (a carried step's
    work, or the periodic exploration, for a plan standing still away from its target) are
    counted apart; the summary counts them."""
    import mpcasv.mpc.bench as bench

    params, ctrl, seq, times = bench.record_run("case6", "mpc-multi", True, steps=110,
                                                step_iter=step_iter)  # fmt: skip
    kinds, sources = times["kind"], times["source"]
    assert len(kinds) == len(sources) == 110
    carried = sources == "carried"
    if not step_iter:
        assert params.solver.step_iter is None and not np.any(carried)
        assert np.any(sources != "plan"), "no rescued step in this window: the test needs one"
    else:
        assert params.solver.step_iter == 15 and np.any(carried)
    np.testing.assert_array_equal(kinds == "rescue", (sources != "plan") & ~carried)
    np.testing.assert_array_equal(kinds == "carried", carried)
    n_between, n_explore = len(times["between"]), int(np.sum(kinds == "explore"))
    assert kinds[0] == "explore" and n_explore >= 1
    assert n_between >= int(np.sum(carried))  # every carried step's work after its command
    if not step_iter:
        assert n_between + n_explore <= ctrl.explored  # (a rescued step may have explored too)
    s = bench.step_summary(times, ctrl)
    assert {k: v["steps"] for k, v in s["by_kind"].items()} == {
        k: int(np.sum(kinds[1:] == k)) for k in ("solve", "explore", "rescue", "carried")
        if np.any(kinds[1:] == k)}  # fmt: skip
    assert s.get("between", {"solves": 0})["solves"] == n_between
