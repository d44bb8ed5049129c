"""Each AUV's own navigation filter: dead reckoning between aiding fixes, a Kalman update with
every USBL fix that reaches the AUV and with GPS at the surface.

A real AUV without DVL dead-reckons on its INS and is aided by the USBL fixes the ASV sends
it; the quantity the ASV exists to bound is that filter's error. The simulator knows the
truth, so it runs the filter on the *error* ``e = p_hat - p`` (horizontal, per AUV):

- Dead reckoning (thesis §2.5 eq. 2.7, PAPER-FACTS §1, ``dp = 1/2 eps_a t^2``): between two
  aiding updates the error grows from its value ``e_u`` right after the last update ``t_u``
  by a constant accelerometer error ``a`` and an optional drift per distance travelled::

      e(t) = e_u + 1/2 a (t - t_u)^2 + c s(t) n,   a ~ N(0, eps_a^2 / 2 I_2)           (N1)

  (``|a|`` has RMS ``eps_a``; ``s`` is the distance travelled since ``t_u``, ``c`` the
  ``drift_per_distance`` fraction, ``n`` a random unit vector). The quadratic law restarts at
  each update, as the thesis's ``T_max = sqrt(2 dp_max / eps_a)`` reasoning assumes (the
  INS is realigned at each fix); ``a`` and ``n`` are drawn anew then.
- The filter's covariance follows the same model::

      P(t) = P_u + (eps_a^2 / 8 (t - t_u)^4 + (c s)^2 / 2) I_2                         (N2)

  so without aiding the RMS error (and the filter's own 1-sigma radius) is ``1/2 eps_a t^2``.
- Aiding by a position measurement ``z = p + v``, ``v ~ N(0, R)``: Kalman gain
  ``K = P (P + R)^-1``, ``p_hat+ = p_hat + K (z - p_hat)``, that is::

      e+ = (I - K) e + K v,   P+ = (I - K) P (I - K)^T + K R K^T   (Joseph form)       (N3)

  ``R`` of a USBL fix is the fix's own covariance (range noise along the 3-D line of sight,
  bearing error x slant range across it and in elevation, thesis eq. 2.9 ``dd = dbeta r``,
  projected to the horizontal; see :func:`mpcasv.models.acoustics.usbl_fix`): a far fix has
  a large ``R`` and moves the estimate less than a near one. GPS at the surface:
  ``R = gps_sigma^2 / 2 I_2``.

How a USBL fix reaches the AUV is the simulator's business (:class:`mpcasv.sim.world.World`
sends it back over the acoustic link with the channel's success probability). Every random
draw is handed in (the simulator's synchronised streams, :mod:`mpcasv.sim.streams`).
"""

from __future__ import annotations

import math

import numpy as np

from mpcasv.models.acoustics import NavParams

__all__ = ["AUVNavFilter", "dr_variance", "dr_variance_integral", "fix_variance",
           "fix_posterior_variance"]


# The filter's laws as pure functions of floats, numpy arrays or CasADi expressions (the MPC's
# visiting order values them: mpcasv/mpc/order.py, docs/mpc.md "Visiting order").
def dr_variance(eps_a, t):
    """Dead-reckoning variance per axis (m^2) ``t`` s after an update (N2, thesis eq. 2.7):
    ``eps_a^2 / 8 t^4`` (``eps_a`` in m/s^2), so that the 1-sigma radius is ``1/2 eps_a t^2``.
    Same shape as ``t``."""
    return eps_a**2 / 8.0 * t**4


def dr_variance_integral(eps_a, t0, t1):
    """``integral of dr_variance(eps_a, s) ds`` from ``t0`` to ``t1`` (s; m^2 s):
    ``eps_a^2 / 40 (t1^5 - t0^5)``."""
    return eps_a**2 / 40.0 * (t1**5 - t0**5)


