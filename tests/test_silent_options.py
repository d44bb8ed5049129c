"""Options and configuration fields that were accepted but silently had no effect (an audit,
session 24): each now works or is refused up front in one line (exit 2) naming the option."""

from __future__ import annotations

from pathlib import Path

import pytest

from mpcasv.cli import main
from mpcasv.config import ConfigError

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "experiments" / "scenarios"


def refused(argv: list[str], capsys, *words: str) -> str:
    """``mpcasv ARGV`` exits 2 with one error line holding every word; return that line."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


# -- 1. the plan estimator on a scenario in which no AUV has a plan --------------------------


def test_simulate_refuses_the_plan_estimator_when_no_auv_has_a_plan(tmp_path, capsys):
    """Case 4's AUV is a transit: 'plan' was the Kalman filter under another name."""
    out = tmp_path / "run"
    refused(["simulate", str(SCENARIOS / "case4.toml"), "--estimator", "plan", "--out", str(out),
             "--quiet", "--no-plots"], capsys, "--estimator plan", "no AUV", "--estimator kalman")
    assert not out.exists()
    sc = tmp_path / "case4.toml"  # the same from the scenario's own field
    sc.write_text((SCENARIOS / "case4.toml").read_text().replace(
        'estimator = "perfect"', 'estimator = "plan"'))  # fmt: skip
    refused(["simulate", str(sc), "--out", str(out), "--quiet", "--no-plots"], capsys,
            str(sc), "estimator = 'plan'", "no AUV")
    assert not out.exists()


def test_the_world_refuses_it_too_and_a_subset_without_plans_stays_allowed():
    from mpcasv.estimation import check_plan_estimator, scenario_plans
    from mpcasv.sim.scenario import load_scenario
    from mpcasv.sim.world import World

    with pytest.raises(ConfigError, match="estimator 'plan'"):
        World(load_scenario(SCENARIOS / "case4.toml"), 0, "plan")
    case8 = load_scenario(SCENARIOS / "case8.toml")  # a pursuer beside planned AUVs
    plans = scenario_plans(case8)
    assert None in plans and any(p is not None for p in plans)
    check_plan_estimator(case8, "plan", "--estimator plan")  # no error


def test_a_suite_leaves_out_plan_on_a_scenario_without_plans_and_says_so():
    from mpcasv.experiments.suite import expand

    exp = expand("estimators")
    assert ("case4", "plan") not in {(j.scenario, j.estimator) for j in exp.jobs}
    assert ("case8", "plan") in {(j.scenario, j.estimator) for j in exp.jobs}
    assert ("case4", "kalman") in {(j.scenario, j.estimator) for j in exp.jobs}
    assert len(exp.jobs) == 93
    assert any("'plan'" in s and "'case4'" in s for s in exp.skipped), exp.skipped


# -- 2. compare --workers 1 --job-timeout S --------------------------------------------------

SUITE = """
name = "one"
scenarios = ["case1"]
seeds = [0]
current = ["off"]
duration = 5.0

[[controllers]]
label = "hybrid"
single = "hybrid-single"
multi = "hybrid-multi"
preset = "scenario"
"""


def test_compare_with_one_worker_enforces_the_job_timeout(tmp_path, capsys):
    """The serial branch never read the limit: the job ran to its end, recorded 'ok'."""
    import pandas as pd

    suite = tmp_path / "one.toml"
    suite.write_text(SUITE)
    out = tmp_path / "out"
    assert main(["compare", str(suite), "--out", str(out), "--workers", "1", "--job-timeout",
                 "0.01", "--no-report", "--quiet"]) == 1  # fmt: skip
    table = pd.read_parquet(out / "results.parquet")
    assert list(table["status"]) == ["timeout"], table[["status", "error"]]
    assert "time limit of 0.01 s" in table["error"].iloc[0]


# -- 3. tune yaw --wn with --wn-per-speed -----------------------------------------------------


def test_tune_yaw_refuses_wn_per_speed_beside_wn(tmp_path, capsys):
    """--wn-per-speed was ignored beside --wn (yet written into the provenance)."""
    out = tmp_path / "yaw"
    refused(["tune", "yaw", "--wn", "0.5", "--wn-per-speed", "0.2", "--out", str(out), "--quiet"],
            capsys, "--wn-per-speed 0.2", "--wn 0.5", "give one of them")
    assert not out.exists()


# -- 4. a suite entry's preset for a scenario the entry leaves out ----------------------------


def test_a_suite_refuses_a_preset_for_a_scenario_its_entry_leaves_out(tmp_path, capsys):
    """The suite runs case8, the entry only case3: its case8 preset was silently unused."""
    suite = tmp_path / "s.toml"
    suite.write_text(SUITE.replace('["case1"]', '["case3", "case8"]') + (
        'scenarios = ["case3"]\npresets = { case8 = "paper2-field" }\n'))  # fmt: skip
    out = tmp_path / "out"
    refused(["compare", str(suite), "--out", str(out), "--workers", "1", "--quiet"], capsys,
            str(suite), "controllers[0]", "presets: 'case8'", "scenarios ['case3']")
    assert not out.exists()


# -- 5. simulate --manoeuvre --seed without --noise -------------------------------------------


def test_a_manoeuvre_refuses_a_seed_without_noise(tmp_path, capsys):
    """Without --noise nothing is random: --seed 7 wrote the same file as --seed 0."""
    out = tmp_path / "logs"
    refused(["simulate", "--manoeuvre", "zigzag", "--seed", "7", "--duration", "20", "--out",
             str(out)], capsys, "--seed 7", "--noise")  # fmt: skip
    assert not out.exists()
    assert main(["simulate", "--manoeuvre", "zigzag", "--duration", "20", "--out", str(out)]) == 0
    assert (out / "zigzag-0.csv").is_file()  # the default seed still names the file


