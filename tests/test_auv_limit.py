"""A preset's AUV limit is refused before anything compiles or runs (the tester's defect: 5 AUVs
with ``mpc-multi`` / ``mpc-multi-order`` compiled a 5-AUV MPC for 38 s, then crashed at the first
control step in ``best_order`` with a traceback, exit 1; in ``compare`` a job error).

The limit is declared once (:func:`mpcasv.mpc.order.auv_limit`, ``MAX_ENUMERATED``, listed in
the ``mpc-multi`` kind's ``auv_limit``) and read by ``check_auv_count``: simulate, the
suite validation of compare and tune, sitl, deploy and ``make_controller``.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from mpcasv.cli import main
from mpcasv.config import ConfigError
from mpcasv.controllers import load_preset, make_controller
from mpcasv.controllers.registry import auv_limit, check_auv_count
from mpcasv.experiments.suite import expand
from mpcasv.mpc.order import MAX_ENUMERATED

STARTS = [(200.0, 0.0), (0.0, 200.0), (-200.0, 0.0), (0.0, -200.0), (150.0, 150.0)]


def scenario(n_auv: int, preset: str = "mpc-multi-order") -> str:
    text = (f'name = "m{n_auv}loit"\nduration = 20.0\ncontroller = "mpc-multi"\n'
            f'preset = "{preset}"\n')  # fmt: skip
    for k, (N, E) in enumerate(STARTS[:n_auv]):
        text += (f'\n[[auv]]\nname = "a{k}"\nstart = {{ N = {N}, E = {E}, depth = 0.0 }}\n'
                 "[auv.behaviour.loiter]\n")  # fmt: skip
    return text


def one_line_exit_2(code: int, err: str, *words: str) -> str:
    assert code == 2, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for w in words:
        assert w in lines[0], (w, err)
    return lines[0]


def test_the_check_reads_the_preset_limit():
    order = load_preset("mpc-multi", "mpc-multi-order")
    assert auv_limit("mpc-multi", order)[0] == MAX_ENUMERATED == 4
    assert check_auv_count("mpc-multi", 4, order, "mpc-multi-order").name == "mpc-multi"
    with pytest.raises(ConfigError, match=r"'mpc-multi-order' handles at most 4 AUVs, the "
                                          r"scenario has 5"):  # fmt: skip
        check_auv_count("mpc-multi", 5, order, "mpc-multi-order")
    # the age rule has no limit; without parameters only the kind's multi is checked
    assert auv_limit("mpc-multi", load_preset("mpc-multi", "mpc-multi")) is None
    check_auv_count("mpc-multi", 8, load_preset("mpc-multi", "mpc-multi"), "mpc-multi")
    check_auv_count("mpc-multi", 8)
    with pytest.raises(ConfigError, match="handles one AUV"):
        check_auv_count("hybrid-single", 4)


def test_make_controller_refuses_before_building():
    with pytest.raises(ConfigError, match="at most 4 AUVs"):
        make_controller("mpc-multi", 5, "mpc-multi-order")


def test_a_built_controller_reset_for_more_auvs_refuses_before_rebuilding(monkeypatch):
    """Through the Python API a controller built for 2 AUVs may be run on a 5-AUV scenario
    (``simulate`` calls ``reset(5)``): refused there, before a 5-AUV problem is built (it
    compiled one, then crashed in ``best_order`` at the first step)."""
    ctrl = make_controller("mpc-multi", 2, "mpc-multi-order")
    monkeypatch.setattr(ctrl, "_setup", lambda n: pytest.fail(f"rebuilt for {n} AUVs"))
    with pytest.raises(ValueError, match="at most 4 AUVs with these parameters, got 5"):
        ctrl.reset(5)


def test_simulate_refuses_five_auvs_in_one_line_and_writes_nothing(tmp_path, capsys):
    path = tmp_path / "m5loit.toml"
    path.write_text(scenario(5))
    out = tmp_path / "out"
    code = main(["simulate", str(path), "--out", str(out)])
    one_line_exit_2(code, capsys.readouterr().err, str(path), "mpc-multi-order",
                    "at most 4 AUVs", "has 5")  # fmt: skip
    assert not out.exists()


def test_sitl_refuses_five_auvs(tmp_path, capsys):
    path = tmp_path / "m5loit.toml"
    path.write_text(scenario(5))
    code = main(["sitl", str(path), "--duration", "1", "--out", str(tmp_path / "out")])
    one_line_exit_2(code, capsys.readouterr().err, "at most 4 AUVs", "has 5")
    assert not (tmp_path / "out").exists()


def test_deploy_config_with_five_auvs_is_refused(tmp_path, capsys):
    src = Path(__file__).resolve().parents[1] / "experiments" / "deploy" / "sitl-case6.toml"
    text = src.read_text().replace('name = "hybrid-multi"\npreset = "paper2-field"',
                                   'name = "mpc-multi"\npreset = "mpc-multi-order"')
    assert "mpc-multi-order" in text
    more = "".join(f'\n[[vehicle]]\nrole = "auv"\nname = "sitl-auv{k}"\n' for k in (4, 5))
    text = text.replace("\n[controller]", more + "\n[controller]")
    path = tmp_path / "five.toml"
    path.write_text(text)
    code = main(["deploy", str(path), "--dry-run", "--duration", "1"])
    one_line_exit_2(code, capsys.readouterr().err, str(path), "at most 4 AUVs",
                    "the config has 5")  # fmt: skip


SUITE = """
name = "limit"
scenarios = ["m4loit.toml", "m5loit.toml"]
seeds = [0]

[[controllers]]
label = "order"
name = "mpc-multi"
preset = "mpc-multi-order"
"""


def test_compare_refuses_at_suite_validation(tmp_path, capsys):
    (tmp_path / "m4loit.toml").write_text(scenario(4))
    (tmp_path / "m5loit.toml").write_text(scenario(5))
    suite = tmp_path / "suite.toml"
    suite.write_text(textwrap.dedent(SUITE))
    with pytest.raises(ConfigError) as err:
        expand(suite)
    msg = str(err.value)
    for w in (str(suite), "'m5loit'", "at most 4 AUVs", "has 5"):
        assert w in msg, (w, msg)
    # the 4-AUV scenario alone expands
    suite.write_text(textwrap.dedent(SUITE).replace(', "m5loit.toml"', ""))
    assert {j.n_auv for j in expand(suite).jobs} == {4}
    suite.write_text(textwrap.dedent(SUITE))
    out = tmp_path / "out"
    code = main(["compare", str(suite), "--out", str(out), "--workers", "1"])
    one_line_exit_2(code, capsys.readouterr().err, "at most 4 AUVs")
    assert not out.exists()  # nothing started
