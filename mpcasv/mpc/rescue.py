"""What the MPC does before it hands a step to the hybrid controller (issue 16 item 7).

The warm start (the previous plan moved on) is usually the best start; it fails in two ways
(docs/mpc.md, "Fallbacks"): the solver stops at its iteration limit, or it converges to a plan
that goes deeper into an anti-collision radius, a local minimum of a plan that was heading
towards an AUV that then turned towards the ASV (at speed the steering needs several seconds
to turn the boat, and the solver's local model cannot see the turn-away plan). Before the
step is handed to the hybrid controller the MPC solves again from guesses built here, each a
dynamically consistent rollout of the plan model under a simple stage-wise steering and
thrust law:

- :func:`escape_guess`: full thrust, steering away from the AUVs whose anti-collision radius
  the ASV is in or is about to enter (the direction that opens the range fastest);
- :func:`command_guess`: what the hybrid controller commands this step (steer for its
  waypoint at its speed cap, or stop for its standby).

Only the primal start changes: the problem, its constraints and its cost are the same.
:func:`funnel` relaxes the range bounds (parameters) when the ASV is far outside them, so
that such a step is solved rather than handed over (docs/mpc.md, "Fallbacks").
"""

from __future__ import annotations

import math

import numpy as np

from mpcasv.mpc.problem import OCP

#: AUVs closer than their anti-collision radius (margin included) plus this (m), at some
#: stage with the ASV adrift (carried by the plan's current), are the ones to escape from
ESCAPE_BUFFER = 20.0


def threats(ocp: OCP, p: np.ndarray, margin: float) -> np.ndarray:
    """Which AUVs (bool, shape (K,)) come within their anti-collision radius plus
    ``ESCAPE_BUFFER`` (``r_lo`` in ``p`` includes the plan's ``margin``, taken off here) of the
    ASV adrift (propeller off, carried by the plan's current from where it is), at some stage
    of the horizon. Not held where it is: a boat that stops moves with the water, and an AUV
    the current carries it onto is a threat as well (session 34). The AVOIDANCE label and the
    exploration's "already there" test (:mod:`mpcasv.mpc.plan_output`, :mod:`mpcasv.mpc.safety`)
    still hold the ASV where it is: session 17 tried the drift there and dropped it (7 hangs,
    more time in the collision domain; docs/mpc.md "Controller step" 3), not re-measured since."""
    par = ocp.unpack_par(p)
    here = par["z0"][None, 0:2] + ocp.t_stage[:, None] * par["current"][None, :]  # (N+1, 2)
    here = here[:, None, :]  # against each AUV
    dist = np.hypot(*(par["pa"] - here).transpose(2, 0, 1))  # (N+1, K)
    return np.any(dist < par["r_lo"] - margin + ESCAPE_BUFFER, axis=0)


def escape_heading(ocp: OCP, p: np.ndarray, k: int, z: np.ndarray, near: np.ndarray):
    """Heading (rad) that opens the range to the threatening AUVs ``near`` fastest at stage
    ``k`` from state ``z``: away from each, weighted by the inverse square of its range
    (None: no threat)."""
    par = ocp.unpack_par(p)
    if not np.any(near):
        return None
    rel = z[0:2] - par["pa"][k][near]  # (k, 2) AUV -> ASV
    r = np.maximum(np.hypot(rel[:, 0], rel[:, 1]), 1.0)
    v = np.sum(rel / r[:, None] ** 3, axis=0)
    if np.hypot(*v) < 1e-12:
        return None
    return math.atan2(v[1], v[0])


def escape_guess(ocp: OCP, p: np.ndarray, margin: float,
                 T_cap: float | None = None) -> np.ndarray | None:  # fmt: skip
    """Full thrust (``T_cap`` N under a speed cap, :mod:`mpcasv.mpc.speedcap`) away from
    the AUVs that threaten the ASV (:func:`threats`); None when none does."""
    near = threats(ocp, p, margin)
    if not np.any(near):
        return None
    T_go = ocp.vessel.T_max if T_cap is None else T_cap
    return ocp.steered_rollout(p, lambda k, z: escape_heading(ocp, p, k, z, near),
                               lambda k, z: T_go)


def command_guess(ocp: OCP, p: np.ndarray, waypoint, speed: float) -> np.ndarray:
    """The hybrid controller's command as a plan: steer for ``waypoint`` (N, E; m) with the
    thrust of ``speed`` (m/s), or (``waypoint`` None: STANDBY) thrust and steering to 0."""
    if waypoint is None:
        return ocp.steered_rollout(p, lambda k, z: None, lambda k, z: 0.0)
    wp = np.asarray(waypoint, float)
    T_go = ocp.model.thrust_for_speed(min(speed, ocp.vessel.u_max))
    return ocp.steered_rollout(p, lambda k, z: math.atan2(wp[1] - z[1], wp[0] - z[0]),
                               lambda k, z: T_go)


def funnel(ocp: OCP, p: np.ndarray, max_gap: float, speed: float) -> np.ndarray:
    """Parameters whose range bounds are relaxed where the ASV is now more than ``max_gap``
    (m) outside them (beyond ``r_hi`` or inside ``r_lo``; the bounds in ``p`` include the
    margin): at stage ``k`` by ``max(gap - speed t_k, 0)``, a funnel that closes at ``speed``
    (m/s). The slacks then measure how far the plan lags behind a return at that speed, not
    the whole gap: with a gap of hundreds of metres (an AUV estimate that jumped when a report
    arrived) the exact-penalty problem was badly scaled (costs 1e5-1e6 against about 1e2) and
    fatrop met NaNs and never returned, so such steps used to go to the hybrid controller
    unsolved. Returns a copy; ``p`` unchanged when no gap exceeds ``max_gap``."""
    p = np.array(p, float)
    par = ocp.unpack_par(p)  # views into p
    d0 = np.hypot(*(par["pa"][0] - par["z0"][0:2]).T)
    t = ocp.t_stage[:, None]
    out = d0 - par["r_hi"][0]
    inn = par["r_lo"][0] - d0
    if np.any(out > max_gap):
        par["r_hi"][:] += np.where(out > max_gap, np.maximum(out - speed * t, 0.0), 0.0)
    if np.any(inn > max_gap):
        par["r_lo"][:] -= np.where(inn > max_gap, np.maximum(inn - speed * t, 0.0), 0.0)
    return p
