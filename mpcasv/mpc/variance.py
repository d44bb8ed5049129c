"""The navigation-variance objective of the MPC (opt-in: ``objective = "variance"``; issue 16
item 3; docs/mpc.md "Objective: navigation uncertainty"). A mixin of
:class:`~mpcasv.mpc.problem.OCP`, ported from the session-4 branch ``mpcorder``.

With ``objective = "variance"`` the problem is a different compiled one (more parameters,
other terms); the default problem (``objective = "age"``) is built exactly as before. Its
additions, with ``V(tau) = eps_a^2 / 8 tau^4`` an AUV's dead-reckoning variance per axis
(m^2; :func:`~mpcasv.models.auv_nav.dr_variance`, thesis eq. 2.7):

- (M2') a fix lowers the expected fix age in proportion to the share of the AUV's variance it
  removes at its slant range: ``dtau/dt = 1 - eta(tau, slant) rho tau`` with
  ``eta = 1 - P+ / V`` (:func:`fix_gain`; ``P+`` the AUV filter's posterior for the USBL's
  variances at that range, thesis eq. 2.9). ``tau`` becomes an *equivalent* fix age;
- (M4n) stage cost ``nav / V_ref * sum_i V(tau_i)`` (``V_ref = V(tau_ref)``);
- (M4d) stage cost ``near`` per s within ``NEAR_BUFFER`` of an AUV's anti-collision bound;
- (M7c) terminal cost: the AUVs' variance over a tail of ``Theta = weights.tail`` s past the
  horizon, the ASV *waiting* where the plan ends (``N_TAIL`` segments along each AUV's
  forecast), and for the target AUV the soft minimum of waiting and *going* (transit at
  ``U_go`` to where it meets the AUV's target circle, ``e_go`` per s, then waiting there).

The parameters these need follow the default problem's, in one block (:data:`EXT_NAMES`, then
per AUV the tail's forecast positions (2 N_TAIL), depths (N_TAIL) and meeting point (2)).
"""

from __future__ import annotations

import dataclasses
import math

import casadi as ca
import numpy as np

from mpcasv.models.auv_nav import (
    dr_variance,
    dr_variance_integral,
    fix_posterior_variance,
    fix_variance,
)
from mpcasv.models.vessel import NX as NXV
from mpcasv.mpc.order import transit_cost
from mpcasv.mpc.smooth import D_EPS, SOFT_T, SOFTPLUS_M, sigmoid, softplus

#: the tail (M7c) is valued at this many segments of the tail window
N_TAIL = 4
NEAR_BUFFER = 10.0  # m beyond the plan's anti-collision bound that count as "near" (M4d)
NEAR_W = 3.0  # m, width of that sigmoid
N_SUB_TAIL = 3  # implicit steps of M2' per tail segment
SOFTMIN_REL = 0.02  # temperature of the wait/go soft minimum, relative to the costs (M7c)
#: the block's scalars, in this order: the USBL's range noise (m) and bearing error (rad), the
#: AUVs' accelerometer error (m/s^2), the weights nav (per V_ref, per s), near (per s), e_go
EXT_NAMES = ("sigma_range", "sigma_bearing", "eps_a", "nav", "near", "e_go")
NEXT = len(EXT_NAMES)
N_NAV = 3  # the first three enter the dynamics (M2')


def n_ext(n_auv: int) -> int:
    """Length of the variance objective's parameter block for ``n_auv`` AUVs."""
    return NEXT + n_auv * (3 * N_TAIL + 2)


def fix_gain(tau, slant, sigma_range, sigma_bearing, eps_a):
    """Expected fraction of an AUV's navigation variance a fix at slant range ``slant`` (m)
    removes at (equivalent) fix age ``tau`` (s; eq. M2'): ``eta = 1 - P+ / V`` with
    ``V = eps_a^2 / 8 tau^4`` (N2) and ``P+`` the filter's posterior (N3) for the USBL's
    variances at that range (``sigma_range`` m, ``sigma_bearing`` rad; :mod:`mpcasv.models.
    auv_nav`). Near 1 when the dead-reckoning variance dwarfs the fix's, small for a far fix
    of a fresh AUV. Floats, numpy arrays (broadcast) or CasADi expressions."""
    V = dr_variance(eps_a, tau) + 1e-12
    R_los, R_perp = fix_variance(slant, sigma_range, sigma_bearing)
    return 1.0 - fix_posterior_variance(V, R_los, R_perp) / V


