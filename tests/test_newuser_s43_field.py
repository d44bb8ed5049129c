"""A field engineer's findings (session 43, new-user trial): a restarted deploy wrote over the
trial's log (now kept, renamed); watchdog and timeout values that switch the watchdogs off
(1e5 s) or turn every gap into a verdict (0.001 s: 298 plan starts in 15 s) were accepted;
``--prepare`` printed its progress as warnings. Each refusal is one line naming the field
and the value, exit 2, before anything is written."""

from __future__ import annotations

import json
import logging

import pytest
from test_deploy_usbl import _log
from test_io_bad_input import _deploy_config, _exit_code, _refused

from mpcasv.config import ConfigError
from mpcasv.io.logs import FolderLock, keep_earlier, read_jsonl
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
    "timeout within two periods": ({"control_period": "5.0", "followref_timeout": "9.0"},
                                   ["link.followref_timeout", "9 s", "control_period = 5 s",
                                    "one late or skipped decision"]),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BAD))
@pytest.mark.parametrize("mode", [["--prepare"], ["--dry-run", "--duration", "1"]])
def test_deploy_refuses_watchdogs_and_timeouts_that_mean_nothing(case, mode, tmp_path, capsys):
    lines, words = BAD[case]
    path = _deploy_config(tmp_path, **lines)
    _refused(["deploy", path, "--quiet", *mode], capsys, str(path), *words)
    assert not (tmp_path / "log").exists()


def test_a_deploy_keeps_an_earlier_runs_log_instead_of_writing_over_it(tmp_path, capsys):
    # a restart wrote over the trial's record; refusing the folder (this session's first
    # answer) broke docs/deploy.md's dry run then run of one configuration: now kept
    path = _deploy_config(tmp_path)
    log = tmp_path / "log"
    log.mkdir()
    (log / "deploy.jsonl").write_text('{"kind": "the trial\'s record"}\n')
    (log / "imc.lsf").write_bytes(b"LSF of the trial")
    assert _exit_code(["deploy", path, "--quiet", "--prepare"]) == 0  # --prepare writes none
    assert sorted(p.name for p in log.iterdir()) == ["deploy.jsonl", "imc.lsf"]
    run = ["deploy", path, "--quiet", "--dry-run", "--duration", "1"]
    assert _exit_code(run) == 1  # no vehicle heard: ran, never decided
    capsys.readouterr()
    assert (log / "deploy.1.jsonl").read_text() == '{"kind": "the trial\'s record"}\n'
    assert (log / "imc.1.lsf").read_bytes() == b"LSF of the trial"
    started = [r for r in read_jsonl(log / "deploy.jsonl", "event") if r["event"] == "started"]
    assert started[0]["earlier_log_kept"] == {"deploy.jsonl": "deploy.1.jsonl",
                                              "imc.lsf": "imc.1.lsf"}  # fmt: skip
    assert _exit_code(run) == 1  # and the next run keeps this one as .2
    assert {p.name for p in log.iterdir()} == {"deploy.jsonl", "imc.lsf", "deploy.1.jsonl",
                                               "imc.1.lsf", "deploy.2.jsonl", "imc.2.lsf",
                                               "deploy.lock"}  # fmt: skip
    first = [r for r in read_jsonl(log / "deploy.2.jsonl", "event") if r["event"] == "started"]
    assert first[0]["earlier_log_kept"] == started[0]["earlier_log_kept"]  # the first run's


def test_keep_earlier_shares_one_number_and_skips_empty_files(tmp_path):
    (tmp_path / "deploy.jsonl").write_text("x\n")
    (tmp_path / "imc.lsf").write_text("")  # a start that failed before writing: no record
    (tmp_path / "imc.1.lsf").write_text("older\n")  # 1 taken by one of the names: 2 for all
    assert keep_earlier(tmp_path) == {"deploy.jsonl": "deploy.2.jsonl"}
    assert keep_earlier(tmp_path / "none") == {}


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


def test_replay_takes_a_logged_watchdog_this_version_bounds_tighter(tmp_path):
    # a review: a log written with asv_stale_s = 0.5 (accepted then) could no longer be
    # replayed with another controller (its guard is built from the logged [watchdog])
    log, _ = _log(tmp_path, fix_times=True)
    recs = [json.loads(ln) for ln in log.read_text().splitlines()]
    recs[0]["config"]["watchdog"]["asv_stale_s"] = 0.5
    log.write_text("".join(json.dumps(r) + "\n" for r in recs))
    rep = replay(log, controller="hybrid-single")
    assert rep.n_steps == 4
    (note,) = [n for n in rep.notes if "[watchdog]" in n]
    assert "asv_stale_s" in note and "replayed with the logged values" in note
    assert "\n" not in note
    recs[0]["config"]["watchdog"]["asv_stale_s"] = "3"  # a wrong type is no bound: refused
    log.write_text("".join(json.dumps(r) + "\n" for r in recs))
    with pytest.raises(ConfigError, match="asv_stale_s"):
        replay(log, controller="hybrid-single")


def test_a_second_deploy_on_a_folder_in_use_is_refused(tmp_path, capsys):
    # a review: two deploys on one folder renamed and interleaved each other's logs
    path = _deploy_config(tmp_path)
    log = tmp_path / "log"
    held = FolderLock(log)  # as a running deploy holds it
    try:
        _refused(["deploy", path, "--quiet", "--dry-run", "--duration", "1"], capsys,
                 "log.dir", str(log), "in use by another running deploy")  # fmt: skip
        assert sorted(p.name for p in log.iterdir()) == ["deploy.lock"]
    finally:
        held.close()
    assert _exit_code(["deploy", path, "--quiet", "--dry-run", "--duration", "1"]) == 1
    FolderLock(log).close()  # the run released it
