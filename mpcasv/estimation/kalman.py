"""A nearly-constant-velocity Kalman filter per AUV, on USBL fixes and acoustic status reports.

State ``x = [N, E, v_N, v_E]`` (m, m/s), horizontal; the depth has its own filter
(:class:`mpcasv.estimation.depth.DepthFilter`: the reports' pressure depths and the fixes'
USBL depths, each weighted by its variance).

Motion model (per horizontal axis, white-noise acceleration of power spectral density ``q``,
m^2/s^3). With ``tau_v = inf`` it is the constant-velocity (CV) model; with a finite
``tau_v`` the velocity is a first-order Gauss-Markov process (integrated Ornstein-Uhlenbeck,
Singer's model without the acceleration state), so that a prediction over a gap much longer
than ``tau_v`` stops at ``v tau_v`` instead of extrapolating a stale velocity for ever:

    p(t + dt) = p + tau (1 - e) v,   v(t + dt) = e v,   e = exp(-dt / tau)        (K1)

    Q_vv = q tau / 2 (1 - e^2)
    Q_pv = q tau^2 / 2 (1 - e)^2                                                 (K2)
    Q_pp = q tau^2 [dt - 2 tau (1 - e) + tau / 2 (1 - e^2)]

which tends to the CV model ``F = [[1, dt], [0, 1]]``,
``Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]`` as ``tau -> inf``.

Measurements:

- USBL fix: ``z = [N, E]`` with the fix's own covariance ``R`` (thesis eq. 2.9's angle error
  on the 3-D line of sight, across it and in elevation, and the range noise, projected to the
  horizontal: :func:`mpcasv.models.acoustics.usbl_error_map`, the simulator's fixes and the
  deploy's covariance of a DUNE fix without an accuracy).
- Status report: the AUV's own navigation estimate ``[N, E]`` with ``R = nav_sigma^2 I``, and
  its velocity over ground ``U [cos psi, sin psi]`` (``psi`` the course, ``U`` the speed over
  ground) with ``R_v = sigma_U^2 I + (U sigma_psi)^2 n n^T``,
  ``n = [-sin psi, cos psi]``: speed noise in every direction plus the first-order effect of
  the course error across the track; never singular, also for an AUV at rest.

Updates use the Joseph form. :meth:`KalmanEstimator.estimate` predicts from the last update
without changing the filter (the prediction is a pure function of the stored state).
"""

from __future__ import annotations

import math

import numpy as np

from mpcasv.config import Flag, NonNeg, Pos, PosOrInf, frozen
from mpcasv.estimation.depth import DepthFilter
from mpcasv.interface import AUVEstimate
from mpcasv.models.acoustics import Fix, Report

__all__ = ["KalmanEstimator", "KalmanParams", "cv_model"]


@frozen
class KalmanParams:
    """Tuning of :class:`KalmanEstimator` (SI units).

    Attributes
    ----------
    q : float
        White-noise acceleration power spectral density per axis (m^2/s^3). The default
        covers an LAUV's turns between 30-s reports (a 90-degree turn at 1.5 m/s changes the
        velocity by 2.1 m/s; ``sqrt(q T) = 0.55`` m/s per axis over T = 30 s).
    tau_v : float
        Velocity correlation time (s); ``inf`` is the constant-velocity model (K1-K2). The
        default makes the stationary velocity variance ``q tau_v / 2`` 3.0 m^2/s^2 per axis
        (1.7 m/s, 1 sigma; an LAUV's top speed of 2 m/s in a random direction would give
        ``U_max^2 / 2`` = 2.0, at ``tau_v`` = 400 s): over a 30-s report interval the
        velocity decays by 4.9 % and the distance run falls 2.5 % short of constant
        velocity, but over a long gap without reports (an AUV at the surface) the prediction
        stops at ``v tau_v`` instead of extrapolating a stale velocity for ever.
    sigma_v0 : float
        1-sigma per axis of the velocity before any report (m/s): the AUV's velocity is
        unknown at start.
    sigma_p0 : float
        Floor on the initial position 1-sigma per axis (m) when the initial estimate has a
        zero covariance.
    sigma_speed : float
        Noise of the reported speed, 1 sigma (m/s): speed through water vs over ground.
    sigma_heading_deg : float
        Noise of the reported heading, 1 sigma (deg): heading vs course over ground.
    report_velocity : bool
        Use the reports' heading and speed (False: position only).
    q_depth : float
        Vertical-acceleration power spectral density of the depth filter (m^2/s^3;
        :class:`~mpcasv.estimation.depth.DepthFilter`): ``sqrt(q T) = 0.12`` m/s over a
        30-s report interval.
    sigma_w0 : float
        1-sigma of the vertical speed before it is measured (m/s): an LAUV's vertical speed
        limit (the domains' ``w_max``).
    sigma_depth : float
        Noise of a report's (pressure sensor) depth, 1 sigma (m).
    """

    q: Pos = 0.01
    tau_v: PosOrInf = 600.0  # inf: the constant-velocity model
    sigma_v0: NonNeg = 1.0
    sigma_p0: NonNeg = 1.0
    sigma_speed: NonNeg = 0.1
    sigma_heading_deg: NonNeg = 5.0
    report_velocity: Flag = True
    q_depth: Pos = 5e-4
    sigma_w0: NonNeg = 0.5
    sigma_depth: Pos = 0.1


