"""Paired statistics of the report (mpcasv.experiments.stats) on synthetic results tables,
and the report rendered from one: headline table first, missing metrics named."""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps

from mpcasv.experiments import stats
from mpcasv.experiments.report import directions, write_report
from mpcasv.experiments.report_series import ENVELOPE_BINS, fix_age_trace
from mpcasv.experiments.stats import HEADLINE, paired_stat, paired_table, significant_win_loss

BETTER = {"min_range_m": "higher", "energy_J": "lower", "nav_error_rms_m": "lower"}


def results(shift: dict[str, float], seeds=range(8), cases=("c1", "c2"),
            variants=("ref", "new"), world_sd: float = 50.0) -> pd.DataFrame:  # fmt: skip
    """One row per (case, current, seed, variant). Each world (case, current, seed) has its
    own level (spread ``world_sd``, far larger than any shift: only pairing finds the shift);
    variant "new" (and any after the first) adds ``shift[metric]``."""
    rng = np.random.default_rng(7)
    rows, index = [], 0
    for case in cases:
        for current in ("off", "0.1,0.1"):
            for seed in seeds:
                world = {m: 100.0 + world_sd * rng.standard_normal() for m in shift}
                for i, v in enumerate(variants):
                    row = {"index": index, "suite": "synthetic", "scenario": case,
                           "variant": v, "current": current, "estimator": "perfect",
                           "seed": seed, "status": "ok", "auv_names": "auv1",
                           "run_dir": f"runs/{case}-{v}-{current}-{seed}"}  # fmt: skip
                    for m, s in shift.items():  # small own noise per run, shift for i > 0
                        row[m] = world[m] + (s if i else 0.0) + 0.05 * rng.standard_normal()
                    rows.append(row)
                    index += 1
    return pd.DataFrame(rows)


def test_a_known_shift_gives_a_ci_excluding_zero_and_a_small_p():
    df = results({"min_range_m": 2.0, "energy_J": 3.0})
    t = paired_table(df, ["min_range_m", "energy_J"], BETTER).set_index(["metric", "case"])
    for case in ("c1", "c2"):
        r = t.loc[("min_range_m", case)]
        assert r["n"] == 16 and r["n_unpaired"] == 0  # 8 seeds x 2 currents
        assert 0 < r["ci_low"] <= 2.0 <= r["ci_high"] and r["median"] == pytest.approx(2, abs=0.1)
        assert r["p"] < 1e-3
        assert r["verdict"] == "new better"  # higher min range is better
        e = t.loc[("energy_J", case)]
        assert e["ci_low"] > 0 and e["p"] < 1e-3
        assert e["verdict"] == "ref better"  # more energy is worse
    # the same shift is invisible without the pairing: the worlds spread far more
    unpaired = df.groupby("variant")["min_range_m"].agg(["mean", "std"])
    assert unpaired["std"].min() > 10 * 2.0


def test_identical_controllers_give_a_ci_containing_zero():
    df = results({"min_range_m": 0.0})  # only the runs' own noise differs
    t = paired_table(df, ["min_range_m"], BETTER)
    assert (t["ci_low"] < 0).all() and (t["ci_high"] > 0).all()
    assert (t["p"] > 0.05).all()
    assert set(t["verdict"]) == {"no significant difference"}
    # exactly equal results: every difference zero, the interval is the point 0, no test
    same = results({"min_range_m": 0.0})
    same.loc[same["variant"] == "new", "min_range_m"] = same.loc[
        same["variant"] == "ref", "min_range_m"
    ].to_numpy()
    t = paired_table(same, ["min_range_m"], BETTER)
    assert (t["ci_low"] == 0).all() and (t["ci_high"] == 0).all() and t["p"].isna().all()
    assert set(t["verdict"]) == {"no difference"}
    assert t["note"].str.contains("differences zero").all()


