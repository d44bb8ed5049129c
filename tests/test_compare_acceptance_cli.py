"""`mpcasv compare` and a suite's [acceptance] targets on the command line (session 25 audit):
with --no-report nothing judged them and nothing said so; the exit status is the jobs', not
the targets' verdict (docs/experiments.md, "Exit status")."""

from __future__ import annotations

import textwrap
from pathlib import Path

from test_experiments_bad_input import SCENARIO  # the 20-s go-to scenario

from mpcasv.cli import main


def _suite(tmp: Path, variants: int = 2) -> Path:
    """Two go-to variants (one slower) on a 20-s scenario, one seed, with a target the
    slower one cannot be shown to meet (one pair: too few for a verdict of 'met');
    ``variants=1``: the first alone."""
    (tmp / "demo.toml").write_text(SCENARIO)
    path = tmp / "acc.toml"
    text = textwrap.dedent("""
        name = "acc"
        scenarios = ["demo.toml"]
        seeds = [0]
        plots = "none"
        [[controllers]]
        label = "goto"
        name = "goto"
        preset = "goto"
        [[controllers]]
        label = "slow"
        name = "goto"
        preset = "goto"
        overrides = { speed = 0.5 }
        [acceptance]
        targets = { propeller_on_s = -0.5 }
    """)  # fmt: skip
    if variants == 1:
        text = text.replace(text[text.index('[[controllers]]\nlabel = "slow"'):
                                 text.index("[acceptance]")], "")  # fmt: skip
    path.write_text(text)
    return path


def test_no_report_says_the_acceptance_was_not_judged(tmp_path, capsys):
    """The targets are judged in the report only; --no-report skipped it without a word."""
    suite = _suite(tmp_path)
    assert main(["compare", str(suite), "--out", str(tmp_path / "out"), "--workers", "1",
                 "--quiet", "--no-report"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if ln.startswith("acceptance:")]
    assert len(lines) == 1, out
    assert "1 [acceptance] target not judged: it is judged in the report" in lines[0]
    assert "--no-report" in lines[0]
    assert not (tmp_path / "out" / "report.md").exists()
    # the same command with the report: judged there, the line not printed; a target not
    # met is a research result, not an error: exit 0 (docs/experiments.md, "Exit status")
    assert main(["compare", str(suite), "--out", str(tmp_path / "out"), "--workers", "1",
                 "--quiet"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "acceptance:" not in out and "0 jobs run" in out
    md = (tmp_path / "out" / "report.md").read_text()
    # one pair, too few for any verdict: said as such (it read "0 of 1 targets met")
    assert "## Acceptance" in md and "**The target is not judged**" in md



def test_no_report_with_one_variant_says_the_report_could_not_judge_either(tmp_path, capsys):
    """With one variant the report says "acceptance targets are not judged: no paired
    comparison"; --no-report advised rerunning without it to judge them. Both now give the
    same reason (acceptance.why_not_judged, one definition)."""
    suite = _suite(tmp_path, variants=1)
    assert main(["compare", str(suite), "--out", str(tmp_path / "out"), "--workers", "1",
                 "--quiet", "--no-report"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    (line,) = [ln for ln in out.splitlines() if ln.startswith("acceptance:")]
    why = "no paired comparison (1 controller variant(s) with results)"
    assert line.endswith(f"not judged by the report either: {why}"), line
    assert "rerun" not in line
    assert main(["compare", str(suite), "--out", str(tmp_path / "out"), "--workers", "1",
                 "--quiet"]) == 0  # fmt: skip
    md = (tmp_path / "out" / "report.md").read_text()
    assert f"**The suite's acceptance targets are not judged**: {why}." in md


def test_cli_main_docstring_lists_every_exit_1():
    """cli.main's docstring lists the commands that exit 1 (ran, and a check failed); it
    named compare, tune and falsify but not deploy (no decision: io/commands.py) nor
    identify (validation FAIL: control/identify_cli.py)."""
    from mpcasv.cli import main as cli_main

    doc = " ".join(cli_main.__doc__.split())
    for words in ("``compare``: a job failed", "``tune yaw``/``tune speed``", "``falsify``",
                  "``deploy``: the run made no decision",
                  "``identify``: the held-out validation FAILs"):  # fmt: skip
        assert words in doc, words
