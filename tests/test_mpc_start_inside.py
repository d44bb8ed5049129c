"""An ASV that starts inside a surfaced AUV's anti-collision radius (a new user's scenario,
session 43): the MPC's first plan converged to rest there (at rest the rudder has no
authority: a local minimum), its exploration found the way out but stopped at its iteration
limit, and the ASV stood by for a whole step inside the domain while the hybrid controller
left at once. Now the escape manoeuvre is commanded that step, and the next solve starts from
it."""

from __future__ import annotations

import pytest

from mpcasv.controllers import Boat, make_controller
from mpcasv.sim.scenario import load_scenario
from mpcasv.sim.simulator import simulate

NEAR = """
name = "near"
description = "a surfaced AUV 5 m ahead of the ASV at the start, crossing; current 0.3 m/s SW"
duration = {duration}
estimator = "perfect"
current = [-0.212, -0.212]

[asv.start]
N = 0.0
E = 0.0
psi_deg = 0.0

[[auv]]
name = "near"
start = {{ N = 5.0, E = 0.0, depth = 0.0, psi_deg = 90.0 }}
[auv.behaviour.plan]
speed = 1.5
[[auv.behaviour.plan.route]]
lawnmower = {{ origin = [5.0, 0.0], heading_deg = 90.0, length = 150.0, spacing = 15.0, legs = 6 }}
{far}"""

FAR = """
[[auv]]
name = "far"
start = { N = -200.0, E = 150.0, depth = 20.0, psi_deg = 0.0 }
[auv.behaviour.plan]
speed = 1.5
[[auv.behaviour.plan.route]]
[auv.behaviour.plan.route.lawnmower]
origin = [-200.0, 150.0]
heading_deg = 0.0
length = 150.0
spacing = 15.0
legs = 6
depth = 20.0
"""


@pytest.mark.parametrize("name", ["mpc-single", "mpc-multi"])
def test_an_asv_started_inside_a_domain_leaves_from_the_first_step(name, tmp_path):
    path = tmp_path / "near.toml"
    path.write_text(NEAR.format(duration=40.0, far=FAR if name == "mpc-multi" else ""))
    sc = load_scenario(path)
    ctrl = make_controller(name, len(sc.auv), name, boat=Boat.of_scenario(sc))
    ts = simulate(sc, ctrl, seed=0).timeseries
    first = ts.iloc[0]
    assert first["mode"] == "transit" and first["thrust"] > 100.0, ts.head(3)
    assert first["mpc_source"] == "escape" and first["mpc_fallback"] == 0
    assert (ts["mpc_fallback"] == 0).all()
    # out of the way: the range opens past 10 m within 10 s (the boat turns away first;
    # before the change too: 14.37 m at 10 s either way, the thrust ramps up the same)
    r = ts.set_index("t")["range0"]
    assert r.loc[10.0] > 10.0 and r.loc[40.0] > r.loc[10.0]
