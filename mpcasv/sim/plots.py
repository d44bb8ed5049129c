"""Figures of one run, like the papers': North-East paths, range with the donut bands,
fix ages. All functions take a :class:`~mpcasv.sim.simulator.RunResult` and a file path."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

AUV_COLOURS = ("tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink")
#: standby (propeller off) in every run figure: none of the AUVs', the ASV's or the plans'
STANDBY_COLOUR = "grey"

#: a series with fewer samples than this is drawn with markers (a one-sample line, e.g. of a
#: one-second run, drew nothing) and its bands as bars at the samples (a fill has no width)
FEW = 3


def _marks(n: int) -> dict:
    """Line keywords for a series of ``n`` samples: markers when there are few."""
    return {"marker": "o", "ms": 4} if n < FEW else {}


def _band(ax, t, lo, hi, where=None, step=None, **kw) -> None:
    """``fill_between(t, lo, hi)``; with fewer than :data:`FEW` samples, a bar (thick
    vertical line) per sample, which a zero-width fill is not."""
    if len(t) >= FEW:
        ax.fill_between(t, lo, hi, where=where, step=step, **kw)
        return
    t = np.asarray(t, float)
    lo, hi = np.broadcast_to(lo, t.shape), np.broadcast_to(hi, t.shape)
    keep = np.ones(t.shape, bool) if where is None else np.asarray(where, bool)
    if keep.any():
        ax.vlines(t[keep], np.asarray(lo)[keep], np.asarray(hi)[keep], lw=8, **kw)


def _time_axis(ax, t) -> None:
    """With few samples, the time axis from the run's start (0 s) past the last sample
    (matplotlib's own limits around one sample at 1 s were 0.96-1.04 s)."""
    if len(t) and len(t) < FEW:
        t0, t1 = min(0.0, float(np.min(t))), float(np.max(t))
        pad = 0.05 * max(t1 - t0, 1e-9)
        ax.set_xlim(t0 - pad, t1 + pad)


def _n_auv(ts) -> int:
    return sum(1 for c in ts.columns if c.startswith("auv") and c.endswith("_N"))


def run_title(result, what: str) -> str:
    """The title of figure ``what`` (e.g. ``"paths"``) of one run: its scenario, controller
    and seed, which tell apart the figures of a suite's many run folders."""
    return f"{result.scenario.name}: {what} ({result.controller}, seed {result.seed})"


def plot_paths(result, path: str | Path) -> Path:
    """:func:`paths_figure` saved to ``path``."""
    return _save(paths_figure(result), path)


def paths_figure(result):
    """North-East paths of the ASV (standby positions marked) and the AUVs, plus any MPC
    plans recorded during the run (dashed). Returns the figure."""
    ts = result.timeseries
    mk = _marks(len(ts))
    fig, ax = plt.subplots(figsize=(7, 7))
    ax.plot(ts["E"], ts["N"], color="tab:blue", lw=1.2, label="ASV", **mk)
    # standby stretches as a broad grey band under the path (before: 2-pt dots in the
    # path's own colour, which a new user could not see; green, first tried, is AUV 2's),
    # each sample a marker too, so that a standby while drifting a metre still shows
    sb = (ts["mode"] == "standby").to_numpy()
    E_sb, N_sb = np.where(sb, ts["E"], np.nan), np.where(sb, ts["N"], np.nan)
    ax.plot(E_sb, N_sb, "-o", color=STANDBY_COLOUR, lw=6, ms=5, alpha=0.45, zorder=1,
            solid_capstyle="round", label="ASV in standby (propeller off)")  # fmt: skip
    ax.plot(ts["E"].iloc[0], ts["N"].iloc[0], "o", color="tab:blue")
    for k in range(_n_auv(ts)):
        c = AUV_COLOURS[k % len(AUV_COLOURS)]
        name = result.scenario.auv[k].name
        ax.plot(ts[f"auv{k}_E"], ts[f"auv{k}_N"], color=c, lw=1, label=f"AUV {name}", **mk)
        ax.plot(ts[f"auv{k}_E"].iloc[0], ts[f"auv{k}_N"].iloc[0], "s", color=c)
    for i, (_, plan) in enumerate(result.plans):
        ax.plot(plan.E, plan.N, "--", color="tab:red", lw=0.8,
                label="MPC plan" if i == 0 else None)  # fmt: skip
    ax.set_xlabel("East (m)")
    ax.set_ylabel("North (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(run_title(result, "paths"))
    return fig


def plot_ranges(result, path: str | Path) -> Path:
    """:func:`range_figure` saved to ``path``."""
    return _save(range_figure(result), path, tight=False)


def inner_label(n_auv: int) -> str:
    """The collision domain's radius as the range figures name it: Paper 2's ``r_avoid``
    with several AUVs, Paper 1's ``r_inner`` with one."""
    return "r_avoid" if n_auv > 1 else "r_inner"


def outer_in_reach(r_outer, top: float) -> bool:
    """Whether a range axis reaching ``top`` (m) draws ``r_outer`` (m, array): not Paper 2's
    (3500 m: no outer boundary)."""
    return float(np.min(r_outer)) < 2 * top


def range_figure(result):
    """ASV-AUV horizontal range per AUV with r_inner, r_t +- eps and r_outer when known;
    the believed (estimated) range dashed; standby shaded. Returns the figure."""
    ts = result.timeseries
    mk = _marks(len(ts))
    n = _n_auv(ts)
    fig, axes = plt.subplots(n, 1, figsize=(9, 2.6 * n + 0.6), sharex=True, squeeze=False)
    t = ts["t"].to_numpy()
    sb = (ts["mode"] == "standby").to_numpy()
    eps = getattr(getattr(result, "domain", None), "eps_plus", None)
    for k, ax in enumerate(axes[:, 0]):
        top = 1.15 * float(np.nanmax([ts[f"range{k}"].max(), ts[f"est_range{k}"].max()]))
        if f"r_inner{k}" in ts:
            top = max(top, 1.15 * float(ts[f"r_t{k}"].max() + (eps or 0)))
            _band(ax, t, 0, ts[f"r_inner{k}"].to_numpy(), color="tab:red", alpha=0.15,
                  label=f"inside {inner_label(n)}")  # fmt: skip
            ax.plot(t, ts[f"r_t{k}"], color="tab:green", lw=1, label="r_t", **mk)
            if eps is not None:
                r_t = ts[f"r_t{k}"].to_numpy()
                _band(ax, t, r_t - eps, r_t + eps, color="tab:green", alpha=0.15,
                      label="target domain")  # fmt: skip
            if outer_in_reach(ts[f"r_outer{k}"], top):
                ax.plot(t, ts[f"r_outer{k}"], color="tab:red", lw=1, ls=":", label="r_outer",
                        **mk)  # fmt: skip
                top = max(top, 1.1 * float(ts[f"r_outer{k}"].max()))
        ax.plot(t, ts[f"range{k}"], color="tab:blue", lw=1.2, label="range (true)", **mk)
        ax.plot(t, ts[f"est_range{k}"], color="k", lw=0.8, ls="--", alpha=0.7,
                label="range (believed)", **(mk and {"marker": "x", "ms": 6}))  # fmt: skip
        _band(ax, t, 0, top, where=sb, color=STANDBY_COLOUR, alpha=0.12, step="mid",
              label="standby")  # fmt: skip
        _time_axis(ax, t)
        ax.set_ylim(0, top)
        ax.set_ylabel(f"range to {result.scenario.auv[k].name} (m)")
        ax.grid(alpha=0.3)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(run_title(result, "ASV-AUV range"))
    fig.tight_layout(rect=(0, 0.06 if n > 1 else 0.1, 1, 1))
    return fig


def plot_fix_age(result, path: str | Path) -> Path:
    """:func:`fix_age_figure` saved to ``path``."""
    return _save(fix_age_figure(result), path)


def fix_age_figure(result):
    """Per AUV: Paper 2's reliable-fix age tau_k (eq. 9, solid; reliable fixes ticked) and
    the age of the last fix that arrived at all (thin), from the simulator's ground truth.
    Returns the figure (the caller saves and closes it)."""
    ts = result.timeseries
    mk = _marks(len(ts))
    fig, ax = plt.subplots(figsize=(11, 3.4))
    for k in range(_n_auv(ts)):
        c = AUV_COLOURS[k % len(AUV_COLOURS)]
        name = result.scenario.auv[k].name
        if f"rfix_age{k}" in ts and result.domain is not None:
            ax.plot(ts["t"], ts[f"rfix_age{k}"], color=c, lw=1.3,
                    label=f"{name}: reliable-fix age tau", **mk)  # fmt: skip
        ax.plot(ts["t"], ts[f"fix_age{k}"], color=c, lw=0.7, alpha=0.6,
                label=f"{name}: fix age (any fix)", **(mk and {"marker": "x", "ms": 6}))
        rel = result.reliable_fix_times[k]
        ax.plot(rel, np.zeros(len(rel)), "|", color=c, ms=8)
    _time_axis(ax, ts["t"].to_numpy())
    if len(ts) < FEW:  # an age is >= 0: from 0, not matplotlib's +-4 % around one value
        ax.set_ylim(bottom=0)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("age (s)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title(run_title(result, "fix ages per AUV") + "; ticks: reliable fixes (Paper 2 eq. 9)")
    return fig


def _save(fig, path, tight: bool = True) -> Path:
    path = Path(path)
    if tight:
        fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_run(result, out_dir: str | Path) -> list[Path]:
    """All standard figures of a run into ``out_dir``."""
    out = Path(out_dir)
    return [
        plot_paths(result, out / "paths.png"),
        plot_ranges(result, out / "range.png"),
        plot_fix_age(result, out / "fix_age.png"),
    ]
