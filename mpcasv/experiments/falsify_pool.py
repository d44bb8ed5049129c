"""Running a batch of falsification trials: in this process, or on a local process pool.

Pool workers are started with ``spawn`` and exit if the search process dies, as in
:mod:`mpcasv.experiments.runner`. A run that raises is reported to ``tell`` with its error
(one line, ``Type: message``); nothing else stops the batch. With a ``timeout`` (s of wall
clock per run) the runs go to a pool even for one worker: a run still going after
``timeout`` s (a solver that never returns) is reported as an error, the pool's processes
are ended and the batch's other unfinished runs start again on a fresh pool. The timeout
decides only whether a run gives a result, never what a run does.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Executor, ProcessPoolExecutor, wait
from multiprocessing import get_context

from mpcasv.config import ConfigError
from mpcasv.experiments.runner import _watch_parent


class WorkerPool:
    """A spawn-started process pool of ``workers`` processes, or None (run here) when
    ``workers == 1`` and there is no timeout. Use as a context manager."""

    def __init__(self, workers: int, timeout: float | None = None):
        if workers < 1:
            raise ConfigError(f"--workers must be >= 1, got {workers}")
        if timeout is not None and timeout <= 0:
            raise ConfigError(f"--timeout must be > 0, got {timeout}")
        self.workers, self.timeout = workers, timeout
        self.pool: Executor | None = None

    def __enter__(self) -> WorkerPool:
        if self.workers > 1 or self.timeout is not None:
            self.pool = self._new()
        return self

    def __exit__(self, kind, *exc) -> None:
        if self.pool is None:
            return
        if kind is None:
            self.pool.shutdown(wait=True, cancel_futures=True)
        else:  # Ctrl-C or a failure: the runs in flight are ended, not waited for (the
            self._kill()  # workers ignore SIGINT: spawning_quietly)

    def _new(self) -> Executor:
        """A fresh pool whose processes have started (untimed): a run's deadline counts the
        run, not the spawn and imports of a process (seconds on a loaded machine; after a
        restart they made a quick run miss a 3-s deadline in a test under load)."""
        from mpcasv.experiments.workers import spawning_quietly

        pool = ProcessPoolExecutor(self.workers, mp_context=get_context("spawn"),
                                   initializer=_watch_parent, initargs=(os.getpid(),))  # fmt: skip
        with spawning_quietly():  # the workers ignore Ctrl-C: this process stops them
            ready = [pool.submit(_ready) for _ in range(self.workers)]
        wait(ready)
        return pool

    def _kill(self) -> None:
        """End every worker process now."""
        self.pool.shutdown(wait=False, cancel_futures=True)
        for child in multiprocessing.active_children():
            child.kill()
            child.join()

    def restart(self) -> None:
        """End every worker process (a run that does not return) and start a fresh pool."""
        self._kill()
        self.pool = self._new()


def _ready() -> None:
    """A worker's first job: nothing (the process is up)."""


def _guarded(args: tuple) -> tuple[dict | None, str | None]:
    from mpcasv.experiments.falsify import run_trial

    try:
        return run_trial(*args), None
    except Exception as exc:  # the run failed: a finding, recorded with the trial
        return None, f"{type(exc).__name__}: {exc}".replace("\n", " ")


def run_batch(items: list[tuple[object, Callable[[], tuple]]], workers: WorkerPool,
              tell: Callable[[object, dict | None, str | None], None]) -> None:  # fmt: skip
    """Run ``items = [(trial, make_args), ...]``; call ``tell(trial, measures, error)`` as each
    finishes (in this process, so the caller's storage is only written from here)."""
    jobs = []
    for trial, make_args in items:
        try:
            jobs.append((trial, make_args()))
        except ConfigError as exc:  # these parameters give no valid scenario
            tell(trial, None, f"invalid scenario: {exc}".replace("\n", " "))
    if workers.pool is None:
        for trial, args in jobs:
            tell(trial, *_guarded(args))
        return
    queue, inflight = list(jobs), {}  # future -> (trial, args, deadline)
    limit = workers.timeout if workers.timeout is not None else float("inf")
    while queue or inflight:
        while queue and len(inflight) < workers.workers:  # each starts at once: own deadline
            trial, args = queue.pop(0)
            fut = workers.pool.submit(_guarded, args)
            inflight[fut] = (trial, args, time.monotonic() + limit)
        soonest = min(d for _, _, d in inflight.values())
        left = None if soonest == float("inf") else max(soonest - time.monotonic(), 0.0)
        done, _ = wait(inflight, timeout=left, return_when=FIRST_COMPLETED)
        for fut in done:
            tell(inflight.pop(fut)[0], *fut.result())
        now = time.monotonic()
        late = [f for f, (_, _, d) in inflight.items() if d <= now and not f.done()]
        if late:  # a run that does not return: record it, end the pool, rerun the others
            for fut in late:
                tell(inflight.pop(fut)[0], None,
                     f"timeout: the run did not finish in {workers.timeout:g} s")  # fmt: skip
            queue = [(t, a) for t, a, _ in inflight.values()] + queue
            inflight = {}
            workers.restart()
