"""Issue 16 item 8: the MPC's exploration solve runs after the step's command, in the idle part
of the control period (``between_steps``), so a step's latency is the warm-started solve
alone. The decisions must not depend on who runs it: the simulator calls ``between_steps``
after each step; a caller that does not (a replay, a test) gets it run at the start of the
next ``step``, with the same result (the simulator does not call it after the last step).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from test_mpc_deadline import WALL_COLUMNS

from mpcasv.controllers import make_controller
from mpcasv.sim.scenario import load_scenario, scenario_with
from mpcasv.sim.simulator import simulate

#: the standing-time term off (see the fixture) and the mode dwell off (the presets'
#: min_dwell = 5 s since session 36): without the dwell the ASV's 1-s transits
#: at 14 s and 22 s stay 1 s long: with the dwell the first is held to 5 s and no exploration
#: in the 40 s is cheaper than its step's plan (measured: 8 explorations, none adopted)
#: and the projected terminal (M7a): with the integral one (M7i, the preset's since session
#: 39) the ASV sets off from rest at once here, as with M7s (measured: 1 exploration in 40 s)
STILL = {"weights.stand": 0.0, "min_dwell": 0.0, "weights.terminal": "projected"}


class _NoHook:
    """The controller without ``between_steps``: its ``step`` must run the exploration."""

    def __init__(self, ctrl):
        self._ctrl = ctrl

    def __getattr__(self, name):
        if name == "between_steps":
            raise AttributeError(name)
        return getattr(self._ctrl, name)


@pytest.fixture(scope="module")
def runs(scenarios_dir):
    sc = scenario_with(load_scenario(scenarios_dir / "case3.toml"), duration=40.0)
    # without the standing-time term (M7s) the ASV stands by from rest here and explores
    # every 5 s; with it (the presets since session 12) it sets off at once: 2 explorations
    # in 40 s, too few to see the periodic ones
    hooked = make_controller("mpc-single", 1, "mpc-single", STILL)
    log = _instrument(hooked)
    ts_hooked = simulate(sc, hooked, seed=0).timeseries
    lazy = make_controller("mpc-single", 1, "mpc-single", STILL)
    ts_lazy = simulate(sc, _NoHook(lazy), seed=0).timeseries
    return hooked, ts_hooked, lazy, ts_lazy, log


def _instrument(ctrl) -> dict:
    """Count the solves inside ``step`` and inside ``between_steps``, and record what each
    ``between_steps`` did to the next step's warm start."""
    log = {"phase": None, "step": [], "between": [], "warm": []}
    step, between, solve = ctrl.step, ctrl.between_steps, ctrl._solve

    def counted_solve(*a, **k):
        log[log["phase"]][-1] += 1
        return solve(*a, **k)

    def counted_step(obs):
        log["phase"] = "step"
        log["step"].append(0)
        return step(obs)

    def counted_between():  # (also called at the start of each step: nothing left to do)
        phase, log["phase"] = log["phase"], "between"
        log["between"].append(0)
        w_before, adopted = ctrl.w_prev, ctrl.explore_adopted
        between()
        log["warm"].append((ctrl.explore_adopted > adopted, ctrl.w_prev is not w_before))
        log["phase"] = phase

    ctrl._solve, ctrl.step, ctrl.between_steps = counted_solve, counted_step, counted_between
    return log


def test_the_exploration_runs_between_steps_and_its_plan_starts_the_next_step(runs):
    """Case 3 from rest: the ASV stands by, so every ``explore_every`` = 5 s an exploration
    solve heads for the AUV (measured: 3 in 40 s, none cheaper; the ASV sets off at 13 s).
    The first, at the run's first step (as after a target change), runs inside the step;
    the periodic ones while the plan stands still ran after their step's command (no step
    here needed a rescue: one solve each). An exploration's plan becomes the next step's
    warm start only when cheaper (the preset's run below has one). Until session 46 this run
    had 5 explorations, one cheaper: the current observer, given the actuators at the ends of
    a period only, read the first transit period (thrust from 0 to 223 N) as a current of
    up to 0.038 m/s, and the plan stood by again (38 s of the 40 against 13 s now)."""
    hooked, ts, _, _, log = runs
    assert (ts["mpc_source"] == "plan").all()
    assert log["step"] == [2] + [1] * (len(ts) - 1)  # then the warm-started solve alone
    n_between = hooked.explored - 1
    assert sum(log["between"]) == n_between >= 2
    assert int((ts["mpc_explore_iter"] > 0).sum()) == n_between
    assert ts["mpc_explore_ms"].notna().sum() == n_between
    assert hooked.explore_adopted == int(ts["mpc_explore_adopted"].sum())
    assert _adopted_only_when_cheaper(ts, log) == 0  # measured: none cheaper here


