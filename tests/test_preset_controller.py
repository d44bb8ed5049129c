"""A preset names the controller(s) it is for; loading it for another is refused in one line.

Review finding (session 5): `mpcasv simulate experiments/scenarios/case1.toml --controller
mpc-single --params paper1-field` ran the MPC silently with its default weights and that
hybrid preset's domain, because the hybrid's preset (a speed and a domain) also validates as
an MPC preset. Every shipped preset now says ``controller = ...``; user presets without the
key keep the validation-only check (see :mod:`mpcasv.controllers.registry`).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_io_silent_options import _deploy_log

from mpcasv.cli import main
from mpcasv.config import DATA_DIR, ConfigError, load_toml
from mpcasv.controllers import CONTROLLERS, load_preset, make_controller
from mpcasv.io.replay import replay

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "experiments" / "scenarios" / "case1.toml"
SHIPPED = sorted(p.stem for p in (DATA_DIR / "presets").glob("*.toml"))


def _declared(stem: str) -> list[str]:
    value = load_toml(DATA_DIR / "presets" / f"{stem}.toml").get("controller")
    return [value] if isinstance(value, str) else list(value or [])


@pytest.mark.parametrize("stem", SHIPPED)
def test_every_shipped_preset_names_its_controller_and_is_refused_for_the_others(stem):
    declared = _declared(stem)
    assert declared and set(declared) <= set(CONTROLLERS), (stem, declared)
    for name in declared:
        load_preset(name, stem)  # validates for the controller it names
    for name in sorted(set(CONTROLLERS) - set(declared)):
        with pytest.raises(ConfigError) as err:
            load_preset(name, stem)
        lines = str(err.value).splitlines()
        assert len(lines) == 1, str(err.value)
        assert f"{stem}.toml" in lines[0] and repr(name) in lines[0], lines[0]
        assert all(d in lines[0] for d in declared), lines[0]


def test_the_review_command_is_refused_in_one_line(tmp_path, capsys):
    """The review's exact command: a hybrid preset for the MPC. Exit 2, one line naming the
    preset and both controllers, no run folder (and no MPC built: refused before)."""
    out = tmp_path / "run"
    code = main(["simulate", str(CASE1), "--controller", "mpc-single", "--params",
                 "paper1-field", "--duration", "2", "--out", str(out), "--quiet",
                 "--no-plots"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for word in ("paper1-field", "hybrid-single", "mpc-single"):
        assert word in lines[0], (word, lines[0])
    assert not out.exists()


def test_make_controller_refuses_too():
    with pytest.raises(ConfigError, match="paper2-field.*hybrid-multi.*'mpc-multi'"):
        make_controller("mpc-multi", 3, "paper2-field")


def _user_preset(tmp_path: Path, controller_line: str | None) -> Path:
    """paper1-field.toml with its ``controller`` line replaced (None: removed)."""
    text = (DATA_DIR / "presets" / "paper1-field.toml").read_text().splitlines()
    kept = [ln for ln in text if not ln.startswith("controller =")]
    assert len(kept) == len(text) - 1  # the shipped file has exactly one such line
    if controller_line is not None:
        kept.insert(1, controller_line)
    p = tmp_path / "mine.toml"
    p.write_text("\n".join(kept) + "\n")
    return p


def test_a_user_preset_without_the_key_keeps_the_validation_only_check(tmp_path):
    """Decision: accepted as before (fronts' trial presets written before the key existed
    must keep loading); a preset that validates only for other controllers is still said
    to be theirs."""
    p = _user_preset(tmp_path, None)
    assert load_preset("mpc-single", p).domain.alpha_inner == 5.0
    assert load_preset("hybrid-single", p).domain.alpha_inner == 5.0
    with pytest.raises(ConfigError, match="a preset for .*not for 'goto'"):
        load_preset("goto", p)


def test_a_list_serves_several_controllers(tmp_path):
    p = _user_preset(tmp_path, 'controller = ["hybrid-single", "mpc-single"]')
    assert load_preset("hybrid-single", p).speed == 2.5
    assert load_preset("mpc-single", p).speed == 2.5
    with pytest.raises(ConfigError) as err:
        load_preset("hybrid-multi", p)
    assert "hybrid-single / mpc-single" in str(err.value) and "'hybrid-multi'" in str(err.value)


@pytest.mark.parametrize("line,word", [('controller = "hybird-single"', "hybird-single"),
                                       ("controller = 3", "controller = 3"),
                                       ("controller = []", "non-empty")])  # fmt: skip
def test_a_bad_controller_key_is_refused_in_one_line(tmp_path, line, word):
    p = _user_preset(tmp_path, line)
    with pytest.raises(ConfigError) as err:
        load_preset("hybrid-single", p)
    lines = str(err.value).splitlines()
    assert len(lines) == 1 and str(p) in lines[0] and word in lines[0], str(err.value)


def test_deploy_config_with_a_preset_of_another_controller_is_refused(tmp_path, capsys):
    from mpcasv.io.config import load_deploy_config

    shipped = ROOT / "experiments" / "deploy" / "sitl-case3.toml"
    load_deploy_config(shipped)  # the shipped pairing (hybrid-single, paper1-field) loads
    text = shipped.read_text()
    assert text.count('name = "hybrid-single"') == 1
    bad = tmp_path / "deploy.toml"
    bad.write_text(text.replace('name = "hybrid-single"', 'name = "mpc-single"'))
    with pytest.raises(ConfigError, match="paper1-field.*hybrid-single.*'mpc-single'"):
        load_deploy_config(bad)
    code = main(["deploy", str(bad), "--dry-run", "--duration", "1"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err


def test_falsify_refuses_a_preset_of_another_controller(tmp_path, capsys):
    family = ROOT / "experiments" / "falsify" / "pursuer-single.toml"
    code = main(["falsify", str(family), "--controller", "mpc-single", "--params",
                 "paper1-field", "--budget", "1", "--out", str(tmp_path / "f"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    assert "paper1-field" in err and "hybrid-single" in err and "mpc-single" in err


@pytest.mark.parametrize("key,word", [
    ("solver.threads", "has no parameter 'solver' (its parameters: avoidance, domain, speed)"),
    ("nosuch", "has no parameter 'nosuch'"),
    ("domain.nosuch", "has no parameter 'domain.nosuch' ('domain' has parameters: "),
    ("speed.x", "has no parameter 'speed.x' ('speed' is a single value)"),  # was a traceback
])  # fmt: skip
def test_an_override_of_a_parameter_the_controller_lacks_is_refused_in_one_line(key, word):
    """New-user check: ``solver.threads`` (an MPC parameter) given to the hybrid's preset came
    out as pydantic's "solver: Unexpected keyword argument"."""
    with pytest.raises(ConfigError) as err:
        load_preset("hybrid-single", "paper1-field", {key: 2})
    lines = str(err.value).splitlines()
    assert len(lines) == 1 and f"override {key!r}: controller 'hybrid-single'" in lines[0]
    assert word in lines[0] and "Unexpected keyword" not in lines[0], lines[0]
    assert load_preset("mpc-single", "mpc-single", {"solver.threads": 2}).solver.threads == 2


