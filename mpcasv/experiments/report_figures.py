"""Figures of the sweep report drawn from the results table (see :mod:`mpcasv.experiments.report`;
the figures drawn from the runs' time series, ECDFs and representative runs, are in
:mod:`mpcasv.experiments.report_series`), and the number format the report uses.

- :func:`forest_figure`: paired differences (other - reference) per headline metric, one
  panel per metric, cases on the y axis, 95 % CI as bars, the zero line, which side is better;
- :func:`box_figure`: per scenario, box plots across seeds (horizontal: long labels fit).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from mpcasv.experiments.stats import ALPHA, COMPARE, HeadlineMetric

CONDITION = ["current", "estimator"]
SYMLOG_RATIO = 100.0  # forest panels whose nonzero |median| span more than this: symlog x
#: differences within this fraction of the metric's size (its values in the case) are
#: floating-point noise, drawn at 0: a min range difference of -3.23e-11 m (of ~100 m) gave
#: an axis in units of 1e-11 m, which looked like a real difference. Far above the noise of
#: sums over a run (~1e-16 relative per operation), far below any physical difference
FLOAT_NOISE = 1e-9
VERDICT_COLOURS = {"other": "tab:green", "reference": "tab:red", "none": "0.35"}


def num(x: float) -> str:
    """A number for tables and labels: 4 significant digits, exponent when large/small."""
    if not np.isfinite(x):
        return "nan" if np.isnan(x) else str(x)
    if x == 0:
        return "0"
    if abs(x) >= 1e5 or abs(x) < 1e-3:
        return f"{x:.3g}"
    return f"{x:.4g}" if abs(x) < 1000 else f"{x:.0f}"


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return path


def group_label(r, conditions: Sequence[str]) -> str:
    """``variant``, or ``variant · current 0.1,0.1`` when conditions vary in the suite."""
    extra = ", ".join(f"{c} {r[c]}" for c in conditions)
    return f"{r[COMPARE]} · {extra}" if extra else str(r[COMPARE])


# ----------------------------------------------------------------------------- forest


def centre(g: pd.DataFrame) -> str:
    """The column of :func:`stats.paired_table` its interval is about: ``estimate`` (the
    Hodges-Lehmann estimate; since session 49), else ``median`` (an older table)."""
    return "estimate" if "estimate" in g else "median"


def float_noise(g: pd.DataFrame) -> pd.Series:
    """Rows of :func:`stats.paired_table` whose estimate (:func:`centre`) and CI bounds are
    all zero to floating-point precision (within :data:`FLOAT_NOISE` of the larger of the
    reference's and the other's median) but not all exactly zero: no difference, drawn at
    0."""
    est = centre(g)
    size = np.maximum(np.abs(g["ref_median"]), np.abs(g["ref_median"] + g[est]))
    cols = [g[c].where(np.isfinite(g[c]), 0.0) for c in (est, "ci_low", "ci_high")]
    tiny = np.logical_and.reduce([np.abs(v) <= FLOAT_NOISE * size for v in cols])
    return pd.Series(tiny & (np.abs(g[est]) > 0), index=g.index)


def forest_figure(table: pd.DataFrame, metrics: Sequence[HeadlineMetric], path: Path) -> Path:
    """Paired-difference plot of one (reference, other) pair of :func:`stats.paired_table`.

    One panel per metric of ``metrics`` present in ``table``; y: the cases; a dot at the
    Hodges-Lehmann estimate of the difference (other - reference; :func:`centre`), its
    95 % distribution-free CI (the Wilcoxon test's, :func:`stats.hodges_lehmann`) as a bar;
    green where ``other`` is significantly better, red where the reference is, grey
    otherwise; hollow grey dots where the CI is n/a (the reason on the right); a difference zero to
    floating-point precision (:func:`float_noise`) at 0, its value on the right.
    """
    ref, other = table["reference"].iloc[0], table["other"].iloc[0]
    est = centre(table)
    specs = [h for h in metrics if h.name in set(table["metric"])]
    cases = list(dict.fromkeys(table["case"]))
    ncol = 2
    nrow = math.ceil(len(specs) / ncol)
    h_panel = 0.32 * len(cases) + 1.3
    fig, axes = plt.subplots(nrow, ncol, figsize=(17, h_panel * nrow), squeeze=False,
                             layout="constrained")  # fmt: skip
    fig.get_layout_engine().set(wspace=0.08)
    y = np.arange(len(cases))[::-1]  # first case on top
    for ax, h in zip(axes.flat, specs, strict=False):
        g = table[table["metric"] == h.name].set_index("case").reindex(cases)
        noise = float_noise(g)
        right = []
        for yi, (_, r) in zip(y, g.iterrows(), strict=True):
            if r["verdict"] == f"{other} better":
                c = VERDICT_COLOURS["other"]
            elif r["verdict"] == f"{ref} better":
                c = VERDICT_COLOURS["reference"]
            else:
                c = VERDICT_COLOURS["none"]
            if r["verdict"] == "no difference":
                ax.plot(0.0, yi, "o", color=c, ms=5)
                right.append(f"no difference (all {r['n']} zero)")
            elif noise[r.name]:  # zero but for rounding: at 0, its value on the right
                ax.plot(0.0, yi, "o", color=c, ms=5)
                why = f" ({r['note']})" if not np.isfinite(r["ci_low"]) and r["note"] else ""
                right.append(f"0 to float precision ({num(r[est])}) n={r['n']}{why}")
            elif np.isfinite(r["ci_low"]):
                ax.errorbar(r[est], yi, xerr=[[r[est] - r["ci_low"]],
                            [r["ci_high"] - r[est]]], fmt="o", color=c, ms=5,
                            capsize=3, lw=1.5)  # fmt: skip
                p = "n/a" if not np.isfinite(r["p"]) else f"{r['p']:.2g}"
                right.append(
                    f"{num(r[est])} [{num(r['ci_low'])}, {num(r['ci_high'])}]"
                    f" p={p} n={r['n']}"
                    + (" negligible" if r["verdict"].startswith("negl") else "")
                )
            elif np.isfinite(r[est]):
                ax.plot(r[est], yi, "o", mfc="none", color="0.5", ms=5)
                right.append(f"{num(r[est])} ({r['note']})")
            else:
                right.append(r["note"] or "no pairs")
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_yticks(y, cases, fontsize=8)
        ax.set_ylim(-0.7, len(cases) - 0.3)
        twin = ax.twinx()
        twin.set_ylim(ax.get_ylim())
        twin.set_yticks(y, right, fontsize=7)
        lo, hi = ax.get_xlim()
        span = max(abs(lo), abs(hi))
        ax.set_xlim(-span * 1.05, span * 1.05)  # zero in the middle: both sides labelled
        scale = ""
        med = np.abs(g.loc[~noise, est].to_numpy(float))
        med = med[np.isfinite(med) & (med > 0)]
        if len(med) and med.max() > SYMLOG_RATIO * med.min():  # cases of very different size
            # linear within the smallest case (at most 3 decades below the largest)
            lin = float(max(med.min(), med.max() / 1e3))
            ax.set_xscale("symlog", linthresh=lin)
            ax.set_xlim(-span * 2.0, span * 2.0)
            dec = 10.0 ** np.arange(np.ceil(np.log10(lin)) + 1, np.floor(np.log10(span)) + 1)
            ax.set_xticks(np.concatenate([-dec[::-1], [0.0], dec]))
            scale = "; symlog scale"
        left_is_other = h.better == "lower"
        ax.text(0.01, 1.01, f"← {other if left_is_other else ref} better",
                transform=ax.transAxes, fontsize=7, ha="left", va="bottom")  # fmt: skip
        ax.text(0.99, 1.01, f"{ref if left_is_other else other} better →",
                transform=ax.transAxes, fontsize=7, ha="right", va="bottom")  # fmt: skip
        ax.set_title(f"{h.name} ({h.group}; {h.better} is better)", fontsize=9, pad=12)
        ax.set_xlabel(f"Hodges-Lehmann paired difference, {other} − {ref} ({h.unit}{scale})",
                      fontsize=8)
        ax.tick_params(axis="x", labelsize=7)
        ax.grid(axis="x", alpha=0.3)
    for ax in list(axes.flat)[len(specs) :]:
        ax.axis("off")
    fig.suptitle(f"Paired differences {other} − {ref} per case: Hodges-Lehmann estimate "
                 "and its 95 % CI (Walsh averages)\n"
                 f"green: {other} significantly better, red: {ref} significantly better (CI "
                 f"excludes 0, Wilcoxon p < {ALPHA}, not negligible); grey: neither",
                 fontsize=10)  # fmt: skip
    return _save(fig, path)


# ----------------------------------------------------------------------------- per scenario


def box_figure(ok: pd.DataFrame, scenario: str, metrics: Sequence[str],
               better: Mapping[str, str | None], path: Path) -> Path:  # fmt: skip
    """Horizontal box plots across seeds of ``metrics``, one box per variant (and condition
    where the suite has several), every run as a dot; labels on the shared y axis."""
    g = ok[ok["scenario"] == scenario].copy()
    multi = [c for c in CONDITION if g[c].nunique() > 1]
    g["group"] = [group_label(r, multi) for _, r in g.iterrows()]
    labels = list(dict.fromkeys(g["group"]))
    metrics = [m for m in metrics if m in g]
    ncol = 3
    nrow = math.ceil(len(metrics) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.0 * ncol, (0.45 * len(labels) + 1.3) * nrow),
                             squeeze=False, sharey=True)  # fmt: skip
    pos = np.arange(len(labels))[::-1] + 1.0  # first group on top
    for ax, m in zip(axes.flat, metrics, strict=False):
        data = [g.loc[g["group"] == lab, m].astype(float).dropna().to_numpy() for lab in labels]
        ax.boxplot(
            data,
            positions=pos,
            orientation="horizontal",
            showmeans=True,
            widths=0.6,
            showfliers=False,
        )  # every run is drawn as a dot
        for p, d in zip(pos, data, strict=True):
            ax.plot(d, np.full(len(d), p), ".", color="k", alpha=0.5, ms=4)
        ax.set_title(f"{m} ({better.get(m) or 'no direction'} is better)", fontsize=9)
        ax.tick_params(axis="x", labelsize=7)
        ax.grid(alpha=0.3)
    for row in axes:
        row[0].set_yticks(pos, labels, fontsize=8)
    for ax in list(axes.flat)[len(metrics) :]:
        ax.axis("off")
    fig.suptitle(f"{scenario}: across seeds (n = {g['seed'].nunique()} per box)")
    fig.tight_layout()
    return _save(fig, path)
