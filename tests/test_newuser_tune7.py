"""A new user of the controller tuning (issue 17; docs/tuning-controllers.md) breaking it, and
the fixes: each refusal is one line with exit status 2, given before any run.

Found by using ``mpcasv tune controller`` / ``tune compare`` / suites with ``front = ...`` on
tiny budgets (Case 3 cut to 120 s, 2 training seeds, 2-4 trials, batches of 2):

* a per-AUV metric (``reliable_fix_age_p95_s_auv``) as an objective passed the range file and
  ended in a pandas ``KeyError`` traceback after the first batch had run;
* a constraint that is also an objective (``energy_J``) put the summed constraint in the
  objective's ``trials.csv`` column (39208 J where the objective mean was 19604 J) and a
  duplicate ``heldout.energy_J`` column in ``front.csv``;
* a better-higher constraint (``min_range_m``: "summed <= 0") made every trial infeasible, and
  wall-time objectives (``controller_step_ms_median``) made the search depend on the machine;
* ``trials`` not a multiple of ``batch``: extending 3 -> 6 trials asked trial 4 with speed
  1.84497 where an uninterrupted 6-trial search asked 1.85195;
* ``--trials 2`` on a study of 4 trials: exit 0, the report said "budget: 2 trials" over 4;
* resuming with other ``heldout_seeds``: accepted; the report counted the old seed's run
  ("3 runs" for 2 seeds) and ``tune compare`` read the folder's held-out parts;
* ``tune controller --out`` an ``mpcasv compare`` folder (and the reverse) replaced the other
  command's ``report.md``;
* ``tune compare --baseline``: ignored without ``--plot``, a pyarrow traceback for a file that
  is not parquet; a search without a feasible point was "no held-out runs (rerun without
  --no-heldout)" although it had been run with them;
* a suite ``front`` entry's range was printed rounded: "level = 20689.6 J is outside the
  front's energy_J range [20689.6, 20689.6]".
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from mpcasv.cli import main

SUITE = (
    'name = "tn7-train"\nscenarios = ["case3"]\nduration = 120.0\nseeds = [0, 1]\n'
    'plots = "none"\n[[controllers]]\nlabel = "hybrid"\nsingle = "hybrid-single"\n'
    'preset = "scenario"\n'
)
PARAMS = (
    '[params]\n"domain.delta_r" = { low = 20.0, high = 60.0 }\n'
    '"speed" = { low = 1.0, high = 2.5 }\n'
)


def _ranges(tmp: Path, extra: str = "", trials: int = 2, batch: int = 2, heldout: str = "[7]",
            name: str = "ranges.toml") -> Path:  # fmt: skip
    (tmp / "train.toml").write_text(SUITE)
    path = tmp / name
    path.write_text(f'controller = "hybrid-single"\nsuite = "train.toml"\n'
                    f"heldout_seeds = {heldout}\ntrials = {trials}\nbatch = {batch}\nseed = 1\n"
                    f"{extra}\n{PARAMS}")  # fmt: skip
    return path


def _tune(ranges: Path, out: Path, *more: str) -> int:
    return main(["tune", "controller", str(ranges), "--out", str(out), "--workers", "1",
                 "--quiet", *more])  # fmt: skip


def _refused(capsys, code: int, *needles: str) -> str:
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


@pytest.fixture(scope="module")
def searched(tmp_path_factory):
    """A finished 2-trial search with held-out seed 7 (one batch)."""
    tmp = tmp_path_factory.mktemp("tn7")
    ranges = _ranges(tmp)
    out = tmp / "out"
    assert _tune(ranges, out) == 0
    return tmp, ranges, out


@pytest.mark.parametrize("extra, needles", [
    ('objectives = ["reliable_fix_age_p95_s_auv", "energy_J"]',
     ("per-AUV list", "'reliable_fix_age_p95_s'")),
    ('objectives = ["controller_step_ms_median", "energy_J"]', ("wall time",)),
    ('constraint = "over_budget_steps"', ("wall time",)),
    ('constraint = "energy_J"', ("also an objective",)),
    ('constraint = "min_range_m"', ("lower-is-better", "'min_range_m'")),
])  # fmt: skip
def test_range_file_metrics_that_cannot_be_searched_are_refused_before_any_run(
        tmp_path, capsys, extra, needles):  # fmt: skip
    """Before the fix the first two ran a batch (the per-AUV one then raised a KeyError
    traceback), the third and fourth ran to the end with wrong or machine-dependent figures."""
    out = tmp_path / "o"
    _refused(capsys, _tune(_ranges(tmp_path, extra), out), str(tmp_path / "ranges.toml"),
             *needles)  # fmt: skip
    assert not (out / "train").exists(), "refused before any run"


def test_a_budget_that_is_not_a_multiple_of_the_batch_is_refused(tmp_path, capsys):
    """3 trials in batches of 2, then extended to 6, asked another trial 4 than 6 at once."""
    _refused(capsys, _tune(_ranges(tmp_path, trials=3), tmp_path / "a"), "trials = 3",
             "multiple of batch = 2", "use 2 or 4")  # fmt: skip
    _refused(capsys, _tune(_ranges(tmp_path, trials=4), tmp_path / "b", "--trials", "5"),
             "--trials = 5", "use 4 or 6")  # fmt: skip
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_budget_below_the_finished_trials_is_refused(searched, tmp_path, capsys):
    """Before: exit 0 and a report saying 'budget: N trials' over more trials than N."""
    import shutil

    _, ranges, out = searched
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    # a 4-trial budget extends (resumable) ...
    report_before = (copy / "report.md").read_text()
    assert "**budget: 2 trials**" in report_before
    # ... but one below the study's 2 trials cannot be honoured
    big = _ranges(tmp_path, trials=4, batch=2, name="r4.toml")
    assert _tune(big, copy, "--no-heldout") == 0
    _refused(capsys, _tune(ranges, copy), "holds 4 trials already", "give at least 4")


def test_resuming_with_other_heldout_seeds_is_refused(searched, tmp_path, capsys):
    import shutil

    _, _, out = searched
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    parts = sorted((copy / "heldout" / "parts").glob("*.parquet"))
    other = _ranges(tmp_path, heldout="[8]", name="other.toml")
    _refused(capsys, _tune(other, copy), "heldout_seeds [7]", "says [8]", "copy study.db")
    assert sorted((copy / "heldout" / "parts").glob("*.parquet")) == parts, "nothing ran"
    # the way the message gives: the search's trials and runs, evaluated on seed 8
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    shutil.copy(copy / "study.db", fresh / "study.db")
    shutil.copytree(copy / "train", fresh / "train")
    assert _tune(other, fresh) == 0
    assert json.loads((fresh / "tune.json").read_text())["heldout"]["seeds"] == [8]
    assert len(list((fresh / "train" / "parts").glob("*.parquet"))) == len(
        list((copy / "train" / "parts").glob("*.parquet"))), "no training run was redone"
    # the same seeds still resume (nothing to do) and write the outputs
    assert _tune(_ranges(tmp_path, name="same.toml"), copy) == 0
    assert json.loads((copy / "tune.json").read_text())["heldout"]["seeds"] == [7]


def test_tune_and_compare_refuse_each_others_output_folder(searched, tmp_path, capsys):
    """Before: each replaced the other's report.md (and mixed their files)."""
    tmp, ranges, out = searched
    report = (out / "report.md").read_text()
    suite = tmp_path / "s.toml"
    suite.write_text(SUITE.replace("tn7-train", "tn7-s"))
    _refused(capsys, main(["compare", str(suite), "--out", str(out), "--workers", "1",
                           "--quiet"]), "'mpcasv tune controller'", "tune.json")  # fmt: skip
    assert (out / "report.md").read_text() == report
    cmp_out = tmp_path / "cmp"
    cmp_out.mkdir()
    (cmp_out / "sweep.json").write_text("{}\n")
    (cmp_out / "report.md").write_text("a comparison\n")
    _refused(capsys, _tune(ranges, cmp_out), "'mpcasv compare'", "sweep.json")
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine\n")
    _refused(capsys, _tune(ranges, other), "no study.db")
    assert (cmp_out / "report.md").read_text() == "a comparison\n"
    assert not (cmp_out / "study.db").exists() and not (other / "study.db").exists()
    # a killed `mpcasv falsify` leaves only its study.db: another Optuna study, not mixed in
    import optuna

    falsify = tmp_path / "falsify"
    falsify.mkdir()
    optuna.create_study(study_name="falsify-x", storage=f"sqlite:///{falsify / 'study.db'}")
    _refused(capsys, _tune(ranges, falsify), "falsify-x", "not a search of")
    assert optuna.study.get_all_study_names(f"sqlite:///{falsify / 'study.db'}") == ["falsify-x"]
    _refused(capsys, main(["compare", str(suite), "--out", str(falsify), "--workers", "1",
                           "--quiet"]), "Optuna study (study.db)")  # fmt: skip


