"""Comparison at matched operating points inside ``mpcasv compare`` (issue 17 item 3): a suite
entry names a tuned front, a metric and a level; the front point nearest the level runs with
its preset on the suite's seeds, the choice and the achieved level are in the report, the
paired statistics compare the entries; bad fronts/levels are refused in one line (exit 2).

The fronts are built here with a tiny budget (hybrid-single, Cases 1 and 3 cut to 60 s,
one training seed, 6 trials, two objectives).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from mpcasv.cli import main

DUR = 150.0  # s: long enough for the ASV to move in both cases (energy differs per trial)


def _tune(tmp: Path, name: str, seed: int) -> Path:
    """A finished tiny search in ``tmp/name`` (held-out seed 7); its folder."""
    (tmp / "train.toml").write_text(
        f'name = "tiny-train"\nscenarios = ["case1", "case3"]\nduration = {DUR}\nseeds = [0]\n'
        'plots = "none"\n[[controllers]]\nlabel = "hybrid"\nsingle = "hybrid-single"\n'
        'preset = "scenario"\n'
    )
    ranges = tmp / f"{name}.toml"
    ranges.write_text(
        'controller = "hybrid-single"\nsuite = "train.toml"\nheldout_seeds = [7]\n'
        'objectives = ["min_range_m", "energy_J"]\n'
        f"trials = 6\nbatch = 3\nseed = {seed}\n[params]\n"
        '"domain.alpha_inner" = { low = 3.0, high = 10.0 }\n'
        '"speed" = { low = 1.0, high = 2.5 }\n'
    )
    out = tmp / name
    assert main(["tune", "controller", str(ranges), "--out", str(out), "--workers", "1",
                 "--quiet"]) == 0  # fmt: skip
    return out


@pytest.fixture(scope="module")
def fronts(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fronts")
    return _tune(tmp, "a", 1), _tune(tmp, "b", 2)


def _candidates(folder: Path) -> pd.DataFrame:
    front = pd.read_csv(folder / "front.csv")
    return front[front["heldout_front"].astype(bool)]


def _suite(tmp: Path, entries: str, seeds: str = "[20, 21, 22, 23, 24, 25]") -> Path:
    path = tmp / "matched.toml"
    path.write_text(
        f'name = "matched"\nscenarios = ["case1", "case3"]\nduration = {DUR}\nseeds = {seeds}\n'
        f'plots = "none"\n{entries}'
    )
    return path


def _entry(label: str, folder: Path, level: float, at: str = "energy_J",
           name: str = "hybrid-single", extra: str = "") -> str:  # fmt: skip
    return (f'[[controllers]]\nlabel = "{label}"\nname = "{name}"\nfront = "{folder}"\n'
            f'at = "{at}"\nlevel = {level!r}\n{extra}\n')  # fmt: skip


def test_front_entries_run_the_point_nearest_the_level_with_paired_statistics(fronts, tmp_path):
    from mpcasv.controllers import load_preset
    from mpcasv.experiments.suite import expand

    a, b = fronts
    ca, cb = _candidates(a), _candidates(b)
    assert len(ca) >= 2, "the tiny front has one point: nothing to choose; pick other seeds"
    # a level inside each front's held-out energy range (the two fronts need not overlap)
    level = {k: float(0.3 * c["heldout.energy_J"].min() + 0.7 * c["heldout.energy_J"].max())
             for k, c in (("a", ca), ("b", cb))}  # fmt: skip
    suite = _suite(tmp_path, _entry("a", a, level["a"]) + _entry("b", b, level["b"]))
    exp = expand(suite)
    want = {}
    for label, c in (("a", ca), ("b", cb)):
        d = (c["heldout.energy_J"] - level[label]).abs()
        want[label] = int(c.loc[d[d == d.min()].index, "trial"].min())
    assert {f.label: f.trial for f in exp.fronts} == want
    # each job runs the chosen trial's preset of its scenario group (paper1-sim / -field)
    for j in exp.jobs:
        stem = f"trial-{want[j.label]:04d}-{j.scenario}.toml"
        assert Path(j.preset).name == stem, (j.preset, stem)
    out = tmp_path / "out"
    assert main(["compare", str(suite), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    res = pd.read_parquet(out / "results.parquet")
    assert len(res) == 2 * 2 * 6 and (res["status"] == "ok").all()
    for label, folder in (("a", a), ("b", b)):  # the runs used the chosen trial's values
        row = pd.read_csv(folder / "front.csv").set_index("trial").loc[want[label]]
        for preset in res.loc[res["label"] == label, "preset"].unique():
            params = load_preset("hybrid-single", preset)
            assert params.domain.alpha_inner == row["domain.alpha_inner"]
            assert params.speed == row["speed"]
    report = (out / "report.md").read_text()
    assert "## Matched operating points" in report
    sec = report[report.index("## Matched operating points"):report.index("## Headline")]
    for label in ("a", "b"):
        achieved = res.loc[res["label"] == label, "energy_J"].mean()
        line = next(ln for ln in sec.splitlines() if ln.startswith(f"| {label} |"))
        assert f"| {want[label]} |" in line and f"{float(f'{achieved:.5g}')}" in line, line
    # the paired statistics of the fair comparison: b against a, 6 pairs per case (enough
    # for a statistic: stats.MIN_PAIRS; with 5 every row had become n/a, session 43)
    assert "Δ = b − a" in report
    assert "| case1 | 6 |" in report and "| case3 | 6 |" in report


def test_training_means_are_used_without_held_out_runs(fronts, tmp_path):
    """A folder without held-out columns: the training front's means are matched."""
    from mpcasv.experiments.tune_match import choose_front

    a = fronts[0]
    copy = tmp_path / "a"
    copy.mkdir()
    front = pd.read_csv(a / "front.csv")
    front.drop(columns=[c for c in front if c.startswith("heldout")]).to_csv(
        copy / "front.csv", index=False)  # fmt: skip
    (copy / "tune.json").write_text((a / "tune.json").read_text())
    (copy / "presets").symlink_to(a / "presets")
    top = float(front["train.energy_J"].max())
    c = choose_front("a", str(copy), "energy_J", top, tmp_path, "here")
    assert c.source == "training" and c.front_level == top
    assert c.trial == int(front.loc[front["train.energy_J"] == top, "trial"].min())


