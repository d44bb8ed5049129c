"""The simulator's USBL fixes against a Monte Carlo of thesis eq. 2.9 applied in 3-D: slant
range noise ``sigma_range`` along the 3-D line of sight, angle error ``sigma_b`` in both
directions perpendicular to it (across and in elevation). The fixes the simulator draws and
the covariance it hands the filters with them must both be that error projected to the
horizontal (docs/estimation.md section 5, a session-47 reviewer's ``usbl_mc.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mpcasv.models import acoustics
from mpcasv.models.acoustics import AcousticParams
from mpcasv.sim import world  # the fix function the simulator calls (world.usbl_fix)

P = AcousticParams()


def _monte_carlo(asv_NE, auv_NEd, n=400_000, seed=0):
    """Fixes (n x 3: N, E, depth) of the exact (not linearised) 3-D model."""
    rng = np.random.default_rng(seed)
    rel = np.array([auv_NEd[0] - asv_NE[0], auv_NEd[1] - asv_NE[1], auv_NEd[2]])
    slant = np.linalg.norm(rel)
    u = rel / slant
    a = np.cross(u, [0.0, 0.0, 1.0])
    a = a / np.linalg.norm(a) if np.linalg.norm(a) > 1e-9 else np.array([0.0, 1.0, 0.0])
    b = np.cross(u, a)
    sb = math.radians(P.sigma_bearing_deg)
    rho = slant + P.sigma_range * rng.standard_normal(n)
    d = u + sb * (rng.standard_normal(n)[:, None] * a + rng.standard_normal(n)[:, None] * b)
    d /= np.linalg.norm(d, axis=1)[:, None]
    return np.array([asv_NE[0], asv_NE[1], 0.0]) + rho[:, None] * d


CASES = [(100.0, 28.0), (5.0, 100.0), (0.0, 50.0), (400.0, 20.0)]


@pytest.mark.parametrize("r_h, depth", CASES)
@pytest.mark.parametrize("bearing_deg", [0.0, 37.0])
def test_fix_and_its_covariance_are_the_3d_error_projected(r_h, depth, bearing_deg):
    """At r_h 100 m / depth 28 m the error along the line of sight is 0.69 m (the range noise
    alone, 0.50 m, before); at r_h 5 m / depth 100 m (nearly under the ASV) it is isotropic,
    1.75 m every way (0.50 m along, 1.75 across before)."""
    asv = (10.0, -20.0)
    br = math.radians(bearing_deg)
    auv = (asv[0] + r_h * math.cos(br), asv[1] + r_h * math.sin(br), depth)
    mc = _monte_carlo(asv, auv)
    C_mc = np.cov(mc.T)
    rng = np.random.default_rng(1)
    fixes = [world.usbl_fix(0.0, 0, asv, auv, P, rng.standard_normal(3)) for _ in range(20_000)]
    R = np.reshape(fixes[0].cov, (2, 2))
    # the covariance handed to the filters is the Monte Carlo's horizontal covariance (sd in
    # every direction within 2 %; the Monte Carlo's own error on an sd is 0.1 %)
    for ang in np.radians([0.0, 30.0, 60.0, 90.0, 120.0, 150.0]):
        v = np.array([math.cos(ang), math.sin(ang)])
        assert math.sqrt(v @ R @ v) == pytest.approx(math.sqrt(v @ C_mc[:2, :2] @ v), rel=0.02)
    # every fix of this geometry carries the same covariance, and the fixes are drawn from it
    assert all(np.allclose(f.cov, fixes[0].cov) for f in fixes)
    X = np.array([[f.N, f.E, f.depth] for f in fixes])
    C_draw = np.cov(X.T)
    for ang in np.radians([0.0, 45.0, 90.0, 135.0]):
        v = np.array([math.cos(ang), math.sin(ang)])
        assert math.sqrt(v @ C_draw[:2, :2] @ v) == pytest.approx(
            math.sqrt(v @ C_mc[:2, :2] @ v), rel=0.03)
    e = X[:, :2] - np.array(auv[:2])
    nees = np.einsum("ij,ij->i", e, np.linalg.solve(R, e.T).T)
    assert nees.mean() == pytest.approx(2.0, abs=0.06)  # 2 dof; its standard error 0.014
    # the depth is the 3-D error's vertical part: sigma_range d / rho and sigma_b r_h
    assert math.sqrt(C_draw[2, 2]) == pytest.approx(math.sqrt(C_mc[2, 2]), rel=0.03)
    # ... its variance handed on with the fix (J[2] @ J[2]) is the Monte Carlo's
    assert math.sqrt(fixes[0].depth_var) == pytest.approx(math.sqrt(C_mc[2, 2]), rel=0.02)
    # and its correlation with the horizontal error (the elevation error moves a fix out and
    # up together: at r_h 100 m / depth 28 m along-line and depth correlate by -0.6; the sign
    # of the elevation vector b is seen only here) is the Monte Carlo's, from the drawn fixes
    # and from the map
    J, _ = acoustics.usbl_error_map(asv, auv, P)
    C_map = J @ J.T
    for C in (C_draw, C_map):
        for ang in np.radians([0.0, 45.0, 90.0, 135.0]):
            v = np.array([math.cos(ang), math.sin(ang)])
            corr = (v @ C[:2, 2]) / math.sqrt((v @ C[:2, :2] @ v) * C[2, 2])
            corr_mc = (v @ C_mc[:2, 2]) / math.sqrt((v @ C_mc[:2, :2] @ v) * C_mc[2, 2])
            assert corr == pytest.approx(corr_mc, abs=0.03)


def test_under_the_asv_the_covariance_does_not_depend_on_north():
    """Straight under the ASV the error is sigma_b depth in every direction: the covariance
    is isotropic whatever line of sight the code picks there."""
    f = world.usbl_fix(0.0, 0, (3.0, 4.0), (3.0, 4.0, 60.0), P, np.zeros(3))
    s = math.radians(P.sigma_bearing_deg) * 60.0
    np.testing.assert_allclose(np.reshape(f.cov, (2, 2)), s**2 * np.eye(2), rtol=1e-9)
    assert (f.N, f.E, f.depth) == (3.0, 4.0, 60.0)  # z = 0: no error
