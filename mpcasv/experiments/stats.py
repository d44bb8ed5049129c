"""Paired statistics of a comparison: controllers on the same (scenario, realisation) pairs.

Two controller variants ran on the same worlds when their jobs agree on every column of
:data:`PAIR_KEY` (every column that identifies a job except the controller; ``realisation``
too when the results table has it). For each metric, each case (scenario) and each variant
against the reference variant, the paired differences ``d_i = x_other,i - x_reference,i``
give:

- the Hodges-Lehmann estimate of the difference (the median of the Walsh averages
  ``(d_i + d_j) / 2``, i <= j) and its 95 % distribution-free confidence interval, the
  Walsh averages' order statistics that invert the signed-rank test (:func:`hodges_lehmann`;
  Hollander, Wolfe & Chicken 2014, §3.2-3.3; no random draw);
- the two-sided Wilcoxon signed-rank p-value (:func:`scipy.stats.wilcoxon`, zero differences
  dropped, exact distribution for small n): the test of the same estimand, so that without
  tied or zero differences the interval excludes 0 exactly when p < :data:`ALPHA` (until
  session 49 the interval was a bootstrap of the *median*, and the two disagreed in 5 of
  176 tested comparisons of session 48's main job); with ties or zeros they can still part
  at the boundary (:func:`interval_disagrees`), and the verdict, which needs both, is then
  none;
- a verdict: a variant is *better* only when the interval excludes 0 **and** p < :data:`ALPHA`,
  in the metric's direction (:class:`HeadlineMetric.better`), and the interval is not
  *negligible*: inside +-:data:`NEGLIGIBLE` times the reference's median (differences of
  1e-4 m in a 140 m minimum range are significant for a deterministic simulator, and of no
  consequence). All differences zero: "no difference".

Pairs are pooled over the conditions of a case (current, estimator): each pair is matched
within its condition. The unit of the statistics is the *world*, not the run
(:func:`per_world`): the pairs of a case on the same realisation (seeds whose draws give the
same scenario, e.g. one whose ``[uncertain]`` table draws nothing, where the seed varies
only the sensor and acoustic draws; or conditions that leave the world as it is, such as the
estimators) are one world, and their pairs are averaged into one; six copies of one world's
difference would otherwise give a zero-width interval and p = 0.03. With fewer than
:data:`MIN_PAIRS` worlds, all differences zero, or no direction, the statistic is "n/a" with
the reason (the two-sided Wilcoxon test cannot reach p < 0.05 with fewer than 6 non-zero
differences: its smallest p is ``2 / 2^n``); so is the test of a case with enough worlds but
fewer than :data:`MIN_PAIRS` non-zero differences (the test drops the zeros: Case 5's
collision time, 10 worlds and 5 non-zero, said "no significant difference, p = 1" where no
p could be below 0.0625; its median and interval are still given). Rows of one variant
without a partner in the other (failed job, missing value) are excluded and counted
(``n_unpaired``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats as sps

from mpcasv.experiments.metrics import HEADLINE as METRIC_HEADLINE
from mpcasv.experiments.metrics import METRIC_INFO
from mpcasv.experiments.paired_diff import (  # noqa: F401 (re-exported: one set of pairs)
    ALPHA,
    CONFIDENCE,
    MIN_PAIRS,
    N_RESAMPLES,
    NEGLIGIBLE,
    SEED,
    PairedStat,
    hodges_lehmann,
    interval_disagrees,
    median_stat,
    paired_stat,
    signed_rank_null_cdf,
    verdict,
    walsh_averages,
    wilcoxon_p,
)

#: column naming the compared controller (label plus grid values, e.g. "hybrid[dT=0.2]")
COMPARE = "variant"
#: columns that identify a job apart from the controller: rows equal on these are one pair
PAIR_KEY = ("scenario", "current", "estimator", "seed")
#: identity columns used too when the table has them (the drawn scenario realisation)
OPTIONAL_KEY = ("realisation",)
CASE = "scenario"  # one line of the headline table and forest plot per case


class PairingError(ValueError):
    """The results table cannot be paired (a pairing column missing, or a key that does not
    identify the job)."""


@dataclass(frozen=True)
class HeadlineMetric:
    """One metric of the headline table: its name, unit and direction come from
    :data:`mpcasv.experiments.metrics.METRIC_INFO` (the one definition); the group is the
    headline table's section."""

    name: str
    group: str  # "safety", "liveness", "navigation", "effort"
    unit: str
    better: str  # "lower" | "higher"


#: the headline table's section of each headline metric
_GROUP = {"min_range_m": "safety", "collision_domain_s": "safety",
          "reliable_fix_age_p95_s": "liveness", "reliable_fix_age_max_s": "liveness",
          "nav_error_rms_m": "navigation", "nav_error_p95_m": "navigation",
          "energy_J": "effort", "propeller_on_s": "effort"}  # fmt: skip

