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

import casadi as ca
import numpy as np
import pytest

from mpcasv.controllers import Boat, load_preset
from mpcasv.mpc.problem import OCP


def _ocp(stand: float | None = None) -> OCP:
    over = {} if stand is None else {"weights.stand": stand}
    return OCP(load_preset("mpc-single", "mpc-single", over), 1, outer=True,
               boat=Boat.load("gretha"))  # fmt: skip


def _sp(N_, E_, r_hi=195.0):
    return np.array([N_, E_, 50.0, r_hi, 0.0])  # pa (2), r_lo, r_hi, depth


@pytest.mark.parametrize(("auv_from", "expected"), [
    ((-105.4, 0.0), 295.0 / 1.35),  # coming towards the ASV: passes it, leaves 195 m beyond
    ((-94.6, 0.0), 95.0 / 1.35),  # going away from 100 m
    ((-100.0, 20.0), None),  # across the line: |(100, -E(t))| = 195
])
def test_the_standing_time_is_when_the_auv_reaches_the_outer_bound(auv_from, expected):
    ocp = _ocp()
    z = ca.SX.sym("z", ocp.dims.nx)
    s0, s1 = ca.SX.sym("s0", 5), ca.SX.sym("s1", 5)
    f = ca.Function("t_s", [z, s0, s1], [ocp._standing_time(z, s0, s1, 4.0)])
    v = (np.array([-100.0, 0.0]) - np.array(auv_from)) / 4.0
    if expected is None:  # 1.35 m/s... here 5 m/s west: E(t) = 5 t, 100^2 + (5 t)^2 = 195^2
        expected = float(np.sqrt(195.0**2 - 100.0**2) / np.hypot(*v))
    t = float(f(np.zeros(ocp.dims.nx), _sp(*auv_from), _sp(-100.0, 0.0)))
    assert t == pytest.approx(expected, rel=1e-3)


def test_a_still_auv_leaves_a_long_time_and_one_beyond_the_bound_none():
    ocp = _ocp()
    z = ca.SX.sym("z", ocp.dims.nx)
    s0, s1 = ca.SX.sym("s0", 5), ca.SX.sym("s1", 5)
    f = ca.Function("t_s", [z, s0, s1], [ocp._standing_time(z, s0, s1, 4.0)])
    x = np.zeros(ocp.dims.nx)
    assert float(f(x, _sp(-100.0, 0.0), _sp(-100.0, 0.0))) > 1e4
    assert float(f(x, _sp(-300.0, 0.0), _sp(-294.6, 0.0))) < 1e-3


def test_the_terminal_cost_prefers_ending_ahead_of_the_auv_only_with_stand():
    """The same distance (150 m) and fix age: ending ahead of the AUV (it comes towards the
    ASV: 256 s to stand) costs less than ending behind it (33 s) with ``stand`` > 0, the same
    without."""
    costs = {}
    for stand in (0.0, 20.0):
        ocp = _ocp(stand)
        gp = np.r_[0.0, 0.0, 80.0, 70.0, 1.0, np.zeros(6), ocp.weight_vector()]
        x = np.zeros(ocp.dims.nx)
        x[3], x[8] = 0.0, 30.0  # at rest, fix age 30 s
        s0 = np.r_[ocp.s_z]
        zs = x / s0  # the terminal function takes scaled states
        ahead = float(ocp.term(zs, _sp(-155.4, 0.0), _sp(-150.0, 0.0), gp))
        behind = float(ocp.term(zs, _sp(144.6, 0.0), _sp(150.0, 0.0), gp))
        costs[stand] = (ahead, behind)
    assert costs[0.0][0] == pytest.approx(costs[0.0][1], rel=1e-9)
    assert costs[20.0][0] < costs[20.0][1] - 1e-3
    assert costs[20.0][0] == pytest.approx(costs[0.0][0], abs=1e-6)  # 256 s: nothing short
