"""Issue 16 item 1 (in part): the plan sees each AUV's depth over the horizon, and with it the
depth-dependent radii (an AUV rising under the ASV grows its collision domain from 0 below
r_in to r_in at the surface); the fix-rate model uses the run's acoustic channel."""

from __future__ import annotations

import numpy as np
import pytest

from mpcasv.controllers import Boat, make_controller
from mpcasv.interface import ASVState, AUVEstimate, Observation
from mpcasv.mpc.problem import channel_vector
from mpcasv.mpc.smooth import sigmoid
from mpcasv.sim.scenario import load_scenario, scenario_with
from mpcasv.sim.simulator import simulate

RISING = """
name = "rising"
description = "AUV at 60 m rising at 0.5 m/s to the surface, 25 m beside a standing-by ASV"
duration = 200.0
estimator = "perfect"

[asv.start]
N = 0.0
E = 25.0
psi_deg = 0.0

[[auv]]
name = "auv"
start = { N = 0.0, E = 0.0, depth = 60.0, psi_deg = 0.0, speed = 0.2 }
[auv.behaviour.transit]
heading_deg = 0.0
speed = 0.2
depth = 0.0
"""


def test_an_auv_rising_under_a_standing_by_asv_is_left_before_its_domain_reaches_it(tmp_path):
    """The AUV climbs from 60 m at 0.5 m/s, 25 m beside the ASV: r_inner(d) grows from 0 (at
    50 m depth) to 50 m at the surface and passes the ASV at about 43 m depth (t = 34 s).
    Before issue 16 (constant depth over the horizon, and an exploration guess that counted
    'inside the target circle' as 'there') the MPC stood by inside r_inner for 166 of the
    200 s. Now it must be inside for no longer than the escape time r_in / u_max (20 s);
    with the depth forecast it leaves before the domain reaches it (measured: never inside,
    smallest margin 8.9 m; with the depth held constant 6 s inside)."""
    path = tmp_path / "rising.toml"
    path.write_text(RISING)
    sc = load_scenario(path)
    ctrl = make_controller("mpc-single", 1, "mpc-single", boat=Boat.of_scenario(sc))
    ts = simulate(sc, ctrl, seed=0).timeseries
    r_inner = np.asarray(ctrl.domain.inner(ts["auv0_depth"].to_numpy()), float)
    inside = ts["range0"].to_numpy() < r_inner  # true range and r_inner at the true depth
    escape = ctrl.domain.r_in / ctrl.ocp.vessel.u_max
    assert ts["auv0_depth"].iloc[-1] < 1.0 and r_inner.max() == pytest.approx(50.0)
    assert inside.sum() * sc.sim.control_period <= escape
    assert not inside.any(), f"inside r_inner at t = {list(ts['t'].to_numpy()[inside])}"
    assert (ts["mode"] == "transit").any()


def test_the_plan_forecasts_depth_and_the_radii_grow_over_the_horizon():
    ctrl = make_controller("mpc-single", 1, "mpc-single")
    ctrl.reset(1)
    for k, depth in enumerate((60.0, 59.5, 59.0)):  # climbing at 0.5 m/s
        obs = Observation(float(k), ASVState(0.0, 25.0, 0.0), False,
                          (AUVEstimate(0.0, 0.0, depth),))  # fmt: skip
        ctrl._track_depth(obs)
    assert ctrl.w_depth[0] == pytest.approx(-0.5)
    par = ctrl.ocp.unpack_par(ctrl.parameters(obs))
    ts = ctrl.ocp.dt * np.arange(ctrl.ocp.dims.N + 1)
    np.testing.assert_allclose(par["depth"][:, 0], np.maximum(59.0 - 0.5 * ts, 0.0))
    r_inner = np.asarray(ctrl.domain.inner(par["depth"][:, 0]), float)
    np.testing.assert_allclose(par["r_lo"][:, 0], r_inner + ctrl.params.margin)
    assert par["r_lo"][0, 0] == pytest.approx(ctrl.params.margin)  # 59 m: below r_in
    assert par["r_lo"][-1, 0] > 40.0  # 29 m at the horizon's end: r_inner 40.7 m
    # an AUV that levels off: the held estimate brings the vertical speed back to 0
    for k in range(3, 8):
        ctrl._track_depth(Observation(float(k), obs.asv, False, (AUVEstimate(0.0, 0.0, 59.0),)))
    assert ctrl.w_depth[0] == 0.0