def test_tune_compare_checks_its_baseline_and_names_an_empty_front(searched, tmp_path,
                                                                    capsys):  # fmt: skip
    _, _, out = searched
    png = tmp_path / "f.png"
    _refused(capsys, main(["tune", "compare", str(out), str(out), "--baseline",
                           str(tmp_path / "none.parquet")]), "--baseline")  # fmt: skip
    _refused(capsys, main(["tune", "compare", str(out), str(out), "--plot", str(png),
                           "--baseline", str(tmp_path / "none.parquet")]),
             "no such file")  # fmt: skip
    _refused(capsys, main(["tune", "compare", str(out), str(out), "--plot", str(png),
                           "--baseline", str(out / "trials.csv")]), "not a parquet")  # fmt: skip
    assert not png.exists()
    # a baseline on other realisations (an `mpcasv compare` on seeds 200-201 beside fronts
    # held out on others) was drawn without a word
    real = json.loads((out / "tune.json").read_text())["heldout"]["realisations"]
    row = {"variant": "published", "status": "ok", "collision_domain_s": 0.0,
           "reliable_fix_age_p95_s": 1.0, "nav_error_rms_m": 1.0, "energy_J": 1.0}  # fmt: skip
    other = tmp_path / "other.parquet"
    pd.DataFrame([row | {"realisation": "9d4b06b59c"}]).to_parquet(other)
    _refused(capsys, main(["tune", "compare", str(out), str(out), "--plot", str(png),
                           "--baseline", str(other)]), "its runs are on realisations")  # fmt: skip
    assert not png.exists()
    same = tmp_path / "same.parquet"
    pd.DataFrame([row | {"realisation": r} for r in real]).to_parquet(same)
    assert main(["tune", "compare", str(out), str(out), "--plot", str(png), "--baseline",
                 str(same)]) == 0 and png.exists()  # fmt: skip
    # a search without a feasible trial (propeller_on_s = 0 is impossible for a moving boat)
    empty = tmp_path / "empty"
    assert _tune(_ranges(tmp_path, 'constraint = "propeller_on_s"', name="e.toml"), empty) == 0
    assert len(pd.read_csv(empty / "front.csv")) == 0
    _refused(capsys, main(["tune", "compare", str(out), str(empty)]), "front is empty",
             "no feasible trial")  # fmt: skip