def test_unpaired_rows_are_excluded_and_counted():
    df = results({"min_range_m": 2.0})
    full = paired_table(df, ["min_range_m"], BETTER).set_index("case")
    # c1: one "new" run failed, one "ref" run has no value, one "ref" run never ran
    new_c1 = df[(df["scenario"] == "c1") & (df["variant"] == "new")].index
    ref_c1 = df[(df["scenario"] == "c1") & (df["variant"] == "ref")].index
    df.loc[new_c1[0], "status"] = "error"
    df.loc[ref_c1[1], "min_range_m"] = np.nan
    df = df.drop(index=ref_c1[2])
    t = paired_table(df, ["min_range_m"], BETTER).set_index("case")
    assert t.loc["c1", "n"] == 16 - 3 and t.loc["c1", "n_unpaired"] == 3
    assert t.loc["c2", "n"] == 16 and t.loc["c2", "n_unpaired"] == 0
    assert t.loc["c2", "ci_low"] == full.loc["c2", "ci_low"]  # c2 untouched
    # the statistic is that of the remaining pairs alone
    pairs, unpaired = stats.pairs(df, "min_range_m", "ref", "new")
    g = pairs[pairs["scenario"] == "c1"]
    assert len(g) == 13 and unpaired["c1"] == 3
    s = paired_stat(g["ref"].to_numpy(), g["other"].to_numpy())
    assert (s.median, s.ci_low, s.ci_high, s.p) == tuple(
        t.loc["c1", ["median", "ci_low", "ci_high", "p"]]
    )


def test_a_different_realisation_is_not_a_pair():
    df = results({"min_range_m": 2.0})
    df["realisation"] = [f"{r.scenario}-{r.current}-{r.seed}" for r in df.itertuples()]
    i = df[(df["scenario"] == "c2") & (df["variant"] == "new")].index[0]
    df.loc[i, "realisation"] = "another world"
    t = paired_table(df, ["min_range_m"], BETTER).set_index("case")
    assert "realisation" in stats.pair_key(df)
    assert t.loc["c2", "n"] == 15 and t.loc["c2", "n_unpaired"] == 2


def test_tiny_n_and_missing_pairs_say_na_with_the_reason():
    df = results({"min_range_m": 2.0}, seeds=range(2))  # 4 pairs per case
    t = paired_table(df, ["min_range_m"], BETTER)
    assert (t["n"] == 4).all() and t["ci_low"].isna().all() and t["p"].isna().all()
    assert t["note"].str.fullmatch(r"n/a: 4 pairs < \d+").all()
    assert set(t["verdict"]) == {"n/a"}
    assert np.isfinite(t["median"]).all()  # the median itself is still shown
    # a case where the other variant never ran: no pairs, every reference row unpaired
    df = results({"min_range_m": 2.0})
    df = df[~((df["scenario"] == "c2") & (df["variant"] == "new"))]
    t = paired_table(df, ["min_range_m"], BETTER).set_index("case")
    assert t.loc["c2", "n"] == 0 and t.loc["c2", "note"] == "no pairs"
    assert t.loc["c2", "n_unpaired"] == 16


def test_a_key_that_does_not_identify_the_job_is_refused():
    df = results({"min_range_m": 2.0})
    df = pd.concat([df, df.iloc[[0]]])
    with pytest.raises(stats.PairingError, match="share a pairing key"):
        paired_table(df, ["min_range_m"], BETTER)


def test_several_variants_are_each_compared_with_the_first():
    df = results({"min_range_m": 2.0}, variants=("hybrid", "mpc", "mpc2"))
    t = paired_table(df, ["min_range_m"], BETTER)
    assert set(t["reference"]) == {"hybrid"} and list(dict.fromkeys(t["other"])) == [
        "mpc", "mpc2"]  # fmt: skip
    wl = significant_win_loss(t).set_index("other")
    assert wl.loc["mpc", "other_better"] == 2 and wl.loc["mpc", "reference_better"] == 0


def test_negligible_significant_differences_get_no_verdict():
    df = results({"min_range_m": 2e-4}, world_sd=1.0)
    df["min_range_m"] = df.groupby(["scenario", "current", "seed"])["min_range_m"].transform(
        "min"
    ) + np.where(df["variant"] == "new", 2e-4, 0.0)  # a deterministic 0.2 mm shift of ~100 m
    t = paired_table(df, ["min_range_m"], BETTER)
    assert (t["p"] < 1e-3).all() and (t["ci_low"] > 0).all()
    assert set(t["verdict"]) == {"negligible difference"}


def test_bootstrap_is_reproducible_and_warning_free():
    df = results({"min_range_m": 1.0, "energy_J": -1.0})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        a = paired_table(df, ["min_range_m", "energy_J"], BETTER)
        b = paired_table(df, ["min_range_m", "energy_J"], BETTER)
    pd.testing.assert_frame_equal(a, b)


