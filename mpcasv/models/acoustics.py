"""Acoustic channel (USBL fixes, status reports) and the AUVs' INS drift parameters.

- USBL pings every ``T0`` per AUV. Success probability depends on slant range (near certain
  below d1, sporadic to d2, none beyond; PAPER-FACTS §1) and drops while the ASV's propeller
  runs (propeller noise).
- A fix's error (:func:`usbl_error_map`): the range noise along the 3-D line of sight and
  thesis eq. 2.9's angle error (transverse error = angle error x range) across it and in
  elevation, projected to the horizontal for the covariance (U1, U2 below). One definition
  for the simulator's fixes (:func:`usbl_fix`) and the deploy's covariance of a DUNE fix
  without an accuracy (:func:`usbl_fix` at the measured position).
- Each AUV's own navigation (:class:`NavParams`: dp = 1/2 eps_a t^2 between fixes, thesis
  eq. 2.7) is filtered by :class:`mpcasv.models.auv_nav.AUVNavFilter`: dead reckoning, and a
  Kalman update with each USBL fix that reaches the AUV (weighted by the fix's covariance)
  and with GPS at the surface.
- The reliable-fix rule (Paper 2 eq. 9) is defined once, in
  :func:`mpcasv.hybrid.domains.reliable_fix_possible`.
- Acoustic status reports every ``T_report`` carry the AUV's own navigation estimate, depth,
  course and speed over ground.

The USBL's error (session 49): a USBL measures the slant range ``rho`` (noise
``sigma_range``) and the direction of the 3-D line of sight ``u`` from the ASV to the AUV,
with an angle error ``sigma_b`` (rad, from ``sigma_bearing_deg``) in both directions
perpendicular to it: across, horizontal, and in elevation, in the vertical plane of the line
of sight. Eq. 2.9 (transverse error = angle error
x range) makes each a displacement ``sigma_b rho``. To first order the fix's error in (N, E,
depth) is ``J z`` with ``z`` three standard normals (range, across, elevation) and

    J = [sigma_range u,  sigma_b rho a,  sigma_b rho b]                              (U1)

``u = [r_h/rho los, d/rho]``, ``a = [perp, 0]``, ``b = [-d/rho los, r_h/rho]`` (``los``,
``perp`` the horizontal unit vectors along and across the line of sight, ``r_h`` the
horizontal range, ``d`` the depth). Projected to the horizontal:

    sigma_along = sqrt((sigma_range r_h / rho)^2 + (sigma_b d)^2),  sigma_across = sigma_b rho,
    R = sigma_along^2 los los^T + sigma_across^2 perp perp^T                           (U2)

Far off (``r_h >> d``) this is the range noise along and ``sigma_b rho`` across; under the
ASV (``r_h -> 0``) it is isotropic, ``sigma_b d`` in every direction (so the arbitrary ``los``
there does not matter). The fix's depth is the AUV's depth plus the vertical row of (U1):
``sigma_range d/rho`` from the range and ``sigma_b r_h`` from the elevation error.

Until session 49 the fix had the range noise alone along the horizontal line of sight (no
elevation error: under the ASV an anisotropic covariance along an arbitrary north, 0.5 m N
and ``sigma_b rho`` E, where the error is isotropic) and a separate ``sigma_range`` noise on
the depth (``usbl_geometry``, also the deploy's covariance).

No randomness is drawn here: the simulator hands in its draws (the synchronised streams of
:mod:`mpcasv.sim.streams`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import model_validator

from mpcasv.config import DURATION_MAX, Flag, Prob, between, frozen

# Bounds of the channel's numbers (docs/experiments.md, "Bounds"; nan and inf refused as "not
# a finite number"):
#: A ping or report period (s): at least a second (a USBL fix waits for the ping's round trip,
#: 1 s to 750 m; ``T0 = 1e-9`` looped for ever over the pings of one period) and at most the
#: longest run.
Period = between(1.0, DURATION_MAX, "s", "a round trip takes about a second; a run a week")
#: The longest acoustic range (m): about twice the longest-range USBL systems' ~10 km.
ACOUSTIC_RANGE_MAX = 20000.0
AcousticRange = between(0, ACOUSTIC_RANGE_MAX, "m", "no USBL reaches further", lo_open=True)
#: A bearing error, 1 sigma (deg): beyond half a turn a bearing says nothing.
BearingSigma = between(0, 180, "deg", "beyond half a turn a bearing says nothing")
#: A range error, 1 sigma (m): no larger than the longest range.
RangeSigma = between(0, ACOUSTIC_RANGE_MAX, "m", "no larger than the longest acoustic range")
#: A GPS error, 1 sigma (m): 1 km off is no fix (a GPS fix is 2-10 m).
GpsSigma = between(0, 1000, "m", "a GPS fix is metres, 1 km off is no fix")


@frozen
class AcousticParams:
    """Acoustic channel parameters (PAPER-FACTS §1; guesses marked)."""

    T0: Period = 5.0  # USBL fix period per AUV (s)
    T_report: Period = 30.0  # status report period (s)
    usbl: Flag = True  # USBL fixes available (False: only status reports, as in Case 5)
    d1: AcousticRange = 500.0  # slant range of good reception (m)
    d2: AcousticRange = 800.0  # slant range of sporadic reception (m)
    p_good: Prob = 0.95  # success probability below d1 (guess)
    p_sporadic: Prob = 0.3  # success probability in (d1, d2] (guess)
    propeller_factor: Prob = 0.63  # multiplier while the propeller runs (Norgren et al.: 63 %)
    sigma_bearing_deg: BearingSigma = 1.0  # USBL bearing error, 1 sigma (deg; guess)
    sigma_range: RangeSigma = 0.5  # USBL range noise, 1 sigma (m; guess)
    gps_sigma: GpsSigma = 2.0  # AUV position error after a GPS fix at the surface (m)

    @model_validator(mode="after")
    def _order(self) -> AcousticParams:
        if self.d2 < self.d1:
            raise ValueError(f"d2 ({self.d2}) must be >= d1 ({self.d1})")
        return self


@frozen
class NavParams:
    """AUV inertial navigation drift between fixes (thesis eq. 2.7)."""

    #: accelerometer noise, RMS (m/s^2); MRU 5 value from the thesis. At most 1 m/s^2 (eq. 2.7
    #: puts the AUV 450 m off 30 s after a fix: no navigation at all; IMUs: 1e-4 to 0.1)
    eps_a: between(0, 1.0, "m/s^2", "1 m/s^2 is 450 m off 30 s after a fix") = 0.002
    #: extra drift as a fraction of distance travelled (at most 1: all of it)
    drift_per_distance: between(0, 1.0, "", "a drift as long as the way is no navigation") = 0.0


def success_probability(slant, propeller_on, p: AcousticParams):
    """Probability that one acoustic transmission gets through (vectorised)."""
    slant = np.asarray(slant, float)
    base = np.where(slant <= p.d1, p.p_good, np.where(slant <= p.d2, p.p_sporadic, 0.0))
    return base * np.where(np.asarray(propeller_on, bool), p.propeller_factor, 1.0)


@dataclass(frozen=True, slots=True)
class Fix:
    """A USBL fix of AUV ``auv`` at time ``t``: measured position and its covariance.

    ``depth`` is the USBL's (the 3-D fix's vertical part, as DUNE's ``UsblFixExtended``),
    ``depth_var`` its variance (m^2; ``J[2] @ J[2]`` of (U1): ``sigma_b r_h`` is 1.7 m at
    100 m, 7 m at 400 m); NaN: not known (the estimators then use the depth only to start)."""

    t: float
    auv: int
    N: float
    E: float
    depth: float
    cov: tuple[float, float, float, float]
    slant: float
    depth_var: float = math.nan


@dataclass(frozen=True, slots=True)
class Report:
    """An acoustic status report: the AUV's own navigation estimate and motion."""

    t: float
    auv: int
    N: float
    E: float
    depth: float
    psi: float
    speed: float
    nav_sigma: float  # the AUV's own estimate of its position error, 1 sigma (m)