@pytest.mark.parametrize("kind", ["uncertainty", "reachable"])
def test_each_stages_radius_is_the_domain_then_along_the_previous_plan(kind):
    """With a growing domain (kinds ``uncertainty``, ``reachable``) stage k's radius is the
    domain ``t_k`` ahead at the forecast depth, along the bearing to the previous plan's stage-k
    position: the horizon computed at once equals one ``estimate_shape`` per stage."""
    import dataclasses

    from mpcasv.hybrid.avoidance import estimate_shape

    ctrl = make_controller("mpc-multi", 2, "mpc-multi", overrides={"avoidance.kind": kind})
    ctrl.reset(2)
    auvs = (AUVEstimate(40.0, -30.0, 12.0, 0.8, 0.4, (4.0, 0.0, 0.0, 4.0), 3.0),
            AUVEstimate(-60.0, 90.0, 3.0, -0.5, 1.1, (1.0, 0.0, 0.0, 1.0), 8.0))  # fmt: skip
    obs = Observation(10.0, ASVState(0.0, 0.0, 0.3, 1.2), True, auvs)
    ocp = ctrl.ocp
    ts = ocp.t_stage
    Z = np.zeros((ocp.dims.N + 1, ocp.dims.nx))  # a previous plan heading north-east
    Z[:, 0], Z[:, 1] = 1.0 * ts, 0.7 * ts
    ctrl.w_prev = ocp.join(Z, np.zeros((ocp.dims.N, ocp.dims.nu)))
    ctrl.w_depth[:] = (-0.4, 0.0)  # AUV 0 rising
    par = ocp.unpack_par(ctrl.parameters(obs))
    depth = ctrl.depth_forecast(obs, ts)
    for k, t in enumerate(ts):
        stage = [dataclasses.replace(a, depth=float(d)) for a, d in zip(auvs, depth[k],
                                                                           strict=True)]
        shape = estimate_shape(ctrl.params.avoidance, ctrl.domain, stage, obs.t, float(t))
        rel = Z[k, 0:2] - shape.center
        r = shape.radius(np.arctan2(rel[:, 1], rel[:, 0]))
        np.testing.assert_allclose(par["r_lo"][k], r + ctrl.params.margin, rtol=0, atol=1e-12)


def test_the_fix_rate_model_uses_the_scenarios_acoustic_channel(scenarios_dir):
    """Case 5 has no USBL, only status reports every 30 s: the plan's fix rate is 1 / 30 s
    times the success probability, not the default channel's 1 / 5 s."""
    sc = load_scenario(scenarios_dir / "case5.toml")
    assert not sc.acoustics.usbl and sc.acoustics.T_report == 30.0
    ctrl = make_controller("mpc-single", 1, "mpc-single", boat=Boat.of_scenario(sc))
    ctrl.reset(1)
    obs = Observation(0.0, ASVState(0.0, 0.0, 0.0), False, (AUVEstimate(80.0, 0.0, 20.0),))
    par = ctrl.ocp.unpack_par(ctrl.parameters(obs))
    np.testing.assert_allclose(par["channel"], channel_vector(sc.acoustics))
    assert par["channel"][0] == pytest.approx(1 / 30.0)
    # the smooth thrust factor of eq. M3 at zero thrust: sig(T_quiet / w_T) (0.97)
    quiet = float(sigmoid(ctrl.ocp.T_quiet / ctrl.ocp.w_T))
    rate = ctrl._rates(obs)[0]
    assert rate == pytest.approx(sc.acoustics.p_good / 30.0 * quiet, rel=1e-3)
    default = make_controller("mpc-single", 1, "mpc-single")
    default.reset(1)
    assert default._rates(obs)[0] == pytest.approx(sc.acoustics.p_good / 5.0 * quiet, rel=1e-3)
    # with the propeller on: no fix counts (presets), or the channel's propeller factor scales
    # the success (noisy_fixes)
    loud = Observation(0.0, obs.asv, True, obs.auvs)
    assert default._rates(loud)[0] < 1e-3 * default._rates(obs)[0]
    noisy = make_controller("mpc-single", 1, "mpc-single", {"fix.noisy_fixes": True})
    noisy.reset(1)
    assert noisy._rates(loud)[0] == pytest.approx(
        sc.acoustics.propeller_factor * sc.acoustics.p_good / 5.0, rel=0.02)  # fmt: skip
    # the boat's channel reaches the controller through the registry (scenario_with keeps it)
    sc2 = scenario_with(sc, duration=10.0)
    assert Boat.of_scenario(sc2).acoustics == sc.acoustics
