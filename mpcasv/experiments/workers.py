"""How many local worker processes a command starts (``--workers`` of ``compare``,
``falsify`` and ``tune controller``).

A local pool never has more processes than there are jobs to run (:func:`pool_size`; the
command says so when it starts fewer than asked), and ``--workers`` above
:data:`MAX_PER_CPU` times the machine's CPU count is refused before anything runs
(:func:`check_workers`): ``compare --workers 1000`` on a one-job suite started 1000 Python
interpreters (the machine stalled, semaphores leaked). With ``--dask`` the cluster's workers
run the jobs: ``--workers`` given with it is refused (it was silently ignored).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading

from mpcasv.config import ConfigError

#: local worker processes allowed per CPU (oversubscription beyond this only adds memory and
#: start-up time: every job is CPU-bound)
MAX_PER_CPU = 4


def cpu_count() -> int:
    """CPUs this process may use (the affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except AttributeError:  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


def check_workers(workers: int | None, dask: str | None = None, option: str = "--workers") -> int:
    """The number of local worker processes to use: ``workers``, or by default (None) the
    CPUs this process may use (:func:`cpu_count`).

    Raises
    ------
    ConfigError
        ``workers`` given with ``dask`` (the cluster's workers run the jobs: it would be
        ignored); ``workers < 1``; more than ``MAX_PER_CPU * cpu_count()`` (the message
        names the option, the value and the CPU count).
    """
    if workers is None:
        return cpu_count()
    if dask is not None:
        raise ConfigError(f"{option} {workers} with --dask {dask}: the Dask cluster's workers "
                          f"run the jobs (their number is the cluster's: 'dask worker "
                          f"--nworkers N' on each machine); {option} is for local processes "
                          "only: leave it out")  # fmt: skip
    if workers < 1:
        raise ConfigError(f"{option} {workers}: must be >= 1")
    limit = MAX_PER_CPU * cpu_count()
    if workers > limit:
        raise ConfigError(f"{option} {workers}: more than {MAX_PER_CPU} x the {cpu_count()} "
                          f"CPUs of this machine ({limit}); each worker is a process running "
                          f"CPU-bound jobs: use at most {limit}")  # fmt: skip
    return workers


def pool_size(workers: int, jobs: int) -> int:
    """The processes a local pool starts for ``jobs`` jobs: never more than the jobs."""
    return max(1, min(workers, jobs))


def reduced_note(workers: int, used: int, why: str = "the number of jobs to run") -> str:
    """`` (--workers N reduced to M, the number of jobs to run)`` when fewer processes start
    than asked, else ``""`` (appended to the command's progress line)."""
    return f" (--workers {workers} reduced to {used}, {why})" if used < workers else ""


@contextlib.contextmanager
def spawning_quietly():
    """Ignore SIGINT in this process while the block starts worker processes (main thread
    only; elsewhere nothing changes). A spawned worker inherits the ignored SIGINT through
    its exec and Python leaves it ignored, so a Ctrl-C, which the terminal sends to the
    whole process group, reaches only this process, which stops the pool: it no longer
    interrupts the workers' start-up and imports (38-73 lines of their tracebacks on stderr
    under ``falsify`` and ``tune controller``: a new user, session 47). A Ctrl-C within the
    block itself is lost (the block lasts as long as the processes take to start)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