def test_front_means_training_chooses_by_training_means(fronts, tmp_path):
    """``front_means = "training"``: the whole training front, its training means, although
    the folder has held-out runs (expansion only: nothing runs)."""
    from mpcasv.experiments.suite import expand

    a = fronts[0]
    front = pd.read_csv(a / "front.csv")
    t = front["train.energy_J"]
    level = float(0.5 * (t.min() + t.max()))
    suite = _suite(tmp_path, _entry("a", a, level, extra='front_means = "training"'))
    (choice,) = expand(suite).fronts
    d = (t - level).abs()
    assert choice.source == "training" and choice.candidates == len(front)
    assert choice.trial == int(front.loc[d[d == d.min()].index, "trial"].min())
    assert choice.front_level == float(front.set_index("trial").loc[choice.trial,
                                                                    "train.energy_J"])


def _refused(capsys, suite: Path, out: Path, *causes: str) -> None:
    assert main(["compare", str(suite), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for cause in causes:
        assert cause in err, (cause, err)
    assert not out.exists()


def test_bad_front_entries_are_refused_in_one_line(fronts, tmp_path, capsys):
    a = fronts[0]
    c = _candidates(a)["heldout.energy_J"]
    mid = float(c.median())
    out = tmp_path / "o"
    cases = [
        (_entry("a", tmp_path / "nowhere", mid), ["front folder", "not found"]),
        (_entry("a", tmp_path, mid), ["no tune.json", "not an output folder"]),
        (_entry("a", a, mid, at="energy_Joules"), ["unknown metric", "energy_Joules"]),
        (_entry("a", a, mid, at="nav_error_rms_m"), ["not an objective", "nav_error_rms_m"]),
        (_entry("a", a, float(c.max()) * 1.5), ["outside the front's energy_J range"]),
        (_entry("a", a, float(c.min()) * 0.5), ["outside the front's energy_J range"]),
        (_entry("a", a, mid, name="mpc-single"), ["tuned 'hybrid-single'", "not 'mpc-single'"]),
        (_entry("a", a, mid, extra='preset = "paper1-sim"'), ["drop ['preset']"]),
        ('[[controllers]]\nlabel = "a"\nname = "hybrid-single"\nlevel = 1.0\n',
         ["['level'] without 'front'"]),
        # review (session 5): 'at' alone (a matched operating point, no front) ran silently
        ('[[controllers]]\nlabel = "a"\nname = "hybrid-single"\nat = "energy_J"\n',
         ["['at'] without 'front'"]),
        (_entry("a", a, mid, extra='front_means = "test"'), ["front_means"]),
        (f'[[controllers]]\nlabel = "a"\nname = "hybrid-single"\nfront = "{a}"\n',
         ["'front' needs 'level'"]),
    ]  # fmt: skip
    for entry, causes in cases:
        _refused(capsys, _suite(tmp_path, entry), out, "matched.toml", *causes)


def test_a_scenario_without_a_preset_of_the_point_is_refused(fronts, tmp_path, capsys):
    """The tiny fronts were tuned on Cases 1 and 3 (presets per scenario group): Case 4 has
    none."""
    a = fronts[0]
    mid = float(_candidates(a)["heldout.energy_J"].median())
    suite = tmp_path / "matched.toml"
    suite.write_text('name = "matched"\nscenarios = ["case1", "case4"]\nduration = 60.0\n'
                     f'seeds = [0]\nplots = "none"\n{_entry("a", a, mid)}')  # fmt: skip
    _refused(capsys, suite, tmp_path / "o", "for scenarios ['case1', 'case3'] only", "'case4'")