def _adopted_only_when_cheaper(ts, log) -> int:
    """An exploration's plan became the next step's warm start exactly when it was adopted,
    and only when cheaper than the plan the step used (the same problem); returns how many."""
    assert all(adopted == replaced for adopted, replaced in log["warm"])
    adopted = ts[ts["mpc_explore_adopted"] == 1]
    assert (adopted["mpc_explore_cost"] < adopted["mpc_cost"]).all()
    return len(adopted)


def _same_decisions(hooked, ts_hooked, lazy, ts_lazy):
    assert lazy.explored == hooked.explored and lazy.explore_adopted == hooked.explore_adopted
    keep = [c for c in ts_hooked.columns
            if c not in WALL_COLUMNS and "explore" not in c and "deferred" not in c]
    pd.testing.assert_frame_equal(ts_hooked[keep], ts_lazy[keep])


def test_the_decisions_are_the_same_whether_or_not_the_caller_runs_between_steps(runs):
    hooked, ts_hooked, lazy, ts_lazy, _ = runs
    _same_decisions(hooked, ts_hooked, lazy, ts_lazy)


def test_the_same_with_the_presets_standing_time_term(scenarios_dir):
    """As above with the shipped preset (``stand = 20``, the integral terminal M7i): the ASV
    sets off at once and first stands by after about 100 s; Case 3, 300 s (2 explorations, 1
    after its step, cheaper: its plan started the next step; 80 s, as before M7i, had only
    the first)."""
    sc = scenario_with(load_scenario(scenarios_dir / "case3.toml"), duration=300.0)
    hooked = make_controller("mpc-single", 1, "mpc-single")
    log = _instrument(hooked)
    ts_hooked = simulate(sc, hooked, seed=0).timeseries
    lazy = make_controller("mpc-single", 1, "mpc-single")
    ts_lazy = simulate(sc, _NoHook(lazy), seed=0).timeseries
    assert hooked.explored >= 2 and hooked.params.weights.stand > 0
    assert _adopted_only_when_cheaper(ts_hooked, log) == hooked.explore_adopted >= 1
    _same_decisions(hooked, ts_hooked, lazy, ts_lazy)


def test_the_exploration_has_an_iteration_limit_of_its_own(scenarios_dir):
    """``solver.explore_iter`` bounds the exploration solve alone. Case 4 (nominal), the second
    exploration (t = 11 s): by default (the presets' max_iter, 50) it stops at the limit
    (fatrop reports 51; in session 8's paper run 907 of 2839 explorations did), with 150 it
    converges (78); the warm-started solves are the same in both runs up to there. (150 as
    the default was measured on the paper suite and not kept: docs/mpc.md, "Controller
    step". Until session 12 the first one, at t = 6 s, stopped at 50; with the standing-time
    term in the presets it converges in 35.)"""
    sc = scenario_with(load_scenario(scenarios_dir / "case4.toml"), duration=12.0)
    runs = {}
    for limit in (None, 150):
        ctrl = make_controller("mpc-single", 1, "mpc-single", {"solver.explore_iter": limit})
        runs[limit or 50] = simulate(sc, ctrl, seed=0).timeseries.set_index("t")
    assert runs[50].loc[11.0, "mpc_explore_iter"] in (50, 51)  # at the limit
    assert 51 < runs[150].loc[11.0, "mpc_explore_iter"] < 150  # converged past 50
    pd.testing.assert_series_equal(runs[50]["mpc_iter"], runs[150]["mpc_iter"])


