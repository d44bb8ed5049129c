"""What ``mpcasv tune controller`` writes into its output folder (issue 17 items 2 and 4):

* ``trials.csv``: every trial (state, values, objectives, constraint, error);
* ``front.csv`` / ``front.md``: the training Pareto front (feasible, non-dominated trials) with
  their held-out objectives and constraint, and whether each stays non-dominated and feasible
  on the held-out realisations;
* ``front.png``: the objectives pairwise: every trial, the training front, and the front's
  held-out values (a line from each training point to its held-out point);
* ``presets/trial-NNNN.toml``: each front trial's complete preset (the base preset with the
  suite entry's overrides and the trial's values), usable with ``mpcasv simulate --params``
  or as a suite's ``preset``; one file per scenario (``trial-NNNN-<scenario>.toml``) when
  the entry's base differs between scenarios (``preset = "scenario"``, ``domain_from``);
* ``importance.csv``: Optuna's PED-ANOVA importance of each parameter per objective;
* ``report.md`` and ``tune.json``: budgets (trials, runs), seeds, wall time, the tables.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from mpcasv.experiments.tune_controller import front_trials
from mpcasv.experiments.tune_jobs import heldout_jobs, training_jobs, trial_jobs
from mpcasv.experiments.tune_space import TuneSpec
from mpcasv.wording import count


def trials_table(spec: TuneSpec, study) -> pd.DataFrame:
    """One row per trial: number, state, the searched values, objectives, constraint."""
    rows = []
    for t in study.get_trials(deepcopy=False):
        row = {"trial": t.number, "state": t.state.name}
        row |= {p.name: t.params.get(p.name, math.nan) for p in spec.params}
        vals = t.values or [math.nan] * len(spec.objectives)
        row |= dict(zip(spec.objectives, vals, strict=True))
        if spec.constraint:
            row[spec.constraint] = t.system_attrs.get(f"constraints:{spec.constraint}", math.nan)
        row["error"] = t.user_attrs.get("error", "")
        rows.append(row)
    return pd.DataFrame(rows)


def non_dominated(values: np.ndarray, signs: np.ndarray) -> np.ndarray:
    """Mask of the rows of ``values`` (n, m) that no other row dominates; ``signs`` (m,) is
    +1 for objectives to minimise, -1 to maximise."""
    v = values * signs
    n = len(v)
    mask = np.ones(n, bool)
    for i in range(n):
        better_eq = np.all(v <= v[i], axis=1)
        strictly = np.any(v < v[i], axis=1)
        mask[i] = not np.any(better_eq & strictly)
    return mask


def front_table(spec: TuneSpec, study, heldout: dict) -> pd.DataFrame:
    """The training front with its held-out objectives (``heldout.<metric>``)."""
    from mpcasv.experiments.tune_controller import directions

    rows = []
    for t in front_trials(study):
        row = {"trial": t.number} | {p.name: t.params[p.name] for p in spec.params}
        row |= {f"train.{m}": v for m, v in zip(spec.objectives, t.values, strict=True)}
        h_vals, h_c, h_err = heldout.get(t.number, (None, math.nan, "not run"))
        h_vals = h_vals or [math.nan] * len(spec.objectives)
        row |= {f"heldout.{m}": v for m, v in zip(spec.objectives, h_vals, strict=True)}
        if spec.constraint:
            row[f"heldout.{spec.constraint}"] = h_c
        row["heldout_error"] = h_err or ""
        rows.append(row)
    columns = ["trial", *(p.name for p in spec.params),
               *(f"{s}.{m}" for s in ("train", "heldout") for m in spec.objectives),
               *([f"heldout.{spec.constraint}"] if spec.constraint else []), "heldout_error",
               "heldout_front"]  # fmt: skip
    # the columns also without a front (no feasible trial): front.csv keeps its header
    df = pd.DataFrame(rows, columns=columns[:-1])
    if not len(df):
        df["heldout_front"] = pd.Series(dtype=bool)
    else:
        signs = np.array([1.0 if d == "minimize" else -1.0 for d in directions(spec)])
        h = df[[f"heldout.{m}" for m in spec.objectives]].to_numpy(float)
        ok = np.all(np.isfinite(h), axis=1)
        if spec.constraint:
            ok &= df[f"heldout.{spec.constraint}"].to_numpy(float) <= 0
        nd = np.zeros(len(df), bool)
        if ok.any():
            nd[ok] = non_dominated(h[ok], signs)
        df["heldout_front"] = nd
    return df


def _set(data: dict, dotted: str, value) -> None:
    *path, last = dotted.split(".")
    for part in path:
        data = data.setdefault(part, {})
    data[last] = value


def write_presets(spec: TuneSpec, study, out: Path) -> list[Path]:
    """Each front trial's preset as TOML (see the module docstring), checked by loading it
    back: it must validate to the very parameters the trial ran with."""
    import tomli_w

    from mpcasv.controllers import load_preset
    from mpcasv.controllers.registry import _preset_data

    groups: dict = {}
    for j in training_jobs(spec):
        groups.setdefault((j.preset, j.overrides), []).append(j.scenario)
    folder = out / "presets"
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for t in front_trials(study):
        values = dict(t.params)
        for (preset, overrides), scenarios in groups.items():
            src, data = _preset_data(spec.controller, preset)
            for k, v in (dict(overrides) | values).items():
                _set(data, k, v)
            names = sorted(set(scenarios))
            suffix = "" if len(groups) == 1 else "-" + "+".join(names)
            path = folder / f"trial-{t.number:04d}{suffix}.toml"
            objs = ", ".join(f"{m} = {v:.4g}" for m, v in zip(spec.objectives, t.values,
                                                               strict=True))  # fmt: skip
            head = [f"# GENERATED by `mpcasv tune controller {spec.path.name}`: trial {t.number} "
                    f"of the training front of {spec.controller}",
                    f"# base preset {src} with the suite entry's overrides {dict(overrides)}",
                    f"# (scenarios {names}) and the trial's values {values}",
                    f"# training means: {objs}"]  # fmt: skip
            path.write_text("\n".join(head) + "\n" + tomli_w.dumps(data))
            if load_preset(spec.controller, path) != load_preset(
                spec.controller, preset, dict(overrides) | values
            ):
                raise RuntimeError(f"{path}: does not load back to trial {t.number}'s parameters")
            written.append(path)
    for path in sorted(set(folder.glob("trial-*.toml")) - set(written)):
        # a point of an earlier (shorter) search that is no longer on the front: its file
        # said "of the training front" (a file not generated here is left alone)
        if path.read_text().startswith("# GENERATED by `mpcasv tune controller"):
            path.unlink()
    return written


#: PED-ANOVA's top quantile: the share of complete trials whose parameter distribution is
#: compared with that of all trials (Optuna's default 0.1 keeps one or two of a small budget)
TARGET_QUANTILE = 0.25


def importances(spec: TuneSpec, study) -> pd.DataFrame:
    """Importance of each parameter (rows) for each objective and for reaching the Pareto
    front (column ``front``): Optuna's PED-ANOVA (Watanabe et al. 2023; deterministic, no
    scikit-learn, unlike its fANOVA) over the complete trials, normalised to sum 1 per
    column; empty when fewer than 4 trials are complete."""
    import warnings

    from optuna.importance import PedAnovaImportanceEvaluator, get_param_importances
    from optuna.trial import TrialState

    from mpcasv.experiments.tune_controller import directions

    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len(done) < 4:  # the columns all the same: importance.csv keeps its header (it was '""')
        return pd.DataFrame(columns=[*spec.objectives, "front"],
                            index=pd.Index([], name="parameter"))  # fmt: skip
    evaluator = PedAnovaImportanceEvaluator(target_quantile=TARGET_QUANTILE)
    signs = [1.0 if d == "minimize" else -1.0 for d in directions(spec)]
    targets = {m: (lambda t, i=i: signs[i] * t.values[i]) for i, m in enumerate(spec.objectives)}
    targets["front"] = None  # multi-objective: importance of reaching the Pareto front
    rows = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "quantiles select the same set": equal importances
        for m, target in targets.items():
            rows[m] = get_param_importances(study, evaluator=evaluator, target=target,
                                            normalize=True)  # fmt: skip
    return pd.DataFrame(rows).reindex([p.name for p in spec.params]).rename_axis("parameter")


def plot_front(spec: TuneSpec, trials: pd.DataFrame, front: pd.DataFrame, path: Path) -> Path:
    """Pairwise objective scatter: trials, training front, held-out values of the front."""
    import matplotlib.pyplot as plt

    fig = front_figure(spec, trials, front)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def front_figure(spec: TuneSpec, trials: pd.DataFrame, front: pd.DataFrame):
    """The figure of :func:`plot_front` (a matplotlib Figure, not yet saved)."""
    import itertools

    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    from mpcasv.experiments.metric_info import axis_label

    # one objective: against the trial number (it was drawn against itself, a diagonal)
    pairs = list(itertools.combinations(spec.objectives, 2)) or [("trial", spec.objectives[0])]
    # at most three panels a row: four objectives (six pairs) made a strip too wide to read
    ncols = min(3, len(pairs))
    nrows = math.ceil(len(pairs) / ncols)
    fig, grid = plt.subplots(nrows, ncols, figsize=(5.2 * ncols, 4.4 * nrows + 0.6),
                             squeeze=False, layout="constrained")  # fmt: skip
    for ax in grid.ravel()[len(pairs):]:
        ax.set_visible(False)
    axes = [grid.ravel()[: len(pairs)]]
    done = trials[trials["state"] == "COMPLETE"]
    front = front.assign(**{"train.trial": front["trial"], "heldout.trial": front["trial"]})
    feas = (done[spec.constraint] <= 0) if spec.constraint else np.ones(len(done), bool)
    for ax, (a, b) in zip(axes[0], pairs, strict=True):
        ax.scatter(done.loc[feas, a], done.loc[feas, b], s=14, c="0.6", label="trial (feasible)")
        if (~feas).any():
            ax.scatter(done.loc[~feas, a], done.loc[~feas, b], s=18, c="0.6", marker="x",
                       label="trial in a collision domain")  # fmt: skip
        if len(front):
            for _, r in front.iterrows():
                ax.plot([r[f"train.{a}"], r[f"heldout.{a}"]], [r[f"train.{b}"], r[f"heldout.{b}"]],
                        c="0.8", lw=0.8, zorder=1)  # fmt: skip
            ax.scatter(front[f"train.{a}"], front[f"train.{b}"], s=36, c="tab:blue",
                       label="front (training)", zorder=3)  # fmt: skip
            ax.scatter(front[f"heldout.{a}"], front[f"heldout.{b}"], s=36, c="tab:orange",
                       marker="s", label="same trials, held-out", zorder=3)  # fmt: skip
            for _, r in front.iterrows():
                ax.annotate(str(int(r["trial"])), (r[f"train.{a}"], r[f"train.{b}"]),
                            fontsize=7, xytext=(3, 3), textcoords="offset points")  # fmt: skip
        ax.set_xlabel("trial" if a == "trial" else axis_label(a))
        ax.set_ylabel(axis_label(b))
        # at most 5 x ticks: 7-digit labels (0.00722, 0.00724, ...) ran into each other
        ax.xaxis.set_major_locator(MaxNLocator(nbins=5, integer=a == "trial"))
        ax.grid(alpha=0.3)
    handles, labels = axes[0][0].get_legend_handles_labels()
    # below the panels: inside the first one ("best" place) it covered a point
    fig.legend(handles, labels, loc="outside lower center", fontsize=7,
               ncol=2 if ncols == 1 else len(labels))  # fmt: skip
    # two lines: on one panel (two objectives, 5.2 in wide) one line was cut at both edges
    fig.suptitle(f"{spec.controller}: {len(done)} complete trials\ntraining means vs held-out "
                 "means of the training front", fontsize=10)  # fmt: skip
    return fig


def _cell(v, fmt: str) -> str:
    if isinstance(v, (float, np.floating)):
        return "" if math.isnan(v) else format(float(v), fmt)
    return str(v).replace("|", "\\|")


def _md(df: pd.DataFrame, fmt: str = ".4g") -> str:
    """A markdown table of ``df`` (its columns; numbers formatted with ``fmt``)."""
    if not len(df):
        return "(none)"
    lines = ["| " + " | ".join(map(str, df.columns)) + " |", "|" + "---|" * len(df.columns)]
    for row in df.itertuples(index=False):
        lines.append("| " + " | ".join(_cell(v, fmt) for v in row) + " |")
    return "\n".join(lines)


def write_outputs(spec: TuneSpec, study, heldout: dict, out: str | Path) -> Path:
    """Write every output (module docstring) into ``out``; returns ``out/report.md``."""
    from mpcasv.experiments.store import done_ids

    out = Path(out).resolve()
    trials = trials_table(spec, study)
    trials.to_csv(out / "trials.csv", index=False)
    front = front_table(spec, study, heldout)
    front.to_csv(out / "front.csv", index=False)
    (out / "front.md").write_text(_md(front) + "\n")
    plot_front(spec, trials, front, out / "front.png")
    presets = write_presets(spec, study, out)
    imp = importances(spec, study)
    imp.to_csv(out / "importance.csv")
    train = training_jobs(spec)
    held = heldout_jobs(spec, train)
    states = trials["state"].value_counts().to_dict()
    n_feasible = int(((trials["state"] == "COMPLETE") & (trials[spec.constraint] <= 0)).sum()
                     if spec.constraint else states.get("COMPLETE", 0))  # fmt: skip
    runs = {k: len(done_ids(out / k)) for k in ("train", "heldout")}  # finished runs
    least = []
    if spec.constraint and (trials["state"] == "COMPLETE").any():
        done = trials[trials["state"] == "COMPLETE"]
        k = done[spec.constraint].idxmin()
        least = [int(done.loc[k, "trial"]), float(done.loc[k, spec.constraint])]
    summary = {
        "controller": spec.controller, "range_file": str(spec.path), "suite": spec.suite,
        "sampler": spec.sampler, "batch": spec.batch, "seed": spec.seed,
        "budget_trials": spec.trials, "trials": states, "feasible_trials": n_feasible,
        "least_violation": least,
        "objectives": list(spec.objectives), "constraint": spec.constraint,
        "params": [p.name for p in spec.params],
        "training": {"runs_per_trial": len(train),
                     "scenarios": sorted({j.scenario for j in train}),
                     "seeds": sorted({j.seed for j in train}),
                     "duration_s": sorted({j.duration for j in train}),
                     "realisations": sorted({j.realisation for j in train})},
        "heldout": {"runs_per_trial": len(held), "seeds": list(spec.heldout_seeds),
                    "realisations": sorted({j.realisation for j in held}),
                    "front_trials_run": len(heldout),
                    # each front trial's held-out runs (mpcasv tune compare): a trial that
                    # repeats another's values shares its runs, stored under that trial's name
                    "job_ids": {str(t.number): [j.job_id for j in trial_jobs(held, t.number,
                                                                             dict(t.params))]
                                for t in front_trials(study) if t.number in heldout}},
        "runs": {"training": runs["train"], "heldout": runs["heldout"]},
        "wall_s": {"search": float(study.user_attrs.get("wall_s", math.nan)),
                   "heldout": float(study.user_attrs.get("heldout_wall_s", 0.0)),
                   "sessions": int(study.user_attrs.get("sessions", 0))},
        "front": [int(t) for t in front["trial"]] if len(front) else [],
        "presets": [str(p.relative_to(out)) for p in presets],
    }  # fmt: skip
    (out / "tune.json").write_text(json.dumps(summary, indent=1) + "\n")
    report = out / "report.md"
    report.write_text(_report(spec, summary, front, imp))
    return report


def _report(spec: TuneSpec, s: dict, front: pd.DataFrame, imp: pd.DataFrame) -> str:
    tr, ho, w = s["training"], s["heldout"], s["wall_s"]
    lines = [
        f"# Tuning {spec.controller} (`mpcasv tune controller {spec.path.name}`)", "",
        f"- searched: {', '.join(f'`{p}`' for p in s['params'])}",
        f"- objectives (means over the training runs): {', '.join(s['objectives'])}; "
        f"constraint: {s['constraint'] or 'none'} = 0 on every training run (Optuna "
        "`Trial.set_constraint`, read by the sampler; no penalty)",
        f"- sampler {spec.sampler}, batches of {count(spec.batch, 'trial')}, seed {spec.seed}",
        f"- **budget: {count(spec.trials, 'trial')}**; states {s['trials']}; feasible "
        f"{s['feasible_trials']}; {count(s['runs']['training'], 'training run')} "
        f"({tr['runs_per_trial']} per trial; none for a trial the preset refuses)",
        *([f"- **no feasible trial**: the smallest summed {spec.constraint} is "
           f"{s['least_violation'][1]:.4g} (trial {s['least_violation'][0]}); no front"]
          if spec.constraint and not s["feasible_trials"] and s["least_violation"] else []),
        f"- training: scenarios {tr['scenarios']}, seeds {tr['seeds']}, duration "
        f"{tr['duration_s']} s; realisations {tr['realisations']}",
        f"- held-out: the {count(ho['front_trials_run'], 'front trial')} x "
        f"{count(ho['runs_per_trial'], 'run')} (seeds {ho['seeds']}; realisations "
        f"{ho['realisations']}); {count(s['runs']['heldout'], 'run')}",
        f"- wall time: search {w['search']:.0f} s over {w['sessions']} session(s), held-out "
        f"{w['heldout']:.0f} s", "",
        "## Training front and held-out values", "",
        "`heldout_front`: still feasible and non-dominated among the front on the held-out "
        "realisations. Figure: `front.png`; presets: `presets/`.", "",
        _md(front), "",
        "## Which parameters matter", "",
        f"Optuna's PED-ANOVA importance (top {TARGET_QUANTILE:.0%} of the complete trials "
        "against all of them), per objective and for reaching the Pareto front (`front`), "
        "normalised per column. With a small budget these are rough indications.", "",
        _md(imp.reset_index(), ".2f") if len(imp) else "(too few complete trials: fewer than 4)",
        "",
    ]  # fmt: skip
    return "\n".join(lines)
