"""Sweeps on a Dask cluster (``--dask ADDRESS`` of ``compare`` and ``tune controller``): the
workers need no file system shared with this machine, each job's row comes back through Dask
and is written here (docs/experiments.md "Dask"). A Dask task cannot be ended from outside, so
a cluster has no per-job time limit (``--job-timeout`` is refused with ``--dask``); an MPC's
hang guard still abandons a hung solve, in a solver process the worker must be allowed to
start (:func:`check_dask_workers`).
"""

from __future__ import annotations

from pathlib import Path

from mpcasv.config import ConfigError
from mpcasv.experiments.runner import SweepStats, finish_job, record_row, run_job
from mpcasv.experiments.suite import Job

__all__ = ["check_dask_workers", "run_dask"]


def _is_daemon() -> bool:  # runs in each Dask worker
    import multiprocessing

    return multiprocessing.current_process().daemon


def check_dask_workers(client, jobs: list[Job], address: str) -> None:
    """Refuse, before any job is submitted, a cluster whose workers cannot run the jobs: MPC
    jobs (the kinds with compiled libraries) on workers that are daemon processes (``dask
    worker``'s default, under its nanny), which may not start the MPC's solver process (every
    such job failed with multiprocessing's "daemonic processes are not allowed to have
    children"). Workers that join later are not seen here: their MPC jobs fail with the same
    explanation (:data:`mpcasv.mpc.deadline.DAEMON_REFUSED`).

    Raises
    ------
    ConfigError
        One line naming the address, how many workers are daemons and how to start them
        instead.
    """
    from mpcasv.controllers import controller_kind
    from mpcasv.mpc.deadline import DAEMON_REFUSED

    mpc = sorted({j.controller for j in jobs if controller_kind(j.controller).libraries})
    if not mpc:
        return
    daemons = [w for w, daemon in client.run(_is_daemon).items() if daemon]
    if daemons:
        raise ConfigError(f"--dask {address}: {len(daemons)} of the cluster's workers cannot "
                          f"run the {', '.join(mpc)} jobs: {DAEMON_REFUSED}")  # fmt: skip


def run_dask(jobs: list[Job], out: Path, runs: str, stats: SweepStats, address: str,
             bar) -> None:  # fmt: skip
    """Run ``jobs`` on the Dask scheduler at ``address`` (one task each, no retries); each
    job's row comes back through Dask and is written into ``out`` here, so the workers need no
    file system shared with this machine (docs/experiments.md "Dask"). A job lost with its
    worker has no row (rerun on resume).

    Raises
    ------
    ConfigError
        No scheduler answers at ``address``; or its workers cannot run the jobs
        (:func:`check_dask_workers`).
    """
    from dask.distributed import Client
    from dask.distributed import as_completed as dask_completed

    try:
        client = Client(address, timeout="20s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise ConfigError(f"--dask {address}: cannot connect to a Dask scheduler: {exc}") from None
    try:
        stats.workers = len(client.nthreads())
        check_dask_workers(client, jobs, address)
        futures = {client.submit(run_job, job, runs, pure=False, retries=0): job
                   for job in jobs}  # fmt: skip
        for fut in dask_completed(list(futures)):
            job = futures[fut]
            try:
                row = fut.result()  # the row comes back through Dask: written here
            except Exception as exc:  # the machinery failed (e.g. KilledWorker): no row
                stats.lost += 1
                bar.write(f"lost {job.run_name}: {type(exc).__name__}: {exc} (rerun to resume)")
            else:
                record_row(stats, job, finish_job(out, row))
            bar.set_postfix(errors=stats.errors, refresh=False)
            bar.update(1)
    finally:
        client.close()
