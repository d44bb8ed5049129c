"""Safety-domain geometry (Paper 1 eqs. 3-10, Paper 2 eqs. 3-7)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mpcasv.config import ConfigError, parse
from mpcasv.hybrid.domains import (
    DomainParams,
    in_target_domain,
    point_on_circle,
    r_avoid,
    r_in,
    r_inner,
    r_out,
    r_outer,
    r_target,
    range_bearing,
)

depths = st.floats(0.0, 5000.0, allow_nan=False)
radii = st.floats(0.1, 5000.0, allow_nan=False)
coords = st.floats(-1e4, 1e4, allow_nan=False)


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


# --- radii of the spheres (eqs. 3-4), checked against the radii the papers report -------------


@pytest.mark.parametrize(
    ("alpha_outer", "expected"), [(17.5, 200.0), (11.7, 300.0)]
)  # Paper 1 field / simulations (PAPER-FACTS §7)
def test_r_out_matches_paper_values(alpha_outer, expected):
    assert r_out(3500.0, alpha_outer) == pytest.approx(expected, abs=1.5)


@pytest.mark.parametrize(("alpha", "expected"), [(5, 50.0), (3, 30.0)])
def test_r_in_matches_paper_values(alpha, expected):
    assert r_in(alpha, 5.0, 2.0) == pytest.approx(expected)


# --- the donut at and around its boundaries (eq. 5) --------------------------------------------


def test_r_inner_at_surface_is_sphere_radius():
    assert r_inner(0.0, 50.0) == 50.0


def test_r_inner_pythagorean_triple():
    assert r_inner(30.0, 50.0) == pytest.approx(40.0)
    assert r_outer(120.0, 200.0) == pytest.approx(160.0)


def test_r_inner_exactly_at_r_in_is_zero():
    assert r_inner(50.0, 50.0) == 0.0


def test_r_inner_just_above_r_in_is_small_positive():
    d = np.nextafter(50.0, 0.0)
    assert 0.0 < r_inner(d, 50.0) < 1e-5


def test_deeper_than_r_in_leaves_circle_domain():
    # d > r_in: the inner boundary is gone but the outer one still cuts the surface
    assert r_inner(60.0, 50.0) == 0.0
    assert r_outer(60.0, 200.0) == pytest.approx(math.sqrt(200.0**2 - 60.0**2))
    assert r_target(60.0, 50.0, 20.0) == pytest.approx(20.0)


def test_deeper_than_r_out_empties_domain():
    assert r_outer(200.0, 200.0) == 0.0
    assert r_outer(250.0, 200.0) == 0.0
    assert r_inner(250.0, 50.0) == 0.0


def test_r_avoid_per_auv():
    assert r_avoid(0.0, 50.0) == 50.0
    assert r_avoid(30.0, 50.0) == pytest.approx(40.0)
    assert r_avoid(50.0, 50.0) == 0.0
    assert r_avoid(51.0, 50.0) == 0.0


def test_in_target_domain_closed_interval_with_asymmetric_eps():
    r_t, em, ep = 70.0, 10.0, 5.0
    assert in_target_domain(r_t - em, r_t, em, ep)
    assert in_target_domain(r_t + ep, r_t, em, ep)
    assert in_target_domain(r_t, r_t, em, ep)
    assert not in_target_domain(np.nextafter(r_t - em, 0.0), r_t, em, ep)
    assert not in_target_domain(np.nextafter(r_t + ep, 1e9), r_t, em, ep)
    assert not in_target_domain(r_t + em, r_t, em, ep)  # the asymmetry matters


# --- vectorisation -----------------------------------------------------------------------------


DEPTHS = [0.0, 10.0, 30.0, 49.999, 50.0, 50.001, 150.0, 200.0, 250.0]


@pytest.mark.parametrize("fn", [r_inner, r_outer, r_avoid])
def test_vectorised_equals_scalar(fn):
    radius = 200.0 if fn is r_outer else 50.0
    vec = fn(np.array(DEPTHS), radius)
    assert vec.shape == (len(DEPTHS),)
    np.testing.assert_array_equal(vec, [fn(d, radius) for d in DEPTHS])


def test_vectorised_target_and_membership_equal_scalar():
    d = np.array(DEPTHS)
    r = np.linspace(0.0, 150.0, len(DEPTHS))
    rt = r_target(d, 50.0, 20.0)
    inside = in_target_domain(r, rt, 10.0, 10.0)
    np.testing.assert_array_equal(rt, [r_target(x, 50.0, 20.0) for x in DEPTHS])
    np.testing.assert_array_equal(
        inside,
        [
            in_target_domain(ri, r_target(di, 50.0, 20.0), 10.0, 10.0)
            for ri, di in zip(r, d, strict=True)
        ],
    )


def test_broadcasting_depths_against_radii():
    d = np.array(DEPTHS)[:, None]
    rad = np.array([30.0, 50.0, 200.0])
    out = r_inner(d, rad)
    assert out.shape == (len(DEPTHS), 3)
    for i, di in enumerate(DEPTHS):
        for k, rk in enumerate(rad):
            assert out[i, k] == r_inner(di, rk)


def test_range_bearing_cardinal_directions():
    auv = np.array([100.0, -50.0])
    asv = auv + np.array([[10.0, 0.0], [0.0, 10.0], [-10.0, 0.0], [0.0, -10.0]])
    r, beta = range_bearing(asv, auv)
    np.testing.assert_allclose(r, 10.0)
    np.testing.assert_allclose(beta[[0, 1, 3]], [0.0, np.pi / 2, -np.pi / 2])
    assert abs(beta[2]) == pytest.approx(np.pi)
    for k in range(4):  # vectorised == scalar
        assert (r[k], beta[k]) == range_bearing(asv[k], auv)


def test_point_on_circle_north_is_beta_zero_and_vectorises():
    auv = np.array([[0.0, 0.0], [5.0, 5.0]])
    p = point_on_circle(auv, np.array([3.0, 4.0]), np.array([0.0, np.pi / 2]))
    assert p.shape == (2, 2)
    np.testing.assert_allclose(p, [[3.0, 0.0], [5.0, 9.0]], atol=1e-12)
    np.testing.assert_array_equal(p[1], point_on_circle(auv[1], 4.0, np.pi / 2))


# --- properties --------------------------------------------------------------------------------


@given(d=depths, rad=radii)
def test_prop_r_inner_bounded(d, rad):
    ri = r_inner(d, rad)
    assert 0.0 <= ri <= rad
    if d <= rad:
        assert ri**2 + d**2 == pytest.approx(rad**2, rel=1e-9, abs=1e-6)
    else:
        assert ri == 0.0


@given(d1=depths, d2=depths, rad=radii)
def test_prop_r_inner_decreasing_in_depth(d1, d2, rad):
    lo, hi = sorted((d1, d2))
    assert r_inner(lo, rad) >= r_inner(hi, rad)


@given(d=depths, rad=radii, delta_r=st.floats(0.0, 500.0))
def test_prop_target_beyond_inner_boundary(d, rad, delta_r):
    assert r_target(d, rad, delta_r) >= r_inner(d, rad) + delta_r - 1e-9


@given(N=coords, E=coords, radius=st.floats(1.0, 5000.0), beta=st.floats(-math.pi, math.pi))
def test_prop_point_on_circle_range_bearing_round_trip(N, E, radius, beta):
    auv = np.array([N, E])
    r, b = range_bearing(point_on_circle(auv, radius, beta), auv)
    assert r == pytest.approx(radius, rel=1e-9, abs=1e-8)
    assert abs(_wrap(b - beta)) < 1e-9


@given(aN=coords, aE=coords, sN=coords, sE=coords)
def test_prop_range_bearing_inverse(aN, aE, sN, sE):
    auv, asv = np.array([aN, aE]), np.array([sN, sE])
    r, b = range_bearing(asv, auv)
    np.testing.assert_allclose(point_on_circle(auv, r, b), asv, atol=1e-8)


# --- DomainParams ------------------------------------------------------------------------------


def _field():  # Paper 1 field trials
    return DomainParams(alpha_outer=17.5, alpha_inner=5, delta_r=20, eps_minus=10, eps_plus=10)


def test_params_defaults_give_paper_radii():
    p = _field()
    assert (p.r0, p.T0, p.rdot_max) == (3500.0, 5.0, 2.0)
    assert p.r_in == pytest.approx(50.0)
    assert p.r_out == pytest.approx(200.0)


@pytest.mark.parametrize("d", [0.0, 30.0, 50.0, 80.0, 200.0, 300.0])
def test_params_methods_use_the_functions(d):
    p = _field()
    assert p.inner(d) == r_inner(d, r_in(5, 5, 2))
    assert p.outer(d) == r_outer(d, r_out(3500, 17.5))
    assert p.target(d) == r_target(d, r_in(5, 5, 2), 20)
    assert p.avoid(d) == r_avoid(d, r_in(5, 5, 2))  # Paper 2: r_avoid = alpha T0 rdot_max


def test_params_methods_vectorise():
    d = np.array(DEPTHS)
    np.testing.assert_array_equal(_field().target(d), [_field().target(x) for x in DEPTHS])


def test_params_frozen_and_strict():
    p = _field()
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.delta_r = 5.0
    base = dict(alpha_outer=17.5, alpha_inner=5, delta_r=20, eps_minus=10, eps_plus=10)
    assert parse(DomainParams, base) == p
    for bad in ({"delta_r": "20"}, {"eps_plus": -1.0}, {"T0": 0.0}, {"unknown": 1.0}):
        with pytest.raises(ConfigError):
            parse(DomainParams, base | bad)


def test_params_refuse_empty_donut_and_overlapping_target_domain():
    base = dict(alpha_outer=17.5, alpha_inner=5, delta_r=20, eps_minus=10, eps_plus=10)
    with pytest.raises(ConfigError, match="empty donut"):
        parse(DomainParams, base | {"alpha_outer": 70.0})  # r_out = 50 m = r_in
    with pytest.raises(ConfigError, match="collision domain"):
        parse(DomainParams, base | {"eps_minus": 20.5})
    assert parse(DomainParams, base | {"eps_minus": 20.0}).eps_minus == 20.0


def test_params_refuse_a_target_domain_beyond_the_outer_boundary():
    # a new user's preset (session 43): delta_r = 400 put r_t at 450 m with r_out = 200 m;
    # the hybrid ran its propeller 299.7 of 300 s out there and got no reliable fix
    base = dict(alpha_outer=17.5, alpha_inner=5, delta_r=20, eps_minus=10, eps_plus=10)
    for bad in ({"delta_r": 400.0}, {"eps_plus": 500.0}, {"delta_r": 140.0}):  # 50+140+10
        with pytest.raises(ConfigError, match="beyond the outer boundary"):
            parse(DomainParams, base | bad)
    ok = parse(DomainParams, base | {"delta_r": 139.9})  # r_t + eps_plus = 199.9 m < 200 m
    assert ok.r_in + ok.delta_r + ok.eps_plus < ok.r_out