#: the headline table's metrics, in :data:`mpcasv.experiments.metrics.HEADLINE` order
HEADLINE: tuple[HeadlineMetric, ...] = tuple(
    HeadlineMetric(m, _GROUP[m], METRIC_INFO[m].unit, METRIC_INFO[m].better)
    for m in METRIC_HEADLINE
)


def pair_key(results: pd.DataFrame) -> list[str]:
    """The pairing columns of this table: :data:`PAIR_KEY` plus the present optional ones.

    Raises
    ------
    PairingError
        If a column of :data:`PAIR_KEY` or :data:`COMPARE` is missing.
    """
    missing = [c for c in (*PAIR_KEY, COMPARE) if c not in results]
    if missing:
        raise PairingError(f"results table lacks the pairing column(s) {missing}")
    return [*PAIR_KEY, *(c for c in OPTIONAL_KEY if c in results)]


def variants(results: pd.DataFrame) -> list[str]:
    """The compared variants in table order (suite order); the first is the reference."""
    ok = results[results["status"] == "ok"]
    if "index" in ok:
        ok = ok.sort_values("index", kind="stable")
    return list(dict.fromkeys(ok[COMPARE]))


def comparison_problem(results: pd.DataFrame) -> str | None:
    """Why no paired comparison can be made of ``results`` (None: it can): fewer than two
    variants with ``status == "ok"`` rows, or a table whose columns do not identify the
    pairs (:func:`pair_key`: a pairing column missing, or two ok rows of a variant sharing a
    key). One definition for the report's headline and acceptance sections and for
    ``mpcasv compare --no-report`` (:func:`mpcasv.experiments.acceptance.why_not_judged`)."""
    names = variants(results) if len(results) else []
    if len(names) < 2:
        return f"{len(names)} controller variant(s) with results"
    try:
        key = pair_key(results)
    except PairingError as exc:
        return str(exc)
    ok = results[results["status"] == "ok"]
    for v in names:
        dup = ok[ok[COMPARE] == v].duplicated(key, keep=False)  # every row of a shared key
        if dup.any():
            return (f"{v}: {int(dup.sum())} rows share a pairing key {key}; the key does not "
                    "identify the job")  # fmt: skip
    return None


def missing_metrics(results: pd.DataFrame, metrics: Sequence[str]) -> list[str]:
    """The metrics of ``metrics`` without a column in ``results`` (e.g. an older table)."""
    return [m for m in metrics if m not in results]


def pairs(results: pd.DataFrame, metric: str, reference: str, other: str
          ) -> tuple[pd.DataFrame, pd.Series]:  # fmt: skip
    """The paired values of ``metric``: ``reference`` vs ``other`` on equal :func:`pair_key`.

    Only ``status == "ok"`` rows with a value count; an infinite value (e.g. an AUV never
    revisited: ``revisit_interval_max_s``) is the worst a run can do and is kept, never
    dropped as missing (only NaN is). Returns the pairs (key columns,
    ``ref``, ``other``; one row per pair) and, per case, how many rows of either variant
    found no partner. Raises :class:`PairingError` if a variant has two rows with the same key
    (the key does not identify the job).
    """
    key = pair_key(results)
    ok = results[(results["status"] == "ok") & results[COMPARE].isin([reference, other])]
    ok = ok[[*key, COMPARE, metric]].copy()
    ok[metric] = pd.to_numeric(ok[metric], errors="coerce").astype(float)
    ok = ok[ok[metric].notna()]
    sides = {}
    for name, v in (("ref", reference), ("other", other)):
        side = ok[ok[COMPARE] == v].drop(columns=COMPARE).rename(columns={metric: name})
        dup = side.duplicated(key, keep=False)  # every row of a shared key (at least 2)
        if dup.any():
            raise PairingError(f"{v}: {int(dup.sum())} rows share a pairing key {key}; "
                             "the key does not identify the job")  # fmt: skip
        sides[name] = side
    both = sides["ref"].merge(sides["other"], on=key, how="outer", indicator=True)
    paired = both[both["_merge"] == "both"].drop(columns="_merge")
    unpaired = both[both["_merge"] != "both"].groupby(CASE, sort=False).size()
    return paired.reset_index(drop=True), unpaired


def per_world(p: pd.DataFrame) -> pd.DataFrame:
    """The pairs of :func:`pairs` with one row per world: the pairs of a case with the same
    non-empty ``realisation`` (the same drawn scenario: seeds whose draws repeat, or a
    scenario that draws nothing; and the conditions that leave the world as it is, e.g. the
    estimators of one realisation) averaged into one, ``ref`` and ``other`` the means of
    their runs. An infinite value makes its world's mean infinite (both infinite: no
    difference, as for one pair); metrics never negative cannot mix +inf and -inf. Column
    ``runs``: how many pairs each row stands for. A table without a ``realisation`` column,
    or rows without one, keep one row per pair. Row order: each world where its first pair
    was (the seeded bootstrap depends on it)."""
    p = p.assign(runs=1)
    if "realisation" not in p or not len(p):
        return p
    real = p["realisation"].astype("string").fillna("")
    world = np.where(real.eq("").to_numpy(), "row " + p.index.astype(str), real.to_numpy())
    g = p.assign(_world=world, _first=np.arange(len(p))).groupby([CASE, "_world"], sort=False)
    agg = {c: (c, "first") for c in p.columns if c not in ("ref", "other", "runs")}
    merged = g.agg(**agg, ref=("ref", "mean"), other=("other", "mean"), runs=("runs", "size"),
                   _first=("_first", "min"))  # fmt: skip
    return merged.sort_values("_first").reset_index(drop=True)[p.columns]


