"""Session 17 (a helper's sweep of new scenarios): with two AUVs loitering 60 m apart in a
0.25 m/s current, ``mpc-multi`` stood by at its target's circle while the current carried it
into the other AUV's collision domain, and stayed there 104 s, its plan's cost growing step
after step: the exploration that finds a way off a plan stuck at rest looked only at the
target AUV's radius and at the ASV held where it is (no drift), and an exploration that
stopped at its iteration limit far cheaper was dropped when it ran inside the step."""

from __future__ import annotations

from pathlib import Path

from mpcasv.controllers import Boat, make_controller
from mpcasv.experiments.metrics import compute_metrics
from mpcasv.sim.scenario import load_scenario
from mpcasv.sim.simulator import simulate

SCENARIO = """
name = "overlap"
duration = 300.0
controller = "mpc-multi"
preset = "mpc-multi"
current = [0.0, 0.25]

[asv.start]
N = -200.0
E = 0.0

[[auv]]
name = "west"
start = { N = 0.0, E = -30.0, depth = 0.0 }
[auv.behaviour.loiter]
speed = 0.5

[[auv]]
name = "east"
start = { N = 0.0, E = 30.0, depth = 0.0 }
[auv.behaviour.loiter]
speed = 0.5
"""


def test_a_standby_drifting_into_another_auvs_domain_leaves_it(tmp_path: Path):
    path = tmp_path / "overlap.toml"
    path.write_text(SCENARIO)
    sc = load_scenario(path)
    ctrl = make_controller("mpc-multi", 2, "mpc-multi", boat=Boat.of_scenario(sc))
    m = compute_metrics(simulate(sc, ctrl, seed=0))
    # before: 104 s in one stay (t = 136-241 s), at rest; the hybrid controller's longest
    # stay on this scenario is 19 s
    longest = m["collision_domain_longest_s"]
    assert longest < 30.0, (longest, m["solver_hangs"])
