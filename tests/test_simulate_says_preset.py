"""``mpcasv simulate`` says which controller and preset it ran: with ``--controller`` other
than the scenario's, the scenario's preset (made for its own controller) is not used and
the controller's default is, which a new user's trial (session 45) found only in run.json: a
hybrid-single run of an MPC scenario stood still for 300 s on ``paper1-sim``'s 3.5-km donut."""

from __future__ import annotations

from mpcasv.cli import main

SCENARIO = """
name = "s"
duration = 20.0
controller = "mpc-single"
preset = "mpc-single"
[[auv]]
name = "a"
start = { N = 150.0, E = 0.0, depth = 20.0 }
[auv.behaviour.loiter]
"""


def test_simulate_names_the_preset_and_why_it_is_not_the_scenarios(tmp_path, capsys):
    (tmp_path / "s.toml").write_text(SCENARIO)
    args = ["simulate", str(tmp_path / "s.toml"), "--no-plots", "--quiet"]
    assert main([*args, "--controller", "hybrid-single", "--out", str(tmp_path / "a")]) == 0
    out = capsys.readouterr().out
    assert ("  controller hybrid-single, preset paper1-sim (its default: the scenario's preset "
            "'mpc-single' is for its controller 'mpc-single')") in out.splitlines(), out
    assert main([*args, "--controller", "hybrid-single", "--params", "paper1-field", "--out",
                 str(tmp_path / "b")]) == 0  # fmt: skip
    assert "  controller hybrid-single, preset paper1-field" in capsys.readouterr().out.splitlines()
