"""A TOML file saved with a UTF-8 byte-order mark (some Windows editors add one; TOML forbids
it) was refused as "Invalid statement (at line 1, column 1)", which does not name the cause
(a helper's sweep, session 35). The message now says what it is and what to do."""

from __future__ import annotations

from pathlib import Path

import pytest

from mpcasv.cli import main
from mpcasv.config import ConfigError, load_toml


def test_a_byte_order_mark_is_named(tmp_path: Path):
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbfname = 'x'\n")
    with pytest.raises(ConfigError, match="byte-order mark"):
        load_toml(path)
    path.write_bytes(b"name = 'x'\n")  # the same file without it is read
    assert load_toml(path) == {"name": "x"}


def test_other_syntax_errors_keep_the_parsers_message(tmp_path: Path):
    path = tmp_path / "bad.toml"
    path.write_bytes(b"name = \n")
    with pytest.raises(ConfigError, match="not valid TOML: Invalid value") as err:
        load_toml(path)
    assert "byte-order" not in str(err.value)


def test_simulate_refuses_it_in_one_line_with_exit_2(tmp_path: Path, capsys):
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbfname = 'x'\n")
    assert main(["simulate", str(path), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "byte-order mark (BOM)" in err[0]
