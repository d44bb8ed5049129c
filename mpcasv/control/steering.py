"""Steering authority of a steerable drive at full lock, and the thrust floor it sizes.

A steerable stern drive turns the boat by its side force ``T sin(delta) + |Y_uudelta| u^2
delta``: at low speed and little thrust it barely turns (thrust vectoring needs thrust). The
execution level (:func:`mpcasv.control.execution.steering_floor`) therefore keeps a least
thrust at full lock, sized here from the model's steady full-lock turns (docs/tuning.md,
"Thrust floor and eq. 3.1"):

    T_lock = min(T_req, T_hold)

- ``T_req``: the least thrust whose steady full-lock turn reaches the yaw rate ``r_steer``
  (the steering-authority criterion, ``ExecutionParams.r_steer``);
- ``T_hold``: the thrust whose steady full-lock turn runs at eq. 3.1's turn speed ``u_ff``.
  More thrust than that would hold the boat above eq. 3.1's command in a hard turn.
"""

from __future__ import annotations

import dataclasses
import math

import casadi as ca
import numpy as np

from mpcasv.control.params import ExecutionParams
from mpcasv.models.vessel import IX, NC, VesselModel

#: thrust grid (fractions of T_max) and settling run of :func:`full_lock_turns`
N_GRID, T_SETTLE, DT_SETTLE = 57, 400.0, 0.2


@dataclasses.dataclass(frozen=True)
class FullLockTurns:
    """Steady full-lock turns of the open-loop model (still water), one per thrust.

    ``T`` (N), ``u`` (m/s), ``v`` (m/s), ``r`` (rad/s): arrays of shape ``(N_GRID,)``;
    ``T`` increasing up to ``T_max``, ``r`` positive (turning the way the steering asks).
    """

    T: np.ndarray
    u: np.ndarray
    v: np.ndarray
    r: np.ndarray

    def thrust_for_rate(self, r: float) -> float:
        """Least thrust (N) whose steady turn reaches yaw rate ``r`` (rad/s); ``inf`` if none."""
        ok = np.flatnonzero(self.r >= r)
        if not ok.size:
            return math.inf
        i = int(ok[0])
        if i == 0:
            return float(self.T[0])
        return float(np.interp(r, self.r[i - 1 : i + 1], self.T[i - 1 : i + 1]))

    def thrust_for_speed(self, u: float) -> float:
        """Least thrust (N) whose steady turn runs at surge speed ``u``; ``inf`` if none."""
        ok = np.flatnonzero(self.u >= u)
        if not ok.size:
            return math.inf
        i = int(ok[0])
        if i == 0:
            return float(self.T[0])
        return float(np.interp(u, self.u[i - 1 : i + 1], self.T[i - 1 : i + 1]))


_TURNS: dict = {}


def full_lock_turns(model: VesselModel) -> FullLockTurns:
    """Steady turns at ``delta = +delta_max`` for thrusts up to ``T_max`` (cached per model).

    Thrusts ``T_max k / (N_GRID - 1)``, ``k = 1 ...``; each turn is the end of a 400 s
    open-loop run (RK4, 0.2 s, in the sub-steps a stiff hull needs: :meth:`VesselModel.rk4`)
    from 0.5 m/s straight ahead, settled when ``|nu_dot|`` is below
    1e-4 (m/s^2, rad/s^2). The grid ends before the first thrust whose turn does not settle
    (a course-unstable hull may circle in a limit cycle at high thrust).

    Raises
    ------
    ValueError
        One line naming the vessel, if not even the smallest thrust's turn settles.
    """
    key = model.p.tobytes()
    if key in _TURNS:
        return _TURNS[key]
    P = model.params
    n = int(round(T_SETTLE / DT_SETTLE))
    F = model.rk4(DT_SETTLE)
    x, T = ca.SX.sym("x", len(IX)), ca.SX.sym("T")
    step = ca.Function("step", [x, T], [F(x, ca.vertcat(T, P.delta_max), ca.DM.zeros(NC))])
    run = step.mapaccum("run", n, [0], [0])  # state accumulated, thrust repeated
    rows = []
    for Tk in np.linspace(0.0, P.T_max, N_GRID)[1:]:
        x0 = np.zeros(len(IX))
        x0[IX["u"]], x0[IX["T"]], x0[IX["delta"]] = 0.5, Tk, P.delta_max
        end = np.array(run(x0, np.full((1, n), Tk)))[:, -1]
        xdot = np.array(model.f(end, [Tk, P.delta_max], np.zeros(NC))).ravel()
        if np.abs(xdot[IX["u"] : IX["r"] + 1]).max() > 1e-4:
            break
        rows.append((Tk, end[IX["u"]], end[IX["v"]], end[IX["r"]]))
    if not rows:
        raise ValueError(f"{P.name}: no full-lock turn settles in {T_SETTLE:g} s")
    out = FullLockTurns(*(np.array(c) for c in zip(*rows, strict=True)))
    _TURNS[key] = out
    return out


def lock_thrust(model: VesselModel, ep: ExecutionParams) -> dict[str, float]:
    """The full-lock thrust floor and its two bounds (module docstring).

    Returns ``{"T_lock", "T_req", "T_hold", "r_lock", "u_lock"}``: N, N, N, rad/s (steady
    yaw rate at ``T_lock``), m/s (its steady surge speed). ``T_req`` or ``T_hold`` is ``inf``
    when no thrust up to ``T_max`` reaches the rate or the speed (then ``T_lock`` is the
    other one, or ``T_max``).
    """
    turns = full_lock_turns(model)
    T_req = turns.thrust_for_rate(ep.r_steer)
    T_hold = turns.thrust_for_speed(ep.reference.u_ff)
    T_lock = min(T_req, T_hold)
    if not math.isfinite(T_lock):
        if turns.T[-1] < model.params.T_max:
            raise ValueError(f"{model.params.name}: no settled full-lock turn up to "
                             f"{turns.T[-1]:.4g} N reaches r_steer or u_ff")  # fmt: skip
        T_lock = model.params.T_max
    return {
        "T_lock": T_lock, "T_req": T_req, "T_hold": T_hold,
        "r_lock": float(np.interp(T_lock, turns.T, turns.r)),
        "u_lock": float(np.interp(T_lock, turns.T, turns.u)),
    }  # fmt: skip
