"""The exploration's guess (``OCP.guided_rollout``) goes round the other AUVs' anti-collision
radii (session 13): from a guess straight through a stopped AUV's domain the solve kept its
way through, and Case 6, seed 14 stood by for its last 262 s beside a stopped AUV that lay
across the way to its target (docs/mpc.md, "Controller step")."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_mpc_between_steps import _start

from mpcasv.mpc.warmstart import around

NORTH = np.array([100.0, 0.0])


def _ray_miss(here, psi, c):
    """Distance (m) from ``c`` to the ray from ``here`` along heading ``psi``."""
    u = np.array([math.cos(psi), math.sin(psi)])
    w = np.asarray(c, float) - here
    return float(np.hypot(*(w - max(float(w @ u), 0.0) * u)))


def test_straight_on_when_nothing_is_in_the_way():
    here = np.zeros(2)
    assert around(here, NORTH, np.empty((0, 2)), np.empty(0)) == pytest.approx(0.0)
    # a disc beside the way, and one behind
    centres, radii = np.array([[50.0, 40.0], [-60.0, 0.0]]), np.array([30.0, 50.0])
    assert around(here, NORTH, centres, radii) == pytest.approx(0.0)


@pytest.mark.parametrize("offset", [-10.0, 0.5, 10.0])
def test_round_a_disc_in_the_way_on_the_nearer_side(offset):
    """The tangent: the new heading's ray touches the disc, on the side away from its
    centre's offset (the shorter way round)."""
    here, c, R = np.zeros(2), np.array([50.0, offset]), 30.0
    psi = around(here, NORTH, c[None, :], np.array([R]))
    assert _ray_miss(here, psi, c) == pytest.approx(R, abs=1e-6)
    assert math.copysign(1.0, psi) == -math.copysign(1.0, offset)
    assert abs(psi) < math.pi / 2  # still forwards


@pytest.mark.parametrize(("centres", "radius"), [
    ([[100.0, 60.0], [110.0, 0.0]], 65.0),  # entered first: not the one whose centre is first
    ([[150.0, -10.0], [170.0, 100.0]], 65.0),  # overlapping: one's tangent leads into the other
    ([[100.0, 10.0], [200.0, 50.0], [200.0, -50.0]], 40.0),  # a gap too narrow, behind a third
])
def test_round_several_discs(centres, radius):
    """The heading's ray enters none of the discs before the goal (300 m North): a tangent
    that leads into another disc is widened to that disc's, on the same side."""
    here, goal = np.zeros(2), np.array([300.0, 0.0])
    c, R = np.array(centres), np.full(len(centres), radius)
    psi = around(here, goal, c, R)
    assert all(_ray_miss(here, psi, ci) >= Ri - 1e-6 for ci, Ri in zip(c, R, strict=True))


def test_within_the_clearance():
    """Inside a disc: straight on when that leads away from its centre, else along its
    circle (perpendicular to the centre's bearing), on the side nearer the goal."""
    here = np.zeros(2)
    behind = np.array([[-20.0, 0.0]])
    assert around(here, NORTH, behind, np.array([30.0])) == pytest.approx(0.0)
    ahead_left = np.array([[20.0, -5.0]])
    psi = around(here, NORTH, ahead_left, np.array([30.0]))
    psi_c = math.atan2(-5.0, 20.0)
    assert psi == pytest.approx(psi_c + math.pi / 2)


def test_the_guess_keeps_out_of_a_stopped_auv_in_the_way(scenarios_dir):
    """Case 6's first step with AUV 1 as the target and AUV 0 moved onto the straight way
    there, 90 m ahead, stopped: the guess keeps outside the plan's inner bound for it at
    every stage (straight through it before session 13)."""
    ctrl, obs, p = _start(scenarios_dir, "case6", "mpc-multi")
    ocp, p = ctrl.ocp, p.copy()
    par = ocp.unpack_par(p)  # views into p
    here = par["z0"][:2].copy()
    to = par["pa"][0, 1] - here
    block = here + 90.0 * to / np.hypot(*to)
    par["pa"][:, 0] = block
    Z, _ = ocp.split(ocp.guided_rollout(p, 1, 2.5))
    gap = np.hypot(*(Z[:, :2] - block).T) - par["r_lo"][:, 0]
    # r_lo holds the plan's 5 m margin; the guess aims CLEAR beyond it and turns late
    # (5.3 m beyond it); straight through before session 13 (34.6 m inside)
    assert gap.min() > 0.0, f"the guess comes {-gap.min():.1f} m inside r_lo"
    start, end = (np.hypot(*(Z[i, :2] - par["pa"][i, 1])) for i in (0, -1))
    assert start - end > 25.0  # and it gets on (from rest and round the disc: 38 m in 60 s)


def test_a_turn_towards_a_goal_astern_keeps_its_side():
    """The guesses steer stage by stage for a goal heading (``steered_rollout``). With the goal
    astern, flipping 0.1 rad across the stern from one stage to the next (as the bearing of a
    point near astern does when the boat moves), a turn beyond ``TURN_COMMIT`` keeps its
    side: the steering stays at the lock and the heading turns one way through more than a
    full circle in the horizon. Before session 34 each stage took the shorter side: the
    steering chattered lock to lock and the heading stayed within 0.6 rad of its start."""
    from mpcasv.controllers import make_controller
    from mpcasv.interface import ASVState, AUVEstimate, Observation

    c = make_controller("mpc-single", 1, "mpc-single")
    c.reset(1)
    obs = Observation(0.0, ASVState(0.0, 0.0, 0.0, 2.0), True,
                      (AUVEstimate(400.0, 400.0, 0.0),))  # fmt: skip
    p, ocp = c.parameters(obs), c.ocp
    assert not ocp.heading  # steering planned (the heading-reference plan is M1h's)

    def astern(k, z):
        return z[2] + math.pi + (0.05 if k % 2 else -0.05)

    Z, _ = ocp.split(ocp.steered_rollout(p, astern, lambda k, z: 0.5 * ocp.vessel.T_max))
    steer = Z[1:, 7]
    assert np.all(steer > 0.0)  # one side throughout (the first stage's e is +pi - 0.05)
    assert np.all(np.diff(Z[:, 2]) > 0.0) and Z[-1, 2] > 2.0 * math.pi


def test_a_committed_turn_keeps_its_side_only_beyond_turn_commit():
    """``_committed``: a turn beyond ``TURN_COMMIT`` (135 deg) takes the shorter side and
    commits to it; while committed, a goal that crosses the stern is reached the committed
    way (the longer one); at or within ``TURN_COMMIT`` the shorter way, and the commitment
    ends."""
    from mpcasv.mpc.warmstart import TURN_COMMIT, _committed

    e, side = _committed(math.pi - 0.1, 0.0, 0.0)  # a new turn to port of the stern: free
    assert e == pytest.approx(math.pi - 0.1) and side == 1.0
    e, side = _committed(-(math.pi - 0.1), 0.0, 1.0)  # crossed the stern: kept to +
    assert e == pytest.approx(math.pi + 0.1) and side == 1.0
    e, side = _committed(-(math.pi - 0.1), 0.0, -1.0)  # committed the same way: as it is
    assert e == pytest.approx(-(math.pi - 0.1)) and side == -1.0
    e, side = _committed(-TURN_COMMIT, 0.0, 1.0)  # at TURN_COMMIT: the shorter way, ended
    assert e == pytest.approx(-TURN_COMMIT) and side == 0.0
    e, side = _committed(0.5, 6.0 * math.pi + 0.2, 1.0)  # unwrapped: the wrapped difference
    assert e == pytest.approx(0.3) and side == 0.0
