"""The plan's integration stays finite wherever a solver's trial point may put it
(:func:`mpcasv.mpc.dynamics.water_guard`): in a strong current the OCP's box on the ground
velocities admits speeds through the water where the hull's quadratic damping overflows the
RK4 sub-steps, and fatrop hung on the Inf (docs/mpc.md, "Known problems": strong currents).
Where a boat can go, the plan is the shared model unchanged."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from mpcasv.controllers import Boat, load_preset, make_controller
from mpcasv.experiments.metrics import compute_metrics
from mpcasv.models.envelope import envelope_states
from mpcasv.mpc import dynamics
from mpcasv.mpc.dynamics import U_ABOVE, GuardBounds, water_guard
from mpcasv.mpc.problem import NXV, OCP
from mpcasv.sim.scenario import load_scenario, scenario_with
from mpcasv.sim.simulator import simulate

STRONG = (2.0, 0.0)  # m/s (N, E): along the loiter case's approach


@pytest.fixture(scope="module")
def single():
    return OCP(load_preset("mpc-single", "mpc-single"), 1, outer=True)


def _guard(bounds: GuardBounds) -> ca.Function:
    x, c = ca.SX.sym("x", NXV), ca.SX.sym("c", 2)
    return ca.Function("guard", [x, c], [water_guard(x, c, bounds)])


def test_the_guard_changes_nothing_where_a_boat_can_go(single):
    """States inside the bounds through the water (currents up to 2 m/s, any heading) come
    back with the same values, bit for bit."""
    b = single.guard
    g = _guard(b)
    rng = np.random.default_rng(3)
    for _ in range(500):
        c = rng.uniform(-1.4, 1.4, 2)
        psi = rng.uniform(-np.pi, np.pi)
        c_body = [np.cos(psi) * c[0] + np.sin(psi) * c[1], -np.sin(psi) * c[0] + np.cos(psi) * c[1]]
        c1 = abs(c[0]) + abs(c[1])
        u_r = rng.uniform(b.u_lo - c1, max(b.u_hi, c1 + U_ABOVE))
        v_r = rng.uniform(-b.v_max - c1, b.v_max + c1)
        rest = rng.uniform([-b.r_max, 0.0, -0.5], [b.r_max, 100.0, 0.5])  # r, T, delta
        x = np.r_[rng.uniform(-500, 500, 2), psi, u_r + c_body[0], v_r + c_body[1], rest]
        np.testing.assert_array_equal(np.asarray(g(x, c)).ravel(), x)


@pytest.mark.parametrize("vessel", ["gretha", "dune-otter"])
def test_a_plan_stage_through_the_vessels_manoeuvres_is_the_unguarded_one(vessel, monkeypatch):
    """Every state of the vessel's manoeuvring envelope (full-steering turns included: the
    dune-otter's reach 1.18 rad/s, beyond the OCP's 0.5), in still water and in 1 m/s (the
    same motion through the water: the current added to the velocities over the ground): the
    plan's stage is the one without the guard, the same values."""
    params = load_preset("mpc-single", "mpc-single")
    boat = Boat.load(vessel)
    guarded = OCP(params, 1, outer=True, boat=boat)
    monkeypatch.setattr(dynamics, "water_guard", lambda x, c, bounds: x)
    plain = OCP(params, 1, outer=True, boat=boat)
    X = envelope_states(guarded.model)
    for c in ((0.0, 0.0), (0.6, -0.8)):
        q = np.zeros(guarded.F.size1_in(2))
        q[0:2] = c
        for x in X[:: max(1, len(X) // 200)]:
            cs, sn = np.cos(x[2]), np.sin(x[2])
            x = x + np.r_[0, 0, 0, cs * c[0] + sn * c[1], -sn * c[0] + cs * c[1], 0, 0, 0]
            z = np.r_[x, np.zeros(guarded.F.size1_in(0) - NXV)]
            np.testing.assert_array_equal(np.asarray(guarded.F(z, [0.0, 0.0], q)),
                                          np.asarray(plain.F(z, [0.0, 0.0], q)))  # fmt: skip


def test_an_upstream_trial_point_in_a_strong_current_integrates_finite(single):
    """The box's corner in 2 m/s heading upstream (ground surge ``u_max + 0.5 + |c|``: 7 m/s
    through the water) with a yaw rate beyond the box (a trial point may leave it): the plan's
    stage is finite and its surge moves by less than 10 m/s (the blow-up criterion of
    docs/mpc.md), where the shared model's RK4 in the same sub-steps overflows."""
    hz, u_max = single.params.horizon, single.vessel.u_max
    z0 = np.zeros(single.F.size1_in(0))
    z0[[2, 3, 5, 6]] = [np.pi, u_max + 0.5 + 2.0, 1.5, 50.0]  # heading South, against
    q = np.zeros(single.F.size1_in(2))
    q[0:2] = STRONG
    plan = np.asarray(single.F(z0, [0.0, 0.0], q)).ravel()
    assert np.all(np.isfinite(plan))
    assert abs(plan[3] - z0[3]) < 10.0 and abs(plan[4] - z0[4]) < 10.0
    shared = single.model.rk4(hz.dt, single.n_sub)(z0[:NXV], z0[6:8], STRONG)
    assert not np.all(np.isfinite(np.asarray(shared)))


def test_no_solver_hang_approaching_an_auv_with_a_strong_current_known(scenarios_dir):
    """The loiter case with 2 m/s North and the true current (``current = "oracle"``): the
    plans' trial points ran into Inf and fatrop hung 17 times in 300 s from t = 29 s (session
    31); none now in the first 60 s."""
    sc = scenario_with(load_scenario(scenarios_dir / "loiter-surface.toml"), duration=60.0,
                       current=STRONG)  # fmt: skip
    ctrl = make_controller("mpc-single", 1, "mpc-single", overrides={"current": "oracle"},
                           boat=Boat.of_scenario(sc))  # fmt: skip
    m = compute_metrics(simulate(sc, ctrl, seed=0))
    assert m["solver_hangs"] == 0
    assert m["fallbacks"] == 0