def cv_model(dt: float, q: float, tau_v: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
    """Transition ``F`` and process noise ``Q`` (4x4, state ``[N, E, v_N, v_E]``) over ``dt``.

    Equations (K1-K2) of the module docstring; ``dt`` may be negative (a retrodiction: the
    mean runs backwards, the noise grows with ``|dt|``).
    """
    a = abs(dt)
    if math.isinf(tau_v):
        f_pv, f_vv = a, 1.0
        q_pp, q_pv, q_vv = a**3 / 3.0, a * a / 2.0, a
    else:
        tau = tau_v
        e = math.exp(-a / tau)
        one_e = -math.expm1(-a / tau)  # 1 - e, accurate for small dt / tau
        f_pv, f_vv = tau * one_e, e
        q_vv = tau / 2.0 * one_e * (1.0 + e)
        q_pv = tau**2 / 2.0 * one_e**2
        q_pp = tau**2 * (a - 2.0 * tau * one_e + tau / 2.0 * one_e * (1.0 + e))
    F = np.eye(4)
    F[0, 2] = F[1, 3] = f_pv
    F[2, 2] = F[3, 3] = f_vv
    Q1 = q * np.array([[q_pp, q_pv], [q_pv, q_vv]])
    Q = np.kron(Q1, np.eye(2))  # axes independent: [[pp I, pv I], [pv I, vv I]]
    if dt < 0:  # retrodiction: x(t) = F^-1 x(t + |dt|) - F^-1 w, w ~ N(0, Q)
        F = np.linalg.inv(F)
        Q = F @ Q @ F.T  # (the forward noise with its cross term negated only when tau = inf)
    return F, Q


def report_velocity(report: Report, sigma_speed: float, sigma_heading: float):
    """Velocity ``U [cos psi, sin psi]`` of a report and its 2x2 covariance (see module doc)."""
    c, s, U = math.cos(report.psi), math.sin(report.psi), report.speed
    z = np.array([U * c, U * s])
    perp = np.array([-s, c])
    R = sigma_speed**2 * np.eye(2) + (U * sigma_heading) ** 2 * np.outer(perp, perp)
    return z, R


class KalmanEstimator:
    """Nearly-constant-velocity Kalman filter for one AUV (see the module docstring).

    Parameters
    ----------
    initial : AUVEstimate, optional
        Known initial state (position, depth, velocity, covariance, time). Without it the
        filter starts at the first fix or report.
    params : KalmanParams, optional
    """

    name = "kalman"

    def __init__(self, initial: AUVEstimate | None = None, params: KalmanParams | None = None):
        self.params = params or KalmanParams()
        self.x = np.full(4, math.nan)
        self.P = np.full((4, 4), math.nan)
        self.t = math.nan  # time of x, P
        p = self.params
        self.depth_filter = DepthFilter(p.q_depth, p.sigma_w0, p.sigma_depth)
        self.t_last = -math.inf  # time of the last measurement
        self.nis: float = math.nan  # normalised innovation squared of the last update
        self.n_updates = 0
        if initial is not None and math.isfinite(initial.N) and math.isfinite(initial.E):
            self.x = np.array([initial.N, initial.E, initial.v_N, initial.v_E], float)
            self.P = np.zeros((4, 4))
            self.P[:2, :2] = np.reshape(initial.cov, (2, 2))
            self.P[:2, :2] += p.sigma_p0**2 * np.eye(2) * (np.trace(self.P[:2, :2]) == 0)
            self.P[2:, 2:] = p.sigma_v0**2 * np.eye(2)
            self.t = initial.t_last_fix if math.isfinite(initial.t_last_fix) else 0.0
            self.t_last = initial.t_last_fix
        if initial is not None and math.isfinite(initial.depth):  # known: as a report's
            t0 = initial.t_last_fix if math.isfinite(initial.t_last_fix) else 0.0
            self.depth_filter.start(t0, initial.depth, p.sigma_depth**2)

    @property
    def depth(self) -> float:
        """The depth estimate (m; NaN before any depth)."""
        return self.depth_filter.depth

    @property
    def initialised(self) -> bool:
        return bool(np.isfinite(self.x).all())

    # -- events ---------------------------------------------------------------------------

    def on_truth(self, t, N, E, depth, v_N, v_E) -> None:
        pass

    def on_fix(self, fix: Fix) -> None:
        R = np.reshape(fix.cov, (2, 2))
        self._measure(fix.t, np.array([fix.N, fix.E]), R, velocity=False)
        self.depth_filter.measure(fix.t, fix.depth, fix.depth_var)

    def on_report(self, report: Report) -> None:
        p = self.params
        z, R = np.array([report.N, report.E]), report.nav_sigma**2 * np.eye(2)
        if p.report_velocity:
            zv, Rv = report_velocity(report, p.sigma_speed, math.radians(p.sigma_heading_deg))
            z = np.concatenate([z, zv])
            R = np.block([[R, np.zeros((2, 2))], [np.zeros((2, 2)), Rv]])
        self._measure(report.t, z, R, velocity=p.report_velocity)
        self.depth_filter.report(report.t, report.depth)

    # -- filter ---------------------------------------------------------------------------

    def predict(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Predicted ``(x, P)`` at time ``t`` (pure: the filter is not changed)."""
        if not self.initialised:
            return self.x.copy(), self.P.copy()
        F, Q = cv_model(t - self.t, self.params.q, self.params.tau_v)
        return F @ self.x, F @ self.P @ F.T + Q

    def innovation(self, t: float, z: np.ndarray, R: np.ndarray):
        """Innovation ``nu``, its covariance ``S`` and ``H`` for a measurement at ``t``
        (position, or position and velocity when ``len(z) == 4``)."""
        x, P = self.predict(t)
        H = np.eye(4)[: len(z)]
        return z - H @ x, H @ P @ H.T + R, H, x, P

    def _measure(self, t: float, z: np.ndarray, R: np.ndarray, velocity: bool):
        if not self.initialised:
            self._start(t, z, R)
        else:
            nu, S, H, x, P = self.innovation(t, z, R)
            K = np.linalg.solve(S, H @ P).T  # P H^T S^-1 (S, P symmetric)
            IKH = np.eye(4) - K @ H
            self.x = x + K @ nu
            self.P = IKH @ P @ IKH.T + K @ R @ K.T  # Joseph form
            self.P = 0.5 * (self.P + self.P.T)
            self.nis = float(nu @ np.linalg.solve(S, nu))
        self.t = t
        self.t_last = max(self.t_last, t)
        self.n_updates += 1

    def _start(self, t: float, z: np.ndarray, R: np.ndarray) -> None:
        """First measurement without a prior: position from it, velocity from it or unknown."""
        self.x = np.zeros(4)
        self.P = self.params.sigma_v0**2 * np.eye(4)
        n = len(z)
        self.x[:n] = z
        self.P[:n, :n] = R
        self.nis = math.nan

    def estimate(self, t: float) -> AUVEstimate:
        if not self.initialised:
            return AUVEstimate(math.nan, math.nan, self.depth)
        x, P = self.predict(t)
        cov = (float(P[0, 0]), float(P[0, 1]), float(P[1, 0]), float(P[1, 1]))
        return AUVEstimate(
            float(x[0]), float(x[1]), float(self.depth), float(x[2]), float(x[3]), cov,
            self.t_last,
        )  # fmt: skip
