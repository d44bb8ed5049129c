"""The OCP's per-stage terms (docs/mpc.md, "Cost" and "Variables and dynamics"): the stage
cost rate (M4, M4b, M4c), the path constraints (M5, M6), the smooth ranges and times to go,
and the standing time of eq. M7s. A mixin of :class:`~mpcasv.mpc.problem.OCP` (its
dimensions, weights and thresholds live there)."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from mpcasv.mpc.dynamics import NXV
from mpcasv.mpc.layout import NCH, WEIGHT_NAMES
from mpcasv.mpc.smooth import D_EPS, SOFT_T, SOFTPLUS_M, sigmoid, softplus

#: eq. M7s's smoothing: of the square root (m^2/s), of the room inside the bound (m^2), of
#: the sign of the approach d.v (m^2/s) and of the AUV's squared speed (m^2/s^2)
STAND_EPS, STAND_ROOM, STAND_DV, STAND_V2 = 1.0, 100.0, 10.0, 1e-4


class StageTerms:
    """Stage cost, path constraints and the geometry they share (mixin; state in the OCP)."""

    def _stage_cost(self, z, v, sp, W: dict, ext):
        """The stage cost rate ``L`` (per s; eqs. M4, M4b, M4c; with the variance objective
        M4n, M4d) at state ``z``, control ``v`` and stage parameters ``sp``."""
        d = self.dims
        K = d.n_auv
        T, u = z[6], z[3]
        L = W["age"] * ca.sum1(z[NXV : NXV + K])  # (M4)
        if d.epi:
            L += W["worst"] * v[2 + K]
        L += W["thrust"] * T + W["power"] * T * u
        L += W["dT"] * v[0] ** 2 + W["ddelta"] * v[1] ** 2
        L += W["slack"] * ca.sum1(v[2 : 2 + K])
        # (M4b) thrusts the execution level cannot hold (between the propeller-on threshold and
        # its transit thrust floor): without this the plan "creeps" quietly at a few newtons
        w_T = self.w_T
        running = sigmoid((T - self.T_on) / w_T)  # ~1 while the propeller runs
        L += W["deadband"] * running * sigmoid((self.T_floor - T) / w_T)
        L += W["running"] * running  # (M4c) propeller time (noise, wear), whatever the thrust
        w_floor = self.params.weights.floor  # compiled in: 0 builds the problem without it
        if w_floor > 0:  # (M4f) no ground surge below speed_min while the propeller runs: the
            # TRANSIT command clips its speed there, the execution level cannot follow it
            L += w_floor * running * ca.fmax(self.params.speed_min - u, 0) ** 2
        if ext is not None:
            L += self._variance_stage(z, sp, ext)  # (M4n, M4d)
        return L

    def _dist(self, z, sp):
        """Smooth horizontal ranges from the ASV to each AUV at one stage (m)."""
        K = self.dims.n_auv
        return [ca.sqrt((z[0] - sp[2 * i]) ** 2 + (z[1] - sp[2 * i + 1]) ** 2 + D_EPS**2)
                for i in range(K)]  # fmt: skip

    def _standing_time(self, z, sp0, sp, dt):
        """How long (s) the ASV could stand still at ``z``'s position before the AUV, moving on
        at its velocity over the last stage (``sp0`` -> ``sp``, ``dt`` s), leaves the donut
        (eq. M7s; one AUV): it reaches the outer bound ``r_hi`` (the root ``t >= 0`` of
        ``|d - v t| = r_hi``, ``d`` the ASV's offset from the AUV, in the form
        ``room / (sqrt((d.v)^2 + |v|^2 room) - d.v)`` with ``room = r_hi^2 - |d|^2``: no
        ``1 / |v|^2``, so a still AUV gives a very long time) or, first, if its path passes
        within the inner bound ``r_lo``, it enters the collision domain (the first root of
        ``|d - v t| = r_lo``, :meth:`_entry_time`). ``room`` enters as a softplus
        (``STAND_ROOM`` m^2), so the time is positive and smooth everywhere and about 0 outside
        the bound (where the donut's slack acts)."""
        d = z[0:2] - sp[0:2]
        v = (sp[0:2] - sp0[0:2]) / dt
        r_lo, r_hi = sp[2], sp[3]  # the single AUV's bounds (layout: pa (2), r_lo, r_hi, depth)
        room = STAND_ROOM * softplus((r_hi**2 - ca.sumsqr(d)) / STAND_ROOM)
        dv = ca.dot(d, v)
        t_out = room / (ca.sqrt(dv**2 + ca.sumsqr(v) * room + STAND_EPS**2) - dv)  # (M7s)
        t_in, enters = self._entry_time(d, v, r_lo)
        return t_out - enters * SOFT_T * softplus((t_out - t_in) / SOFT_T)  # ~min(t_out, t_in)

    @staticmethod
    def _entry_time(d, v, r_lo):
        """When (s) an AUV at offset ``-d`` (m) from the ASV, moving at ``v`` (m/s), enters the
        inner bound ``r_lo`` (m) around a still ASV, and a smooth indicator (0..1) that its
        path does (approaching, ``d.v > 0``, with a miss distance below ``r_lo``; eq. M7s):
        ``t_in = (|d|^2 - r_lo^2) / (d.v + sqrt(disc))``, ``disc = (d.v)^2 - |v|^2 (|d|^2 -
        r_lo^2)``. The squares are softplus-smoothed (``STAND_ROOM`` m^2), the sign of ``d.v``
        over ``STAND_DV`` m^2/s."""
        dv, vv, dd = ca.dot(d, v), ca.sumsqr(v), ca.sumsqr(d)
        outside = dd - r_lo**2
        disc = dv**2 - vv * outside
        miss = dv**2 / (vv + STAND_V2) - outside  # r_lo^2 - miss distance^2, m^2
        enters = sigmoid(miss / STAND_ROOM) * sigmoid(dv / STAND_DV)
        dv_pos = STAND_DV * softplus(dv / STAND_DV)
        root = ca.sqrt(STAND_ROOM * softplus(disc / STAND_ROOM) + STAND_EPS**2)
        t_in = STAND_ROOM * softplus(outside / STAND_ROOM) / (dv_pos + root)
        return t_in, enters

    def _t_go(self, z, sp, gp):
        """Time to reach each AUV's target circle from the stage's position (s, smooth)."""
        K = self.dims.n_auv
        r_t = gp[2 + K : 2 + 2 * K]
        inv_U = gp[2 + 3 * K + NCH + WEIGHT_NAMES.index("inv_U_go")]
        return ca.vertcat(*[SOFTPLUS_M * softplus((d - r_t[i]) / SOFTPLUS_M) * inv_U
                            for i, d in enumerate(self._dist(z, sp))])  # fmt: skip

    def _path(self, z, slack, m, sp):
        """Path constraints ``h`` of one stage and their bounds (M5, M6)."""
        K, d = self.dims.n_auv, self.dims
        r_lo, r_hi = sp[2 * K : 3 * K], sp[3 * K : 4 * K]
        dist = self._dist(z, sp)
        h, lb, ub = [], [], []
        for i in range(K):
            h.append(dist[i] + slack[i] - r_lo[i])
            lb.append(0.0)
            ub.append(math.inf)
            if d.outer:
                h.append(dist[i] - slack[i] - r_hi[i])
                lb.append(-math.inf)
                ub.append(0.0)
        if d.epi:
            for i in range(K):
                h.append(m - z[NXV + i])
                lb.append(0.0)
                ub.append(math.inf)
        return ca.vertcat(*h), np.array(lb), np.array(ub)
