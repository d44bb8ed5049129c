"""Counts in the comparison report and the commands' lines agree in number: a new user read
"n/a: 1 pairs < 6" in the report (and "1 errors", "1 jobs have not run", "0 of 1 targets
met", "held-out: 1 front trials x 2 runs" elsewhere)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mpcasv.experiments import stats
from mpcasv.wording import count, noun


def test_count_says_one_thing_and_several_things():
    assert count(1, "pair") == "1 pair" and count(0, "pair") == "0 pairs"
    assert count(2, "world") == "2 worlds" and noun(1, "has", "have") == "has"
    assert noun(3, "has", "have") == "have"


@pytest.mark.parametrize("n, note", [(1, "n/a: 1 pair < 6"), (2, "n/a: 2 pairs < 6")])
def test_too_few_pairs_note(n, note):
    assert stats.MIN_PAIRS == 6
    s = stats.paired_stat([1.0] * n, [2.0] * n)
    assert s.note == note


def test_rows_sharing_a_pairing_key_are_counted_all():
    """Two ok rows of one variant on one key were "1 rows share a pairing key"."""
    rows = pd.DataFrame({"scenario": ["case3"] * 3, "seed": [0, 0, 0],
                         "variant": ["a", "a", "b"], "status": ["ok"] * 3,
                         "current": ["off"] * 3, "estimator": ["kf"] * 3})  # fmt: skip
    why = stats.comparison_problem(rows)
    assert why is not None and why.startswith("a: 2 rows share a pairing key"), why


def test_a_missing_time_series_of_one_run_is_said_in_the_singular(tmp_path):
    from mpcasv.experiments.report_series import ecdf_panels

    ok = pd.DataFrame({"scenario": ["case3"], "variant": ["hybrid"], "auv_names": ["auv1"],
                       "run_dir": [None], "reliable_fix_age_p95_s": [10.0]})  # fmt: skip
    _, notes = ecdf_panels(tmp_path, ok, "case3")
    assert notes[0] == "1 of 1 run has no time series here", notes


def test_tune_report_counts_one_front_trial():
    """report.md of a search whose front is one trial said "the 1 front trials x 2 runs"."""
    from types import SimpleNamespace

    from mpcasv.experiments import tune_outputs

    spec = SimpleNamespace(controller="hybrid-single", path=Path("ranges.toml"), sampler="nsga2",
                           batch=1, seed=0, trials=1, constraint="collision_domain_s")  # fmt: skip
    s = {"params": ["speed"], "objectives": ["energy_J", "reliable_fixes"],
         "constraint": "collision_domain_s", "trials": {"COMPLETE": 1}, "feasible_trials": 1,
         "least_violation": [0, 0.0], "runs": {"training": 1, "heldout": 1},
         "training": {"runs_per_trial": 1, "scenarios": ["case3"], "seeds": [0],
                      "duration_s": [120.0], "realisations": ["x"]},
         "heldout": {"front_trials_run": 1, "runs_per_trial": 1, "seeds": [7],
                     "realisations": ["y"]},
         "wall_s": {"search": 1.0, "sessions": 1, "heldout": 1.0}}  # fmt: skip
    text = tune_outputs._report(spec, s, pd.DataFrame({"trial": [0]}), pd.DataFrame())
    assert "batches of 1 trial," in text and "**budget: 1 trial**" in text
    assert "1 training run " in text
    assert "the 1 front trial x 1 run (seeds" in text and "; 1 run\n" in text


def test_a_table_of_n_a_comparisons_says_none_was_tested(tmp_path):
    """The methods say "each table says how many tests it holds", but with every comparison
    n/a (4 worlds a case, fewer than stats.MIN_PAIRS) the table said nothing about tests."""
    from types import SimpleNamespace

    from mpcasv.experiments.report import write_report

    rows = [{"index": i, "suite": "s", "scenario": "c1", "variant": v, "current": "off",
             "estimator": "perfect", "seed": seed, "status": "ok", "auv_names": "auv1",
             "run_dir": f"runs/{v}-{seed}", "min_range_m": 100.0 + seed + (v == "mpc")}
            for i, (seed, v) in enumerate((s, v) for s in range(4) for v in ("hybrid", "mpc"))]
    df = pd.DataFrame(rows)
    exp = SimpleNamespace(suite=SimpleNamespace(name="s", description="", seeds=list(range(4))),
                          jobs=list(range(len(df))), skipped=[])  # fmt: skip
    md = write_report(tmp_path, exp, df)[0].read_text()
    assert "each table says how many tests it holds" in md
    section = md.split("### mpc vs hybrid")[1].split("\n## ")[0]
    line = next((ln for ln in section.splitlines() if "Multiple comparisons" in ln), None)
    assert line is not None and "none tested in this table" in line, section
    assert "n/a: 4 pairs < 6" in section


@pytest.mark.parametrize("n_auv, inner", [(1, "inside r_inner"), (2, "inside r_avoid")])
def test_the_compare_figure_names_the_domain_as_the_runs_range_figure(tmp_path, monkeypatch,
                                                                      n_auv, inner):
    """A new user's two-AUV report (session 45): the compare figure's range panel read
    "inside r_inner" and listed an r_outer line that Paper 2's domain (r_outer 3500 m) never
    drew; the run's own range figure says r_avoid and leaves r_outer out."""
    from mpcasv.experiments import report_series

    t = np.arange(0.0, 100.0, 1.0)
    r_outer = 3500.0 if n_auv > 1 else 300.0
    ts = {"t": t, "N": 0 * t, "E": 0 * t}
    for k in range(n_auv):
        ts |= {f"auv{k}_N": 100.0 + t, f"auv{k}_E": 0 * t, f"range{k}": 100.0 + t,
               f"r_inner{k}": 0 * t + 50.0, f"r_t{k}": 0 * t + 90.0,
               f"r_outer{k}": 0 * t + r_outer, f"rfix_age{k}": t % 20}  # fmt: skip
    for v in ("A", "B"):
        (tmp_path / "runs" / v).mkdir(parents=True)
        pd.DataFrame(ts).to_parquet(tmp_path / "runs" / v / "timeseries.parquet")
    reps = pd.DataFrame({"variant": ["A", "B"], "run_dir": ["runs/A", "runs/B"],
                         "auv_names": [",".join(f"a{k}" for k in range(n_auv))] * 2,
                         "seed": [0, 0], "current": ["off"] * 2,
                         "estimator": ["perfect"] * 2})  # fmt: skip
    figs = []
    monkeypatch.setattr(report_series, "_save", lambda fig, path: figs.append(fig) or path)
    report_series.compare_figure(tmp_path, reps, "s", tmp_path / "c.png")
    labels = [t.get_text() for t in figs[0].axes[1].get_legend().get_texts()]
    assert inner in labels and ("r_outer" in labels) == (n_auv == 1), labels
    assert figs[0].axes[1].get_ylim()[1] >= (1.1 * r_outer if n_auv == 1 else 199.0 * 1.1)
