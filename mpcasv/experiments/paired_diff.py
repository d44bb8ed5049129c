"""The statistics of one set of paired differences (other - reference, one per world):
the Hodges-Lehmann estimate with its distribution-free interval and the Wilcoxon signed-rank
p-value of the same estimand (:func:`paired_stat`, the headline's), the median with its
bootstrap interval (:func:`median_stat`, descriptive: the acceptance's per-pair column), and
the verdict. :mod:`mpcasv.experiments.stats` builds the tables from them (and re-exports
these names). Infinite differences take part (a stand-in beyond every finite one, reported
back as +-inf); no statistic here draws at random but :func:`median_stat`'s seeded bootstrap.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import stats as sps

from mpcasv.wording import count

ALPHA = 0.05
CONFIDENCE = 0.95
#: fewest pairs (worlds) with a statistic: the two-sided exact Wilcoxon p is at least 2 / 2^n,
#: 0.0625 for 5, so below 6 no verdict could be "better"
MIN_PAIRS = 6
NEGLIGIBLE = 1e-3  # relative to |reference median|: smaller differences are no verdict
N_RESAMPLES = 9999  # bootstrap resamples (median_stat; the acceptance's sums)
SEED = 20240601  # their generator's seed


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
    d, M = _finite_stand_in(_differences(np.asarray(ref, float), np.asarray(other, float)))
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
    d, M = _finite_stand_in(_differences(np.asarray(ref, float), np.asarray(other, float)))
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
