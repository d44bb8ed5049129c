"""The report's tables of per-run metrics: which column is which metric (per AUV
expanded), the summary over seeds, per-run summaries of per-AUV lists, and the cases without
any USBL fix. Used by :mod:`mpcasv.experiments.report`."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from mpcasv.experiments import stats as paired
from mpcasv.experiments.metrics import METRIC_NAMES, auv_column
from mpcasv.experiments.report_figures import CONDITION, group_label, num
from mpcasv.wording import count, noun

#: how a per-AUV list metric is summarised per run for wins and losses
LIST_SUMMARY = {"fixes_auv": "sum", "reliable_fixes_auv": "sum",
                "reliable_fix_age_max_s_auv": "max", "auv_distance_m_auv": "sum"}  # fmt: skip


def metric_columns(df: pd.DataFrame) -> list[tuple[str, str, int | None]]:
    """(column, metric, AUV index or None) for every metric column present, in
    :data:`METRIC_NAMES` order, each column once: a per-AUV column goes with its scalar
    (``fixes_auv0`` is listed as ``fixes`` AUV 0, not again as ``fixes_auv`` AUV 0); a list
    with no scalar (``target_domain_s_auv``) keeps its own name."""
    out, seen = [], set()
    for m in METRIC_NAMES:
        if m in df:
            out.append((m, m, None))
            seen.add(m)
        for k, col in enumerate(_auv_columns(df, m)):
            if col not in seen:
                out.append((col, m, k))
                seen.add(col)
    return out


def _auv_columns(df: pd.DataFrame, m: str) -> list[str]:
    """The columns of AUVs 0, 1, ... of metric ``m`` present in ``df``, up to the first
    missing one."""
    cols: list[str] = []
    while auv_column(m, len(cols)) in df:
        cols.append(auv_column(m, len(cols)))
    return cols


def with_list_summaries(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` plus one column per per-AUV list metric of :data:`LIST_SUMMARY` (summed or
    maxed over the per-AUV columns of each run) where it has no scalar column."""
    out = df.copy()
    for m, how in LIST_SUMMARY.items():
        cols = _auv_columns(df, m)
        if m not in df and cols:
            out[m] = getattr(df[cols].astype(float), how)(axis=1, skipna=True)
    return out


def summary_table(df: pd.DataFrame) -> pd.DataFrame:
    """Long table: scenario, condition, variant, column, metric, auv, mean, sd, n (the runs
    with a value), runs (the ok runs of the group: n < runs where a metric is undefined,
    null, in some runs, e.g. ``between_steps_ms_max`` of a run without a solve between steps;
    an infinite value is a value: ``revisit_interval_max_s`` of an AUV never reliably fixed
    makes the mean inf), n_inf (the runs with an infinite value), finite_mean, finite_sd
    (over the others)."""
    rows = []
    ok = df[df["status"] == "ok"]
    keys = ["scenario", *CONDITION, "variant"]
    for key, g in ok.groupby(keys, sort=False):
        for col, m, k in metric_columns(g):
            v = g[col].astype(float).dropna()
            if not len(v):  # e.g. a per-AUV column of another scenario: left out; a scalar
                if k is None:  # metric not defined for these runs (null): a row saying so
                    rows.append(dict(zip(keys, key, strict=True)) | {
                        "column": col, "metric": m, "auv": k, "mean": math.nan,
                        "sd": math.nan, "n": 0, "runs": len(g), "n_inf": 0,
                        "finite_mean": math.nan, "finite_sd": math.nan})  # fmt: skip
                continue
            with np.errstate(invalid="ignore"):  # an infinite value: mean inf, sd nan (quietly)
                sd = float(v.std(ddof=1)) if len(v) > 1 else math.nan
            fin = v[np.isfinite(v)]
            rows.append(dict(zip(keys, key, strict=True)) | {
                "column": col, "metric": m, "auv": k, "mean": float(v.mean()), "sd": sd,
                "n": len(v), "runs": len(g), "n_inf": len(v) - len(fin),
                "finite_mean": float(fin.mean()) if len(fin) else math.nan,
                "finite_sd": float(fin.std(ddof=1)) if len(fin) > 1 else math.nan,
            })  # fmt: skip
    return pd.DataFrame(rows)


#: the fix-age metrics whose value has a ceiling where an AUV was never reliably fixed
CEILING_METRICS = ("reliable_fix_age_p95_s", "reliable_fix_age_max_s", "reliable_fix_age_mean_s")


