"""The reliable-fix age of an AUV never reliably fixed is the metric's ceiling (p95 = 0.95 x
the run's length, max = the length: metrics.age_stats), so two runs that both leave it
unserved read "no change" (a statistician's review, session 49). The report counts such
AUV-runs per case and variant beside the fix-age rows; the metric stays as it is."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd

from mpcasv.experiments.metrics import age_stats
from mpcasv.experiments.report import NEVER_COLUMN, headline_table, write_report
from mpcasv.experiments.report_tables import never_fixed, never_fixed_table
from mpcasv.experiments.stats import HEADLINE, pair_key, paired_table

T = 700.0  # run length (s), as paper's Case 8


def table() -> pd.DataFrame:
    """Case c1: two AUVs, 6 seeds; hybrid leaves AUV 1 unserved in seeds 0-2, mpc in seed 0
    (both: one pair). Case c2: every AUV served."""
    rows = []
    for case in ("c1", "c2"):
        for seed in range(6):
            for v in ("hybrid", "mpc"):
                unserved = case == "c1" and (seed < 3 if v == "hybrid" else seed == 0)
                fixes = [4.0, 0.0 if unserved else 3.0]
                ages = [age_stats([] if f == 0 else [100.0, 400.0], T)[1] for f in fixes]
                rows.append({"index": len(rows), "scenario": case, "variant": v,
                             "current": "scenario", "estimator": "kf", "seed": seed,
                             "status": "ok", "auv_names": "a,b",
                             "run_dir": f"runs/{case}-{v}-{seed}",
                             "reliable_fixes_auv0": fixes[0], "reliable_fixes_auv1": fixes[1],
                             "reliable_fixes": sum(fixes), "fixes": 20.0,
                             "reliable_fix_age_p95_s": max(ages) + seed,
                             "reliable_fix_age_max_s": T if 0 in fixes else 300.0 + seed,
                             "min_range_m": 50.0 + seed + (v == "mpc")})  # fmt: skip
    return pd.DataFrame(rows)


def test_the_never_fixed_auv_runs_are_counted_per_case_and_variant():
    assert age_stats([], T)[:2] == (T, 0.95 * T)  # the ceiling the count warns of
    df = table()
    assert never_fixed(df).tolist()[:4] == [1.0, 1.0, 1.0, 0.0]  # c1 seed 0 hybrid, mpc; ...
    t = never_fixed_table(df, "hybrid", "mpc", pair_key(df))
    assert t.loc["c1"].to_dict() == {"ref_never": 3, "ref_auv_runs": 12, "other_never": 1,
                                     "other_auv_runs": 12, "both": 1}  # fmt: skip
    assert t.loc["c2", ["ref_never", "other_never", "both"]].tolist() == [0, 0, 0]
    # no per-AUV fix counts in the table (an older one): unknown, not zero
    assert never_fixed(df.drop(columns=["reliable_fixes_auv0", "reliable_fixes_auv1"])
                       ).isna().all()  # fmt: skip


def test_the_headline_shows_them_beside_the_fix_age_rows_only(tmp_path):
    df = table()
    metrics = ["min_range_m", "reliable_fix_age_p95_s", "reliable_fix_age_max_s"]
    better = {h.name: h.better for h in HEADLINE}
    t = paired_table(df, metrics, better)
    d = headline_table(t, never_fixed_table(df, "hybrid", "mpc", pair_key(df)))
    cells = dict(zip(zip(t["metric"], t["case"], strict=True), d[NEVER_COLUMN], strict=True))
    assert cells[("reliable_fix_age_p95_s", "c1")] == "hybrid 3/12, mpc 1/12; both in 1 pair"
    assert cells[("reliable_fix_age_max_s", "c2")] == "hybrid 0/12, mpc 0/12"
    assert cells[("min_range_m", "c1")] == ""
    suite = SimpleNamespace(name="s", description="", seeds=list(range(6)))
    md = write_report(tmp_path, SimpleNamespace(suite=suite, jobs=list(range(len(df))),
                                                skipped=[]), df)[0].read_text()  # fmt: skip
    head = md.split("## Significant wins")[0]
    assert f"| {NEVER_COLUMN} |" in head
    assert "c1 hybrid 3, mpc 1, both in 1 pair." in head and "0.95 x the run's length" in head
    assert np.isfinite(t["p"]).any()