def test_a_suite_front_level_outside_the_range_prints_bounds_that_can_be_typed(
        searched, tmp_path, capsys):  # fmt: skip
    """The bounds were rounded to 6 digits: the printed bound, typed back, was refused."""
    _, _, out = searched
    front = pd.read_csv(out / "front.csv")
    cand = front[front["heldout_front"].astype(bool)]["heldout.energy_J"]
    low, high = float(cand.min()), float(cand.max())
    suite = tmp_path / "m.toml"

    def write(level: float) -> None:
        suite.write_text(
            'name = "tn7-m"\nscenarios = ["case3"]\nduration = 30.0\nseeds = [200]\n'
            'plots = "none"\n[[controllers]]\nlabel = "t"\nname = "hybrid-single"\n'
            f'front = "{out}"\nat = "energy_J"\nlevel = {level!r}\n'
        )  # fmt: skip

    write(high + 1000.0)
    err = _refused(capsys, main(["compare", str(suite), "--out", str(tmp_path / "c"),
                                 "--workers", "1", "--quiet"]), "is outside")  # fmt: skip
    shown = err.split("range [")[1].split("]")[0].split(", ")
    assert [float(v) for v in shown] == [low, high], err
    write(float(shown[1]))  # the printed upper bound is accepted as a level
    assert main(["compare", str(suite), "--out", str(tmp_path / "c"), "--workers", "1",
                 "--quiet", "--no-report"]) == 0  # fmt: skip


