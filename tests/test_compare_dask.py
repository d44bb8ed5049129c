"""Dask without a shared file system (issue 12 item 7): each job's row comes back through Dask
and the client writes the parts and the results table; the run folders go where the user says
(a path or an fsspec URL) or stay in the worker's working directory.

The cluster is a local ``distributed.LocalCluster`` of worker processes (Nannies) whose
working directory is another folder (a worker preload changes it), and which cannot write
results parts (the preload makes :func:`mpcasv.experiments.store.write_part` raise in the
worker): a complete table can then only come from the client.
"""

from __future__ import annotations

import dataclasses
import json
import textwrap
from pathlib import Path

import pandas as pd
import pytest
from tiny_suite import tiny_suite

from mpcasv.controllers import load_preset
from mpcasv.experiments.runner import run_suite
from mpcasv.experiments.suite_file import SCENARIOS_DIR

distributed = pytest.importorskip("distributed")

CASE3 = SCENARIOS_DIR / "case3.toml"
SUITE = tiny_suite()

PRELOAD = """
import os
import mpcasv.experiments.runner as runner
import mpcasv.experiments.store as store

def _refuse(*args, **kwargs):
    raise RuntimeError("a worker wrote a results part")

def dask_setup(worker):
    os.makedirs({where!r}, exist_ok=True)
    os.chdir({where!r})
    store.write_part = runner.write_part = _refuse
"""


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    where = tmp_path_factory.mktemp("worker-cwd")
    preload = textwrap.dedent(PRELOAD).format(where=str(where))
    # dashboard_address None still serves HTTP, on 8787: taken by a parallel test's cluster,
    # distributed's retry leaked a socket (ResourceWarning); a free port on loopback instead
    with distributed.LocalCluster(processes=True, n_workers=1, threads_per_worker=1,
                                  dashboard_address="127.0.0.1:0",
                                  preload=[preload]) as c:  # fmt: skip
        yield c, where


def _write_a_part(out):
    from mpcasv.experiments import runner

    runner.write_part(out, {"job_id": "x", "status": "ok"})


