"""AUV motion: a kinematic vehicle limited in speed, acceleration, turn rate and depth rate.

State per AUV ``[N, E, d, psi, U]`` (m, m, m down, rad, m/s: over ground without a current,
through the water with one); set-point ``[N_t, E_t, U_d, d_d]`` (a point to head for, a speed,
a depth); limits ``[U_max, r_max, w_max, a_max]`` (changeable per period: limit events, an
abort's rise rate); optionally a water current carrying each AUV. The kinematics are unrolled
over one supervisory period in CasADi and mapped over all AUVs, so moving every AUV costs one
call per period.
"""

from __future__ import annotations

import math
from functools import lru_cache

import casadi as ca
import numpy as np

from mpcasv.config import AUV_SPEED_MAX, between, frozen

NA = 5  # AUV state size
K_PSI = 1.0  # heading P-gain (1/s) before the turn-rate limit
K_DEPTH = 0.5  # depth P-gain (1/s) before the depth-rate limit
T_SPEED = 2.0  # speed first-order lag (s) before the acceleration limit

#: Bounds of an AUV's limits (scenario files: ``limits``, limits events, an abort's rise rate;
#: docs/experiments.md, "Bounds"): no AUV goes faster than AUV_SPEED_MAX, nor dives or rises
#: faster than it moves; the heading loop (K_PSI on an error of at most pi rad) never turns
#: faster than 180 deg/s; no propeller-driven AUV accelerates at 1 g.
SpeedLimit = between(0, AUV_SPEED_MAX, "m/s", "no AUV is faster", lo_open=True)
TurnRateLimit = between(0, 180, "deg/s", "the heading loop never turns faster", lo_open=True)
DepthRateLimit = between(0, AUV_SPEED_MAX, "m/s", "no AUV dives or rises faster than it moves",
                         lo_open=True)  # fmt: skip
AccelLimit = between(0, 9.81, "m/s^2", "1 g", lo_open=True)


@frozen
class AUVLimits:
    """Motion limits of an AUV (defaults: OceanScan LAUV, PAPER-FACTS §1)."""

    speed_max: SpeedLimit = 2.0  # m/s (thesis: max 2 m/s)
    turn_rate_max_deg: TurnRateLimit = 10.0  # deg/s (guess for a 1.8 m LAUV)
    depth_rate_max: DepthRateLimit = 0.5  # m/s (guess)
    accel_max: AccelLimit = 0.2  # m/s^2 (guess)

    def vector(self) -> np.ndarray:
        return np.array(
            [self.speed_max, math.radians(self.turn_rate_max_deg), self.depth_rate_max,
             self.accel_max]
        )  # fmt: skip


def _clip(x, lim):
    return ca.fmin(ca.fmax(x, -lim), lim)


@lru_cache(maxsize=16)
def auv_step_function(dt: float, n_sub: int, n_auv: int, drift: bool = False) -> ca.Function:
    """``F(S, SP, LIM) -> (S_next, S_traj)`` for ``n_auv`` AUVs (columns), ``n_sub`` steps.

    With ``drift``: ``F(S, SP, LIM, C)``, where ``C`` (2 x n_auv, m/s) is the water current
    ``(V_N, V_E)`` carrying each AUV during the period (added to its velocity through the water;
    ``U`` and ``psi`` then describe that velocity, the position moves over ground).
    """
    s0, sp, lim = ca.SX.sym("s", NA), ca.SX.sym("sp", 4), ca.SX.sym("lim", 4)
    c = ca.SX.sym("c", 2) if drift else ca.SX.zeros(2)
    s, traj = s0, []
    for _ in range(n_sub):
        N, E, d, psi, U = s[0], s[1], s[2], s[3], s[4]
        psi_d = ca.atan2(sp[1] - E, sp[0] - N)
        e_psi = ca.atan2(ca.sin(psi_d - psi), ca.cos(psi_d - psi))
        # do not turn when the target is (numerically) reached
        far = ca.hypot(sp[1] - E, sp[0] - N) > 0.5
        psi_dot = ca.if_else(far, _clip(K_PSI * e_psi, lim[1]), 0)
        U_d = ca.fmin(ca.fmax(sp[2], 0), lim[0])
        U_dot = _clip((U_d - U) / T_SPEED, lim[3])
        d_dot = _clip(K_DEPTH * (sp[3] - d), lim[2])
        U_next = U + dt * U_dot
        s = ca.vertcat(
            N + dt * (U_next * ca.cos(psi) + c[0]), E + dt * (U_next * ca.sin(psi) + c[1]),
            ca.fmax(d + dt * d_dot, 0), psi + dt * psi_dot, U_next,
        )  # fmt: skip
        traj.append(s)
    ins = [s0, sp, lim, c] if drift else [s0, sp, lim]
    f = ca.Function("auv_step", ins, [s, ca.horzcat(*traj)])
    return f.map(n_auv)
