"""A plan-aware predictor: the AUV follows its known survey plan, until it does not.

Pre-planned surveys are the usual case: the ASV knows the AUV's waypoints, speed and planned
surface intervals (in the field: the Neptus plan). Between fixes the AUV is then predicted
*along the planned path* rather than along a straight line, which is right through turns,
lawnmower ends and surface intervals, where a constant-velocity model is wrong.
The plan as the ASV knows it (:class:`~mpcasv.estimation.survey_plan.KnownPlan`) and its
path (:class:`~mpcasv.estimation.survey_plan.Polyline`) are in
:mod:`mpcasv.estimation.survey_plan`.

Path. The polyline ``xi(s)`` through the AUV's start and its waypoints, ``s`` the arc length
(m), unit tangent ``T(s)`` on each segment. Planned along-track speed
``u_p(t) = U`` (``U_s`` inside a planned surface interval; 0 once the plan is finished).

State ``x = [s, e_u, b_N, b_E]``: along-track position, along-track speed error (m/s) and a
horizontal offset from the path (cross-track error, navigation bias of the reports):

    s(t + dt) = s + int_t^{t+dt} u_p + e_u dt,   e_u, b random walks                (P1)
    position  = xi(clip(s, 0, S)) + b,           velocity = (u_p + e_u) T(s)         (P2)

Fixes and reports update it as an (iterated) extended Kalman filter with
``H = [[T, 0, I], [0, T, 0]]`` (velocity rows for reports only). Near a waypoint the AUV cuts
or overshoots the corner by up to its turn radius ``U / r_max`` plus the acceptance radius,
and its heading is anything in between (at the last waypoint it stops): a path-model error
is added to ``R`` there.

Departure. Every measurement is gated on the plan hypothesis: normalised innovation squared
``nu^T S^-1 nu`` above the chi-square quantile ``gate_prob`` (2 or 4 degrees of freedom).
A measurement that fails the gate is not applied to the plan filter and the estimate falls
back to a :class:`~mpcasv.estimation.kalman.KalmanEstimator` that runs on every measurement;
``n_miss`` consecutive failures declare a departure. The plan is re-acquired when the
Kalman estimate lies on the path (within the gate) and moves along it, ``n_hit`` times in a
row.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from mpcasv.config import NonNeg, Pos, PosInt, Prob, frozen
from mpcasv.estimation.kalman import KalmanEstimator, KalmanParams, report_velocity
from mpcasv.estimation.survey_plan import KnownPlan, Polyline
from mpcasv.interface import AUVEstimate
from mpcasv.models.acoustics import Fix, Report

__all__ = ["PlanEstimator", "PlanParams"]


@functools.lru_cache(maxsize=32)
def _chi2_ppf(prob: float, dof: int) -> float:
    """Chi-square quantile (scipy.stats imported lazily: it costs ~1.5 s at start-up)."""
    from scipy.stats import chi2

    return float(chi2.ppf(prob, dof))


@frozen
class PlanParams:
    """Tuning of :class:`PlanEstimator` (SI units).

    Attributes
    ----------
    q_s : float
        Random walk of the along-track position (m^2/s): speed transients.
    q_u : float
        Random walk of the along-track speed error (m^2/s^3).
    q_b : float
        Random walk of the offset from the path (m^2/s).
    sigma_s0, sigma_u0, sigma_b0 : float
        Initial 1-sigma of ``s`` (m), ``e_u`` (m/s) and each offset axis (m).
    sigma_path : float
        Path-model error away from waypoints, 1 sigma (m).
    turn_rate_max_deg : float
        The AUV's turn-rate limit (deg/s): near a waypoint the path-model error is
        ``acceptance + U / r_max`` and the heading is free (velocity error ``U``).
    gate_prob : float
        Probability of the chi-square gate on the plan hypothesis.
    n_miss, n_hit : int
        Consecutive gate failures that declare a departure; consecutive on-path Kalman
        estimates that re-acquire the plan.
    """

    q_s: NonNeg = 0.05
    q_u: NonNeg = 1e-5
    q_b: NonNeg = 0.01
    sigma_s0: NonNeg = 5.0
    sigma_u0: NonNeg = 0.1
    sigma_b0: NonNeg = 2.0
    sigma_path: Pos = 1.0
    turn_rate_max_deg: Pos = 10.0
    gate_prob: Prob = 0.999
    n_miss: PosInt = 2
    n_hit: PosInt = 2


class PlanEstimator:
    """Plan-aware predictor with a Kalman-filter fallback (see the module docstring).

    Parameters
    ----------
    initial : AUVEstimate, optional
        The AUV's start (the first vertex of the path); without it the path starts at the
        first waypoint and the filter anchors on the first measurement.
    plan : KnownPlan, optional
        Without a plan the estimator is exactly its Kalman filter (``mode == "kalman"``).
    params : PlanParams, optional
    kalman : KalmanParams, optional
        Tuning of the fallback filter.
    """

    name = "plan"

    def __init__(self, initial: AUVEstimate | None = None, plan: KnownPlan | None = None,
                 params: PlanParams | None = None, kalman: KalmanParams | None = None):  # fmt: skip
        self.params = params or PlanParams()
        self.kf = KalmanEstimator(initial, kalman)
        self.plan = plan
        self.x = np.full(4, math.nan)
        self.P = np.full((4, 4), math.nan)
        self.t = math.nan
        self.on_plan = False  # the last measurement agreed with the plan
        self.departed = plan is None
        self.misses = self.hits = 0
        self.nis = math.nan
        self.departures: list[float] = []  # times a departure was declared
        self.path: Polyline | None = None
        if plan is not None:
            start = [] if initial is None or not math.isfinite(initial.N) else [
                [initial.N, initial.E]]  # fmt: skip
            self.path = Polyline(np.vstack([*start, *plan.waypoints]) if start else plan.waypoints)
            if start:
                p = self.params
                self.x = np.array([0.0, 0.0, 0.0, 0.0])
                self.P = np.diag([p.sigma_s0**2, p.sigma_u0**2, p.sigma_b0**2, p.sigma_b0**2])
                self.t = self.kf.t
                self.on_plan = True

    @property
    def mode(self) -> str:
        """``"plan"`` while the plan hypothesis holds, else ``"kalman"``."""
        return "plan" if self.on_plan and not self.departed else "kalman"

    # -- events ---------------------------------------------------------------------------

    def on_truth(self, t, N, E, depth, v_N, v_E) -> None:
        pass

    def on_fix(self, fix: Fix) -> None:
        self.kf.on_fix(fix)
        self._plan_measure(fix.t, np.array([fix.N, fix.E]), np.reshape(fix.cov, (2, 2)))

    def on_report(self, report: Report) -> None:
        self.kf.on_report(report)
        z, R = np.array([report.N, report.E]), report.nav_sigma**2 * np.eye(2)
        kp = self.kf.params
        if kp.report_velocity:
            zv, Rv = report_velocity(report, kp.sigma_speed, math.radians(kp.sigma_heading_deg))
            z = np.concatenate([z, zv])
            R = np.block([[R, np.zeros((2, 2))], [np.zeros((2, 2)), Rv]])
        self._plan_measure(report.t, z, R)

    # -- plan filter ----------------------------------------------------------------------

    def _predict(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Plan state and covariance at ``t`` (P1); pure."""
        p, dt = self.params, t - self.t
        F = np.eye(4)
        F[0, 1] = dt
        x = F @ self.x
        x[0] += self.plan.speed_integral(self.t, t)
        a = abs(dt)
        Q = np.zeros((4, 4))
        Q[:2, :2] = p.q_u * np.array([[a**3 / 3, dt * a / 2], [dt * a / 2, a]])
        Q[0, 0] += p.q_s * a
        Q[2, 2] = Q[3, 3] = p.q_b * a
        return x, F @ self.P @ F.T + Q

    def _h(self, x: np.ndarray, t: float, n: int):
        """Measurement prediction and Jacobian (P2) for ``n`` = 2 (position) or 4 rows."""
        xi, T = self.path.point(x[0])
        H = np.zeros((n, 4))
        H[0:2, 0] = T
        H[0:2, 2:4] = np.eye(2)
        h = xi + x[2:4]
        if n == 4:
            u = self.plan.speed_at(t) + x[1] if np.any(T) else 0.0
            H[2:4, 1] = T
            h = np.concatenate([h, u * T])
        return h, H

    def _model_noise(self, s: float, t: float, n: int) -> np.ndarray:
        """Path-model error added to ``R`` (larger near waypoints: corner cutting, turns)."""
        p, plan = self.params, self.plan
        U = max(plan.speed_at(t), plan.speed)
        r_turn = U / math.radians(p.turn_rate_max_deg)
        near = self.path.corner_distance(s) < math.pi * r_turn + plan.acceptance
        sig = plan.acceptance + r_turn if near else p.sigma_path
        R = np.zeros((n, n))
        R[:2, :2] = sig**2 * np.eye(2)
        if n == 4:
            R[2:, 2:] = (U**2 if near else 0.0) * np.eye(2)
        return R

    def _plan_measure(self, t: float, z: np.ndarray, R: np.ndarray) -> None:
        if self.plan is None:
            return
        if self.departed or not np.isfinite(self.x).all():
            self._try_acquire(t)
            return
        x0, P0 = self._predict(t)
        n = len(z)
        R = R + self._model_noise(x0[0], t, n)
        x = x0.copy()
        for _ in range(3):  # iterated EKF: re-linearise at the updated along-track position
            h, H = self._h(x, t, n)
            S = H @ P0 @ H.T + R
            K = np.linalg.solve(S, H @ P0).T
            nu = z - h - H @ (x0 - x)
            x = x0 + K @ nu
        h0, H0 = self._h(x0, t, n)
        S0 = H0 @ P0 @ H0.T + R
        nu0 = z - h0
        self.nis = float(nu0 @ np.linalg.solve(S0, nu0))
        if self.nis > _chi2_ppf(self.params.gate_prob, n):
            self.misses += 1
            self.on_plan = False
            if self.misses >= self.params.n_miss:
                self.departed = True
                self.departures.append(t)
                self.hits = 0
            return
        IKH = np.eye(4) - K @ H
        self.x, self.P, self.t = x, IKH @ P0 @ IKH.T + K @ R @ K.T, t
        self.P = 0.5 * (self.P + self.P.T)
        self.misses, self.on_plan = 0, True

    def _try_acquire(self, t: float) -> None:
        """Re-anchor on the plan when the Kalman estimate lies on the path and moves along it."""
        p = self.params
        est = self.kf.estimate(t)
        if not math.isfinite(est.N):
            return
        s, d = self.path.project(est.position)
        _, T = self.path.point(s)
        # d is the distance across the path: its 1-D variance, with the path model's error
        # (at or beyond the path's ends, where d is to the end point, the largest, 2-D)
        C = np.reshape(est.cov, (2, 2))
        inside = np.any(T) and 0.0 < s < self.path.length  # else d is to an end: 2-D
        n, dof = (np.array([-T[1], T[0]]), 1) if inside else (None, 2)
        var = float(n @ C @ n) if n is not None else est.sigma**2
        sig = math.sqrt(max(var, 0.0) + (self.plan.acceptance + p.sigma_path) ** 2)
        v = np.array([est.v_N, est.v_E])
        u_p = self.plan.speed_at(t)
        along = float(v @ T) if np.any(T) else 0.0
        across = T[0] * v[1] - T[1] * v[0]
        vel_ok = abs(along - u_p) < 0.5 * max(u_p, 0.5) and abs(across) < 0.5 * max(u_p, 0.5)
        if d < math.sqrt(_chi2_ppf(p.gate_prob, dof)) * sig and vel_ok:
            self.hits += 1
        else:
            self.hits = 0
        if self.hits >= p.n_hit:
            xi, _ = self.path.point(s)
            self.x = np.array([s, 0.0, est.N - xi[0], est.E - xi[1]])
            self.P = np.zeros((4, 4))
            self.P[0, 0], self.P[1, 1] = p.sigma_s0**2, p.sigma_u0**2
            self.P[2:, 2:] = np.reshape(est.cov, (2, 2))
            self.t, self.departed, self.on_plan, self.misses = t, False, True, 0

    # -- output ---------------------------------------------------------------------------

    def plan_estimate(self, t: float) -> AUVEstimate:
        """The plan hypothesis's belief at ``t`` (whatever :attr:`mode` is)."""
        x, P = self._predict(t)
        h, H = self._h(x, t, 4)
        C = H @ P @ H.T
        return AUVEstimate(
            float(h[0]), float(h[1]), float(self.kf.depth), float(h[2]), float(h[3]),
            (float(C[0, 0]), float(C[0, 1]), float(C[1, 0]), float(C[1, 1])), self.kf.t_last,
            forecast=functools.partial(self._forecast, self.x.copy(), self.t, t),
        )  # fmt: skip

    def _forecast(self, x0: np.ndarray, t0: float, t: float, dt: np.ndarray) -> np.ndarray:
        """Positions ``(len(dt), 2)`` at ``t + dt`` predicted along the plan (P1-P2) from the
        filter state ``x0`` of time ``t0``: through the plan's turns and surface intervals,
        held at its end (the MPC's AUV prediction)."""
        out = np.empty((len(dt), 2))
        for i, d in enumerate(np.asarray(dt, float)):
            s = x0[0] + self.plan.speed_integral(t0, t + d) + x0[1] * (t + d - t0)
            out[i] = self.path.point(s)[0] + x0[2:4]
        return out

    def estimate(self, t: float) -> AUVEstimate:
        if self.mode == "kalman":
            return self.kf.estimate(t)
        return self.plan_estimate(t)
