"""Shared assertion of the scenario format's tests: a bad file is refused in one line."""

from __future__ import annotations

from pathlib import Path

import pytest

from mpcasv.cli import main
from mpcasv.config import ConfigError
from mpcasv.sim.scenario import load_scenario


def assert_refused_in_one_line(path: Path, word: str, out: Path, capsys) -> None:
    """Loading ``path`` raises one ConfigError line naming the file and containing ``word``;
    `mpcasv simulate` on it exits 2 with one error line, no traceback and no output folder."""
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    problems = [ln for ln in str(err.value).splitlines() if str(path) in ln]
    assert len(problems) == 1, str(err.value)
    assert word in problems[0], (word, problems[0])
    assert main(["simulate", str(path), "--out", str(out), "--quiet", "--no-plots"]) == 2
    err_text = capsys.readouterr().err
    assert "error" in err_text and "Traceback" not in err_text
    assert not out.exists()