def test_tune_compare_refuses_searches_with_no_objective_but_the_matched_one(searched, tmp_path,
                                                                            capsys):  # fmt: skip
    """A one-objective search (energy_J) against another: it printed "nothing to pair: the
    reference has no point on its held-out front ...", exit 0, though both fronts had one."""
    _, _, out = searched
    one = tmp_path / "one"
    assert _tune(_ranges(tmp_path, 'objectives = ["energy_J"]', name="one.toml"), one) == 0
    assert pd.read_csv(one / "front.csv")["heldout_front"].any()
    _refused(capsys, main(["tune", "compare", str(one), str(out), "--at", "energy_J"]),
             "no objective but --at 'energy_J'")  # fmt: skip


def _boxes_overlap(ax, renderer) -> list:
    boxes = [t.get_window_extent(renderer) for t in ax.get_xticklabels() if t.get_text()]
    return [(a, b) for a, b in zip(boxes, boxes[1:], strict=False) if a.x1 > b.x0]


def test_front_png_one_objective_against_the_trial_and_x_labels_apart():
    """front.png of a one-objective search drew the objective against itself (a diagonal);
    with nav_error_rms_m values 0.0072099-0.0073723 (a Case 3 search) the x tick labels
    ran into each other ("0.007200.00724...")."""
    from types import SimpleNamespace

    import matplotlib.pyplot as plt

    from mpcasv.experiments.tune_outputs import front_figure

    a, b, c = "reliable_fix_age_p95_s", "nav_error_rms_m", "energy_J"
    trials = pd.DataFrame({"trial": [0, 1, 2, 3], "state": ["COMPLETE"] * 4,
                           a: [142.5] * 4, b: [0.0072099, 0.0072099, 0.0072099, 0.0072099],
                           c: [19604.0, 11633.6, 19392.9, 19603.9],
                           "collision_domain_s": [0.0] * 4})  # fmt: skip
    front = pd.DataFrame({"trial": [1], f"train.{a}": [142.5], f"train.{b}": [0.0072099],
                          f"train.{c}": [11633.6], f"heldout.{a}": [142.5],
                          f"heldout.{b}": [0.0073723], f"heldout.{c}": [20689.6]})  # fmt: skip
    spec = SimpleNamespace(controller="hybrid-single", objectives=[a, b, c],
                           constraint="collision_domain_s")  # fmt: skip
    fig = front_figure(spec, trials, front)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        for ax in fig.axes:
            assert not _boxes_overlap(ax, renderer), ax.get_xlabel()
    finally:
        plt.close(fig)
    spec1 = SimpleNamespace(controller="hybrid-single", objectives=[c],
                            constraint="collision_domain_s")  # fmt: skip
    fig = front_figure(spec1, trials, front[["trial", f"train.{c}", f"heldout.{c}"]])
    try:
        (ax,) = fig.axes
        assert ax.get_xlabel() == "trial" and ax.get_ylabel().startswith("energy_J")
        xs = sorted(x for coll in ax.collections for x, _ in coll.get_offsets())
        assert xs == [0, 1, 1, 1, 2, 3], xs  # 4 trials + the front point, training and held-out
    finally:
        plt.close(fig)


def test_a_run_without_the_constraint_metric_fails_its_trial(tmp_path):
    """experiments/scenarios/demo.toml has no collision domain: collision_domain_s is NaN in
    every run. The summed constraint skipped the NaNs (0.0) and every trial was "feasible"."""
    (tmp_path / "train.toml").write_text(
        'name = "tn7-demo"\nscenarios = ["demo"]\nduration = 60.0\nseeds = [0, 1]\n'
        'plots = "none"\n[[controllers]]\nlabel = "hybrid"\nsingle = "hybrid-single"\n'
        'preset = "default"\n'
    )  # fmt: skip
    ranges = tmp_path / "demo.toml"
    ranges.write_text('controller = "hybrid-single"\nsuite = "train.toml"\nheldout_seeds = [7]\n'
                      'objectives = ["energy_J", "nav_error_rms_m"]\ntrials = 2\nbatch = 2\n'
                      '[params]\n"speed" = { low = 1.0, high = 2.5 }\n')  # fmt: skip
    out = tmp_path / "out"
    assert _tune(ranges, out) == 0
    parts = pd.concat(pd.read_parquet(p) for p in (out / "train" / "parts").glob("*.parquet"))
    assert len(parts) == 4 and parts["collision_domain_s"].isna().all()
    trials = pd.read_csv(out / "trials.csv")
    assert list(trials["state"]) == ["FAIL", "FAIL"], trials
    assert trials["error"].str.contains("constraint collision_domain_s is missing").all()
    assert len(pd.read_csv(out / "front.csv")) == 0


