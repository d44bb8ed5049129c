"""One job of a sweep, on a worker: simulate it, write its run folder and return its row.

:func:`run_job` is what a worker runs (in this process, on a local process pool or on Dask):
it simulates the job (:func:`simulate_job`), writes the run folder under the runs location (a
local folder, or an fsspec URL it is uploaded to) and returns the job's row of the results
table: its description, outcome (``ok`` or ``error`` with the traceback) and metrics.
:func:`timeout_row` is the row of a job ended at its time limit. Nothing here writes the
results table: the client does (:mod:`mpcasv.experiments.runner`).
"""

from __future__ import annotations

import datetime
import json
import os
import socket
import time
import traceback
from pathlib import Path

from mpcasv.experiments.metrics import auv_column
from mpcasv.experiments.suite import Job
from mpcasv.experiments.sweep_folder import is_url


def _describe(job: Job) -> dict:
    """The description columns of a job's row."""
    row = {
        "job_id": job.job_id, "index": job.index, "suite": job.suite, "scenario": job.scenario,
        "label": job.label, "variant": job.variant, "controller": job.controller,
        "preset": job.preset or "default", "overrides": json.dumps(dict(job.overrides)),
        "current_N": (job.current_realised or job.current)[0],  # simulated (drawn) current
        "current_E": (job.current_realised or job.current)[1],
        "current": job.current_axis, "realisation": job.realisation,
        "estimator": job.estimator, "seed": job.seed, "n_auv": job.n_auv,
        "auv_names": ",".join(job.auv_names),
    }  # fmt: skip
    for k, v in job.overrides:
        row[f"param.{k}"] = json.dumps(v) if isinstance(v, (list, dict)) else v
    return row


def _metric_columns(metrics: dict) -> dict:
    """metrics.json values as columns; per-AUV lists expanded by :func:`auv_column`."""
    out = {}
    for k, v in metrics.items():
        if isinstance(v, list):
            out |= {auv_column(k, i): (float("nan") if x is None else x) for i, x in enumerate(v)}
        else:
            out[k] = float("nan") if v is None else v
    return out


def simulate_job(job: Job, run_dir: Path) -> dict:
    """Simulate one job and write its run folder; return its metrics as computed (an
    infinite value stays infinite: ``revisit_interval_max_s`` of an AUV never reliably fixed,
    the worst a run can do, which the paired statistics keep; metrics.json, JSON, has null
    there, and until session 45 the results table took that null, so such runs dropped out
    of the pairs as missing)."""
    from mpcasv.controllers import Boat, make_controller
    from mpcasv.experiments.metrics import compute_metrics
    from mpcasv.sim.record import params_record, write_run
    from mpcasv.sim.simulator import simulate

    scenario, realisation = job.realised_scenario()  # the seed's draw of its [uncertain] table
    boat = Boat.of_scenario(scenario)  # one vessel per run: the simulator's and the MPC's
    controller = make_controller(job.controller, job.n_auv, job.preset, dict(job.overrides),
                                 boat=boat)  # fmt: skip
    if hasattr(controller, "say_current"):  # the metric and the sweep's last lines say it
        controller.say_current = False
    result = simulate(scenario, controller, job.seed, job.estimator)
    extra = {"job_id": job.job_id, "suite": job.suite, "variant": job.variant,
             "preset": job.preset, "overrides": dict(job.overrides),
             "estimator": job.estimator, "current": job.current,
             "realisation": realisation.as_dict(), "boat": boat.describe(),
             "params": params_record(controller)}  # fmt: skip
    metrics = compute_metrics(result)
    write_run(result, run_dir, metrics, plots=job.plots, extra=extra)
    return metrics


def _run_into(job: Job, runs: str) -> tuple[dict, str]:
    """Simulate ``job`` and write its run folder under ``runs``; (metrics, where it is).

    A local ``runs`` (relative: to this worker's working directory) gets the folder directly
    (written atomically by :func:`mpcasv.sim.record.write_run`); a URL gets a folder written
    here in a temporary directory and then uploaded with fsspec (replacing an old one).
    """
    if not is_url(runs):
        run_dir = Path(runs).expanduser().resolve() / job.run_name
        return simulate_job(job, run_dir), str(run_dir)
    import tempfile

    import fsspec

    fs, root = fsspec.core.url_to_fs(runs)
    target = f"{root.rstrip('/')}/{job.run_name}"
    with tempfile.TemporaryDirectory(prefix="mpcasv-run-") as tmp:
        metrics = simulate_job(job, Path(tmp) / job.run_name)
        if fs.exists(target):
            fs.rm(target, recursive=True)
        fs.put(str(Path(tmp) / job.run_name), target, recursive=True)
    return metrics, fs.unstrip_protocol(target)


def run_job(job: Job, runs: str) -> dict:
    """Run one job on a worker: write its run folder under ``runs`` and return its row.

    Writes nothing else: the caller (the client) writes the row
    (:func:`~mpcasv.experiments.runner.finish_job`).
    Exceptions of the job are caught and recorded in the row (``status = "error"``);
    ``KeyboardInterrupt`` and other ``BaseException`` propagate (no row: rerun on resume).
    """
    t0 = time.perf_counter()
    row = _describe(job)
    try:
        metrics, where = _run_into(job, runs)
        row |= {"status": "ok", "error": None, "run_dir": where}
        row |= _metric_columns(metrics)
    except Exception:
        row |= {"status": "error", "error": traceback.format_exc(), "run_dir": None}
    row |= {
        "wall_s": time.perf_counter() - t0,
        "finished_at": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "worker": f"{socket.gethostname()}:{os.getpid()}",
    }
    return row


def timeout_row(job: Job, limit: float) -> dict:
    """The row of a job ended at its time limit (``status = "timeout"``)."""
    return _describe(job) | {
        "status": "timeout", "run_dir": None, "wall_s": limit, "worker": None,
        "error": f"job ended after its time limit of {limit:g} s (--job-timeout)",
        "finished_at": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }  # fmt: skip
