"""Sweeps on a Dask cluster (``--dask ADDRESS`` of ``compare`` and ``tune controller``): the
workers need no file system shared with this machine, each job's row comes back through Dask
and is written here (docs/experiments.md "Dask"). A Dask task cannot be ended from outside, so
a cluster has no per-job time limit (``--job-timeout`` is refused with ``--dask``); an MPC's
hang guard still abandons a hung solve, in a solver process the worker must be allowed to
start (:func:`check_dask_workers`).

Dask keeps a task that no worker can take waiting for one, for ever: a sweep on a scheduler
without workers, or whose workers all died (``kill -9``), sat at 0/12 or 3/12 with no word. A
sweep now waits at most :data:`WORKER_WAIT_S` for a worker, saying so, then gives up: at the
start it is refused (:func:`wait_for_a_worker`, nothing written), mid-sweep the jobs not
finished are recorded as lost (:func:`run_dask`; a rerun resumes). The wait decides only
whether jobs run, never what a run computes.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from mpcasv.config import ConfigError
from mpcasv.experiments.job_worker import run_job
from mpcasv.experiments.runner import SweepStats, finish_job, record_row
from mpcasv.experiments.suite import Job
from mpcasv.wording import count

__all__ = ["WORKER_WAIT_S", "check_dask_cluster", "check_dask_workers", "connect",
           "hang_guarded", "run_dask", "wait_for_a_worker", "worker_count"]  # fmt: skip

#: how long a sweep waits for a Dask worker (s) when the scheduler has none: at the start
#: (workers started with the scheduler take a few seconds to join) and mid-sweep (a
#: restarted worker takes as long); then it gives up (module docstring)
WORKER_WAIT_S = 60.0
#: how often a sweep looks for finished jobs while none is ready (s)
POLL_S = 0.1
#: how often a sweep asks the scheduler for its workers while no job finishes (s)
WORKER_CHECK_S = 1.0


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


def worker_count(client) -> int:
    """The workers connected to ``client``'s scheduler now; 0 when the scheduler does not
    answer (it is gone: no worker of it will run a job either)."""
    try:
        return len(client.nthreads())
    except (OSError, TimeoutError, RuntimeError):  # (a closed pool: "ConnectionPool is closed")
        return 0


def wait_for_a_worker(client, address: str) -> int:
    """The number of workers of the scheduler at ``address``, once it has one: when it has
    none, say so on stderr and wait up to :data:`WORKER_WAIT_S` for the first.

    Raises
    ------
    ConfigError
        No worker joined within :data:`WORKER_WAIT_S` (one line naming the address and how
        to start workers).
    """
    n = worker_count(client)
    if n:
        return n
    print(f"mpcasv: waiting up to {WORKER_WAIT_S:g} s for a worker to join the Dask scheduler "
          f"at {address} (it has none)", file=sys.stderr, flush=True)  # fmt: skip
    try:
        client.wait_for_workers(1, timeout=WORKER_WAIT_S)
    except TimeoutError:  # distributed's WorkerStartTimeoutError
        raise ConfigError(f"--dask {address}: no worker joined the scheduler in "
                          f"{WORKER_WAIT_S:g} s, so nothing would run the jobs: start workers "
                          f"('dask worker {address} ...', docs/experiments.md \"Dask\") and "
                          "rerun") from None  # fmt: skip
    return max(worker_count(client), 1)


def check_dask_workers(client, jobs: list[Job], address: str) -> None:
    """Refuse a cluster that has no worker after :func:`wait_for_a_worker`'s wait, or whose
    workers cannot run ``jobs``: an MPC with its hang guard
    (:func:`hang_guarded`) on workers that are daemon processes (``dask worker``'s default,
    under its nanny), which may not start the MPC's solver process; every such job failed with
    multiprocessing's "daemonic processes are not allowed to have children". Only the workers
    connected now are asked: one that joins later fails its MPC jobs with the explanation
    (:data:`mpcasv.mpc.deadline.DAEMON_REFUSED`).

    Raises
    ------
    ConfigError
        As :func:`wait_for_a_worker`; or one line naming the address, how many workers are
        daemons, the controllers and how to start the workers instead.
    """
    from mpcasv.mpc.deadline import DAEMON_FIX

    if not jobs:  # a finished sweep rerun for its report: no worker needed (a review)
        return
    wait_for_a_worker(client, address)
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
    """Before a sweep writes anything: the scheduler at ``address`` answers, has a worker
    (after up to :data:`WORKER_WAIT_S`) and its workers can run ``jobs``
    (:func:`check_dask_workers`).

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
    worker has no row (rerun on resume); so has every job not finished when the scheduler
    has had no worker for :data:`WORKER_WAIT_S` (its tasks are cancelled: the sweep ends).

    Raises
    ------
    ConfigError
        No scheduler answers at ``address``; or it has no worker, or its workers cannot run
        the jobs (:func:`check_dask_workers`).
    """
    from dask.distributed import as_completed as dask_completed

    client = connect(address)
    try:
        check_dask_workers(client, jobs, address)
        stats.workers = worker_count(client)
        left = {client.submit(run_job, job, runs, pure=False, retries=0): job
                for job in jobs}  # fmt: skip (the jobs not yet taken)
        done = dask_completed(list(left))
        no_worker_since, next_check = None, time.monotonic() + WORKER_CHECK_S
        while left:
            ready = done.next_batch(block=False)
            for fut in ready:
                _take(left.pop(fut), fut, out, stats, bar)
            if ready:
                continue
            time.sleep(POLL_S)
            now = time.monotonic()
            if now < next_check:
                continue
            next_check = now + WORKER_CHECK_S
            if worker_count(client):
                if no_worker_since is not None:
                    bar.write(f"the Dask scheduler at {address} has a worker again")
                no_worker_since = None
            elif no_worker_since is None:
                no_worker_since = now
                bar.write(f"the Dask scheduler at {address} has no worker: waiting up to "
                          f"{WORKER_WAIT_S:g} s for one")  # fmt: skip
            elif now - no_worker_since >= WORKER_WAIT_S:  # give up: the jobs left are lost
                client.cancel(list(left))
                stats.lost += len(left)
                bar.write(f"lost {count(len(left), 'job')} not finished: no Dask worker for "
                          f"{WORKER_WAIT_S:g} s at {address}; rerun the same command to "
                          "resume")  # fmt: skip
                bar.update(len(left))
                break
    finally:
        client.close()


def _take(job: Job, fut, out: Path, stats: SweepStats, bar) -> None:
    """Write the row of ``job``'s finished future ``fut`` (or count it lost), advance ``bar``;
    the task is released (a worker dying later would otherwise have it computed again)."""
    try:
        row = fut.result()  # the row comes back through Dask: written here
    except Exception as exc:  # the machinery failed (e.g. KilledWorker): no row
        stats.lost += 1
        bar.write(f"lost {job.run_name}: {type(exc).__name__}: {exc} (rerun to resume)")
    else:
        record_row(stats, job, finish_job(out, row))
    finally:
        fut.release()
    bar.set_postfix(errors=stats.errors, refresh=False)
    bar.update(1)
