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
from mpcasv.wording import count

#: column naming the compared controller (label plus grid values, e.g. "hybrid[dT=0.2]")
COMPARE = "variant"
#: columns that identify a job apart from the controller: rows equal on these are one pair
PAIR_KEY = ("scenario", "current", "estimator", "seed")
#: identity columns used too when the table has them (the drawn scenario realisation)
OPTIONAL_KEY = ("realisation",)
CASE = "scenario"  # one line of the headline table and forest plot per case
ALPHA = 0.05
CONFIDENCE = 0.95
#: fewest pairs (worlds) with a statistic: the two-sided exact Wilcoxon p is at least 2 / 2^n,
#: 0.0625 for 5, so below 6 no verdict could be "better"
MIN_PAIRS = 6
NEGLIGIBLE = 1e-3  # relative to |reference median|: smaller differences are no verdict
N_RESAMPLES = 9999  # bootstrap resamples (median_stat; the acceptance's sums)
SEED = 20240601  # their generator's seed


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


@dataclass(frozen=True)
class PairedStat:
    """A paired difference (other - reference): its point estimate, CI and Wilcoxon p-value.

    :func:`paired_stat`: ``estimate`` is the Hodges-Lehmann estimate and ``ci_low`` /
    ``ci_high`` its distribution-free interval (the estimand of the Wilcoxon signed-rank
    test, whose ``p`` it is); ``median`` is the plain median of the differences, shown for
    comparison only. :func:`median_stat`: ``median`` and its bootstrap interval, ``estimate``
    NaN. ``ci_low``/``ci_high``/``p`` are NaN where not computed; ``note`` then says why.
    """

    n: int  # pairs
    median: float
    ci_low: float
    ci_high: float
    p: float
    note: str  # "" or the reason a value is n/a
    estimate: float = math.nan  # Hodges-Lehmann (paired_stat); NaN for the others