def fix_variance(slant, sigma_range, sigma_bearing):
    """Variances (m^2) of a USBL fix at slant range ``slant`` (m) along and across the line
    of sight: ``(sigma_range^2, (sigma_bearing slant)^2)`` (``sigma_range`` in m,
    ``sigma_bearing`` in rad; thesis eq. 2.9). That is the covariance
    :func:`mpcasv.models.acoustics.usbl_fix` hands the filter for an AUV at the surface; at
    depth ``d`` the along-line variance there is ``(sigma_range r_h / slant)^2 +
    (sigma_bearing d)^2`` (the elevation error, U2), which the opt-in planning models using
    this (``mpc/order.py``, ``mpc/variance.py``) leave out (session 49: at r_h 60 m, d 28 m,
    0.45 against 0.25 m^2)."""
    return sigma_range**2, (sigma_bearing * slant) ** 2


def fix_posterior_variance(P, R_los, R_perp):
    """Mean per-axis variance (m^2) of the filter after a fix (N3, the Kalman update of
    :meth:`AUVNavFilter.update`) from an isotropic prior ``P`` per axis (m^2) and a fix with
    variances ``R_los`` along and ``R_perp`` across the line of sight (m^2): each axis
    ``P R / (P + R)``. Exact for an isotropic prior (the dead-reckoning growth N2 is)."""
    return 0.5 * (P * R_los / (P + R_los) + P * R_perp / (P + R_perp))


