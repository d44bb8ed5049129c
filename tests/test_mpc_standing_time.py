"""One AUV: the terminal cost values the standing time the plan's end leaves (docs/mpc.md,
eq. M7s; ``weights.stand``).

Without it the terminal cost (M7a) sees the fix age where the plan ends, not that the ASV
must leave soon after: moving first and standing by last leaves a smaller age at the
horizon's end than standing first, so each plan moved first, and the next plan did the same
(dune-otter on Case 3 kept the propeller on at the AUV's speed for minutes, 120-190 m behind
it). ``stand`` charges each second by which the ASV, standing where the plan ends, could stand
less than one horizon before the AUV reaches ``r_outer``.
"""

from __future__ import annotations

import functools

import casadi as ca
import numpy as np
import pytest

from mpcasv.controllers import Boat, load_preset
from mpcasv.mpc.problem import OCP


def _ocp(stand: float | None = None) -> OCP:
    over = {} if stand is None else {"weights.stand": stand}
    return OCP(load_preset("mpc-single", "mpc-single", over), 1, outer=True,
               boat=Boat.load("gretha"))  # fmt: skip


def _t_s():
    """The OCP and its standing time as a function of (z, stage N - 1 and N parameters),
    stages 4 s apart."""
    ocp = _ocp()
    z = ca.SX.sym("z", ocp.dims.nx)
    s0, s1 = ca.SX.sym("s0", 5), ca.SX.sym("s1", 5)
    return ocp, ca.Function("t_s", [z, s0, s1], [ocp._standing_time(z, s0, s1, 4.0)])


def _sp(N_, E_, r_hi=195.0):
    return np.array([N_, E_, 50.0, r_hi, 0.0])  # pa (2), r_lo, r_hi, depth


@pytest.mark.parametrize(("auv_from", "auv_to", "expected"), [
    # coming towards the ASV, passing 60 m beside it: leaves 195 m beyond
    ((-105.4, 60.0), (-100.0, 60.0), (100.0 + np.sqrt(195.0**2 - 60.0**2)) / 1.35),
    ((-94.6, 0.0), (-100.0, 0.0), 95.0 / 1.35),  # going away from 100 m
    ((-100.0, 20.0), (-100.0, 0.0), np.sqrt(195.0**2 - 100.0**2) / 5.0),  # across, 5 m/s
])
def test_the_standing_time_is_when_the_auv_reaches_the_outer_bound(auv_from, auv_to, expected):
    ocp, f = _t_s()
    t = float(f(np.zeros(ocp.dims.nx), _sp(*auv_from), _sp(*auv_to)))
    assert t == pytest.approx(expected, rel=1e-3)


@pytest.mark.parametrize("offset", [0.0, 20.0, 40.0])
def test_an_auv_whose_path_crosses_the_collision_domain_ends_the_standing_at_its_entry(offset):
    """Coming towards the ASV at 1.35 m/s from 150 m, passing ``offset`` m to the side: with a
    miss distance below ``r_lo`` (50 m) the ASV can stand only until the AUV enters the
    collision domain, not until it leaves 195 m beyond (the falsified pursuer, session 12)."""
    ocp, f = _t_s()
    t = float(f(np.zeros(ocp.dims.nx), _sp(-155.4, offset), _sp(-150.0, offset)))
    assert t == pytest.approx((150.0 - np.sqrt(50.0**2 - offset**2)) / 1.35, rel=1e-3)


@pytest.mark.parametrize("offset", [60.0, 120.0])
def test_an_auv_passing_outside_the_collision_domain_leaves_the_whole_pass(offset):
    ocp, f = _t_s()
    t = float(f(np.zeros(ocp.dims.nx), _sp(-155.4, offset), _sp(-150.0, offset)))
    assert t == pytest.approx((150.0 + np.sqrt(195.0**2 - offset**2)) / 1.35, rel=1e-3)


def test_a_still_auv_leaves_a_long_time_and_one_beyond_the_bound_none():
    ocp, f = _t_s()
    x = np.zeros(ocp.dims.nx)
    assert float(f(x, _sp(-100.0, 0.0), _sp(-100.0, 0.0))) > 1e4
    assert float(f(x, _sp(-300.0, 0.0), _sp(-294.6, 0.0))) < 1e-3


def test_the_terminal_cost_prefers_ending_ahead_of_the_auv_only_with_stand():
    """The same distance (150 m) and fix age: ending ahead of the AUV (it comes towards the
    ASV and passes 60 m beside it: 239 s to stand) costs less than ending behind it (33 s)
    with ``stand`` > 0, the same without; ending in its path (it enters the 50-m collision
    domain after 74 s) costs more than beside it."""
    costs = {}
    for stand in (0.0, 20.0):
        ocp = _ocp(stand)
        gp = np.r_[0.0, 0.0, 80.0, 70.0, 1.0, np.zeros(6), ocp.weight_vector()]
        x = np.zeros(ocp.dims.nx)
        x[3], x[8] = 0.0, 30.0  # at rest, fix age 30 s
        zs = x / ocp.s_z  # the terminal function takes scaled states
        N_a = -np.sqrt(150.0**2 - 60.0**2)
        ahead = float(ocp.term(zs, _sp(N_a - 5.4, 60.0), _sp(N_a, 60.0), gp))
        behind = float(ocp.term(zs, _sp(144.6, 0.0), _sp(150.0, 0.0), gp))
        in_path = float(ocp.term(zs, _sp(-155.4, 0.0), _sp(-150.0, 0.0), gp))
        costs[stand] = (ahead, behind, in_path)
    assert costs[0.0][0] == pytest.approx(costs[0.0][1], rel=1e-9)
    assert costs[0.0][2] == pytest.approx(costs[0.0][1], rel=1e-9)
    assert costs[20.0][0] < costs[20.0][1] - 1e-3
    assert costs[20.0][0] < costs[20.0][2] - 1e-3
    assert costs[20.0][0] == pytest.approx(costs[0.0][0], abs=1e-6)  # 239 s: nothing short


