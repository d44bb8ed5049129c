"""Common random numbers (mpcasv.sim.streams): two runs of one (scenario, seed) meet the same
channel noise ping for ping, whatever the ASV does. Until session 48 one generator drew ping
success and fix errors as they happened: after the first ping whose outcome differed between
the runs, every later draw was shifted (a statistician's review)."""

from __future__ import annotations

import numpy as np

from mpcasv.models.acoustics import usbl_error_map
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


def _standing_world(asv_N: float, seed: int) -> tuple[World, dict]:
    """The world with the ASV standing (propeller off) at (asv_N, 0) for 600 s, and each
    fix's standard normals (range, across, elevation: ``J^-1`` of its error, U1 of
    :func:`mpcasv.models.acoustics.usbl_error_map`) by its time."""
    w = World(scenario_from_dict(SCENARIO), seed=seed)
    w.x[0] = asv_N
    at = {}
    for _ in range(600):
        w.advance(np.zeros(4))
        at[round(w.t, 6)] = (w.x[:2].copy(), w.S[:3, 0].copy())
    z = {}
    for f in w.fixes[0]:
        asv, auv = at[round(f.t, 6)]
        J, _ = usbl_error_map(asv, auv, w.ac)
        z[f.t] = np.linalg.solve(J, np.array([f.N, f.E, f.depth]) - auv)
    return w, z


def test_a_ping_that_gets_through_far_gets_through_near_with_the_same_errors():
    """The ASV 100 m from the AUV (p = 0.6) and 400 m (p = 0.3), the same seed: every ping
    the far run got through, the near run got too (the same success uniform below both
    probabilities), and with the same three standard normals (range, across, elevation),
    each run's geometry scaling them (U1)."""
    for seed in range(3):
        (near, z_near), (far, z_far) = _standing_world(0.0, seed), _standing_world(-300.0, seed)
        t_near = {f.t: f for f in near.fixes[0]}
        t_far = {f.t: f for f in far.fixes[0]}
        assert 0.45 < len(t_near) / 600 * near.ac.T0 < 0.75  # p = 0.6 (sanity)
        assert 0.15 < len(t_far) / 600 * far.ac.T0 < 0.45  # p = 0.3
        assert set(t_far) <= set(t_near), sorted(set(t_far) - set(t_near))[:5]
        for t, f in t_far.items():
            np.testing.assert_allclose(z_far[t], z_near[t], atol=1e-6)
            assert f.slant > 400.0 > 150.0 > t_near[t].slant  # the two p apply


def test_the_streams_of_one_seed_repeat_and_other_seeds_differ():
    (a, _), (b, _) = _standing_world(0.0, 5), _standing_world(0.0, 5)
    assert [(f.t, f.N, f.E) for f in a.fixes[0]] == [(f.t, f.N, f.E) for f in b.fixes[0]]
    c, _ = _standing_world(0.0, 6)
    assert [f.t for f in a.fixes[0]] != [f.t for f in c.fixes[0]]
