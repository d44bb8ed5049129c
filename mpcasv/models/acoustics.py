"""Acoustic channel (USBL fixes, status reports) and the AUVs' INS drift parameters.

- USBL pings every ``T0`` per AUV. Success probability depends on slant range (near certain
  below d1, sporadic to d2, none beyond; PAPER-FACTS §1) and drops while the ASV's propeller
  runs (propeller noise).
- A fix's position error grows with range: transverse error = bearing error x range
  (thesis eq. 2.9), plus range noise along the line of sight.
- Each AUV's own navigation (:class:`NavParams`: dp = 1/2 eps_a t^2 between fixes, thesis
  eq. 2.7) is filtered by :class:`mpcasv.models.auv_nav.AUVNavFilter`: dead reckoning, and a
  Kalman update with each USBL fix that reaches the AUV (weighted by the fix's covariance)
  and with GPS at the surface.
- The reliable-fix rule (Paper 2 eq. 9) is defined once, in
  :func:`mpcasv.hybrid.domains.reliable_fix_possible`.
- Acoustic status reports every ``T_report`` carry the AUV's own navigation estimate, depth,
  heading and speed.

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
    """A USBL fix of AUV ``auv`` at time ``t``: measured position and its covariance."""

    t: float
    auv: int
    N: float
    E: float
    depth: float
    cov: tuple[float, float, float, float]
    slant: float


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


def usbl_geometry(asv_NE, auv_NEd, p: AcousticParams):
    """The USBL's error geometry for an AUV at ``auv_NEd`` (N, E, depth; m) seen from the
    ASV at ``asv_NE`` (m): ``(los, perp, s_t, R, slant)``, the horizontal unit vectors along
    and across the line of sight, the transverse error's 1 sigma ``s_t`` (m; thesis eq. 2.9:
    bearing error x slant range), the horizontal covariance ``R`` (2 x 2, m^2: range noise
    along the line of sight, ``s_t`` across it) and the slant range (m). One definition for
    the simulator's fixes (:func:`usbl_fix`) and the deploy's reading of DUNE's fixes."""
    rel = np.asarray(auv_NEd[:2], float) - np.asarray(asv_NE, float)
    r_h = float(np.hypot(*rel))
    slant = math.hypot(r_h, auv_NEd[2])
    los = rel / r_h if r_h > 1e-9 else np.array([1.0, 0.0])
    perp = np.array([-los[1], los[0]])
    s_t = math.radians(p.sigma_bearing_deg) * slant
    R = p.sigma_range**2 * np.outer(los, los) + s_t**2 * np.outer(perp, perp)
    return los, perp, s_t, R, slant


def usbl_fix(t, auv, asv_NE, auv_NEd, p: AcousticParams, z) -> Fix:
    """Measure an AUV from the ASV: range noise along the line of sight, bearing error
    across it (eq. 2.9: transverse error = bearing error x range).

    ``z``: shape (3,), standard normals drawn by the caller (the simulator's ping stream,
    :mod:`mpcasv.sim.streams`): the errors along the line of sight, across it and in depth
    in units of their 1-sigma."""
    los, perp, s_t, R, slant = usbl_geometry(asv_NE, auv_NEd, p)
    z_los, z_perp, z_d = (float(v) for v in z)
    e = los * p.sigma_range * z_los + perp * s_t * z_perp
    return Fix(
        t, auv, float(auv_NEd[0] + e[0]), float(auv_NEd[1] + e[1]),
        float(auv_NEd[2] + p.sigma_range * z_d),
        (float(R[0, 0]), float(R[0, 1]), float(R[1, 0]), float(R[1, 1])), slant,
    )  # fmt: skip
