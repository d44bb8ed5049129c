"""Closed-loop simulator: the trivial controller, reproducibility, run files, bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mpcasv.cli import main
from mpcasv.config import ConfigError
from mpcasv.controllers import make_controller
from mpcasv.sim.scenario import load_scenario, scenario_from_dict
from mpcasv.sim.simulator import simulate

BASE = {
    "name": "t", "duration": 300.0, "estimator": "acoustic",
    "auv": [{"name": "a", "start": {"N": 100.0, "depth": 20.0},
             "behaviour": {"plan": {"speed": 1.5, "route": [
                 {"lawnmower": {"origin": [100.0, 0.0], "length": 200.0, "spacing": 40.0,
                                "legs": 3, "depth": 20.0}}]}}}],
}  # fmt: skip


def test_trivial_controller_reaches_its_waypoint_then_stands_by_with_zero_thrust():
    sc = scenario_from_dict(BASE)
    ctrl = make_controller("goto", 1, None, overrides={"waypoint": [250.0, 150.0]})
    ts = simulate(sc, ctrl, seed=0).timeseries
    dist = np.hypot(ts["N"] - 250.0, ts["E"] - 150.0)
    first = int(np.argmax(dist < 10.0))
    assert dist.min() < 10.0 and ts["mode"].iloc[first - 2] == "transit"
    after = ts.iloc[first + 1 :]
    assert (after["mode"] == "standby").all()
    assert (after["thrust"].iloc[10:] < 1e-6).all()  # thrust lag has decayed
    assert not after["propeller_on"].iloc[10:].any()


def test_same_seed_gives_an_identical_run_and_another_seed_does_not():
    sc = scenario_from_dict(BASE)
    runs = [simulate(sc, make_controller("hybrid-single", 1, "paper1-field"), seed=s)
            for s in (5, 5, 6)]  # fmt: skip
    cols = [c for c in runs[0].timeseries.columns if c != "step_ms"]
    pd.testing.assert_frame_equal(runs[0].timeseries[cols], runs[1].timeseries[cols])
    assert not runs[0].timeseries[cols].equals(runs[2].timeseries[cols])


def test_run_files_are_written(tmp_path, scenarios_dir):
    out = tmp_path / "run"
    rc = main(["simulate", str(scenarios_dir / "case3.toml"), "--out", str(out), "--quiet"])
    assert rc == 0
    for f in ("timeseries.parquet", "metrics.json", "run.json", "jumps.csv", "paths.png",
              "range.png", "fix_age.png"):  # fmt: skip
        assert (out / f).stat().st_size > 0, f
    m = json.loads((out / "metrics.json").read_text())
    ts = pd.read_parquet(out / "timeseries.parquet")
    assert m["duration_s"] == pytest.approx(ts["t"].iloc[-1])
    assert m["min_range_m"] <= ts["range0"].min() + 1e-9
    assert m["fallbacks"] == 0


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda d: d.update(unknown_key=1), "unknown_key"),
        (lambda d: d["auv"][0].update(limits={"speed_max": -2.0}), "auv[0].limits.speed_max"),
        (lambda d: d.pop("duration"), "duration"),
        (lambda d: d.update(duration="long"), "duration"),
        (lambda d: d["auv"][0]["behaviour"]["plan"].update(speed="fast"), "plan.speed"),
    ],
)
def test_bad_scenarios_are_refused_naming_file_and_field(tmp_path, mutate, field):
    import copy

    import tomli_w

    data = copy.deepcopy(BASE)
    mutate(data)
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(data))
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    assert str(path) in str(err.value) and field in str(err.value)
    # through the CLI: one clear message, exit code 2, and no output folder
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out), "--quiet"]) == 2
    assert not out.exists()


def test_auv_behaviour_speed_above_its_limit_is_refused():
    data = json.loads(json.dumps(BASE))
    data["auv"][0]["behaviour"]["plan"]["speed"] = 2.5
    with pytest.raises(ConfigError, match="speed_max"):
        scenario_from_dict(data, "x.toml")


def test_unknown_controller_and_preset_are_refused(tmp_path, scenarios_dir):
    with pytest.raises(ConfigError, match="unknown controller"):
        make_controller("nope", 1)
    with pytest.raises(ConfigError, match="unknown preset"):
        make_controller("hybrid-single", 1, "nope")
    with pytest.raises(ConfigError, match="handles one AUV"):
        make_controller("hybrid-single", 3, "paper1-sim")


def test_current_pushes_a_standing_asv():
    data = json.loads(json.dumps(BASE))
    data["current"] = [0.2, 0.0]
    sc = scenario_from_dict(data)
    ts = simulate(sc, make_controller("goto", 1, None, overrides={"waypoint": [0.0, 0.0]}), 0)
    N = ts.timeseries["N"].to_numpy()
    v_end = (N[-1] - N[-21]) / 20.0  # 1 row per second
    assert v_end == pytest.approx(0.2, abs=0.015)  # drifting with the current (surge lag ~90 s)
    assert math.isfinite(v_end) and abs(ts.timeseries["E"].iloc[-1]) < 1.0


@pytest.mark.parametrize("speed", [0.0, 1.0])
def test_the_asv_starts_carried_by_the_current(speed):
    """``asv.start.speed`` is through the water: the boat starts moving with the current as
    well, not held against it (before session 34 its ground velocity was ``speed`` along its
    heading and a standing ASV took about 90 s to pick up the drift). Its first second,
    propeller off, covers the current plus its own way (the drag of 1 m/s slows it little in
    1 s)."""
    from mpcasv.control.execution import NCMD
    from mpcasv.sim.world import World

    data = json.loads(json.dumps(BASE)) | {"current": [0.3, -0.2]}
    data["asv"] = {"start": {"N": 0.0, "E": 0.0, "psi_deg": 60.0, "speed": speed}}
    w = World(scenario_from_dict(data), seed=0)
    psi = math.radians(60.0)
    vN = w.x[3] * math.cos(psi) - w.x[4] * math.sin(psi)  # body -> NED
    vE = w.x[3] * math.sin(psi) + w.x[4] * math.cos(psi)
    assert (vN, vE) == pytest.approx((0.3 + speed * math.cos(psi), -0.2 + speed * math.sin(psi)))
    w.advance(np.zeros(NCMD))
    own = speed * np.array([math.cos(psi), math.sin(psi)])
    moved = w.x[:2] - (np.array([0.3, -0.2]) + own)
    assert np.hypot(*moved) < 0.05 + 0.1 * speed, moved


def test_the_asv_starts_carried_by_the_current_field_where_it_is():
    """With a ``[current_field]`` the start's drift is the field at t = 0 at the ASV's start
    (its gradient makes it differ from the constant part there)."""
    from mpcasv.sim.world import World

    data = json.loads(json.dumps(BASE)) | {"current": [0.1, 0.0], "current_field": {
        "gradient": [[0.0, 0.0], [0.0, 0.001]], "radius": 1000.0, "auv_factor": 0.0}}
    data["asv"] = {"start": {"N": 0.0, "E": 200.0, "psi_deg": 90.0}}
    w = World(scenario_from_dict(data), seed=0)
    cN, cE = w.current_at_asv()
    assert (cN, cE) == pytest.approx((0.1, 0.2))  # V_0 + G (p - p_0), p_0 the origin
    # heading East: surge along E, sway to starboard (South)
    assert (w.x[3], w.x[4]) == pytest.approx((cE, -cN))


def test_multi_auv_ranges_pair_each_auv_with_the_asv_at_the_same_instant():
    """range_min{k} is AUV k's own closest approach within the period, at plant resolution."""
    data = json.loads(json.dumps(BASE))
    data["auv"] = [
        {"name": f"a{k}", "start": {"N": 100.0 * (k + 1), "psi_deg": 90.0},
         "behaviour": {"transit": {"heading_deg": 90.0, "speed": 1.0 + 0.5 * k}}}
        for k in range(3)
    ]  # fmt: skip
    sc = scenario_from_dict(data)
    ts = simulate(sc, make_controller("goto", 3, None, overrides={"waypoint": [0.0, 0.0]}), 0)
    df = ts.timeseries
    for k in range(3):
        # the ASV stands still at the origin; AUV k moves East at 1 + 0.5 k m/s from N = 100 (k+1)
        t = df["t"].to_numpy()
        east_prev = (1.0 + 0.5 * k) * np.maximum(t - 1.0 - 5.0, 0.0)  # crude lower bound
        assert (df[f"range_min{k}"] <= df[f"range{k}"] + 1e-9).all()
        assert (df[f"range_min{k}"] >= 100.0 * (k + 1) - 1.0).all()
        assert (df[f"range_min{k}"] >= np.hypot(100.0 * (k + 1), east_prev) - 10.0).all()
    assert ts.min_range_m == pytest.approx(df[[f"range_min{k}" for k in range(3)]].min().min())


