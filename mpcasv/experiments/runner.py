"""Running a suite's jobs: in this process (1 worker), on a local process pool, or on a Dask
distributed cluster; each finished job is written at once (run folder, then its results part).

Local pool workers are started with ``spawn`` (fresh interpreters: each builds its own CasADi
functions, which are cached per process, and nothing half-initialised is inherited) and exit
by themselves if the runner dies. On Dask the workers write into ``DIR`` themselves, so ``DIR``
must be on a file system the workers share with the client, at the same path.

A job that raises is recorded (``status = "error"``, the traceback in ``error``) and the others
go on; a failure of the machinery itself (a worker process killed, the cluster lost) writes no
row, so resuming reruns that job.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import socket
import threading
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

from mpcasv.config import ConfigError
from mpcasv.experiments.store import done_ids, write_part, write_results
from mpcasv.experiments.suite import Expansion, Job, expand


def _describe(job: Job) -> dict:
    """The description columns of a job's row."""
    row = {
        "job_id": job.job_id, "index": job.index, "suite": job.suite, "scenario": job.scenario,
        "label": job.label, "variant": job.variant, "controller": job.controller,
        "preset": job.preset or "default", "overrides": json.dumps(dict(job.overrides)),
        "current_N": job.current[0], "current_E": job.current[1],
        "current": "off" if job.current == (0.0, 0.0) else f"{job.current[0]:g},{job.current[1]:g}",
        "estimator": job.estimator, "seed": job.seed, "n_auv": job.n_auv,
        "auv_names": ",".join(job.auv_names),
    }  # fmt: skip
    for k, v in job.overrides:
        row[f"param.{k}"] = json.dumps(v) if isinstance(v, (list, dict)) else v
    return row


def _metric_columns(metrics: dict) -> dict:
    """metrics.json values as columns; per-AUV lists expanded to ``<name>_auv<k>``."""
    out = {}
    for k, v in metrics.items():
        if isinstance(v, list):
            out |= {f"{k}_auv{i}": (float("nan") if x is None else x) for i, x in enumerate(v)}
        else:
            out[k] = float("nan") if v is None else v
    return out


def simulate_job(job: Job, run_dir: Path) -> dict:
    """Simulate one job and write its run folder; return its metrics."""
    from mpcasv.controllers import Boat, make_controller
    from mpcasv.experiments.metrics import compute_metrics
    from mpcasv.sim.record import write_run
    from mpcasv.sim.scenario import load_scenario, scenario_with
    from mpcasv.sim.simulator import simulate

    scenario = scenario_with(load_scenario(job.scenario_path), **job.scenario_changes())
    boat = Boat.of_scenario(scenario)  # one vessel per run: the simulator's and the MPC's
    controller = make_controller(job.controller, job.n_auv, job.preset, dict(job.overrides),
                                 boat=boat)  # fmt: skip
    result = simulate(scenario, controller, job.seed, job.estimator)
    extra = {"job_id": job.job_id, "suite": job.suite, "variant": job.variant,
             "preset": job.preset, "overrides": dict(job.overrides),
             "estimator": job.estimator, "current": job.current,
             "boat": boat.describe()}  # fmt: skip
    return write_run(result, run_dir, compute_metrics(result), plots=job.plots, extra=extra)


def run_job(job: Job, out: str) -> dict:
    """Run one job and write its run folder and its results part; return the row.

    Exceptions of the job are caught and recorded in the row (``status = "error"``);
    ``KeyboardInterrupt`` and other ``BaseException`` propagate (no row: rerun on resume).
    """
    out_p = Path(out)
    t0 = time.perf_counter()
    row = _describe(job)
    run_dir = out_p / "runs" / job.run_name
    try:
        metrics = simulate_job(job, run_dir)
        row |= {"status": "ok", "error": None, "run_dir": str(run_dir.relative_to(out_p))}
        row |= _metric_columns(metrics)
    except Exception:
        row |= {"status": "error", "error": traceback.format_exc(), "run_dir": None}
    row |= {
        "wall_s": time.perf_counter() - t0,
        "finished_at": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "worker": f"{socket.gethostname()}:{os.getpid()}",
    }
    write_part(out_p, row)
    return row


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
    jobs_wall_s: float = 0.0
    interrupted: bool = False
    error_jobs: list = dataclasses.field(default_factory=list)  # (run name, last error line)


def _record(stats: SweepStats, job: Job, row: dict) -> None:
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