def _start(scenarios_dir, case="case3", kind="mpc-single"):
    """A fresh controller (``kind``), the first observation of ``case`` and its parameters."""
    from mpcasv.sim.world import World

    sc = scenario_with(load_scenario(scenarios_dir / f"{case}.toml"), duration=2.0)
    n_auv = len(sc.auv)
    ctrl = make_controller(kind, n_auv, kind)
    ctrl.reset(n_auv)
    obs = World(sc, 0, None).observation()
    return ctrl, obs, ctrl.parameters(obs)


def test_a_plan_stuck_at_rest_outside_the_bounds_is_explored(scenarios_dir):
    """A plan that stands by now (the STANDBY rule), moves later and leaves the range bounds
    meanwhile (a slack above ``STUCK_SLACK``) is explored every ``explore_every`` s, as one
    that stands still; one that stands by and moves later inside the bounds (the usual
    standby) is not, nor one that moves now. Until session 11 a plan with thrust anywhere in
    its horizon was never explored: a solve stuck at rest that put its start off step after
    step (dune-otter on Case 3: it stood by from 190 m to 260 m with r_outer at 200 m) kept
    its plan."""
    from mpcasv.mpc.solvers import SolveResult

    ctrl, obs, p = _start(scenarios_dir)  # the AUV 158 m away: not in its target domain
    ocp = ctrl.ocp
    Z, V = ocp.split(ocp.rollout(p))
    n = Z.shape[0]

    def explored(T, slack):
        Z[:, 6], V[:, 2] = T, slack
        res = SolveResult(ocp.join(Z, V), None, None, 1.0, True, "ok", 5, 1.0)
        ctrl.t_explore = obs.t - 10.0  # the last exploration 10 s ago
        return ctrl._explore(obs, p, res) is not None

    later = [0.0] * 8 + [ocp.vessel.T_max] * (n - 8)  # stands by 28 s, then moves
    outside = np.r_[np.zeros(6), np.full(n - 7, 20.0)]  # 20 m beyond r_outer from 24 s on
    assert explored(later, outside)
    assert not explored(later, 0.0)  # inside the bounds: the usual standby
    assert not explored([0.0] + [ocp.vessel.T_max] * (n - 1), outside)  # moves now


def test_a_standby_that_puts_its_start_off_is_explored(scenarios_dir):
    """Several AUVs: a standby plan that moves later (no range bound: no slack) is not
    explored while the ASV stands by within the time the streak's first standby plan meant
    to stand by (plus one stage); past it, the plan is late (each plan puts its start off)
    and is explored, once per promise. Until session 13 nothing explored it, and Case 7,
    seed 1 stood by for 795 s drifting in the current. With one AUV the rule is off (the
    outer bound's slack shows a stuck plan; ``_stuck``)."""
    import dataclasses

    from mpcasv.mpc.solvers import SolveResult

    one, obs1, _ = _start(scenarios_dir)
    one.t_depart = obs1.t - 100.0  # a promise long broken
    assert not one._late(obs1.t)
    ctrl, obs, p = _start(scenarios_dir, "case6", "mpc-multi")  # 66-316 m off
    ocp = ctrl.ocp
    Z, V = ocp.split(ocp.rollout(p))
    n = Z.shape[0]
    Z[:, 6] = [0.0] * 8 + [ocp.vessel.T_max] * (n - 8)  # stands by 28 s, then moves
    V[:, 2:5] = 0.0  # no slack: not stuck
    res = SolveResult(ocp.join(Z, V), None, None, 1.0, True, "ok", 5, 1.0)

    def command(t, w):  # the step's end: the plan stored, then its command
        ctrl._store_plan(t, w)
        return ctrl._command(dataclasses.replace(obs, t=t), w, p)

    command(obs.t, res.w)  # STANDBY: the streak's first plan sets its departure
    # where the thrust reaches the propeller-on threshold between 28 and 32 s
    assert ctrl.t_depart == pytest.approx(obs.t + 28.0 + 4.0 * ocp.T_on / ocp.vessel.T_max)

    def explored(t):
        ctrl.t_explore = t - 10.0  # the last exploration 10 s ago
        return ctrl._explore(dataclasses.replace(obs, t=t), p, res) is not None

    for dt in (10.0, 28.0, 31.0):  # within the promise and its one-stage (4 s) grace
        command(obs.t + dt, res.w)  # a plan standing by as long: the promise stays
        assert not explored(obs.t + dt)
    assert explored(obs.t + 33.0)  # late
    assert ctrl.t_depart is None  # explored once: the next standby plan promises anew
    command(obs.t + 34.0, res.w)
    assert not explored(obs.t + 34.0)
    Z[:, 6] = ocp.vessel.T_max  # a plan that moves now ends the streak
    command(obs.t + 35.0, ocp.join(Z, V))
    assert ctrl.t_depart is None