def test_importance_csv_keeps_its_header_when_too_few_trials_are_complete(searched):
    """2 complete trials (< 4): importance.csv was the one line '""' (pandas: 'Unnamed: 0')."""
    _, _, out = searched
    imp = pd.read_csv(out / "importance.csv")
    assert len(imp) == 0
    assert list(imp.columns) == ["parameter", "reliable_fix_age_p95_s", "nav_error_rms_m",
                                 "energy_J", "front"]  # fmt: skip
    assert "(too few complete trials: fewer than 4)" in (out / "report.md").read_text()


def test_tune_compare_of_two_searches_of_one_controller_names_the_folders(searched, tmp_path):
    """Both sides were "hybrid-single" (and a verdict "hybrid-single better" named neither)."""
    import shutil

    from mpcasv.experiments.tune_compare import matched_comparison

    _, _, out = searched
    copy = tmp_path / "again"
    shutil.copytree(out, copy)
    df = matched_comparison(out, copy)
    assert len(df) and set(df["ref"]) == {"hybrid-single (out)"}
    assert set(df["other"]) == {"hybrid-single (again)"}


def test_a_suite_asking_for_heldout_means_of_a_front_without_them_is_refused(tmp_path, capsys):
    """front_means = "heldout" on a search run with --no-heldout silently matched on the
    training means (the default, no front_means, still does, and says so)."""
    out = tmp_path / "nohold"
    assert _tune(_ranges(tmp_path), out, "--no-heldout") == 0
    level = float(pd.read_csv(out / "front.csv")["train.energy_J"].iloc[0])
    suite = tmp_path / "m.toml"
    body = ('name = "tn7-h"\nscenarios = ["case3"]\nduration = 30.0\nseeds = [200]\n'
            'plots = "none"\n[[controllers]]\nlabel = "t"\nname = "hybrid-single"\n'
            f'front = "{out}"\nat = "energy_J"\nlevel = {level!r}\n')  # fmt: skip
    suite.write_text(body + 'front_means = "heldout"\n')
    _refused(capsys, main(["compare", str(suite), "--out", str(tmp_path / "c"), "--workers",
                           "1", "--quiet", "--no-report"]),
             "front_means = 'heldout'", "no held-out means")  # fmt: skip
    suite.write_text(body)
    assert main(["compare", str(suite), "--out", str(tmp_path / "c"), "--workers", "1",
                 "--quiet", "--no-report"]) == 0  # fmt: skip
    assert "training mean" in capsys.readouterr().out


def test_resuming_with_another_search_says_what_differs(searched, tmp_path, capsys):
    """It said "other ['train_jobs']" / "other ['seed']": now the values or what the name
    covers (a changed suite duration is a change of the training jobs)."""
    tmp, _, out = searched
    seed = tmp / "seed.toml"
    seed.write_text((tmp / "ranges.toml").read_text().replace("seed = 1", "seed = 2"))
    _refused(capsys, _tune(seed, out), "seed 1 -> 2", "use another --out")
    (tmp_path / "train.toml").write_text(SUITE.replace("duration = 120.0", "duration = 110.0"))
    longer = tmp_path / "r.toml"
    longer.write_text((tmp / "ranges.toml").read_text())
    _refused(capsys, _tune(longer, out), "training jobs (the suite's scenarios, seeds, duration")


