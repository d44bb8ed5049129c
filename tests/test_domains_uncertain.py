"""Uncertainty-aware and reachable-set anti-collision domains (issue 8)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mpcasv.config import ConfigError, parse
from mpcasv.hybrid.avoidance import (
    AvoidanceParams,
    avoidance_radii,
    avoidance_shape,
    estimate_shape,
    r_avoid_uncertain,
)
from mpcasv.hybrid.domains import DomainParams, r_avoid
from mpcasv.interface import AUVEstimate
from mpcasv.models.auv import AUVLimits, auv_step_function

DOM = DomainParams(alpha_outer=17.5, alpha_inner=5.0, delta_r=20.0, eps_minus=10.0,
                   eps_plus=10.0)  # fmt: skip  # Paper 1 field: r_in = 50 m


def _est(N=0.0, E=0.0, d=0.0, vN=0.0, vE=0.0, s2=0.0, t_fix=0.0):
    return AUVEstimate(N, E, d, vN, vE, (s2, 0.0, 0.0, s2), t_fix)


# --- the fixed kind is the papers' radius ------------------------------------------------------


@given(st.lists(st.floats(0.0, 80.0), min_size=1, max_size=4), st.floats(-math.pi, math.pi))
def test_fixed_kind_equals_papers_radius(depths, bearing):
    auvs = [_est(10.0 * k, 0.0, d) for k, d in enumerate(depths)]
    asv = np.array([math.cos(bearing), math.sin(bearing)]) * 500.0
    r = avoidance_radii(AvoidanceParams(), DOM, auvs, 3.0, asv)
    np.testing.assert_allclose(r, DOM.avoid(np.array(depths)), atol=1e-12)


# --- (a) the uncertainty radius -----------------------------------------------------------------


@given(st.floats(0.0, 60.0), st.floats(0.0, 50.0), st.floats(0.0, 100.0))
def test_uncertainty_radius_grows_and_reduces_to_the_sphere(d, sigma, age):
    base = r_avoid_uncertain(d, 50.0, 0.0, 0.0, 2.45, 2.0, 0.5)
    assert base == pytest.approx(float(r_avoid(d, 50.0)))
    r = r_avoid_uncertain(d, 50.0, sigma, age, 2.45, 2.0, 0.5)
    assert r >= base - 1e-12
    assert r_avoid_uncertain(d, 50.0, sigma + 1.0, age, 2.45, 2.0, 0.5) >= r
    assert r_avoid_uncertain(d, 50.0, sigma, age + 1.0, 2.45, 2.0, 0.5) >= r


def test_uncertainty_radius_covers_every_position_the_auv_can_be_at():
    """Union of keep-out spheres around every position the AUV may have reached: sampled."""
    rng = np.random.default_rng(0)
    sigma, age, k, u, w = 3.0, 12.0, 2.45, 2.0, 0.5
    for d, R in [(30.0, 40.0), (40.0, 36.0), (40.0, 30.0)]:
        r = r_avoid_uncertain(d, R, sigma, age, k, u, w)
        reach = 0.0
        for _ in range(2000):
            ang = rng.uniform(0, 2 * math.pi)
            off = rng.uniform(0, k * sigma + u * age) * np.array([math.cos(ang), math.sin(ang)])
            depth = rng.uniform(max(d - w * age, 0.0), d)
            if depth < R:  # this sphere cuts the surface: its disc must be inside
                reach = max(reach, np.hypot(*off) + math.sqrt(R**2 - depth**2))
        assert reach <= r + 1e-9
        assert reach >= 0.9 * r  # and the radius is not much larger than needed


def test_uncertainty_domain_empty_for_a_deep_auv():
    av = AvoidanceParams(kind="uncertainty", r_keep=20.0)
    shape = estimate_shape(av, DOM, [_est(d=60.0, s2=25.0, t_fix=9.0)], 10.0)
    assert shape.rho[0] == 0.0 and not shape.inside(np.array([1.0, 0.0]))[0]


# --- (b) the reachable-set domain ---------------------------------------------------------------


def _sample_reachable(rng, n_runs, T, dt, U0, psi0):
    """AUV positions along random admissible trajectories of the kinematics in
    mpcasv.models.auv (random targets, speeds and depths changing every 0.5-1 s)."""
    lim = AUVLimits()
    step = auv_step_function(dt, 1, n_runs)
    LIM = np.tile(lim.vector()[:, None], (1, n_runs))
    S = np.vstack([np.zeros((3, n_runs)), np.full(n_runs, psi0), np.full(n_runs, U0)])
    S[2] = 20.0
    pts, t, next_switch = [S[:2].copy()], 0.0, np.zeros(n_runs)
    SP = np.zeros((4, n_runs))
    while t < T - 1e-9:
        new = t >= next_switch
        ang = rng.uniform(-math.pi, math.pi, n_runs)
        far = rng.choice([5.0, 1e4], n_runs)
        SP[:, new] = np.vstack([S[0] + far * np.cos(ang), S[1] + far * np.sin(ang),
                                rng.uniform(0, lim.speed_max * 1.2, n_runs),
                                rng.uniform(0, 60, n_runs)])[:, new]  # fmt: skip
        next_switch[new] = t + rng.uniform(0.5, 1.0, new.sum())
        S = np.array(step(S, SP, LIM)[0])
        t += dt
        pts.append(S[:2].copy())
    return np.stack(pts, axis=-1)  # (2, n_runs, n_t)


def _bare_reach(T_reach, U0, psi0):
    """The reachable domain of an AUV at the surface with a vanishing keep-out sphere and no
    estimate uncertainty: the reach polygon alone, built by avoidance_shape."""
    av = AvoidanceParams(kind="reachable", r_keep=1e-9, k_sigma=0.0, u_age=0.0,
                         psi_margin_deg=0.0, U_margin=0.0, T_reach=T_reach)  # fmt: skip
    vel = U0 * np.array([math.cos(psi0), math.sin(psi0)])
    return avoidance_shape(av, DOM, 0.0, 0.0, 0.0, *vel)


@pytest.mark.parametrize(("U0", "psi0"), [(1.5, 0.3), (0.0, -2.0), (2.0, 2.5), (0.4, 1.0)])
def test_reachable_domain_contains_every_reachable_position(U0, psi0):
    """Every position the AUV model reaches within T from a known state lies inside the
    reach polygon; and the polygon is not vacuous: the trajectories come close to its
    front, which (for a moving AUV) is much further than its back."""
    rng = np.random.default_rng(int(10 * U0))
    T = 8.0
    pts = np.moveaxis(_sample_reachable(rng, 400, T, 0.1, U0, psi0), 0, -1)
    shape = _bare_reach(T, U0, psi0)
    assert shape.signed_distance(pts).max() <= 1e-9
    front, back = float(shape.radius(psi0)), float(shape.radius(psi0 + math.pi))
    reached = np.max(pts @ np.array([math.cos(psi0), math.sin(psi0)]))
    if U0 > 0:
        assert reached >= 0.8 * front
        assert back < 0.5 * front


def test_reachable_check_can_fail():
    """The sampled check rejects a reach set computed for too short a horizon."""
    rng = np.random.default_rng(5)
    pts = np.moveaxis(_sample_reachable(rng, 200, 8.0, 0.1, 1.5, 0.0), 0, -1)
    assert _bare_reach(4.0, 1.5, 0.0).signed_distance(pts).max() > 1.0


def test_reachable_domain_contains_uncertainty_disc_and_is_anisotropic():
    av = AvoidanceParams(kind="reachable", r_keep=20.0, u_age=0.0)
    un = AvoidanceParams(kind="uncertainty", r_keep=20.0, u_age=0.0)
    est = [_est(0.0, 0.0, 5.0, 0.0, 1.5, 9.0, 10.0)]  # heading East
    reach, disc = estimate_shape(av, DOM, est, 12.0), estimate_shape(un, DOM, est, 12.0)
    beta = np.linspace(-math.pi, math.pi, 73)
    assert np.all(reach.radius(beta[:, None]) >= disc.radius(beta[:, None]) - 1e-9)
    assert reach.radius(math.pi / 2)[0] > reach.radius(-math.pi / 2)[0] + 5.0  # ahead > behind


def test_radius_agrees_with_inside():
    av = AvoidanceParams(kind="reachable", r_keep=20.0)
    shape = estimate_shape(av, DOM, [_est(10.0, -5.0, 3.0, 1.0, 1.0, 4.0, 0.0)], 6.0)
    for b in np.linspace(-math.pi, math.pi, 37):
        r = float(shape.radius(b)[0])
        u = np.array([math.cos(b), math.sin(b)])
        assert shape.inside(shape.center[0] + 0.999 * r * u)[0]
        assert not shape.inside(shape.center[0] + 1.001 * r * u)[0]


def test_lookahead_moves_the_centre_and_grows_the_domain():
    av = AvoidanceParams(kind="uncertainty", r_keep=20.0)
    est = [_est(0.0, 0.0, 0.0, 1.0, 0.0, 4.0, 0.0)]
    now, ahead = estimate_shape(av, DOM, est, 5.0), estimate_shape(av, DOM, est, 5.0, 10.0)
    np.testing.assert_allclose(ahead.center[0], [10.0, 0.0])
    assert ahead.rho[0] > now.rho[0]


@pytest.mark.parametrize("kind", ["fixed", "uncertainty", "reachable"])
def test_stages_at_once_equal_each_stage_alone(kind):
    """An MPC's horizon in one call (lookahead shape (S,), depth forecast (S, K)) gives, bit
    for bit, the radii of one call per stage with the AUVs' depths replaced."""
    av = AvoidanceParams(kind=kind, r_keep=30.0)
    est = [_est(5.0, -3.0, 25.0, 0.8, 0.3, 4.0, 2.0), _est(-40.0, 60.0, 4.0, 0.0, -1.2, 1.0, 7.0)]
    ahead = np.array([0.0, 4.0, 8.0, 30.0, 90.0])
    depth = np.array([[25.0, 4.0], [20.0, 3.0], [15.0, 1.0], [5.0, 0.0], [0.0, 0.0]])
    asv = np.array([[[3.0, 1.0]], [[0.0, 9.0]], [[-8.0, 2.0]], [[-20.0, 30.0]], [[40.0, -5.0]]])
    at_once = estimate_shape(av, DOM, est, 10.0, ahead, depth)
    rel = asv - at_once.center
    r_all = at_once.radius(np.arctan2(rel[..., 1], rel[..., 0]))
    assert r_all.shape == (5, 2)
    for k in range(5):
        alone = [dataclasses.replace(e, depth=float(d)) for e, d in zip(est, depth[k], strict=True)]
        shape = estimate_shape(av, DOM, alone, 10.0, float(ahead[k]))
        rel_k = asv[k] - shape.center
        np.testing.assert_array_equal(shape.radius(np.arctan2(rel_k[..., 1], rel_k[..., 0])),
                                      r_all[k])  # fmt: skip
        np.testing.assert_array_equal(shape.center, at_once.center[k])


