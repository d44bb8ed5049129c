"""``mpcasv compare`` end to end on the quick suite: 1 worker, 2 local workers and a Dask
LocalCluster give identical results; the results table and the report."""

from __future__ import annotations

import json
import re
import warnings

import numpy as np
import pandas as pd
import pytest

from mpcasv.cli import main
from mpcasv.experiments.metrics import METRIC_NAMES
from mpcasv.experiments.report import BETTER, directions, summary_table
from mpcasv.experiments.runner import run_suite
from mpcasv.experiments.stats import paired_table
from mpcasv.experiments.store import TIMING_COLUMNS
from mpcasv.experiments.suite import expand

QUICK = expand("quick")


def _comparable(df: pd.DataFrame) -> pd.DataFrame:
    """The results without the machine's timings (wall time, controller step times)."""
    return df[[c for c in df.columns if c not in TIMING_COLUMNS]]


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    rc = main(["compare", "quick", "--out", str(out), "--workers", "1", "--quiet"])
    return rc, out, pd.read_parquet(out / "results.parquet")


def test_quick_suite_runs_every_job_once_and_writes_its_run(serial):
    rc, out, df = serial
    assert rc == 0
    assert list(df["job_id"]) == [j.job_id for j in QUICK.jobs]  # suite order, each once
    assert (df["status"] == "ok").all()
    for _, row in df.iterrows():
        metrics = json.loads((out / row["run_dir"] / "metrics.json").read_text())
        assert set(metrics) == set(METRIC_NAMES)
        assert row["min_range_m"] == pytest.approx(metrics["min_range_m"])
        for k, v in enumerate(metrics["fixes_auv"]):  # per-AUV lists expanded
            assert row[f"fixes_auv{k}"] == v
    assert sorted(p.stem for p in (out / "parts").glob("*.parquet")) == sorted(df["job_id"])
    # the grid, the currents and the seeds all reach the simulation
    assert df.groupby("variant")["asv_distance_m"].mean().nunique() == 2
    assert df.groupby("current")["energy_J"].mean().nunique() == 2
    assert df.groupby("seed")["fixes_auv0"].apply(list).map(tuple).nunique() == 2


@pytest.fixture(scope="module")
def pool(tmp_path_factory):
    out = tmp_path_factory.mktemp("pool")
    return out, run_suite("quick", out, workers=2, quiet=True, report=False)[2]


def test_two_local_workers_and_dask_give_identical_results(serial, pool, tmp_path):
    distributed = pytest.importorskip("distributed")
    _, _, ref = serial
    pool_out, pool = pool
    pd.testing.assert_frame_equal(_comparable(pool), _comparable(ref))
    assert pool["worker"].nunique() == 2  # both workers did jobs
    # (HTTP on a free loopback port: 8787, the default even with None, may be taken by a
    # parallel test's cluster; the retry then leaked a socket)
    with distributed.LocalCluster(processes=True, n_workers=2, threads_per_worker=1,
                                  dashboard_address="127.0.0.1:0") as cluster:  # fmt: skip
        stats, _, dask = run_suite("quick", tmp_path / "dask", dask=cluster.scheduler_address,
                                   quiet=True, report=False,
                                   runs_dir=tmp_path / "dask" / "runs")  # fmt: skip
    assert stats.workers == 2 and stats.ok == len(QUICK.jobs)
    pd.testing.assert_frame_equal(_comparable(dask), _comparable(ref))
    # rerunning a finished sweep runs nothing and changes nothing
    stats, _, again = run_suite("quick", pool_out, workers=2, quiet=True, report=False)
    assert stats.ran == 0 and stats.already_done == len(QUICK.jobs)
    pd.testing.assert_frame_equal(again, pool)