@pytest.mark.parametrize(("case", "seed", "duration", "hooks", "overrides"), [
    ("case7", 1, 900.0, True, {}),
])
def test_several_auvs_no_standby_far_from_the_target_for_minutes(tmp_path, case, seed,
                                                                  duration, hooks, overrides):
    """No standby away from the target AUV's reliable range lasts two minutes.

    Case 7, seed 1 (three AUVs, a 0.29 m/s current) for 900 s: before session 13 the MPC
    stood by from t = 692 s to the end, and from t = 706 s away from its target AUV
    (390-700 m off), each plan moving off later (795 s over 1500 s; 195 s by 900 s); the
    late standby's exploration fixed it (59 s at most over the whole run). The rule's
    decisions are the same whoever runs ``between_steps``.

    Case 6, seed 0: from t = 1268 s the ASV stood by 166 s beside an AUV that had finished
    its pattern, its target 250 m off: the late explorations (heading there) at 1314 and
    1373 s were dearer over the horizon than the plans that put their start off again, and
    until session 15 only a cheaper one was kept. A late standby's converged exploration is
    now kept (48 s). That run had no step budget (before session 16's presets): without one
    it needed the rule; with the presets' budget this seed takes another course. Since
    session 17 (a plan stuck at rest is explored wherever its target is) it takes another
    course without a budget too: no late standby's dearer exploration is taken any more and
    its longest standby away from the target is 28 s (scratch /work/s17/f1/c6.py); the rule
    itself is checked by ``test_a_late_standby_keeps_its_exploration_even_if_dearer``. So the
    Case 6 run (1440 s without the presets' step budget, 42 s of the suite) no longer met the
    situation it was written for, and was dropped in session 25 to keep the suite short."""
    from mpcasv.controllers import Boat
    from mpcasv.experiments.suite import expand

    suite = tmp_path / "s.toml"
    suite.write_text(f'name = "s"\ndescription = "one run"\nscenarios = ["{case}"]\n'
                     f'seeds = [{seed}]\nduration = {duration}\n[[controllers]]\n'
                     'label = "mpc"\nmulti = "mpc-multi"\npreset = "default"\n'
                     'domain_from = "scenario"\n')
    job = expand(suite).jobs[0]
    scenario, _ = job.realised_scenario()

    def run(hooked: bool):
        ctrl = make_controller(job.controller, job.n_auv, job.preset,
                               dict(job.overrides) | overrides,
                               boat=Boat.of_scenario(scenario))  # fmt: skip
        res = simulate(scenario, ctrl if hooked else _NoHook(ctrl), job.seed, job.estimator)
        return ctrl, res.timeseries

    ctrl, d = run(True)
    target = d["mpc_target"].to_numpy(int)
    i = np.arange(len(d))
    rng = np.stack([d[f"range{k}"] for k in range(3)], 1)[i, target]
    r_t = np.stack([d[f"r_t{k}"] for k in range(3)], 1)[i, target]
    far = (d["mode"].to_numpy() == "standby") & (rng > r_t + ctrl.params.domain.eps_plus)
    longest = max((len(s) for s in "".join("x" if f else " " for f in far).split()),
                  default=0)  # fmt: skip
    assert longest < 120, f"stood by {longest} s away from the target's reliable range"
    if hooks:
        _same_decisions(ctrl, d, *run(False))


