"""The MPC's first tour (eq. M9t, docs/mpc.md "Cost" M9) in closed loop: four AUVs at the
corners of a 500-m square (session 35's sweep found one of them without a reliable fix in
900 s under ``mpc-multi``). With the largest projected fix age alone the ASV crosses the
square along its diagonals, a cycle the age rule then keeps; with the first tour it goes
round it."""

from __future__ import annotations

import numpy as np
import pandas as pd

_CORNERS = [(250.0, 250.0), (250.0, -250.0), (-250.0, -250.0), (-250.0, 250.0)]


def _scenario() -> str:
    text = """
name = "square"
description = "four surface AUVs on small lawn-mowers at the corners of a 500-m square"
duration = 900.0
controller = "mpc-multi"
estimator = "perfect"

[asv.start]
N = 0.0
E = 0.0
psi_deg = 0.0
"""
    for k, (n, e) in enumerate(_CORNERS):
        text += f"""
[[auv]]
name = "auv{k + 1}"
start = {{ N = {n}, E = {e}, depth = 0.0, psi_deg = 0.0 }}
[auv.behaviour.plan]
speed = 1.0
route = [ {{ lawnmower = {{ origin = [{n}, {e}], heading_deg = 0.0, length = 60.0, spacing = 15.0, legs = 30 }} }} ]
"""  # noqa: E501
    return text


_SUITE = """
name = "first-tour"
scenarios = ["{scenario}"]
seeds = [0]
duration = 420.0
plots = "none"

[[controllers]]
label = "age"
single = "mpc-single"
multi = "mpc-multi"
preset = "default"
overrides = {{ "first_tour" = false }}

[[controllers]]
label = "tour"
single = "mpc-single"
multi = "mpc-multi"
preset = "default"
"""


def _legs(ts: pd.DataFrame) -> list[float]:
    """Distances (m) between the AUVs' areas for each change of the MPC's target."""
    targets = ts["mpc_target"].to_numpy()
    changes = [int(t) for t, s in zip(targets[1:], targets[:-1], strict=True) if t != s]
    visits = [int(targets[0]), *changes]
    c = np.array(_CORNERS)
    return [float(np.hypot(*(c[b] - c[a]))) for a, b in zip(visits, visits[1:], strict=False)]


def test_the_first_tour_goes_round_a_square_that_the_age_rule_crosses(tmp_path):
    """The first 420 s (two changes of target; the run's first target is AUV 0): the age
    rule's second target is the diagonal corner (707 m), the first tour's every leg is a
    side (500 m)."""
    from mpcasv.experiments.runner import run_suite

    scenario = tmp_path / "square.toml"
    scenario.write_text(_scenario())
    suite = tmp_path / "suite.toml"
    suite.write_text(_SUITE.format(scenario=scenario))
    out = tmp_path / "out"
    results = run_suite(suite, out, workers=1, quiet=True, report=False, job_timeout=0)[2]
    assert (results["status"] == "ok").all()
    legs = {}
    for label in ("age", "tour"):
        (run,) = (out / "runs").glob(f"square-{label}-*")
        legs[label] = _legs(pd.read_parquet(run / "timeseries.parquet"))
    assert len(legs["age"]) >= 2 and len(legs["tour"]) >= 2, legs
    assert max(legs["age"]) > 700.0, legs  # the age rule crosses the square
    assert legs["tour"] == [500.0] * len(legs["tour"]), legs  # the first tour goes round it
