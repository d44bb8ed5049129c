"""What a plan means for the boat and how to check it was followed (issue 16 item 4): the
planned energy over an executed period, the planned standby time, and the offsets at which
each used plan is logged for the plan-following metrics
(:func:`mpcasv.experiments.metrics.plan_following`)."""

from __future__ import annotations

import math

import numpy as np

from mpcasv.interface import PlannedTrajectory
from mpcasv.models.frames import ned_to_body

__all__ = ["PLAN_CHECK_S", "commands_standby", "plan_energy", "planned_standby"]

#: offsets (s) at which each used plan's position and thrust are logged (``mpc_plan_N<h>``,
#: ``mpc_plan_E<h>``, ``mpc_plan_T<h>``) and compared with what the boat did
#: (``plan_tracking_error_m``, :mod:`mpcasv.experiments.metrics`): the near horizon, up to
#: the presets' ``lookahead`` (the part of the plan the TRANSIT waypoint stands for)
PLAN_CHECK_S = (5, 10, 15)


def plan_energy(plan: PlannedTrajectory, t1: float, n: int = 20) -> float:
    """Propulsive energy (J) ``plan`` meant to spend from its start to ``t1`` (s): thrust x
    surge speed through the water, ``T |u - u_c|`` with ``u_c`` the planned current along
    the planned heading (the definition of ``energy_J``), on the plan's linear interpolation
    between stages, trapezoidal rule with ``n`` intervals."""
    t = np.linspace(plan.t[0], t1, n + 1)
    if t1 <= plan.t[0]:
        return 0.0
    x = plan.extra
    T, u, psi = (np.interp(t, plan.t, x[k]) for k in ("T", "u", "psi"))
    c = x["current"]
    power = T * np.abs(u - ned_to_body(psi, c[0], c[1])[0])
    return float(np.sum(0.5 * (power[1:] + power[:-1]) * np.diff(t)))


def commands_standby(T: np.ndarray, dt: float, standby_time: float, T_on: float) -> bool:
    """The STANDBY rule: a plan whose thrust ``T`` (N, at stages of ``dt`` s, ``T[0]`` the
    observed state) stays below the propeller-on threshold ``T_on`` over the next
    ``standby_time`` s (at least one stage) is handed over as STANDBY, whatever it does later."""
    m = max(1, math.ceil(standby_time / dt - 1e-9))
    return bool(np.max(np.asarray(T, float)[1 : m + 1]) < T_on)


def planned_standby(ts: np.ndarray, T: np.ndarray, T_on: float) -> float:
    """How long (s) from now a standby plan (thrust ``T`` at stage offsets ``ts``, s; below
    ``T_on`` at the first stage, the STANDBY rule) keeps the propeller off: until its thrust
    next reaches ``T_on`` after the first stage (linear between stages); the horizon's length
    when it never does (a lower bound). The thrust at ``ts[0]`` (the observed state) is not
    looked at: the plan may be stopping a running propeller."""
    T = np.asarray(T, float)
    above = np.flatnonzero(T[1:] >= T_on) + 1
    if not above.size:
        return float(ts[-1])
    k = int(above[0])
    if T[k - 1] >= T_on:  # not a standby plan: the thrust is on at the first stage
        return 0.0
    return float(ts[k - 1] + (T_on - T[k - 1]) / (T[k] - T[k - 1]) * (ts[k] - ts[k - 1]))