def test_report_has_every_metric_per_scenario_and_its_figures(serial):
    _, out, df = serial
    md = (out / "report.md").read_text()
    page = (out / "report.html").read_text()
    assert 'pd.read_parquet("' in md and str(out / "results.parquet") in md
    for scenario in df["scenario"].unique():
        assert f"## {scenario}" in md
        for fig in (f"box-{scenario}.png", f"compare-{scenario}.png"):
            assert (out / "figures" / fig).stat().st_size > 10_000
            assert f"figures/{fig}" in md
    for scenario in df["scenario"].unique():  # ECDFs of fix age and navigation error
        assert (out / "figures" / f"ecdf-{scenario}.png").stat().st_size > 10_000
    # per scenario: ECDF, representative runs, box plots; one forest plot per compared pair
    n_pairs = df["variant"].nunique() - 1
    assert page.count("data:image/png;base64,") == 3 * df["scenario"].nunique() + n_pairs
    for m in METRIC_NAMES:  # a per-AUV list with a scalar: its rows go by the scalar's name
        row = m[:-4] if m.endswith("_auv") and m[:-4] in METRIC_NAMES else m
        assert f"| {row} " in md, m
    assert not any(f"| {m} [" in md for m in METRIC_NAMES if m[:-4] in METRIC_NAMES)
    # one cell checked against pandas: case8, first variant, current off, min_range_m
    v = df["variant"].iloc[0]
    g = df[(df["scenario"] == "case8") & (df["variant"] == v) & (df["current"] == "off")]
    mean, sd = g["min_range_m"].mean(), g["min_range_m"].std()
    section = md.split("## case8")[1]
    line = next(ln for ln in section.splitlines() if ln.startswith("| min_range_m "))
    first = line.split("|")[2].strip()
    assert re.fullmatch(r"[-\d.e+]+ ± [-\d.e+]+", first)
    got_mean, got_sd = (float(x) for x in first.split(" ± "))
    assert got_mean == pytest.approx(mean, rel=1e-3) and got_sd == pytest.approx(
        sd, rel=1e-3, abs=1e-9
    )
    # per-AUV metrics have one row per AUV, named, once
    for name in df.loc[df["scenario"] == "case8", "auv_names"].iloc[0].split(","):
        assert section.split("\n## ")[0].count(f"| fixes [{name}] ") == 1
    # the wins and losses count no wall-clock metric (machine and load, never compared: it
    # gave the hybrids 8 "better" on controller step time in the paper report)
    from mpcasv.experiments.metric_info import WALL_CLOCK

    wins = md.split("## Significant wins and losses")[1].split("\n## ")[0]
    assert "| reliable_fix_age_max_s " in wins or "| min_range_m " in wins, wins
    assert not any(f"| {m} " in wins for m in WALL_CLOCK), wins


def test_same_suite_and_seeds_give_the_same_report_numbers(serial, pool):
    _, _, ref = serial
    _, again = pool  # another sweep of the same suite (and another backend)
    timing = {"controller_step_ms_median", "controller_step_ms_p99"}
    a, b = summary_table(ref), summary_table(again)
    a, b = a[~a["metric"].isin(timing)], b[~b["metric"].isin(timing)]
    pd.testing.assert_frame_equal(a.reset_index(drop=True), b.reset_index(drop=True))
    metrics = [m for m in BETTER if BETTER[m] and m in ref and m not in timing]
    pa, pb = paired_table(ref, metrics, directions()), paired_table(again, metrics, directions())
    pd.testing.assert_frame_equal(pa, pb)  # the bootstrap is seeded


def test_every_metric_has_a_direction():
    assert set(BETTER) == set(METRIC_NAMES)
    assert set(BETTER.values()) <= {"higher", "lower", None}