@pytest.mark.parametrize(("ok", "finite", "cheaper", "adopted"), [
    (True, True, True, True),  # converged and cheaper: its plan and multipliers
    (False, True, True, True),  # at its iteration limit, finite, cheaper: its plan alone
    (False, False, True, False),  # a non-finite iterate: never a warm start
    (True, True, False, False),  # dearer: the step's own plan stays
])
def test_which_exploration_warm_starts_the_next_step(scenarios_dir, ok, finite, cheaper,
                                                     adopted):
    """``between_steps`` adopts the exploration's plan as the next warm start when it costs
    less than the plan the step used and is finite, converged or not (an unconverged one
    without multipliers): the way out of a plan stuck at rest (session 11, docs/mpc.md
    "Controller step"). Its cost is compared alone, not its dynamics gaps (a known problem,
    docs/mpc.md)."""
    from mpcasv.mpc.solvers import SolveResult

    ctrl, obs, p = _start(scenarios_dir)
    w_step = ctrl.ocp.rollout(p)
    res = SolveResult(w_step, np.zeros(len(w_step)), np.zeros(3), 100.0, True, "ok", 5, 1.0)
    w_alt = w_step + 1.0
    if not finite:
        w_alt[3] = np.nan
    lam = (np.ones(len(w_step)), np.ones(3)) if ok else (None, None)
    alt = SolveResult(w_alt, *lam, 50.0 if cheaper else 150.0, ok,
                      "ok" if ok else "max_iter", 50, 1.0)  # fmt: skip
    ctrl.w_prev, ctrl.lam_prev = w_step, (res.lam_x, res.lam_g)
    ctrl._pending = (obs, p, res)
    ctrl._explore = lambda *a: alt
    ctrl.between_steps()
    assert ctrl.explore_adopted == int(adopted)
    assert ctrl.diagnostics()["mpc_explore_adopted"] == int(adopted)
    if adopted:
        assert ctrl.w_prev is w_alt
        assert (ctrl.lam_prev is None) == (not ok)
        if ok:
            assert ctrl.lam_prev[0] is alt.lam_x
    else:
        assert ctrl.w_prev is w_step and ctrl.lam_prev[0] is res.lam_x


@pytest.mark.parametrize(("kind", "late", "ok", "slack", "adopted"), [
    ("mpc-multi", True, True, 0.0, True),  # late: the converged exploration, dearer, is kept
    ("mpc-multi", True, False, 0.0, False),  # ... not a dearer iterate that did not converge
    ("mpc-multi", True, True, 5.0, False),  # ... nor a dearer way through an AUV's domain
    ("mpc-multi", False, True, 0.0, False),  # a standby within its promise: dearer not kept
    ("mpc-single", True, True, 0.0, False),  # one AUV: no promise rule
])
def test_a_late_standby_keeps_its_exploration_even_if_dearer(scenarios_dir, kind, late, ok,
                                                             slack, adopted):
    """Several AUVs, a standby past the streak's promise (``_late``): the exploration heading
    for the target warm-starts the next step if it converged within the range bounds, dearer
    or not. Each plan put its start off, priced over a horizon that does not reach the
    target; taking the cheaper plan alone left Case 6, seed 0 standing by 166 s beside a
    finished AUV (docs/mpc.md, "Controller step"). The lateness is read before the
    exploration, which makes the next promise anew (as the fake does here)."""
    from mpcasv.mpc.solvers import SolveResult

    ctrl, obs, p = _start(scenarios_dir, *(("case6", kind) if kind == "mpc-multi" else ()))
    ocp = ctrl.ocp
    w_step = ocp.rollout(p)
    res = SolveResult(w_step, np.zeros(len(w_step)), np.zeros(3), 100.0, True, "ok", 5, 1.0)
    Z, V = ocp.split(w_step + 1.0)
    V[:, 2 : 2 + ocp.dims.n_auv] = 0.0  # within the range bounds ...
    V[:, 2] = slack  # ... but for AUV 0's slack (m) at every stage
    lam = (np.ones(len(w_step)), np.ones(3)) if ok else (None, None)
    alt = SolveResult(ocp.join(Z, V), *lam, 150.0, ok, "ok" if ok else "max_iter", 50, 1.0)
    ctrl.w_prev, ctrl.lam_prev = w_step, (res.lam_x, res.lam_g)
    ctrl.t_depart = obs.t - (100.0 if late else 0.0)  # the promise: long broken, or now
    assert ctrl._late(obs.t) == (late and kind == "mpc-multi")
    ctrl._pending = (obs, p, res)

    def explore(*_):  # as the real one: exploring makes the next standby promise anew
        ctrl.t_depart = None
        return alt

    ctrl._explore = explore
    ctrl.between_steps()
    assert ctrl.explore_adopted == int(adopted)
    assert (ctrl.w_prev is alt.w) == adopted