@pytest.mark.parametrize(("auv_N", "stand_off"), [
    (60.0, True), (-60.0, True), (64.0, True), (68.0, False), (150.0, False),
])
def test_the_standing_time_is_off_while_an_auv_threatens_the_asv(auv_N, stand_off):
    """M7s extrapolates the AUV in a straight line past the horizon; a pursuer re-aims at the
    ASV, so while an AUV comes within its anti-collision radius plus 20 m of the ASV adrift
    (carried by the plan's current; none here: where it is) at some stage, the step's
    ``stand`` weight is 0 (runtime, no recompile), and so is the integral terminal's
    accrual (M7i: a pull towards the AUV that grows with its age).
    A still AUV at 20 m depth (r_inner 45.8 m): the threshold is 65.8 m."""
    from mpcasv.controllers import make_controller
    from mpcasv.interface import ASVState, AUVEstimate, Observation
    from mpcasv.mpc.layout import WEIGHT_NAMES

    ctrl = make_controller("mpc-single", 1, "mpc-single", boat=Boat.load("gretha"))
    ctrl.reset(1)
    assert ctrl.params.weights.stand == 20.0  # the preset's
    obs = Observation(0.0, ASVState(0.0, 0.0, 0.0), False, (AUVEstimate(auv_N, 0.0, 20.0),))
    r_inner = float(ctrl.domain.inner(20.0))
    assert r_inner + 20.0 == pytest.approx(65.8, abs=0.05)
    W = ctrl.ocp.unpack_par(ctrl.parameters(obs))["weights"]
    assert ctrl.stand_off is stand_off
    assert W[WEIGHT_NAMES.index("stand")] == (0.0 if stand_off else 20.0)
    # the integral terminal's accrual (M7i, the preset's) goes with it
    assert ctrl.params.weights.terminal == "integral"
    assert W[WEIGHT_NAMES.index("accrue")] == (0.0 if stand_off else 1.0)


@functools.cache
def _terminal_ocp(kind: str) -> OCP:
    return OCP(load_preset("mpc-single", "mpc-single",
                           {"weights.stand": 0.0, "weights.terminal": kind}),
               1, outer=True, boat=Boat.load("gretha"))  # fmt: skip


def _terminal(kind: str, tau: float, d: float, accrue: float = 1.0) -> float:
    """Terminal cost (no M7s) of a plan ending at rest ``d`` m South of the only AUV (still),
    with the AUV's expected fix age ``tau`` s there; r_t = 70 m, the preset's tail 20 s and
    U_go 2.5 m/s; ``accrue``: M7i's accrual weight (0 under a threat)."""
    ocp = _terminal_ocp(kind)
    w = ocp.weight_vector()
    w[-1] = accrue
    gp = np.r_[0.0, 0.0, 80.0, 70.0, 1.0, np.zeros(6), w]
    x = np.zeros(ocp.dims.nx)
    x[8] = tau
    return float(ocp.term(x / ocp.s_z, _sp(d, 0.0), _sp(d, 0.0), gp))


def test_the_integral_terminal_is_the_age_accrued_until_the_next_fix():
    """(M7i) ``age / tau_ref * (tau t + t^2 / 2)``, ``t = t_go + tail``: the running age cost
    integrated while the ASV goes to the target circle and waits a tail for the fix. Its pull
    (the cost of ending 100 m further out) grows with the fix age; M7a's does not, which left
    the MPC trailing 100 m off an AUV it had no fix from for minutes in a 1 m/s cross current
    (docs/mpc.md, "Closed loop ... session 39")."""
    t_go = {d: 5.0 * np.log1p(np.exp((d - 70.0) / 5.0)) / 2.5 for d in (80.0, 180.0)}
    for tau in (0.0, 200.0):
        for d in (80.0, 180.0):
            t = t_go[d] + 20.0
            assert _terminal("integral", tau, d) == pytest.approx((tau * t + t**2 / 2) / 100.0,
                                                                  rel=1e-5)  # fmt: skip
    pull = {(kind, tau): _terminal(kind, tau, 180.0) - _terminal(kind, tau, 80.0)
            for kind in ("projected", "integral") for tau in (0.0, 200.0)}  # fmt: skip
    assert pull["projected", 200.0] == pytest.approx(pull["projected", 0.0], rel=1e-9)
    assert pull["integral", 200.0] > 5.0 * pull["integral", 0.0]
    assert pull["integral", 0.0] > pull["projected", 0.0]  # the age accrued on the way
    # under a threat (accrue = 0) M7a's pull is left
    gated = _terminal("integral", 200.0, 180.0, 0.0) - _terminal("integral", 200.0, 80.0, 0.0)
    assert gated == pytest.approx(pull["projected", 200.0], rel=1e-9)
