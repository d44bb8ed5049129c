"""A vessel file that ``mpcasv identify`` marked VALIDATION FAILED is refused by every loader
(``tune``, ``simulate``, ``compare``, ``deploy``: :func:`mpcasv.models.params.load_vessel`) in
one line, exit 2, unless its ``[identification]`` table says ``use_anyway = true``
(:mod:`mpcasv.models.ident_record`). Before, the verdict was only a header comment, which
TOML loaders drop: ``tune yaw`` tuned on such a file, exit 0 (a new user's finding,
scratch ``zz/id_tiny.toml``)."""

from __future__ import annotations

import tomllib

import pytest
import tomli_w
from test_ident_walkthrough import _fake, _zigzag

from mpcasv.cli import main
from mpcasv.config import DATA_DIR, ConfigError
from mpcasv.experiments.suite_file import EXPERIMENTS_DIR, SCENARIOS_DIR
from mpcasv.models.params import load_vessel

REFUSED = "mpcasv identify marked this vessel file VALIDATION FAILED"


@pytest.fixture
def prior():
    return load_vessel("gretha")


@pytest.fixture
def failed(prior, tmp_path, monkeypatch):
    """A vessel file as ``mpcasv identify`` writes it when the validation fails (exit 1):
    the fit is a stand-in whose held-out u fit is -0.6 %."""
    import mpcasv.io.identlog as identlog

    monkeypatch.setattr(identlog, "identify", lambda logs, p, c, **kw: _fake(p, fit_u=-0.6))
    log = tmp_path / "z.csv"
    _zigzag(prior, 121.0).to_csv(log, index=False)
    out = tmp_path / "failed.toml"
    assert main(["identify", str(log), "--coeffs", "X_u", "--out", str(out), "--quiet"]) == 1
    return out


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_a_failed_identification_is_marked_in_the_file_and_refused_on_load(failed, capsys):
    rec = tomllib.loads(failed.read_text())["identification"]
    assert rec == {"validation": "failed", "why": "held-out fit below 0 % for u -0.6 %",
                   "use_anyway": False}  # fmt: skip
    with pytest.raises(ConfigError) as exc:
        load_vessel(failed)
    msg = str(exc.value)
    assert "\n" not in msg and REFUSED in msg and "u -0.6 %" in msg
    assert "use_anyway = true" in msg
    capsys.readouterr()
    # tune: exit 2, one line (it tuned and wrote the execution file, exit 0, before)
    assert main(["tune", "yaw", "--vessel", str(failed), "--out",
                 str(failed.parent / "tuned")]) == 2  # fmt: skip
    line = _one_line(capsys)
    assert line.startswith("mpcasv tune: error: ") and REFUSED in line, line
    assert not (failed.parent / "tuned").exists()


def test_simulate_compare_and_deploy_refuse_a_failed_vessel(failed, tmp_path, capsys):
    text = (SCENARIOS_DIR / "case3.toml").read_text().replace(
        "[asv.start]", f'[asv]\nvessel = "{failed}"\n\n[asv.start]', 1)  # fmt: skip
    scen = tmp_path / "mine.toml"
    scen.write_text(text)
    capsys.readouterr()
    assert main(["simulate", str(scen), "--out", str(tmp_path / "sim")]) == 2
    assert REFUSED in _one_line(capsys)
    suite = tmp_path / "suite.toml"
    suite.write_text(f'name = "s"\nscenarios = ["{scen}"]\nseeds = [0]\nduration = 30.0\n\n'
                     '[[controllers]]\nlabel = "hybrid"\nsingle = "hybrid-single"\n'
                     'multi = "hybrid-multi"\npreset = "scenario"\n')  # fmt: skip
    assert main(["compare", str(suite), "--out", str(tmp_path / "cmp")]) == 2
    assert REFUSED in _one_line(capsys)
    cfg = tomllib.loads((EXPERIMENTS_DIR / "deploy" / "sitl-case3.toml").read_text())
    cfg["controller"]["vessel"] = str(failed)
    cfg["log"]["dir"] = str(tmp_path / "log")
    dep = tmp_path / "deploy.toml"
    dep.write_text(tomli_w.dumps(cfg))
    assert main(["deploy", str(dep), "--prepare"]) == 2
    assert REFUSED in _one_line(capsys)


def test_use_anyway_accepts_a_failed_vessel(failed):
    data = tomllib.loads(failed.read_text())
    data["identification"]["use_anyway"] = True
    failed.write_text(tomli_w.dumps(data))
    assert load_vessel(failed).name == "gretha-identified"


def test_a_file_marked_only_by_the_old_header_is_refused_too(tmp_path):
    """Files written before the table existed carry only the header line."""
    path = tmp_path / "old.toml"
    path.write_text("# VALIDATION FAILED: held-out fit below 0 % for u: this model predicts "
                    "the validation data worse than their mean; do not use it as is.\n"
                    + (DATA_DIR / "vessels" / "gretha.toml").read_text())  # fmt: skip
    with pytest.raises(ConfigError, match="VALIDATION FAILED .*its header: VALIDATION FAILED: "
                       "held-out fit below 0 % for u.*use_anyway = true"):  # fmt: skip
        load_vessel(path)


def test_a_passed_identification_and_the_shipped_vessels_load(prior, tmp_path, monkeypatch):
    import mpcasv.io.identlog as identlog

    monkeypatch.setattr(identlog, "identify", lambda logs, p, c, **kw: _fake(p))
    log = tmp_path / "z.csv"
    _zigzag(prior, 121.0).to_csv(log, index=False)
    out = tmp_path / "ok.toml"
    assert main(["identify", str(log), "--coeffs", "X_u", "--out", str(out), "--quiet"]) == 0
    assert tomllib.loads(out.read_text())["identification"] == {"validation": "passed"}
    assert load_vessel(out).name == "gretha-identified"
    for p in sorted((DATA_DIR / "vessels").glob("*.toml")):
        assert load_vessel(p.stem).name == p.stem


def test_a_malformed_identification_table_is_refused(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text((DATA_DIR / "vessels" / "gretha.toml").read_text()
                    + '\n[identification]\nvalidation = "maybe"\n')  # fmt: skip
    with pytest.raises(ConfigError, match=r"\[identification\]: validation"):
        load_vessel(path)
