"""Log files written while the link runs: every IMC packet in and out (LSF) and a JSON-lines
file of decisions and events.

LSF, as DUNE writes it (``Data.lsf``), is nothing but serialized IMC packets one after the
other, so imcpy's ``LSFReader``, :func:`mpcasv.io.lsf.read_messages` and Neptus read it.
Both files are flushed by :meth:`flush` (called every ``log.flush_s`` <= 1 s by the owner and
on close), so a crash loses at most the last second.
"""

from __future__ import annotations

import fcntl
import json
import math
import time
from pathlib import Path
from typing import IO, Any

import numpy as np

from mpcasv.config import ConfigError
from mpcasv.errors import LogError

__all__ = ["FolderLock", "JsonlWriter", "LsfWriter", "jsonable", "keep_earlier",
           "read_jsonl", "read_jsonl_cut"]


class _LogFile:
    """A log file opened (created or truncated) at construction; flush and close are safe to
    call repeatedly, writes after close are ignored."""

    mode = "wb"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        enc = None if "b" in self.mode else "utf-8"
        self._fh: IO | None = self.path.open(self.mode, encoding=enc)

    @property
    def closed(self) -> bool:
        return self._fh is None

    def flush(self) -> None:
        if self._fh is not None:
            self._fh.flush()

    def close(self) -> None:
        if self._fh is not None:
            self._fh.flush()
            self._fh.close()
            self._fh = None


class LsfWriter(_LogFile):
    """Append whole IMC packets to ``path`` (created, or truncated)."""

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        self.packets = 0

    def write(self, packet: bytes) -> None:
        if self._fh is not None:
            self._fh.write(packet)
            self.packets += 1


def jsonable(v: Any) -> Any:
    """Plain JSON value: numpy scalars/arrays to Python, NaN/inf to None, enums to str."""
    if isinstance(v, dict):
        return {str(k): jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return jsonable(v.tolist())
    if isinstance(v, (np.floating, float)):
        f = float(v)
        return f if math.isfinite(f) else None
    if isinstance(v, (np.integer, np.bool_)):
        return v.item()
    if isinstance(v, (str, int, bool)) or v is None:
        return v
    return str(v)


class JsonlWriter(_LogFile):
    """One JSON object per line; every record gets ``wall`` (UNIX time of writing)."""

    mode = "w"

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        self.lines = 0

    def write(self, record: dict) -> None:
        if self._fh is not None:
            rec = {"wall": time.time()} | record
            self._fh.write(json.dumps(jsonable(rec), allow_nan=False) + "\n")
            self.lines += 1


#: the files a deploy writes in its log folder (:class:`~mpcasv.io.deploy.Deploy`)
DEPLOY_LOG_FILES = ("deploy.jsonl", "imc.lsf")
#: the lock a running deploy holds on its log folder (:class:`FolderLock`)
LOCK_FILE = "deploy.lock"


class FolderLock:
    """An exclusive lock of one process on a log folder: ``fcntl.flock`` on
    ``folder/deploy.lock`` (made with the folder if need be). The operating system releases it
    when the process ends, however it ends, so a crashed deploy leaves no stale lock; the file
    itself stays, empty. A review (session 43): two deploys started on one folder renamed and
    interleaved each other's logs.

    Raises
    ------
    ConfigError
        The folder is locked by another running process (``what`` names the setting).
    """

    def __init__(self, folder: str | Path, what: str = "log.dir"):
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self._fh = open(folder / LOCK_FILE, "a")  # held until close()
        try:
            fcntl.flock(self._fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._fh.close()
            self._fh = None
            raise ConfigError(f"{what} = {folder}: in use by another running deploy (it holds "
                              f"{LOCK_FILE}): give this one its own --log-dir") from None

    def close(self) -> None:
        """Release the lock (again: nothing)."""
        if self._fh is not None:
            self._fh.close()
            self._fh = None


def keep_earlier(folder: str | Path, names: tuple[str, ...] = DEPLOY_LOG_FILES) -> dict:
    """Keep an earlier run's log in ``folder`` before a new run writes there: each of
    ``names`` that is a non-empty file is renamed ``stem.K.suffix`` (``deploy.1.jsonl``,
    ``imc.1.lsf``), ``K`` the smallest number free for all of them, so one run's files share
    it. Returns ``{old name: new name}`` (empty: nothing to keep). A restarted deploy wrote
    over the trial's record until session 43; refusing the folder instead broke the dry run
    then run of one configuration that docs/deploy.md describes."""
    folder = Path(folder)
    found = [n for n in names if (folder / n).is_file() and (folder / n).stat().st_size]
    if not found:
        return {}

    def numbered(name: str, k: int) -> str:
        stem, _, suffix = name.partition(".")
        return f"{stem}.{k}.{suffix}"

    k = 1
    while any((folder / numbered(n, k)).exists() for n in names):
        k += 1
    for n in found:
        (folder / n).rename(folder / numbered(n, k))
    return {n: numbered(n, k) for n in found}


def read_jsonl(path: str | Path, kind: str | None = None) -> list[dict]:
    """Records of a JSON-lines log (optionally only ``kind``); a last line cut by a crash is
    skipped, any other bad line raises :class:`~mpcasv.errors.LogError` (a ValueError) naming
    the file and line."""
    return read_jsonl_cut(path, kind)[0]


def read_jsonl_cut(path: str | Path, kind: str | None = None) -> tuple[list[dict], bool]:
    """:func:`read_jsonl`'s records and whether the log's last line was cut (not JSON: a crash
    or a kill mid-write) and skipped; ``mpcasv replay`` says so."""
    path = Path(path)
    lines = path.read_text(encoding="utf-8").splitlines()
    out = []
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as exc:
            if i == len(lines):
                return out, True
            raise LogError(f"{path}:{i}: not JSON ({exc}); a deploy log (deploy.jsonl) is JSON "
                           "lines") from None  # fmt: skip
        if kind is None or rec.get("kind") == kind:
            out.append(rec)
    return out, False