def test_simulate_refuses_to_replace_a_folder_that_is_not_a_run(tmp_path, capsys):
    """`mpcasv simulate --out DIR` deleted an existing folder it had not written (found by a
    new user: data loss). A non-empty folder without run.json, or a file, is refused before
    the run with one line and exit 2, and left as it was; an earlier run's folder is replaced."""
    from mpcasv.cli import main

    keep = tmp_path / "precious"
    keep.mkdir()
    (keep / "thesis.tex").write_text("data")
    scenario = str(Path(__file__).resolve().parents[1] / "experiments/scenarios/demo.toml")
    assert main(["simulate", scenario, "--out", str(keep), "--no-plots", "--quiet"]) == 2
    assert (keep / "thesis.tex").read_text() == "data"
    assert "not a run folder" in capsys.readouterr().err
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main(["simulate", scenario, "--out", str(afile), "--no-plots", "--quiet"]) == 2
    run = tmp_path / "run"
    assert main(["simulate", scenario, "--out", str(run), "--no-plots", "--quiet"]) == 0
    assert main(["simulate", scenario, "--out", str(run), "--no-plots", "--quiet"]) == 0
    assert (run / "run.json").is_file()


def test_simulate_duration_cuts_a_scenario_and_manoeuvre_options_are_refused(tmp_path, capsys):
    """`mpcasv simulate SCENARIO --duration 20` ran the whole scenario (the option belonged to
    --manoeuvre and was silently ignored; found by a new user). It now simulates the first 20 s
    (recorded in metrics.json); the manoeuvre-only options, and a non-positive duration, are
    refused with one line and exit 2 instead of being ignored."""
    scenario = str(Path(__file__).resolve().parents[1] / "experiments/scenarios/demo.toml")
    out = tmp_path / "cut"
    assert main(["simulate", scenario, "--duration", "20", "--out", str(out), "--no-plots",
                 "--quiet"]) == 0  # fmt: skip
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["duration_s"] == pytest.approx(20.0)
    capsys.readouterr()
    for bad in (["--speed", "2"], ["--speed", "0"], ["--vessel", "otter"], ["--noise"],
                ["--duration", "0"], ["--duration", "nan"], ["--duration", "1e-9"],
                ["--duration", "1e6"]):  # fmt: skip
        assert main(["simulate", scenario, "--out", str(tmp_path / "x"), *bad]) == 2, bad
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "error" in err[0], (bad, err)
    assert not (tmp_path / "x").exists()
    man = ["simulate", "--manoeuvre", "zigzag", "--out", str(tmp_path / "m.csv")]
    assert main([*man, "--duration", "-3"]) == 2  # a traceback before (review)
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_a_preset_of_another_controller_is_named_as_such(tmp_path, capsys):
    """`--controller hybrid-single --params mpc-single` listed twelve "Unexpected keyword
    argument" errors (found by a new user); it now says in one line which controllers the
    preset is for. A preset that fits no controller keeps its field-by-field errors."""
    scenario = str(Path(__file__).resolve().parents[1] / "experiments/scenarios/case3.toml")
    out = str(tmp_path / "x")
    assert main(["simulate", scenario, "--controller", "hybrid-single", "--params",
                 "mpc-single", "--out", out, "--quiet"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()  # the shipped preset names its controller
    assert len(err) == 1 and ("a preset for mpc-single (its 'controller' key), not for "
                              "'hybrid-single'") in err[0], err  # fmt: skip
    # a user preset without the key: the controllers whose parameters validate it are named
    mine = tmp_path / "mine.toml"
    text = (Path(__file__).resolve().parents[1] / "mpcasv/data/presets/mpc-single.toml").read_text()
    mine.write_text("\n".join(ln for ln in text.splitlines() if not ln.startswith("controller =")))
    assert main(["simulate", scenario, "--controller", "hybrid-single", "--params", str(mine),
                 "--out", out, "--quiet"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a preset for mpc-multi, mpc-single, not for 'hybrid-single'" in err[0]
    bad = tmp_path / "bad.toml"
    bad.write_text("speed = -3\n")
    assert main(["simulate", scenario, "--params", str(bad), "--out", out, "--quiet"]) == 2
    assert "-3 m/s is outside the allowed range (0, 10] m/s" in capsys.readouterr().err


def test_every_run_figure_is_titled_with_its_scenario_controller_and_seed():
    """fix_age.png was titled "Fix ages per AUV (...)" alone: a suite's many run folders'
    figures could not be told apart; it is titled like paths.png and range.png now."""
    import matplotlib.pyplot as plt

    from mpcasv.sim.plots import fix_age_figure, run_title

    res = simulate(scenario_from_dict(BASE | {"name": "titled", "duration": 20.0}),
                   make_controller("goto", 1, None), seed=7)  # fmt: skip
    assert run_title(res, "x") == "titled: x (goto, seed 7)"
    fig = fix_age_figure(res)
    try:
        assert fig.axes[0].get_title() == ("titled: fix ages per AUV (goto, seed 7); ticks: "
                                           "reliable fixes (Paper 2 eq. 9)")  # fmt: skip
    finally:
        plt.close(fig)