def test_summary_table_gives_mean_sd_and_n_over_seeds():
    # the paired statistics and their win/loss counts: tests/test_report_stats.py
    rows = []
    values = {("s1", "A"): (50.0, 9.0), ("s1", "B"): (40.0, 5.0),
              ("s2", "A"): (30.0, 1.0), ("s2", "B"): (30.0, 2.0)}  # fmt: skip
    for (s, v), (r, e) in values.items():
        for seed, noise in enumerate((-1.0, 1.0)):
            rows.append(
                {
                    "scenario": s,
                    "variant": v,
                    "current": "off",
                    "estimator": "perfect",
                    "seed": seed,
                    "status": "ok",
                    "min_range_m": r + noise,
                    "energy_J": e + noise,
                    "fixes_auv0": 3,
                    "fixes_auv1": 1 + seed,
                }
            )
    summ = summary_table(pd.DataFrame(rows))
    cell = summ[(summ["scenario"] == "s1") & (summ["variant"] == "A")
                & (summ["metric"] == "min_range_m")].iloc[0]  # fmt: skip
    assert cell["mean"] == 50.0 and cell["sd"] == pytest.approx(np.sqrt(2.0)) and cell["n"] == 2
    cell = summ[(summ["scenario"] == "s2") & (summ["variant"] == "B")
                & (summ["column"] == "fixes_auv1")].iloc[0]  # fmt: skip
    assert cell["mean"] == 1.5 and cell["auv"] == 1 and cell["n"] == 2


def test_a_mean_over_fewer_runs_than_the_group_says_how_many():
    """A metric undefined (null) in some runs of a group: the mean of the others is not the
    group's. In the paper suite's Case 8 (session 43) the hybrid's four worst worlds, whose
    ``revisit_interval_max_s`` was null then, dropped out silently ("363.3 ± 75.48" over 6 of
    10 runs, beside the MPC's over 10; a statistician's review, session 44)."""
    from mpcasv.experiments.report import scenario_table

    rows = [{"scenario": "s", "variant": v, "current": "off", "estimator": "perfect",
             "seed": seed, "status": "ok", "min_range_m": 10.0 + seed,
             "revisit_interval_max_s": None if v == "A" and seed >= 3 else 100.0 + seed}
            for v in ("A", "B") for seed in range(5)]  # fmt: skip
    df = pd.DataFrame(rows)
    df["revisit_interval_max_s"] = df["revisit_interval_max_s"].astype(float)
    summ = summary_table(df)
    got = summ.set_index(["variant", "metric"])
    assert got.loc[("A", "revisit_interval_max_s"), ["n", "runs"]].tolist() == [3, 5]
    assert got.loc[("B", "revisit_interval_max_s"), ["n", "runs"]].tolist() == [5, 5]
    t = scenario_table(summ, "s", ["auv1"])
    assert t.loc["revisit_interval_max_s", "A"] == "101 ± 1 (3 of 5 runs)"
    assert t.loc["revisit_interval_max_s", "B"] == "102 ± 1.581"
    assert t.loc["min_range_m", "A"] == "12 ± 1.581"
    # an infinite value (an AUV never reliably fixed) is a value: the mean is inf, quietly
    # (pandas' sd of it warned "invalid value encountered in subtract" in the main job)
    df.loc[(df.variant == "B") & (df.seed == 0), "revisit_interval_max_s"] = np.inf
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        summ = summary_table(df)
    t = scenario_table(summ, "s", ["auv1"])
    assert t.loc["revisit_interval_max_s", "B"] == "inf in 1 of 5; the others 102.5 ± 1.291"
    df.loc[df.variant == "B", "revisit_interval_max_s"] = np.inf
    t = scenario_table(summary_table(df), "s", ["auv1"])
    assert t.loc["revisit_interval_max_s", "B"] == "inf in 5 of 5"


def test_report_of_a_sweep_whose_jobs_all_failed_lists_the_errors(tmp_path):
    from mpcasv.experiments.report import write_report

    job = QUICK.jobs[0]
    rows = pd.DataFrame([{"job_id": job.job_id, "index": 0, "scenario": job.scenario,
                          "variant": job.variant, "seed": job.seed, "current": "off",
                          "estimator": job.estimator, "status": "error",
                          "error": "Traceback ...\nRuntimeError: solver exploded\n"}])  # fmt: skip
    md, page = write_report(tmp_path, QUICK, rows)
    text = md.read_text()
    # one failed job: "1 errors" (a hard plural)
    assert "**1 error**" in text and "1 errors" not in text
    assert "RuntimeError: solver exploded" in text
    assert f"**Incomplete**: {len(QUICK.jobs) - 1} jobs have not run" in text
    assert "solver exploded" in page.read_text()