def test_deploy_refuses_a_solver_override_of_a_hybrid_controller(tmp_path, capsys):
    text = (ROOT / "experiments" / "deploy" / "sitl-case3.toml").read_text()
    assert text.count('estimator = "perfect"\n') == 1
    bad = tmp_path / "deploy.toml"
    bad.write_text(text.replace('estimator = "perfect"\n', 'estimator = "perfect"\n'
                                'overrides = { "solver.threads" = 2 }\n'))  # fmt: skip
    code = main(["deploy", str(bad), "--prepare"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert (f"{bad}: controller: override 'solver.threads': controller 'hybrid-single' has no "
            "parameter 'solver'") in err, err  # fmt: skip


def test_the_refusal_names_no_command_it_may_not_have_come_from():
    """The refusal is raised for simulate, compare, deploy, replay, sitl, falsify and tune
    alike: it said "(simulate: --controller X)" whatever the command (a new user came
    through another one); it now names the preset's controller only."""
    with pytest.raises(ConfigError) as err:
        load_preset("mpc-single", "paper1-field")
    line = str(err.value)
    assert "simulate" not in line and "--controller" not in line, line
    assert "choose a preset of 'mpc-single' (its default: 'mpc-single'), or use this preset " \
           "with its controller ('hybrid-single')" in line, line


def test_simulate_records_the_preset_it_ran_with(tmp_path, capsys):
    """`simulate --controller X` without --params runs X's default preset: run.json said
    "preset": null; it names the default."""
    out = tmp_path / "run"
    assert main(["simulate", str(CASE1), "--controller", "goto", "--duration", "2", "--out",
                 str(out), "--quiet", "--no-plots"]) == 0  # fmt: skip
    assert json.loads((out / "run.json").read_text())["preset"] == "goto"


def test_a_run_records_the_parameters_it_ran_with(tmp_path, capsys):
    """run.json named the preset file only: a copied preset with one line changed (a new
    user's M2o trial, session 40) left no trace of what ran. It now holds the controller's
    parameters as run (``params``), for `simulate` and for each `compare` job."""
    preset = tmp_path / "slow.toml"
    text = (DATA_DIR / "presets" / "paper1-field.toml").read_text()
    preset.write_text(text.replace("speed = 2.5", "speed = 1.7", 1))
    out = tmp_path / "run"
    assert main(["simulate", str(CASE1), "--controller", "hybrid-single", "--params",
                 str(preset), "--duration", "2", "--out", str(out), "--quiet",
                 "--no-plots"]) == 0  # fmt: skip
    params = json.loads((out / "run.json").read_text())["params"]
    assert params["speed"] == 1.7 and params["domain"]["eps_plus"] > 0


def test_replay_records_the_preset_it_replayed_with(tmp_path, capsys):
    """`replay` of a log whose controller ran its default preset, or with another
    --controller, said "(preset None)"; it names the preset the replay built."""
    log = _deploy_log(tmp_path, {"name": "hybrid-single", "preset": None})
    rep = replay(log)
    assert (rep.controller, rep.preset, rep.n_steps, rep.n_differ) == (
        "hybrid-single", "paper1-sim", 1, 0)  # fmt: skip
    assert replay(log, controller="goto").preset == "goto"
    assert main(["replay", str(log), "--controller", "goto"]) == 0
    assert "with goto (preset goto)" in capsys.readouterr().out
