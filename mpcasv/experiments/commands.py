"""``mpcasv compare``: run a suite of experiments and write the results table and the report."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from mpcasv.experiments.workers import cpu_count
from mpcasv.wording import count, noun


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare", help="run a suite (scenarios x controllers x tunings x seeds) and report",
        description="Expand SUITE into jobs, run them on a local process pool (or a Dask "
        "cluster), write each finished job at once (run folder + results row) and finally "
        "DIR/results.parquet, DIR/report.md and DIR/report.html. Rerunning the same command "
        "resumes an interrupted sweep; a DIR holding another suite's results is refused.",
    )  # fmt: skip
    p.add_argument(
        "suite",
        nargs="?",
        default="paper",
        help="suite name in experiments/suites (default: paper) or a TOML path",
    )
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="output folder DIR (default: results/<suite name>)")  # fmt: skip
    p.add_argument("--workers", type=int, default=None,
                   help=f"local worker processes (default: the cores this process may use, "
                   f"{cpu_count()}; 1 runs them one at a time, in one worker process while "
                   "--job-timeout holds, in this process with --job-timeout 0; at most 4 per "
                   "core; never more than the jobs to run; not with --dask)")  # fmt: skip
    p.add_argument("--dask", metavar="ADDRESS",
                   help="run on an existing Dask scheduler (e.g. tcp://host:8786); the workers "
                   "need no file system shared with this machine: each job's row comes back "
                   "here and DIR is written here; MPC jobs need workers that are not daemons "
                   "(DASK_DISTRIBUTED__WORKER__DAEMON=False dask worker ...)")  # fmt: skip
    p.add_argument("--runs-dir", metavar="PATH|URL",
                   help="where the run folders go: a path the workers can write or an fsspec "
                   "URL (e.g. s3://bucket/runs); default DIR/runs, and with --dask "
                   "mpcasv-runs/SUITE in each worker's working directory")  # fmt: skip
    p.add_argument(
        "--retry-errors",
        action="store_true",
        help="rerun jobs recorded with an error (default: keep them)",
    )
    p.add_argument("--job-timeout", type=float, metavar="S", default=None,
                   help="end a job running longer than S seconds and record it as 'timeout' "
                   "(default 1200; 0: no limit; with --workers 1 too: the job then runs in "
                   "a worker process; only 0 with --dask: a Dask task cannot be ended from "
                   "outside)")  # fmt: skip
    p.add_argument("--no-report", action="store_true", help="skip report.md / report.html")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mpcasv.config import ConfigError
    from mpcasv.experiments import acceptance
    from mpcasv.experiments.report import READ_LINE
    from mpcasv.experiments.runner import JOB_TIMEOUT_S, is_url, run_suite, say_untested_current
    from mpcasv.experiments.suite_file import load_suite
    from mpcasv.experiments.sweep_folder import LOCK_FILE
    from mpcasv.experiments.workers import check_workers
    from mpcasv.outputs import check_not_other_output, check_output_folder

    # at most 4 per CPU locally (1000 hung the machine); not with --dask (was ignored)
    args.workers = check_workers(args.workers, args.dask)
    if args.dask and args.job_timeout:  # was silently ignored (0, no limit, is what Dask has)
        raise ConfigError(f"--job-timeout {args.job_timeout:g} with --dask {args.dask}: a Dask "
                          "task cannot be ended from outside, so a cluster has no per-job time "
                          "limit (an MPC's hang guard still abandons a hung solve): leave it "
                          "out, or run on local workers")  # fmt: skip
    if args.job_timeout is not None and not (math.isfinite(args.job_timeout)
                                             and args.job_timeout >= 0):  # fmt: skip
        raise ConfigError(f"--job-timeout {args.job_timeout}: a finite number of seconds >= 0 "
                          "(0: no limit)")  # fmt: skip
    limit = JOB_TIMEOUT_S if args.job_timeout is None else (args.job_timeout or None)
    suite = load_suite(args.suite)[0]  # a bad suite (or another kind of file): refused now
    out = check_output_folder(args.out or Path("results") / suite.name)
    check_not_other_output(out, "mpcasv compare")
    if (out / "study.db").exists():  # an Optuna study: tune controller's or falsify's
        raise ConfigError(f"--out {out}: holds an Optuna study (study.db) of 'mpcasv tune "
                          "controller' or 'mpcasv falsify'; 'mpcasv compare' would overwrite "
                          "files there: use another folder")  # fmt: skip
    if not (out / "parts").exists():  # (results without suite.toml: refused by the runner)
        # a non-empty folder that is no compare's (no suite.toml, no lock) is a user's:
        # refused (its report.md and results.parquet were replaced: a new user, session 47)
        check_not_other_output(out, "mpcasv compare", own=("suite.toml", LOCK_FILE))
    if args.runs_dir is not None and not is_url(args.runs_dir) and not args.dask:
        check_output_folder(args.runs_dir, "--runs-dir")  # (with --dask: the workers' paths)
    stats, exp, results = run_suite(args.suite, out, args.workers, args.dask, args.quiet,
                                    args.retry_errors, not args.no_report,
                                    runs_dir=args.runs_dir, job_timeout=limit)  # fmt: skip
    out = out.resolve()
    ok = int((results["status"] == "ok").sum()) if len(results) else 0
    print(f"{count(stats.ran, 'job')} run in {stats.jobs_wall_s:.1f} s on "
          f"{stats.backend or 'nothing'} ({stats.already_done} "
          f"{noun(stats.already_done, 'was', 'were')} done before); results: {ok} ok, "
          f"{count(len(results) - ok, 'error')}, of {count(len(exp.jobs), 'job')}")  # fmt: skip
    for c in exp.fronts:  # entries naming a tuned front (mpcasv.experiments.tune_match)
        print(f"{c.label}: {c.controller} front point trial {c.trial} of {c.folder} "
              f"({c.at} {c.front_level:.5g}, {c.source} mean; asked {c.level:.5g})")  # fmt: skip
    print(f"run folders: {stats.runs}")
    say_untested_current(results)
    for name, err in stats.error_jobs:
        print(f"  error in {name}: {err}")
    _say_kept_errors(results, exp, stats)
    if stats.lost:
        print(f"  {count(stats.lost, 'job')} lost with their worker: rerun the same command to "
              "resume")  # fmt: skip
    if not args.no_report:
        print(f"report: {out / 'report.html'} (and report.md)")
    elif suite.acceptance is not None:  # judged only in the report: say it was not
        n = len(suite.acceptance.targets)
        what = (f"the suite's {n} [acceptance] target{'s' * (n > 1)} not judged: "
                f"{'they are' if n > 1 else 'it is'}")  # fmt: skip
        why = acceptance.why_not_judged(results)
        if why is None:
            print(f"acceptance: {what} judged in the report, which --no-report skips (rerun "
                  "the same command without --no-report: finished jobs are not run again)")
        else:  # the report could not judge them either, and says so
            print(f"acceptance: {what} not judged by the report either: {why}")
    print(f"results table: import pandas as pd; df = {READ_LINE.format(out=out)}")
    return 0 if ok == len(exp.jobs) else 1


def _say_kept_errors(results, exp, stats) -> None:
    """Print the error jobs recorded by an earlier sweep and not rerun (without
    ``--retry-errors``): a rerun of a sweep whose every error was kept printed none of them,
    and exited 1 (session 47)."""
    if not len(results):
        return
    said = {name for name, _ in stats.error_jobs}
    names = {j.job_id: j.run_name for j in exp.jobs}
    for job_id, error in results.loc[results["status"] != "ok", ["job_id", "error"]].values:
        name = names.get(job_id, job_id)
        if name not in said:
            last = (str(error).strip().splitlines() or ["(no message)"])[-1]
            print(f"  error in {name} (recorded before; --retry-errors reruns it): {last}")