def test_an_unwritable_runs_dir_is_refused_before_any_job(tmp_path, capsys):
    """`--runs-dir /proc/x` ran every job and recorded each as an error (found by a new
    user); it is refused in one line, exit 2, before any job or output folder exists. A
    writable fsspec URL passes the same check."""
    from mpcasv.experiments.runner import check_runs_location

    out = tmp_path / "out"
    assert main(["compare", "quick", "--out", str(out), "--runs-dir", "/proc/x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--runs-dir /proc/x: cannot write in /proc" in err[0]
    assert not out.exists()
    check_runs_location(f"file://{tmp_path / 'remote'}", None)  # no exception
    assert (tmp_path / "remote").is_dir() and not any((tmp_path / "remote").iterdir())


def test_a_second_compare_on_a_busy_folder_is_refused(tmp_path, capsys):
    """Two sweeps in one folder ran the same jobs side by side and both rewrote
    results.parquet and the report; the second is refused at once, exit 2, one line."""
    from mpcasv.experiments.sweep_folder import LOCK_FILE
    from mpcasv.outputs import folder_lock

    out = tmp_path / "out"
    with folder_lock(out, "mpcasv compare", LOCK_FILE):  # a first compare at work
        assert main(["compare", "quick", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another 'mpcasv compare' is working in this folder" in err[0], err
    assert not (out / "parts").exists()


def test_a_resumed_sweep_removes_what_a_killed_one_left_half_written(serial, tmp_path):
    """A kill -9 left hidden temporary copies (runs/.<run name>.*, parts/.*.tmp) that no
    resume removed; the next sweep in the folder removes those of its jobs."""
    import shutil

    _, done, _ = serial
    out = tmp_path / "out"
    shutil.copytree(done, out)
    job = QUICK.jobs[0]
    (out / "parts" / f"{job.job_id}.parquet").unlink()  # the job the kill interrupted
    stale_run = out / "runs" / f".{job.run_name}.k1ll3d"
    stale_run.mkdir()
    (stale_run / "timeseries.parquet").write_bytes(b"half")
    stale_part = out / "parts" / f".{job.job_id}.999.abcdef12.tmp"
    stale_part.write_bytes(b"half")
    # one a sweep of before session 45 left, its run name with another current in it
    old_name = out / "runs" / f".{job.scenario}-{job.variant}-cur9_9-s{job.seed}-{job.job_id[:8]}.x"
    old_name.mkdir()
    other = out / "runs" / f".{QUICK.jobs[1].run_name}.k1ll3d"  # a job that is done: kept
    other.mkdir()
    assert main(["compare", "quick", "--out", str(out), "--quiet", "--no-report"]) == 0
    assert not stale_run.exists() and not stale_part.exists() and not old_name.exists()
    assert other.exists()
    assert (out / "runs" / job.run_name / "metrics.json").is_file()


def test_an_infinite_metric_reaches_the_results_table_as_infinite(tmp_path):
    """``revisit_interval_max_s`` of a run where an AUV was never reliably fixed is infinite,
    the worst a run can do (the paired statistics keep it: ``stats.pairs``). metrics.json has
    null there (JSON); the results row took that null until session 45, and such runs
    dropped out of the pairs as missing (a review)."""
    from mpcasv.experiments.job_worker import run_job

    job = next(j for j in QUICK.jobs if j.scenario == "case8")  # 90 s: not every AUV is fixed
    row = run_job(job, str(tmp_path))
    written = json.loads((tmp_path / job.run_name / "metrics.json").read_text())
    assert row["status"] == "ok", row["error"]
    assert row["revisit_interval_max_s"] == np.inf and written["revisit_interval_max_s"] is None
    assert 0 in written["reliable_fixes_auv"]
