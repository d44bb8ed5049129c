"""Figures of the sweep report drawn from the runs' time series (the other figures, drawn
from the results table, are in :mod:`mpcasv.experiments.report_figures`).

- :func:`ecdf_figure`: per case, ECDFs of the acoustic fix age and of the AUV navigation
  error per controller variant, pooled over runs, AUVs and time (per-run metrics stand in
  where no run has a time series);
- :func:`compare_figure`: per scenario, the representative runs (:func:`representative_runs`)
  drawn from their time series: paths, range with the domain's radii, reliable-fix age (its upper
  envelope in long runs: :func:`fix_age_trace`);
- :func:`run_path`, :func:`has_timeseries`: where a run's folder is, and whether its time
  series is there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from mpcasv.experiments.report_figures import _save, num
from mpcasv.experiments.stats import COMPARE
from mpcasv.sim.plots import inner_label, outer_in_reach
from mpcasv.wording import count, noun

# ----------------------------------------------------------------------------- ECDF


@dataclass(frozen=True)
class EcdfSeries:
    """A time-series quantity drawn as an ECDF: column ``f"{prefix}{k}"`` per AUV k; the
    per-run metric ``run_metric`` stands in (ECDF over runs, said so) where no run folder
    of the case has a time series."""

    prefix: str
    title: str
    unit: str
    run_metric: str


ECDF_SERIES = (
    EcdfSeries("rfix_age", "reliable-fix age τ", "s", "reliable_fix_age_p95_s"),  # Paper 2 eq. 9
    EcdfSeries("fix_age", "acoustic fix age", "s", "fix_age_p95_s"),
    EcdfSeries("nav_err", "AUV navigation error", "m", "nav_error_p95_m"),
)


def run_path(out: Path, run_dir: str) -> Path:
    """A run's folder: ``run_dir`` of the results table, relative to ``out`` or absolute."""
    p = Path(str(run_dir))
    return p if p.is_absolute() else out / p


def has_timeseries(out: Path, row) -> bool:
    """Whether the run of results row ``row`` has its ``timeseries.parquet`` here."""
    run_dir = row.get("run_dir")
    return isinstance(run_dir, str) and (run_path(out, run_dir) / "timeseries.parquet").is_file()


def ecdf_panels(out: Path, ok: pd.DataFrame, scenario: str,
                series: Sequence[EcdfSeries] = ECDF_SERIES) -> tuple[list, list[str]]:  # fmt: skip
    """The data of :func:`ecdf_figure`: per series with data, (title, y label, series,
    {variant: sorted values pooled over the runs, AUVs and time steps}), and the notes."""
    g = ok[ok["scenario"] == scenario]
    names = list(dict.fromkeys(g[COMPARE]))
    n_auv = len(g.iloc[0]["auv_names"].split(","))
    found: dict[str, list[pd.DataFrame]] = {v: [] for v in names}
    wanted = [f"{s.prefix}{k}" for s in series for k in range(n_auv)]
    n_missing = 0
    for _, r in g.iterrows():
        if not has_timeseries(out, r):
            n_missing += 1
            continue
        f = run_path(out, r["run_dir"]) / "timeseries.parquet"
        have = set(pq.read_schema(f).names)
        found[r[COMPARE]].append(pd.read_parquet(f, columns=[c for c in wanted if c in have]))
    notes = ([f"{n_missing} of {count(len(g), 'run')} {noun(n_missing, 'has', 'have')} no time "
              "series here"] if n_missing else [])  # fmt: skip
    panels = []  # (title, ylabel, series, {variant: sorted values}) of the series with data
    for s in series:
        cols = [f"{s.prefix}{k}" for k in range(n_auv)]
        from_ts = any(c in ts for v in names for ts in found[v] for c in cols)
        if not from_ts and any(found[v] for v in names):
            notes.append(f"{s.title}: the time series have no column {s.prefix}<k>")
        data = {}
        for v in names:
            if from_ts:
                vals = [ts[c].to_numpy(float) for ts in found[v] for c in cols if c in ts]
                x = np.concatenate(vals) if vals else np.empty(0)
            elif s.run_metric in g:
                x = g.loc[g[COMPARE] == v, s.run_metric].to_numpy(float)
            else:
                x = np.empty(0)
            data[v] = np.sort(x[np.isfinite(x)])
        if from_ts:
            panels.append((f"{s.title} ({s.unit}): all runs, AUVs and time steps",
                           "fraction of time ≤ x", s, data))  # fmt: skip
        elif s.run_metric in g:
            notes.append(f"{s.title}: ECDF over runs of {s.run_metric} (no time series)")
            panels.append((f"per-run {s.run_metric} ({s.unit}): no time series",
                           "fraction of runs ≤ x", s, data))  # fmt: skip
        else:
            notes.append(f"{s.title}: neither time series nor {s.run_metric} available")
    return [p for p in panels if any(len(x) for x in p[3].values())], notes


