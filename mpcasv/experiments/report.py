"""The sweep report: ``DIR/report.md`` and ``DIR/report.html`` from the results table.

- **Headline** (first): every controller variant against the reference variant (the first of
  the suite) on the same (scenario, realisation) pairs, per headline metric
  (:data:`mpcasv.experiments.stats.HEADLINE`: safety, liveness, AUV navigation, effort) and
  case: the Hodges-Lehmann estimate of the paired difference with its 95 % distribution-free
  CI, the Wilcoxon signed-rank p-value of the same estimand and which variant is
  significantly better (:mod:`mpcasv.experiments.stats`), and a
  forest plot per pair. Metrics missing from the table are named, never filled in.
- **Significant wins and losses**: per metric with a direction (:data:`BETTER` and the
  headline's), in how many cases each variant is significantly better on the paired test
  (per-AUV lists first summarised per run by :data:`LIST_SUMMARY`).
- **Summary** per scenario: every metric of ``metrics.json`` (per-AUV lists expanded, one row
  per AUV) as mean ± sd over seeds, one column per controller variant and condition (current,
  estimator); ECDFs of fix age and navigation error per variant; box plots across seeds of
  :data:`BOX_METRICS`; the representative runs (first seed, first condition) drawn from their
  time series; links to the per-run figures of :mod:`mpcasv.sim.plots`. The HTML embeds its
  own figures (base64) and links the run figures; the Markdown links both.

Only ``status == "ok"`` rows enter the numbers; errors are listed.
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

import pandas as pd

from mpcasv.experiments import acceptance
from mpcasv.experiments import report_figures as rf
from mpcasv.experiments import report_series as rs
from mpcasv.experiments import stats as paired
from mpcasv.experiments.metric_info import WALL_CLOCK
from mpcasv.experiments.metrics import METRIC_INFO
from mpcasv.experiments.report_tables import (  # noqa: F401 (re-exported)
    CEILING_METRICS,
    LIST_SUMMARY,
    NEVER_COLUMN,
    cases_without_fixes,
    headline_table,
    metric_columns,
    never_fixed_table,
    scenario_table,
    summary_table,
    win_loss_table,
    with_list_summaries,
)
from mpcasv.wording import count, noun

#: which way is better, per metric: "higher", "lower", or None (defined once, in
#: :data:`mpcasv.experiments.metrics.METRIC_INFO`)
BETTER: dict[str, str | None] = {name: info.better for name, info in METRIC_INFO.items()}

#: metrics shown as box plots across seeds
BOX_METRICS = ("min_range_m", "reliable_fix_age_max_s", "reliable_fix_age_p95_s",
               "nav_error_rms_m", "propeller_on_s", "energy_J")  # fmt: skip

PER_CASE = ("Per case, the same rule on each case's pairs alone (the relative change of the "
            f"sums [95 % CI] (pairs, of which the other variant did worse in): verdict; fewer "
            f"than {paired.MIN_PAIRS} pairs have no interval). A pooled verdict can sit between "
            "cases that go opposite ways.")
READ_LINE = 'pd.read_parquet("{out}/results.parquet")'


def directions() -> dict[str, str | None]:
    """Which way is better for every metric the report knows (:data:`BETTER` and the
    headline's)."""
    return {**BETTER, **{h.name: h.better for h in paired.HEADLINE}}


# ----------------------------------------------------------------------------- text


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


def run_link(path: Path, out: Path) -> str:
    """Link to a run file from the report in ``out``: relative when the run folder is under
    ``out`` (move ``out`` as a whole), else its absolute ``file://`` URI (run folders put
    elsewhere with ``--runs-dir``)."""
    try:
        return path.relative_to(out).as_posix()
    except ValueError:
        return path.resolve().as_uri()


def _heading_id(text: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in text.lower())


def write_report(out: Path, exp, results: pd.DataFrame, stats=None) -> tuple[Path, Path]:
    """Write ``report.md``, ``report.html`` and ``figures/`` into ``out``.

    ``exp``: the expanded suite (:func:`mpcasv.experiments.suite.expand`); ``results``: the
    results table; ``stats``: the sweep's run statistics (unused here)."""
    out = Path(out)
    figdir = out / "figures"
    figdir.mkdir(exist_ok=True)
    ok = results[results["status"] == "ok"] if len(results) else results
    errors = results[results["status"] != "ok"] if len(results) else results
    summ = summary_table(results) if len(ok) else pd.DataFrame()
    suite = exp.suite
    better = directions()
    headline = [h.name for h in paired.HEADLINE]
    md, h = [], []  # markdown and HTML bodies

    def both(text_md: str, text_html: str) -> None:
        md.append(text_md)
        h.append(text_html)

    def figure(fig: Path) -> None:
        rel = fig.relative_to(out)
        both(f"![{fig.stem}]({rel})\n", f'<img src="{_img_b64(fig)}" alt="{fig.stem}">')

    def bullet(text: str) -> None:
        page = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", html.escape(text).replace("`", ""))
        page = re.sub(r"\*(.+?)\*", r"<i>\1</i>", page)
        both(f"- {text}", f"<p>{page}</p>")

    title = f"Comparison: suite {suite.name}"
    both(f"# {title}\n", f"<h1>{html.escape(title)}</h1>")
    if len(results) < len(exp.jobs):
        left = len(exp.jobs) - len(results)
        bullet(f"**Incomplete**: {count(left, 'job')} {noun(left, 'has', 'have')} not run "
               "(rerun the same command to resume).")  # fmt: skip
    if len(errors):
        bullet(f"**{count(len(errors), 'error')}** (listed below): their pairs are left out.")
    missing = paired.missing_metrics(results, headline) if len(ok) else []
    if missing:
        bullet("**Missing headline metrics** (no column in this results table, e.g. written by "
               f"an older version; left out, not replaced): {', '.join(missing)}.")  # fmt: skip
    md.append("")
    names = paired.variants(results) if len(ok) else []
    runs = with_list_summaries(results) if len(ok) else results
    table, why = pd.DataFrame(), paired.comparison_problem(results)
    if why is None:
        # lists of a scalar once; not the wall-clock metrics (machine and load: never
        # compared; the wins table gave the hybrids 8 "better" on controller step time)
        rest = [
            m
            for m in better
            if better[m] and m not in headline and m not in WALL_CLOCK
            and not (m.endswith("_auv") and m[:-4] in better)
        ]  # fmt: skip
        table = paired.paired_table(runs, [*headline, *rest], better)
        why = "no metric with a direction in this results table"  # if the table is empty
    fronts = getattr(exp, "fronts", None)  # entries naming a tuned front (tune_match)
    if fronts:
        from mpcasv.experiments.tune_match import MATCHED_NOTE, matched_table

        mt = matched_table(fronts, results)
        both(f"\n## Matched operating points\n\n{MATCHED_NOTE}\n\n{_md_table(mt)}\n",
             f"<h2>Matched operating points</h2><p>{html.escape(MATCHED_NOTE)}</p>"
             f"{mt.to_html()}")  # fmt: skip
    both("\n## Headline: paired differences\n", "<h2>Headline: paired differences</h2>")
    acc = getattr(suite, "acceptance", None)  # the suite's targets (acceptance.py), if any
    if not len(table):
        bullet(f"**No paired comparison**: {why}.")
        if acc is not None:  # the reason compare --no-report gives (acceptance.why_not_judged)
            not_judged = acceptance.why_not_judged(results) or f"no paired comparison ({why})"
            bullet(f"**The suite's acceptance targets are not judged**: {not_judged}.")
    else:
        key = paired.pair_key(results)
        ref = names[0]
        lines = [
            f"Reference: **{ref}** (the suite's first variant); "
            + (
                f"each of {', '.join(names[1:])} is compared with it."
                if len(names) > 2
                else f"compared with {names[1]}."
            ),
            f"Pairs: runs equal on ({', '.join(key)}), pooled over the conditions of a case; "
            f"Δ = other − reference per pair; the pairs of a case on the same realisation "
            f"(seeds whose draws repeat, conditions such as estimators on one world) are one "
            f"world and averaged into one pair (the unit is the world, not the run). "
            f"The Hodges-Lehmann estimate of Δ (the median of the Walsh averages, the "
            f"pseudo-median the Wilcoxon signed-rank test is about) with its "
            f"{paired.CONFIDENCE:.0%} distribution-free CI (the Walsh averages' order "
            f"statistics that invert the test; Hollander, Wolfe & Chicken 2014, §3.3; no "
            f"random draw) and the two-sided Wilcoxon signed-rank p (scipy.stats.wilcoxon's "
            f"test, zero differences dropped): without tied or zero differences the CI "
            f"excludes 0 exactly when p < {paired.ALPHA}; with them the two can part at the "
            f"boundary, and the p cell says so. The reference's median is the median of its "
            f"own values over the worlds. A variant is *better* only if the CI "
            f"excludes 0, p < {paired.ALPHA} and the CI is not inside ±{paired.NEGLIGIBLE:.1%} "
            f"of the reference's median (else: negligible difference). No correction for "
            f"multiple comparisons in the verdicts: each table says how many tests it holds and "
            f"how many of its verdicts survive the Benjamini-Hochberg adjustment. "
            f"n/a: fewer than {paired.MIN_PAIRS} pairs or non-zero differences "
            f"(the two-sided Wilcoxon test drops zeros and cannot reach p < 0.05 below 6 "
            f"non-zero differences), or all differences zero.",
        ]
        # worlds and runs of one row per case (the first variant's first metric)
        one = table[(table["other"] == table["other"].iloc[0])
                    & (table["metric"] == table["metric"].iloc[0])]  # fmt: skip
        shared = one[one["runs"] > one["n"]]
        if len(shared):
            lines.append(
                "Runs that met the same world: " + "; ".join(
                    f"{r['case']} {int(r['runs'])} runs of {count(int(r['n']), 'world')}"
                    for _, r in shared.iterrows()) + ". Their draws gave the same realisation "
                "(a scenario without an `[uncertain]` table, a suite current that replaced its "
                "only drawn value, a discrete draw that repeated, or conditions such as the "
                "estimators on one world), so the statistics count worlds, not runs."
            )  # fmt: skip
        never = never_fixed_table(results, ref, names[1], key) if len(names) == 2 else None
        if never is not None and (never[["ref_never", "other_never"]].to_numpy().sum()):
            lines.append(
                "A run that never reliably fixed an AUV gives that AUV a reliable-fix age of "
                "0.95 x the run's length (p95) and the run's length (max), the metric's "
                "ceiling: the worst AUV's value then says no more than 'never served', and two "
                "runs that both leave one unserved read 'no change'. The column "
                f"'{NEVER_COLUMN}' counts them per case and variant (AUVs x runs) and the "
                "pairs in which both runs left one unserved: " + "; ".join(
                    f"{c} {ref} {int(r_['ref_never'])}, {names[1]} {int(r_['other_never'])}"
                    + (f", both in {count(int(r_['both']), 'pair')}" if r_["both"] else "")
                    for c, r_ in never.iterrows() if r_["ref_never"] or r_["other_never"])
                + "."
            )  # fmt: skip
        no_fix = cases_without_fixes(ok)
        if no_fix:
            lines.append(
                f"No USBL fix arrived in any run of {', '.join(no_fix)}: there the fix ages are "
                "the run's clock and the AUVs navigate without fixes whatever the controller, so "
                "its liveness and navigation rows compare nothing."
            )
        for line in lines:
            bullet(line)
        md.append("")
        for other, t in table.groupby("other", sort=False):
            th = t[t["metric"].isin(headline)]
            sub = f"{other} vs {ref}"
            both(f"\n### {sub}\n", f"<h3>{html.escape(sub)}</h3>")
            if len(th):
                bullet(_multiplicity_line(paired.multiplicity(th), "this table"))
                md.append("")
                nv = never_fixed_table(results, ref, str(other), key)
                d = headline_table(th, nv)
                both(_md_table(d) + "\n", d.to_html())
                figure(
                    rf.forest_figure(
                        th, paired.HEADLINE, figdir / f"forest-{_heading_id(other)}.png"
                    )
                )
        if acc is not None:  # the suite's targets, judged
            head, rule, parts = acceptance.report_parts(results, acc, names, no_fix)
            both(f"\n## {head}\n", f"<h2>{html.escape(head)}</h2>")
            bullet(rule)
            for other, (sub, d, says) in zip(names[1:], parts, strict=True):
                both(f"\n### {sub}\n\n{_md_table(d)}\n", f"<h3>{html.escape(sub)}</h3>"
                     f"{d.to_html()}")  # fmt: skip
                bullet(says)
                d = acceptance.per_case_table(results, acc, names[0], other, no_fix)
                both(f"\n{PER_CASE}\n\n{_md_table(d)}\n",
                     f"<p>{html.escape(PER_CASE)}</p>{d.to_html()}")  # fmt: skip
            md.append("")
        wl = paired.significant_win_loss(table)
        note = (
            "Per metric with a direction: the number of cases in which each variant is "
            "significantly better on the paired test above (per-AUV counts summed, fix "
            "ages maxed per run). 'No significant difference' includes negligible and identical; "
            "unpaired or n/a comparisons are never counted as wins."
        )
        both(
            f"\n## Significant wins and losses (paired)\n\n{note}\n",
            f"<h2>Significant wins and losses (paired)</h2><p>{html.escape(note)}</p>",
        )
        for other, w in wl.groupby("other", sort=False):
            d = win_loss_table(w)
            sub = f"{other} vs {ref}"
            both(f"\n### {sub}\n\n{_md_table(d)}\n", f"<h3>{html.escape(sub)}</h3>{d.to_html()}")
            # its counts rest on many tests too (a statistician's review, session 48)
            bullet(_multiplicity_line(paired.multiplicity(table[table["other"] == other]),
                                      "these counts"))  # fmt: skip
            md.append("")
    both("\n## The sweep\n", "<h2>The sweep</h2>")
    facts = [
        f"{suite.description}".strip(),
        f"Jobs: {len(exp.jobs)} in the suite, {len(results)} with results "
        f"({len(ok)} ok, {count(len(errors), 'error')}); seeds {list(suite.seeds)}; the "
        "per-scenario tables give means ± sd over seeds.",
        f"Whole results table: `{READ_LINE.format(out=out)}` (one row per job).",
    ]
    facts += [f"Skipped: {s}" for s in exp.skipped]
    for f in filter(None, facts):
        bullet(f)
    md.append("")
    if len(errors):
        both("\n## Errors\n", "<h2>Errors</h2>")
        for _, r in errors.iterrows():
            last = (r["error"] or "").strip().splitlines()[-1:] or [""]
            t = f"{r['scenario']} / {r['variant']} / seed {r['seed']} / current {r['current']}"
            both(f"- {t}: `{last[0]}`", f"<p>{html.escape(t)}: <code>{html.escape(last[0])}"
                 "</code></p>")  # fmt: skip
    for scenario in dict.fromkeys(ok["scenario"]) if len(ok) else []:
        g = ok[ok["scenario"] == scenario]
        auv_names = g.iloc[0]["auv_names"].split(",")
        both(f"\n## {scenario}\n", f"<h2>{html.escape(scenario)}</h2>")
        if scenario in cases_without_fixes(ok):
            bullet("No USBL fix arrived in any run of this case: the fix-age ECDFs are the "
                   "run's clock, and the navigation error does not depend on the controller.")
        t = scenario_table(summ, scenario, auv_names)
        both(_md_table(t) + "\n", t.to_html())
        ecdf, notes = rs.ecdf_figure(out, ok, scenario, figdir / f"ecdf-{scenario}.png")
        for n_ in notes:
            bullet(n_)
        reps = rs.representative_runs(ok, scenario)
        figs = [ecdf] if ecdf else []
        lost = [r["run_dir"] for _, r in reps.iterrows() if not rs.has_timeseries(out, r)]
        if lost:
            bullet(f"No figure of the representative runs: no time series in {', '.join(lost)}.")
        else:
            figs.append(rs.compare_figure(out, reps, scenario, figdir / f"compare-{scenario}.png"))
        figs.append(
            rf.box_figure(ok, scenario, BOX_METRICS, better, figdir / f"box-{scenario}.png")
        )
        for fig in figs:
            figure(fig)
        links_md, links_html = [], []
        for _, r in reps.iterrows():
            pngs = sorted(rs.run_path(out, r["run_dir"]).glob("*.png"))
            if pngs:
                links_md.append(f"{r['variant']}: " + ", ".join(
                    f"[{p.stem}]({run_link(p, out)})" for p in pngs))  # fmt: skip
                anchors = [f'<a href="{html.escape(run_link(p, out))}">{p.stem}</a>'
                           for p in pngs]  # fmt: skip
                links_html.append(html.escape(r["variant"]) + ": " + ", ".join(anchors))
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


def _multiplicity_line(mu: paired.Multiplicity, what: str) -> str:
    """The report's line on how much the 'better' verdicts of ``what`` (a table) rest on
    chance (:func:`mpcasv.experiments.stats.multiplicity`)."""
    if not mu.tests:  # the methods say every table says how many tests it holds: this too
        return (f"Multiple comparisons: none tested in {what} (no comparison has a p-value: "
                f"fewer than {paired.MIN_PAIRS} pairs or non-zero differences, or all "
                "differences zero); no 'better' verdict, nothing to adjust.")  # fmt: skip
    return (f"Multiple comparisons: {count(mu.tests, 'test')} in {what} at α = {paired.ALPHA} "
            f"(about {mu.expected_false:.1f} 'better' verdicts expected by chance if nothing "
            f"differed); {count(mu.better, 'verdict')} 'better', {mu.better_bh} of them with "
            f"Benjamini-Hochberg adjusted p < {paired.ALPHA} "
            "(scipy.stats.false_discovery_control), which bounds the expected share of false "
            "ones among them, not the chance of any (Holm's adjustment would).")  # fmt: skip
