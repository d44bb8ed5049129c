"""Issue 16 item 2: the visiting order (mpcasv/mpc/order.py; opt-in ``target_rule = "order"``,
preset mpc-multi-order; docs/mpc.md "Visiting order"), ported from the session-4 branch
``mpcorder``.

Hand-built geometries; the navigation laws the order values are checked against the AUVs'
own filter (:class:`~mpcasv.models.auv_nav.AUVNavFilter`), not against a copy of its
equations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mpcasv.models.acoustics import AcousticParams, NavParams
from mpcasv.models.auv_nav import (
    AUVNavFilter,
    dr_variance,
    dr_variance_integral,
    fix_posterior_variance,
    fix_variance,
)
from mpcasv.mpc.order import (
    OrderModel,
    best_order,
    committed_target,
    meet_time,
    order_cost,
    transit_cost,
)
from mpcasv.mpc.params import WeightParams
from mpcasv.sim.streams import ins_draws

AC = AcousticParams()
EPS_A = NavParams().eps_a
MODEL = OrderModel(eps_a=EPS_A, sigma_range=AC.sigma_range,
                   sigma_bearing=math.radians(AC.sigma_bearing_deg), U=2.5, T_stay=30.0,
                   window=600.0, nav=1.0, V_ref=dr_variance(EPS_A, 100.0), e_go=0.1)  # fmt: skip


def still(N, E):
    """Forecast of an AUV standing at (N, E)."""
    return lambda dt: np.tile([N, E], (len(np.atleast_1d(dt)), 1)).astype(float)


def moving(N, E, vN, vE):
    return lambda dt: np.array([N, E]) + np.atleast_1d(dt)[:, None] * np.array([vN, vE])


# ----------------------------------------------------------------------- navigation laws
def test_variance_grows_as_half_eps_a_t_squared_like_the_auv_filter():
    """dr_variance is the filter's own growth (N2): RMS radius 1/2 eps_a t^2 (thesis eq.
    2.7), the value AUVNavFilter reports without aiding; its integral is the integral."""
    f = AUVNavFilter(1, NavParams(), ins_draws(np.random.default_rng(0)))
    for t in (10.0, 60.0, 300.0):
        # per-axis variance eps_a^2 / 8 t^4: the filter's sigma (largest eigenvalue's root) and
        # the horizontal radius sqrt(2 V) = 1/2 eps_a t^2
        assert f.sigma(t)[0] == pytest.approx(math.sqrt(dr_variance(EPS_A, t)), rel=1e-12)
        assert math.sqrt(2 * dr_variance(EPS_A, t)) == pytest.approx(0.5 * EPS_A * t**2)
    s = np.linspace(30.0, 250.0, 20001)
    v = dr_variance(EPS_A, s)
    trapezoid = float(np.sum((v[1:] + v[:-1]) / 2 * np.diff(s)))
    assert dr_variance_integral(EPS_A, 30.0, 250.0) == pytest.approx(trapezoid, rel=1e-6)


def test_fix_posterior_is_the_filters_update_and_a_near_fix_removes_more():
    """fix_posterior_variance equals the mean per-axis variance AUVNavFilter.update leaves
    (isotropic prior, the fix's covariance at that slant range); a fix at 70 m removes more
    of the variance than one at 400 m."""
    t = 120.0
    post = {}
    for slant in (70.0, 400.0):
        f = AUVNavFilter(1, NavParams(), ins_draws(np.random.default_rng(1)))
        R_los, R_perp = fix_variance(slant, AC.sigma_range, math.radians(AC.sigma_bearing_deg))
        f.update(0, t, np.zeros(2), np.diag([R_los, R_perp]), ins_draws(np.random.default_rng(2)))
        mean_axis = float(np.trace(f.P_u[0])) / 2
        post[slant] = fix_posterior_variance(dr_variance(EPS_A, t), R_los, R_perp)
        assert post[slant] == pytest.approx(mean_axis, rel=1e-9)
    assert post[70.0] < post[400.0] < dr_variance(EPS_A, t)


# ----------------------------------------------------------------------- visiting order
def test_meet_time_of_an_auv_coming_towards_the_asv_is_shorter():
    s_still = meet_time(np.zeros(2), still(300.0, 0.0), 70.0, 2.5)
    s_coming = meet_time(np.zeros(2), moving(300.0, 0.0, -1.5, 0.0), 70.0, 2.5)
    assert s_still == pytest.approx(230.0 / 2.5)
    assert s_coming == pytest.approx(230.0 / 4.0, rel=1e-3)


def test_one_auv_never_visited_costs_its_whole_growth_plus_the_transit():
    """An AUV beyond reach within the window (an AUV at 2 km, 600 s at 2.5 m/s reaches
    1.5 km): J is its variance integral over the window plus e_go for all of it (O1)."""
    tau = np.array([50.0])
    J, arrive = order_cost((0,), np.zeros(2), [still(2000.0, 0.0)], np.zeros(1), tau,
                           np.full(1, 70.0), MODEL)  # fmt: skip
    nav = dr_variance_integral(EPS_A, 50.0, 650.0) / MODEL.V_ref
    assert J == pytest.approx(nav + MODEL.e_go * 600.0)
    assert arrive[0] == math.inf


def test_the_oldest_auv_is_visited_first():
    """Two AUVs at the same distance on either side; AUV 1's variance grows fastest (it has
    gone longest without a fix): it comes first. Swap the ages: the order swaps."""
    fc = [still(250.0, 0.0), still(-250.0, 0.0)]
    depth, r_t = np.zeros(2), np.full(2, 70.0)
    plan = best_order(np.zeros(2), fc, depth, np.array([40.0, 200.0]), r_t, MODEL)
    assert plan.order == (1, 0)
    plan = best_order(np.zeros(2), fc, depth, np.array([200.0, 40.0]), r_t, MODEL)
    assert plan.order == (0, 1)


def test_the_near_one_first_when_ages_are_equal_and_three_auvs_enumerated():
    """Three AUVs of equal age in a line at 150, 450 and 750 m: visit them nearest first
    (the other five orders go back and forth); all 6 orders are valued."""
    fc = [still(450.0, 0.0), still(750.0, 0.0), still(150.0, 0.0)]
    plan = best_order(np.zeros(2), fc, np.zeros(3), np.full(3, 120.0), np.full(3, 70.0), MODEL)
    assert plan.order == (2, 0, 1)
    assert len(plan.costs) == 6
    assert np.all(np.diff(plan.arrive[list(plan.order)]) > 0)


def test_oldest_but_far_waits_for_an_old_one_on_the_way():
    """AUV 0 is older (200 s) but 600 m away; AUV 1 (150 s) lies half-way: visiting 1 on the
    way costs less than going past it (the age rule would head for AUV 0)."""
    fc = [still(600.0, 0.0), still(300.0, 0.0)]
    plan = best_order(np.zeros(2), fc, np.zeros(2), np.array([200.0, 150.0]),
                      np.full(2, 70.0), MODEL)  # fmt: skip
    assert plan.order == (1, 0)


def test_commitment_keeps_the_target_unless_clearly_cheaper():
    fc = [still(250.0, 0.0), still(-250.0, 0.0)]
    plan = best_order(np.zeros(2), fc, np.zeros(2), np.array([100.0, 101.0]),
                      np.full(2, 70.0), MODEL)  # fmt: skip
    assert committed_target(plan, plan.order[1], 0.02) == plan.order[1]  # nearly equal: stays
    assert committed_target(plan, plan.order[1], 0.0) == plan.order[0]  # no hysteresis: moves
    plan = best_order(np.zeros(2), fc, np.zeros(2), np.array([40.0, 250.0]),
                      np.full(2, 70.0), MODEL)  # fmt: skip
    assert committed_target(plan, 0, 0.02) == 1  # far cheaper: switches


def test_a_served_target_is_left_for_the_cheapest_order_that_starts_elsewhere():
    """Session 16: the re-plan after the target was served does not stay with it (which
    would commit to it anew, for another whole visit), whatever the band; with one AUV
    there is nowhere else to go."""
    fc = [still(250.0, 0.0), still(-250.0, 0.0), still(0.0, 300.0)]
    plan = best_order(np.zeros(2), fc, np.zeros(3), np.array([0.0, 100.0, 101.0]),
                      np.full(3, 70.0), MODEL)  # fmt: skip
    elsewhere = min((o for o in plan.costs if o[0] != 0), key=plan.costs.__getitem__)
    assert committed_target(plan, 0, 10.0) == 0  # not served: a wide band keeps it
    assert committed_target(plan, 0, 10.0, served=True) == elsewhere[0] != 0
    one = best_order(np.zeros(2), fc[:1], np.zeros(1), np.zeros(1), np.full(1, 70.0), MODEL)
    assert committed_target(one, 0, 0.02, served=True) == 0


def test_more_than_four_auvs_refused():
    fc = [still(100.0 * k, 0.0) for k in range(5)]
    with pytest.raises(ValueError, match="at most 4"):
        best_order(np.zeros(2), fc, np.zeros(5), np.zeros(5), np.full(5, 70.0), MODEL)


def test_transit_cost_is_the_energy_terms_at_the_transit_thrust():
    """e_go: thrust, power and running weights of eq. M4 at the thrust holding U_go, the
    thrust capped at T_max."""
    wt = WeightParams(thrust=0.05, power=0.05, running=0.1, U_go=2.5)
    assert transit_cost(wt, 50.0, 100.0, 5.0) == pytest.approx(0.05 * 0.5 + 0.05 * 0.25 + 0.1)
    assert transit_cost(wt, 150.0, 100.0, 5.0) == transit_cost(wt, 100.0, 100.0, 5.0)
