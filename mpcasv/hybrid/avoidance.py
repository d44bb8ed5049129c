"""Uncertainty-aware and reachable-set anti-collision domains (issue 8; thesis further work:
"less conservative anti-collision domains"). They replace the papers' isotropic sphere
``r_avoid = alpha T0 rdot_max`` of :mod:`mpcasv.hybrid.domains` (the one definition of the
papers' geometry) where a preset asks for them (``AvoidanceParams.kind``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mpcasv.config import NonNeg, Pos, PosInt, frozen
from mpcasv.hybrid.domains import (
    DomainParams,
    _surface_radius,
    r_avoid,
    range_bearing,
)

__all__ = [
    "AvoidanceParams",
    "AvoidanceShape",
    "avoidance_radii",
    "avoidance_shape",
    "estimate_shape",
    "r_avoid_uncertain",
    "reach_support",
]


# --- uncertainty-aware anti-collision domains (issue 8) ----------------------------------------
#
# The papers' anti-collision sphere r_avoid = alpha T0 rdot_max is isotropic and ignores what
# the ASV knows. Two options beside it, both built from one AvoidanceParams:
#
# (U) "uncertainty": the surface disc of a keep-out sphere of radius r_keep around every AUV
#     position the ASV cannot exclude. The AUV is within rho_h = k_sigma sigma + u_age tau of
#     the estimate (sigma: the estimate's largest 1-sigma; tau = t - t_last_fix; u_age: the
#     speed at which the AUV can move away from the belief's mean: its top speed for a
#     stationary estimate, 0 for a predicting estimator whose covariance already grows) and
#     no deeper than d_eff = max(d - w_max tau, 0) below the surface (depth is held between
#     measurements). The union of the surface discs is the disc
#         r_U = sqrt(r_keep^2 - d_eff^2) + rho_h   if d_eff < r_keep, else 0 (empty).     (U1)
# (R) "reachable": (U) swept over the set of positions the AUV can reach within T_reach from
#     its estimated state (speed U <= U_max, |dU/dt| <= a_max, |dpsi/dt| <= r_max), further
#     ahead than behind. Its support function in a direction at angle theta from the heading
#     (heading known within dpsi, speed <= U0 = |v| + U_margin) is bounded by
#         h(theta) = int_0^T min(U_max, U0 + a_max t) max(cos(max(phi - r_max t, 0)), 0) dt,
#         phi = max(|theta| - dpsi, 0)                                                  (R1)
#     (the velocity component along the direction is at most U(t) cos of the smallest heading
#     offset reachable by then; the integrand is non-decreasing in t, so a right Riemann sum
#     shifted by one step bounds the integral and any explicit-Euler discretisation with a
#     step <= T / n_time). The domain is the polygon {x: n_j.(x - c) <= h_j + r_U} with
#     n_facets outward normals n_j (a superset of the reach set (+) the disc).
#
# Signed distance. For a convex set K given by support values, sd(q) = max_j n_j.(q - c) - h_j
# is the exact signed distance inside and a lower bound outside (conservative); minus r_U for
# the disc.


@frozen
class AvoidanceParams:
    """Which anti-collision domain a controller uses, and its parameters (SI units).

    Attributes
    ----------
    kind : {"fixed", "uncertainty", "reachable"}
        ``fixed``: the papers' ``r_avoid,i`` (Paper 2 eq. 5 / Paper 1's ``r_inner``), nothing
        else used. ``uncertainty``: the disc (U1). ``reachable``: the polygon (R1) (+) (U1).
    r_keep : float or None
        Keep-out sphere radius around the AUV's *true* position (m); None: the
        :class:`DomainParams` collision sphere ``alpha T0 rdot_max``. With None the
        ``uncertainty`` kind is the papers' radius grown by the uncertainty (never smaller
        than ``fixed``), and so is ``reachable``. A less conservative ``reachable`` domain
        replaces the sphere's ``alpha T0 rdot_max`` (a time margin at the top relative speed)
        by the explicit reach set: then ``r_keep`` is only the clearance (e.g. 20 m).
    k_sigma : float
        Multiplier on the estimate's 1-sigma (2.45: 95 % for a circular 2-D Gaussian).
    u_age : float
        Speed at which the AUV can move away from the belief's mean between fixes (m/s):
        the AUV's top speed for the stationary ``acoustic`` estimate; 0 is enough for the
        ``kalman``/``plan`` estimators, whose covariance grows with the fix age.
    w_max : float
        AUV depth-rate limit (m/s): it may have risen this fast since the last depth.
    T_reach : float
        Reachable-set horizon (s): how far ahead the AUV's motion must be covered. Not the
        fix period (the estimate already moves with the AUV) but the time the ASV needs to
        get out of the way from standby (turn, spin up, accelerate past the AUV's speed).
        ``r_keep = 20``, ``T_reach = 15`` kept ``min_range_m >= 10`` in Cases 4 and 8
        (pursuers) where ``T_reach = 10`` did not (docs/estimation.md).
    U_max, turn_rate_max_deg, accel_max : float
        AUV motion limits (m/s, deg/s, m/s^2); defaults as :class:`mpcasv.models.auv.AUVLimits`.
    psi_margin_deg : float
        Heading uncertainty of the estimate's velocity (deg).
    U_margin : float
        Speed uncertainty (m/s); below it the heading is treated as unknown (any direction).
    n_facets, n_time : int
        Polygon facets and time steps of the quadrature of (R1).
    """

    kind: Literal["fixed", "uncertainty", "reachable"] = "fixed"
    r_keep: Pos | None = None
    k_sigma: NonNeg = 2.45
    u_age: NonNeg = 2.0
    w_max: NonNeg = 0.5
    T_reach: NonNeg = 15.0
    U_max: Pos = 2.0
    turn_rate_max_deg: Pos = 10.0
    accel_max: Pos = 0.2
    psi_margin_deg: NonNeg = 20.0
    U_margin: NonNeg = 0.3
    n_facets: PosInt = 48
    n_time: PosInt = 20

    def sphere(self, domain: DomainParams | None) -> float:
        """The keep-out sphere radius (m): ``r_keep`` or the domain's ``r_in``."""
        if self.r_keep is not None:
            return float(self.r_keep)
        if domain is None:
            raise ValueError("AvoidanceParams.r_keep is None and no DomainParams was given")
        return domain.r_in


def r_avoid_uncertain(
    d: ArrayLike, r_keep: ArrayLike, sigma: ArrayLike, age: ArrayLike, k_sigma: ArrayLike,
    u_age: ArrayLike, w_max: ArrayLike,
) -> NDArray | float:  # fmt: skip
    """Uncertainty-aware anti-collision radius on the surface (eq. U1 above).

    ``sqrt(r_keep**2 - d_eff**2) + k_sigma sigma + u_age age`` with
    ``d_eff = max(d - w_max age, 0)``; 0 where the keep-out sphere cannot reach the surface.

    Parameters
    ----------
    d : float or array_like
        Last known AUV depth (m, positive down).
    r_keep : float or array_like
        Keep-out sphere radius (m).
    sigma : float or array_like
        1-sigma horizontal uncertainty of the estimate (m).
    age : float or array_like
        Time since the last fix or report (s, >= 0).
    k_sigma, u_age, w_max : float or array_like
        See :class:`AvoidanceParams`.
    """
    age = np.maximum(np.asarray(age, float), 0.0)
    r_keep = np.asarray(r_keep, float)
    d_eff = np.maximum(np.asarray(d, float) - np.asarray(w_max, float) * age, 0.0)
    grow = np.asarray(k_sigma, float) * np.asarray(sigma, float) + np.asarray(u_age, float) * age
    return np.where(d_eff < r_keep, _surface_radius(d_eff, r_keep) + grow, 0.0)


def reach_support(
    theta: ArrayLike, T: float, U0: ArrayLike, U_max: float, omega_max: float, a_max: float,
    dpsi: ArrayLike = 0.0, n_time: int = 20,
) -> NDArray:  # fmt: skip
    """Upper bound of the support function of the AUV's reachable set over ``[0, T]`` (R1).

    Parameters
    ----------
    theta : array_like, shape (M,)
        Directions relative to the AUV's heading (rad).
    T : float
        Horizon (s).
    U0 : float or array_like, shape (...)
        Upper bound of the current speed (m/s).
    U_max, omega_max, a_max : float
        Speed (m/s), turn-rate (rad/s) and acceleration (m/s^2) limits.
    dpsi : float or array_like, shape (...)
        Heading uncertainty (rad); ``pi`` for an unknown heading.
    n_time : int
        Quadrature steps (the bound also covers Euler steps <= ``T / n_time``).

    Returns
    -------
    ndarray, shape (..., M)
        ``max over reachable p(t), t <= T, of  n(theta) . (p(t) - p(0))`` (m), >= 0.
    """
    theta = np.asarray(theta, float)
    U0 = np.asarray(U0, float)[..., None, None]
    dpsi = np.asarray(dpsi, float)[..., None, None]
    if T <= 0:
        return np.zeros(np.broadcast_shapes(U0.shape[:-2], dpsi.shape[:-2]) + theta.shape)
    step = T / n_time
    t = step * np.arange(2, n_time + 2)  # right ends, shifted by one step (see R1)
    wrapped = np.abs((theta + np.pi) % (2 * np.pi) - np.pi)
    phi = np.maximum(wrapped[:, None] - dpsi, 0.0)  # (..., M, 1)
    c = np.maximum(np.cos(np.maximum(phi - omega_max * t, 0.0)), 0.0)
    U = np.minimum(U_max, U0 + a_max * t)
    return step * np.sum(U * c, axis=-1)


@dataclass(frozen=True)
class AvoidanceShape:
    """An anti-collision domain on the surface, for one or several AUVs (leading axes).

    The disc of radius ``rho`` around ``center`` (``normals is None``), or the polygon
    ``{x: normals_j . (x - center) <= h_j + rho}``. ``rho == 0`` with ``h == 0`` is an empty
    domain (the sphere does not reach the surface).
    """

    center: NDArray  # (..., 2) m
    rho: NDArray  # (...) m
    normals: NDArray | None = None  # (..., M, 2) unit outward normals
    h: NDArray | None = None  # (..., M) m, support of the reachable set

    def signed_distance(self, q: ArrayLike) -> NDArray:
        """Signed-distance-like function of the ASV position ``q`` (..., 2): negative inside
        (exact depth), positive outside (exact for the disc, a lower bound for the polygon)."""
        rel = np.asarray(q, float) - self.center
        if self.normals is None:
            return np.hypot(rel[..., 0], rel[..., 1]) - self.rho
        proj = np.einsum("...mj,...j->...m", self.normals, rel)
        return np.max(proj - self.h, axis=-1) - self.rho

    def inside(self, q: ArrayLike) -> NDArray:
        """Whether ``q`` is strictly inside (Paper 2's ``r < r_avoid``)."""
        return self.signed_distance(q) < 0

    def radius(self, beta: ArrayLike) -> NDArray:
        """Distance from ``center`` to the boundary along bearing ``beta`` (rad from North):
        the drop-in replacement of ``r_avoid,i`` / ``r_inner`` at that bearing."""
        beta = np.asarray(beta, float)
        if self.normals is None:
            return np.broadcast_to(self.rho, np.broadcast_shapes(np.shape(self.rho), beta.shape))
        u = np.stack([np.cos(beta), np.sin(beta)], axis=-1)
        nu = np.einsum("...mj,...j->...m", self.normals, u)
        off = self.h + np.asarray(self.rho)[..., None]
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(nu > 1e-12, off / nu, np.inf)
        return np.min(r, axis=-1)


def avoidance_shape(
    avoid: AvoidanceParams, domain: DomainParams | None, N: ArrayLike, E: ArrayLike,
    depth: ArrayLike, v_N: ArrayLike = 0.0, v_E: ArrayLike = 0.0, sigma: ArrayLike = 0.0,
    age: ArrayLike = 0.0,
) -> AvoidanceShape:  # fmt: skip
    """The anti-collision domain of each AUV (vectorised over AUVs; see the section comment).

    Parameters
    ----------
    avoid : AvoidanceParams
    domain : DomainParams or None
        Supplies ``r_in`` (kind ``fixed``, or ``r_keep`` None).
    N, E, depth, v_N, v_E : float or array_like, shape (K,)
        Estimated position (m), depth (m) and velocity (m/s) of each AUV.
    sigma : float or array_like
        1-sigma horizontal uncertainty (m), e.g. :attr:`mpcasv.interface.AUVEstimate.sigma`.
    age : float or array_like
        Time since the last fix (s).
    """
    center = np.stack(np.broadcast_arrays(np.asarray(N, float), np.asarray(E, float)), axis=-1)
    depth = np.asarray(depth, float)
    if avoid.kind == "fixed":
        if domain is None:
            raise ValueError("the fixed anti-collision domain needs DomainParams (r_in)")
        return AvoidanceShape(center, np.asarray(r_avoid(depth, domain.r_in)))
    age = np.maximum(np.asarray(age, float), 0.0)
    ahead = avoid.T_reach if avoid.kind == "reachable" else 0.0
    rho = np.asarray(r_avoid_uncertain(  # (U1); the AUV may also rise during T_reach
        np.maximum(depth - avoid.w_max * ahead, 0.0), avoid.sphere(domain), sigma, age,
        avoid.k_sigma, avoid.u_age, avoid.w_max,
    ))  # fmt: skip
    if avoid.kind == "uncertainty":
        return AvoidanceShape(center, rho)
    v_N, v_E = np.broadcast_arrays(np.asarray(v_N, float), np.asarray(v_E, float))
    speed = np.hypot(v_N, v_E)
    psi = np.arctan2(v_E, v_N)
    known = speed > avoid.U_margin
    dpsi = np.where(known, math.radians(avoid.psi_margin_deg), np.pi)
    U0 = np.where(known, np.minimum(speed + avoid.U_margin, avoid.U_max), avoid.U_max)
    M = avoid.n_facets
    theta = 2 * np.pi * np.arange(M) / M
    h = reach_support(theta, avoid.T_reach, U0, avoid.U_max,
                      math.radians(avoid.turn_rate_max_deg), avoid.accel_max, dpsi,
                      avoid.n_time)  # fmt: skip
    ang = np.asarray(psi)[..., None] + theta
    normals = np.stack([np.cos(ang), np.sin(ang)], axis=-1)
    empty = rho <= 0
    h = np.where(np.asarray(empty)[..., None], 0.0, h)
    return AvoidanceShape(center, rho, normals, h)


def estimate_shape(avoid: AvoidanceParams, domain: DomainParams | None, auvs, t: float,
                   lookahead: ArrayLike = 0.0, depth: ArrayLike | None = None,
                   ) -> AvoidanceShape:  # fmt: skip
    """The domains of the AUVs of an observation (``obs.auvs``, :class:`AUVEstimate` s) at
    time ``t + lookahead``: centres moved along the estimated velocity, fix ages grown (for an
    MPC stage ``lookahead`` s ahead; 0 for the hybrid controllers).

    ``lookahead`` (s) is a float or an array of shape (S,) (S stages at once: the shape's
    arrays then have shape (S, K, ...)); ``depth`` (m, shape (K,) or (S, K)) replaces the
    estimates' depths (an MPC's depth forecast), None keeps them."""
    a = list(auvs)
    col = {f: np.array([getattr(e, f) for e in a], float)
           for f in ("N", "E", "depth", "v_N", "v_E", "t_last_fix")}  # fmt: skip
    sigma = np.array([e.sigma for e in a], float)
    ahead = np.asarray(lookahead, float)
    if ahead.ndim:  # one row per stage
        ahead = ahead[:, None]
    return avoidance_shape(
        avoid, domain, col["N"] + col["v_N"] * ahead, col["E"] + col["v_E"] * ahead,
        col["depth"] if depth is None else np.asarray(depth, float), col["v_N"], col["v_E"],
        sigma, t + ahead - col["t_last_fix"],
    )  # fmt: skip


def avoidance_radii(avoid: AvoidanceParams, domain: DomainParams | None, auvs, t: float,
                    asv_NE: ArrayLike) -> NDArray:  # fmt: skip
    """Each AUV's anti-collision radius along the bearing from it to the ASV (m, shape (K,)).

    Drop-in for ``domain.avoid(depth)`` / ``domain.inner(depth)`` in the hybrid controllers:
    ``r < avoidance_radii(...)`` is the collision-avoidance test, ``radii + delta_r`` the
    target circle at that bearing. With ``kind == "fixed"`` it equals ``domain.avoid(depth)``.
    """
    shape = estimate_shape(avoid, domain, auvs, t)
    _, beta = range_bearing(asv_NE, shape.center)
    return shape.radius(beta)
