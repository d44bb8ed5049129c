"""The simulator's USBL fixes: thesis eq. 2.9's angle error applied to the 3-D line of sight,
projected to the horizontal. One definition (:func:`usbl_error_map`) gives both the drawn fix
(:func:`usbl_fix`) and the covariance the filters get with it (:func:`usbl_covariance`).

A USBL measures the slant range ``rho`` (noise ``sigma_range``) and the direction of the
3-D line of sight ``u`` from the ASV to the AUV, with an angle error ``sigma_b`` (rad, from
``sigma_bearing_deg``) in both directions perpendicular to it: across, horizontal, and in
elevation, in the vertical plane of the line of sight. Eq. 2.9 (transverse error = angle error
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

Before, the simulator used :func:`mpcasv.models.acoustics.usbl_fix`: the range noise
alone along the line of sight (no elevation error: under the ASV an anisotropic covariance
along an arbitrary north, 0.5 m N and ``sigma_b rho`` E, where the error is isotropic) and a
separate ``sigma_range`` noise on the depth. :func:`mpcasv.models.acoustics.usbl_geometry`
(the deploy's covariance for a DUNE fix without an accuracy) still is that model.

No randomness is drawn here: the simulator hands in ``z`` (three standard normals per fix,
the ping stream of :mod:`mpcasv.sim.streams`).
"""

from __future__ import annotations

import math

import numpy as np

from mpcasv.models.acoustics import AcousticParams, Fix

__all__ = ["usbl_covariance", "usbl_error_map", "usbl_fix"]


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


def usbl_covariance(asv_NE, auv_NEd, p: AcousticParams) -> tuple[np.ndarray, float]:
    """``(R, slant)``: the horizontal covariance (U2) of a fix (2 x 2, m^2; ``J_h J_h^T``
    with ``J_h`` the first two rows of (U1)) and the slant range (m)."""
    J, slant = usbl_error_map(asv_NE, auv_NEd, p)
    return J[:2] @ J[:2].T, slant


def usbl_fix(t, auv, asv_NE, auv_NEd, p: AcousticParams, z) -> Fix:
    """A USBL fix of AUV ``auv`` at ``auv_NEd`` from the ASV at ``asv_NE``: the position plus
    ``J z`` (U1), with the horizontal covariance (U2) of the same ``J``.

    ``z``: shape (3,), standard normals drawn by the caller (the simulator's ping stream,
    :mod:`mpcasv.sim.streams`): the range error, the angle error across the line of sight
    and the angle error in elevation, in units of their 1-sigma."""
    J, slant = usbl_error_map(asv_NE, auv_NEd, p)
    e = J @ np.asarray(z, float).reshape(3)
    R = J[:2] @ J[:2].T
    return Fix(
        t, auv, float(auv_NEd[0] + e[0]), float(auv_NEd[1] + e[1]), float(auv_NEd[2] + e[2]),
        (float(R[0, 0]), float(R[0, 1]), float(R[1, 0]), float(R[1, 1])), slant,
    )  # fmt: skip