def test_headline_spec_agrees_with_metrics_module_when_it_defines_metric_info():
    from mpcasv.experiments import metrics

    info = getattr(metrics, "METRIC_INFO", None)
    if info is None:
        pytest.skip("mpcasv.experiments.metrics has no METRIC_INFO yet (CONTRACT.md)")
    assert tuple(h.name for h in HEADLINE) == tuple(metrics.HEADLINE)
    for h in HEADLINE:
        assert info[h.name].better == h.better and info[h.name].unit == h.unit, h.name


def test_long_fix_age_series_is_drawn_as_its_envelope():
    t = np.arange(0.0, 14_000.0)  # a Case 5 length at 1 Hz, a fix every 7 s
    age = t % 7.0
    age[5000:5100] = np.arange(100.0)  # one long gap
    tt, a, suffix = fix_age_trace(t, age)
    assert len(tt) <= ENVELOPE_BINS and "max per" in suffix
    assert a.max() == 99.0 and a.min() == 6.0  # the gap kept, each window's peak
    short_t, short_age = t[:200], age[:200]  # 28 fixes: drawn as it is
    tt, a, suffix = fix_age_trace(short_t, short_age)
    assert suffix == "" and np.array_equal(a, short_age)


def _exp(df: pd.DataFrame) -> SimpleNamespace:
    suite = SimpleNamespace(name="synthetic", description="synthetic results", seeds=[0, 1])
    return SimpleNamespace(suite=suite, jobs=list(range(len(df))), skipped=[])


def test_report_opens_with_the_headline_table_and_names_missing_metrics(tmp_path):
    present = ["min_range_m", "energy_J", "nav_error_rms_m", "nav_error_p95_m", "propeller_on_s"]
    df = results({m: 2.0 for m in present}, variants=("hybrid", "mpc", "mpc2"))
    md_path, html_path = write_report(tmp_path, _exp(df), df)
    md = md_path.read_text()
    headings = [ln for ln in md.splitlines() if ln.startswith("## ")]
    assert headings[0] == "## Headline: paired differences"
    assert md.index("## Headline") < md.index("| metric | case | pairs |")
    assert md.index("| metric | case | pairs |") < md.index("## Significant wins")
    missing = [h.name for h in HEADLINE if h.name not in present]
    line = next(ln for ln in md.splitlines() if "Missing headline metrics" in ln)
    assert all(m in line for m in missing) and not any(m in line for m in present)
    assert "Reference: **hybrid**" in md and "each of mpc, mpc2 is compared with it" in md
    # the min range row of case c1, mpc vs hybrid, against the statistics module
    t = paired_table(df, ["min_range_m"], directions()).set_index(["other", "case"])
    r = t.loc[("mpc", "c1")]
    section = md.split("### mpc vs hybrid")[1]
    row = next(ln for ln in section.splitlines() if ln.startswith("| min_range_m"))
    assert "| c1 | 16 |" in row and "mpc better" in row and f"{r['p']:.2g}" in row
    for other in ("mpc", "mpc2"):
        assert (tmp_path / "figures" / f"forest-{other}.png").stat().st_size > 10_000
    # no time series in the synthetic run folders: said, and the ECDF falls back visibly
    assert "No figure of the representative runs: no time series in runs/c1-" in md
    assert "48 of 48 runs have no time series here" in md
    assert "AUV navigation error: ECDF over runs of nav_error_p95_m (no time series)" in md
    assert "acoustic fix age: neither time series nor fix_age_p95_s available" in md
    assert "reliable-fix age τ: neither time series nor reliable_fix_age_p95_s" in md
    assert (tmp_path / "figures" / "ecdf-c1.png").stat().st_size > 10_000
    page = html_path.read_text()
    assert page.index("Headline: paired differences") < page.index("The sweep")


@pytest.mark.parametrize("d", [
    [0, 0, 1, 2, 2, 3, -1, 4],  # zeros and ties: scipy's own (slow) permutation test
    [1, 1, 1, 2, 2, -3, 5, 0, 0, 0, 7, 1, 1],  # n = 13, the largest exact case
    [1, 2, 3, 4, 5, -6],  # no ties: exact distribution
    [1, 1, 1, 1, 1, 1],
    [0, 0, 0, 0, 0, 0, 0, 0, 0, 3],  # one non-zero difference (a real Case 1 min range)
    [3, -1, 2, 2, 0, 5, 1, 4, -2, 6, 7, 8, 1, 9],  # n = 14 with ties: normal approximation
])  # fmt: skip
def test_wilcoxon_p_equals_scipy_wilcoxon(d):
    d = np.asarray(d, float)
    assert stats.wilcoxon_p(d) == pytest.approx(
        sps.wilcoxon(d, zero_method="wilcox").pvalue, rel=1e-12
    )


