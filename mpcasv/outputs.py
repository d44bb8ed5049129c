"""Output locations of the command line, checked before any long work starts.

Every command that writes a folder (``--out`` of simulate, paper-table, compare, falsify,
tune ..., sitl; ``--log-dir`` of deploy; ``replay-solve --export``) or a file (``identify
--out``, ``bench --json``, ``tune compare --out/--plot``, ``replay --json``, ``sitl
--ready-file``, ``tune yaw|speed --toml``, ``python -m mpcasv.estimation.evaluate --plot``)
calls :func:`check_output_folder` or :func:`check_output_file` on it first, a file with the
suffixes it writes: an unwritable place (``/proc/x``, a read-only file system, a folder
without write permission), a file where a folder is to be made, a folder named like a file
(``--out m.txt``) or a file named as another kind (``replay --json x.csv``) were found only
after the whole run, or silently wrote a folder called ``m.txt`` or JSON into ``x.csv``.

Nothing is created: writability is probed by making and removing a temporary folder in the
nearest existing folder on the way to the output.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from mpcasv.config import ConfigError

#: Suffixes that name a file, not a folder: an output folder ``--out m.txt`` (or ``.csv``,
#: ``.toml``, ...) is refused unless that folder already exists.
FILE_SUFFIXES = frozenset({
    ".txt", ".csv", ".tsv", ".parquet", ".json", ".jsonl", ".toml", ".yaml", ".yml", ".md",
    ".html", ".png", ".pdf", ".svg", ".jpg", ".jpeg", ".lsf", ".gz", ".zip", ".db", ".log",
    ".npz", ".npy", ".pkl", ".py", ".xlsx",
})  # fmt: skip

#: Suffixes of a figure file (``--plot``): the formats matplotlib picks by the suffix that the
#: project writes; others (``--plot out.txt``) are refused before the work that draws it.
PLOT_SUFFIXES = (".png", ".pdf", ".svg")


def check_output_folder(path: str | os.PathLike, option: str = "--out") -> Path:
    """Refuse an output folder that cannot be made or written, before the work that fills it.

    Parameters
    ----------
    path : path
        The folder to be written (it may exist, e.g. a run to resume, or not yet).
    option : str
        How the user gave it (``"--out"``, ``"--log-dir"``, ``"log.dir of FILE"``): named in
        the message.

    Returns
    -------
    Path
        ``path``, unchanged.

    Raises
    ------
    ConfigError
        One line naming the option, the path and the cause: a file is there (at the path or
        at a folder above it); the name has a file suffix (:data:`FILE_SUFFIXES`) and no such
        folder exists; the nearest existing folder cannot be written in.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{option} {out}: a file is there, where an output folder is written; "
                          "name a folder")  # fmt: skip
    if not out.is_dir() and out.suffix.lower() in FILE_SUFFIXES:
        raise ConfigError(f"{option} {out}: names a file ({out.suffix}), but this command "
                          "writes a folder there; name a folder (e.g. "
                          f"{out.with_suffix('')})")  # fmt: skip
    _probe(out, option)
    return out


def check_output_file(path: str | os.PathLike, option: str = "--out",
                      suffixes: tuple[str, ...] | None = None,
                      parents: bool = False) -> Path:  # fmt: skip
    """Refuse an output file that cannot be written, before the work that produces it.

    Parameters
    ----------
    path : path
        The file to be written (an existing file is replaced).
    option : str
        How the user gave it, named in the message.
    suffixes : tuple of str, optional
        The suffixes the command writes (e.g. ``(".csv", ".parquet")``); others are refused.
    parents : bool
        Whether the command makes the missing folders above the file (else the folder of the
        file must exist).

    Raises
    ------
    ConfigError
        One line naming the option, the path and the cause: a folder is there; the suffix is
        not one of ``suffixes``; the folder of the file does not exist (``parents`` False); a
        file is where a folder above it should be; the nearest existing folder cannot be
        written in.
    """
    out = Path(path)
    if out.is_dir():
        raise ConfigError(f"{option} {out}: a folder is there, where a file is written; name a "
                          "file")  # fmt: skip
    if suffixes is not None and out.suffix.lower() not in suffixes:
        raise ConfigError(f"{option} {out}: this command writes a {' or '.join(suffixes)} file; "
                          f"the name ends in {out.suffix or 'no suffix'}")  # fmt: skip
    _probe(out.parent, option, out)
    if not parents and not out.parent.exists():
        raise ConfigError(f"{option} {out}: no folder {out.parent} to write it in")
    return out


