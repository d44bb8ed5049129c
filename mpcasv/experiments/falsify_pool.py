"""Running a batch of falsification trials: in this process, or on a local process pool.

Pool workers are started with ``spawn`` and exit if the search process dies, as in
:mod:`mpcasv.experiments.runner`. A run that raises is reported to ``tell`` with its error
(one line, ``Type: message``); nothing else stops the batch.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Executor, ProcessPoolExecutor, wait
from multiprocessing import get_context

from mpcasv.config import ConfigError
from mpcasv.experiments.runner import _watch_parent


@contextlib.contextmanager
def worker_pool(workers: int) -> Iterator[Executor | None]:
    """A spawn-started process pool of ``workers`` processes; None (run here) for 1."""
    if workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers}")
    if workers == 1:
        yield None
        return
    import os

    pool = ProcessPoolExecutor(workers, mp_context=get_context("spawn"),
                               initializer=_watch_parent, initargs=(os.getpid(),))  # fmt: skip
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _guarded(args: tuple) -> tuple[dict | None, str | None]:
    from mpcasv.experiments.falsify import run_trial

    try:
        return run_trial(*args), None
    except Exception as exc:  # the run failed: a finding, recorded with the trial
        return None, f"{type(exc).__name__}: {exc}".replace("\n", " ")


def run_batch(items: list[tuple[object, Callable[[], tuple]]], pool: Executor | None,
              tell: Callable[[object, dict | None, str | None], None]) -> None:  # fmt: skip
    """Run ``items = [(trial, make_args), ...]``; call ``tell(trial, measures, error)`` as each
    finishes (in this process, so the caller's storage is only written from here)."""
    jobs = []
    for trial, make_args in items:
        try:
            jobs.append((trial, make_args()))
        except ConfigError as exc:  # these parameters give no valid scenario
            tell(trial, None, f"invalid scenario: {exc}".replace("\n", " "))
    if pool is None:
        for trial, args in jobs:
            tell(trial, *_guarded(args))
        return
    futures = {pool.submit(_guarded, args): trial for trial, args in jobs}
    while futures:
        done, _ = wait(futures, return_when=FIRST_COMPLETED)
        for fut in done:
            tell(futures.pop(fut), *fut.result())
