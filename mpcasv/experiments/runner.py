"""Running a suite's jobs: in this process (1 worker, no time limit), on a local process pool,
or on a Dask distributed cluster; each finished job is written at once (run folder, then its
results part).

A worker runs a job, writes its run folder under the runs location and returns the job's row
(description, outcome, metrics: :mod:`mpcasv.experiments.job_worker`); this process (the
client) writes the row as the job's part in ``DIR/parts`` and, at the end,
``DIR/results.parquet``. So the workers need no file system
shared with the client: the results table is complete and resumable from the client alone.
The runs location (:func:`~mpcasv.experiments.sweep_folder.runs_location`) is ``DIR/runs``
for local workers; on Dask it is the ``--runs-dir`` the user names (a path the workers can
write, or an fsspec URL such as ``s3://bucket/runs``), else ``mpcasv-runs/<suite>`` in each
worker's working directory (the run folders stay where the worker is; the row's ``run_dir``
and ``worker`` say where).

Local pool workers are started with ``spawn`` (fresh interpreters: each builds its own CasADi
functions, which are cached per process, and nothing half-initialised is inherited) and exit
by themselves if the runner dies.

A job that raises is recorded (``status = "error"``, the traceback in ``error``) and the others
go on; a failure of the machinery itself (a worker process killed, the cluster lost) writes no
row, so resuming reruns that job. On a local pool a job running longer than ``job_timeout``
(default :data:`JOB_TIMEOUT_S`) is ended (its worker process killed and replaced, by Pebble's
process pool) and recorded with ``status = "timeout"``; the sweep goes on (issue 16 item 5:
a hung solve must not stall a sweep). ``--workers 1`` with a limit runs on a pool of one
process for that reason; ``--workers 1 --job-timeout 0`` (no limit) runs in this process. Dask
does not enforce it (the command refuses a limit with ``--dask``). A local pool starts no more
processes than there are jobs to run (:mod:`mpcasv.experiments.workers`), and a sweep refuses
an output folder holding another suite's results
(:func:`~mpcasv.experiments.sweep_folder.check_suite_folder`).
"""

from __future__ import annotations

import dataclasses
import json
import os
import threading
import time
from concurrent.futures import as_completed
from multiprocessing import get_context
from pathlib import Path

from mpcasv.experiments.job_worker import run_job, timeout_row
from mpcasv.experiments.store import done_ids, write_part, write_results
from mpcasv.experiments.suite import Expansion, Job, expand
from mpcasv.experiments.sweep_folder import (
    LOCK_FILE,
    check_runs_location,
    check_suite_folder,
    is_url,
    remove_leftovers,
    runs_location,
)
from mpcasv.experiments.workers import pool_size, reduced_note, spawning_quietly
from mpcasv.outputs import folder_lock
from mpcasv.wording import count

#: default time limit of one job on a local pool (s): generous (a 1500 s MPC run with three
#: AUVs takes a few minutes on a busy 2-core machine)
JOB_TIMEOUT_S = 1200.0


def finish_job(out: Path, row: dict) -> dict:
    """Client side: write a returned row as the job's part in ``out`` (atomically); a run
    folder inside ``out`` is recorded relative to it (``runs/<run name>``)."""
    run_dir = row.get("run_dir")
    if run_dir and not is_url(run_dir) and Path(run_dir).is_relative_to(out):
        row = row | {"run_dir": str(Path(run_dir).relative_to(out))}
    write_part(out, row)
    return row