class VarianceObjective:
    """The terms of ``objective = "variance"`` (mixin of the OCP; state there)."""

    def ext_vector(self, acoustics, tail_pa, tail_depth, meet,
                   U_go: float | None = None) -> np.ndarray:  # fmt: skip
        """The block's numbers (shape ``(n_ext(K),)``): the run's USBL noise (``acoustics``,
        :class:`~mpcasv.models.acoustics.AcousticParams`), the preset's ``eps_a`` and
        weights, and per AUV the tail's forecast positions ``tail_pa`` (K, N_TAIL, 2; m),
        depths ``tail_depth`` (K, N_TAIL; m) and meeting points ``meet`` (K, 2; m); the
        transit cost ``e_go`` at ``U_go`` (m/s; None: the weights', else a speed cap's)."""
        P, vp = self.params, self.vessel
        wt, eps_a = P.weights, P.navigation.eps_a
        if U_go is not None and U_go != wt.U_go:
            wt = dataclasses.replace(wt, U_go=U_go)
        e_go = transit_cost(wt, self.model.thrust_for_speed(wt.U_go), vp.T_max, vp.u_max)
        head = [acoustics.sigma_range, math.radians(acoustics.sigma_bearing_deg), eps_a,
                P.variance.nav / dr_variance(eps_a, wt.tau_ref), P.variance.near,
                e_go]  # fmt: skip
        K = self.dims.n_auv
        tail = np.concatenate([np.asarray(tail_pa, float).reshape(K, 2 * N_TAIL),
                               np.asarray(tail_depth, float).reshape(K, N_TAIL),
                               np.asarray(meet, float).reshape(K, 2)], axis=1)  # fmt: skip
        return np.concatenate([np.array(head, float), tail.ravel()])

    def _variance_stage(self, z, sp, ext):
        """Stage cost M4n + M4d (per s) at one stage."""
        K = self.dims.n_auv
        eps_a, w_nav, w_near = ext[2], ext[3], ext[4]
        L = w_nav * ca.sum1(dr_variance(eps_a, z[NXV : NXV + K]))  # (M4n)
        r_lo = sp[2 * K : 3 * K]  # (M4d) near the anti-collision bound
        L += w_near * sum(sigmoid((r_lo[i] + NEAR_BUFFER - di) / NEAR_W)
                          for i, di in enumerate(self._dist(z, sp)))  # fmt: skip
        return L

    @staticmethod
    def _relax(tau, k, h):
        """Expected (equivalent) fix age after ``h`` s at fix rate ``k`` from ``tau``: one
        implicit Euler step of M2 (exact in both limits: ``tau + h`` without fixes, ``1 / k``
        for ``k h`` large; never divides by zero)."""
        return (tau + h) / (1 + k * h)

    def _segment(self, tau, rho, slant, h, nav):
        """(variance-time over a tail segment of ``h`` s (m^2 s), age at its end) for an AUV
        at slant range ``slant`` with fix rate ``rho`` (M3): ``N_SUB_TAIL`` implicit steps of
        M2', the gain re-evaluated at each; Simpson's rule on ``V(tau)`` in each (exact for
        the quartic growing without fixes). ``nav``: the block's first ``N_NAV`` entries."""
        eps_a = nav[2]
        hs, total = h / N_SUB_TAIL, 0
        for _ in range(N_SUB_TAIL):
            k = rho * fix_gain(tau, slant, *nav)
            mid, end = self._relax(tau, k, hs / 2), self._relax(tau, k, hs)
            total += hs / 6 * (dr_variance(eps_a, tau) + 4 * dr_variance(eps_a, mid)
                               + dr_variance(eps_a, end))  # fmt: skip
            tau = end
        return total, tau

    def _tail_cost(self, z, r_t, d_fix, target, ch, W, ext):
        """Terminal cost M7c (module docstring): every AUV's variance over the tail with the
        ASV waiting; for the target (one-hot ``target``) the soft minimum of waiting and
        going. ``r_t``, ``d_fix`` (K,): target radii and reliable-fix ranges (m)."""
        K, M = self.dims.n_auv, N_TAIL
        nav = [ext[j] for j in range(N_NAV)]
        eps_a, w_nav, e_go = ext[2], ext[3], ext[5]
        Theta = W["tail"]
        h = Theta / M
        total = 0
        for i in range(K):
            b = ext[NEXT + i * (3 * M + 2) : NEXT + (i + 1) * (3 * M + 2)]
            tau, wait = z[NXV + i], 0
            for m in range(M):
                dh = ca.sqrt((z[0] - b[2 * m]) ** 2 + (z[1] - b[2 * m + 1]) ** 2 + D_EPS**2)
                dep = b[2 * M + m]
                rho = self.fix_rate(dh, dep, d_fix[i], 0.0, ch)
                cost, tau = self._segment(tau, rho, ca.sqrt(dh**2 + dep**2), h, nav)
                wait += cost
            # go: transit to the meeting point, then wait on the target circle
            meet = b[3 * M : 3 * M + 2]
            dm = ca.sqrt((z[0] - meet[0]) ** 2 + (z[1] - meet[1]) ** 2 + D_EPS**2)
            t_go = SOFTPLUS_M * softplus((dm - r_t[i]) / SOFTPLUS_M) * W["inv_U_go"]
            tau0 = z[NXV + i]
            go = dr_variance_integral(eps_a, tau0, tau0 + t_go)
            rest = SOFT_T * softplus((Theta - t_go) / SOFT_T)
            dep = b[2 * M + M // 2]
            rho = self.fix_rate(r_t[i], dep, d_fix[i], 0.0, ch)
            cost, _ = self._segment(tau0 + t_go, rho, ca.sqrt(r_t[i] ** 2 + dep**2), rest, nav)
            a_wait = w_nav * wait
            a_go = w_nav * (go + cost) + e_go * t_go
            kappa = SOFTMIN_REL * (a_wait + a_go) + 1e-3
            lo = ca.fmin(a_wait, a_go)
            soft = lo - kappa * ca.log(ca.exp(-(a_wait - lo) / kappa)
                                       + ca.exp(-(a_go - lo) / kappa))  # fmt: skip
            total += target[i] * soft + (1 - target[i]) * a_wait
        return total