def test_report_says_why_when_the_table_cannot_be_paired(tmp_path):
    df = results({"min_range_m": 2.0})
    df = pd.concat([df, df.iloc[[0]].assign(index=999)])  # e.g. an axis not in PAIR_KEY
    md, _ = write_report(tmp_path, _exp(df), df)
    text = md.read_text()
    # both rows of the shared key counted (it said "1 rows share a pairing key")
    assert "**No paired comparison**: ref: 2 rows share a pairing key" in text
    assert "## c1" in text  # the rest of the report is still written


def _write_timeseries(out, df: pd.DataFrame, n: int = 50) -> None:
    """A small time series per run of ``df`` (one AUV) in its run folder."""
    rng = np.random.default_rng(3)
    t = np.arange(n, dtype=float)
    for r in df.itertuples():
        d = out / r.run_dir
        d.mkdir(parents=True)
        pd.DataFrame({
            "t": t, "N": rng.normal(size=n), "E": rng.normal(size=n), "auv0_N": t, "auv0_E": t,
            "range0": 100 + rng.normal(size=n), "r_inner0": 50.0, "r_t0": 90.0,
            "r_outer0": 200.0, "fix_age0": t % 5, "rfix_age0": t % 11,
            "nav_err0": rng.gamma(2.0, size=n),
        }).to_parquet(d / "timeseries.parquet")  # fmt: skip


def test_ecdfs_pool_every_run_auv_and_step_of_a_case_per_variant(tmp_path):
    from mpcasv.experiments.report_series import ecdf_panels

    df = results({"min_range_m": 2.0})
    _write_timeseries(tmp_path, df)
    panels, notes = ecdf_panels(tmp_path, df, "c1")
    assert notes == [] and [p[2].prefix for p in panels] == ["rfix_age", "fix_age", "nav_err"]
    nav = panels[2][3]
    for v in ("ref", "new"):
        runs = df[(df["scenario"] == "c1") & (df["variant"] == v)]
        expect = np.concatenate([pd.read_parquet(tmp_path / d / "timeseries.parquet")["nav_err0"]
                                 for d in runs["run_dir"]])  # fmt: skip
        assert len(runs) == 16 and np.array_equal(nav[v], np.sort(expect))
    # the report draws them and the representative runs (no 'no time series' line)
    md, _ = write_report(tmp_path, _exp(df), df)
    text = md.read_text()
    assert "no time series" not in text
    for f in ("ecdf-c1.png", "compare-c1.png", "box-c1.png"):
        assert (tmp_path / "figures" / f).stat().st_size > 10_000


def test_one_nonzero_difference_is_no_crash_and_no_verdict():
    # a real case: case1 min range, 10 pairs of which 9 identical (delta_r 40 vs 50 m)
    ref = np.array([7.439196, 95.58, 41.66, 27.62, 19.15, 10.2, 81.6, 27.7, 15.4, 7.87])
    other = ref.copy()
    other[0] = 7.439086
    s = paired_stat(ref, other)
    # one non-zero difference: no test (it said p = 1, "no significant difference")
    assert s.n == 10 and np.isnan(s.p) and s.note == "n/a: 1 non-zero difference < 6"
    assert stats.verdict(s, "higher", "a", "b", 20.0) == "n/a"


@pytest.mark.parametrize(("nonzero", "tested"), [(5, False), (6, True)])
def test_a_case_with_fewer_than_six_nonzero_differences_is_not_tested(nonzero, tested):
    """The Wilcoxon test drops zero differences: with 5 non-zero its smallest p is 2/2^5 =
    0.0625, so Case 5's collision time (10 worlds, 5 non-zero) could never be "better" and
    read "no significant difference, p = 1" (a statistician's review, session 44). Its median
    and interval stay."""
    ref = np.zeros(10)
    other = np.zeros(10)
    other[:nonzero] = np.arange(1.0, nonzero + 1)
    s = paired_stat(ref, other)
    assert s.n == 10 and np.isfinite(s.median) and np.isfinite(s.ci_high)
    assert np.isfinite(s.p) == tested
    assert (s.note == "") == tested