def run_jobs(jobs: list[Job], out: Path, stats: SweepStats, workers: int = 1,
             dask: str | None = None, quiet: bool = False) -> None:  # fmt: skip
    """Run ``jobs`` (serially, on a process pool, or on Dask), updating ``stats``."""
    out = out.resolve()
    bar = _bar(len(jobs), stats.suite, quiet)
    t0 = time.perf_counter()
    try:
        if dask:
            stats.backend = f"dask {dask}"
            _run_dask(jobs, out, stats, dask, bar)
        elif workers <= 1:
            stats.backend, stats.workers = "serial (this process)", 1
            for job in jobs:
                _record(stats, job, run_job(job, str(out)))
                bar.set_postfix(errors=stats.errors, refresh=False)
                bar.update(1)
        else:
            stats.backend, stats.workers = f"local process pool ({workers} workers)", workers
            _run_pool(jobs, out, stats, workers, bar)
    except KeyboardInterrupt:
        stats.interrupted = True
        raise
    finally:
        stats.jobs_wall_s = time.perf_counter() - t0
        bar.close()


def _run_pool(jobs, out: Path, stats: SweepStats, workers: int, bar) -> None:
    from concurrent.futures.process import BrokenProcessPool

    ctx = get_context("spawn")
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_watch_parent,
                               initargs=(os.getpid(),))  # fmt: skip
    try:
        futures = {pool.submit(run_job, job, str(out)): job for job in jobs}
        for fut in as_completed(futures):
            job = futures[fut]
            try:
                _record(stats, job, fut.result())
            except BrokenProcessPool as exc:
                raise RuntimeError(f"a worker process died ({exc}); rerun the same command to "
                                   "resume (finished jobs are kept)") from None  # fmt: skip
            bar.set_postfix(errors=stats.errors, refresh=False)
            bar.update(1)
    except BaseException:  # Ctrl-C or a failure: stop now, not after the queued jobs
        for proc in list(getattr(pool, "_processes", {}).values()):  # kill_workers() in 3.14
            proc.terminate()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _run_dask(jobs, out: Path, stats: SweepStats, address: str, bar) -> None:
    from dask.distributed import Client
    from dask.distributed import as_completed as dask_completed

    try:
        client = Client(address, timeout="20s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise ConfigError(f"--dask {address}: cannot connect to a Dask scheduler: {exc}") from None
    try:
        stats.workers = len(client.nthreads())
        futures = {client.submit(run_job, job, str(out), pure=False, retries=0): job
                   for job in jobs}  # fmt: skip
        for fut in dask_completed(list(futures)):
            job = futures[fut]
            try:
                _record(stats, job, fut.result())
            except Exception as exc:  # the machinery failed (e.g. KilledWorker): no row
                stats.lost += 1
                bar.write(f"lost {job.run_name}: {type(exc).__name__}: {exc} (rerun to resume)")
            bar.set_postfix(errors=stats.errors, refresh=False)
            bar.update(1)
    finally:
        client.close()


def run_suite(suite: str | Path, out: str | Path, workers: int = 1, dask: str | None = None,
              quiet: bool = False, retry_errors: bool = False, report: bool = True):  # fmt: skip
    """Expand ``suite``, run its pending jobs, consolidate ``results.parquet``, write the report.

    Returns
    -------
    (SweepStats, Expansion, pandas.DataFrame)
        The sweep's figures, the suite's jobs and the whole results table.
    """
    exp = expand(suite)  # refuses a bad suite before anything starts
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    (out / "suite.toml").write_bytes(exp.path.read_bytes())
    todo = pending_jobs(exp, out, retry_errors)
    stats = SweepStats(exp.suite.name, len(exp.jobs), len(exp.jobs) - len(todo), workers=workers)
    if not quiet:
        for s in exp.skipped:
            print(f"skipped (optional controller not available): {s}")
        where = (
            f"Dask at {dask}"
            if dask
            else ("this process" if workers <= 1 else f"{workers} local worker processes")
        )
        print(f"suite {exp.suite.name}: {len(exp.jobs)} jobs, {stats.already_done} already done, "
              f"{len(todo)} to run on {where}; output {out}")  # fmt: skip
    try:
        if todo:
            run_jobs(todo, out, stats, workers, dask, quiet)
    except KeyboardInterrupt:
        print(f"interrupted after {stats.ran} of {len(todo)} jobs; rerun the same command to "
              "resume (finished jobs are kept)")  # fmt: skip
        raise
    finally:
        results = write_results(out, exp.jobs)
        (out / "sweep.json").write_text(json.dumps(dataclasses.asdict(stats), indent=1) + "\n")
    if report:
        from mpcasv.experiments.report import write_report

        write_report(out, exp, results, stats)
    return stats, exp, results
