"""``mpcasv tune compare DIR_REF DIR_OTHER``: two tuned controllers compared at matched
operating points (issue 17 item 3), with the paired statistics of the fair comparison.

Each ``DIR`` is the output of ``mpcasv tune controller`` with held-out runs. For every point
of the reference's training front that stayed feasible and non-dominated on the held-out
realisations, the other controller's front point (among those feasible on the held-out runs)
with the nearest held-out mean of the matching metric (``--at``, default ``energy_J``) is
taken, if that mean is within ``--tolerance`` (relative) of the reference's; the two trials'
held-out runs are then paired by realisation (scenario, current, estimator, seed: both
searches must use the same held-out realisations) and every other objective gets the
Hodges-Lehmann estimate of the paired difference (other - reference, column ``estimate``), its
distribution-free CI and the Wilcoxon p-value of the same estimand
(:func:`mpcasv.experiments.stats.paired_stat`, at least ``stats.MIN_PAIRS`` pairs) and a
verdict (:func:`mpcasv.experiments.stats.verdict`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd

from mpcasv.config import ConfigError

PAIR_COLUMNS = ("scenario", "current", "estimator", "seed", "realisation")


def _load(d: Path) -> tuple[dict, pd.DataFrame, pd.DataFrame]:
    """(tune.json, front.csv, held-out rows) of a tuning output folder."""
    from mpcasv.experiments.store import read_parts

    for name in ("tune.json", "front.csv"):
        if not (d / name).exists():
            raise ConfigError(f"{d}: no {name}: not an output folder of 'mpcasv tune controller'")
    summary = json.loads((d / "tune.json").read_text())
    front = pd.read_csv(d / "front.csv")
    if not len(front):  # no feasible training trial: nothing was run on held-out seeds
        raise ConfigError(f"{d}: its training front is empty (no feasible trial: see its "
                          "report.md): no point to compare")  # fmt: skip
    rows = read_parts(d / "heldout")
    if not len(rows) or "heldout_front" not in front:
        raise ConfigError(f"{d}: no held-out runs (rerun without --no-heldout)")
    return summary, front, rows


def _runs(rows: pd.DataFrame, trial: int, summary: dict) -> pd.DataFrame:
    """The ok held-out runs of ``trial``: by the job ids tune.json lists (a trial repeating
    another's values shares its runs, stored under the other's name: selected by name, it had
    none and was compared on "no pairs"); by name in a folder written before those ids."""
    ids = summary["heldout"].get("job_ids", {}).get(str(trial))
    if ids is not None:
        sel = rows[rows["job_id"].isin(ids)]
    else:
        sel = rows[rows["variant"].str.endswith(f"[trial={trial}]")]
    return sel[sel["status"] == "ok"].set_index(list(PAIR_COLUMNS))


def matched_comparison(ref_dir: str | Path, other_dir: str | Path, at: str = "energy_J",
                       tolerance: float = 0.1) -> pd.DataFrame:  # fmt: skip
    """One row per (reference point, objective): the matched other point and the paired
    statistics of that objective on their held-out runs (see the module docstring).

    Raises
    ------
    ConfigError
        A folder is not a tuning output with held-out runs, ``at`` is not an objective of
        both, or the two used different held-out realisations.
    """
    from mpcasv.experiments.metrics import METRIC_INFO
    from mpcasv.experiments.stats import paired_stat, verdict

    (sa, fa, ra), (sb, fb, rb) = _load(Path(ref_dir)), _load(Path(other_dir))
    for s, d in ((sa, ref_dir), (sb, other_dir)):
        if at not in s["objectives"]:
            raise ConfigError(f"{d}: --at {at!r} is not one of its objectives {s['objectives']}")
    if sorted(sa["heldout"]["realisations"]) != sorted(sb["heldout"]["realisations"]):
        raise ConfigError(
            f"{ref_dir} and {other_dir}: different held-out realisations; "
            "pairing needs the same scenarios, conditions and seeds"
        )
    objectives = [m for m in sa["objectives"] if m in sb["objectives"] and m != at]
    if not objectives:  # it printed "nothing to pair: the reference has no point ..."
        raise ConfigError(f"{ref_dir} and {other_dir}: no objective but --at {at!r} in both "
                          f"searches ({sa['objectives']}, {sb['objectives']}): nothing to "
                          "compare at matched levels")  # fmt: skip
    ca, cb = sa["controller"], sb["controller"]
    if ca == cb:  # two searches of one controller: "hybrid-single better" named neither
        ca, cb = f"{ca} ({Path(ref_dir).name})", f"{cb} ({Path(other_dir).name})"
        if ca == cb:
            ca, cb = f"{ca} [ref]", f"{cb} [other]"
    fb_ok = fb[fb["heldout_error"].isna() | (fb["heldout_error"] == "")]
    if sb.get("constraint"):  # only points that stayed feasible on the held-out runs
        fb_ok = fb_ok[fb_ok[f"heldout.{sb['constraint']}"] <= 0]
    out = []
    for _, pa in fa[fa["heldout_front"]].iterrows():
        ea = pa[f"heldout.{at}"]
        if not len(fb_ok):
            break
        k = (fb_ok[f"heldout.{at}"] - ea).abs().idxmin()
        pb = fb_ok.loc[k]
        rel = abs(pb[f"heldout.{at}"] - ea) / max(abs(ea), 1e-12)
        base = {"ref": ca, "ref_trial": int(pa["trial"]), "other": cb,
                "other_trial": int(pb["trial"]), f"ref.{at}": ea,
                f"other.{at}": pb[f"heldout.{at}"], "mismatch": rel}  # fmt: skip
        if rel > tolerance:
            out.append(base | {"metric": "", "verdict": f"no match within {tolerance:.0%}"})
            continue
        a, b = _runs(ra, int(pa["trial"]), sa), _runs(rb, int(pb["trial"]), sb)
        both = a.index.intersection(b.index)
        for m in objectives:
            s = paired_stat(a.loc[both, m].to_numpy(float), b.loc[both, m].to_numpy(float))
            ref_med = float(a.loc[both, m].median()) if len(both) else math.nan
            out.append(base | {"metric": m, "n": s.n, "ref_median": ref_med,
                               "estimate": s.estimate, "ci_low": s.ci_low,
                               "ci_high": s.ci_high, "p": s.p, "note": s.note,
                               "verdict": verdict(s, METRIC_INFO[m].better, ca, cb,
                                                  ref_med)})  # fmt: skip
    return pd.DataFrame(out)


def _read_baseline(results: str | Path) -> pd.DataFrame:
    """An ``mpcasv compare`` results table, or a one-line ConfigError naming the file."""
    path = Path(results)
    if path.is_dir() and (path / "results.parquet").exists():
        path = path / "results.parquet"
    if not path.is_file():
        raise ConfigError(f"--baseline {results}: no such file (a results.parquet of "
                          "'mpcasv compare')")  # fmt: skip
    try:
        df = pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises several types for a file that is not parquet
        raise ConfigError(f"--baseline {results}: not a parquet table ("
                          f"{' '.join(str(exc).split())[:120]})") from None  # fmt: skip
    missing = sorted({"variant", "status", "realisation", "collision_domain_s"} - set(df.columns))
    if missing:
        raise ConfigError(f"--baseline {results}: no columns {missing}: not a results.parquet "
                          "of 'mpcasv compare'")  # fmt: skip
    return df


def baseline_points(results: str | Path, objectives: list[str]) -> pd.DataFrame:
    """Mean of each objective per variant of an ``mpcasv compare`` results table (e.g. the
    published presets on the same held-out realisations), and the summed constraint.

    Raises
    ------
    ConfigError
        No such file, not a parquet table, or not an ``mpcasv compare`` results table.
    """
    df = _read_baseline(results)
    missing = [m for m in objectives if m not in df.columns]
    if missing:
        raise ConfigError(f"--baseline {results}: no columns {missing}: not a results table "
                          "with the searches' objectives")  # fmt: skip
    df = df[df["status"] == "ok"]
    agg = df.groupby("variant")[list(objectives)].mean()
    agg["collision_domain_s"] = df.groupby("variant")["collision_domain_s"].sum()
    agg["runs"] = df.groupby("variant").size()
    return agg


def plot_fronts(dirs: list[str | Path], path: str | Path,
                baseline: str | Path | None = None) -> Path:  # fmt: skip
    """The held-out values of several tunings' fronts (one colour per folder; filled: still
    feasible and non-dominated on the held-out realisations), objectives pairwise; with
    ``baseline`` (an ``mpcasv compare`` results.parquet on the same realisations), each of
    its variants as a star. Drawn by :func:`fronts_figure`."""
    import matplotlib.pyplot as plt

    searches = [(*_load(Path(d))[:2], Path(d).name) for d in dirs]
    objectives = [m for m in searches[0][0]["objectives"]  # those of every search
                  if all(m in s["objectives"] for s, _, _ in searches)]  # fmt: skip
    if len(objectives) < 2:
        raise ConfigError(f"--plot: the searches in {[str(d) for d in dirs]} share the "
                          f"objectives {objectives} only: nothing to draw pairwise")  # fmt: skip
    base = baseline_points(baseline, objectives) if baseline is not None else None
    fig = fronts_figure(searches, objectives, base)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def fronts_figure(searches: list[tuple[dict, pd.DataFrame, str]], objectives: list[str],
                  base: pd.DataFrame | None = None):  # fmt: skip
    """The figure of :func:`plot_fronts` (a matplotlib Figure, not yet saved): ``searches``
    are (tune.json, front.csv, folder name) of each tuning, ``base`` the
    :func:`baseline_points` (or None). Each axis says which way is better (objectives of
    both directions: ``reliable_fixes`` is higher-is-better); the legend is below the panels,
    never on a data point."""
    import itertools

    import matplotlib.pyplot as plt

    from mpcasv.experiments.metric_info import axis_label

    pairs = list(itertools.combinations(objectives, 2))
    fig, axes = plt.subplots(1, len(pairs), figsize=(5.2 * len(pairs), 4.4 + 0.3 * len(searches)),
                             squeeze=False, layout="constrained")  # fmt: skip
    for (summary, front, name), colour in zip(searches, plt.cm.tab10.colors, strict=False):
        nd = front["heldout_front"].astype(bool)
        for ax, (a, b) in zip(axes[0], pairs, strict=True):
            x, y = front[f"heldout.{a}"], front[f"heldout.{b}"]
            ax.scatter(x[nd], y[nd], c=[colour], s=34,
                       label=f"{summary['controller']} ({name}): held-out front")  # fmt: skip
            if (~nd).any():  # a legend entry only for what is drawn
                ax.scatter(x[~nd], y[~nd], facecolors="none", edgecolors=[colour], s=34,
                           label=f"{summary['controller']} ({name}): dominated or infeasible "
                           "on held-out")  # fmt: skip
    if base is not None:
        for (variant, row), marker in zip(base.iterrows(), "*P^v", strict=False):
            for ax, (a, b) in zip(axes[0], pairs, strict=True):
                ax.scatter(row[a], row[b], marker=marker, s=140, c="k",
                           label=f"{variant} (published preset): "
                           f"{row['collision_domain_s']:g} s in a collision domain")  # fmt: skip
    for ax, (a, b) in zip(axes[0], pairs, strict=True):
        ax.set_xlabel(axis_label(a))
        ax.set_ylabel(axis_label(b))
        ax.grid(alpha=0.3)
    handles, labels = axes[0][0].get_legend_handles_labels()
    # below the panels: inside a panel ("best" place) it covered a data point
    fig.legend(handles, labels, loc="outside lower center", fontsize=7,
               ncol=1 if len(pairs) == 1 else 2)  # fmt: skip
    # two lines: on one panel (5.2 in wide) one line was cut at both ends; which way is
    # better is on each axis (it was "lower is better" for all, reliable_fixes too)
    fig.suptitle("Tuned fronts re-run on the held-out realisations\n(means over the runs; "
                 "each axis says which way is better)", fontsize=10)  # fmt: skip
    return fig


def register_compare(tsub) -> None:
    """Add ``compare`` to the sub-commands of ``mpcasv tune``."""
    p = tsub.add_parser(
        "compare", help="compare two tuned controllers at matched operating points",
        description="Pair the held-out runs of two 'mpcasv tune controller' outputs at "
        "matched values of --at (default energy_J): for each feasible held-out front point of "
        "DIR_REF, the front point of DIR_OTHER nearest in --at; paired median differences, "
        "bootstrap CIs and Wilcoxon p-values of the other objectives.",
    )  # fmt: skip
    p.add_argument("ref", type=Path, help="output folder of the reference tuning")
    p.add_argument("other", type=Path, help="output folder of the other tuning")
    p.add_argument("--at", default="energy_J", help="metric to match (default energy_J)")
    p.add_argument("--tolerance", type=float, default=0.1,
                   help="largest relative mismatch of --at (default 0.1)")  # fmt: skip
    p.add_argument("--out", type=Path, help="write the table here (a .csv file)")
    p.add_argument("--plot", type=Path, help="draw both held-out fronts into this PNG")
    p.add_argument("--baseline", type=Path,
                   help="results.parquet of 'mpcasv compare' on the same held-out "
                   "realisations: its variants drawn as stars")  # fmt: skip
    p.set_defaults(func=_run)


def _run(args) -> int:
    if not args.tolerance > 0:
        raise ConfigError(f"--tolerance {args.tolerance}: must be > 0")
    from mpcasv.outputs import PLOT_SUFFIXES, check_output_file

    if args.out is not None:
        check_output_file(args.out, "--out", (".csv",))
    if args.plot is not None:  # matplotlib picks the format by the suffix
        check_output_file(args.plot, "--plot", PLOT_SUFFIXES)
    if args.baseline is not None:  # checked before the work; drawn only on the figure
        if args.plot is None:
            raise ConfigError(f"--baseline {args.baseline}: is drawn on the figure only; give "
                              "--plot FILE too")  # fmt: skip
        summary = _load(Path(args.ref))[0]
        baseline_points(args.baseline, summary["objectives"])
        # drawn beside the held-out fronts: it must be run on the same realisations
        got = set(_read_baseline(args.baseline)["realisation"].astype(str))
        want = set(summary["heldout"]["realisations"])
        if got != want:
            raise ConfigError(f"--baseline {args.baseline}: its runs are on realisations "
                              f"{sorted(got)}, the held-out ones of {args.ref} are "
                              f"{sorted(want)}: run the baseline on the searches' held-out "
                              "seeds and scenarios")  # fmt: skip
    df = matched_comparison(args.ref, args.other, args.at, args.tolerance)
    if args.out:
        df.to_csv(args.out, index=False)
    if args.plot:
        plot_fronts([args.ref, args.other], args.plot, args.baseline)
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(df.to_string(index=False, float_format=lambda v: f"{v:.4g}") if len(df)
              else "nothing to pair: the reference has no point on its held-out front, or the "
              "other no point feasible on the held-out realisations")  # fmt: skip
    return 0