def test_multiplicity_counts_tests_and_the_verdicts_that_survive_benjamini_hochberg():
    t = pd.DataFrame({"p": [0.001, 0.04, 0.2, np.nan],
                      "verdict": ["mpc better", "hybrid better", "no significant difference",
                                  "n/a"]})  # fmt: skip
    mu = stats.multiplicity(t)
    # BH by hand, m = 3: sorted p 0.001, 0.04, 0.2 -> 0.003, 0.06, 0.2: only the first stays
    assert (mu.tests, mu.better, mu.better_bh) == (3, 2, 1)
    assert mu.expected_false == pytest.approx(3 * stats.ALPHA)
    assert stats.multiplicity(t.iloc[:0]) == stats.Multiplicity(0, 0.0, 0, 0)


def test_report_states_the_negligible_rule_and_the_multiplicity_of_each_table(tmp_path):
    df = results({"min_range_m": 1.0, "energy_J": 0.0}, variants=("hybrid", "mpc"))
    md = write_report(tmp_path, _exp(df), df)[0].read_text()
    assert f"±{stats.NEGLIGIBLE:.1%} of the reference's median" in md
    section = md.split("### mpc vs hybrid")[1]
    line = next(ln for ln in section.splitlines() if "Multiple comparisons" in ln)
    t = paired_table(df, [h.name for h in HEADLINE], directions())
    mu = stats.multiplicity(t)
    assert mu.tests == 4 and mu.better >= 2  # min_range_m in c1 and c2 (shift 1 m, 32 pairs)
    assert f"{mu.tests} tests in this table" in line and f"{mu.better} verdicts" in line
    assert f"'better', {mu.better_bh} of them" in line
    assert section.index("Multiple comparisons") < section.index("| metric | case | pairs |")


def test_the_wins_and_losses_counts_say_how_many_tests_they_rest_on(tmp_path):
    """The "Significant wins and losses" table counted 'better' verdicts over every metric
    and case (179 tests in the main job, about 9 expected by chance) without a word on
    multiplicity (a statistician's review, session 48)."""
    df = results({"min_range_m": 1.0, "energy_J": 0.0}, variants=("hybrid", "mpc"))
    md = write_report(tmp_path, _exp(df), df)[0].read_text()
    section = md.split("## Significant wins and losses (paired)")[1].split("\n## ")[0]
    line = next(ln for ln in section.splitlines() if "Multiple comparisons" in ln)
    n = int(re.search(r"(\d+) tests in these counts", line).group(1))
    mu = stats.multiplicity(paired_table(df, [h.name for h in HEADLINE], directions()))
    assert n == mu.tests  # (this table's metrics with a direction are the headline's)
    assert f"{mu.better} verdicts 'better', {mu.better_bh} of them" in line
    assert f"about {n * stats.ALPHA:.1f} 'better' verdicts expected by chance" in line
    assert "not the chance of any" in line


def test_a_panel_draws_every_variant_alike_when_one_needs_the_envelope():
    """paper run, Case 4 (compare-case4.png): the hybrid's tau (many fixes) was drawn as its
    envelope, a staircase, the MPC's (few) as a raw saw-tooth, and the y label carried the
    last variant's (empty) suffix; one decision per panel now."""
    from mpcasv.experiments.report_series import needs_envelope

    t = np.arange(0.0, 1242.0)
    many, few = t % 7.0, t % 300.0  # 177 resets / 4 resets
    assert needs_envelope(t, many) and not needs_envelope(t, few)
    tt, a, suffix = fix_age_trace(t, few, envelope=True)
    assert len(tt) <= ENVELOPE_BINS and "max per" in suffix and a.max() == 299.0
    tt, a, suffix = fix_age_trace(t, many, envelope=False)
    assert suffix == "" and np.array_equal(a, many)


def test_a_case_without_any_fix_is_named_in_the_report(tmp_path):
    """paper run, Case 5: no USBL fix in any of the 20 runs (the case's acoustic reports
    stand in); its fix-age rows were 'no difference' without saying why."""
    from mpcasv.experiments.report import cases_without_fixes

    df = results({"min_range_m": 1.0}, variants=("hybrid", "mpc"))
    df["fixes"] = np.where(df["scenario"] == "c2", 0, 12)
    assert cases_without_fixes(df) == ["c2"]
    md = write_report(tmp_path, _exp(df), df)[0].read_text()
    head = md.split("### mpc vs hybrid")[0]
    assert "No USBL fix arrived in any run of c2:" in head
    assert md.split("\n## c2")[1].count("No USBL fix arrived in any run of this case") == 1
    assert "No USBL fix arrived in any run of this case" not in md.split("\n## c1")[1].split(
        "\n## c2")[0]  # fmt: skip
    one = df.copy()
    one.loc[one.index[one["scenario"] == "c2"][0], "fixes"] = 1  # one fix in one run
    assert cases_without_fixes(one) == []