def _median_difference(other: np.ndarray, ref: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.median(other - ref, axis=axis)


def _differences(ref: np.ndarray, other: np.ndarray) -> np.ndarray:
    """``other - ref`` with two equal infinities a zero difference (both never did it)."""
    with np.errstate(invalid="ignore"):
        d = other - ref
    return np.where(np.isinf(ref) & (ref == other), 0.0, d)


def _finite_stand_in(d: np.ndarray) -> tuple[np.ndarray, float]:
    """``d`` with +-inf replaced by +-S, S far beyond every finite ``|d|`` (ranks, signs and
    order statistics kept), and the largest finite ``|d|`` M: a statistic of the stand-in
    beyond M is infinite."""
    finite = np.abs(d[np.isfinite(d)])
    M = float(finite.max()) if finite.size else 0.0
    return np.where(np.isinf(d), np.sign(d) * 1e15 * (M + 1.0), d), M


def _back(v: float, M: float) -> float:
    """A statistic of the stand-in (:func:`_finite_stand_in`) in the metric's terms: beyond
    the largest finite ``|d|`` M it fell on an infinite difference."""
    return math.copysign(math.inf, v) if abs(v) > M * (1 + 1e-9) + 1e-9 else float(v)


def signed_rank_null_cdf(n: int) -> np.ndarray:
    """``P(T+ <= t)``, t = 0 .. n(n+1)/2 (shape (n(n+1)/2 + 1,)), of the Wilcoxon
    signed-rank statistic T+ of n differences without ties or zeros under the null
    hypothesis (symmetry about 0): each rank 1..n is positive with probability 1/2
    independently, so the distribution is the coefficients of prod_i (1 + x^i) / 2
    (Hollander, Wolfe & Chicken, *Nonparametric Statistical Methods*, 3rd ed., Wiley 2014,
    §3.1). Computed exactly for any n (no normal approximation)."""
    pmf = np.zeros(n * (n + 1) // 2 + 1)
    pmf[0] = 1.0
    for i in range(1, n + 1):
        pmf[i:] = 0.5 * (pmf[i:] + pmf[:-i])  # in place, from the top: pmf[:-i] is old
        pmf[:i] *= 0.5
    return np.minimum(np.cumsum(pmf), 1.0)


def walsh_averages(d: np.ndarray) -> np.ndarray:
    """The n(n+1)/2 Walsh averages ``(d_i + d_j) / 2``, i <= j, sorted (shape
    (n(n+1)/2,))."""
    i, j = np.triu_indices(len(d))
    return np.sort((d[i] + d[j]) / 2.0)


def hodges_lehmann(d: np.ndarray, confidence: float = CONFIDENCE
                   ) -> tuple[float, float, float, float]:  # fmt: skip
    """The Hodges-Lehmann estimate of the differences ``d`` (shape (n,), finite) and its
    distribution-free confidence interval, the interval that inverts the two-sided Wilcoxon
    signed-rank test (Tukey 1949; Hollander, Wolfe & Chicken 2014, §3.2-3.3): with the
    sorted Walsh averages W(1) <= ... <= W(M), M = n(n+1)/2,

    - estimate = median of the W (Hodges & Lehmann, *Ann. Math. Stat.* 34:598, 1963), the
      estimand the signed-rank test is about (the pseudo-median: the centre of symmetry
      when the differences are symmetric about one);
    - interval [W(C), W(M + 1 - C)], C the largest integer with P(T+ <= C - 1) <= alpha / 2
      under the exact null distribution (:func:`signed_rank_null_cdf`; Hollander-Wolfe's
      C_alpha = M + 1 - t_alpha/2). Its coverage for continuous differences symmetric about
      their centre is 1 - 2 P(T+ <= C - 1) >= ``confidence`` (n = 10: C = 9, 95.1 %).

    Returns (estimate, low, high, achieved confidence); low/high NaN when no C exists (n < 6
    at 95 %: the test cannot reach p < 0.05 there either). Without ties and zeros, 0 lies
    outside the interval exactly when the exact two-sided Wilcoxon p < 1 - ``confidence``.
    """
    d = np.asarray(d, float)
    w = walsh_averages(d)
    est = float(np.median(w))
    cdf = signed_rank_null_cdf(len(d))
    alpha = 1.0 - confidence
    ok = np.flatnonzero(cdf <= alpha / 2 * (1 + 1e-12))
    if not ok.size:
        return est, math.nan, math.nan, math.nan
    c = int(ok[-1]) + 1  # C: P(T+ <= C - 1) <= alpha / 2
    return est, float(w[c - 1]), float(w[len(w) - c]), float(1.0 - 2.0 * cdf[c - 1])


def paired_stat(ref: np.ndarray, other: np.ndarray, seed: int = SEED) -> PairedStat:
    """Statistics of the pairs ``(ref[i], other[i])`` (shape (n,) each, units of the metric):
    the Hodges-Lehmann estimate of the difference with its distribution-free 95 % interval
    (:func:`hodges_lehmann`) and the two-sided Wilcoxon signed-rank p (:func:`wilcoxon_p`):
    the interval and the test are about the same estimand. Until session 49 the interval was
    a percentile bootstrap of the *median* difference beside the Wilcoxon test of the
    pseudo-median: the two disagreed (session 48's main job, Case 5 minimum range: interval
    [-0.92, 38.1] m with p = 0.037; Case 2 worst fix age: [-260, -5] s with p = 0.064).
    ``median`` keeps the plain median of the differences, for reference. Infinite values
    take part: the test only sees ranks and signs, and an estimate or bound that falls on
    an infinite difference is reported as +-inf. ``seed`` is kept for the callers: no
    statistic here draws at random."""
    ref, other = np.asarray(ref, float), np.asarray(other, float)
    d, M = _finite_stand_in(_differences(ref, other))
    n = len(d)
    if n == 0:
        return PairedStat(0, math.nan, math.nan, math.nan, math.nan, "no pairs")
    med = _back(float(np.median(d)), M)
    est, lo, hi, _ = hodges_lehmann(d)
    est = _back(est, M)
    if n < MIN_PAIRS:
        return PairedStat(n, med, math.nan, math.nan, math.nan,
                          f"n/a: {count(n, 'pair')} < {MIN_PAIRS}", est)  # fmt: skip
    if np.all(d == 0):
        return PairedStat(n, 0.0, 0.0, 0.0, math.nan,
                          f"all {n} differences zero: no test", 0.0)  # fmt: skip
    lo, hi = _back(lo, M), _back(hi, M)
    nonzero = int(np.count_nonzero(d))
    if nonzero < MIN_PAIRS:  # the test drops the zeros: its smallest p is 2 / 2^nonzero
        return PairedStat(n, med, lo, hi, math.nan,
                          f"n/a: {count(nonzero, 'non-zero difference')} < {MIN_PAIRS}", est)
    return PairedStat(n, med, lo, hi, wilcoxon_p(d), "", est)


def median_stat(ref: np.ndarray, other: np.ndarray, seed: int = SEED) -> PairedStat:
    """The median of the paired differences ``other - ref`` (shape (n,) each) with its 95 %
    percentile bootstrap interval (:func:`scipy.stats.bootstrap`, ``paired=True``,
    :data:`N_RESAMPLES` resamples, generator seeded with ``seed``; ``p`` NaN: no test).
    A descriptive figure (the acceptance's per-pair relative change); the headline's
    statistic is :func:`paired_stat`. The percentile interval of a median of few values
    covers less than its nominal 95 % (a Student t with 3 degrees of freedom, 4000 seeded
    samples: 93.9 % at n = 6, 94.7 % at n = 10; tests/test_stats_hodges_lehmann.py).
    """
    ref, other = np.asarray(ref, float), np.asarray(other, float)
    d, M = _finite_stand_in(_differences(ref, other))
    n = len(d)
    if n == 0:
        return PairedStat(0, math.nan, math.nan, math.nan, math.nan, "no pairs")
    med = _back(float(np.median(d)), M)
    if n < MIN_PAIRS:
        return PairedStat(n, med, math.nan, math.nan, math.nan,
                          f"n/a: {count(n, 'pair')} < {MIN_PAIRS}")  # fmt: skip
    if np.all(d == d[0]):  # every resample has the same median: the interval is that point
        lo = hi = _back(float(d[0]), M)
    else:
        ci = sps.bootstrap(
            (d, np.zeros(n)), _median_difference, vectorized=True, paired=True,
            n_resamples=N_RESAMPLES, confidence_level=CONFIDENCE, method="percentile",
            rng=np.random.default_rng(seed),
        ).confidence_interval  # fmt: skip
        lo, hi = _back(float(ci.low), M), _back(float(ci.high), M)
    return PairedStat(n, med, lo, hi, math.nan, "")


def wilcoxon_p(d: np.ndarray) -> float:
    """Two-sided Wilcoxon signed-rank p-value of the differences ``d`` (zeros dropped), as
    :func:`scipy.stats.wilcoxon` with ``method="auto"`` gives it: exact without ties or
    zeros; with them, an exact sign-flip permutation test for n <= 13, else the normal
    approximation. scipy runs that permutation test with an unvectorised statistic (0.2 to
    0.7 s per call here, minutes for a report); the same test is run here through
    :func:`scipy.stats.permutation_test` with the statistic vectorised (equal p-values:
    tests/test_report_stats.py)."""
    d = np.asarray(d, float)
    nz = d[d != 0]
    ties = len(np.unique(np.abs(nz))) < len(nz)
    if not ties and len(nz) == len(d):
        return float(sps.wilcoxon(d, method="exact").pvalue)
    if len(d) > 13:
        return float(sps.wilcoxon(d, method="asymptotic").pvalue)
    if len(nz) < 2:  # one non-zero difference: scipy's own test (p = 1), cheap here
        return float(sps.wilcoxon(d, zero_method="wilcox").pvalue)
    ranks = sps.rankdata(np.abs(nz))

    def r_plus(x: np.ndarray, axis: int = -1) -> np.ndarray:  # sum of the positive ranks
        return np.sum(ranks * (x > 0), axis=axis)

    return float(sps.permutation_test((nz,), r_plus, permutation_type="samples",
                                      vectorized=True, alternative="two-sided").pvalue)  # fmt: skip


def verdict(s: PairedStat, better: str | None, reference: str, other: str,
            ref_median: float = math.nan) -> str:  # fmt: skip
    """Which variant is significantly better (CI excludes 0 and p < ALPHA, and the CI is not
    inside +-NEGLIGIBLE x |ref_median|), in words."""
    if s.n and s.note.startswith(f"all {s.n} differences zero"):
        return "no difference"
    if s.note or better is None or not np.isfinite(s.p):
        return "n/a"
    if not (s.p < ALPHA and (s.ci_low > 0 or s.ci_high < 0)):
        return "no significant difference"
    if max(abs(s.ci_low), abs(s.ci_high)) < NEGLIGIBLE * abs(ref_median):
        return "negligible difference"
    centre = s.estimate if not math.isnan(s.estimate) else s.median  # the interval's own
    other_better = (centre > 0) == (better == "higher")
    return f"{other if other_better else reference} better"


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


def interval_disagrees(r: Mapping) -> bool:
    """Whether the interval and the test of one :func:`paired_table` row (or
    :class:`PairedStat` fields as a mapping) say different things: the interval excludes 0
    and p >= :data:`ALPHA`, or the reverse. Impossible without tied or zero differences
    (:func:`hodges_lehmann`); with them (whole seconds, counts) the exact interval's level
    and the test's tie-corrected p can part at the boundary, and the verdict, which needs
    both, is then "no significant difference"."""
    p, lo, hi = r["p"], r["ci_low"], r["ci_high"]
    if not np.isfinite(p) or math.isnan(lo) or math.isnan(hi):  # no test or no interval
        return False
    return bool((lo > 0 or hi < 0) != (p < ALPHA))


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
