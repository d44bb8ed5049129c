"""An AUV deeper than the evaluation domain's outer sphere has no donut on the surface
(r_outer = 0, Paper 1 eq. 5). A helper's sweep (session 35) ran one at 350 m against
paper1-field's 200-m sphere: hybrid-single ran its propeller for the whole run and no one was
told why. `mpcasv simulate` now names the AUV and the time."""

from __future__ import annotations

from pathlib import Path

import pytest

from mpcasv.cli import main

SCENARIO = """
name = "deep"
duration = 12.0
controller = "hybrid-single"
preset = "paper1-field"
estimator = "perfect"

[asv.start]
N = -100.0
E = 0.0

[[auv]]
name = "deep-one"
start = {{ N = 0.0, E = 0.0, depth = {depth} }}
[auv.behaviour.loiter]
"""


@pytest.mark.parametrize("depth,said", [(350.0, True), (30.0, False)])
def test_simulate_names_an_auv_too_deep_for_the_donut(tmp_path: Path, capsys, depth, said):
    path = tmp_path / "deep.toml"
    path.write_text(SCENARIO.format(depth=depth))
    rc = main(["simulate", str(path), "--out", str(tmp_path / "run"), "--no-plots", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0
    line = [s for s in out.splitlines() if "deeper than the outer sphere" in s]
    if said:  # the whole run: 12 periods of 1 s
        assert line == ["  AUV 'deep-one': deeper than the outer sphere (r_out = 200 m) for 12 s: "
                        "no donut there (r_outer = 0, Paper 1 eq. 5), so no standby by the "
                        "hybrid controllers; docs/metrics.md"]
    else:
        assert line == []
