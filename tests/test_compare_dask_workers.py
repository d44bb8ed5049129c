"""``mpcasv compare --dask`` on a cluster without a worker: a scheduler alone, or one whose only
worker dies mid-sweep (``kill -9``). Both hung for ever, the progress bar at 0/3 or 1/3:
Dask keeps a task no worker can take waiting for one. Now the command waits a bounded time
(:data:`mpcasv.experiments.dask_runner.WORKER_WAIT_S`, cut to 2 s here) and then refuses
(no worker at the start: exit 2, nothing written) or records the remaining jobs as lost (exit
1, what finished is written; a rerun resumes).

The commands run in subprocesses (a hang is a failed test, after a timeout, not a stuck test
session); the scheduler is a ``distributed.LocalCluster`` without workers in this process,
the worker a ``dask worker --no-nanny`` process (nothing restarts it), killed by SIGKILL.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd
import pytest
from tiny_suite import tiny_suite

distributed = pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[1]
WAIT_S = 2.0
SUITE = tiny_suite()
# mpcasv with the worker wait cut to WAIT_S
MPCASV = (f"import sys, mpcasv.experiments.dask_runner as d; d.WORKER_WAIT_S = {WAIT_S}; "
          "from mpcasv.cli import main; sys.exit(main(sys.argv[1:]))")
# a worker killed as by kill -9 at its second job, once the client has written the first's row
DIES_AT_SECOND_JOB = """
import os, signal, time
from pathlib import Path
import mpcasv.experiments.job_worker as job_worker

def run_job(job, runs, _run_job=job_worker.run_job, _calls=[]):
    _calls.append(job.job_id)
    if len(_calls) > 1:
        parts = Path(os.environ["MPCASV_TEST_OUT"]) / "parts"
        deadline = time.monotonic() + 60
        while not any(parts.glob("*.parquet")) and time.monotonic() < deadline:
            time.sleep(0.05)
        os.kill(os.getpid(), signal.SIGKILL)
    return _run_job(job, runs)

run_job.dies = True
if not getattr(job_worker.run_job, "dies", False):  # (a preload file may run twice)
    job_worker.run_job = run_job
"""


def _env(**extra) -> dict:
    return os.environ | {"PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"} | extra


def _compare(suite: Path, out: Path, address: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", MPCASV, "compare", str(suite), "--out",
                           str(out), "--dask", address, "--quiet", "--no-report"],
                          capture_output=True, text=True, timeout=90, env=_env())  # fmt: skip


def _worker(address: str, tmp_path: Path, preload: str | None = None, **env):
    args = [sys.executable, "-m", "distributed.cli.dask_worker", address, "--no-nanny",
            "--nthreads", "1", "--dashboard-address", "127.0.0.1:0",
            "--local-directory", str(tmp_path / "worker")]  # fmt: skip
    if preload:
        path = tmp_path / "preload_dies.py"
        path.write_text(textwrap.dedent(preload))
        args += ["--preload", str(path)]
    proc = subprocess.Popen(args, cwd=tmp_path, env=_env(**env), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)  # fmt: skip
    try:  # connected before the command starts (its own wait is cut to WAIT_S)
        with distributed.Client(address, timeout="30s") as client:
            client.wait_for_workers(1, timeout=60)
    except BaseException:
        proc.kill()
        proc.wait()
        raise
    return proc


@pytest.fixture
def scheduler():
    """The address of a scheduler without workers."""
    with distributed.LocalCluster(n_workers=0, processes=False, protocol="tcp://",
                                  host="127.0.0.1",
                                  dashboard_address="127.0.0.1:0") as c:  # fmt: skip
        yield c.scheduler_address


@pytest.fixture
def suite(tmp_path) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(SUITE)
    return path


def test_a_scheduler_without_workers_is_refused_after_the_wait(scheduler, suite, tmp_path):
    out = tmp_path / "out"
    r = _compare(suite, out, scheduler)
    assert r.returncode == 2, r.stderr
    said = r.stderr.strip().splitlines()
    assert len(said) == 2, r.stderr  # the wait said, then the one-line refusal
    assert said[0].startswith(f"mpcasv: waiting up to {WAIT_S:g} s for a worker")
    assert said[1].startswith(f"mpcasv compare: error: --dask {scheduler}: no worker")
    assert f"{WAIT_S:g} s" in said[1]
    assert not out.exists()  # refused before anything was written


def test_jobs_are_lost_when_the_only_worker_dies_and_a_rerun_resumes(scheduler, suite,
                                                                     tmp_path):  # fmt: skip
    out = tmp_path / "out"
    worker = _worker(scheduler, tmp_path, DIES_AT_SECOND_JOB, MPCASV_TEST_OUT=str(out))
    try:
        r = _compare(suite, out, scheduler)
    finally:
        worker.kill()
        worker.wait()
    assert worker.returncode == -9  # it died by SIGKILL, as the preload says
    assert r.returncode == 1, r.stdout + r.stderr
    assert f"no Dask worker for {WAIT_S:g} s" in r.stdout
    assert "2 jobs lost with their worker: rerun the same command to resume" in r.stdout
    sweep = json.loads((out / "sweep.json").read_text())
    assert (sweep["ok"], sweep["lost"], sweep["ran"]) == (1, 2, 1)
    df = pd.read_parquet(out / "results.parquet")  # what finished is written
    assert len(df) == 1 and (df["status"] == "ok").all()

    worker = _worker(scheduler, tmp_path)  # a worker again: the rerun runs the lost jobs
    try:
        r = _compare(suite, out, scheduler)
    finally:
        worker.kill()
        worker.wait()
    assert r.returncode == 0, r.stdout + r.stderr
    sweep = json.loads((out / "sweep.json").read_text())
    assert (sweep["ok"], sweep["lost"], sweep["already_done"]) == (2, 0, 1)
    assert (pd.read_parquet(out / "results.parquet")["status"] == "ok").sum() == 3
