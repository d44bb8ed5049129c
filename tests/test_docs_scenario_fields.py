"""docs/experiments.md lists every field a scenario file accepts ("Every scenario field"): one
Markdown table per class the loader parses a table with (every dataclass reachable from
:class:`~mpcasv.sim.scenario.Scenario`), a row per field, "required" exactly where the field
has no default, and the default the code has. A field added to a scenario class and not
documented fails here, as does a row for a field that is no longer accepted (the lawnmower
fields, ``[acoustics]`` and ``log_every_step`` had fallen behind before session 45)."""

from __future__ import annotations

import dataclasses
import re
import typing
from pathlib import Path

from mpcasv.sim.scenario import Scenario

DOC = Path(__file__).parents[1] / "docs" / "experiments.md"
SECTION = "## Every scenario field"


def _classes(root: type) -> dict[str, type]:
    """Every dataclass reachable from ``root`` through its fields' types (tuples, unions,
    dicts, ``Annotated`` included), by class name."""
    found: dict[str, type] = {}

    def types_in(tp) -> list[type]:
        if dataclasses.is_dataclass(tp) and isinstance(tp, type):
            return [tp]
        return [c for arg in typing.get_args(tp) for c in types_in(arg)]

    def visit(cls: type) -> None:
        if cls.__name__ in found:
            return
        found[cls.__name__] = cls
        hints = typing.get_type_hints(cls, include_extras=True)
        for f in dataclasses.fields(cls):
            for sub in types_in(hints[f.name]):
                visit(sub)

    visit(root)
    return found


def _cells(line: str) -> list[str]:
    parts = re.split(r"(?<!\\)\|", line.strip())[1:-1]
    return [p.strip() for p in parts]


def _documented() -> dict[tuple[str, ...], dict[str, list[str]]]:
    """``{(class names of a heading): {field: row cells}}`` of the reference section."""
    text = DOC.read_text()
    assert SECTION in text, f"{DOC.name} has no section {SECTION!r}"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    out: dict[tuple[str, ...], dict[str, list[str]]] = {}
    rows: dict[str, list[str]] | None = None
    for line in section.splitlines():
        if line.startswith("### "):
            names = tuple(re.findall(r"`([A-Z][A-Za-z]+)`", line))
            assert names, f"a heading of {SECTION!r} names no class: {line!r}"
            rows = out.setdefault(names, {})
        elif line.startswith("| `") and rows is not None:
            cells = _cells(line)
            assert len(cells) == 4, f"not 4 cells (field, type, default, meaning): {line!r}"
            rows[cells[0].strip("`")] = cells
    return out


def _number(value: float) -> str:
    return f"{value:g}"


def _default_says(cell: str, default) -> bool:
    """Whether a row's default cell says the code's ``default`` (checked for numbers, booleans,
    strings and tuples of numbers; a table's or a None default only must not read
    "required")."""
    if cell.startswith("required"):
        return False
    if isinstance(default, bool):
        return str(default).lower() in cell
    if isinstance(default, (int, float)):
        return re.search(rf"(?<![\d.]){re.escape(_number(default))}(?![\d.])", cell) is not None
    if isinstance(default, str):
        return f'"{default}"' in cell
    if isinstance(default, tuple) and all(isinstance(x, (int, float)) for x in default):
        return "[" + ", ".join(_number(x) for x in default) + "]" in cell
    return True


def _problems(classes: dict[str, type], documented) -> list[str]:
    """What the reference section gets wrong about ``classes`` (empty: nothing)."""
    named = {n for names in documented for n in names}
    out = [f"class {n} has no table" for n in sorted(set(classes) - named)]
    out += [f"a table of {n}, which the loader no longer has" for n in sorted(named - set(classes))]
    for names, rows in documented.items():
        if not set(names) <= set(classes):
            continue
        fields = {f.name: f for n in names for f in dataclasses.fields(classes[n])}
        where = f"table of {', '.join(names)}"
        out += [f"{where}: field {n!r} not listed" for n in sorted(set(fields) - set(rows))]
        out += [f"{where}: row {n!r} is no field" for n in sorted(set(rows) - set(fields))]
        for name, f in fields.items():
            if name not in rows:
                continue
            cell = rows[name][2]
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                if not cell.startswith("required"):
                    out.append(f"{where}: {name} has no default, the doc says {cell!r}")
            else:
                default = None if f.default is dataclasses.MISSING else f.default
                if not _default_says(cell, default):
                    out.append(f"{where}: {name}'s default is {default!r}, the doc says {cell!r}")
    return out


def test_every_class_of_the_scenario_format_has_a_table_of_every_field():
    problems = _problems(_classes(Scenario), _documented())
    assert problems == [], f"{DOC.name}, {SECTION!r}:\n" + "\n".join(problems)


@dataclasses.dataclass
class _Extra:
    """A table a future loader might accept (for the self-test)."""

    new_field: float = 1.0


def test_the_check_finds_an_undocumented_table_field_and_default():
    """What the check says, whatever else the doc gets wrong at the moment (the problems
    beyond those of the doc as it is)."""
    classes, documented = _classes(Scenario), _documented()
    before = set(_problems(classes, documented))
    assert set(_problems(classes | {"_Extra": _Extra}, documented)) - before == {
        "class _Extra has no table"}  # fmt: skip
    key = ("AcousticParams",)
    rows = dict(documented[key])
    del rows["usbl"]
    rows["T0"] = [*rows["T0"][:2], "50", rows["T0"][3]]
    rows["T_reply"] = rows["T_report"]
    assert set(_problems(classes, documented | {key: rows})) - before == {
        "table of AcousticParams: field 'usbl' not listed",
        "table of AcousticParams: row 'T_reply' is no field",
        "table of AcousticParams: T0's default is 5.0, the doc says '50'",
    }
    assert not _default_says("required", 0.0)
    assert not _default_says("`true`", False)
    assert not _default_says('`"left"`', "right")
    assert _default_says("[0, 0]", (0.0, 0.0)) and _default_says("1000", 1000.0)
