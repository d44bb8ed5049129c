"""Crash safety: a sweep whose runner process is killed, with one job that raises, resumes to
completion with every job present exactly once and the failed job recorded with its error."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import pandas as pd

from mpcasv.cli import main
from mpcasv.experiments.runner import pending_jobs
from mpcasv.experiments.suite import expand

QUICK = expand("quick")
FAILING = pending_jobs(QUICK, QUICK.path.parent / "no-such-dir")[0]  # the first job to run

# The runner in a child process, with one job made to raise and every job slowed down a
# little (so that the kill lands in the middle of the sweep).
DRIVER = textwrap.dedent("""
    import os, sys, time
    from mpcasv.experiments import job_worker
    real = job_worker.simulate_job

    def simulate_job(job, run_dir):
        if job.job_id == os.environ["FAIL_JOB"]:
            raise RuntimeError("injected failure")
        time.sleep(0.3)
        return real(job, run_dir)

    job_worker.simulate_job = simulate_job
    from mpcasv.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def _runner(tmp_path, out):
    driver = tmp_path / "driver.py"
    driver.write_text(DRIVER)
    env = os.environ | {"FAIL_JOB": FAILING.job_id}
    # --job-timeout 0: the jobs run in this process, where the driver's patch is (with a
    # limit, --workers 1 is a pool of one spawned process, which would not see it)
    cmd = [sys.executable, str(driver), "compare", "quick", "--out", str(out), "--workers", "1",
           "--job-timeout", "0", "--quiet", "--no-report"]  # fmt: skip
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def test_killed_sweep_resumes_with_every_job_exactly_once(tmp_path):
    out = tmp_path / "sweep"
    parts = out / "parts"
    proc = _runner(tmp_path, out)
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and proc.poll() is None:
        if parts.exists() and len(list(parts.glob("*.parquet"))) >= 4:
            break
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()  # still running: killed mid-sweep
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stdout.close()  # (not read: a child it left may still hold them)
    proc.stderr.close()
    before = {p.stem for p in parts.glob("*.parquet")}
    assert 4 <= len(before) < len(QUICK.jobs)
    assert FAILING.job_id in before  # the failing job ran first and was recorded

    proc = _runner(tmp_path, out)  # resume: the same command
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 1, stderr.decode()  # one job failed
    stats = json.loads((out / "sweep.json").read_text())
    assert stats["already_done"] == len(before) and stats["ran"] == len(QUICK.jobs) - len(before)

    df = pd.read_parquet(out / "results.parquet")
    assert list(df["job_id"]) == [j.job_id for j in QUICK.jobs]  # each exactly once, in order
    assert sorted(p.stem for p in parts.glob("*.parquet")) == sorted(df["job_id"])
    err = df[df["status"] == "error"]
    assert list(err["job_id"]) == [FAILING.job_id]
    assert "RuntimeError: injected failure" in err["error"].iloc[0]
    # the resume did not rerun the failed job; it still names it (it printed nothing, and
    # exited 1, on a rerun of a sweep whose every error was recorded before: session 47)
    said = [ln for ln in stdout.decode().splitlines() if "error in" in ln]
    assert said == [f"  error in {FAILING.run_name} (recorded before; --retry-errors reruns "
                    "it): RuntimeError: injected failure"], stdout.decode()
    ok = df[df["status"] == "ok"]
    assert len(ok) == len(QUICK.jobs) - 1 and ok["min_range_m"].notna().all()
    for run_dir in ok["run_dir"]:
        assert (out / run_dir / "metrics.json").exists()

    # --retry-errors reruns only the failed job (here without the injected failure)
    assert main(["compare", "quick", "--out", str(out), "--workers", "1", "--quiet",
                 "--no-report", "--retry-errors"]) == 0  # fmt: skip
    stats = json.loads((out / "sweep.json").read_text())
    assert stats["ran"] == 1
    df = pd.read_parquet(out / "results.parquet")
    assert list(df["job_id"]) == [j.job_id for j in QUICK.jobs] and (df["status"] == "ok").all()
