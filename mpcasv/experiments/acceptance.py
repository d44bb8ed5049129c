"""Acceptance targets of a suite: the relative changes a compared variant must show against
the reference, judged on the paired runs with their confidence intervals.

A suite may name them (issue 16's acceptance in ``experiments/suites/paper.toml``)::

    [acceptance]
    source = "issue 16"
    explained_in = "docs/mpc.md, 'What stands in the way of the acceptance'"
    targets = { reliable_fix_age_p95_s = -0.30, nav_error_rms_m = -0.20,
                propeller_on_s = 0.0, collision_domain_s = 0.0 }

A target ``c`` of a metric where lower is better asks for ``(sum other - sum ref) / sum ref
<= c`` (-0.30: at least 30 % lower; 0: no more); where higher is better, ``>= c``: the
relative change of the sums (equivalently of the means) over the paired worlds (the report's
pairing, :func:`mpcasv.experiments.stats.pairs`, one pair per world), pooled over every case
of the suite except, for a metric that needs fixes (:data:`NEEDS_FIXES`), the cases where no
USBL fix arrived in any run (there the fix ages are the run's clock and the AUVs navigate
without fixes whatever the controller). Its 95 % CI is a percentile bootstrap of the
stratified design: worlds resampled within each cell (scenario, current, estimator: the
suite fixes their number per cell), one-world cells collapsed, rescaled (:func:`sums_stat`,
:func:`strata`); the interval is conditional on these cells: it says nothing of cases unlike
them.
Verdict: **met** when the whole CI is at or on the better side of the target, **not met**
when it is all on the worse side, else **undecided**; a target with unpaired runs is not
counted as met.

Until session 48 the verdict was the median of the per-pair relative changes ``(other - ref)
/ |ref|`` with an unstratified bootstrap CI (still shown, :func:`relative_changes`,
:func:`mpcasv.experiments.stats.median_stat`; since session 49 the headline's interval is
another, the Hodges-Lehmann one, and this column keeps its own). A
statistician's review found it the wrong estimand for these targets: pooled over cases whose
effects go opposite ways it fell in the gap between them (issue 16's propeller time: +15 to
+591 % in Cases 1-4, -25 to +17 % in Cases 5-8, pooled median +9.8 % [-5.1, +32.3],
"undecided", with no world between +4.2 and +15.4 %; the sums +14.9 %, not met), and a
median meets "no more time in the collision domain" with a few worlds much worse (4 of 80 in
session 47's main job, each +inf). "At least 30 % lower" and "no more" are statements about
totals; the sums are also defined where many worlds are 0 (which the per-pair change had to
leave out). Infinite values on both sides (e.g. AUVs never revisited under both
controllers) leave the ratio of the sums undefined: n/a, the per-pair median still shown;
on one side only the sums are infinite or -100 %, as per pair. Fewer than
:data:`~mpcasv.experiments.stats.MIN_PAIRS` pairs: n/a.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from mpcasv.config import Float, frozen
from mpcasv.experiments import stats as paired
from mpcasv.experiments.metric_info import METRIC_INFO
from mpcasv.wording import count, noun

#: metrics that compare nothing in a case without any USBL fix (name prefixes)
NEEDS_FIXES = ("reliable_fix_age", "fix_age", "nav_error", "fixes", "reliable_fixes")


@frozen
class Acceptance:
    """A suite's ``[acceptance]`` table.

    Attributes
    ----------
    targets : dict
        Metric name -> required relative change of every compared variant against the
        reference (dimensionless: -0.30 = at least 30 % lower where lower is better; 0 = no
        more). Per-run metrics of :data:`~mpcasv.experiments.metric_info.METRIC_INFO` with a
        direction only (not the per-AUV lists ``*_auv``).

    Raises
    ------
    ValueError
        No target; a name that is not such a metric; a target at or below -1 (-100 %).
    source : str
        Where the targets come from (e.g. "issue 16"); shown in the report's heading.
    explained_in : str
        Where a reader finds what stands in the way when a target is not met.
    """

    targets: dict[str, Float]
    source: str = ""
    explained_in: str = ""

    def __post_init__(self) -> None:
        if not self.targets:
            raise ValueError("'targets' is empty: name at least one metric")
        for m, c in self.targets.items():
            info = METRIC_INFO.get(m)
            if m.endswith("_auv") or info is None or info.better not in ("lower", "higher"):
                usable = sorted(k for k, v in METRIC_INFO.items()
                                if v.better and not k.endswith("_auv"))  # fmt: skip
                raise ValueError(f"target {m!r}: not a per-run metric with a direction (a "
                                 f"per-AUV list is judged by its scalar); known: {usable}")
            if c <= -1.0:
                raise ValueError(f"target {m} = {c}: a relative change of a metric >= 0 is "
                                 "above -100 % (-1)")  # fmt: skip


def relative_changes(ref: np.ndarray, other: np.ndarray) -> np.ndarray:
    """Per pair ``(other - ref) / |ref|`` (shape (n,), dimensionless), its limits where that
    is undefined: equal values (both zero, both infinite) 0; the reference zero and the
    other not: +-inf with the other's sign; the reference infinite and the other finite: -1
    (e.g. an AUV never revisited against one revisited)."""
    ref, other = np.asarray(ref, float), np.asarray(other, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = (other - ref) / np.abs(ref)
    rel = np.where(ref == 0, np.copysign(math.inf, other), rel)
    rel = np.where(np.isinf(ref) & np.isfinite(other), -1.0, rel)
    return np.where(ref == other, 0.0, rel)


def verdict(better: str, target: float, s: paired.PairedStat) -> str:
    """"met", "not met", "undecided" or "n/a: ..." for the relative-change statistics ``s``
    against ``target`` on a metric where ``better`` ("lower" | "higher") is better: met when
    the whole CI is at or on the better side of the target, not met when the whole CI is on
    the worse side, else undecided."""
    if math.isnan(s.ci_low) or math.isnan(s.ci_high):  # too few pairs, or none
        note = s.note or "no interval"
        return note if note.startswith("n/a") else f"n/a: {note}"
    lo, hi = (s.ci_low, s.ci_high) if better == "lower" else (-s.ci_high, -s.ci_low)
    c = target if better == "lower" else -target
    if hi <= c:
        return "met"
    if lo > c:
        return "not met"
    return "undecided"


#: the label of the stratum the design's one-world cells are collapsed into (:func:`strata`)
COLLAPSED = "(cells with one world)"


def strata(cells: np.ndarray) -> np.ndarray:
    """The bootstrap's strata (shape (n,), labels) from the design's cells ``cells`` (shape
    (n,), one label per world): a cell with one world has no variance within it and would
    enter every resample unchanged (eight one-world cases gave a zero-width interval, a
    review), so such cells are collapsed into one stratum, and a lone one into the smallest
    other cell (collapsed strata: Wolter, *Introduction to Variance Estimation*, 2nd ed.
    2007, §2.5)."""
    labels = pd.Series(cells, dtype="string").to_numpy(dtype=object)
    names, sizes = np.unique(labels, return_counts=True)
    single = names[sizes == 1]
    if len(single) >= 2:
        labels = np.where(np.isin(labels, single), COLLAPSED, labels)
    elif len(single) == 1 and len(names) > 1:
        big = sizes > 1
        labels = np.where(labels == single[0], names[big][np.argmin(sizes[big])], labels)
    return labels


def sums_stat(ref: np.ndarray, other: np.ndarray, cells: np.ndarray,
              seed: int = paired.SEED) -> paired.PairedStat:  # fmt: skip
    """The relative change of the sums ``(sum other - sum ref) / sum ref`` of the pairs
    ``(ref[i], other[i])`` (shape (n,) each, the metric's units; limits as
    :func:`relative_changes`: both sums 0 is 0, ``sum ref`` 0 alone +-inf, an infinite
    ``sum other`` +inf, an infinite ``sum ref`` alone -1) as a
    :class:`~mpcasv.experiments.stats.PairedStat` (``median`` holds the change, ``p`` NaN),
    with its 95 % percentile bootstrap CI: :data:`~mpcasv.experiments.stats.N_RESAMPLES`
    resamples of the stratified design, the strata the design's cells (``cells``, shape
    (n,): scenario, current and estimator; :func:`strata`). Each resample draws ``n_h - 1``
    of a stratum's ``n_h`` worlds with replacement and weights them ``n_h / (n_h - 1)`` (the
    rescaling bootstrap of Rao & Wu, *JASA* 83:231, 1988, with ``m_h = n_h - 1``, as McCarthy
    & Snowden 1985: the naive ``n_h`` of ``n_h`` under-states a stratum's variance by
    ``(n_h - 1) / n_h``); quantiles without interpolation (an infinite resample stays one).

    n/a (``ci_low``/``ci_high`` NaN, ``note`` says why): fewer than
    :data:`~mpcasv.experiments.stats.MIN_PAIRS` pairs; infinite values on both sides (their
    sums' ratio is undefined)."""
    ref, other = np.asarray(ref, float), np.asarray(other, float)
    n = len(ref)
    if n == 0:
        return paired.PairedStat(0, math.nan, math.nan, math.nan, math.nan, "n/a: no pairs")
    if np.isinf(ref).any() and np.isinf(other).any():
        return paired.PairedStat(n, math.nan, math.nan, math.nan, math.nan,
                                 "n/a: infinite on both sides (no ratio of their sums)")
    change = float(relative_changes(np.array([ref.sum()]), np.array([other.sum()]))[0])
    if n < paired.MIN_PAIRS:
        return paired.PairedStat(n, change, math.nan, math.nan, math.nan,
                                 f"n/a: {count(n, 'pair')} < {paired.MIN_PAIRS}")  # fmt: skip
    rng = np.random.default_rng(seed)
    sum_r = np.zeros(paired.N_RESAMPLES)
    sum_o = np.zeros(paired.N_RESAMPLES)
    st = strata(cells)
    for h in dict.fromkeys(st):  # the strata in their order: the same draws each time
        r, o = ref[st == h], other[st == h]
        idx = rng.integers(0, len(r), size=(paired.N_RESAMPLES, len(r) - 1))
        sum_r += len(r) * r[idx].mean(axis=1)
        sum_o += len(r) * o[idx].mean(axis=1)
    boot = relative_changes(sum_r, sum_o)
    alpha = (1 - paired.CONFIDENCE) / 2
    lo, hi = np.quantile(boot, [alpha, 1 - alpha], method="inverted_cdf")
    return paired.PairedStat(n, change, float(lo), float(hi), math.nan, "")


def acceptance_table(results: pd.DataFrame, acc: Acceptance, reference: str, other: str,
                     no_fix_cases: list[str]) -> pd.DataFrame:  # fmt: skip
    """One row per target: ``metric``, ``better``, ``target``, ``pairs`` (one per world,
    :func:`mpcasv.experiments.stats.per_world`), ``runs`` (the pairs of runs they hold),
    ``unpaired`` (runs of either variant without a partner: a failed job, a missing value),
    ``cases`` (pooled), ``sums``, ``sums_low``, ``sums_high`` (the relative change of the
    sums and its CI, :func:`sums_stat`: the verdict's), ``median``, ``ci_low``, ``ci_high``
    (the median relative change per pair and its percentile bootstrap CI,
    :func:`mpcasv.experiments.stats.median_stat`, shown beside it), ``both_zero``
    (pairs left out of that median: both 0 says nothing about more or less; unless all are:
    then it is 0), ``worse`` (pairs where ``other`` is on the worse side of ``reference``: a
    total can meet "no more" with some worlds worse, a statistician's review, session 46) and
    ``verdict`` (with ", N runs unpaired" when some are). ``no_fix_cases``: the cases left
    out for :data:`NEEDS_FIXES` metrics. A metric without a column: 0 pairs, "n/a: no
    column"."""
    rows = []
    for m, c in acc.targets.items():
        better = METRIC_INFO[m].better
        row = {"metric": m, "better": better, "target": float(c)}
        if m not in results:
            rows.append(row | {"pairs": 0, "runs": 0, "unpaired": 0, "cases": "",
                               "sums": math.nan, "sums_low": math.nan, "sums_high": math.nan,
                               "median": math.nan, "ci_low": math.nan, "ci_high": math.nan,
                               "both_zero": 0, "worse": 0,
                               "verdict": "n/a: no column"})  # fmt: skip
            continue
        p, unpaired = paired.pairs(results, m, reference, other)
        if m.startswith(NEEDS_FIXES):
            p = p[~p[paired.CASE].isin(no_fix_cases)]
            unpaired = unpaired.drop(no_fix_cases, errors="ignore")
        p = paired.per_world(p)
        ref, oth = p["ref"].to_numpy(float), p["other"].to_numpy(float)
        cell = [c for c in paired.pair_key(results) if c not in ("seed", "realisation")]
        total = sums_stat(ref, oth, p[cell].astype(str).agg(" | ".join, axis=1).to_numpy())
        zero = (ref == 0) & (oth == 0)
        if zero.all():  # both 0 in every pair: the change is 0 in each (not "no pairs")
            zero = zero & False
        # the median and its bootstrap interval (descriptive: no test goes with it)
        per_pair = paired.median_stat(np.zeros(int(np.sum(~zero))),
                                      relative_changes(ref[~zero], oth[~zero]))  # fmt: skip
        n_unpaired = int(unpaired.sum())
        v = verdict(better, c, total) + (f", {count(n_unpaired, 'run')} unpaired"
                                         if n_unpaired else "")  # fmt: skip
        rows.append(row | {"pairs": len(p), "runs": int(p["runs"].sum()),
                           "unpaired": n_unpaired,
                           "cases": ", ".join(dict.fromkeys(p[paired.CASE])),
                           "sums": total.median, "sums_low": total.ci_low,
                           "sums_high": total.ci_high,
                           "median": per_pair.median, "ci_low": per_pair.ci_low,
                           "ci_high": per_pair.ci_high, "both_zero": int(zero.sum()),
                           "worse": int(np.sum(oth > ref) if better == "lower"
                                        else np.sum(oth < ref)),
                           "verdict": v})  # fmt: skip
    return pd.DataFrame(rows)


def _pct(v: float) -> str:
    if math.isnan(v):
        return "n/a"
    return f"{100 * v:+.1f} %" if math.isfinite(v) else ("+inf" if v > 0 else "-inf")


def display_table(t: pd.DataFrame) -> pd.DataFrame:
    """:func:`acceptance_table` as the report shows it (percentages)."""
    return pd.DataFrame({
        "required (other vs reference)": [("<= " if b == "lower" else ">= ") + _pct(c)
                                          for b, c in zip(t["better"], t["target"],
                                                          strict=True)],
        "pairs": [f"{n}" + (f" {noun(n, 'world')} ({r} runs)" if r > n else "")
                  + (f" (+{u} unpaired)" if u else "")
                  for n, r, u in zip(t["pairs"], t["runs"], t["unpaired"], strict=True)],
        f"change of the sums [{paired.CONFIDENCE:.0%} CI, worlds resampled in each cell]": [
            _pct(v) + (f" [{_pct(lo)}, {_pct(hi)}]" if not math.isnan(lo) else "")
            for v, lo, hi in zip(t["sums"], t["sums_low"], t["sums_high"], strict=True)],
        f"per pair: median [{paired.CONFIDENCE:.0%} CI]": [
            f"{_pct(m)} [{_pct(lo)}, {_pct(hi)}]" + (f" ({z} both 0 left out)" if z else "")
            for m, lo, hi, z in zip(t["median"], t["ci_low"], t["ci_high"], t["both_zero"],
                                    strict=True)],
        "worse in": [f"{w} of {n}" for w, n in zip(t["worse"], t["pairs"], strict=True)],
        "verdict": t["verdict"].to_list(),
    }, index=pd.Index(t["metric"], name="metric"))  # fmt: skip


def per_case_table(results: pd.DataFrame, acc: Acceptance, reference: str, other: str,
                   no_fix_cases: list[str]) -> pd.DataFrame:  # fmt: skip
    """The targets judged on each case alone (the same rule as :func:`acceptance_table`, on
    one case's pairs): rows are the cases in the order of ``results``, columns the targets'
    metrics; each cell reads ``"+126 % [+80, +160] (10, 9 worse): not met"`` (the relative
    change of the sums, its 95 % CI, the pairs used and how many of them the other variant
    did worse in; dimensionless, in %) or ``"no fix"`` for a
    :data:`NEEDS_FIXES` metric in one of ``no_fix_cases``. A pooled verdict can sit between
    cases that go opposite ways (issue 16, session 44: propeller +43-126 % in Cases 1-4,
    -5 to -10 % in Cases 5-8, pooled "undecided"); this table shows them."""
    cells: dict[str, dict[str, str]] = {}
    for case in dict.fromkeys(results[paired.CASE]):
        t = acceptance_table(results[results[paired.CASE] == case], acc, reference, other,
                             no_fix_cases).set_index("metric")  # fmt: skip
        cells[case] = {m: "no fix" if m.startswith(NEEDS_FIXES) and case in no_fix_cases
                       else _cell(t.loc[m]) for m in acc.targets}  # fmt: skip
    return pd.DataFrame.from_dict(cells, orient="index").rename_axis(paired.CASE)


def _cell(row: pd.Series) -> str:
    """One :func:`per_case_table` cell from an :func:`acceptance_table` row."""
    def short(v: float) -> str:
        return _pct(v).removesuffix(" %") if math.isfinite(v) else _pct(v)

    if row["pairs"] == 0:
        return row["verdict"]
    ci = ("" if math.isnan(row["sums_low"])
          else f" [{short(row['sums_low'])}, {short(row['sums_high'])}]")  # fmt: skip
    return f"{_pct(row['sums'])}{ci} ({row['pairs']}, {row['worse']} worse): {row['verdict']}"


def report_parts(results: pd.DataFrame, acc: Acceptance, names: list[str],
                 no_fix_cases: list[str]) -> tuple[str, str, list[tuple[str, pd.DataFrame, str]]]:
    """What the report's "Acceptance" section says: its heading, the rule, and for each
    variant after the reference ``names[0]`` (sub-heading, :func:`display_table`, the
    conclusion: how many targets are met and, unless all, where
    :attr:`Acceptance.explained_in` says what stands in the way)."""
    head = f"Acceptance ({acc.source})" if acc.source else "Acceptance"
    needs = [m for m in acc.targets if m.startswith(NEEDS_FIXES)]
    left_out = (f" ({', '.join(needs)} without {', '.join(no_fix_cases)}: no USBL fix arrived "
                "there)") if no_fix_cases and needs else ""  # fmt: skip
    rule = (f"The relative change of the sums (Σ other − Σ reference) / Σ reference over the "
            f"paired worlds, pooled over the cases{left_out}, one pair per world (the pairs of "
            f"a case on the same realisation averaged), with its {paired.CONFIDENCE:.0%} "
            "percentile bootstrap CI resampling the worlds within each cell of the design "
            "(scenario, current, estimator; one-world cells collapsed; Rao-Wu rescaled), so "
            "conditional on these cells; the median of the per-pair relative changes (other − "
            "reference) / |reference| is shown beside it (pairs where both are 0 left out of "
            "it). *met*: the whole CI of the sums' change is at or on the better side of the "
            "requirement; *not met*: the whole CI is on the worse side; *undecided*: it "
            "straddles it. A target with unpaired runs (a failed job, a missing value) is not "
            "counted as met.")  # fmt: skip
    parts = []
    for other in names[1:]:
        t = acceptance_table(results, acc, names[0], other, no_fix_cases)
        met = int((t["verdict"] == "met").sum())
        unjudged = int(t["verdict"].str.startswith("n/a").sum())
        if met == len(t):
            says = "**The target is met.**" if met == 1 else f"**All {met} targets met.**"
        elif unjudged == len(t):
            says = ("**The target is not judged** (its verdict says why)." if unjudged == 1
                    else f"**None of the {unjudged} targets judged** (each verdict says why).")
        else:
            says = (f"**{met} of {count(len(t), 'target')} met.**"
                    + (f" {unjudged} not judged (n/a)." if unjudged else "") + (
                        f" What stands in the way: {acc.explained_in}."
                        if acc.explained_in else ""))  # fmt: skip
        parts.append((f"{other} vs {names[0]}", display_table(t), says))
    return head, rule, parts


def why_not_judged(results: pd.DataFrame) -> str | None:
    """Why a suite's targets cannot be judged on ``results`` (None: they can, in the
    report): no paired comparison (:func:`mpcasv.experiments.stats.comparison_problem`).
    One definition for the report's acceptance section and for ``mpcasv compare
    --no-report``'s line."""
    why = paired.comparison_problem(results)
    return None if why is None else f"no paired comparison ({why})"