def never_fixed(df: pd.DataFrame) -> pd.Series:
    """Per run (index of ``df``): how many of its AUVs had no reliable fix at all
    (``reliable_fixes_auv<k>`` 0), NaN where the table has no such column or the run no
    value. Such an AUV's reliable-fix age runs from 0 to the run's end: its p95 is 0.95 x
    the run's length, its max the length (:func:`mpcasv.experiments.metrics.age_stats`),
    the most the metric can say, whatever else happened; two runs that both leave an AUV
    unserved read "no change" on it."""
    cols = _auv_columns(df, "reliable_fixes_auv")
    if not cols:
        return pd.Series(math.nan, index=df.index)
    v = df[cols].apply(pd.to_numeric, errors="coerce")
    out = (v == 0).sum(axis=1).astype(float)
    return out.where(v.notna().any(axis=1))


def never_fixed_table(df: pd.DataFrame, reference: str, other: str,
                      pair_key: list[str]) -> pd.DataFrame:  # fmt: skip
    """Per case (index ``scenario``, the order of ``df``): the AUV-runs never reliably fixed
    (:func:`never_fixed`) of ``reference`` and ``other`` (``ref_never``, ``other_never``) out
    of their AUV-runs (``ref_auv_runs``, ``other_auv_runs``), and ``both``: the pairs of runs
    (equal on ``pair_key``) in which each run left at least one AUV without a reliable fix
    (the worst AUV's fix age at its ceiling on both sides). Only ``status == "ok"`` rows."""
    ok = df[df["status"] == "ok"]
    cols = _auv_columns(ok, "reliable_fixes_auv")
    never = never_fixed(ok)
    auvs = (ok[cols].notna().sum(axis=1) if cols else pd.Series(0, index=ok.index))
    rows = {}
    for case, g in ok.groupby("scenario", sort=False):
        row = {}
        for name, v in (("ref", reference), ("other", other)):
            sel = g["variant"] == v
            row[f"{name}_never"] = int(never[g.index][sel].fillna(0).sum())
            row[f"{name}_auv_runs"] = int(auvs[g.index][sel].sum())
        a = g[g["variant"] == reference].assign(_n=never).set_index(pair_key)["_n"]
        b = g[g["variant"] == other].assign(_n=never).set_index(pair_key)["_n"]
        a, b = a.align(b, join="inner")
        row["both"] = int(((a > 0) & (b > 0)).sum())
        rows[case] = row
    return pd.DataFrame.from_dict(rows, orient="index").rename_axis("scenario")


def cases_without_fixes(ok: pd.DataFrame) -> list[str]:
    """Scenarios in which no USBL fix arrived in any ok run (``fixes`` 0 everywhere): there
    the fix ages are the run's clock and the AUVs' navigation does not depend on the
    controller, so their liveness and navigation comparisons say nothing about it."""
    if "fixes" not in ok or not len(ok):
        return []
    n = pd.to_numeric(ok["fixes"], errors="coerce")
    return [c for c, g in n.groupby(ok["scenario"], sort=False) if g.notna().all() and
            (g == 0).all()]  # fmt: skip


def scenario_table(summ: pd.DataFrame, scenario: str, auv_names: list[str]) -> pd.DataFrame:
    """Rows: metrics (per AUV expanded); columns: variant (| condition); cells mean ± sd
    over the runs with a value (:func:`_cell`), followed by "(n of N runs)" when some runs
    have none (a metric undefined there: the mean of the others is not the mean of the
    group); infinite values are counted first, not averaged ("inf in 2 of 10; the others
    400 ± 52.8")."""
    s = summ[summ["scenario"] == scenario].copy()
    multi = [c for c in CONDITION if s[c].nunique() > 1]
    s["group"] = [group_label(r, multi) for _, r in s.iterrows()]
    s["cell"] = [_cell(r) for _, r in s.iterrows()]
    s["row"] = [m if pd.isna(k) else f"{m} [{auv_names[int(k)]}]"
                for m, k in zip(s["metric"], s["auv"], strict=True)]  # fmt: skip
    rows = list(dict.fromkeys(s["row"]))
    table = s.pivot(index="row", columns="group", values="cell").reindex(rows)
    table = table[list(dict.fromkeys(s["group"]))]
    table.index.name = "metric"
    table.columns.name = None
    return table


