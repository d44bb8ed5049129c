"""The output folder of ``mpcasv compare`` (``DIR``) and where its run folders go.

``DIR/suite.toml`` is a copy of the suite that made the folder, written before its first job:
a folder holding another suite's results (another ``name``) is refused before anything runs
(:func:`check_suite_folder`), as is a folder with results (``parts/``) but no suite.toml.
``compare quick --out DIR`` on a folder of another suite kept that suite's rows in ``parts/``
and, with ``--no-report``, its report (titled with the other suite). Rerunning the same suite
(even edited: more seeds, another controller) resumes: its jobs are found by their ids.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from mpcasv.config import ConfigError


def check_suite_folder(out: Path, suite_name: str, option: str = "--out") -> None:
    """Refuse ``out`` when it holds the results of a suite other than ``suite_name``.

    Raises
    ------
    ConfigError
        One line naming the option, the folder, its suite and this one: ``out/suite.toml``
        names another suite (or cannot be read), or ``out/parts`` exists without it.
    """
    recorded = out / "suite.toml"
    if not recorded.exists():
        if (out / "parts").is_dir():
            raise ConfigError(f"{option} {out}: holds job results (parts/) but no suite.toml "
                              "naming their suite: choose another --out")  # fmt: skip
        return
    try:
        name = tomllib.loads(recorded.read_text()).get("name")
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"{option} {out}: its {recorded.name} (the suite that made the "
                          f"folder) cannot be read ({exc}): choose another --out") from None
    if name != suite_name:
        raise ConfigError(f"{option} {out}: holds the results of suite {name!r} "
                          f"({recorded.name}), not of suite {suite_name!r}: choose another "
                          f"--out (or rerun suite {name!r} there to resume it)")  # fmt: skip


def is_url(location: str) -> bool:
    """Whether a runs location is an fsspec URL (``s3://...``, ``file://...``), not a path."""
    return "://" in str(location)


def runs_location(out: Path, suite: str, runs_dir: str | None, dask: str | None) -> str:
    """Where the run folders go: ``runs_dir`` as given (a local path made absolute here, or a
    URL), else ``DIR/runs`` for local workers and ``mpcasv-runs/<suite>`` relative to each Dask
    worker's working directory."""
    if runs_dir:
        return str(runs_dir) if is_url(runs_dir) else str(Path(runs_dir).expanduser().resolve())
    return f"mpcasv-runs/{suite}" if dask else str(out / "runs")


def check_runs_location(runs: str, dask: str | None) -> None:
    """Refuse, before any job starts, a runs location this process cannot write: a local
    path (unless Dask workers write it on their own machines) or an fsspec URL. Raises
    :class:`ConfigError` in one line naming it and the cause (every job would fail on it)."""
    if dask and not is_url(runs):
        return  # a path on the workers' machines: only they can tell
    if not is_url(runs):
        from mpcasv.outputs import check_output_folder

        check_output_folder(runs, "--runs-dir")  # the one check of a local output folder
        return
    probe = ".mpcasv-write-probe"
    try:
        import fsspec

        fs, root = fsspec.core.url_to_fs(runs)
        fs.makedirs(root, exist_ok=True)
        fs.pipe(f"{root.rstrip('/')}/{probe}", b"")
        fs.rm(f"{root.rstrip('/')}/{probe}")
    except (OSError, ValueError, ImportError) as exc:
        cause = getattr(exc, "strerror", None) or str(exc).splitlines()[0]
        raise ConfigError(f"--runs-dir {runs}: cannot write run folders there ({cause})") from None


#: the lock file a running ``mpcasv compare`` holds in its output folder
LOCK_FILE = "compare.lock"


def remove_leftovers(out: Path, runs: str | None, jobs) -> int:
    """Remove what killed sweeps left half-written in ``out`` (the run folders' and parts'
    temporary copies: ``runs/.<run name>.*``, found by the name's seed and job id, and
    ``parts/.*.tmp``) for the jobs about to run;
    return how many. Only under the folder's lock (:data:`LOCK_FILE`): no other sweep writes
    there then. A ``kill -9`` left them, and resuming never removed them. ``runs`` None:
    the run folders are not this folder's alone (a ``--runs-dir``, which another sweep may
    share, or Dask workers' own disks) and are left alone."""
    import shutil

    n = 0
    if runs is not None and not is_url(runs) and Path(runs).is_dir():
        for job in jobs:
            # by the name's end, "-s<seed>-<job id[:8]>": a run name made before session 45
            # said the nominal current where it now says the drawn one
            for tmp in Path(runs).glob(f".*-s{job.seed}-{job.job_id[:8]}.*"):
                if tmp.is_dir():
                    shutil.rmtree(tmp, ignore_errors=True)
                    n += 1
    parts = out / "parts"
    if parts.is_dir():
        for tmp in parts.glob(".*.tmp"):
            tmp.unlink(missing_ok=True)
            n += 1
    return n
