"""``mpcasv falsify``: search a scenario family for a controller's worst case; write the worst
cases as scenario files with their figures, and a table of the search."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from mpcasv.wording import count

#: the search folder's lock file (:func:`mpcasv.outputs.folder_lock`): one search at a time
LOCK_FILE = "falsify.lock"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "falsify", help="search a scenario family for a controller's worst case (CMA-ES)",
        description="Search the parameters of FAMILY (a TOML file: a template scenario and "
        "parameter ranges, e.g. experiments/falsify/pursuer-single.toml) for the smallest "
        "margin min_t (slant range - required separation) (or the longest stay inside a "
        "collision domain) of CONTROLLER, with Optuna's CMA-ES sampler. Writes DIR/study.db "
        "(resumable: rerun the same command; DIR/falsify.json records the search, and a DIR "
        "holding another search is refused), DIR/trials.csv, DIR/trials.md, and the worst "
        "cases as DIR/worst/<name>.toml with their run folders (paths.png, range.png). A "
        "search finds counterexamples; it does not prove safety.",
    )  # fmt: skip
    p.add_argument("family", type=Path, help="family TOML (template scenario + parameters)")
    p.add_argument("--controller", required=True, help="controller name")
    p.add_argument("--params", help="controller preset: shipped name or TOML path")
    p.add_argument("--budget", type=int, default=32, help="runs in all (default 32)")
    p.add_argument("--workers", type=int, default=1,
                   help="worker processes (default 1; at most 4 per core; no more start than "
                   "runs go at once, 4)")  # fmt: skip
    p.add_argument("--timeout", type=float, metavar="S",
                   help="wall-clock limit per run (s): a run still going is recorded as an "
                   "error (a solver that never returns); default: none")  # fmt: skip
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the sampler and of every run (default 0)")  # fmt: skip
    p.add_argument("--objective", choices=("margin", "stay"), default="margin",
                   help="minimise the margin (default) or maximise the longest stay")  # fmt: skip
    p.add_argument("--separation", type=float, metavar="M",
                   help="required separation (m; default: the controller's r_in)")  # fmt: skip
    p.add_argument("--worst", type=int, default=3, help="worst cases written (default 3)")
    p.add_argument("--require-margin", type=float, metavar="M",
                   help="exit 1 if the worst margin found is below M (m)")  # fmt: skip
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="output folder (default results/falsify/FAMILY-CONTROLLER)")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no line per finished run")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mpcasv.experiments.falsify import time_ranges
    from mpcasv.experiments.falsify_family import corner_warning
    from mpcasv.experiments.falsify_folder import record_study
    from mpcasv.outputs import folder_lock

    setup, out, identity = check_inputs(args)  # every refusal: before any trial or file
    corners = corner_warning(setup.family)
    if corners:
        print(corners, file=sys.stderr)
    for r in time_ranges(setup.family):  # partly past the duration: said, the search goes on
        if r.past:  # (after the refusals: a refused command prints its one line only)
            print(r.warning(args.family), file=sys.stderr)
    if setup.preset is None:
        print(f"warning: no preset (--params, or the family's 'preset'): the runs have no "
              f"evaluation domain, so no escape power turn and null domain metrics; the "
              f"margin is measured against {args.controller}'s default r_in",
              file=sys.stderr)  # fmt: skip
    # a second search in the folder took the first one's running trials for a killed
    # search's and ran them again: Optuna's UpdateFinishedTrialError (a review)
    with folder_lock(out, "mpcasv falsify", LOCK_FILE):
        record_study(out, identity)
        return _search_and_write(args, setup, out)


def _search_and_write(args: argparse.Namespace, setup, out: Path) -> int:
    """:func:`run` once the folder is locked: the search, its table and the worst cases."""
    from mpcasv.experiments.falsify import BATCH, search, trials_table
    from mpcasv.experiments.workers import pool_size, reduced_note

    used = pool_size(args.workers, min(BATCH, args.budget))  # runs going at once
    if used < args.workers and not args.quiet:
        print(f"{used} worker processes" + reduced_note(args.workers, used, "the most runs that "
                                                         "go at once"))  # fmt: skip

    def progress(number: int, m: dict) -> None:
        if args.quiet:
            return
        if "error" in m:
            print(f"  trial {number:3d}: error {m['error'][:120]}", flush=True)
        else:
            print(f"  trial {number:3d}: margin {m['margin_m']:7.2f} m, longest stay "
                  f"{m['longest_stay_s']:5.0f} s", flush=True)  # fmt: skip

    study = search(setup, out / "study.db", args.budget, args.workers, progress, args.timeout)
    table = trials_table(study)
    table.to_csv(out / "trials.csv", index=False)
    (out / "trials.md").write_text(_markdown(table, setup, args.budget) + "\n")
    ok = table[table["state"] == "complete"] if len(table) else table
    if not len(ok):
        print(f"no run finished without an error: see {out / 'trials.csv'}")
        return 1
    key = "margin_m" if args.objective == "margin" else "longest_stay_s"
    ranked = ok.sort_values(key, ascending=args.objective == "margin")
    top = ranked.head(args.worst).iterrows()
    reruns = dict(write_worst(setup, row, rank, out / "worst")
                  for rank, (_, row) in enumerate(top, 1))  # fmt: skip
    written = list(reruns)
    worst = float(ok["margin_m"].min())
    summary = {"family": setup.family.name, "controller": args.controller, "preset": args.params,
               "budget": args.budget, "seed": args.seed, "objective": args.objective,
               "finished": int(len(table)), "errors": int((table["state"] != "complete").sum()),
               "worst_margin_m": worst, "longest_stay_s": float(ok["longest_stay_s"].max()),
               "r_sep_m": float(ok["r_sep_m"].iloc[0]), "worst_cases": written,
               "rerun_margin_m": reruns}  # fmt: skip
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(f"{count(len(table), 'run')} ({count(summary['errors'], 'error')}); worst margin "
          f"{worst:.2f} m "
          f"(r_sep {summary['r_sep_m']:g} m), longest stay {summary['longest_stay_s']:.0f} s; "
          f"worst cases: {', '.join(written)}"
          + (f" (simulate them with --seed {args.seed}, the search's)" if args.seed else "")
          + f"; table: {out / 'trials.md'}")  # fmt: skip
    if args.require_margin is not None and worst < args.require_margin:
        print(f"margin check FAIL: {worst:.2f} m < {args.require_margin:g} m")
        return 1
    return 0


def check_inputs(args: argparse.Namespace):
    """Check every option, the family, the controller and the output folder before any trial
    or file: (SearchSetup, output folder, the search's identity for ``DIR/falsify.json``).

    Raises
    ------
    ConfigError
        One line naming the option or file and the cause: a bad number; a family refused by
        :func:`~mpcasv.experiments.falsify_family.load_family` (e.g. a range end giving an
        invalid scenario); an unknown controller or bad preset; a controller without a safety
        domain and no ``--separation``; worst-case names that cannot be file names; an output
        folder of another command or holding another search
        (:func:`~mpcasv.experiments.falsify_folder.check_study_folder`).
    """
    from mpcasv.config import ConfigError, anchor, check_path_name, check_seed
    from mpcasv.controllers import Boat
    from mpcasv.controllers.registry import check_boat, check_controller_flag, checked_preset
    from mpcasv.experiments.falsify import SearchSetup, candidate, load_family
    from mpcasv.experiments.falsify_folder import check_study_folder, study_identity
    from mpcasv.experiments.workers import check_workers
    from mpcasv.outputs import check_not_other_output, check_output_folder

    check_controller_flag(args.controller)
    for flag in ("budget", "worst"):
        if getattr(args, flag) < 1:
            raise ConfigError(f"--{flag} must be >= 1, got {getattr(args, flag)}")
    check_workers(args.workers)  # at most 4 per CPU (each a process)
    # nan here was a search that never ended (--separation: every margin nan, Optuna refuses
    # the value), a check that always passed (--require-margin) or a traceback (--seed -1)
    check_seed(args.seed)
    if args.separation is not None and not (math.isfinite(args.separation)
                                            and args.separation >= 0):  # fmt: skip
        raise ConfigError(f"--separation {args.separation:g}: a finite distance >= 0 (m)")
    if args.require_margin is not None and not math.isfinite(args.require_margin):
        raise ConfigError(f"--require-margin {args.require_margin:g}: a finite margin (m)")
    if args.timeout is not None and not (math.isfinite(args.timeout) and args.timeout > 0):
        raise ConfigError(f"--timeout {args.timeout:g}: a finite number of seconds > 0 "
                          "(leave it out for no limit)")  # fmt: skip
    family = load_family(args.family)  # ranges checked at their ends and corners
    # the preset the controller runs and the world judges by (SearchSetup): --params, else
    # the family's own; a path is made absolute, so the worst cases name it from anywhere
    preset = args.params if args.params is not None else family.template.get("preset")
    preset = None if preset in (None, "default") else anchor(preset, Path.cwd())
    mid = {p.name: 0.5 * (p.low + p.high) for p in family.spec.param}
    scenario, _ = candidate(family, mid, "midpoint")
    # unknown controller, bad preset, AUVs it cannot serve, another vessel: every trial
    # failed on these (a budget of one-line errors, exit 1, and a study in the folder)
    _, params = checked_preset(args.controller, len(scenario.auv), preset,
                               holder=f"the family {family.name!r}")  # fmt: skip
    check_boat(params, Boat.of_scenario(scenario), preset or "default")
    if args.separation is None and getattr(params, "domain", None) is None:
        # every trial failed on it ("has no safety domain"), the search exited 1 with a study
        raise ConfigError(f"--controller {args.controller}: has no safety domain (no collision "
                          "sphere r_in to measure the margin against): give --separation M")
    worst = f"falsified-{family.name}-{args.controller}-{args.worst}"
    try:  # the worst cases' file and folder names
        check_path_name(worst)
    except ValueError as exc:
        raise ConfigError(f"--controller {args.controller}: worst cases would be named "
                          f"{worst!r}, not a file name: {exc}") from None
    out = args.out or Path("results") / "falsify" / f"{family.name}-{args.controller}"
    check_output_folder(out)
    # a compare or tune folder, or a non-empty one that is no search's: refused
    check_not_other_output(out, "mpcasv falsify", own=("study.db", LOCK_FILE))
    setup = SearchSetup(family, args.controller, preset, args.seed, args.separation,
                        args.objective, named=args.params)  # fmt: skip
    identity = study_identity(family, args.controller, args.params, params, args.seed,
                              args.objective, args.separation)  # fmt: skip
    check_study_folder(out, identity)  # another search there: refused, not mixed
    return setup, out, identity


def _markdown(table, setup, budget: int) -> str:
    head = (f"# Falsification: {setup.family.name} with {setup.controller} "
            f"(preset {setup.preset or 'default'})\n\nbudget {count(budget, 'run')}, seed "
            f"{setup.seed}, "
            f"objective {setup.objective}; sorted by margin (m). A search finds "
            "counterexamples; it does not prove safety.\n")  # fmt: skip
    if not len(table):
        return head
    measures = ("margin_m", "t_margin_s", "auv_margin", "longest_stay_s", "time_inside_s",
                "min_range_m", "fallbacks", "error")  # fmt: skip
    cols = ["trial", *[p.name for p in setup.family.spec.param],
            *[c for c in measures if c in table]]  # fmt: skip
    from mpcasv.experiments.report import _md_table

    shown = table[cols].set_index("trial").map(lambda v: f"{v:.2f}" if isinstance(v, float) else v)
    return head + "\n" + _md_table(shown)


def write_worst(setup, row, rank: int, folder: Path) -> str:
    """Write the scenario of a trial as ``folder/<name>.toml`` and rerun it into
    ``folder/<name>/`` with the figures; return the name and the rerun's margin (m), which
    should be the searched one (runs are deterministic; a warning is printed if not)."""
    import tomli_w

    from mpcasv.controllers import Boat, make_controller
    from mpcasv.experiments.falsify import robustness
    from mpcasv.experiments.metrics import compute_metrics
    from mpcasv.sim.record import write_run
    from mpcasv.sim.scenario import scenario_from_dict
    from mpcasv.sim.simulator import simulate

    fam = setup.family
    params = {p.name: float(row[p.name]) for p in fam.spec.param}
    name = f"falsified-{fam.name}-{setup.controller}-{rank}"
    _, data = setup.scenario(params, name)  # what the trial ran
    data = {**data, "name": name,
            "description": f"worst case {rank} of mpcasv falsify {fam.source.name} for "
                           f"{setup.controller} (trial {int(row['trial'])})"}  # fmt: skip
    prov = dict(data.get("provenance", {}))
    prov["falsify"] = (f"family {fam.source.name}, controller {setup.controller}, preset "
                       f"{setup.preset or 'default'}, seed {setup.seed}, trial "
                       f"{int(row['trial'])}: margin {row['margin_m']:.3f} m (r_sep "
                       f"{row['r_sep_m']:g} m), longest stay {row['longest_stay_s']:g} s; "
                       "parameters "
                       + ", ".join(f"{k} = {v:.4g}" for k, v in params.items()))  # fmt: skip
    data["provenance"] = prov
    # the run under the worst case's own name (its run.json and figures named the family)
    scenario = scenario_from_dict(data, f"{fam.source} ({name})")
    folder.mkdir(parents=True, exist_ok=True)
    # the scenario format has no seed: the run is this file with the search's seed
    again = f"mpcasv simulate {name}.toml" + (f" --seed {setup.seed}" if setup.seed else "")
    header = f"# {data['description']}\n# {prov['falsify']}\n# the searched run: {again}\n"
    (folder / f"{name}.toml").write_text(header + tomli_w.dumps(data))
    ctrl = make_controller(setup.controller, len(scenario.auv), setup.preset,
                           boat=Boat.of_scenario(scenario))  # fmt: skip
    result = simulate(scenario, ctrl, setup.seed)
    rob = robustness(result.timeseries, len(scenario.auv), float(row["r_sep_m"]),
                     scenario.sim.row_period)
    if not math.isclose(rob.margin_m, float(row["margin_m"]), abs_tol=1e-6):
        # the runs should be deterministic: say so loudly, keep the rerun (its figures)
        print(f"warning: {name}: the rerun's margin is {rob.margin_m:.3f} m, the search's "
              f"{float(row['margin_m']):.3f} m: this controller's runs are not "
              "reproducible")  # fmt: skip
    extra = {"preset": setup.preset, "falsify": prov["falsify"], "rerun_margin_m": rob.margin_m}
    write_run(result, folder / name, compute_metrics(result), extra=extra)
    return name, rob.margin_m
