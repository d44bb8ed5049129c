"""The sweep report: ``DIR/report.md`` and ``DIR/report.html`` from the results table.

- **Summary** per scenario: every metric of ``metrics.json`` (per-AUV lists expanded, one row
  per AUV) as mean ± sd over seeds, one column per controller variant and condition (current,
  estimator).
- **Wins and losses** per metric between every pair of controller variants: for each scenario
  and condition the means over seeds are compared in the direction of :data:`BETTER`; per-AUV
  lists are first summarised per run by :data:`LIST_SUMMARY`. Equal means (within 1e-9
  relative) are ties; metrics without a direction are not counted.
- **Figures**: per scenario, box plots across seeds of :data:`BOX_METRICS`, and one figure of
  the representative runs (first seed, first condition) of every variant drawn from their
  time series: paths, range with the domain bands, fix age. The per-run figures of
  :mod:`mpcasv.sim.plots` are linked from each run folder. The HTML embeds its own figures
  (base64) and links the run figures; the Markdown links both.

Only ``status == "ok"`` rows enter the numbers; errors are listed.
"""

from __future__ import annotations

import base64
import html
import itertools
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from mpcasv.experiments.metrics import METRIC_INFO, METRIC_NAMES

#: which way is better, per metric: "higher", "lower", or None (defined once, in
#: :data:`mpcasv.experiments.metrics.METRIC_INFO`)
BETTER: dict[str, str | None] = {name: info.better for name, info in METRIC_INFO.items()}

#: how a per-AUV list metric is summarised per run for wins and losses
LIST_SUMMARY = {"fixes_auv": "sum", "reliable_fixes_auv": "sum",
                "reliable_fix_age_max_s_auv": "max", "auv_distance_m_auv": "sum"}  # fmt: skip

#: metrics shown as box plots across seeds
BOX_METRICS = ("min_range_m", "reliable_fix_age_max_s", "reliable_fix_age_p95_s",
               "nav_error_rms_m", "propeller_on_s", "energy_J")  # fmt: skip

CONDITION = ["current", "estimator"]
READ_LINE = 'pd.read_parquet("{out}/results.parquet")'


def metric_columns(df: pd.DataFrame) -> list[tuple[str, str, int | None]]:
    """(column, metric, AUV index or None) for every metric column present, in
    :data:`METRIC_NAMES` order."""
    out = []
    for m in METRIC_NAMES:
        if m in df:
            out.append((m, m, None))
        k = 0
        while f"{m}_auv{k}" in df:
            out.append((f"{m}_auv{k}", m, k))
            k += 1
    return out


def per_run_values(df: pd.DataFrame) -> pd.DataFrame:
    """One value per run and metric (per-AUV lists summarised by :data:`LIST_SUMMARY`)."""
    out = df[["scenario", *CONDITION, "variant", "seed"]].copy()
    for m in METRIC_NAMES:
        if m in df:
            out[m] = df[m].astype(float)
        elif m in LIST_SUMMARY:
            cols = [c for c, name, k in metric_columns(df) if name == m and k is not None]
            if cols:
                out[m] = getattr(df[cols].astype(float), LIST_SUMMARY[m])(axis=1, skipna=True)
    return out


def summary_table(df: pd.DataFrame) -> pd.DataFrame:
    """Long table: scenario, condition, variant, column, metric, auv, mean, sd, n (seeds)."""
    rows = []
    ok = df[df["status"] == "ok"]
    keys = ["scenario", *CONDITION, "variant"]
    for key, g in ok.groupby(keys, sort=False):
        for col, m, k in metric_columns(g):
            v = g[col].astype(float).dropna()
            if not len(v):  # e.g. a per-AUV column of another scenario
                continue
            rows.append(dict(zip(keys, key, strict=True)) | {
                "column": col, "metric": m, "auv": k, "mean": float(v.mean()),
                "sd": float(v.std(ddof=1)) if len(v) > 1 else math.nan, "n": len(v),
            })  # fmt: skip
    return pd.DataFrame(rows)