def prepare_controllers(jobs: list[Job], quiet: bool = False, dask: str | None = None) -> list:
    """Before the workers start: compile the libraries the jobs' controllers need that are not
    in the cache, saying which, that it happens once, and how long (issue 12 item 8); the
    workers then load them. With Dask, the workers' machines have their own caches: only the
    message is given. Returns the libraries compiled here."""
    from mpcasv.controllers import Boat, controller_kind
    from mpcasv.controllers.prepare import needed_libraries, prepare
    from mpcasv.sim.scenario import load_scenario

    builds, seen = [], set()
    for job in jobs:
        if controller_kind(job.controller).libraries is None:
            continue
        key = (job.controller, job.n_auv, job.preset, job.overrides, job.scenario_path)
        if key in seen:
            continue
        seen.add(key)
        boat = Boat.of_scenario(load_scenario(job.scenario_path))  # the suite changes no boat
        builds.append((job.controller, job.n_auv, job.preset, dict(job.overrides), boat))
    if not builds:
        return []
    libs = needed_libraries(builds)
    if dask:
        if libs and not quiet:
            est = ", ".join(sorted({f"{lib.label}: about {lib.estimate_s:.0f} s" for lib in libs}))
            print(f"MPC libraries: each Dask worker machine compiles the {len(libs)} it needs "
                  f"once, at its first MPC job, unless its cache has them ({est})")  # fmt: skip
        return []
    return prepare(libs, quiet=quiet)


def _watch_parent(parent_pid: int) -> None:  # pragma: no cover - runs in pool workers
    """Pool worker initializer: exit when the runner process is gone (killed)."""

    def loop():
        while True:
            time.sleep(1.0)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=loop, daemon=True, name="mpcasv-parent-watch").start()


@dataclasses.dataclass
class SweepStats:
    """What a sweep did (printed and written to ``DIR/sweep.json``)."""

    suite: str
    jobs: int
    already_done: int
    ran: int = 0
    ok: int = 0
    errors: int = 0  # jobs of this sweep that raised
    lost: int = 0  # jobs whose worker failed (no row: rerun on resume)
    backend: str = ""
    workers: int = 1
    runs: str = ""  # where the run folders are (see runs_location)
    jobs_wall_s: float = 0.0
    interrupted: bool = False
    error_jobs: list = dataclasses.field(default_factory=list)  # (run name, last error line)


def record_row(stats: SweepStats, job: Job, row: dict) -> None:
    """Count a finished job's row (written by :func:`finish_job`) in ``stats``."""
    stats.ran += 1
    if row["status"] == "ok":
        stats.ok += 1
    else:
        stats.errors += 1
        stats.error_jobs.append((job.run_name, row["error"].strip().splitlines()[-1]))


def _bar(total: int, desc: str, quiet: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="job", disable=quiet, dynamic_ncols=True,
                smoothing=0.1)  # fmt: skip


def pending_jobs(exp: Expansion, out: Path, retry_errors: bool = False) -> list[Job]:
    """Jobs without a part (or with an error part, when ``retry_errors``), longest first."""
    done = done_ids(out)
    todo = [j for j in exp.jobs if j.job_id not in done
            or (retry_errors and done[j.job_id] != "ok")]  # fmt: skip
    return sorted(todo, key=lambda j: (-j.cost, j.index))


def in_this_process(workers: int, job_timeout: float | None) -> bool:
    """Whether local jobs run in this process: one worker and no time limit (a job in this
    process cannot be ended from outside, so a limit needs a pool, of one process if so)."""
    return workers <= 1 and not job_timeout