def _suite(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(SUITE)
    return path


def test_dask_workers_in_another_directory_give_a_complete_resumable_table(cluster, tmp_path):
    c, worker_cwd = cluster
    with distributed.Client(c.scheduler_address) as client:  # the preload really ran
        assert client.run(lambda: __import__("os").getcwd()) == {
            w: str(worker_cwd) for w in client.scheduler_info()["workers"]
        }
        with pytest.raises(RuntimeError, match="a worker wrote a results part"):
            client.submit(_write_a_part, tmp_path, pure=False).result()
    out = tmp_path / "out"
    stats, exp, df = run_suite(_suite(tmp_path), out, dask=c.scheduler_address, quiet=True,
                               report=False)  # fmt: skip
    jobs = [j.job_id for j in exp.jobs]
    assert stats.ok == len(jobs) == 3 and stats.lost == 0
    assert list(df["job_id"]) == jobs and (df["status"] == "ok").all()
    assert df["min_range_m"].notna().all()
    assert sorted(p.stem for p in (out / "parts").glob("*.parquet")) == sorted(jobs)
    # the run folders stayed in the worker's working directory; nothing of them in DIR
    assert not (out / "runs").exists()
    for job, run_dir in zip(exp.jobs, df["run_dir"], strict=True):
        assert Path(run_dir) == worker_cwd / "mpcasv-runs" / "tiny" / job.run_name
        assert (Path(run_dir) / "metrics.json").is_file()
    assert "worker's directory" in stats.runs

    # resumable: a finished sweep runs nothing; a lost part is rerun, the table is whole again
    stats, _, again = run_suite(_suite(tmp_path), out, dask=c.scheduler_address, quiet=True,
                                report=False)  # fmt: skip
    assert stats.ran == 0 and stats.already_done == 3
    pd.testing.assert_frame_equal(again, df)
    (out / "parts" / f"{jobs[1]}.parquet").unlink()
    stats, _, again = run_suite(_suite(tmp_path), out, dask=c.scheduler_address, quiet=True,
                                report=False)  # fmt: skip
    assert stats.ran == 1 and stats.already_done == 2
    assert list(again["job_id"]) == jobs and (again["status"] == "ok").all()
    cols = ["job_id", "seed", "min_range_m", "energy_J", "run_dir"]
    pd.testing.assert_frame_equal(again[cols], df[cols])


def test_run_folders_go_to_the_named_fsspec_url(tmp_path):
    """``--runs-dir file://...``: the folder is written locally, then put through fsspec; the
    row records the URL."""
    remote = tmp_path / "remote"
    out = tmp_path / "out"
    stats, exp, df = run_suite(_suite(tmp_path), out, workers=1, quiet=True, report=False,
                               runs_dir=f"file://{remote}")  # fmt: skip
    assert stats.runs == f"file://{remote}" and (df["status"] == "ok").all()
    for job, run_dir in zip(exp.jobs, df["run_dir"], strict=True):
        assert run_dir == f"file://{remote / job.run_name}"
        assert {p.name for p in (remote / job.run_name).iterdir()} >= {
            "metrics.json", "run.json", "timeseries.parquet"}  # fmt: skip
        # the controller's parameters as the job ran them (its preset and overrides)
        params = json.loads((remote / job.run_name / "run.json").read_text())["params"]
        assert params == dataclasses.asdict(load_preset(job.controller, job.preset,
                                                        dict(job.overrides)))  # fmt: skip
    assert not (out / "runs").exists()


MPC_SUITE = f"""
name = "tiny-mpc"
scenarios = ["{CASE3}"]
duration = 5.0
seeds = [0]
current = ["off"]
estimator = ["scenario"]
plots = "none"

[[controllers]]
label = "mpc"
name = "mpc-single"
overrides = {{ "solver.compiled" = false }}
"""


def test_mpc_jobs_on_daemon_workers_are_refused_before_any_is_submitted(cluster, tmp_path):
    """``dask worker``'s workers are daemons under their nanny and may not start the MPC's
    solver process: every MPC job failed with multiprocessing's "daemonic processes are not
    allowed to have children". Refused up front, in one line saying how to start them."""
    from mpcasv.config import ConfigError

    c, _ = cluster
    path = tmp_path / "mpc.toml"
    path.write_text(MPC_SUITE)
    out = tmp_path / "out"
    with pytest.raises(ConfigError, match="DASK_DISTRIBUTED__WORKER__DAEMON=False") as info:
        run_suite(path, out, dask=c.scheduler_address, quiet=True, report=False)
    said = str(info.value)
    assert "\n" not in said and "mpc-single" in said
    assert "1 of the cluster's 1 workers are daemon processes" in said
    assert not out.exists()  # refused before anything was written


def test_an_mpc_without_its_hang_guard_runs_on_daemon_workers(cluster, tmp_path):
    """``solver.hang_s = 0``: the solves stay in the worker's process, which a daemon may
    run; such a suite is not refused."""
    c, _ = cluster
    path = tmp_path / "mpc.toml"
    path.write_text(MPC_SUITE.replace('"solver.compiled" = false',
                                      '"solver.compiled" = false, "solver.hang_s" = 0'))
    stats, _, df = run_suite(path, tmp_path / "out", dask=c.scheduler_address, quiet=True,
                             report=False, runs_dir=str(tmp_path / "runs"))  # fmt: skip
    assert stats.ok == 1 and (df["status"] == "ok").all(), df.get("error")


def test_mpc_jobs_run_on_workers_started_as_the_refusal_says(tmp_path):
    import dask

    path = tmp_path / "mpc.toml"
    path.write_text(MPC_SUITE)
    with dask.config.set({"distributed.worker.daemon": False}), distributed.LocalCluster(
            processes=True, n_workers=1, threads_per_worker=1,
            dashboard_address="127.0.0.1:0") as c:  # fmt: skip
        stats, exp, df = run_suite(path, tmp_path / "out", dask=c.scheduler_address,
                                   quiet=True, report=False,
                                   runs_dir=str(tmp_path / "runs"))  # fmt: skip
    assert stats.ok == 1 and (df["status"] == "ok").all(), df.get("error")