def win_loss(df: pd.DataFrame) -> pd.DataFrame:
    """Per metric and pair of variants (A, B): how often A's mean over seeds is better, worse
    or equal, over scenarios and conditions where both ran."""
    ok = df[df["status"] == "ok"] if len(df) else df
    if not len(ok):
        return pd.DataFrame()
    runs = per_run_values(ok)
    keys = ["scenario", *CONDITION]
    means = runs.groupby([*keys, "variant"], sort=False).mean(numeric_only=True)
    variants = list(dict.fromkeys(ok["variant"]))
    rows = []
    for a, b in itertools.combinations(variants, 2):
        for m in METRIC_NAMES:
            direction = BETTER[m]
            if direction is None or m not in means:
                continue
            w = l_ = t = 0
            for cond in ok[keys].drop_duplicates().itertuples(index=False):
                try:
                    va, vb = means.loc[(*cond, a), m], means.loc[(*cond, b), m]
                except KeyError:
                    continue
                if not (np.isfinite(va) and np.isfinite(vb)):
                    continue
                if abs(va - vb) <= 1e-9 * max(1.0, abs(va), abs(vb)):
                    t += 1
                elif (va > vb) == (direction == "higher"):
                    w += 1
                else:
                    l_ += 1
            rows.append({"A": a, "B": b, "metric": m, "better": direction, "A_wins": w,
                         "B_wins": l_, "ties": t})  # fmt: skip
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------- figures


def _groups(ok: pd.DataFrame) -> list[str]:
    """Column labels: variant, plus the condition where the suite has several."""
    multi = [c for c in CONDITION if ok[c].nunique() > 1]
    return [_group(r, multi) for _, r in ok.iterrows()]


def _group(r, conditions: list[str]) -> str:
    """``variant``, or ``variant (current off, estimator perfect)`` when conditions vary."""
    extra = ", ".join(f"{c} {r[c]}" for c in conditions)
    return f"{r['variant']} ({extra})" if extra else str(r["variant"])


def box_figure(ok: pd.DataFrame, scenario: str, path: Path) -> Path:
    g = ok[ok["scenario"] == scenario].copy()
    g["group"] = _groups(g)
    labels = list(dict.fromkeys(g["group"]))
    metrics = [m for m in BOX_METRICS if m in g]
    ncol = 3
    nrow = math.ceil(len(metrics) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.2 * nrow), squeeze=False)
    for ax, m in zip(axes.flat, metrics, strict=False):
        data = [g.loc[g["group"] == lab, m].astype(float).dropna().to_numpy() for lab in labels]
        ax.boxplot(data, tick_labels=[lab.replace(" (", "\n(") for lab in labels], showmeans=True)
        for i, d in enumerate(data):
            ax.plot(np.full(len(d), i + 1.0), d, ".", color="k", alpha=0.5, ms=4)
        ax.set_title(f"{m} ({BETTER[m] or 'no direction'} is better)", fontsize=9)
        ax.tick_params(axis="x", labelsize=7)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(metrics) :]:
        ax.axis("off")
    fig.suptitle(f"{scenario}: across seeds (n = {g['seed'].nunique()})")
    return _save(fig, path)


def representative_runs(ok: pd.DataFrame, scenario: str) -> pd.DataFrame:
    """Per variant, the run with the first condition and the lowest seed."""
    g = ok[ok["scenario"] == scenario]
    first = g.iloc[0]
    g = g[(g["current"] == first["current"]) & (g["estimator"] == first["estimator"])]
    return g.sort_values(["index"]).groupby("variant", sort=False).head(1)


def compare_figure(out: Path, reps: pd.DataFrame, scenario: str, path: Path) -> Path:
    """Paths, range (with r_inner / r_t / r_outer of the first variant) and fix age of the
    representative runs, one colour per variant."""
    series = [(r["variant"], pd.read_parquet(out / r["run_dir"] / "timeseries.parquet"))
              for _, r in reps.iterrows()]  # fmt: skip
    names = reps.iloc[0]["auv_names"].split(",")
    n = len(names)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fig = plt.figure(figsize=(15, max(2.6 * n + 0.8, 5.0)))
    gs = fig.add_gridspec(n, 3, width_ratios=[1.2, 1.4, 1.4])
    axp = fig.add_subplot(gs[:, 0])
    ts0 = series[0][1]
    for k in range(n):
        axp.plot(ts0[f"auv{k}_E"], ts0[f"auv{k}_N"], color="0.5", lw=0.8)
        axp.text(ts0[f"auv{k}_E"].iloc[0], ts0[f"auv{k}_N"].iloc[0], names[k], fontsize=7)
    for i, (v, ts) in enumerate(series):
        axp.plot(ts["E"], ts["N"], color=colours[i % len(colours)], lw=1.1, label=f"ASV {v}")
    axp.set_aspect("equal", adjustable="datalim")
    axp.set_xlabel("East (m)")
    axp.set_ylabel("North (m)")
    axp.legend(fontsize=7)
    axp.grid(alpha=0.3)
    axp.set_title("paths (AUVs grey)", fontsize=9)
    for k in range(n):
        axr, axf = fig.add_subplot(gs[k, 1]), fig.add_subplot(gs[k, 2])
        t0 = ts0["t"].to_numpy()
        if f"r_inner{k}" in ts0:
            axr.fill_between(t0, 0, ts0[f"r_inner{k}"], color="tab:red", alpha=0.12,
                             label="inside r_inner")  # fmt: skip
            axr.plot(t0, ts0[f"r_t{k}"], color="tab:green", lw=0.8, ls="--", label="r_t")
            axr.plot(t0, ts0[f"r_outer{k}"], color="tab:red", lw=0.8, ls=":", label="r_outer")
        for i, (v, ts) in enumerate(series):
            c = colours[i % len(colours)]
            axr.plot(ts["t"], ts[f"range{k}"], color=c, lw=1, label=v)
            axf.plot(ts["t"], ts[f"fix_age{k}"], color=c, lw=1, label=v)
        top = max(float(ts[f"range{k}"].max()) for _, ts in series) * 1.1
        axr.set_ylim(0, top)
        axr.set_ylabel(f"range {names[k]} (m)", fontsize=8)
        axf.set_ylabel(f"fix age {names[k]} (s)", fontsize=8)
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
    return _save(fig, path)


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- text


