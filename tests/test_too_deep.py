"""An AUV too deep for the evaluation domain leaves no target domain inside the donut
(r_outer <= r_t - eps_minus; r_outer = 0 below the outer sphere, Paper 1 eqs. 3-5, 10). A
helper's sweep (session 35) ran one at 350 m against paper1-field's 200-m sphere: hybrid-single
ran its propeller for the whole run and no one was told why. `mpcasv simulate` now names the
AUV and the time. A review found the band above r_out where r_outer > 0 is still too small
(paper1-sim, 290 m: r_outer 73 m against r_t - eps_minus = 95 m)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mpcasv.cli import main

SCENARIO = """
name = "deep"
duration = {duration}
controller = "hybrid-single"
preset = "{preset}"
estimator = "perfect"

[asv.start]
N = -100.0
E = 0.0

[[auv]]
name = "deep-one"
start = {{ N = 0.0, E = 0.0, depth = {depth} }}
[auv.behaviour.loiter]
"""


@pytest.mark.parametrize("preset,depth,duration,said", [
    ("paper1-field", 350.0, 12.0, "12 s"), ("paper1-field", 30.0, 12.0, None),
    ("paper1-sim", 290.0, 12.0, "12 s"), ("paper1-sim", 250.0, 12.0, None),
    ("paper1-field", 350.0, 1.0, "1 s"),  # one period: one row
])  # fmt: skip
def test_simulate_names_an_auv_too_deep_for_the_domain(tmp_path: Path, capsys, preset, depth,
                                                       duration, said):  # fmt: skip
    path = tmp_path / "deep.toml"
    path.write_text(SCENARIO.format(depth=depth, preset=preset, duration=duration))
    rc = main(["simulate", str(path), "--out", str(tmp_path / "run"), "--no-plots", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0
    line = [s for s in out.splitlines() if "too deep" in s]
    if said is None:
        assert line == []
        return
    r_out = {"paper1-field": 200, "paper1-sim": 299}[preset]
    assert line == [f"  AUV 'deep-one': too deep for the evaluation domain for {said} (r_outer "
                    "<= r_t - eps_minus: no target domain inside the donut; r_out = "
                    f"{r_out} m): hybrid-single with this domain does not stand by there; "
                    "docs/metrics.md"]
