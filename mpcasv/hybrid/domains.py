"""Geometry of the ASV's safety domain around an AUV (the "donut"): the one definition.

Paper 1 §2.2 (single AUV) puts two spheres around the AUV: a communication sphere of radius
``r_out`` (eq. 3) and a collision sphere of radius ``r_in`` (eq. 4). At AUV depth ``d`` they cut
the surface in two circles, ``r_inner`` and ``r_outer`` (eq. 5), the donut in which the ASV may
idle. The ASV aims at the target circle ``r_t = r_inner + delta_r`` (eq. 8) and accepts the
target domain ``r in [r_t - eps_minus, r_t + eps_plus]`` (eq. 10). Paper 2 §2.3 (several AUVs)
keeps one anti-collision sphere of radius ``r_avoid = alpha T0 rdot_max`` per AUV (eqs. 4-5)
and the target circle ``r_t,i = r_avoid,i + delta_r`` (eq. 6).

Every function is pure and vectorised: arguments may be floats or numpy arrays and broadcast
against each other. Positions are horizontal NED pairs ``[N, E]`` in the last axis (m);
depths are positive down (m); angles are in radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mpcasv.config import NonNeg, Pos, PosInt, frozen

__all__ = [
    "AvoidanceParams",
    "AvoidanceShape",
    "DomainParams",
    "avoidance_radii",
    "avoidance_shape",
    "estimate_shape",
    "r_avoid_uncertain",
    "reach_support",
    "in_reliable_range",
    "in_target_domain",
    "reliable_fix_possible",
    "reliable_limit",
    "target_reached",
    "point_on_circle",
    "r_avoid",
    "r_in",
    "r_inner",
    "r_out",
    "r_outer",
    "r_target",
    "range_bearing",
]


def r_out(r0: ArrayLike, alpha_outer: ArrayLike) -> NDArray | float:
    """Radius of the communication sphere, ``r_out = r0 / alpha_outer`` (Paper 1 eq. 3).

    Parameters
    ----------
    r0 : float or array_like
        Rated maximum range of the USBL modem (m).
    alpha_outer : float or array_like
        Safety factor (> 0) on that range.
    """
    return np.asarray(r0, dtype=float) / np.asarray(alpha_outer, dtype=float)


def r_in(alpha_inner: ArrayLike, T0: ArrayLike, rdot_max: ArrayLike) -> NDArray | float:
    """Radius of the collision sphere, ``r_in = alpha_inner T0 rdot_max`` (Paper 1 eq. 4).

    Paper 2 eq. 4 defines ``r_avoid = alpha T0 rdot_max`` the same way.

    Parameters
    ----------
    alpha_inner : float or array_like
        Safety factor on the USBL period.
    T0 : float or array_like
        Rated USBL update period (s).
    rdot_max : float or array_like
        Largest relative speed between ASV and AUV (m/s).
    """
    return (
        np.asarray(alpha_inner, dtype=float)
        * np.asarray(T0, dtype=float)
        * np.asarray(rdot_max, dtype=float)
    )


def _surface_radius(d: ArrayLike, radius: ArrayLike) -> NDArray | float:
    """Radius of the circle where a sphere of ``radius`` centred at depth ``d`` meets the surface.

    ``sqrt(radius**2 - d**2)`` for ``|d| <= radius``, else 0 (the sphere stays below).
    """
    d = np.asarray(d, dtype=float)
    radius = np.asarray(radius, dtype=float)
    return np.sqrt(np.maximum(radius * radius - d * d, 0.0))


def r_inner(d: ArrayLike, r_in: ArrayLike) -> NDArray | float:
    """Inner boundary of the donut at AUV depth ``d`` (Paper 1 eq. 5).

    Parameters
    ----------
    d : float or array_like
        AUV depth (m, positive down).
    r_in : float or array_like
        Collision-sphere radius (m), see :func:`r_in`.

    Returns
    -------
    float or ndarray
        ``sqrt(r_in**2 - d**2)`` if ``d <= r_in``, else 0 (m).
    """
    return _surface_radius(d, r_in)


def r_outer(d: ArrayLike, r_out: ArrayLike) -> NDArray | float:
    """Outer boundary of the donut at AUV depth ``d`` (Paper 1 eq. 5).

    Returns ``sqrt(r_out**2 - d**2)`` if ``d <= r_out``, else 0 (m). A zero outer radius means
    the safety domain is empty on the surface: the AUV is too deep to be served.
    """
    return _surface_radius(d, r_out)


def r_avoid(d: ArrayLike, r_avoid_sphere: ArrayLike) -> NDArray | float:
    """Per-AUV anti-collision radius on the surface, ``r_avoid,i`` (Paper 2 eq. 5).

    Parameters
    ----------
    d : float or array_like
        Depth ``d_i`` of AUV ``i`` (m, positive down).
    r_avoid_sphere : float or array_like
        Anti-collision sphere radius ``r_avoid = alpha T0 rdot_max`` (m, Paper 2 eq. 4).

    Returns
    -------
    float or ndarray
        ``sqrt(r_avoid**2 - d_i**2)`` if ``d_i <= r_avoid``, else 0 (m).
    """
    return _surface_radius(d, r_avoid_sphere)


def r_target(d: ArrayLike, r_in: ArrayLike, delta_r: ArrayLike) -> NDArray | float:
    """Target-circle radius ``r_t = r_inner(d) + delta_r`` (Paper 1 eq. 8; Paper 2 eq. 6).

    With ``r_in`` the anti-collision sphere radius this is Paper 2's ``r_t,i``.
    """
    return r_inner(d, r_in) + np.asarray(delta_r, dtype=float)


def in_target_domain(
    r: ArrayLike, r_t: ArrayLike, eps_minus: ArrayLike, eps_plus: ArrayLike
) -> NDArray | np.bool_:
    """Whether the range ``r`` is in the target domain ``[r_t - eps_minus, r_t + eps_plus]``.

    The closed interval of Paper 1 eq. 10 / Paper 2 eq. 7. (The jump set D1 of Paper 1 eq. 11
    writes the open ``|e| < eps``; the two differ only on the boundary.)
    """
    r = np.asarray(r, dtype=float)
    r_t = np.asarray(r_t, dtype=float)
    return (r >= r_t - np.asarray(eps_minus, dtype=float)) & (
        r <= r_t + np.asarray(eps_plus, dtype=float)
    )


def reliable_limit(r_t: ArrayLike, eps_plus: ArrayLike) -> NDArray | float:
    """Outer limit of the target domain, ``r_t + eps_plus`` (m; Paper 2 eqs. 7 and 9)."""
    return np.asarray(r_t, dtype=float) + np.asarray(eps_plus, dtype=float)


def in_reliable_range(r: ArrayLike, r_t: ArrayLike, eps_plus: ArrayLike) -> NDArray | np.bool_:
    """The range part of Paper 2's reliable-fix rule (eq. 9): ``r < r_t + eps_plus``.

    Strict, as the paper writes it (``tau_k := 0 for r_k < r_t,k + eps``). Everything
    inside the outer limit counts, the collision domain too (the rule has no lower limit).
    """
    return np.asarray(r, dtype=float) < reliable_limit(r_t, eps_plus)


def reliable_fix_possible(
    r: ArrayLike, r_t: ArrayLike, eps_plus: ArrayLike, propeller_on: ArrayLike
) -> NDArray | np.bool_:
    """Paper 2's reliable-fix rule (eq. 9): ``r_k < r_t,k + eps`` and ``n_p = 0``.

    The ONE definition: the simulator (a fix that arrives while this holds is a reliable fix,
    and restarts the AUV's reliable-fix age tau_k), the metrics and the controllers' own
    fix-age timers call it (directly or via :meth:`DomainParams.reliable_fix_possible`).

    Parameters
    ----------
    r : float or array_like
        Horizontal ASV-AUV range (m).
    r_t : float or array_like
        Target-circle radius at the AUV's depth (m; Paper 2 eq. 6).
    eps_plus : float or array_like
        Outer tolerance of the target domain (m).
    propeller_on : bool or array_like
        ``n_p != 0``.
    """
    return in_reliable_range(r, r_t, eps_plus) & ~np.asarray(propeller_on, dtype=bool)


def target_reached(
    r: ArrayLike, r_t: ArrayLike, eps_minus: ArrayLike, eps_plus: ArrayLike
) -> NDArray | np.bool_:
    """The jump set D1 of the transit mode, ``|e| < eps`` with ``e = r - r_t`` (Paper 1
    eqs. 9 and 11; Paper 2 eqs. 10-11): the OPEN interval ``r_t - eps_minus < r < r_t +
    eps_plus``. (The target domain itself, :func:`in_target_domain`, is the closed one.)"""
    e = np.asarray(r, dtype=float) - np.asarray(r_t, dtype=float)
    return (e > -np.asarray(eps_minus, dtype=float)) & (e < np.asarray(eps_plus, dtype=float))


def range_bearing(asv_NE: ArrayLike, auv_NE: ArrayLike) -> tuple[NDArray, NDArray]:
    """Horizontal range and bearing from the AUV to the ASV (Paper 1 eq. 6; Paper 2 eq. 3).

    Parameters
    ----------
    asv_NE, auv_NE : array_like, shape (..., 2)
        Horizontal positions ``[N, E]`` (m); leading axes broadcast.

    Returns
    -------
    r : ndarray, shape (...)
        ``sqrt((N_asv - N_auv)**2 + (E_asv - E_auv)**2)`` (m).
    beta : ndarray, shape (...)
        ``atan2(E_asv - E_auv, N_asv - N_auv)`` in ``[-pi, pi]`` (rad, from North).
    """
    delta = np.asarray(asv_NE, dtype=float) - np.asarray(auv_NE, dtype=float)
    dN, dE = delta[..., 0], delta[..., 1]
    return np.hypot(dN, dE), np.arctan2(dE, dN)


def point_on_circle(auv_NE: ArrayLike, radius: ArrayLike, beta: ArrayLike) -> NDArray:
    """Point at ``radius`` and bearing ``beta`` from the AUV (Paper 1 eq. 7 waypoint).

    ``xi_auv + radius [cos(beta), sin(beta)]``: the inverse of :func:`range_bearing`.

    Parameters
    ----------
    auv_NE : array_like, shape (..., 2)
        AUV horizontal position ``[N, E]`` (m).
    radius : float or array_like, shape (...)
        Circle radius (m), e.g. ``r_t``.
    beta : float or array_like, shape (...)
        Bearing from the AUV (rad, from North).

    Returns
    -------
    ndarray, shape (..., 2)
        The point ``[N, E]`` (m).
    """
    radius, beta = np.broadcast_arrays(np.asarray(radius, float), np.asarray(beta, float))
    offset = np.stack([radius * np.cos(beta), radius * np.sin(beta)], axis=-1)
    return np.asarray(auv_NE, dtype=float) + offset


@frozen
class DomainParams:
    """Tuning of the safety domain (SI units), with the derived radii.

    Values used in the papers (PAPER-FACTS §7): Paper 1 simulations ``alpha_outer = 11.7``,
    ``alpha_inner = 3`` (thesis text; 5 in Paper 1 Table 1), ``delta_r = 125``, ``eps = 30``;
    Paper 1 field ``17.5, 5, 20, 10``; Paper 2 field ``alpha = 5, delta_r = 20, eps = 10``
    (Paper 2 has no outer boundary). ``r0, T0, rdot_max`` default to the EvoLogics S2C R 18/34
    rating and the papers' relative speed.

    Attributes
    ----------
    alpha_outer : float
        Safety factor on the modem range, ``r_out = r0 / alpha_outer`` (Paper 1 eq. 3).
    alpha_inner : float
        Safety factor on the fix period, ``r_in = alpha_inner T0 rdot_max`` (Paper 1 eq. 4);
        Paper 2's ``alpha`` (eq. 4).
    delta_r : float
        Margin from the inner boundary to the target circle (m, Paper 1 eq. 8).
    eps_minus, eps_plus : float
        Accepted deviation inside / outside the target circle (m, Paper 1 eq. 10);
        ``eps_minus <= delta_r`` so the target domain never reaches into the collision domain.
    r0 : float
        Rated USBL range (m).
    T0 : float
        Rated USBL fix period (s).
    rdot_max : float
        Largest relative speed between the vehicles (m/s).
    """

    alpha_outer: Pos
    alpha_inner: Pos
    delta_r: NonNeg
    eps_minus: NonNeg
    eps_plus: NonNeg
    r0: Pos = 3500.0
    T0: Pos = 5.0
    rdot_max: Pos = 2.0

    def __post_init__(self) -> None:
        if self.r_in >= self.r_out:
            raise ValueError(
                f"empty donut: r_in = {self.r_in:g} m >= r_out = {self.r_out:g} m "
                "(lower alpha_inner or alpha_outer)"
            )
        if self.eps_minus > self.delta_r:
            raise ValueError(
                f"eps_minus = {self.eps_minus:g} m > delta_r = {self.delta_r:g} m: the target "
                "domain would reach into the collision domain"
            )

    @property
    def r_out(self) -> float:
        """Communication-sphere radius (m, Paper 1 eq. 3)."""
        return float(r_out(self.r0, self.alpha_outer))

    @property
    def r_in(self) -> float:
        """Collision-sphere radius (m, Paper 1 eq. 4); equals Paper 2's ``r_avoid``."""
        return float(r_in(self.alpha_inner, self.T0, self.rdot_max))

    def inner(self, d: ArrayLike) -> NDArray | float:
        """Inner donut boundary ``r_inner`` at depth ``d`` (m, Paper 1 eq. 5)."""
        return r_inner(d, self.r_in)

    def outer(self, d: ArrayLike) -> NDArray | float:
        """Outer donut boundary ``r_outer`` at depth ``d`` (m, Paper 1 eq. 5)."""
        return r_outer(d, self.r_out)

    def target(self, d: ArrayLike) -> NDArray | float:
        """Target-circle radius ``r_t`` at depth ``d`` (m, Paper 1 eq. 8; Paper 2 eq. 6)."""
        return r_target(d, self.r_in, self.delta_r)

    def avoid(self, d: ArrayLike) -> NDArray | float:
        """Anti-collision radius ``r_avoid,i`` at depth ``d`` (m, Paper 2 eq. 5)."""
        return r_avoid(d, self.r_in)

    def reliable_limit(self, r_t: ArrayLike) -> NDArray | float:
        """``r_t + eps_plus`` (m): see :func:`reliable_limit`."""
        return reliable_limit(r_t, self.eps_plus)

    def in_reliable_range(self, r: ArrayLike, r_t: ArrayLike) -> NDArray | np.bool_:
        """``r < r_t + eps_plus`` (Paper 2 eq. 9): see :func:`in_reliable_range`."""
        return in_reliable_range(r, r_t, self.eps_plus)

    def reliable_fix_possible(self, r: ArrayLike, r_t: ArrayLike,
                              propeller_on: ArrayLike) -> NDArray | np.bool_:  # fmt: skip
        """Paper 2's reliable-fix rule (eq. 9): see :func:`reliable_fix_possible`."""
        return reliable_fix_possible(r, r_t, self.eps_plus, propeller_on)

    def target_reached(self, r: ArrayLike, r_t: ArrayLike) -> NDArray | np.bool_:
        """Jump set D1, ``|r - r_t| < eps`` (open): see :func:`target_reached`."""
        return target_reached(r, r_t, self.eps_minus, self.eps_plus)


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
                   lookahead: float = 0.0) -> AvoidanceShape:  # fmt: skip
    """The domains of the AUVs of an observation (``obs.auvs``, :class:`AUVEstimate` s) at
    time ``t + lookahead``: centres moved along the estimated velocity, fix ages grown (for an
    MPC stage ``lookahead`` s ahead; 0 for the hybrid controllers)."""
    a = list(auvs)
    col = {f: np.array([getattr(e, f) for e in a], float)
           for f in ("N", "E", "depth", "v_N", "v_E", "t_last_fix")}  # fmt: skip
    sigma = np.array([e.sigma for e in a], float)
    return avoidance_shape(
        avoid, domain, col["N"] + col["v_N"] * lookahead, col["E"] + col["v_E"] * lookahead,
        col["depth"], col["v_N"], col["v_E"], sigma, t + lookahead - col["t_last_fix"],
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
