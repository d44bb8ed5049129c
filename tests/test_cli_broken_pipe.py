"""A closed stdout (``mpcasv compare ... | head -1``): the command printed ``mpcasv compare:
error: Broken pipe`` and exited 2 ("bad input, nothing run") after all its jobs ran and the
report was written. Now, for every command, it ends quietly with 141 (128 + SIGPIPE, as a
tool a closed pipe ends: ``yes | head -1``), its work up to then kept
(:func:`mpcasv.cli.main`).

The commands run in subprocesses whose stdout is a pipe with no reader from the start (its
read end closed before the command starts), so their first write to stdout fails however
fast they are: as ``head -1`` having read its line and gone before the next one.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
from tiny_suite import tiny_suite

from mpcasv.cli import main
from mpcasv.experiments.suite_file import SCENARIOS_DIR

ROOT = Path(__file__).resolve().parents[1]
SUITE = tiny_suite((0, 1))


def _stdout_closed(*args: str) -> subprocess.CompletedProcess:
    """``mpcasv ARGS`` with a stdout nobody reads."""
    read, write = os.pipe()
    os.close(read)
    env = os.environ | {"PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    try:
        return subprocess.run([sys.executable, "-m", "mpcasv", *args], stdout=write,
                              stderr=subprocess.PIPE, text=True, timeout=120,
                              env=env)  # fmt: skip
    finally:
        os.close(write)


def test_compare_into_a_closed_pipe_keeps_its_work_and_ends_as_sigpipe(tmp_path):
    suite, out = tmp_path / "tiny.toml", tmp_path / "out"
    suite.write_text(SUITE)
    r = _stdout_closed("compare", str(suite), "--out", str(out), "--workers", "1",
                       "--job-timeout", "0", "--quiet")  # fmt: skip
    assert (r.returncode, r.stderr) == (141, "")
    df = pd.read_parquet(out / "results.parquet")  # the jobs ran, the report was written
    assert len(df) == 2 and (df["status"] == "ok").all()
    assert (out / "report.md").is_file()


def test_another_command_into_a_closed_pipe_ends_as_sigpipe(tmp_path):
    """Every command goes through :func:`mpcasv.cli.main`: ``simulate``, which prints its
    metrics, said "error: Broken pipe" and exited 2 as well."""
    r = _stdout_closed("simulate", str(SCENARIOS_DIR / "case3.toml"), "--out",
                       str(tmp_path / "run"), "--no-plots", "--quiet")  # fmt: skip
    assert (r.returncode, r.stderr) == (141, "")


def test_a_broken_pipe_that_is_not_stdout_stays_an_error(monkeypatch, tmp_path, capsys):
    """Only a closed stdout ends quietly: another pipe's or socket's EPIPE in a command is
    an error said in one line, as before."""
    from mpcasv.experiments import commands

    def broken(args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(commands, "run", broken)
    assert main(["compare", "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == "mpcasv compare: error: Broken pipe\n"


def test_stdout_closed_tells_an_open_pipe_from_one_whose_reader_left(monkeypatch):
    """What decides between the quiet 141 and the one-line error: ``poll`` on stdout's
    descriptor (the test above passes through a stdout without one)."""
    import os

    from mpcasv.cli import stdout_closed

    r, w = os.pipe()
    with os.fdopen(w, "w") as writer:
        monkeypatch.setattr("sys.stdout", writer)
        assert not stdout_closed()  # a reader is there
        os.close(r)
        assert stdout_closed()  # it left
        monkeypatch.undo()
