"""Common random numbers (mpcasv.sim.streams): two runs of one (scenario, seed) meet the same
channel noise ping for ping, whatever the ASV does. Until session 48 one generator drew ping
success and fix errors as they happened: after the first ping whose outcome differed between
the runs, every later draw was shifted (a statistician's review)."""

from __future__ import annotations

import numpy as np

from mpcasv.sim.scenario import scenario_from_dict
from mpcasv.sim.world import World

#: a deep AUV holding station at (100, 0); p = 0.6 within 150 m, 0.3 to 450 m
SCENARIO = {
    "name": "crn", "duration": 600.0,
    "acoustics": {"p_good": 0.6, "p_sporadic": 0.3, "d1": 150.0, "d2": 450.0},
    "auv": [{"name": "a", "start": {"N": 100.0, "depth": 30.0},
             "behaviour": {"plan": {"speed": 1.0, "route": [
                 {"waypoints": [[100.0, 0.0, 30.0]]}]}}}],
}  # fmt: skip


def _standing_world(asv_N: float, seed: int) -> World:
    """The world with the ASV standing (propeller off) at (asv_N, 0) for 600 s."""
    w = World(scenario_from_dict(SCENARIO), seed=seed)
    w.x[0] = asv_N
    for _ in range(600):
        w.advance(np.zeros(4))
    return w


def test_a_ping_that_gets_through_far_gets_through_near_with_the_same_errors():
    """The ASV 100 m from the AUV (p = 0.6) and 400 m (p = 0.3), the same seed: every ping
    the far run got through, the near run got too (the same success uniform below both
    probabilities), and with the same standard errors (the depth's, sigma_range x z, does
    not depend on the geometry)."""
    for seed in range(3):
        near, far = _standing_world(0.0, seed), _standing_world(-300.0, seed)
        t_near = {f.t: f for f in near.fixes[0]}
        t_far = {f.t: f for f in far.fixes[0]}
        assert 0.45 < len(t_near) / 600 * near.ac.T0 < 0.75  # p = 0.6 (sanity)
        assert 0.15 < len(t_far) / 600 * far.ac.T0 < 0.45  # p = 0.3
        assert set(t_far) <= set(t_near), sorted(set(t_far) - set(t_near))[:5]
        true_depth = 30.0
        for t, f in t_far.items():
            assert f.depth - true_depth == t_near[t].depth - true_depth
            assert f.slant > 400.0 > 150.0 > t_near[t].slant  # the two p apply


def test_the_streams_of_one_seed_repeat_and_other_seeds_differ():
    a, b = _standing_world(0.0, 5), _standing_world(0.0, 5)
    assert [(f.t, f.N, f.E) for f in a.fixes[0]] == [(f.t, f.N, f.E) for f in b.fixes[0]]
    c = _standing_world(0.0, 6)
    assert [f.t for f in a.fixes[0]] != [f.t for f in c.fixes[0]]