class AUVNavFilter:
    """The navigation filters of ``n_auv`` AUVs, on their errors against the truth.

    Parameters
    ----------
    n_auv : int
    p : NavParams
        ``eps_a`` (m/s^2, RMS accelerometer error) and ``drift_per_distance`` (fraction).
    ins0 : array_like, shape (n_auv, 3)
        Each AUV's first dead-reckoning interval's draws: two standard normals (the
        accelerometer error, N1) and a uniform in [0, 1) (the drift's direction). Every
        interval's draws come from the caller (:meth:`update`'s ``ins``; the simulator's
        synchronised streams, :mod:`mpcasv.sim.streams`).

    Every AUV starts with a known position (``e = 0``, ``P = 0``) at ``t = 0``.
    """

    def __init__(self, n_auv: int, p: NavParams, ins0):
        self.p = p
        self.e_u = np.zeros((n_auv, 2))  # error right after the last update, m
        self.P_u = np.zeros((n_auv, 2, 2))  # its covariance, m^2
        self.lam_u = np.zeros(n_auv)  # largest eigenvalue of P_u, m^2
        self.a = np.zeros((n_auv, 2))  # accelerometer error of this DR interval, m/s^2
        self.dirn = np.zeros((n_auv, 2))  # direction of the distance-proportional drift
        self.t_u = np.zeros(n_auv)  # time of the last update, s
        self.dist = np.zeros(n_auv)  # distance travelled since, m
        ins0 = np.asarray(ins0, float).reshape(n_auv, 3)
        for k in range(n_auv):
            self._new_interval(k, 0.0, ins0[k])

    def _new_interval(self, k: int, t: float, ins) -> None:
        self.a[k] = self.p.eps_a * np.asarray(ins[:2], float) / math.sqrt(2)  # (N1)
        ang = 2.0 * math.pi * float(ins[2])
        self.dirn[k] = (math.cos(ang), math.sin(ang))
        self.t_u[k], self.dist[k] = t, 0.0

    def advance(self, distance: np.ndarray) -> None:
        """Add the distance (m, shape (n_auv,)) each AUV travelled since the last call."""
        self.dist += distance

    def error(self, t: float) -> np.ndarray:
        """Navigation errors ``p_hat - p`` at time ``t`` (s): shape (n_auv, 2), m (N1)."""
        dt = (t - self.t_u)[:, None]
        drift = self.p.drift_per_distance * self.dist[:, None] * self.dirn
        return self.e_u + 0.5 * self.a * dt**2 + drift

    def _grow(self, t: float) -> np.ndarray:
        """Variance per axis added since each AUV's last update (m^2, shape (n_auv,)), N2."""
        dt = t - self.t_u
        return dr_variance(self.p.eps_a, dt) + 0.5 * (self.p.drift_per_distance * self.dist) ** 2

    def cov(self, t: float) -> np.ndarray:
        """The filters' covariances at time ``t``: shape (n_auv, 2, 2), m^2 (N2)."""
        return self.P_u + self._grow(t)[:, None, None] * np.eye(2)

    def sigma(self, t: float) -> np.ndarray:
        """Each filter's own 1-sigma error radius (m, shape (n_auv,)): sqrt of the largest
        eigenvalue of :meth:`cov` (that of ``P_u`` plus the isotropic growth)."""
        return np.sqrt(self.lam_u + self._grow(t))

    def update(self, k: int, t: float, v: np.ndarray, R: np.ndarray, ins) -> np.ndarray:
        """Aid AUV ``k`` at time ``t`` with a position measurement whose error is ``v``.

        Parameters
        ----------
        k : int
        t : float
            Time of the measurement (s); the filter is predicted to it first.
        v : array_like, shape (2,)
            Measurement error ``z - p`` (m): the USBL fix's or the GPS's error.
        R : array_like, shape (2, 2)
            Its covariance (m^2), as the AUV is told it.
        ins : array_like, shape (3,)
            The next dead-reckoning interval's draws (as ``ins0`` in the constructor).

        Returns
        -------
        ndarray, shape (2,)
            How far the estimate moved, ``K (z - p_hat)`` (m).
        """
        dt = t - self.t_u[k]
        c = self.p.drift_per_distance * self.dist[k]
        e = self.e_u[k] + 0.5 * self.a[k] * dt**2 + c * self.dirn[k]  # (N1)
        g = dr_variance(self.p.eps_a, dt) + 0.5 * c * c  # (N2)
        (p00, p01), (_, p11) = self.P_u[k]
        p00, p11 = p00 + g, p11 + g
        (r00, r01), (_, r11) = np.asarray(R, float).reshape(2, 2)
        s00, s01, s11 = p00 + r00, p01 + r01, p11 + r11
        det = s00 * s11 - s01 * s01
        if det <= 0.0:  # both exact: nothing to fuse (only at t = 0)
            k00 = k01 = k10 = k11 = 0.0
        else:  # K = P S^-1 (2x2, symmetric P and S)
            i00, i01, i11 = s11 / det, -s01 / det, s00 / det
            k00, k01 = p00 * i00 + p01 * i01, p00 * i01 + p01 * i11
            k10, k11 = p01 * i00 + p11 * i01, p01 * i01 + p11 * i11
        y0, y1 = float(v[0]) - e[0], float(v[1]) - e[1]
        move = np.array([k00 * y0 + k01 * y1, k10 * y0 + k11 * y1])
        self.e_u[k] = e + move  # (N3): e+ = (I - K) e + K v
        a, b, d = _joseph(((1.0 - k00, -k01), (-k10, 1.0 - k11)), (p00, p01, p11),
                          ((k00, k01), (k10, k11)), (r00, r01, r11))  # fmt: skip
        self.P_u[k] = ((a, b), (b, d))
        self.lam_u[k] = max(0.5 * (a + d) + math.sqrt(0.25 * (a - d) ** 2 + b * b), 0.0)
        self._new_interval(k, t, ins)
        return move


def _sandwich(A, S) -> tuple[float, float, float]:
    """``A S A^T`` for a 2x2 ``A`` and a symmetric ``S = (s00, s01, s11)``: (00, 01, 11)."""
    (a, b), (c, d) = A
    s00, s01, s11 = S
    u00, u01 = a * s00 + b * s01, a * s01 + b * s11  # row 0 of A S
    u10, u11 = c * s00 + d * s01, c * s01 + d * s11  # row 1
    return u00 * a + u01 * b, u00 * c + u01 * d, u10 * c + u11 * d


def _joseph(IK, P, K, R) -> tuple[float, float, float]:
    """Joseph-form posterior ``(I - K) P (I - K)^T + K R K^T`` as (00, 01, 11) (2x2, in
    floats: this runs every period for every AUV at the surface)."""
    a, b, c = _sandwich(IK, P)
    x, y, z = _sandwich(K, R)
    return a + x, b + y, c + z
