"""Writing a run to its folder: ``timeseries.parquet``, ``metrics.json``, ``run.json``,
``jumps.csv`` (hybrid controllers), ``hung_solves.pkl`` (an MPC's solves abandoned as hung,
:mod:`mpcasv.mpc.hung`) and the figures. Written into a temporary folder and
renamed at the end, so a failed run leaves no partial output.

The metrics are computed by the caller (:func:`mpcasv.experiments.metrics.compute_metrics`)
and handed in: the simulator's package does not import the experiments'."""

from __future__ import annotations

import dataclasses
import json
import math
import pickle
import shutil
import tempfile
from pathlib import Path


def _jsonable(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, list):
        return [_jsonable(x) for x in v]
    return v


def check_run_dir(out_dir: str | Path) -> Path:
    """Refuse an output folder that :func:`write_run` must not replace: a file, or a folder
    with content but no ``run.json`` (not a run folder: replacing it would delete the user's
    files). An earlier run's folder (it has ``run.json``) or an empty folder is fine.

    Raises
    ------
    ConfigError
        One line naming the path and why.
    """
    from mpcasv.config import ConfigError

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: the output folder is a file")
    if out.is_dir() and any(out.iterdir()) and not (out / "run.json").is_file():
        raise ConfigError(f"{out}: the output folder exists and is not a run folder (no "
                          "run.json): refusing to replace it; name a new or empty folder")
    return out


def params_record(controller) -> dict | None:
    """The parameters ``controller`` ran with, its preset with every override applied
    (``run.json``'s ``params``): a run folder says what ran, not only the preset file's
    name (a new user's finding, session 40: a copied preset with one line changed left no
    trace); None for a controller without dataclass parameters."""
    p = getattr(controller, "params", None)
    return dataclasses.asdict(p) if dataclasses.is_dataclass(p) else None


def write_run(result, out_dir: str | Path, metrics: dict, plots: bool = True,
              extra: dict | None = None) -> dict:  # fmt: skip
    """Write the run files into ``out_dir`` (an earlier run's folder there is replaced; any
    other non-empty folder is refused, :func:`check_run_dir`); return the metrics as written
    (non-finite numbers as None).

    ``run.json`` holds the scenario, controller, seed, wall time, ``extra`` and the boat
    (``boat``: :meth:`mpcasv.controllers.Boat.describe`, when ``extra`` carries it) and the
    controller's parameters (``params``: :func:`params_record`, likewise).
    """
    out = check_run_dir(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    metrics = {k: _jsonable(v) for k, v in metrics.items()}
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
        if getattr(result, "hung_solves", None):  # an MPC's solves abandoned as hung, for
            with open(tmp / "hung_solves.pkl", "wb") as f:  # mpcasv replay-solve (mpc/hung.py)
                pickle.dump(result.hung_solves, f, protocol=pickle.HIGHEST_PROTOCOL)
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
