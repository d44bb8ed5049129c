"""Issue 14, item 4: every command's expected failures end in one line naming the file and the
cause, with exit 2 (never a traceback; exit 1 stays "ran, and an acceptance check failed").

The walk covers every command that ``mpcasv --help`` lists, with bad inputs of each kind:
a missing file, an unknown key, binary garbage given as TOML / CSV / LSF / JSON lines, a
folder for a file, a nonexistent controller or preset. Inputs from ``../shared/cases/``
(read-only) are copied into a temporary folder first.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import pytest
from shared_data import CASES as SHARED_CASES

from mpcasv.cli import build_parser, input_error, main

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "experiments" / "scenarios" / "case1.toml"
FAMILY = ROOT / "experiments" / "falsify" / "pursuer-single.toml"
GARBAGE = bytes(range(0x80, 0x100)) * 2  # not UTF-8, not TOML, not an IMC sync


@pytest.fixture
def bad(tmp_path, monkeypatch) -> Path:
    """A folder of bad inputs (also the working directory, so names are short)."""
    for name in ("garbage.toml", "garbage.csv", "garbage.lsf", "garbage.jsonl"):
        (tmp_path / name).write_bytes(GARBAGE)
    (tmp_path / "unknown.toml").write_text('name = "x"\nbogus_key = 1\n')
    (tmp_path / "wrongcols.csv").write_text("a,b\n1,2\n")
    (tmp_path / "adir").mkdir()
    monkeypatch.chdir(tmp_path)
    return tmp_path


# (argv, the file or name the message must contain); {out} is a fresh output folder
WALK: list[tuple[str, str]] = [
    ("simulate missing.toml --out {out}", "missing.toml"),
    ("simulate garbage.toml --out {out}", "garbage.toml"),
    ("simulate unknown.toml --out {out}", "unknown.toml"),
    ("simulate adir --out {out}", "adir"),
    (f"simulate {CASE1} --controller nosuch --out {{out}}", "--controller nosuch: unknown"),
    (f"simulate {CASE1} --params nosuch --out {{out}}", "nosuch"),
    (f"simulate {CASE1} --params garbage.toml --out {{out}}", "garbage.toml"),
    (f"simulate {CASE1} --params unknown.toml --out {{out}}", "unknown.toml"),
    (f"simulate {CASE1} --estimator nosuch --out {{out}}", "nosuch"),
    ("simulate --manoeuvre zigzag --vessel garbage.toml --out {out}/z.csv", "garbage.toml"),
    ("simulate --manoeuvre zigzag --vessel unknown.toml --out {out}/z.csv", "unknown.toml"),
    ("paper-table --scenarios missingdir --out {out}", "missingdir"),
    ("compare missing.toml --out {out}", "missing.toml"),
    ("compare garbage.toml --out {out}", "garbage.toml"),
    ("compare unknown.toml --out {out}", "unknown.toml"),
    ("falsify missing.toml --controller hybrid-single --out {out}", "missing.toml"),
    ("falsify garbage.toml --controller hybrid-single --out {out}", "garbage.toml"),
    ("falsify unknown.toml --controller hybrid-single --out {out}", "unknown.toml"),
    (f"falsify {FAMILY} --controller nosuch --out {{out}}", "--controller nosuch: unknown"),
    (f"falsify {FAMILY} --controller hybrid-single --params nosuch --out {{out}}", "nosuch"),
    ("tune yaw --vessel missing.toml --out {out}", "missing.toml"),
    ("tune yaw --vessel garbage.toml --out {out}", "garbage.toml"),
    ("tune yaw --vessel unknown.toml --out {out}", "unknown.toml"),
    ("tune speed --base garbage.toml --out {out}", "garbage.toml"),
    ("identify missing.csv --out {out}/id.toml", "missing.csv"),
    ("identify garbage.csv --out {out}/id.toml", "garbage.csv"),
    ("identify garbage.lsf --out {out}/id.toml", "garbage.lsf"),
    ("identify wrongcols.csv --out {out}/id.toml", "wrongcols.csv"),
    ("identify wrongcols.csv --vessel garbage.toml --out {out}/id.toml", "garbage.toml"),
    ("deploy missing.toml --dry-run --duration 1", "missing.toml"),
    ("deploy garbage.toml --dry-run --duration 1", "garbage.toml"),
    ("deploy unknown.toml --dry-run --duration 1", "unknown.toml"),
    ("sitl missing.toml --duration 1", "missing.toml"),
    ("sitl garbage.toml --duration 1", "garbage.toml"),
    ("sitl unknown.toml --duration 1", "unknown.toml"),
    ("replay missing.jsonl", "missing.jsonl"),
    ("replay garbage.jsonl", "garbage.jsonl"),
    ("replay-solve missing.pkl", "missing.pkl"),
    ("replay-solve garbage.toml", "garbage.toml"),
    ("replay-solve adir", "adir"),
    ("bench compare --suite missing.toml", "missing.toml"),
    ("bench compare --suite garbage.toml", "garbage.toml"),
]


def _run(argv: str, out: Path, capsys) -> tuple[int, str]:
    code = main(argv.format(out=out).split())
    return code, capsys.readouterr().err


def _assert_one_line_exit_2(code: int, err: str, names: str) -> None:
    assert code == 2, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and " error: " in lines[0], err
    assert names in lines[0], err


@pytest.mark.parametrize("argv,names", WALK, ids=[a.split(" --out")[0] for a, _ in WALK])
def test_bad_input_gives_one_line_and_exit_2(argv, names, bad, capsys):
    _assert_one_line_exit_2(*_run(argv, bad / "out", capsys), names)


def test_the_walk_covers_every_command():
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    walked = {argv.split()[0] for argv, _ in WALK}
    assert set(sub.choices) <= walked, set(sub.choices) - walked


# ../shared/cases/replay-given-binary-log: `mpcasv replay` given the binary IMC logs of a
# deploy folder (imc.lsf) or of DUNE (Data.lsf.gz) ended in a UnicodeDecodeError traceback
# with exit 1. The specific message ("not a deploy log ...; an IMC/LSF log?") is helper
# `deploy`'s; the top level already gives one line naming the file, exit 2.
@pytest.mark.parametrize("name", ["imc.lsf", "Data.lsf.gz"])
def test_replay_of_a_binary_lsf_log_case(name, bad, capsys):
    src = SHARED_CASES / "replay-given-binary-log" / name
    if not src.is_file():
        pytest.skip(f"shared case not available: {src}")
    shutil.copy(src, bad / name)
    _assert_one_line_exit_2(*_run(f"replay {name}", bad, capsys), name)


# ../shared/cases/unstable-hull-tune-yaw: `tune yaw` on a course-unstable hull raised a
# ValueError traceback with exit 1; now a design for it, or a one-line refusal (exit 2).
@pytest.mark.parametrize("vessel", ["otter.toml", "cybership2.toml"])
def test_tune_yaw_on_a_course_unstable_hull_case(vessel, bad, capsys):
    src = SHARED_CASES / "vessels" / vessel
    if not src.is_file():
        pytest.skip(f"shared case not available: {src}")
    shutil.copy(src, bad / vessel)
    code, err = _run(f"tune yaw --vessel {vessel} --out {{out}} --quiet", bad / "out", capsys)
    assert code in (0, 2) and "Traceback" not in err  # a design, or one line and exit 2
    if code == 2:
        _assert_one_line_exit_2(code, err, vessel)


def test_an_unexpected_exception_keeps_its_traceback():
    assert input_error(ZeroDivisionError("bug")) is None
    assert input_error(ValueError("a bug, not an input")) is None
    assert input_error(KeyError("x")) is None


def test_acceptance_failure_stays_exit_1(bad, capsys):
    """Exit 1 means "ran, and an acceptance check failed" (here falsify's margin check)."""
    family = bad / "fam.toml"
    family.write_text(FAMILY.read_text().replace("duration = 400.0", "duration = 20.0", 1))
    code = main(["falsify", str(family), "--controller", "hybrid-single", "--params",
                 "paper1-field", "--budget", "1", "--worst", "1", "--out", str(bad / "f"),
                 "--quiet", "--require-margin", "1000"])  # fmt: skip
    assert code == 1


def test_a_ctrl_c_while_the_program_loads_is_one_line_and_exit_130(monkeypatch, capsys):
    """A Ctrl-C before a command runs (the console script importing ``mpcasv.cli``, or the
    parser importing the commands' modules) ends it as one during a command does: one line,
    exit 130, no traceback (a helper's walk-through, session 26: it printed
    KeyboardInterrupt's traceback)."""
    import importlib.abc
    import sys

    import mpcasv
    import mpcasv.cli as cli

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["simulate", "x.toml"]) == 130
    assert capsys.readouterr().err.strip().splitlines() == ["mpcasv: interrupted"]

    class CtrlCOnImport(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "mpcasv.cli":
                raise KeyboardInterrupt
            return None

    monkeypatch.delitem(sys.modules, "mpcasv.cli")
    monkeypatch.delattr(mpcasv, "cli", raising=False)
    monkeypatch.setattr(sys, "meta_path", [CtrlCOnImport(), *sys.meta_path])
    assert mpcasv.run() == 130
    assert capsys.readouterr().err.strip().splitlines() == ["mpcasv: interrupted"]
