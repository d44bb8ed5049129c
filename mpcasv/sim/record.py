"""Writing a run to its folder: ``timeseries.parquet``, ``metrics.json``, ``run.json``,
``jumps.csv`` (hybrid controllers) and the figures. Written into a temporary folder and
renamed at the end, so a failed run leaves no partial output."""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from pathlib import Path

from mpcasv.experiments.metrics import compute_metrics


def _jsonable(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, list):
        return [_jsonable(x) for x in v]
    return v


def write_run(result, out_dir: str | Path, plots: bool = True, extra: dict | None = None) -> dict:
    """Write the run files into ``out_dir`` (replaced if present); return the metrics."""
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    metrics = {k: _jsonable(v) for k, v in compute_metrics(result).items()}
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        result.timeseries.to_parquet(tmp / "timeseries.parquet", index=False)
        (tmp / "metrics.json").write_text(json.dumps(metrics, indent=1) + "\n")
        info = {
            "scenario": result.scenario.name, "controller": result.controller,
            "seed": result.seed, "wall_s": result.wall_s, **(extra or {}),
        }  # fmt: skip
        (tmp / "run.json").write_text(json.dumps(info, indent=1, default=str) + "\n")
        if result.jumps is not None:
            result.jumps.to_csv(tmp / "jumps.csv", index=False)
        if plots:
            from mpcasv.sim.plots import plot_run  # matplotlib only when drawing

            plot_run(result, tmp)
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return metrics
