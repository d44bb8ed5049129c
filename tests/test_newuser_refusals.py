"""A new user's bad inputs (session 5, newuser5): each is refused in one line naming the file
and the cause, exit 2, no traceback and no output folder."""

from __future__ import annotations

from pathlib import Path

import pytest
from refusal import assert_refused_in_one_line

CASE1 = Path(__file__).resolve().parents[1] / "experiments" / "scenarios" / "case1.toml"


@pytest.mark.parametrize(
    ("old", "new", "word"),
    [
        # was a traceback (ValueError from make_estimator, exit 1) once the run had started
        ('estimator = "perfect"', 'estimator = "bogus"', "bogus"),
        # was accepted: the run went on with a NaN ASV position (asv_distance_m None, exit 0)
        ("N = 0.0\n", "N = nan\n", "asv.start.N"),
        ("N = 0.0\n", "N = inf\n", "asv.start.N"),
        ("E = 100.0, depth", "E = nan, depth", "auv[0].start.E"),
    ],
)
def test_bad_scenario_values_are_refused_in_one_line(tmp_path, capsys, old, new, word):
    text = CASE1.read_text()
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1))
    assert_refused_in_one_line(path, word, tmp_path / "o", capsys)