def _num(x: float) -> str:
    if not np.isfinite(x):
        return "nan" if np.isnan(x) else str(x)
    if x == 0:
        return "0"
    if abs(x) >= 1e5 or abs(x) < 1e-3:
        return f"{x:.3e}"
    return f"{x:.4g}" if abs(x) < 1000 else f"{x:.0f}"


def scenario_table(summ: pd.DataFrame, scenario: str, auv_names: list[str]) -> pd.DataFrame:
    """Rows: metrics (per AUV expanded); columns: variant (| condition); cells mean ± sd."""
    s = summ[summ["scenario"] == scenario].copy()
    multi = [c for c in CONDITION if s[c].nunique() > 1]
    s["group"] = [_group(r, multi) for _, r in s.iterrows()]
    s["cell"] = [_num(m) if not np.isfinite(sd) else f"{_num(m)} ± {_num(sd)}"
                 for m, sd in zip(s["mean"], s["sd"], strict=True)]  # fmt: skip
    s["row"] = [m if pd.isna(k) else f"{m} [{auv_names[int(k)]}]"
                for m, k in zip(s["metric"], s["auv"], strict=True)]  # fmt: skip
    rows = list(dict.fromkeys(s["row"]))
    table = s.pivot(index="row", columns="group", values="cell").reindex(rows)
    table = table[list(dict.fromkeys(s["group"]))]
    table.index.name = "metric"
    table.columns.name = None
    return table


def win_loss_table(wl: pd.DataFrame) -> pd.DataFrame:
    """Rows: metrics; one column per pair ``A vs B`` with "A wins / B wins / ties"."""
    if not len(wl):
        return pd.DataFrame()
    wl = wl.copy()
    wl["pair"] = wl["A"] + " vs " + wl["B"]
    wl["cell"] = [f"{a} / {b} / {t}" for a, b, t in
                  zip(wl["A_wins"], wl["B_wins"], wl["ties"], strict=True)]  # fmt: skip
    table = wl.pivot(index="metric", columns="pair", values="cell")
    table = table.reindex([m for m in METRIC_NAMES if m in table.index])
    better = wl.drop_duplicates("metric").set_index("metric")["better"]
    table.insert(0, "better", better.reindex(table.index))
    total = wl.groupby("pair", sort=False)[["A_wins", "B_wins", "ties"]].sum()
    total = total.reindex(table.columns[1:])
    table.loc["total"] = ["", *(f"{r.A_wins} / {r.B_wins} / {r.ties}" for r in total.itertuples())]
    table.columns.name = None
    return table


def _md_table(df: pd.DataFrame) -> str:
    cols = [df.index.name or "", *map(str, df.columns)]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for idx, row in df.iterrows():
        cells = [str(idx), *("" if pd.isna(v) else str(v) for v in row)]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines)


