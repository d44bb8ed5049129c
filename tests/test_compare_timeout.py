"""Issue 16 item 5: in ``mpcasv compare`` a job past its time limit is ended and recorded
(``status = "timeout"``) and the sweep goes on."""

from __future__ import annotations

import dataclasses
import signal
import time
from concurrent.futures import TimeoutError as FutureTimeout

import pandas as pd

from mpcasv.config import DURATION_MAX
from mpcasv.experiments.runner import SweepStats, make_pool, pending_jobs, run_jobs
from mpcasv.experiments.store import write_results
from mpcasv.experiments.suite import expand
from mpcasv.experiments.workers import spawning_quietly


def test_a_job_past_its_time_limit_is_ended_and_the_sweep_goes_on(tmp_path):
    quick = expand("quick")
    jobs = sorted(pending_jobs(quick, tmp_path), key=lambda j: j.index)[:3]
    # one job that would run for hours (a week of simulated time, the longest a scenario may
    # last): it stands for a hung solve
    endless = dataclasses.replace(jobs[1], duration=DURATION_MAX, realisation="")  # "": no check
    # against the expansion's realisation (the duration is part of the realised scenario)
    jobs = [jobs[0], endless, jobs[2]]
    stats = SweepStats("quick", len(jobs), 0)
    t0 = time.perf_counter()
    run_jobs(jobs, tmp_path, stats, workers=2, quiet=True, job_timeout=25.0)
    took = time.perf_counter() - t0
    table = write_results(tmp_path, jobs).set_index("job_id")
    assert table.loc[endless.job_id, "status"] == "timeout"
    assert "time limit of 25 s" in table.loc[endless.job_id, "error"]
    assert pd.isna(table.loc[endless.job_id, "run_dir"])
    for job in (jobs[0], jobs[2]):
        assert table.loc[job.job_id, "status"] == "ok"
    assert stats.ran == 3 and stats.ok == 2 and stats.errors == 1 and stats.lost == 0
    assert took < 120.0, f"the sweep took {took:.0f} s"


def test_a_worker_started_after_a_timeout_ignores_ctrl_c():
    """The first workers start under ``spawning_quietly``; the one Pebble starts in place of
    a worker it ended at a job timeout does not, yet runs its jobs with SIGINT ignored
    (Pebble's worker routine ignores it): a Ctrl-C, which reaches the whole process group,
    stops the sweep without the replacement's traceback. docs/experiments.md said otherwise
    until session 49; this pins what it says now."""
    pool = make_pool(1)
    try:
        with spawning_quietly():
            first = pool.schedule(signal.getsignal, (signal.SIGINT,))
            assert first.result(timeout=60) == signal.SIG_IGN
        hung = pool.schedule(time.sleep, (60.0,), timeout=1.0)
        try:
            hung.result(timeout=60)
            raise AssertionError("the job past its time limit was not ended")
        except FutureTimeout:
            pass
        replacement = pool.schedule(signal.getsignal, (signal.SIGINT,))
        assert replacement.result(timeout=60) == signal.SIG_IGN
    finally:
        pool.stop()
        pool.join()
