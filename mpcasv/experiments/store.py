"""The results store of a sweep: one small Parquet part per finished job, written atomically,
and the consolidated ``results.parquet``.

Layout of a sweep folder ``DIR``::

    DIR/runs/<run name>/      one run folder per job (timeseries.parquet, metrics.json, ...);
                              elsewhere with --runs-dir or on Dask (mpcasv.experiments.runner)
    DIR/parts/<job id>.parquet  one row per finished job (ok or error), written atomically by
                              the client (Dask workers return their rows)
    DIR/results.parquet       all rows of the suite's jobs, in suite order (rewritten at the end)
    DIR/report.md, report.html, figures/

A job counts as done when its part exists; the part is written after its run folder, and
both are renamed into place whole, so a killed sweep leaves no half-written row and a resumed
one neither loses nor duplicates rows (a part is named by its job id).

Columns of the results table (one row per job): the job's description (``job_id``, ``index``,
``suite``, ``scenario``, ``label``, ``variant``, ``controller``, ``preset``, ``overrides``
(JSON), ``param.<key>`` per overridden parameter, ``current_N``, ``current_E``, ``current``
(``"off"`` or ``"V_N,V_E"``), ``estimator``, ``seed``, ``n_auv``, ``auv_names``), the outcome
(``status`` ``"ok"``/``"error"``, ``error`` with the traceback, ``run_dir`` relative to DIR
or, outside DIR, the worker's absolute path or the URL,
``wall_s``, ``finished_at``, ``worker``) and every metric of ``metrics.json`` under its name,
per-AUV lists expanded into ``<metric>_auv<k>`` columns.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from mpcasv.experiments.metrics import WALL_CLOCK

#: columns that are measurements of the machine, not results (differ between identical runs)
TIMING_COLUMNS = ("wall_s", "finished_at", "worker", *WALL_CLOCK)


def parts_dir(out: str | Path) -> Path:
    return Path(out) / "parts"


def _atomic_parquet(table: pa.Table, final: Path) -> None:
    tmp = final.parent / f".{final.stem}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp"
    try:
        with open(tmp, "wb") as fh:
            pq.write_table(table, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, final)
    finally:
        tmp.unlink(missing_ok=True)


def write_part(out: str | Path, row: dict) -> Path:
    """Write one job's row as ``DIR/parts/<job_id>.parquet``, atomically."""
    d = parts_dir(out)
    d.mkdir(parents=True, exist_ok=True)
    final = d / f"{row['job_id']}.parquet"
    _atomic_parquet(pa.Table.from_pylist([row]), final)
    return final


def done_ids(out: str | Path) -> dict[str, str]:
    """Job id -> status of every part present."""
    d = parts_dir(out)
    if not d.exists():
        return {}
    out_ = {}
    for p in d.glob("*.parquet"):
        status = pq.read_table(p, columns=["status"]).column("status")[0].as_py()
        out_[p.stem] = status
    return out_


def read_parts(out: str | Path, job_ids: list[str] | None = None) -> pd.DataFrame:
    """Concatenate the parts (of ``job_ids`` only, in that order, when given)."""
    d = parts_dir(out)
    files = {p.stem: p for p in d.glob("*.parquet")} if d.exists() else {}
    ids = [j for j in job_ids if j in files] if job_ids is not None else sorted(files)
    if not ids:
        return pd.DataFrame()
    tables = [pq.read_table(files[j]) for j in ids]
    return pa.concat_tables(tables, promote_options="permissive").to_pandas()


def write_results(out: str | Path, jobs) -> pd.DataFrame:
    """Rewrite ``DIR/results.parquet`` from the parts of ``jobs`` (in suite order); the
    description columns are taken from the current expansion. Return the table."""
    df = read_parts(out, [j.job_id for j in jobs])
    if len(df):
        index = {j.job_id: j.index for j in jobs}
        df["index"] = df["job_id"].map(index)
        df = df.sort_values("index", kind="stable").reset_index(drop=True)
    _atomic_parquet(pa.Table.from_pandas(df, preserve_index=False), Path(out) / "results.parquet")
    return df