def ecdf_figure(
    out: Path, ok: pd.DataFrame, scenario: str, path: Path,
    series: Sequence[EcdfSeries] = ECDF_SERIES,
) -> tuple[Path | None, list[str]]:  # fmt: skip
    """ECDFs per variant of each of ``series`` in ``scenario``, pooled over its ok runs (every
    condition and seed), AUVs and logged time steps (:func:`ecdf_panels`). Returns the figure
    (None if no series has data) and notes on what was missing (runs without a time series,
    quantities drawn from per-run metrics)."""
    panels, notes = ecdf_panels(out, ok, scenario, series)
    if not panels:
        return None, notes
    fig, axes = plt.subplots(1, len(panels), figsize=(6.0 * len(panels), 4.2), squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (title, ylabel, s, data) in zip(axes.flat, panels, strict=True):
        for i, (v, x) in enumerate(data.items()):
            if not len(x):
                continue
            idx = np.unique(np.linspace(0, len(x) - 1, min(len(x), 2000)).astype(int))
            ax.step(x[idx], (idx + 1) / len(x), where="post", color=colours[i % len(colours)],
                    lw=1.3, label=f"{v} (p95 {num(float(np.percentile(x, 95)))})")  # fmt: skip
        ax.set_title(title, fontsize=9)
        ax.set_xlabel(f"{s.title} ({s.unit})", fontsize=8)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    fig.suptitle(f"{scenario}: ECDF per controller variant (further left = smaller "
                 "values = better)", fontsize=10)  # fmt: skip
    fig.tight_layout()
    return _save(fig, path), notes


# ----------------------------------------------------------------------------- representative runs


def representative_runs(ok: pd.DataFrame, scenario: str) -> pd.DataFrame:
    """Per variant, the run with the first condition and the lowest seed."""
    g = ok[ok["scenario"] == scenario]
    first = g.iloc[0]
    g = g[(g["current"] == first["current"]) & (g["estimator"] == first["estimator"])]
    return g.sort_values(["index"]).groupby(COMPARE, sort=False).head(1)


#: above this many fix-age resets in a panel, the fix age is drawn as its upper envelope
MAX_SAWTEETH = 40
ENVELOPE_BINS = 60


def needs_envelope(t: np.ndarray, age: np.ndarray) -> bool:
    """Whether a fix-age series has more than :data:`MAX_SAWTEETH` resets (an unreadable
    solid block when drawn as it is) and enough samples for the envelope."""
    return int(np.sum(np.diff(age) < 0)) > MAX_SAWTEETH and len(t) >= 2 * ENVELOPE_BINS


def fix_age_trace(t: np.ndarray, age: np.ndarray, envelope: bool | None = None
                  ) -> tuple[np.ndarray, np.ndarray, str]:  # fmt: skip
    """The fix age to draw: the series itself, or its maximum per window of (duration /
    :data:`ENVELOPE_BINS`) when ``envelope`` (default: :func:`needs_envelope`). A panel
    with several series passes one ``envelope`` for all, so that they are drawn alike.
    Returns t, value and a label suffix."""
    if envelope is None:
        envelope = needs_envelope(t, age)
    if not envelope or len(t) < 2 * ENVELOPE_BINS:
        return t, age, ""
    edges = np.linspace(t[0], t[-1], ENVELOPE_BINS + 1)
    b = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, ENVELOPE_BINS - 1)
    peak = pd.Series(age).groupby(b).max()
    w = edges[1] - edges[0]
    return edges[peak.index.to_numpy()], peak.to_numpy(), f", max per {w:.2g} s window"


