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
from mpcasv.experiments.job_worker import run_job
from mpcasv.experiments.runner import SweepStats, finish_job, record_row
from mpcasv.experiments.suite import Job

__all__ = ["check_dask_cluster", "check_dask_workers", "connect", "hang_guarded", "run_dask"]


def _is_daemon() -> bool:  # runs in each Dask worker
    import multiprocessing

    return multiprocessing.current_process().daemon


def hang_guarded(jobs: list[Job]) -> list[str]:
    """The controllers (sorted names) of ``jobs`` whose solves run in a solver process of
    their own in simulation: an MPC with its hang guard
    (:attr:`mpcasv.mpc.solver_params.SolverParams.hang_guard`, ``solver.hang_s > 0``)."""
    from mpcasv.controllers import load_preset

    names, seen = set(), set()
    for j in jobs:
        key = (j.controller, j.preset, j.overrides)
        if key in seen or j.controller in names:
            continue
        seen.add(key)
        solver = getattr(load_preset(j.controller, j.preset, dict(j.overrides)), "solver", None)
        if getattr(solver, "hang_guard", False):
            names.add(j.controller)
    return sorted(names)


def check_dask_workers(client, jobs: list[Job], address: str) -> None:
    """Refuse a cluster whose workers cannot run ``jobs``: an MPC with its hang guard
    (:func:`hang_guarded`) on workers that are daemon processes (``dask worker``'s default,
    under its nanny), which may not start the MPC's solver process; every such job failed with
    multiprocessing's "daemonic processes are not allowed to have children". Only the workers
    connected now are asked: one that joins later fails its MPC jobs with the explanation
    (:data:`mpcasv.mpc.deadline.DAEMON_REFUSED`).

    Raises
    ------
    ConfigError
        One line naming the address, how many workers are daemons, the controllers and how
        to start the workers instead.
    """
    from mpcasv.mpc.deadline import DAEMON_FIX

    guarded = hang_guarded(jobs)
    if not guarded:
        return
    answers = client.run(_is_daemon)
    daemons = [w for w, daemon in answers.items() if daemon]
    if daemons:
        raise ConfigError(f"--dask {address}: {len(daemons)} of the cluster's {len(answers)} "
                          "workers are daemon processes (dask worker's default, under its "
                          "nanny), which may not start the MPC's solver process (its hang "
                          f"guard) that the {', '.join(guarded)} jobs need: "
                          f"{DAEMON_FIX}")  # fmt: skip


def connect(address: str):
    """A ``dask.distributed.Client`` of the scheduler at ``address``.

    Raises
    ------
    ConfigError
        No scheduler answers within 20 s (one line naming the address).
    """
    from dask.distributed import Client

    try:
        return Client(address, timeout="20s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise ConfigError(f"--dask {address}: cannot connect to a Dask scheduler: {exc}") from None


def check_dask_cluster(address: str, jobs: list[Job]) -> None:
    """Before a sweep writes anything: the scheduler at ``address`` answers and its workers
    can run ``jobs`` (:func:`check_dask_workers`).

    Raises
    ------
    ConfigError
        As :func:`connect` and :func:`check_dask_workers`.
    """
    client = connect(address)
    try:
        check_dask_workers(client, jobs, address)
    finally:
        client.close()


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
    from dask.distributed import as_completed as dask_completed

    client = connect(address)
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
