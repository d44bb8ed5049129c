"""Where the MPC's "current above the tested one" is said (a new user's findings, session
29): in ``mpcasv simulate`` the controller's stderr line and the printed metric; in a sweep
one line at its end naming the runs (each job's own line named no job and broke the progress
bar); in a deploy the event ``current_untested`` only (the controller's line printed the
vehicle's epoch time as "t = 1796403867 s")."""

from __future__ import annotations

import textwrap

from mpcasv.cli import main

LOITER = """
name = "loiter"
duration = {duration}
controller = "mpc-single"
preset = "mpc-single"
current = [0.0, -1.5]
[asv.start]
N = -100.0
E = 0.0
[[auv]]
name = "a"
start = {{ N = 0.0, E = 0.0, depth = 0.0 }}
[auv.behaviour.loiter]
"""


SUITE = textwrap.dedent("""
    name = "s"
    scenarios = ["loiter.toml"]
    seeds = [0]
    current = [[0.0, -1.5], [0.0, -0.5]]
    plots = "none"
    [[controllers]]
    label = "mpc"
    single = "mpc-single"
    multi = "mpc-multi"
    preset = "mpc-single"
    """)


def test_a_sweep_says_it_once_at_its_end_naming_the_runs(tmp_path, capsys):
    (tmp_path / "loiter.toml").write_text(LOITER.format(duration=20.0))
    suite = tmp_path / "s.toml"
    suite.write_text(SUITE)
    out = tmp_path / "out"
    assert main(["compare", str(suite), "--out", str(out), "--workers", "1",
                 "--job-timeout", "0", "--no-report", "--quiet"]) == 0  # fmt: skip
    err = capsys.readouterr().err
    assert "at t = " not in err, err  # no job's own line
    said = [line for line in err.splitlines() if "runs planned with a current above" in line]
    assert len(said) == 1, err
    assert said[0].startswith("mpcasv: warning: 1 of 2 runs planned"), said
    assert "loiter (0,-1.5)" in said[0], said


def test_a_tuning_batch_says_it_once_naming_the_runs(tmp_path, capsys):
    """``mpcasv tune controller`` runs its trials' jobs through the same worker code (each
    job's own line off): each batch says it in one line."""
    from mpcasv.experiments.suite import expand
    from mpcasv.experiments.tune_controller import run_batch

    (tmp_path / "loiter.toml").write_text(LOITER.format(duration=20.0))
    suite = tmp_path / "s.toml"
    suite.write_text(SUITE)
    jobs = expand(suite).jobs
    rows = run_batch(jobs, tmp_path / "train", 1, None, True, "trials 0-0")
    assert len(rows) == 2
    err = capsys.readouterr().err
    assert "at t = " not in err, err
    said = [line for line in err.splitlines() if "runs planned with a current above" in line]
    assert len(said) == 1 and "1 of 2 runs" in said[0], err


def test_simulate_says_it_and_prints_the_metric(tmp_path, capsys):
    sc = tmp_path / "loiter.toml"
    sc.write_text(LOITER.format(duration=20.0))
    assert main(["simulate", str(sc), "--out", str(tmp_path / "run"), "--no-plots",
                 "--quiet"]) == 0  # fmt: skip
    cap = capsys.readouterr()
    assert cap.err.count("above the 1 m/s the MPC has been run in") == 1, cap.err
    line = [x for x in cap.out.splitlines() if x.strip().startswith("current_untested_s")]
    assert len(line) == 1 and float(line[0].split()[1]) > 10.0, cap.out


def test_a_deploy_leaves_it_to_its_event(tmp_path):
    from test_deploy_field import _mpc_cfg

    from mpcasv.io.config import deploy_config_from_dict
    from mpcasv.io.deploycontroller import build_controller

    ctl = build_controller(deploy_config_from_dict(_mpc_cfg(tmp_path)), log=lambda *a: None)
    assert ctl.say_current is False
