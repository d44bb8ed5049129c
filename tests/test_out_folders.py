"""An output folder a user filled is never written into: compare and falsify refuse a
non-empty folder that is no output of theirs, as tune controller does."""

from __future__ import annotations

import pytest
from test_falsify import short_family

from mpcasv.cli import main


@pytest.mark.parametrize("command", ["compare", "falsify"])
def test_a_users_non_empty_folder_is_refused_as_out(command, tmp_path, capsys):
    """A non-empty folder no compare (falsify) wrote, e.g. a thesis draft's: refused in one
    line before any work (compare replaced its report.md and results.parquet, falsify wrote
    beside its files: a new user, session 47), as tune controller refuses it."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "report.md").write_text("PRECIOUS thesis draft\n")
    args = (["compare", "quick", "--workers", "1"] if command == "compare" else
            ["falsify", str(short_family(tmp_path, 40.0)), "--controller", "hybrid-single",
             "--params", "paper1-field", "--budget", "2"])  # fmt: skip
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not empty and not an output" in err, err
    assert sorted(p.name for p in out.iterdir()) == ["report.md"]
    assert (out / "report.md").read_text() == "PRECIOUS thesis draft\n"