# -- 7. tune controller's budget hint offers only budgets the study allows --------------------


def test_the_budget_hint_offers_no_budget_below_the_study_s_trials(tmp_path, capsys):
    """A study of 6 trials, --trials 5 in batches of 2: the hint said 'use 4 or 6', and 4 was
    then refused ('holds 6 trials already ... give at least 6')."""
    import optuna

    from mpcasv.experiments.tune_controller import STUDY_NAME

    (tmp_path / "train.toml").write_text(
        'name = "tiny-train"\nscenarios = ["case3"]\nduration = 20.0\nseeds = [0]\n'
        'plots = "none"\n[[controllers]]\nlabel = "hybrid"\nsingle = "hybrid-single"\n'
        'preset = "scenario"\n')  # fmt: skip
    ranges = tmp_path / "ranges.toml"
    ranges.write_text('controller = "hybrid-single"\nsuite = "train.toml"\nheldout_seeds = [7]\n'
                      'trials = 6\nbatch = 2\n[params]\n"speed" = { low = 1.0, high = 2.5 }\n')
    out = tmp_path / "out"
    out.mkdir()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(study_name=STUDY_NAME, storage=f"sqlite:///{out / 'study.db'}")
    for _ in range(6):
        study.add_trial(optuna.trial.create_trial(value=0.0))
    line = refused(["tune", "controller", str(ranges), "--trials", "5", "--out", str(out),
                    "--quiet"], capsys, "--trials = 5", "use 6", "holds 6 trials")  # fmt: skip
    assert "4" not in line.split("use ")[1], line
    refused(["tune", "controller", str(ranges), "--trials", "7", "--out", str(out), "--quiet"],
            capsys, "--trials = 7", "use 6 or 8")  # fmt: skip


# -- 6. tune controller and its suite's plots / [acceptance] -----------------------------------


@pytest.mark.parametrize(("add", "words"), [
    ('plots = "all"\n', ("plots = 'all'", "tune controller draws no run figures")),
    ('[acceptance]\nsource = "x"\ntargets = { energy_J = -0.1 }\n', ("[acceptance]",)),
])  # fmt: skip
def test_tune_controller_refuses_suite_plots_and_acceptance_it_would_not_use(
        tmp_path, capsys, add, words):  # fmt: skip
    suite = ('name = "tiny-train"\nscenarios = ["case3"]\nduration = 20.0\nseeds = [0]\n'
             f'{add if add.startswith("plots") else ""}[[controllers]]\nlabel = "hybrid"\n'
             'single = "hybrid-single"\npreset = "scenario"\n'
             f'{"" if add.startswith("plots") else add}')  # fmt: skip
    (tmp_path / "train.toml").write_text(suite)
    ranges = tmp_path / "ranges.toml"
    ranges.write_text('controller = "hybrid-single"\nsuite = "train.toml"\nheldout_seeds = [7]\n'
                      'trials = 2\nbatch = 2\n[params]\n"speed" = { low = 1.0, high = 2.5 }\n')
    out = tmp_path / "out"
    refused(["tune", "controller", str(ranges), "--out", str(out), "--quiet"], capsys,
            str(tmp_path / "train.toml"), *words)
    assert not out.exists()


def test_the_estimator_harness_leaves_plan_out_where_no_auv_has_one(tmp_path, capsys):
    """``python -m mpcasv.estimation.evaluate`` registers its estimators under recording names,
    which the World's check of "plan" did not see: on Case 4 (a transit AUV) its "plan" row
    was the Kalman filter's (a review, session 24). Asked for, it is refused; by default it is
    left out and said."""
    import re

    from mpcasv.estimation.evaluate import main as evaluate
    from mpcasv.estimation.evaluate import run_estimators
    from mpcasv.sim.scenario import load_scenario

    text = (SCENARIOS / "case4.toml").read_text()
    short = tmp_path / "case4.toml"
    short.write_text(re.sub(r"(?m)^duration = .*$", "duration = 5.0", text, count=1))
    assert evaluate([str(short), "--estimators", "kalman", "plan"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--estimators plan" in err[0] and "no AUV" in err[0], err
    with pytest.raises(ConfigError, match="no AUV"):
        run_estimators(load_scenario(short), ["plan"], 0)
    assert evaluate([str(short)]) == 0
    out = capsys.readouterr().out
    assert "plan left out" in out
    assert "means over seeds 0 of" in out  # which seeds (0 alone unless --seeds says)
    rows = re.findall(r"(?m)^(\w+)\s+[-\d.]+\s", out)  # the table's rows: estimator, figures
    assert rows == ["acoustic", "kalman"], out


def test_a_falsify_family_with_plan_and_no_planned_auv_is_refused_up_front(tmp_path):
    """A family whose AUV is a pursuer, with estimator "plan": every trial would have failed
    in the World; refused when the family is checked, before any trial."""
    from mpcasv.experiments.falsify_family import check_range_ends, load_family

    text = (ROOT / "experiments" / "falsify" / "pursuer-single.toml").read_text()
    changed = tmp_path / "pursuer-single.toml"
    changed.write_text(text.replace('estimator = "kalman"', 'estimator = "plan"'))
    assert changed.read_text() != text
    check_range_ends(load_family(ROOT / "experiments" / "falsify" / "pursuer-single.toml"))
    with pytest.raises(ConfigError, match="estimator 'plan'"):
        check_range_ends(load_family(changed))