def usbl_error_map(asv_NE, auv_NEd, p: AcousticParams) -> tuple[np.ndarray, float]:
    """``(J, slant)``: the 3 x 3 matrix (U1) that maps the fix's three standard normals
    (range, across the line of sight, elevation) to its error in (N, E, depth) (m), for an AUV
    at ``auv_NEd`` (N, E, depth; m) seen from the ASV at ``asv_NE`` (m); and the slant range
    (m)."""
    rel = np.asarray(auv_NEd[:2], float) - np.asarray(asv_NE, float)
    r_h = float(np.hypot(*rel))
    d = float(auv_NEd[2])
    slant = math.hypot(r_h, d)
    los = rel / r_h if r_h > 1e-9 else np.array([1.0, 0.0])  # under the ASV: any (isotropic)
    perp = np.array([-los[1], los[0]])
    if slant > 1e-9:
        ch, sv = r_h / slant, d / slant  # cos and sin of the line of sight's depression angle
    else:  # at the transducer: no direction, the range noise along los
        ch, sv = 1.0, 0.0
    s_t = math.radians(p.sigma_bearing_deg) * slant  # eq. 2.9: angle error x range
    u = np.array([ch * los[0], ch * los[1], sv])
    a = np.array([perp[0], perp[1], 0.0])
    b = np.array([-sv * los[0], -sv * los[1], ch])
    J = np.column_stack([p.sigma_range * u, s_t * a, s_t * b])
    return J, slant


def usbl_fix(t, auv, asv_NE, auv_NEd, p: AcousticParams, z) -> Fix:
    """A USBL fix of AUV ``auv`` at ``auv_NEd`` from the ASV at ``asv_NE``: the position plus
    ``J z`` (U1), with the horizontal covariance (U2) of the same ``J`` and the depth's
    variance (its vertical row's ``J[2] @ J[2]``).

    ``z``: shape (3,), standard normals drawn by the caller (the simulator's ping stream,
    :mod:`mpcasv.sim.streams`): the range error, the angle error across the line of sight
    and the angle error in elevation, in units of their 1-sigma."""
    J, slant = usbl_error_map(asv_NE, auv_NEd, p)
    e = J @ np.asarray(z, float).reshape(3)
    R = J[:2] @ J[:2].T
    return Fix(
        t, auv, float(auv_NEd[0] + e[0]), float(auv_NEd[1] + e[1]), float(auv_NEd[2] + e[2]),
        (float(R[0, 0]), float(R[0, 1]), float(R[1, 0]), float(R[1, 1])), slant,
        float(J[2] @ J[2]),
    )  # fmt: skip
