"""Session 17's bad-input walk (a helper attacked every command): the rules shared by the
commands. Usage errors that argparse catches are one line too; a seed is an integer in
``[0, 2**32 - 1]`` wherever one is taken (a huge suite seed ran its job, then failed writing
the results table with a traceback and left an empty table behind); a scenario's or a suite's
name, which becomes part of output paths, cannot climb out of the output folder.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from mpcasv.cli import main
from mpcasv.config import SEED_MAX, ConfigError, check_seed, parse
from mpcasv.experiments.suite_file import load_suite
from mpcasv.sim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "experiments" / "scenarios" / "demo.toml"
QUICK = ROOT / "experiments" / "suites" / "quick.toml"


def _one_line_exit_2(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2, err
    assert len(err.strip().splitlines()) == 1, err
    assert "usage:" not in err
    return err


@pytest.mark.parametrize("argv", [
    ["simulate", "--seed", "abc"],
    ["compare", "--workers", "x"],
    ["bench"],
    ["nope"],
    [],
])  # fmt: skip
def test_usage_errors_are_one_line(argv, capsys):
    err = _one_line_exit_2(argv, capsys)
    assert "error:" in err and "--help" in err


@pytest.mark.parametrize("seed", [-1, SEED_MAX + 1, 10**23])
def test_check_seed_refuses_outside_the_range(seed):
    with pytest.raises(ConfigError, match=r"\[0, 2\*\*32 - 1\]"):
        check_seed(seed)


@pytest.mark.parametrize("seed", [0, SEED_MAX])
def test_check_seed_keeps_the_ends(seed):
    assert check_seed(seed) == seed


@pytest.mark.parametrize("command", ["simulate", "falsify"])
def test_a_huge_seed_is_bad_input(command, tmp_path, capsys):
    argv = {"simulate": ["simulate", str(DEMO), "--out", str(tmp_path / "o")],
            "falsify": ["falsify", str(ROOT / "experiments/falsify/pursuer-single.toml"),
                        "--controller", "hybrid-single", "--out", str(tmp_path / "f")]}[command]
    assert main([*argv, "--seed", str(10**23)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "2**32 - 1" in err, err
    assert not (tmp_path / "o").exists()


def test_a_huge_suite_seed_is_refused_before_any_job(tmp_path):
    text = QUICK.read_text()
    suite = tmp_path / "s.toml"
    suite.write_text(re.sub(r"(?m)^seeds = .*$", f"seeds = [0, {10**23}]", text))
    with pytest.raises(ConfigError, match="seeds"):
        load_suite(suite)


@pytest.mark.parametrize("name", ["../../escaped", "", ".hidden", "a/b", "a\\\\b", " x"])
def test_a_scenario_name_cannot_leave_the_output_folder(name, tmp_path):
    text = DEMO.read_text().replace('name = "demo"', f"name = {name!r}".replace("'", '"'))
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="name"):
        load_scenario(path)


def test_shipped_names_are_path_names():
    for path in sorted((ROOT / "experiments" / "scenarios").rglob("*.toml")):
        load_scenario(path)
    for path in sorted((ROOT / "experiments" / "suites").glob("*.toml")):
        load_suite(path)


def test_a_suite_name_cannot_leave_the_results_folder(tmp_path):
    suite = tmp_path / "s.toml"
    shutil.copy(QUICK, suite)
    text = suite.read_text()
    suite.write_text(re.sub(r'(?m)^name = ".*"$', 'name = "../../../escsuite"', text, count=1))
    with pytest.raises(ConfigError, match="used in output paths"):
        load_suite(suite)


def test_parse_names_the_field():
    from mpcasv.sim.scenario import Scenario

    with pytest.raises(ConfigError, match="name"):
        parse(Scenario, {"name": "a/b", "duration": 1.0, "auv": []})


@pytest.mark.parametrize("argv,names", [
    (["bench", "sim", "--steps", "5"], "--steps"),
    (["bench", "sim", "--quick"], "--quick"),
    (["bench", "mpc", "--suite", "quick"], "--suite"),
    (["bench", "mpc", "--repeat", "2"], "--repeat"),
    (["bench", "compare", "--threads", "4", "--step-iter", "3"], "--threads, --step-iter"),
])  # fmt: skip
def test_bench_refuses_another_benchmarks_options(argv, names, capsys):
    """``bench mpc --suite quick`` ran the whole MPC benchmark as if the suite had been read."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and names in err and "not read by" in err, err