def run_jobs(jobs: list[Job], out: Path, stats: SweepStats, workers: int = 1,
             dask: str | None = None, quiet: bool = False, runs: str | None = None,
             job_timeout: float | None = JOB_TIMEOUT_S) -> None:  # fmt: skip
    """Run ``jobs`` (serially, on a process pool, or on Dask), updating ``stats``; run folders
    under ``runs`` (default: :func:`runs_location`), rows written into ``out`` here.
    ``job_timeout`` (s; None: no limit): a longer job is ended and recorded as ``timeout``.
    ``workers = 1`` runs the jobs in this process only without a limit; with one it runs them
    on a Pebble pool of one process (a job in this process cannot be ended). A local pool
    starts at most one process per job (:func:`~mpcasv.experiments.workers.pool_size`), so a
    single job still gets its timeout. Dask has no limit (the command refuses one)."""
    out = out.resolve()
    runs = runs or runs_location(out, stats.suite, None, dask)
    stats.runs = stats.runs or runs
    bar = _bar(len(jobs), stats.suite, quiet)
    t0 = time.perf_counter()
    try:
        if dask:
            from mpcasv.experiments.dask_runner import run_dask

            stats.backend = f"dask {dask}"
            run_dask(jobs, out, runs, stats, dask, bar)
        elif in_this_process(workers, job_timeout):
            stats.backend, stats.workers = "serial (this process)", 1
            for job in jobs:
                record_row(stats, job, finish_job(out, run_job(job, runs)))
                bar.set_postfix(errors=stats.errors, refresh=False)
                bar.update(1)
        else:
            n = pool_size(max(workers, 1), len(jobs))
            stats.backend, stats.workers = f"local process pool ({n} workers)", n
            _run_pool(jobs, out, runs, stats, n, bar, job_timeout)
    except KeyboardInterrupt:
        stats.interrupted = True
        raise
    finally:
        stats.jobs_wall_s = time.perf_counter() - t0
        bar.close()


def make_pool(workers: int):
    """The sweep's Pebble process pool of ``workers`` spawned processes; each worker, a
    replacement for one ended at a job timeout included, runs :func:`_watch_parent` first.
    Pebble's worker routine ignores SIGINT before it runs any job, so only a worker's start-up
    imports need ``spawning_quietly`` (the first workers); a replacement's are outside it."""
    from pebble import ProcessPool

    return ProcessPool(workers, initializer=_watch_parent, initargs=(os.getpid(),),
                       context=get_context("spawn"))  # fmt: skip


def _run_pool(jobs, out: Path, runs: str, stats: SweepStats, workers: int, bar,
              job_timeout: float | None = JOB_TIMEOUT_S) -> None:  # fmt: skip
    from pebble import ProcessExpired

    pool = make_pool(workers)
    try:
        with spawning_quietly():  # the first schedule starts the workers: they ignore Ctrl-C
            futures = {pool.schedule(run_job, (job, runs), timeout=job_timeout): job
                       for job in jobs}  # fmt: skip
        for fut in as_completed(futures):
            job = futures[fut]
            try:
                row = fut.result()
            except TimeoutError:  # Pebble killed the worker and started another
                row = timeout_row(job, job_timeout)
            except ProcessExpired as exc:  # the machinery failed: no row, rerun on resume
                stats.lost += 1
                bar.write(f"lost {job.run_name}: worker process died ({exc}); rerun the same "
                          "command to resume")  # fmt: skip
                bar.update(1)
                continue
            record_row(stats, job, finish_job(out, row))
            bar.set_postfix(errors=stats.errors, refresh=False)
            bar.update(1)
    except BaseException:  # Ctrl-C or a failure: stop now, not after the queued jobs
        pool.stop()
        raise
    finally:
        pool.close()
        pool.join()


def run_suite(suite: str | Path, out: str | Path, workers: int = 1, dask: str | None = None,
              quiet: bool = False, retry_errors: bool = False, report: bool = True,
              runs_dir: str | None = None,
              job_timeout: float | None = JOB_TIMEOUT_S):  # fmt: skip
    """Expand ``suite``, run its pending jobs, consolidate ``results.parquet``, write the report.

    ``runs_dir``: where the run folders go (a path or an fsspec URL; see
    :func:`runs_location` for the default). ``job_timeout``: see :func:`run_jobs`.

    Returns
    -------
    (SweepStats, Expansion, pandas.DataFrame)
        The sweep's figures, the suite's jobs and the whole results table.
    """
    exp = expand(suite)  # refuses a bad suite before anything starts
    out = Path(out).resolve()
    check_suite_folder(out, exp.suite.name)  # another suite's results: refused, not mixed
    runs = runs_location(out, exp.suite.name, runs_dir, dask)
    if runs_dir:
        check_runs_location(runs, dask)  # before anything is written
    todo = pending_jobs(exp, out, retry_errors)
    if dask:  # the scheduler answers and its workers can run the jobs: before any file
        from mpcasv.experiments.dask_runner import check_dask_cluster

        check_dask_cluster(dask, todo)
    # a second compare on this folder is refused (it ran the same jobs beside the first and
    # both rewrote results.parquet and the report); a crashed one leaves no stale lock
    with folder_lock(out, "mpcasv compare", LOCK_FILE):
        # again under the lock: a sweep that ended while this one waited (the Dask check)
        # ran jobs this one would otherwise run again (a review)
        todo = pending_jobs(exp, out, retry_errors)
        # temporaries of the default run folder only: a --runs-dir may be another sweep's too
        remove_leftovers(out, runs if not (dask or runs_dir) else None, todo)
        return _run_locked(exp, out, runs, runs_dir, todo, workers, dask, quiet, report,
                           job_timeout)  # fmt: skip


