"""An AUV's depth from its status reports and the USBL fixes: a two-state Kalman filter.

State ``[d, w]``: depth (m, down) and vertical speed (m/s), white-noise vertical acceleration
of power spectral density ``q`` (the constant-velocity model, :func:`cv_model`'s one axis):

    F = [[1, dt], [0, 1]],   Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]                    (D1)

Measurements (scalar, inverse-variance weighted by the Kalman gain):

- a status report's depth, from the AUV's pressure sensor: variance ``sigma_report^2``
  (0.1 m: the 1-sigma of a pressure depth);
- a USBL fix's depth, the 3-D fix's vertical part: its own variance
  (:attr:`mpcasv.models.acoustics.Fix.depth_var`, ``J[2] @ J[2]`` of
  :func:`~mpcasv.models.acoustics.usbl_error_map`: ``sigma_b r_h``, 1.7 m at 100 m, 7 m at
  400 m). A fix without one (NaN) starts the filter and is otherwise not used.

Between reports the prior's depth variance grows as ``q dt^3 / 3`` plus ``P_ww dt^2``: the
vertical speed's uncertainty times the age (before a second measurement ``sigma_w0``, the
AUV's vertical speed limit). A steady AUV's reports (every 30 s, 0.1 m) then hold the depth,
and a fix 7 m off moves it by centimetres; an AUV that climbs is followed from its reports'
depth change (its vertical speed after two reports) and the fixes in between.

The estimate handed out is the posterior depth at the last measurement, held (as before:
the anti-collision domains account for how far the AUV may have moved since, ``w_max tau``),
not above the surface. The MPC's vertical speed (``mpcasv/mpc/worldview.py``) differences
these held depths, so it is that of the filter's output, not of raw fix depths (session 49:
with the fix depths copied in, a steady AUV at 28 m gave a 60-s depth forecast spread, p5-p95,
of 0-157 m at 400 m range).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DepthFilter"]


class DepthFilter:
    """Two-state (depth, vertical speed) Kalman filter of one AUV's depth (module docstring).

    Parameters
    ----------
    q : float
        Vertical-acceleration power spectral density (m^2/s^3).
    sigma_w0 : float
        1-sigma of the vertical speed before it is measured (m/s): the AUV's vertical speed
        limit.
    sigma_report : float
        1-sigma of a report's (pressure) depth (m).
    """

    def __init__(self, q: float = 5e-4, sigma_w0: float = 0.5, sigma_report: float = 0.1):
        self.q, self.sigma_w0, self.sigma_report = float(q), float(sigma_w0), float(sigma_report)
        self.x = np.full(2, math.nan)
        self.P = np.full((2, 2), math.nan)
        self.t = math.nan

    @property
    def depth(self) -> float:
        """The held depth estimate (m, not above the surface; NaN before any measurement)."""
        return max(float(self.x[0]), 0.0) if math.isfinite(self.x[0]) else math.nan

    @property
    def rate(self) -> float:
        """The vertical speed estimate (m/s, positive down; NaN before any measurement)."""
        return float(self.x[1])

    def start(self, t: float, depth: float, var: float) -> None:
        """Start at ``depth`` (m) with variance ``var`` (m^2) at ``t``, vertical speed 0."""
        self.x = np.array([float(depth), 0.0])
        self.P = np.diag([float(var), self.sigma_w0**2])
        self.t = float(t)

    def report(self, t: float, depth: float) -> None:
        """A status report's depth (pressure sensor) measured at ``t``."""
        self.measure(t, depth, self.sigma_report**2)

    def measure(self, t: float, depth: float, var: float) -> None:
        """A depth ``depth`` (m) of variance ``var`` (m^2) measured at ``t`` (s); a NaN
        ``var`` (no stated accuracy) only starts the filter. A measurement older than the
        filter's time is taken at the filter's time (the in-order wrapper puts late ones in
        their place)."""
        if not math.isfinite(depth):
            return
        if not math.isfinite(self.x[0]):
            self.start(t, depth, var if math.isfinite(var) else self.sigma_report**2)
            return
        if not math.isfinite(var):
            return
        dt = max(t - self.t, 0.0)
        F = np.array([[1.0, dt], [0.0, 1.0]])
        Q = self.q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        x, P = F @ self.x, F @ self.P @ F.T + Q
        S = P[0, 0] + var
        K = P[:, 0] / S
        self.x = x + K * (depth - x[0])
        IKH = np.eye(2) - np.outer(K, [1.0, 0.0])
        self.P = IKH @ P @ IKH.T + var * np.outer(K, K)  # Joseph form
        self.t = max(self.t, float(t))
