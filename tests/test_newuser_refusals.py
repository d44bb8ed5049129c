"""A new user's bad inputs (session 5, newuser5): each is refused in one line naming the file
and the cause, exit 2, no traceback and no output folder."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from refusal import assert_refused_in_one_line

from mpcasv.cli import main
from mpcasv.config import ConfigError

CASE1 = Path(__file__).resolve().parents[1] / "experiments" / "scenarios" / "case1.toml"


@pytest.mark.parametrize(
    ("old", "new", "word"),
    [
        # was a traceback (ValueError from make_estimator, exit 1) once the run had started
        ('estimator = "perfect"', 'estimator = "bogus"', "bogus"),
        # was accepted: the run went on with a NaN ASV position (asv_distance_m None, exit 0)
        ("N = 0.0\n", "N = nan\n", "asv.start.N"),
        ("N = 0.0\n", "N = inf\n", "asv.start.N"),
        ("E = 100.0, depth", "E = nan, depth", "auv[0].start.E"),
        # was an OverflowError traceback (cannot convert float infinity to integer), exit 1
        ("duration = 3250.0", "duration = inf", "duration"),
        # "unknown preset 'nope'" without the file, raised only once the World was built
        ('preset = "paper1-sim"', 'preset = "nope"', "preset: unknown preset 'nope'"),
    ],
)
def test_bad_scenario_values_are_refused_in_one_line(tmp_path, capsys, old, new, word):
    text = CASE1.read_text()
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1))
    assert_refused_in_one_line(path, word, tmp_path / "o", capsys)


@pytest.mark.parametrize(
    ("loop", "option", "value"),
    [
        ("yaw", "--wn", "nan"),  # was a pydantic traceback, exit 1
        ("yaw", "--dt", "-1"),  # was a traceback, exit 1
        ("yaw", "--T-f", "-1"),  # was a traceback, exit 1
        ("yaw", "--dt", "0"),  # ran and reported acceptance FAIL, exit 1
        ("yaw", "--zeta", "-1"),  # exit 2, but blamed the hull ("turns the bow against ...")
        ("yaw", "--integral-ratio", "0"),  # the same wrong cause
        ("speed", "--w", "nan"),
        ("speed", "--distance", "10,-5"),
    ],
)
def test_bad_tuning_numbers_are_refused_in_one_line(tmp_path, capsys, loop, option, value):
    out = tmp_path / "out"
    assert main(["tune", loop, f"{option}={value}", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert option in err[0] and "finite number > 0" in err[0], err
    assert not out.exists()


def test_identify_says_which_part_of_the_logs_is_too_short(tmp_path, capsys):
    # a 100-s zigzag: 750 training samples hold two 30-s windows, the held-out last 25 % (250
    # samples) none; the refusal said only "logs too short for one 300-sample replay window"
    log = tmp_path / "zig zag.csv"
    assert main(["simulate", "--manoeuvre", "zigzag", "--duration", "100", "--out", str(log),
                 "--quiet"]) == 0  # fmt: skip
    capsys.readouterr()
    out = tmp_path / "params.toml"
    assert main(["identify", str(log), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert "validation parts" in err[0] and "--validation" in err[0] and "250 samples" in err[0]
    assert not out.exists()


@pytest.mark.parametrize(
    ("extra", "word"),
    [
        (["--validation", "1.5"], "--validation 1.5"),  # was a traceback (ValueError), exit 1
        (["--validation", "nan"], "--validation nan"),
        (["--validation", "0"], "--validation 0"),
        (["--coeffs", ""], "--coeffs is empty"),  # ran silently with the default subset
    ],
)
def test_bad_identify_options_are_refused_in_one_line(tmp_path, capsys, extra, word):
    log = tmp_path / "log.csv"
    log.write_text("t,N,E,psi,u,v,r,T_cmd,delta_cmd\n0,0,0,0,1,0,0,50,0\n")
    out = tmp_path / "params.toml"
    assert main(["identify", str(log), "--out", str(out), "--quiet", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert word in err[0], err
    assert not out.exists()


def test_replay_of_a_text_file_that_is_not_json_lines_is_refused_in_one_line(tmp_path, capsys):
    # a TOML file given to `mpcasv replay` was a ValueError traceback, exit 1
    path = tmp_path / "deploy.toml"
    path.write_text('name = "x"\nduration = 1.0\n')
    assert main(["replay", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert str(path) in err[0] and "not JSON" in err[0], err


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--separation", "nan"),  # the search never ended (every trial's margin nan)
        ("--separation", "-5"),  # ran: "r_sep -5 m"
        ("--require-margin", "nan"),  # the check always passed, exit 0
        ("--seed", "-1"),  # a numpy traceback, exit 1
        ("--timeout", "nan"),
        ("--timeout", "inf"),  # said "must be > 0, got inf"
    ],
)
def test_bad_falsify_options_are_refused_in_one_line(tmp_path, capsys, option, value):
    family = Path(__file__).resolve().parents[1] / "experiments" / "falsify" / "pursuer-single.toml"
    out = tmp_path / "out"
    argv = ["falsify", str(family), "--controller", "hybrid-single", "--budget", "1",
            f"{option}={value}", "--out", str(out), "--quiet"]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert option in err[0], err
    if option == "--timeout":
        assert "finite" in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("command", ["simulate", "compare"])
def test_an_output_folder_under_a_file_is_refused_saying_so(tmp_path, capsys, command):
    # `simulate --out FILE/sub` and `compare --out FILE` said only "FILE: File exists" (and
    # `deploy --log-dir FILE`)
    blocker = tmp_path / "afile"
    blocker.write_text("")
    out = blocker / "sub" if command == "simulate" else blocker
    if command == "simulate":
        argv = ["simulate", str(CASE1), "--duration", "20", "--out", str(out), "--quiet",
                "--no-plots"]  # fmt: skip
    else:
        argv = ["compare", "quick", "--out", str(out), "--workers", "1", "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert str(blocker) in err[0] and "a file is there" in err[0], err


@pytest.mark.parametrize(
    ("extra", "word"),
    [
        (["--delta", "nan"], "--delta nan"),  # wrote a log of nan states, exit 0
        (["--current", "nan", "0"], "--current nan"),  # the same
        (["--seed", "-1", "--noise"], "--seed -1"),  # a numpy traceback, exit 1
    ],
)
def test_bad_manoeuvre_options_are_refused_in_one_line(tmp_path, capsys, extra, word):
    out = tmp_path / "log.csv"
    argv = ["simulate", "--manoeuvre", "zigzag", "--duration", "15", "--out", str(out), *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert word in err[0], err
    assert not out.exists()


@pytest.mark.parametrize(
    ("extra", "word"),
    [
        (["sim", "--repeat", "0"], "--repeat 0"),  # ran once: "over 1 runs", exit 0
        (["sim", "--repeat", "-1"], "--repeat -1"),
        (["mpc", "--steps", "-1", "--quick"], "--steps -1"),  # blamed "case3 (modified)"
        (["mpc", "--steps", "1", "--quick"], "--steps 1"),  # crashed: an empty step summary
        (["sim", "--json", "/nonexistent-newuser5/x.json"], "--json"),  # after the benchmark
    ],
)
def test_bad_bench_options_are_refused_before_running(capsys, extra, word):
    assert main(["bench", *extra]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert word in err[0], err
    assert "wall time" not in captured.out  # refused before any timing


def test_a_suite_with_an_infinite_duration_is_refused_in_one_line(tmp_path, capsys):
    # `duration = inf` in a suite replaced every scenario's duration: a run for ever
    suite = tmp_path / "inf.toml"
    suite.write_text('name = "inf"\nscenarios = ["case3"]\nduration = inf\nseeds = [0]\n'
                     '[[controllers]]\nlabel = "hybrid"\nsingle = "hybrid-single"\n')
    out = tmp_path / "out"
    assert main(["compare", str(suite), "--out", str(out), "--workers", "1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert str(suite) in err[0] and "duration" in err[0], err
    assert not out.exists()


def test_a_preset_with_an_infinite_speed_is_refused_in_one_line(tmp_path, capsys):
    # `speed = inf` in a copy of paper1-sim ran until the first transit, then a ValueError
    # traceback ("transit needs a positive speed, got inf"), exit 1
    from mpcasv.controllers import load_preset

    src = Path(__file__).resolve().parents[1] / "mpcasv" / "data" / "presets" / "paper1-sim.toml"
    text = src.read_text()
    assert "\nspeed = 2.5\n" in text
    preset = tmp_path / "my preset.toml"
    preset.write_text(text.replace("\nspeed = 2.5\n", "\nspeed = inf\n"))
    with pytest.raises(ConfigError, match="speed"):
        load_preset("hybrid-single", str(preset))
    out = tmp_path / "o"
    assert main(["simulate", str(CASE1), "--params", str(preset), "--duration", "200",
                 "--out", str(out), "--quiet", "--no-plots"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0] and str(preset) in err[0], err
    assert not out.exists()


def test_the_kalman_time_constant_still_takes_inf():
    # tau_v = inf is the constant-velocity model (docs/estimation.md): not refused with Pos
    from mpcasv.estimation import KalmanParams

    assert KalmanParams(q=0.01, tau_v=math.inf).tau_v == math.inf


@pytest.mark.parametrize("controller", [None, "mpc-single"])
def test_a_controller_or_preset_from_the_scenario_is_refused_naming_the_scenario(
        tmp_path, capsys, controller):  # fmt: skip
    # `controller = "bogus"` in a scenario said "unknown controller 'bogus'" as if --controller
    # had been given; a scenario preset of another controller, likewise without the scenario.
    # Since session 32 the unknown name is refused at load, naming the field too
    text = CASE1.read_text()
    path = tmp_path / "scen.toml"
    if controller is None:
        text = text.replace('controller = "hybrid-single"', 'controller = "bogus"', 1)
        word = f"{path}: controller: unknown controller 'bogus'"
    else:
        text = text.replace('controller = "hybrid-single"', 'controller = "mpc-single"', 1)
        word = "a preset for hybrid-single"
    path.write_text(text)
    out = tmp_path / "o"
    assert main(["simulate", str(path), "--duration", "5", "--out", str(out), "--quiet",
                 "--no-plots"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert str(path) in err[0].split("error: ")[1] and word in err[0], err


@pytest.mark.parametrize(
    ("extra", "word"),
    [
        ([], "no such file"),  # a missing scenario: a ConfigError traceback, exit 1
        (["--estimators", "bogus"], "unknown estimator(s) ['bogus']"),  # ValueError traceback
        (["--seeds", "-1"], "--seeds"),  # a numpy traceback
        # said after the runs had started (their progress bar), without the flag
        (["--controller", "nope"], "--controller nope: unknown controller"),
    ],
)
def test_the_estimation_harness_refuses_bad_input_in_one_line(tmp_path, capsys, extra, word):
    # README: `python -m mpcasv.estimation.evaluate experiments/scenarios/case5.toml`
    from mpcasv.estimation.evaluate import main as evaluate

    scenario = tmp_path / "nope.toml" if not extra else CASE1
    assert evaluate([str(scenario), *extra]) == 2
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if "error" in ln]
    assert len(err) == 1 and "Traceback" not in err[0] and word in err[0], err


@pytest.mark.parametrize(
    ("name", "words"),
    [
        # was a ValueError traceback from savefig ("Format 'txt' is not supported") after
        # every run had been simulated
        ("out.txt", ["--plot", "out.txt", ".png or .pdf or .svg", "ends in .txt"]),
        ("out", ["--plot", "ends in no suffix"]),
        ("afile/out.png", ["--plot", "afile", "a file is there"]),  # a file where a folder is
    ],
)
def test_the_estimation_harness_refuses_a_bad_plot_path_before_the_runs(tmp_path, capsys,
                                                                         name, words):  # fmt: skip
    from mpcasv.estimation.evaluate import main as evaluate

    scenario = tmp_path / "short.toml"  # (the old code ran it before failing: keep it short)
    scenario.write_text(CASE1.read_text().replace("duration = 3250.0", "duration = 5.0", 1))
    (tmp_path / "afile").write_text("keep me\n")
    plot = tmp_path / name
    assert evaluate([str(scenario), "--plot", str(plot)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err  # no progress bar: before the runs
    assert err[0].startswith("mpcasv.estimation.evaluate: error: --plot "), err
    for word in words:
        assert word in err[0], (word, err[0])
    assert captured.out == "" and not plot.exists()


def test_the_estimation_harness_makes_the_folder_of_its_plot(tmp_path, capsys):
    from mpcasv.estimation.evaluate import main as evaluate

    scenario = tmp_path / "short.toml"
    scenario.write_text(CASE1.read_text().replace("duration = 3250.0", "duration = 5.0", 1))
    plot = tmp_path / "new" / "est.svg"
    assert evaluate([str(scenario), "--estimators", "acoustic", "--plot", str(plot)]) == 0
    assert plot.read_text().lstrip().startswith("<?xml")
