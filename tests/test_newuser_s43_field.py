"""A field engineer's findings (session 43, new-user trial): a restarted deploy wrote over the
trial's log; watchdog and timeout values that switch the watchdogs off (1e5 s) or turn every
gap into a verdict (0.001 s: 298 plan starts in 15 s) were accepted; ``--prepare`` printed its
progress as warnings. Each refusal is one line naming the field and the value, exit 2,
before anything is written."""

from __future__ import annotations

import logging

import pytest
from test_deploy_usbl import _log
from test_io_bad_input import _deploy_config, _exit_code, _refused

from mpcasv.io.replay import replay

# (lines replaced, words the one line must hold: the field and the value)
BAD = {
    "tiny asv_stale_s": ({"asv_stale_s": "0.001"}, ["watchdog.asv_stale_s", "0.001 s",
                                                    "[1, 60] s"]),
    "huge asv_stale_s": ({"asv_stale_s": "100000.0"}, ["watchdog.asv_stale_s", "100000 s"]),
    "huge auv_stale_s": ({"auv_stale_s": "100000.0"}, ["watchdog.auv_stale_s", "100000 s"]),
    "huge followref_timeout": ({"followref_timeout": "100000.0"},
                               ["link.followref_timeout", "100000 s", "[1, 300] s"]),
    "tiny control period": ({"control_period": "0.001"}, ["controller.control_period",
                                                          "0.001 s", "at least 0.1 s"]),
    "timeout within a period": ({"control_period": "5.0", "followref_timeout": "4.0"},
                                ["link.followref_timeout", "4 s", "control_period = 5 s",
                                 "between two decisions"]),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BAD))
@pytest.mark.parametrize("mode", [["--prepare"], ["--dry-run", "--duration", "1"]])
def test_deploy_refuses_watchdogs_and_timeouts_that_mean_nothing(case, mode, tmp_path, capsys):
    lines, words = BAD[case]
    path = _deploy_config(tmp_path, **lines)
    _refused(["deploy", path, "--quiet", *mode], capsys, str(path), *words)
    assert not (tmp_path / "log").exists()


@pytest.mark.parametrize("name", ["deploy.jsonl", "imc.lsf"])
@pytest.mark.parametrize("mode", [["--prepare"], ["--dry-run", "--duration", "1"]])
def test_a_deploy_never_writes_over_an_earlier_runs_log(name, mode, tmp_path, capsys):
    path = _deploy_config(tmp_path)
    log = tmp_path / "log"
    log.mkdir()
    (log / name).write_text("the trial's record\n")
    _refused(["deploy", path, "--quiet", *mode], capsys, "log.dir", str(log), name,
             "never writes over a field record")  # fmt: skip
    assert (log / name).read_text() == "the trial's record\n"
    assert sorted(p.name for p in log.iterdir()) == [name]
    # an empty file of a start that failed before writing is no record: taken
    (log / name).write_text("")
    assert _exit_code(["deploy", path, "--quiet", "--prepare"]) == 0


def test_prepare_says_its_progress_as_information_not_as_warnings(tmp_path, caplog):
    # the console prints a warning as "mpcasv.deploy: warning: ..." (session 42)
    path = _deploy_config(tmp_path)
    with caplog.at_level(logging.INFO, logger="mpcasv.deploy"):
        assert _exit_code(["deploy", path, "--prepare"]) == 0
    said = [(r.levelno, r.getMessage()) for r in caplog.records if r.name == "mpcasv.deploy"]
    assert any("ready in" in m for _, m in said), said
    assert all(lv == logging.INFO for lv, m in said if "ready in" in m or "preparing" in m)


def test_replay_says_when_the_log_is_cut_or_has_no_summary(tmp_path):
    # a log cut mid-line replayed "80 decisions, 0 differ" without a word
    log, _ = _log(tmp_path, fix_times=True)
    assert replay(log).notes == ()  # a whole log of a run that ended
    lines = log.read_text().splitlines()
    log.write_text("\n".join(lines[:-1]) + "\n" + lines[-1][:7])  # the summary cut
    notes = replay(log).notes
    assert any("last line is cut" in n for n in notes), notes
    assert any("no 'summary' record" in n for n in notes), notes
    log.write_text("\n".join(lines[:-1]) + "\n")  # killed before the summary
    notes = replay(log).notes
    assert not any("cut" in n for n in notes) and any("no 'summary'" in n for n in notes)
