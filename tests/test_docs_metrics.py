"""docs/metrics.md says what metrics.py defines: the table of every metric row by row (unit,
direction, definition, source), and the per-AUV column names the results table really has."""

from __future__ import annotations

import re
from pathlib import Path

from mpcasv.experiments.metrics import METRIC_INFO, auv_column

DOC = Path(__file__).parents[1] / "docs" / "metrics.md"


def _cells(line: str) -> list[str]:
    """The cells of a Markdown table row; ``\\|`` is a literal pipe inside a cell."""
    parts = re.split(r"(?<!\\)\|", line.strip())[1:-1]
    return [p.strip().replace("\\|", "|") for p in parts]


def _metric_rows() -> dict[str, list[str]]:
    section = DOC.read_text().split("## Every metric", 1)[1]
    rows = {}
    for line in section.splitlines():
        if line.startswith("| `"):
            cells = _cells(line)
            rows[cells[0].strip("`")] = cells
    return rows


def test_every_row_of_the_metric_table_has_five_cells_and_says_what_metric_info_says():
    rows = _metric_rows()
    # a '|' inside a definition (e.g. |believed range - true range|) split the row into
    # more cells than the header has: the rendered table was shifted
    assert {n: len(c) for n, c in rows.items() if len(c) != 5} == {}
    scalars = {n: i for n, i in METRIC_INFO.items() if n in rows}
    for name, info in scalars.items():
        _, unit, better, definition, source = rows[name]
        assert (unit, better, definition, source) == (
            info.unit,
            info.better or "—",
            info.definition,
            info.source or "—",
        ), name
    assert set(rows) <= set(METRIC_INFO), set(rows) - set(METRIC_INFO)
    # the names not in the table are the per-AUV lists, listed in the prose above it
    listed = DOC.read_text().split("## Every metric", 1)[1].split("| name |", 1)[0]
    for name in set(METRIC_INFO) - set(rows):
        assert name.endswith("_auv") and f"`{name}`" in listed, name


def test_the_per_auv_column_example_is_the_column_the_runner_writes():
    text = DOC.read_text()
    for m in re.finditer(r"`(\w+_auv)` -> `(\w+_auv\d)`", text):
        assert auv_column(m[1], int(m[2][-1])) == m[2]
    assert "fixes_auv_auv0" not in text  # the old, wrong example
    assert auv_column("fixes_auv", 0) in text