# --- the smooth (MPC) form ----------------------------------------------------------------------


def test_avoidance_params_validated():
    with pytest.raises(ConfigError, match="kind"):
        parse(AvoidanceParams, {"kind": "sphere"}, "preset.toml")
    with pytest.raises(ConfigError, match="k_sigma"):
        parse(AvoidanceParams, {"kind": "uncertainty", "k_sigma": -1.0}, "preset.toml")
    with pytest.raises(ValueError, match="r_keep"):
        AvoidanceParams(kind="uncertainty").sphere(None)
    assert AvoidanceParams().sphere(DOM) == DOM.r_in


@settings(max_examples=50, deadline=None)
@given(st.floats(0.0, 70.0), st.floats(0.0, 30.0), st.floats(0.0, 60.0), st.floats(0.0, 2.0),
       st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi))  # fmt: skip
def test_default_options_are_never_smaller_than_fixed(d, sigma, age, U, psi, bearing):
    """With r_keep = None (the papers' sphere) both options only add to the fixed radius."""
    est = [_est(0.0, 0.0, d, U * math.cos(psi), U * math.sin(psi), sigma**2, 0.0)]
    asv = 100.0 * np.array([math.cos(bearing), math.sin(bearing)])
    fixed = avoidance_radii(AvoidanceParams(), DOM, est, age, asv)
    for kind in ("uncertainty", "reachable"):
        r = avoidance_radii(AvoidanceParams(kind=kind), DOM, est, age, asv)
        assert r[0] >= fixed[0] - 1e-9
