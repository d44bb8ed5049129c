"""A new user's findings (session 43) with their own scenarios and presets: an absurd transit
speed run as the vessel's top speed without a word, a bad ``--params`` blamed on the scenario,
and standby invisible in paths.png. (The target domain beyond r_out: tests/test_domains.py;
the report's unit, the world: tests/test_report_worlds.py.)"""

from __future__ import annotations

from pathlib import Path

import matplotlib.colors as mcolors
import numpy as np
import pytest

from mpcasv.cli import main
from mpcasv.config import TRANSIT_SPEED_MAX, ConfigError
from mpcasv.controllers import make_controller
from mpcasv.controllers.registry import load_preset
from mpcasv.sim.scenario import scenario_from_dict
from mpcasv.sim.simulator import simulate

ROOT = Path(__file__).resolve().parents[1]
CASE3 = ROOT / "experiments" / "scenarios" / "case3.toml"
SHIPPED = {"hybrid-single": "paper1-field", "hybrid-multi": "paper2-field",
           "mpc-single": "mpc-single", "mpc-multi": "mpc-multi", "goto": "goto"}  # fmt: skip


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_a_transit_speed_beyond_any_asv_is_refused(name):
    # 25 m/s in a preset ran exactly as 2.5 m/s (the execution level's cap at u_max)
    with pytest.raises(ConfigError, match=r"speed: 25 m/s is outside the allowed range"):
        load_preset(name, SHIPPED[name], {"speed": 25.0})
    assert load_preset(name, SHIPPED[name], {"speed": TRANSIT_SPEED_MAX}).speed == 10.0


def test_a_bad_params_is_blamed_on_params_not_on_the_scenario(capsys, tmp_path):
    assert main(["simulate", str(CASE3), "--params", "nope", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    # before: "case3.toml (controller from this scenario): unknown preset 'nope'"
    assert "(controller 'hybrid-single' from this scenario, preset from --params)" in err
    assert "unknown preset 'nope'" in err


def test_standby_shows_in_the_paths_figure_in_its_own_colour():
    import matplotlib.pyplot as plt

    from mpcasv.sim.plots import paths_figure

    sc = scenario_from_dict({
        "name": "sb", "duration": 120.0, "estimator": "perfect",
        "auv": [{"name": "a", "start": {"N": 60.0, "depth": 20.0},
                 "behaviour": {"plan": {"speed": 0.5, "route": [
                     {"waypoints": [[80.0, 0.0, 20.0]]}]}}}]})  # fmt: skip
    res = simulate(sc, make_controller("goto", 1, None, overrides={"waypoint": [-40.0, 0.0]}), 0)
    sb = (res.timeseries["mode"] == "standby").to_numpy()
    assert sb.any() and not sb.all()  # goes, then stands by at its waypoint
    fig = paths_figure(res)
    try:
        lines = {ln.get_label(): ln for ln in fig.axes[0].get_lines()}
        asv, stand = lines["ASV"], lines["ASV in standby (propeller off)"]
        assert mcolors.to_hex(stand.get_color()) != mcolors.to_hex(asv.get_color())
        assert stand.get_markersize() >= 4 and stand.get_linewidth() >= 4
        # drawn exactly where (and only where) the ASV stood by
        x = np.asarray(stand.get_xdata(), float)
        assert np.array_equal(np.isfinite(x), sb)
        assert np.allclose(x[sb], res.timeseries["E"].to_numpy()[sb])
    finally:
        plt.close(fig)