def _cell(r: pd.Series) -> str:
    """A summary cell: mean ± sd, "(n of N runs)" when some runs have no value, and with
    infinite values how many were infinite, then the others' mean ("inf in 2 of 10; the
    others 400 ± 52.8")."""
    if r["n"] == 0:
        return "—"
    m, sd = r["finite_mean"], r["finite_sd"]  # the mean and sd when no value is infinite
    text = "" if np.isnan(m) else num(m) if not np.isfinite(sd) else f"{num(m)} ± {num(sd)}"
    if r["n_inf"]:  # first: the others' mean alone read as the better side (Case 8's
        # hybrid "375.2 ± 73.81, inf in 4" beside the MPC's 400.2, a statistician's review)
        text = f"inf in {r['n_inf']} of {r['n']}" + (f"; the others {text}" if text else "")
    return text + (f" ({r['n']} of {r['runs']} runs)" if r["n"] < r["runs"] else "")


#: the headline's column of AUV-runs never reliably fixed (the fix ages' ceiling)
NEVER_COLUMN = "AUV-runs never reliably fixed"


def headline_table(t: pd.DataFrame, never: pd.DataFrame | None = None) -> pd.DataFrame:
    """Display form of one (reference, other) pair of :func:`stats.paired_table` for the
    headline: one row per metric and case; the metric named on its first row only. The
    difference is the Hodges-Lehmann estimate with its interval (the Wilcoxon test's own
    estimand; :func:`stats.hodges_lehmann`); where the interval and the test still disagree
    (possible only with tied or zero differences: whole seconds, counts) the p cell says so.
    ``never`` (:func:`report_tables.never_fixed_table`, per case): a column on the
    reliable-fix age rows with the AUV-runs never reliably fixed per variant, whose fix age
    sits at its ceiling (0.95 x the run's length for the p95)."""
    ref, other = t["reference"].iloc[0], t["other"].iloc[0]
    units = {h.name: h.unit for h in paired.HEADLINE}
    est = "estimate" if "estimate" in t else "median"
    rows, last = [], None
    for _, r in t.iterrows():
        n = (f"{r['n']}" + (f" {noun(r['n'], 'world')} ({r['runs']} runs)"
                            if r.get("runs", 0) > r["n"] else "")
             + (f" (+{r['n_unpaired']} unpaired)" if r["n_unpaired"] else ""))
        if np.isfinite(r["ci_low"]):
            diff = f"{num(r[est])} [{num(r['ci_low'])}, {num(r['ci_high'])}]"
        else:
            diff = num(r[est]) if np.isfinite(r[est]) else ""
        p = f"{r['p']:.2g}" if np.isfinite(r["p"]) else (r["note"] or "n/a")
        if r["note"] and np.isfinite(r["p"]):
            p += f" ({r['note']})"
        elif r["note"] and p != r["note"]:
            p = f"n/a ({r['note']})"
        if np.isfinite(r["p"]) and paired.interval_disagrees(r):
            p += " (the interval disagrees: tied or zero differences)"
        unit = units.get(r["metric"], "")
        first = r["metric"] != last
        row = {
            "metric": f"{r['metric']} ({unit}, {r['better']} better)" if first else "",
            "case": r["case"], "pairs": n, f"{ref} median": num(r["ref_median"]),
            f"Δ = {other} − {ref}: Hodges-Lehmann [95 % CI]": diff, "Wilcoxon p": p,
            "verdict": r["verdict"],
        }  # fmt: skip
        if never is not None and len(never):
            cell = ""
            if r["metric"] in CEILING_METRICS and r["case"] in never.index:
                c = never.loc[r["case"]]
                cell = (f"{ref} {c['ref_never']}/{c['ref_auv_runs']}, "
                        f"{other} {c['other_never']}/{c['other_auv_runs']}"
                        + (f"; both in {count(int(c['both']), 'pair')}" if c["both"] else ""))
            row[NEVER_COLUMN] = cell
        rows.append(row)
        last = r["metric"]
    return pd.DataFrame(rows).set_index("metric")


def win_loss_table(wl: pd.DataFrame) -> pd.DataFrame:
    """Display form of :func:`stats.significant_win_loss` for one (reference, other) pair."""
    ref, other = wl["reference"].iloc[0], wl["other"].iloc[0]
    t = wl.set_index("metric")[["better", "other_better", "reference_better",
                                "not_significant", "n/a"]].copy()  # fmt: skip
    t.columns = ["better", f"{other} better", f"{ref} better", "no significant difference",
                 "n/a"]  # fmt: skip
    return t
