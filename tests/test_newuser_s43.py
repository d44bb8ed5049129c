"""A new user's findings (session 43) with their own scenarios and presets: an absurd transit
speed run as the vessel's top speed without a word, a bad ``--params`` blamed on the scenario,
and standby invisible in paths.png. (The target domain beyond r_out: tests/test_domains.py;
the report's unit, the world: tests/test_report_worlds.py.)"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

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

    from mpcasv.sim.plots import AUV_COLOURS, paths_figure

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
        # its own colour: not the ASV's, nor any AUV's (green, first tried, was AUV 2's)
        taken = {mcolors.to_hex(c) for c in (asv.get_color(), *AUV_COLOURS)}
        assert mcolors.to_hex(stand.get_color()) not in taken
        assert stand.get_markersize() >= 4 and stand.get_linewidth() >= 4
        # drawn exactly where (and only where) the ASV stood by
        x = np.asarray(stand.get_xdata(), float)
        assert np.array_equal(np.isfinite(x), sb)
        assert np.allclose(x[sb], res.timeseries["E"].to_numpy()[sb])
    finally:
        plt.close(fig)


def test_a_steering_limit_in_degrees_is_refused_in_one_line(tmp_path, capsys):
    # delta_max = 30 (degrees given as radians): `tune yaw` ended in a 37-line traceback and
    # `deploy --prepare` accepted the file
    gretha = (ROOT / "mpcasv" / "data" / "vessels" / "gretha.toml").read_text()
    for field, value in (("delta_max", "30.0"), ("delta_rate_max", "30.0")):
        bad = tmp_path / f"{field}.toml"
        bad.write_text(gretha.replace(f"\n{field} = 0.523599\n", f"\n{field} = {value}\n"))
        assert main(["tune", "yaw", "--vessel", str(bad), "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{field}: 30 rad" in err[0], err
        assert "radians, not degrees" in err[0]


def test_an_existing_file_that_is_not_toml_is_not_called_missing(tmp_path):
    from mpcasv.config import resolve

    png = tmp_path / "pic.png"
    png.write_bytes(b"\x89PNG\r\n")
    with pytest.raises(ConfigError, match=r"pic.png': not a vessel file \(a vessel is a "
                                          r"\.toml file"):  # it said "no such file"
        resolve("vessels", str(png))
    with pytest.raises(ConfigError, match="no such file"):
        resolve("vessels", str(tmp_path / "missing.png"))


def test_tuning_another_vessel_on_gretha_s_base_says_so(tmp_path, capsys, monkeypatch):
    # `tune speed --vessel dune-otter` wrote "Execution level of Gretha" with Gretha's yaw
    # schedule and checked its turns with it, without a word
    from mpcasv.control import tune_cli

    def write(*args, **kwargs):  # the design's end: the warning comes after it
        raise RuntimeError("stopped at the writing")

    monkeypatch.setattr(tune_cli, "_write_if_pass", write)
    with pytest.raises(RuntimeError, match="stopped at the writing"):
        main(["tune", "yaw", "--vessel", "dune-otter", "--speeds", "1", "--quiet", "--out",
              str(tmp_path / "o")])  # fmt: skip
    assert capsys.readouterr().err == ""  # not before the design (nor before a refusal)
    monkeypatch.undo()
    args = SimpleNamespace(base="gretha", vessel="dune-otter")
    tune_cli._warn_base(args, SimpleNamespace(params=SimpleNamespace(name="dune-otter")),
                        "yaw", tmp_path / "x.toml")  # fmt: skip
    err = capsys.readouterr().err
    assert "warning: --base gretha (the default): the speed loop" in err
    assert "not tuned for dune-otter" in err and "mpcasv tune speed --vessel dune-otter" in err
    tune_cli._warn_base(SimpleNamespace(base="gretha", vessel="gretha"),
                        SimpleNamespace(params=SimpleNamespace(name="gretha")), "yaw",
                        tmp_path / "x.toml")  # Gretha on her own base: quiet  # fmt: skip
    assert capsys.readouterr().err == ""
    from mpcasv.control.params import load_execution

    head = tune_cli._header(load_execution(), "dune-otter", tmp_path / "x.toml")
    assert head[0].startswith("Execution level of dune-otter:")
    assert any("--vessel dune-otter --base" in ln for ln in head)
