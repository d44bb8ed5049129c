"""``mpcasv bench compare``: the speed-up of 2 local workers over 1 on the same suite.

Each configuration runs as its own ``mpcasv compare SUITE --workers N`` process into a fresh
folder (so nothing is resumed and each pays its own start-up, as a user would), alternating
1 and 2 workers ``--repeat`` times. Two figures per configuration: the jobs phase (from the
first job submitted to the last written, ``sweep.json``) and the whole command (imports,
suite validation, worker start-up, consolidation; the report is skipped). The results of the
two configurations are checked to be identical (timings aside). The cores are shared with
other users' processes, so the speed-up the machine itself offers two processes at that moment
is probed before and after (a fixed pure-Python loop in 2 processes vs 1) and printed beside
the figures.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd


def _spin(n: int = 5_000_000) -> float:
    """A fixed amount of pure-Python work; its wall time."""
    t0 = time.perf_counter()
    acc = 0
    for i in range(n):
        acc += i * i
    return time.perf_counter() - t0


def available_parallelism(repeat: int = 3) -> float:
    """Speed-up the machine gives two processes over one right now (2.0 on two idle cores;
    less when other processes use the cores): best of ``repeat`` probes."""
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    best = 0.0
    with ProcessPoolExecutor(2, mp_context=get_context("spawn")) as pool:
        list(pool.map(_spin, [1000, 1000]))  # start both workers
        for _ in range(repeat):
            one = min(pool.submit(_spin).result() for _ in range(2))
            t0 = time.perf_counter()
            list(pool.map(_spin, [5_000_000, 5_000_000]))
            best = max(best, 2 * one / (time.perf_counter() - t0))
    return best


def _sweep(suite: str, out: Path, workers: int) -> tuple[float, float]:
    cmd = [sys.executable, "-m", "mpcasv", "compare", suite, "--out", str(out),
           "--workers", str(workers), "--quiet", "--no-report"]  # fmt: skip
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stdout}\n{proc.stderr}")
    return json.loads((out / "sweep.json").read_text())["jobs_wall_s"], wall


def bench_compare(args) -> dict:
    from mpcasv.experiments.store import TIMING_COLUMNS
    from mpcasv.experiments.suite import expand

    suite = getattr(args, "suite", None) or "bench"
    exp = expand(suite)
    repeat = max(1, int(getattr(args, "repeat", 3) or 1))
    jobs = {1: [], 2: []}
    whole = {1: [], 2: []}
    tables = {}
    probe_before = available_parallelism()
    print(f"available parallelism before (2 spinning processes vs 1): {probe_before:.2f}x",
          flush=True)  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="mpcasv-bench-compare-") as tmp:
        for r in range(repeat):
            for w in (1, 2):
                out = Path(tmp) / f"w{w}-r{r}"
                j, t = _sweep(suite, out, w)
                jobs[w].append(j)
                whole[w].append(t)
                tables[w] = pd.read_parquet(out / "results.parquet")
                print(f"  repeat {r + 1}/{repeat}, {w} worker(s): jobs {j:.1f} s, "
                      f"command {t:.1f} s", flush=True)  # fmt: skip
        cols = [c for c in tables[1].columns if c not in TIMING_COLUMNS]
        identical = tables[1][cols].equals(tables[2][cols])
    probe_after = available_parallelism()
    best = {w: (float(np.min(jobs[w])), float(np.min(whole[w]))) for w in (1, 2)}
    speed_jobs = best[1][0] / best[2][0]
    speed_whole = best[1][1] / best[2][1]
    load = os.getloadavg()
    print(
        f"suite {exp.suite.name}: {len(exp.jobs)} jobs; {os.cpu_count()} cores; load average "
        f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (other processes share the cores)"
    )
    print(f"  1 worker : jobs {best[1][0]:.1f} s, whole command {best[1][1]:.1f} s "
          f"(best of {repeat})")  # fmt: skip
    print(f"  2 workers: jobs {best[2][0]:.1f} s, whole command {best[2][1]:.1f} s")
    print(f"  speed-up of 2 workers over 1: {speed_jobs:.2f}x on the jobs, {speed_whole:.2f}x "
          f"on the whole command (target >= 1.7x); identical results: {identical}")  # fmt: skip
    print(
        f"  the machine's available parallelism (pure-Python probe, 2 processes vs 1): "
        f"{probe_before:.2f}x before, {probe_after:.2f}x after (2.00x on idle cores)"
    )
    return {
        "suite": exp.suite.name, "jobs": len(exp.jobs), "repeat": repeat,
        "jobs_s_1": jobs[1], "jobs_s_2": jobs[2], "command_s_1": whole[1],
        "command_s_2": whole[2], "speedup_jobs": speed_jobs, "speedup_command": speed_whole,
        "identical_results": bool(identical), "loadavg": list(load),
        "available_parallelism_before": probe_before, "available_parallelism_after": probe_after,
    }  # fmt: skip