def _img_b64(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode()


CSS = """body{font-family:sans-serif;max-width:1400px;margin:auto;padding:1em}
table{border-collapse:collapse;font-size:12px;margin:0.5em 0}
td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}th{background:#eee}
td:first-child,th:first-child{text-align:left}img{max-width:100%}
code{background:#f4f4f4;padding:1px 4px}"""


def write_report(out: Path, exp, results: pd.DataFrame, stats=None) -> tuple[Path, Path]:
    """Write ``report.md``, ``report.html`` and ``figures/`` into ``out``."""
    out = Path(out)
    figdir = out / "figures"
    figdir.mkdir(exist_ok=True)
    ok = results[results["status"] == "ok"] if len(results) else results
    errors = results[results["status"] != "ok"] if len(results) else results
    summ = summary_table(results) if len(ok) else pd.DataFrame()
    wl = win_loss(results)
    suite = exp.suite
    md, h = [], []  # markdown and HTML bodies

    def both(text_md: str, text_html: str) -> None:
        md.append(text_md)
        h.append(text_html)

    title = f"Comparison: suite {suite.name}"
    both(f"# {title}\n", f"<h1>{html.escape(title)}</h1>")
    facts = [
        f"{suite.description}".strip(),
        f"Jobs: {len(exp.jobs)} in the suite, {len(results)} with results "
        f"({len(ok)} ok, {len(errors)} errors); seeds {list(suite.seeds)}; means ± sd over seeds.",
        f"Whole results table: `{READ_LINE.format(out=out)}` (one row per job).",
    ]
    if len(results) < len(exp.jobs):
        facts.append(f"**Incomplete**: {len(exp.jobs) - len(results)} jobs have not run "
                     "(rerun the same command to resume).")  # fmt: skip
    facts += [f"Skipped (optional controller not available): {s}" for s in exp.skipped]
    for f in filter(None, facts):
        both(f"- {f}", f"<p>{html.escape(f).replace('`', '')}</p>")
    md.append("")
    if len(errors):
        both("\n## Errors\n", "<h2>Errors</h2>")
        for _, r in errors.iterrows():
            last = (r["error"] or "").strip().splitlines()[-1:] or [""]
            t = f"{r['scenario']} / {r['variant']} / seed {r['seed']} / current {r['current']}"
            both(f"- {t}: `{last[0]}`", f"<p>{html.escape(t)}: <code>{html.escape(last[0])}"
                 "</code></p>")  # fmt: skip
    if len(wl):
        t = win_loss_table(wl)
        note = ("Per metric, over scenarios x conditions: A wins / B wins / ties of the means "
                "over seeds ('better': the direction that counts as better; per-AUV metrics "
                "summed (counts) or maxed (fix ages) per run).")  # fmt: skip
        both(f"\n## Wins and losses\n\n{note}\n\n{_md_table(t)}\n",
             f"<h2>Wins and losses</h2><p>{html.escape(note)}</p>{t.to_html()}")  # fmt: skip
    for scenario in dict.fromkeys(ok["scenario"]) if len(ok) else []:
        g = ok[ok["scenario"] == scenario]
        names = g.iloc[0]["auv_names"].split(",")
        both(f"\n## {scenario}\n", f"<h2>{html.escape(scenario)}</h2>")
        t = scenario_table(summ, scenario, names)
        both(_md_table(t) + "\n", t.to_html())
        box = box_figure(ok, scenario, figdir / f"box-{scenario}.png")
        reps = representative_runs(ok, scenario)
        cmp_ = compare_figure(out, reps, scenario, figdir / f"compare-{scenario}.png")
        for fig in (cmp_, box):
            rel = fig.relative_to(out)
            both(f"![{fig.stem}]({rel})\n", f'<img src="{_img_b64(fig)}" alt="{fig.stem}">')
        links_md, links_html = [], []
        for _, r in reps.iterrows():
            pngs = sorted((out / r["run_dir"]).glob("*.png"))
            if pngs:
                links_md.append(f"{r['variant']}: " + ", ".join(
                    f"[{p.stem}]({p.relative_to(out)})" for p in pngs))  # fmt: skip
                links_html.append(html.escape(r["variant"]) + ": " + ", ".join(
                    f'<a href="{p.relative_to(out)}">{p.stem}</a>' for p in pngs))  # fmt: skip
        if links_md:
            both(
                "Run figures (representative runs): " + "; ".join(links_md) + "\n",
                "<p>Run figures (representative runs): " + "; ".join(links_html) + "</p>",
            )
    md_path, html_path = out / "report.md", out / "report.html"
    md_path.write_text("\n".join(md) + "\n")
    html_path.write_text(f"<!doctype html><html><head><meta charset='utf-8'><title>"
                         f"{html.escape(title)}</title><style>{CSS}</style></head><body>"
                         + "\n".join(h) + "</body></html>\n")  # fmt: skip
    return md_path, html_path