def _probe(folder: Path, option: str, shown: Path | None = None) -> None:
    """Make and remove a temporary folder in the nearest existing folder on the way to
    ``folder`` (nothing is left behind); ConfigError if that fails or a file is in the way."""
    shown = folder if shown is None else shown
    base = folder
    while not base.exists() and base != base.parent:
        base = base.parent
    if not base.is_dir():
        raise ConfigError(f"{option} {shown}: {base} is a file: a file is there, where a folder "
                          "was to be made; choose another place")  # fmt: skip
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".mpcasv-probe-", dir=base))
    except OSError as exc:
        raise ConfigError(f"{option} {shown}: cannot write in {base} "
                          f"({exc.strerror or exc})") from None  # fmt: skip


#: files at the top of an output folder naming the command that wrote it
#: (``study.db`` is checked by its study name: ``mpcasv falsify`` writes one too)
OUTPUT_MARKERS: dict[str, str] = {
    "tune.json": "mpcasv tune controller", "sweep.json": "mpcasv compare",
    "suite.toml": "mpcasv compare", "run.json": "mpcasv simulate",
    "summary.json": "mpcasv falsify", "trials.md": "mpcasv falsify",
}  # fmt: skip


def check_not_other_output(path: str | os.PathLike, command: str, option: str = "--out",
                           own: tuple[str, ...] = ()) -> Path:  # fmt: skip
    """Refuse an existing folder that another command wrote (one of :data:`OUTPUT_MARKERS`),
    before any work: writing there would replace its report (``report.md``) and mix two
    commands' files in one folder.

    Parameters
    ----------
    path : path
        The output folder (it may not exist yet).
    command : str
        This command, as in :data:`OUTPUT_MARKERS` (e.g. ``"mpcasv compare"``).
    option : str
        How the user gave the folder, named in the message.
    own : tuple of str
        Files this command writes first: a non-empty folder without any of them is refused
        too (``("study.db", "tune.lock")`` for ``mpcasv tune controller``).

    Raises
    ------
    ConfigError
        One line naming the option, the folder and the other command (or the missing file).
    """
    out = Path(path)
    if not out.is_dir():
        return out
    for name, other in OUTPUT_MARKERS.items():
        if other != command and (out / name).exists():
            raise ConfigError(f"{option} {out}: holds the output of '{other}' ({name}); "
                              f"'{command}' would overwrite its files there: use another "
                              "folder")  # fmt: skip
    if own and not any((out / f).exists() for f in own) and any(out.iterdir()):
        raise ConfigError(f"{option} {out}: not empty and not an output of '{command}' (no "
                          f"{' or '.join(own)}): use a new or empty folder")  # fmt: skip
    return out


@contextlib.contextmanager
def folder_lock(out: str | os.PathLike, command: str, name: str):
    """Hold an exclusive lock (``fcntl.flock``) on ``out/name`` while the block runs: a second
    ``command`` on the same folder is refused at once instead of redoing the first one's
    work and failing on its results.

    Raises
    ------
    ConfigError
        Another process holds the lock (its pid is named when it wrote it).
    """
    import fcntl

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / name, "a+") as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            pid = f.read().strip()
            raise ConfigError(f"{out}: another '{command}' is working in this folder"
                              f"{f' (pid {pid})' if pid else ''}: wait for it to end, or use "
                              "another folder") from None  # fmt: skip
        f.seek(0)
        f.truncate()
        f.write(f"{os.getpid()}\n")
        f.flush()
        try:
            yield out
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)
