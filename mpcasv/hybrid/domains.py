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

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mpcasv.config import NonNeg, Pos, frozen

__all__ = [
    "DomainParams",
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
        ``eps_minus <= delta_r`` so the target domain never reaches into the collision domain,
        and ``r_in + delta_r + eps_plus < r_out`` so it lies inside the outer boundary.
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
        reach = self.r_in + self.delta_r + self.eps_plus  # r_t + eps_plus at the surface
        if reach >= self.r_out:
            raise ValueError(
                f"r_t + eps_plus = r_in + delta_r + eps_plus = {reach:g} m >= r_out = "
                f"{self.r_out:g} m: the target domain would lie beyond the outer boundary "
                "(lower delta_r or eps_plus, or alpha_outer)"
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
