"""The ``mpcasv`` command line: one sub-command per workflow.

Each sub-command lives beside the code it drives (``mpcasv/<package>/commands.py``) and
registers itself through ``register(subparsers)``; this module only assembles them and turns
every expected failure (bad configuration, bad or unsupported input files) into one line
naming the file and the cause, with exit code 2 (:func:`input_error`), and a stdout closed
by its reader (``mpcasv ... | head -1``) into a quiet end with :data:`SIGPIPE_STATUS`
(:func:`main`).
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import select
import sys
import tomllib

from mpcasv import __version__
from mpcasv.config import ConfigError
from mpcasv.errors import LogError

COMMAND_MODULES = (
    "mpcasv.sim.commands",  # simulate
    "mpcasv.hybrid.commands",  # paper-table
    "mpcasv.experiments.commands",  # compare
    "mpcasv.experiments.falsify_commands",  # falsify
    "mpcasv.control.commands",  # tune, identify
    "mpcasv.experiments.tune_commands",  # tune controller (extends "tune": after the above)
    "mpcasv.io.commands",  # deploy, sitl, replay, log
    "mpcasv.bench",  # bench
    "mpcasv.mpc.hung_cli",  # replay-solve
)

#: exit status of a command whose stdout was closed by its reader before the command had
#: written all of it: 128 + SIGPIPE (13), what a shell reports for a tool such a pipe ends
#: (``yes | head -1``); Python ignores SIGPIPE, so the write fails with BrokenPipeError instead
SIGPIPE_STATUS = 141


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (``mpcasv CMD: error: ...``, exit
    2), as every other bad input: argparse's default printed the whole usage block first (3-11
    lines). Sub-command parsers are of this class too (``add_subparsers`` uses the parent's)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="mpcasv",
        description="ASV support of AUVs: hybrid and MPC controllers, experiments, tuning, "
        "IMC deployment. Run 'mpcasv COMMAND --help' for each command.",
    )
    parser.add_argument("--version", action="version", version=f"mpcasv {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def input_error(exc: BaseException) -> str | None:
    """The one-line message for an expected failure, or None for an unexpected exception.

    Expected: the project's error classes (:class:`~mpcasv.config.ConfigError`, a bad log's
    ``mpcasv.errors.LogError``), operating-system errors (a missing or unreadable file, a
    folder given for a file, a port in use) and a file that cannot be decoded (binary
    garbage where TOML, JSON or CSV was expected). The file is named: from the error itself,
    or else the innermost file being read where it was raised.
    """
    if isinstance(exc, (ConfigError, LogError)):
        return "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    if isinstance(exc, FileExistsError) and exc.filename and not os.path.isdir(exc.filename):
        # mkdir of an output folder (or of a parent of it) where a file is: "File exists" alone
        # did not say which option or why
        return (f"{exc.filename}: a file is there, where an output folder was to be made; "
                "choose another output folder")  # fmt: skip
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if exc.filename is not None else ""
        return f"{where}{exc.strerror or exc}"
    if isinstance(exc, UnicodeDecodeError):
        return (f"{_file_being_read(exc)}: not a text file ({exc.reason}: byte "
                f"{exc.object[exc.start]:#04x} at {exc.start}); a binary file where TOML, JSON "
                "or CSV was expected?")  # fmt: skip
    if isinstance(exc, (tomllib.TOMLDecodeError, json.JSONDecodeError)):
        kind = "TOML" if isinstance(exc, tomllib.TOMLDecodeError) else "JSON"
        return f"{_file_being_read(exc)}: not valid {kind}: {exc}"
    return None


def _file_being_read(exc: BaseException) -> str:
    """The innermost open file (or existing file path) in the frames ``exc`` went through."""
    frames = []
    tb = exc.__traceback__
    while tb is not None:
        frames.append(tb.tb_frame)
        tb = tb.tb_next
    for frame in reversed(frames):
        for value in frame.f_locals.values():
            name = getattr(value, "name", None) if hasattr(value, "read") else value
            if isinstance(name, (str, os.PathLike)) and os.path.isfile(name):
                return os.fspath(name)
    return "input file"


def stdout_closed() -> bool:
    """Whether stdout is a pipe (or socket) whose reader has gone, so that writing to it fails
    with EPIPE: ``poll`` reports an error on it (Linux). False when stdout has no file
    descriptor (replaced, as under pytest's capture); True where ``poll`` is missing."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return False
    if not hasattr(select, "poll"):
        return True
    poller = select.poll()
    poller.register(fd, select.POLLOUT)
    return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))


def main(argv: list[str] | None = None) -> int:
    """Run ``mpcasv``: 0 success, 1 ran and a check of the command failed, said on the
    output (``compare``: a job failed or was lost; ``tune yaw``/``tune speed``: a design
    FAILs its acceptance; ``falsify``: no run finished without an error, or with
    ``--require-margin`` the worst margin is below it; ``deploy``: the run made no decision;
    ``identify``: the held-out validation FAILs; a suite's ``[acceptance]`` verdict is a
    result in the report, not such a check), 2 bad input (one line on stderr naming the file
    and the cause), 130 interrupted, :data:`SIGPIPE_STATUS` (141) stdout closed by its reader
    (``mpcasv compare ... | head -1``). An unexpected exception (a bug) keeps its traceback.

    A closed stdout ends the command at its first write after the reader went, as SIGPIPE
    ends a Unix tool: quietly (no message: the reader left on purpose), its work up to then
    kept (``compare``: the finished jobs, and resuming runs the others), exit 141 whatever
    the work's own status would have been (the command was cut short, or its summary was).
    Before, the BrokenPipeError was taken for bad input: "error: Broken pipe", exit 2, after
    a sweep had run. An EPIPE of another pipe or socket stays such an error
    (:func:`stdout_closed`). argparse's own output (``--help``, a usage error) ignores a
    closed stdout by itself.
    """
    try:
        status = _main(argv)
        if sys.stdout is not None:  # a closed stdout shows here at the latest, not at exit
            sys.stdout.flush()
        return status
    except BrokenPipeError:
        if not stdout_closed():
            raise
        # the Python docs' recipe ("Note on SIGPIPE"): stdout to devnull, so that Python's
        # own flush at exit does not fail again on what is still buffered
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return SIGPIPE_STATUS


def _main(argv: list[str] | None) -> int:
    """:func:`main` but for a closed stdout: a BrokenPipeError on it is raised, not taken
    for bad input."""
    try:  # building the parser imports the commands' modules: a Ctrl-C may come there too
        args = build_parser().parse_args(argv)
    except KeyboardInterrupt:
        print("mpcasv: interrupted", file=sys.stderr)
        return 130
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"mpcasv {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        message = input_error(exc)
        if message is None or (isinstance(exc, BrokenPipeError) and stdout_closed()):
            raise
        print(f"mpcasv {args.command}: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
