"""Issue 16 item 6: a stable target. With two AUVs both served the target AUV used to swap
every step for a whole run; now it stays, and it still moves on to an AUV that needs a visit.
The number of switches is reported (``mpc_target_switches`` in the diagnostics)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mpcasv.controllers import make_controller
from mpcasv.interface import ASVState, AUVEstimate, Observation
from mpcasv.mpc.target import FIRST_TOUR_MIN_AUVS, first_tour_next


@pytest.fixture(scope="module")
def ctrl():
    # the SX virtual machine instead of a compiled library: no 2-AUV compile for this test
    return make_controller("mpc-multi", 2, "mpc-multi", overrides={"solver.compiled": False})


def _run(ctrl, auvs, steps: int = 40, tau0=None):
    ctrl.reset(len(auvs))
    if tau0 is not None:  # the AUVs' expected fix ages when the run starts (s)
        ctrl.tau = np.array(tau0, float)
    targets = []
    for k in range(steps):
        obs = Observation(float(k), ASVState(0.0, 0.0, 0.0), False, auvs)
        ctrl.step(obs)
        targets.append(ctrl.diagnostics()["mpc_target"])
    return targets


def test_two_served_auvs_do_not_swap_the_target_every_step(ctrl):
    """Two AUVs 15 m either side of a standing-by ASV at 60 m depth: both within their
    reliable-fix range (r_t + eps_plus = 30 m), both served all the time."""
    auvs = (AUVEstimate(15.0, 0.0, 60.0), AUVEstimate(-15.0, 0.0, 60.0))
    targets = _run(ctrl, auvs)
    assert max(ctrl.tau) <= ctrl.params.tau_served  # both served throughout
    switches = sum(a != b for a, b in zip(targets, targets[1:], strict=False))
    assert switches == 0, targets
    assert ctrl.target_switches == 0 == ctrl.diagnostics()["mpc_target_switches"]


def test_a_served_target_gives_way_to_an_auv_that_needs_a_visit(ctrl):
    """AUV 0 beside the ASV (served), AUV 1 400 m away (projected fix age far above
    tau_served): the target moves to AUV 1 once, and stays."""
    auvs = (AUVEstimate(15.0, 0.0, 60.0), AUVEstimate(400.0, 0.0, 60.0))
    targets = _run(ctrl, auvs, steps=10)
    assert targets[-1] == 1
    assert ctrl.target_switches == 1 == ctrl.diagnostics()["mpc_target_switches"]


def test_an_auv_the_asv_cannot_reach_does_not_keep_the_target(ctrl):
    """AUV 0 (the run's first target) 100 m north going away north at 4 m/s, faster than the
    plan's transit speed U_go (2.5 m/s); AUV 1 300 m east, still, a little younger. AUV 0 has
    the larger projected fix age, but the ASV can never meet it: the target moves to AUV 1
    at the first step and stays (before, AUV 0 kept the target for good: not served, its
    age growing)."""
    auvs = (AUVEstimate(100.0, 0.0, 60.0, 4.0, 0.0), AUVEstimate(0.0, 300.0, 60.0))
    targets = _run(ctrl, auvs, steps=5, tau0=[500.0, 400.0])
    assert targets == [1] * 5, targets
    assert ctrl.target_switches == 1
    # the same AUV 0 at 2 m/s (reachable): it keeps the target (the age rule's choice, and
    # with the first tour, M9t, the nearer AUV not yet visited)
    auvs = (AUVEstimate(100.0, 0.0, 60.0, 2.0, 0.0), AUVEstimate(0.0, 300.0, 60.0))
    assert _run(ctrl, auvs, steps=3, tau0=[500.0, 400.0]) == [0] * 3


# ------------------------------------------------ target_rule = "order" (opt-in, issue 16 item 2)
@pytest.fixture(scope="module")
def ordered():
    # the shipped opt-in preset, the SX virtual machine (no compile for this test)
    return make_controller("mpc-multi", 2, "mpc-multi-order", overrides={"solver.compiled": False})


def test_the_order_preset_is_mpc_multi_with_the_order_rule(ctrl, ordered):
    """The shipped presets keep the age rule; mpc-multi-order differs from mpc-multi only in
    the rule (same domain, horizon, weights, solver: same compiled library)."""
    assert ctrl.params.target_rule == "age"
    assert ordered.params.target_rule == "order"
    assert dataclasses.replace(ordered.params, target_rule="age") == ctrl.params


def test_order_rule_two_served_auvs_do_not_swap(ordered):
    auvs = (AUVEstimate(15.0, 0.0, 60.0), AUVEstimate(-15.0, 0.0, 60.0))
    targets = _run(ordered, auvs)
    assert max(ordered.tau) <= ordered.params.tau_served
    assert ordered.target_switches == 0, targets


def test_order_rule_served_target_gives_way_to_an_auv_that_needs_a_visit(ordered):
    """As with the age rule: AUV 0 beside the ASV (served), AUV 1 400 m away and 150 s
    without a fix: the target moves to AUV 1 once, and stays; the order is recorded."""
    auvs = (AUVEstimate(15.0, 0.0, 60.0), AUVEstimate(400.0, 0.0, 60.0))
    targets = _run(ordered, auvs, steps=10, tau0=(0.0, 150.0))
    assert targets[-1] == 1
    assert ordered.target_switches == 1 == ordered.diagnostics()["mpc_target_switches"]
    assert ordered.order_plan.order[0] == 1


def _first_choice(rule: str) -> int:
    """Three AUVs: the target (2) beside the ASV and served; AUV 0 oldest (200 s) but 600 m
    out, AUV 1 (150 s) half-way. The target chosen by ``rule`` (no solve)."""
    c = make_controller("mpc-multi", 3, "mpc-multi", overrides={
        "solver.compiled": False, "target_rule": rule})  # fmt: skip
    c.reset(3)
    c.target, c.tau = 2, np.array([200.0, 150.0, 0.0])
    c.toured[:] = True  # mid-run: every AUV visited before (no first tour, M9t)
    auvs = (AUVEstimate(600.0, 0.0, 60.0), AUVEstimate(300.0, 0.0, 60.0),
            AUVEstimate(15.0, 0.0, 60.0))  # fmt: skip
    c._choose_target(Observation(0.0, ASVState(0.0, 0.0, 0.0), False, auvs), 1.0)
    return c.target


def test_the_order_rule_leaves_a_served_target_and_stays_when_no_other_auv_needs_a_visit():
    """Session 16: target 2 beside the ASV, committed and served (a fix since the choice).
    Even with a band of 1000 % that would keep it, the order rule leaves it for the first
    AUV of the cheapest order that starts elsewhere (before, it committed to the served AUV
    anew: a second whole visit). With the other AUVs served too, it stays, as the age rule
    does."""
    c = make_controller("mpc-multi", 3, "mpc-multi-order", overrides={
        "solver.compiled": False, "order.hysteresis": 10.0})  # fmt: skip
    far = (AUVEstimate(600.0, 0.0, 60.0), AUVEstimate(300.0, 0.0, 60.0),
           AUVEstimate(15.0, 0.0, 60.0))  # fmt: skip
    near = (AUVEstimate(0.0, 20.0, 60.0), AUVEstimate(0.0, -20.0, 60.0), far[2])
    for auvs, tau, expected in ((far, [200.0, 150.0, 0.0], 1), (near, [10.0, 5.0, 0.0], 2)):
        obs = Observation(0.0, ASVState(0.0, 0.0, 0.0), False, auvs)  # projected ages <= 25 s
        c.reset(3)
        c.target, c.tau, c.t_commit = 2, np.array(tau), -10.0
        c.fixes_since[2] = 1.0
        c._choose_target(obs, 1.0)
        assert c.target == expected, tau


def test_the_order_rule_visits_the_auv_on_the_way_where_the_age_rule_goes_past_it():
    """The age rule heads for the largest projected fix age (AUV 0: 200 s + 530 m / 2.5 m/s);
    the order rule visits AUV 1 on the way (tests/test_mpc_order.py has the order alone)."""
    assert _first_choice("age") == 0
    assert _first_choice("order") == 1


@pytest.mark.parametrize("rule", ["age", "order"])
def test_a_run_that_starts_with_every_fix_age_zero_commits_to_one_target(rule):
    """Case 6's start (measured before the fix: the target swapped between AUVs 1 and 2 every
    step for the first 26 s, 25 switches): three AUVs 120-270 m from the ASV, no fix yet
    since the run began, so every expected fix age is below ``tau_served`` for the first
    10 s. A newly chosen AUV is not served until the ASV has been in its target domain:
    one choice, kept while the ASV is on its way (the ages grow; no solve needed)."""
    c = make_controller("mpc-multi", 3, "mpc-multi", overrides={
        "solver.compiled": False, "target_rule": rule})  # fmt: skip
    c.reset(3)
    auvs = (AUVEstimate(95.0, -75.0, 0.0), AUVEstimate(-160.0, 72.0, 0.0),
            AUVEstimate(-160.0, -222.0, 0.0))  # fmt: skip
    targets = []
    for k in range(30):
        c.tau = np.full(3, float(k))  # no fixes on the way: the ages grow with the time
        c._choose_target(Observation(float(k), ASVState(0.0, 0.0, 0.0), False, auvs), 1.0)
        targets.append(c.target)
    assert c.target_switches <= 1, targets
    assert len(set(targets)) <= 2 and targets[1:] == [targets[-1]] * 29, targets


def test_a_committed_target_is_left_once_it_has_had_a_fix_since_it_was_chosen():
    """Case 6's AUVs; the first choice commits to one of them. Then the ASV lies 20 m beside
    that AUV with its propeller off, and the fix ages and the expected fixes since the
    choice follow the plan's own fix-rate model (eq. M2-M3). The target is kept while its
    age is low only because the run has just begun, and left, once, as soon as an expected
    fix has come since the choice (``fixes_since`` >= 1)."""
    c = make_controller("mpc-multi", 3, "mpc-multi", overrides={"solver.compiled": False})
    c.reset(3)
    auvs = (AUVEstimate(95.0, -75.0, 0.0), AUVEstimate(-160.0, 72.0, 0.0),
            AUVEstimate(-160.0, -222.0, 0.0))  # fmt: skip
    c._choose_target(Observation(0.0, ASVState(0.0, 0.0, 0.0), False, auvs), 1.0)
    j = c.target
    assert c.committed and c.tau[j] <= c.params.tau_served  # age 0: "served" by age alone
    beside = ASVState(auvs[j].N - 20.0, auvs[j].E, 0.0)
    fixes_when_kept, switched_at = [], None
    for k in range(1, 120):
        obs = Observation(float(k), beside, False, auvs)
        c.tau = c._fix_ages(obs, 1.0)
        before = float(c.fixes_since[j])
        c._choose_target(obs, 1.0)
        if c.target != j:
            switched_at, fixes_at_switch = k, before
            break
        fixes_when_kept.append(before)
    assert switched_at is not None
    assert c.target_switches == (1 if j == 0 else 2)  # the first choice (if a switch), the leave
    assert fixes_at_switch >= 1.0 and max(fixes_when_kept) < 1.0
    assert switched_at >= 3  # not at once: the old rule left it at the first step


# ------------------------------------------------ the first tour (eq. M9t)
def _square_choice(tau, toured=(True, False, False, False), **overrides) -> int:
    """Four AUVs at the corners of a 500-m square, the ASV beside AUV 0 (the target,
    committed and served); the AUVs' expected fix ages ``tau`` (s) and which were visited
    once (``toured``). AUVs 1 and 3 are the square's sides away (500 m), AUV 2 its diagonal
    (707 m). The target the age rule chooses (no solve)."""
    c = make_controller("mpc-multi", 4, "mpc-multi",
                        overrides={"solver.compiled": False, **overrides})  # fmt: skip
    c.reset(4)
    c.target, c.tau, c.t_commit = 0, np.array(tau, float), -10.0
    c.fixes_since[0] = 1.0
    c.toured[:] = toured
    auvs = (AUVEstimate(250.0, 250.0, 0.0), AUVEstimate(250.0, -250.0, 0.0),
            AUVEstimate(-250.0, -250.0, 0.0), AUVEstimate(-250.0, 250.0, 0.0))  # fmt: skip
    c._choose_target(Observation(0.0, ASVState(230.0, 250.0, 0.0), False, auvs), 1.0)
    return c.target


def test_the_first_tour_goes_round_a_square_where_the_projected_age_crosses_it():
    """Session 35's sweep (four AUVs at a square's corners, `mpc-multi`: one AUV had no
    reliable fix in 900 s): with every age about the same the projected age (age + time to
    go) is largest for the farthest AUV, the diagonal, and the age rule then repeats that
    crossing cycle. The first tour (M9t) takes a side; once every AUV has been visited,
    the largest projected age decides again (here: the diagonal)."""
    tau = [0.0, 300.0, 300.0, 300.0]
    assert _square_choice(tau, first_tour=False) == 2
    assert _square_choice(tau) == 3  # the nearer side (the ASV is 20 m south of AUV 0)
    assert _square_choice(tau, toured=(True, True, True, True)) == 2


def test_the_first_tour_is_the_least_waiting_path_on_to_the_oldest_visited_auv():
    """``first_tour_next`` by hand: the ASV at the origin, A 60 m south (the nearest), B 200
    m north, the path ending at Z 500 m south (the oldest AUV already visited). Arrivals
    A, B, Z: 60 + 320 + 1020 = 1400 m; B, A, Z: 200 + 460 + 900 = 1560 m: A first (the
    shortest path, B, A, Z at 900 m against 1020, went north first and left A waiting).
    Without Z: A, B 60 + 320 against B, A 200 + 460."""
    pos = np.array([[-60.0, 0.0], [200.0, 0.0], [-500.0, 0.0]])
    assert first_tour_next(np.zeros(2), pos, [0, 1], close=2) == 0
    assert first_tour_next(np.zeros(2), pos, [0, 1], close=None) == 0
    assert first_tour_next(np.zeros(2), pos, [1], close=2) == 1
    with pytest.raises(ValueError, match="at least one AUV"):
        first_tour_next(np.zeros(2), pos, [], close=2)
    many = np.array([[100.0 * (k + 1), 0.0] for k in range(8)])  # beyond the enumeration
    assert first_tour_next(np.zeros(2), many, list(range(8))[::-1], close=None) == 0


@pytest.mark.parametrize("K", [4, 5, 6, 7])
def test_the_first_tour_sweeps_a_line_of_auvs_from_the_near_end(K):
    """K AUVs on a line 250 m apart, the ASV beside the first (just visited, the path's
    end), the others not yet visited, each a few metres off the line either way: the next
    target is the nearest, whatever the offsets. Session 38's sweep (five AUVs, the
    shortest path closing at the first): out-and-back and "far end first, then sweep
    back" were within 0.4 m of each other and the ASV went to the far end first, passing
    three AUVs under way; their first reliable fixes came at 693-1031 s."""
    rng = np.random.default_rng(K)
    for _ in range(20):
        pos = np.array([[rng.uniform(-5.0, 5.0), 250.0 * k] for k in range(K)])
        asv = np.array([0.0, 10.0])
        assert first_tour_next(asv, pos, list(range(1, K)), close=0) == 1


def test_the_first_tour_starts_with_every_auv_even_one_whose_age_is_low_because_the_run_began():
    """Four AUVs on a line 100, 350, 600 and 850 m east of the ASV, no fix yet, the run 1 s
    old: every expected age is below ``tau_served`` only because the run has just begun.
    The first tour commits to AUV 0 (the line's order; before, the AUV nearest the start
    was left out of the first round, its projected age below ``tau_served``), and after an
    expected fix at AUV 0 moves on to another AUV (on a line several paths are about as
    long: which one is test_the_first_tour_closes_at_the_oldest_visited_auv's business);
    without it the farthest AUV comes first."""
    auvs = tuple(AUVEstimate(0.0, e, 0.0) for e in (100.0, 350.0, 600.0, 850.0))
    choice = {}
    for first_tour in (False, True):
        c = make_controller("mpc-multi", 4, "mpc-multi", overrides={
            "solver.compiled": False, "first_tour": first_tour})  # fmt: skip
        c.reset(4)
        c.tau = np.full(4, 1.0)
        c._choose_target(Observation(1.0, ASVState(0.0, 0.0, 0.0), False, auvs), 1.0)
        choice[first_tour] = c.target
    assert choice == {False: 3, True: 0}
    assert c.committed and c.target_switches == 0
    c.fixes_since[0] = c.fixes_run[0] = 1.0  # a fix at AUV 0 (in expectation)
    c.tau = np.array([5.0, 60.0, 60.0, 60.0])
    c._choose_target(Observation(60.0, ASVState(0.0, 30.0, 0.0), False, auvs), 1.0)
    assert c.toured.tolist() == [True, False, False, False]
    assert c.target != 0 and c.target_switches == 1


def _controller(K: int, **overrides):
    c = make_controller("mpc-multi", K, "mpc-multi",
                        overrides={"solver.compiled": False, **overrides})  # fmt: skip
    c.reset(K)
    return c


def test_the_first_tour_closes_at_the_oldest_visited_auv():
    """AUVs P (100 m north of the ASV) and Q (100 m south) not yet visited; Z1 300 m north
    and Z2 300 m east of Q's south, both visited. The target, served, is the younger of
    Z1 and Z2; the path ends at the older. Arrivals P, Q, Z1 = 100 + 300 + 700 m against
    Q, P, Z1 = 100 + 300 + 500 m (Q first); P, Q, Z2 = 100 + 300 + 500 m against Q, P, Z2
    = 100 + 300 + 700 m (P first)."""
    auvs = (AUVEstimate(100.0, 0.0, 0.0), AUVEstimate(-100.0, 0.0, 0.0),
            AUVEstimate(300.0, 0.0, 0.0), AUVEstimate(-300.0, 0.0, 0.0))  # fmt: skip
    chosen = {}
    for served, older in ((3, 2), (2, 3)):
        c = _controller(4)
        c.toured[:] = [False, False, True, True]
        c.target, c.t_commit = served, -10.0
        c.fixes_since[served] = 1.0
        c.tau = np.full(4, 300.0)
        c.tau[served] = 5.0
        c._choose_target(Observation(0.0, ASVState(0.0, 0.0, 0.0), False, auvs), 1.0)
        chosen[older] = c.target
    assert chosen == {2: 1, 3: 0}, chosen


def test_a_target_visited_for_dwell_max_without_a_fix_counts_as_visited():
    """AUV 0 of four, the committed target, not yet visited and without an expected fix
    (its fix model credits none: a moving AUV keeps the age up), the ASV 20 m from it:
    once the ASV has spent ``dwell_max`` in its target domain it counts as visited and
    the first tour moves on."""
    auvs = (AUVEstimate(20.0, 0.0, 0.0), AUVEstimate(-300.0, 0.0, 0.0),
            AUVEstimate(-300.0, 300.0, 0.0), AUVEstimate(0.0, 400.0, 0.0))  # fmt: skip
    c = _controller(4)
    c.target, c.t_commit = 0, -10.0
    c.tau = np.full(4, 200.0)
    c.dwell = c.params.dwell_max - 0.5
    c._choose_target(Observation(0.0, ASVState(0.0, 0.0, 0.0), False, auvs), 1.0)
    assert c.toured.tolist() == [True, False, False, False]
    assert c.target != 0 and c.target_switches == 1


def test_with_fix_times_from_the_estimates_a_visit_is_a_fix_after_the_runs_first_step():
    """``fix_age_source = "estimate"``: the simulator's estimators start with ``t_last_fix =
    0``, the run's first step; that is no visit (a first version counted every finite fix
    time, so every AUV was "visited" at once and the first tour did nothing). A fix time
    after the first step is."""
    auvs = (AUVEstimate(0.0, 100.0, 0.0, t_last_fix=0.0),
            AUVEstimate(0.0, 900.0, 0.0, t_last_fix=0.0),
            AUVEstimate(0.0, 350.0, 0.0, t_last_fix=0.0),
            AUVEstimate(300.0, 350.0, 0.0, t_last_fix=0.0))  # fmt: skip
    c = _controller(4, fix_age_source="estimate")
    c._choose_target(Observation(0.0, ASVState(0.0, 0.0, 0.0), False, auvs), 0.0)
    assert not c.toured.any() and c.target == 0  # the nearest first
    auvs = (dataclasses.replace(auvs[0], t_last_fix=40.0), *auvs[1:])
    c.tau = np.array([5.0, 45.0, 45.0, 45.0])
    c._choose_target(Observation(45.0, ASVState(0.0, 80.0, 0.0), False, auvs), 1.0)
    assert c.toured.tolist() == [True, False, False, False]
    assert c.target != 0 and c.target_switches == 1


def test_with_three_auvs_or_fewer_the_first_tour_changes_nothing():
    """Three AUVs on a line 100, 350 and 600 m east of the ASV at the run's start: every
    closed tour through three AUVs is the same cycle, so the first tour does not apply
    (``FIRST_TOUR_MIN_AUVS``); with or without it the age rule takes the farthest (its
    projected age the largest)."""
    assert FIRST_TOUR_MIN_AUVS == 4
    auvs = tuple(AUVEstimate(0.0, e, 0.0) for e in (100.0, 350.0, 600.0))
    for first_tour in (False, True):
        c = _controller(3, first_tour=first_tour)
        c.tau = np.full(3, 1.0)
        c._choose_target(Observation(1.0, ASVState(0.0, 0.0, 0.0), False, auvs), 1.0)
        assert c.target == 2, first_tour