@pytest.mark.parametrize("extra,names", [
    ([str(DEMO)], "SCENARIO"),
    (["--controller", "goto", "--nominal"], "--controller, --nominal"),
    (["--estimator", "kalman"], "--estimator"),
    (["--no-plots"], "--no-plots"),
    (["--duration", "1e12"], "--duration"),
    (["--duration", "0.1"], "--duration"),
    (["--current", "5", "0"], "--current"),
])  # fmt: skip
def test_a_manoeuvre_refuses_what_it_would_ignore_or_cannot_do(extra, names, tmp_path, capsys):
    """A SCENARIO or scenario options beside --manoeuvre were ignored; --duration 1e12 tried to
    allocate 582 TiB; --duration 0.1 wrote a 2-sample log; --current 5 0 was taken (a scenario
    refuses currents above 2 m/s)."""
    out = tmp_path / "m.csv"
    assert main(["simulate", "--manoeuvre", "zigzag", "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and names in err, err
    assert not out.exists()


def _scenario(tmp_path, old: str, new: str) -> Path:
    text = DEMO.read_text()
    assert old in text
    path = tmp_path / "s.toml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize("old,new,field", [
    ("duration = 900.0", "duration = 1e300", "duration"),
    ("psi_deg = 45.0", "psi_deg = 1e20", "psi_deg"),
    ('name = "auv"', 'name = ""', "name"),
    ('name = "auv"', 'name = " auv"', "name"),
])  # fmt: skip
def test_impossible_scenario_values_are_refused(old, new, field, tmp_path):
    """``duration = 1e300`` ran for ever; a heading of 1e20 deg left the boat unable to turn
    (a yaw step is lost in a float that large); an empty AUV name was taken."""
    with pytest.raises(ConfigError, match=field):
        load_scenario(_scenario(tmp_path, old, new))


def test_the_longest_run_is_still_taken(tmp_path):
    from mpcasv.config import DURATION_MAX

    sc = load_scenario(_scenario(tmp_path, "duration = 900.0", f"duration = {DURATION_MAX}"))
    assert sc.duration == DURATION_MAX


def test_paper_table_refuses_a_negative_seed(tmp_path, capsys):
    assert main(["paper-table", "--seed", "-1", "--out", str(tmp_path / "pt")]) == 2
    assert "--seed -1" in capsys.readouterr().err
    assert not (tmp_path / "pt").exists()


def test_simulate_without_plots_does_not_say_it_wrote_plots(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["simulate", str(DEMO), "--duration", "5", "--out", str(out), "--no-plots",
                 "--quiet"]) == 0  # fmt: skip
    said = capsys.readouterr().out
    assert "(timeseries.parquet, metrics.json)" in said, said
    assert not list(out.glob("*.png"))


def test_a_one_auv_controller_on_several_auvs_is_refused_before_compiling(monkeypatch,
                                                                          tmp_path):
    """``simulate`` of a two-AUV scenario with ``mpc-single`` compiled a two-AUV library
    (10-34 s, left in the cache) and then refused the count."""
    from mpcasv.controllers import prepare as prep

    compiled = []
    monkeypatch.setattr(prep, "prepare", lambda libs, *a, **k: compiled.append(libs))
    with pytest.raises(ConfigError, match="handles one AUV"):
        prep.needed_libraries([("mpc-single", 2, None, None, None)])
    assert main(["simulate", str(ROOT / "experiments/scenarios/case6.toml"),
                 "--controller", "mpc-single", "--params", "mpc-single", "--quiet",
                 "--out", str(tmp_path / "o")]) == 2
    assert not compiled


def test_a_file_of_many_problems_lists_a_few_and_counts_the_rest():
    """An empty vessel file listed its ~40 missing fields on one line."""
    from mpcasv.config import MAX_PROBLEMS
    from mpcasv.models.params import VesselParams

    with pytest.raises(ConfigError) as exc:
        parse(VesselParams, {"name": "x"}, "v.toml")
    listed = str(exc.value).count("v.toml:")
    assert listed == MAX_PROBLEMS and "more" in str(exc.value)


def test_our_validators_words_come_without_pydantics_prefix(tmp_path):
    with pytest.raises(ConfigError) as exc:
        load_scenario(_scenario(tmp_path, 'name = "demo"', 'name = "a/b"'))
    assert "Value error" not in str(exc.value) and "used in output paths" in str(exc.value)