def test_run_folders_outside_the_report_folder_are_linked_by_absolute_uri(tmp_path):
    """`mpcasv compare quick --out A --runs-dir B` (B not under A): the report crashed on
    Path.relative_to (ValueError, a traceback after the whole sweep had run)."""
    runs, out = tmp_path / "elsewhere", tmp_path / "report"
    out.mkdir()
    df = results({"min_range_m": 2.0}, seeds=range(2))
    _write_timeseries(runs, df)
    df["run_dir"] = [str(runs / d) for d in df["run_dir"]]  # absolute, as --runs-dir writes
    for d in df["run_dir"]:
        (Path(d) / "paths.png").write_bytes(b"png")
    md_path, html_path = write_report(out, _exp(df), df)
    md, page = md_path.read_text(), html_path.read_text()
    first = Path(df["run_dir"].iloc[0]) / "paths.png"
    assert f"[paths]({first.as_uri()})" in md and f'href="{first.as_uri()}"' in page
    assert (out / "figures" / "compare-c1.png").stat().st_size > 10_000


def test_an_infinite_value_is_the_worst_run_not_a_missing_one():
    """`revisit_interval_max_s` is infinite when an AUV is never revisited. Such rows were
    dropped as non-finite before pairing, so the controller that never came back lost its
    worst runs from the comparison (found in a review). They are now pairs: in 8 of 10 worlds
    "new" never revisits (inf) where "ref" does, so "new" is significantly worse, with the
    median and upper CI bound infinite; two equal infinities are a zero difference."""
    df = results({"revisit_interval_max_s": 0.0}, seeds=range(5), cases=("c1",))
    new = df["variant"] == "new"
    worlds = df.loc[new].index[:8]
    df.loc[worlds, "revisit_interval_max_s"] = np.inf
    both = df.loc[new].index[8]  # one world where neither revisits: a tie
    df.loc[df["seed"].eq(df.at[both, "seed"]) & df["current"].eq(df.at[both, "current"]),
           "revisit_interval_max_s"] = np.inf  # fmt: skip
    paired, _ = stats.pairs(df, "revisit_interval_max_s", "ref", "new")
    assert len(paired) == 10
    s = paired_stat(paired["ref"].to_numpy(), paired["other"].to_numpy())
    assert s.median == np.inf and s.ci_high == np.inf and s.p < 0.05
    assert stats.verdict(s, "lower", "ref", "new") == "ref better"
    assert paired_stat(np.array([np.inf] * 6), np.array([np.inf] * 6)).note.startswith("all 6")


def test_each_per_auv_column_is_one_row_of_the_scenario_table(tmp_path):
    """A per-AUV list column (``fixes_auv0``) is a row under its scalar's name, once: it
    was listed again as ``fixes_auv [auv1]``; a list with no scalar keeps its own name, and
    the paired table's summed list is still built from the per-AUV columns."""
    from mpcasv.experiments.report import summary_table, with_list_summaries

    df = results({"min_range_m": 1.0, "fixes_auv0": 1.0, "fixes_auv1": 2.0,
                  "target_domain_s_auv0": 3.0, "collision_domain_s": 0.0,
                  "collision_domain_s_auv0": 0.0})  # fmt: skip
    df["auv_names"] = "auv1,auv2"
    summ = summary_table(df)
    one = summ[(summ.scenario == "c1") & (summ.variant == "new") & (summ.current == "off")]
    assert one.groupby("column").size().max() == 1
    rows = {c: (m, None if pd.isna(k) else int(k))
            for c, m, k in zip(one.column, one.metric, one.auv, strict=True)}  # fmt: skip
    assert rows == {"min_range_m": ("min_range_m", None),
                    "fixes_auv0": ("fixes", 0), "fixes_auv1": ("fixes", 1),
                    "target_domain_s_auv0": ("target_domain_s_auv", 0),
                    "collision_domain_s": ("collision_domain_s", None),
                    "collision_domain_s_auv0": ("collision_domain_s", 0)}  # fmt: skip
    summed = with_list_summaries(df)["fixes_auv"]
    assert np.allclose(summed, df["fixes_auv0"] + df["fixes_auv1"])
    md = write_report(tmp_path, _exp(df), df)[0].read_text()
    assert "| fixes [auv1] |" in md and "fixes_auv [" not in md