def paired_table(results: pd.DataFrame, metrics: Sequence[str],
                 better: Mapping[str, str | None], reference: str | None = None,
                 seed: int = SEED) -> pd.DataFrame:  # fmt: skip
    """Long table, one row per (other variant, metric, case): every variant against
    ``reference`` (default: the first variant, :func:`variants`).

    Columns: ``reference``, ``other``, ``metric``, ``better``, ``case``, ``n`` (worlds,
    :func:`per_world`), ``runs`` (the pairs they hold), ``n_unpaired``, ``ref_median`` (the
    reference's median over the worlds), ``estimate`` (the Hodges-Lehmann estimate of the
    difference), ``median`` (the plain median difference, for reference), ``ci_low``,
    ``ci_high`` (the estimate's interval), ``p``, ``note``, ``verdict``. Metrics without a
    column in ``results`` are left out (see :func:`missing_metrics`).
    """
    names = variants(results)
    if not names:
        return pd.DataFrame()
    reference = names[0] if reference is None else reference
    ok = results[results["status"] == "ok"]
    cases = list(dict.fromkeys(ok[CASE]))
    rows = []
    for other in (v for v in names if v != reference):
        for m in (m for m in metrics if m in results):
            p_, unpaired = pairs(results, m, reference, other)
            p_ = per_world(p_)
            for case in cases:
                g = p_[p_[CASE] == case]
                s = paired_stat(g["ref"].to_numpy(), g["other"].to_numpy(), seed)
                ref_median = float(g["ref"].median()) if len(g) else math.nan
                rows.append({
                    "reference": reference, "other": other, "metric": m,
                    "better": better.get(m), "case": case, "n": s.n,
                    "runs": int(g["runs"].sum()),
                    "n_unpaired": int(unpaired.get(case, 0)),
                    "ref_median": ref_median,
                    "estimate": s.estimate, "median": s.median,
                    "ci_low": s.ci_low, "ci_high": s.ci_high, "p": s.p,
                    "note": s.note,
                    "verdict": verdict(s, better.get(m), reference, other, ref_median),
                })  # fmt: skip
    return pd.DataFrame(rows)


NOT_SIGNIFICANT = ("no significant difference", "negligible difference", "no difference")


@dataclass(frozen=True)
class Multiplicity:
    """How much the verdicts of one table rest on chance: ``tests`` comparisons with a
    p-value, ``expected_false`` = ``tests`` x :data:`ALPHA` (the "better" verdicts expected
    if no variant differed anywhere), ``better`` such verdicts, of which ``better_bh`` keep
    p < :data:`ALPHA` after the Benjamini-Hochberg adjustment of the table's p-values
    (:func:`scipy.stats.false_discovery_control`)."""

    tests: int
    expected_false: float
    better: int
    better_bh: int


def multiplicity(table: pd.DataFrame) -> Multiplicity:
    """:class:`Multiplicity` of the rows of :func:`paired_table` in ``table`` (e.g. one
    compared variant's headline rows). The verdicts themselves stay unadjusted."""
    if not len(table):
        return Multiplicity(0, 0.0, 0, 0)
    p = table["p"].to_numpy(float)
    tested = np.isfinite(p)
    better = table["verdict"].str.endswith(" better").to_numpy() & tested
    adjusted = np.full(len(p), np.nan)
    if tested.any():
        adjusted[tested] = sps.false_discovery_control(p[tested], method="bh")
    n = int(tested.sum())
    return Multiplicity(n, n * ALPHA, int(better.sum()), int((better & (adjusted < ALPHA)).sum()))


def significant_win_loss(table: pd.DataFrame) -> pd.DataFrame:
    """Per (other, metric): cases where ``other`` / the reference is significantly better,
    with no significant difference, and n/a (from :func:`paired_table`)."""
    if not len(table):
        return pd.DataFrame()
    rows = []
    for (ref, other, m), g in table.groupby(["reference", "other", "metric"], sort=False):
        rows.append({"reference": ref, "other": other, "metric": m,
                     "better": g["better"].iloc[0],
                     "other_better": int((g["verdict"] == f"{other} better").sum()),
                     "reference_better": int((g["verdict"] == f"{ref} better").sum()),
                     "not_significant": int(g["verdict"].isin(NOT_SIGNIFICANT).sum()),
                     "n/a": int((g["verdict"] == "n/a").sum())})  # fmt: skip
    return pd.DataFrame(rows)
