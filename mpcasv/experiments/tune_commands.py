"""``mpcasv tune controller RANGES.toml`` and ``mpcasv tune compare``: registered under the
``tune`` command of :mod:`mpcasv.control.commands` (registered first: see ``mpcasv.cli``).

    mpcasv tune controller experiments/tuning/hybrid-single.toml --out results/tune-hybrid
    mpcasv tune controller RANGES.toml --out DIR --trials 8 --workers 2   # resume/extend
    mpcasv tune compare DIR_HYBRID DIR_MPC --at energy_J                  # matched points
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mpcasv.experiments.workers import cpu_count


def _tune_subparsers(sub: argparse._SubParsersAction) -> argparse._SubParsersAction:
    """The sub-commands of ``mpcasv tune`` (added by mpcasv.control.commands)."""
    tune = sub.choices.get("tune")
    if tune is None:
        raise RuntimeError(
            "mpcasv.control.commands must be registered before "
            "mpcasv.experiments.tune_commands (see mpcasv.cli)"
        )
    for action in tune._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action
    raise RuntimeError("'mpcasv tune' has no sub-commands to extend")


def register(sub: argparse._SubParsersAction) -> None:
    from mpcasv.experiments.tune_compare import register_compare

    tsub = _tune_subparsers(sub)
    register_compare(tsub)
    p = tsub.add_parser(
        "controller", help="multi-objective search over a controller's preset fields (Optuna)",
        description="Search the preset fields declared in RANGES.toml (bounds, log, int) for "
        "the Pareto front of metrics.json objectives over a suite's training realisations, "
        "with no time in a collision domain as the constraint; re-run the front on held-out "
        "seeds; write front tables and figure, the front's presets, parameter importances and "
        "a report into --out. Resumable: rerun the same command (docs/tuning-controllers.md).",
    )  # fmt: skip
    p.add_argument("ranges", type=Path, help="range file (experiments/tuning/*.toml)")
    p.add_argument("--out", type=Path,
                   help="output folder (default results/tune-<range file name>)")  # fmt: skip
    p.add_argument("--trials", type=int, help="budget: trials (default: the range file's)")
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help=f"local worker processes (default: one per core, {cpu_count()}; 1: one worker "
        "process with the runs' time limit; at most 4 per core; never more than the runs of a "
        "batch; not with --dask)",
    )
    p.add_argument("--dask", metavar="ADDRESS",
                   help="run on a Dask scheduler instead (MPC runs need workers that are not "
                   "daemons: DASK_DISTRIBUTED__WORKER__DAEMON=False dask worker ...)")  # fmt: skip
    p.add_argument("--no-heldout", action="store_true", help="skip the held-out runs")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run_tune_controller)


def run_tune_controller(args: argparse.Namespace) -> int:
    from mpcasv.experiments.tune_controller import evaluate_heldout, search, study_size
    from mpcasv.experiments.tune_jobs import check_presets
    from mpcasv.experiments.tune_outputs import write_outputs
    from mpcasv.experiments.tune_space import load_spec
    from mpcasv.experiments.workers import check_workers
    from mpcasv.outputs import check_not_other_output, check_output_folder, folder_lock

    args.workers = check_workers(args.workers, args.dask)  # <= 4 per CPU; not with --dask
    # the trials already in the study (a budget hint never offers fewer: it was refused next)
    done = study_size(args.out or Path("results") / f"tune-{Path(args.ranges).resolve().stem}")
    spec = load_spec(args.ranges, args.trials, done)
    train = check_presets(spec)  # the suite's entry, range ends no trial could run: before any file
    if args.dask:  # the scheduler and its workers, as compare asks them: before any file (a
        # dead scheduler's error came after study.db and the lock were written, session 46)
        from mpcasv.experiments.dask_runner import check_dask_cluster

        check_dask_cluster(args.dask, train)
    out = check_output_folder((args.out or Path("results") / f"tune-{spec.path.stem}").resolve())
    check_not_other_output(out, "mpcasv tune controller", own=("study.db", "tune.lock"))
    # two commands on one folder ran the same trials; the second died on a traceback
    # ("Cannot tell a COMPLETE trial")
    with folder_lock(out, "mpcasv tune controller", "tune.lock"):
        study = search(spec, out, args.workers, args.dask, args.quiet)
        heldout = {} if args.no_heldout else evaluate_heldout(spec, study, out, args.workers,
                                                              args.dask, args.quiet)  # fmt: skip
        report = write_outputs(spec, study, heldout, out)
    if not args.quiet:
        print(f"report: {report}")
    return 0