def compare_figure(out: Path, reps: pd.DataFrame, scenario: str, path: Path) -> Path:
    """Paths, range (with r_inner / r_t / r_outer of the first variant) and the reliable-fix
    age tau_k (column ``rfix_age<k>``; the fix age ``fix_age<k>`` in runs without it) of the
    representative runs, one colour per variant (its envelope in long runs)."""
    series = [(r[COMPARE], pd.read_parquet(run_path(out, r["run_dir"]) / "timeseries.parquet"))
              for _, r in reps.iterrows()]  # fmt: skip
    names = reps.iloc[0]["auv_names"].split(",")
    n = len(names)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fig = plt.figure(figsize=(15, max(2.6 * n + 0.8, 5.0)))
    gs = fig.add_gridspec(n, 3, width_ratios=[1.2, 1.4, 1.4])
    axp = fig.add_subplot(gs[:, 0])
    ts0 = series[0][1]
    for k in range(n):  # a start dot and an end square: an AUV that stays put is drawn too
        E, N = ts0[f"auv{k}_E"], ts0[f"auv{k}_N"]
        axp.plot(E, N, color="0.5", lw=0.8)
        axp.plot(E.iloc[0], N.iloc[0], "o", color="0.5", ms=3)
        axp.plot(E.iloc[-1], N.iloc[-1], "s", color="0.5", ms=4)
        axp.annotate(names[k], (E.iloc[0], N.iloc[0]), xytext=(3, 3), textcoords="offset points",
                     fontsize=7)  # fmt: skip
    for i, (v, ts) in enumerate(series):
        c = colours[i % len(colours)]
        axp.plot(ts["E"], ts["N"], color=c, lw=1.1, label=f"ASV {v}")
        axp.plot(ts["E"].iloc[0], ts["N"].iloc[0], "o", color=c, ms=3)
    axp.margins(0.08)  # room for the names beside the dots
    axp.set_aspect("equal", adjustable="datalim")
    axp.set_xlabel("East (m)")
    axp.set_ylabel("North (m)")
    axp.legend(fontsize=7)
    axp.grid(alpha=0.3)
    axp.set_title("paths (AUVs grey; dots: starts, squares: AUVs' ends)", fontsize=9)
    # Paper 2's reliable-fix age tau_k (eq. 9) where the runs recorded it, else the fix age
    rel = all(f"rfix_age{k}" in ts for _, ts in series for k in range(n))
    age, age_name = ("rfix_age", "τ reliable-fix age") if rel else ("fix_age", "fix age")
    for k in range(n):
        axr, axf = fig.add_subplot(gs[k, 1]), fig.add_subplot(gs[k, 2])
        t0 = ts0["t"].to_numpy()
        top = max(float(ts[f"range{k}"].max()) for _, ts in series) * 1.1
        if f"r_inner{k}" in ts0:  # the names and the outer rule of the run's range figure
            axr.fill_between(t0, 0, ts0[f"r_inner{k}"], color="tab:red", alpha=0.12,
                             label=f"inside {inner_label(n)}")  # fmt: skip
            axr.plot(t0, ts0[f"r_t{k}"], color="tab:green", lw=0.8, ls="--", label="r_t")
            top = max(top, 1.1 * float(ts0[f"r_t{k}"].max()))
            if outer_in_reach(ts0[f"r_outer{k}"], top):
                axr.plot(t0, ts0[f"r_outer{k}"], color="tab:red", lw=0.8, ls=":",
                         label="r_outer")  # fmt: skip
                top = max(top, 1.1 * float(ts0[f"r_outer{k}"].max()))
        # one representation for every variant of the panel (and its label says which)
        envelope = any(needs_envelope(ts["t"].to_numpy(float), ts[f"{age}{k}"].to_numpy(float))
                       for _, ts in series)  # fmt: skip
        suffix = ""
        for i, (v, ts) in enumerate(series):
            c = colours[i % len(colours)]
            axr.plot(ts["t"], ts[f"range{k}"], color=c, lw=1, label=v)
            tf, af, s_ = fix_age_trace(ts["t"].to_numpy(float),
                                       ts[f"{age}{k}"].to_numpy(float), envelope)  # fmt: skip
            suffix = suffix or s_
            axf.plot(
                tf, af, color=c, lw=1, label=v, drawstyle="steps-post" if s_ else "default"
            )
        axr.set_ylim(0, top)
        axr.set_ylabel(f"range {names[k]} (m)", fontsize=8)
        axf.set_ylabel(f"{age_name} {names[k]} (s{suffix})", fontsize=8)
        for ax in (axr, axf):
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
        if k == 0:
            axr.legend(fontsize=6, ncol=2)
            axf.legend(fontsize=6)
        if k == n - 1:
            axr.set_xlabel("time (s)")
            axf.set_xlabel("time (s)")
    r0 = reps.iloc[0]
    fig.suptitle(f"{scenario}: representative runs (seed {r0['seed']}, current {r0['current']}, "
                 f"estimator {r0['estimator']}); domain bands of {series[0][0]}")  # fmt: skip
    fig.tight_layout()
    return _save(fig, path)
