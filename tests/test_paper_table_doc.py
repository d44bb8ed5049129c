"""docs/paper-table.md is what `mpcasv paper-table` writes today (it was left stale once: Case 7
moved at session 34 and the committed table kept the old numbers until session 44)."""

from __future__ import annotations

from pathlib import Path

from mpcasv.cli import main

DOC = Path(__file__).resolve().parents[1] / "docs" / "paper-table.md"


def test_the_committed_paper_table_is_what_the_command_writes(tmp_path):
    """The command's table (Cases 1-8, seed 0, ~13 s) is the doc's head, line for line; the
    doc goes on with the history of what moved."""
    assert main(["paper-table", "--out", str(tmp_path)]) == 0
    written = (tmp_path / "paper_table.md").read_text().splitlines()
    doc = DOC.read_text().splitlines()
    assert doc[: len(written)] == written, "regenerate: mpcasv paper-table --out DIR"
