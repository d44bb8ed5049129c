"""Simulator speed: wall time of one simulated hour with the trivial controller."""

from __future__ import annotations

import time

import numpy as np


def bench_sim(args) -> dict:
    from mpcasv.config import DATA_DIR  # noqa: F401  (package data present)
    from mpcasv.controllers import make_controller
    from mpcasv.sim.scenario import scenario_from_dict
    from mpcasv.sim.simulator import build_plant, simulate

    scenario = scenario_from_dict({
        "name": "bench-hour", "duration": 3600.0,
        "auv": [{"name": "auv", "start": {"depth": 20.0},
                 "behaviour": {"plan": {"speed": 1.5, "route": [{"lawnmower": {
                     "origin": [0.0, 0.0], "length": 400.0, "spacing": 50.0, "legs": 12,
                     "depth": 20.0}}]}}}],
    }, "bench")  # fmt: skip
    t0 = time.perf_counter()
    build_plant(scenario)
    build_s = time.perf_counter() - t0
    walls = []
    for _ in range(max(1, args.repeat)):
        ctrl = make_controller("goto", 1, "goto")
        t0 = time.perf_counter()
        simulate(scenario, ctrl, seed=0)
        walls.append(time.perf_counter() - t0)
    best, med = float(np.min(walls)), float(np.median(walls))
    print("one simulated hour, trivial controller, 1 AUV, dt = 0.1 s, control period 1 s")
    print(f"  model + execution level build (once per process): {build_s:.3f} s")
    print(f"  wall time per simulated hour: best {best:.3f} s, median {med:.3f} s "
          f"over {len(walls)} runs  (real-time factor {3600 / best:.0f}x)")  # fmt: skip
    return {"build_s": build_s, "wall_s_best": best, "wall_s_median": med,
            "realtime_factor": 3600 / best}  # fmt: skip