@pytest.mark.parametrize("controller, field, ok", [
    ("hybrid-single", "avoidance.r_keep", True),  # float | None: None = off
    ("mpc-single", "fix.T_quiet", True),
    ("mpc-single", "vessel", False),  # str | None: not a number
])  # fmt: skip
def test_an_optional_number_field_can_be_searched(tmp_path, controller, field, ok):
    """"avoidance.r_keep" was refused: "the preset field is not a number (Optional)"."""
    from mpcasv.config import ConfigError
    from mpcasv.experiments.tune_space import load_spec

    path = tmp_path / "r.toml"
    path.write_text(f'controller = "{controller}"\nsuite = "train.toml"\nheldout_seeds = [7]\n'
                    f'trials = 2\nbatch = 2\n[params]\n"{field}" = {{ low = 20.0, high = 80.0 }}\n')
    if ok:
        assert [p.name for p in load_spec(path).params] == [field]
    else:
        with pytest.raises(ConfigError, match="not a number \\(str\\)"):
            load_spec(path)


def test_presets_of_trials_no_longer_on_the_front_are_removed(searched, tmp_path):
    """Extending a search can push a point off the front (a 2-trial search of Case 3, seed 1:
    front {0}; extended to 6: front {5}); its presets/trial-0000.toml stayed, still saying
    "trial 0 of the training front"."""
    import shutil

    tmp, ranges, out = searched
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    front = set(pd.read_csv(copy / "front.csv")["trial"])
    kept = {p.name for p in (copy / "presets").glob("*.toml")}
    assert kept == {f"trial-{n:04d}.toml" for n in front}
    stale = copy / "presets" / "trial-0099.toml"
    stale.write_text((copy / "presets" / sorted(kept)[0]).read_text())
    mine = copy / "presets" / "trial-0098.toml"
    mine.write_text('controller = "hybrid-single"\n')
    assert _tune(ranges, copy) == 0  # nothing to run: the outputs are rewritten
    assert not stale.exists() and mine.exists()
    assert {p.name for p in (copy / "presets").glob("*.toml")} == kept | {mine.name}


def test_a_second_search_on_a_busy_folder_is_refused(searched, tmp_path, capsys):
    """Two `mpcasv tune controller` on one --out (started twice by mistake) both ran the same
    trials; the second ended on a traceback "ValueError: Cannot tell a COMPLETE trial"."""
    import shutil

    from mpcasv.outputs import folder_lock

    _, ranges, out = searched
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    bigger = _ranges(tmp_path, trials=4, name="r4.toml")
    with folder_lock(copy, "mpcasv tune controller", "tune.lock"):  # the first command
        _refused(capsys, _tune(bigger, copy, "--no-heldout"), "another 'mpcasv tune "
                 "controller' is working in this folder", "(pid ")  # fmt: skip
    assert len(pd.read_csv(copy / "trials.csv")) == 2, "nothing ran"
    assert _tune(bigger, copy, "--no-heldout") == 0  # free again
    assert len(pd.read_csv(copy / "trials.csv")) == 4


def test_simulating_a_tuned_preset_of_another_controller_says_how(searched, tmp_path, capsys):
    """`mpcasv simulate case3.toml --params presets/trial-N.toml` of an mpc-single search
    (Case 3's controller is hybrid-single) only said "choose a preset of 'hybrid-single'";
    here a hybrid-single point's preset given to mpc-single."""
    _, _, out = searched
    preset = sorted((out / "presets").glob("*.toml"))[0]
    case3 = Path(__file__).resolve().parents[1] / "experiments" / "scenarios" / "case3.toml"
    code = main(["simulate", str(case3), "--controller", "mpc-single", "--params", str(preset),
                 "--duration", "5", "--out", str(tmp_path / "s"), "--no-plots", "--quiet"])
    _refused(capsys, code, "not for 'mpc-single'", "its controller ('hybrid-single')")


def test_tune_compare_finds_the_runs_a_repeated_trial_shares(searched, tmp_path):
    """NSGA-II repeats points (Case 3 at 150 s, seed 5, 8 trials: trials 4 and 7 the same
    values); a repeat reuses the runs, stored under the first runner's name (here trial 7's).
    `tune compare` selected runs by name: matched to trial 4 it had "n 0, no pairs"."""
    import shutil

    from mpcasv.experiments.tune_compare import matched_comparison

    _, _, out = searched
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    for part in (copy / "heldout" / "parts").glob("*.parquet"):  # runs stored by another
        df = pd.read_parquet(part)  # trial with the same values
        df["variant"] = "hybrid[trial=99]"
        df.to_parquet(part)
    df = matched_comparison(out, copy)
    assert len(df) and (df["n"] == 1).all(), df[["other_trial", "metric", "n", "note"]]