def _run_locked(exp, out, runs, runs_dir, todo, workers, dask, quiet, report, job_timeout):
    """:func:`run_suite` once the folder is locked: run ``todo``, write the table and report."""
    (out / "suite.toml").write_bytes(exp.path.read_bytes())
    stats = SweepStats(exp.suite.name, len(exp.jobs), len(exp.jobs) - len(todo), workers=workers)
    stats.runs = runs if (runs_dir or not dask) else f"{runs} in each Dask worker's directory"
    if not quiet:
        for s in exp.skipped:
            print(f"skipped: {s}")
        where = (
            f"Dask at {dask}"
            if dask
            else ("this process" if in_this_process(workers, job_timeout) or not todo else
                  f"{pool_size(workers, len(todo))} local worker processes"
                  + reduced_note(workers, pool_size(workers, len(todo))))
        )  # fmt: skip
        print(f"suite {exp.suite.name}: {count(len(exp.jobs), 'job')}, {stats.already_done} "
              f"already done, {len(todo)} to run on {where}; output {out}; runs: "
              f"{stats.runs}")  # fmt: skip
    try:
        if todo:
            prepare_controllers(todo, quiet, dask)
            run_jobs(todo, out, stats, workers, dask, quiet, runs, job_timeout)
    except KeyboardInterrupt:
        print(f"interrupted after {stats.ran} of {count(len(todo), 'job')}; rerun the same "
              "command to resume (finished jobs are kept)")  # fmt: skip
        raise
    finally:
        results = write_results(out, exp.jobs)
        (out / "sweep.json").write_text(json.dumps(dataclasses.asdict(stats), indent=1) + "\n")
    if report:
        from mpcasv.experiments.report import write_report

        write_report(out, exp, results, stats)
    return stats, exp, results


def say_untested_current(results) -> None:
    """One line on stderr when runs (``results``: rows of jobs with their metrics, as a
    sweep's results table) had an MPC plan with a current above
    :data:`~mpcasv.mpc.worldview.CURRENT_TESTED` (column ``current_untested_s``), naming
    their scenarios and currents: each job's own line is off in a sweep
    (:func:`~mpcasv.experiments.job_worker.simulate_job`; it would name no job). Called at the
    end of ``mpcasv compare`` and of each batch of ``mpcasv tune controller``."""
    import sys

    if "current_untested_s" not in results:
        return
    runs = results[results["current_untested_s"] > 0]
    if not len(runs):
        return
    from mpcasv.mpc.worldview import CURRENT_TESTED

    where = ", ".join(sorted({f"{s} ({c})" for s, c in zip(runs["scenario"], runs["current"],
                                                           strict=True)}))  # fmt: skip
    print(f"mpcasv: warning: {len(runs)} of {count(len(results), 'run')} planned with a "
          f"current above the {CURRENT_TESTED:g} m/s the MPC has been tested in "
          f"(current_untested_s > 0; docs/mpc.md, \"Known problems\": strong currents): "
          f"{where}", file=sys.stderr)  # fmt: skip
