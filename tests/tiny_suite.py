"""A tiny suite for the tests of sweeps (Dask, a closed stdout): Case 3 cut to 15 s, the
hybrid controller, no figures."""

from __future__ import annotations

from mpcasv.experiments.suite_file import SCENARIOS_DIR


def tiny_suite(seeds: tuple[int, ...] = (0, 1, 2)) -> str:
    """The suite file's text: one job per seed."""
    return f"""
name = "tiny"
scenarios = ["{SCENARIOS_DIR / "case3.toml"}"]
duration = 15.0
seeds = [{", ".join(map(str, seeds))}]
current = ["off"]
estimator = ["scenario"]
plots = "none"

[[controllers]]
label = "hybrid"
name = "hybrid-single"
preset = "scenario"
"""
