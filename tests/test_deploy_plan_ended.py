"""DUNE ends our FollowReference plan (a field engineer's replay of recorded DUNE traffic,
session 47): an operator's stop, a vehicle error, or the maneuver gone without a word.

Before, a PlanControl FAILURE with our request id and info "plan stopped by operator (Neptus)"
was only an INFO ``plan_control`` event labelled ``ours: False``; the deploy went on deciding
and sending References for as long as it ran, every decision showing the last, stale
FollowRefState, and its shutdown waited ``plan_done_timeout`` for an answer to a MANDONE sent to
no maneuver. Nothing watched the FollowRefState's age, which real DUNE sends in answer to every
Reference only while the maneuver runs (DUNE Maneuver/FollowReference; the recording: one
FollowRefState per Reference).

The fake DUNE here answers as the recorded Otter does (shared/data/dune-traffic/README.md §8,
§10): START with SUCCESS "plan loaded" then "FollowReference: executing maneuver" (op START, our
request id), each Reference with a FollowRefState whose ``control_src`` is ours, MANDONE with
SUCCESS "plan completed". The deploy runs on a hand-advanced clock (ASV and AUV states at 2 Hz,
the watchdog pass every 0.25 s), DUNE's answers delivered right after what they answer.
"""

from __future__ import annotations

import asyncio
import dataclasses

import imcpy
import pytest
from test_deploy_speed_watch import _state
from test_io_cases import dry_deploy

from mpcasv.config import ConfigError
from mpcasv.io import commands
from mpcasv.io.deploy import PLAN_ENDED, RUNNING
from mpcasv.io.imc import stamp
from mpcasv.io.logs import read_jsonl

PC = imcpy.PlanControl
FRS = imcpy.FollowRefState
ASV, AUV = ("10.0.10.50", 6002), ("10.0.10.60", 6002)
ASV_ID, AUV_ID, US = 0x2801, 0x2811, 0x4001
MANDONE = int(imcpy.Reference.FlagsBits.MANDONE)


class FakeDune:
    """The ASV's DUNE, answering what the deploy sends (its ``_send_raw``), as recorded.

    ``answer_references = False``: the maneuver is gone and DUNE says nothing more (no
    FollowRefState); the link otherwise lives (states, and PlanControl answers to a START)."""

    def __init__(self, dep, clock) -> None:
        self.dep, self.clock = dep, clock
        self.sent: list[tuple[float, imcpy.Message]] = []  # what the deploy sent the ASV
        self.outbox: list[imcpy.Message] = []
        self.answer_references = True
        self.request: tuple[int, str] | None = None  # the running plan's (request id, plan id)
        dep.link._send_raw = self._receive

    def _receive(self, data: bytes, addr, p=None) -> bool:
        m = imcpy.Packet.deserialize(data)
        self.sent.append((self.clock.t, m))
        if isinstance(m, PC) and m.type == PC.TypeEnum.REQUEST and m.op == PC.OperationEnum.START:
            self.request = (m.request_id, m.plan_id)
            self.answer_references = True  # a new maneuver answers
            for info in ("plan loaded", "FollowReference: executing maneuver"):
                self.outbox.append(self.plan_control(PC.TypeEnum.SUCCESS, info))
            self.outbox.append(self.followref(FRS.StateEnum.WAIT))
        elif isinstance(m, imcpy.Reference) and self.request is not None:
            if int(m.flags) & MANDONE:
                self.outbox.append(self.plan_control(PC.TypeEnum.SUCCESS, "plan completed"))
                self.request = None
            elif self.answer_references:
                self.outbox.append(self.followref(FRS.StateEnum.GOTO))
        return True

    def plan_control(self, kind, info: str, op=PC.OperationEnum.START, request=None):
        pc = PC()
        rid, plan_id = request or self.request
        pc.type, pc.op, pc.request_id, pc.plan_id, pc.info = kind, op, rid, plan_id, info
        return pc

    @staticmethod
    def followref(state) -> imcpy.FollowRefState:
        m = FRS()
        m.control_src, m.control_ent, m.state = US, 0xFF, state
        m.proximity = FRS.ProximityBits.FAR
        return m

    def deliver(self, *extra: imcpy.Message) -> None:
        """DUNE's answers so far, then ``extra``, to the deploy (addressed to it)."""
        msgs, self.outbox = self.outbox + list(extra), []
        for m in msgs:
            raw = stamp(m, ASV_ID, US, self.clock.t).serialize()
            self.dep.link.handle_datagram(raw, ASV)

    def references(self, after: float = -1.0) -> list[imcpy.Reference]:
        return [m for t, m in self.sent if isinstance(m, imcpy.Reference) and t > after]

    def starts(self) -> list[imcpy.PlanControl]:
        return [m for _, m in self.sent if isinstance(m, PC)]


def _deploy(tmp_path, request, **link):
    """A deploy that commands (not a dry run) with a :class:`FakeDune` ASV; closed at the
    test's end (it never runs)."""
    dep, clock = dry_deploy(tmp_path, link={"bind": "127.0.0.1", "port": 0, "announce_to": []}
                            | link)  # fmt: skip
    request.addfinalizer(dep.close)
    dep.dry_run = False
    return dep, clock, FakeDune(dep, clock)


def _run(dep, clock, dune, seconds: float) -> None:
    """``seconds`` of both vehicles' states at 2 Hz (the AUV 1000 m north: the controller
    transits), DUNE's answers after each, the watchdog pass every 0.25 s."""
    for _ in range(int(4 * seconds)):
        clock.t += 0.25
        if round(clock.t * 4) % 2 == 0:
            dep.link.handle_datagram(_state(AUV_ID, clock.t, 1000.0, 0.0), AUV)
            dep.link.handle_datagram(_state(ASV_ID, clock.t, 0.0, 0.5), ASV)
            dune.deliver()
        dep.watch()
        dune.deliver()


def _events(dep, name=None) -> list[dict]:
    dep.jsonl.flush()
    ev = read_jsonl(dep.jsonl.path, "event")
    return [e for e in ev if name is None or e["event"] == name]


def _exit_status(summary: dict, monkeypatch, capsys) -> tuple[int, str]:
    """What ``mpcasv deploy`` makes of a run that returned ``summary``."""
    monkeypatch.setattr("mpcasv.io.deploy.run_deploy", lambda *a, **k: summary)
    args = type("Args", (), {"config": "x.toml", "dry_run": False, "log_dir": None,
                             "duration": None, "prepare": False, "quiet": True})()  # fmt: skip
    status = commands.run_deploy_cli(args)
    return status, capsys.readouterr().err


def test_plan_stopped_by_the_operator_ends_the_run(tmp_path, request, monkeypatch, capsys):
    """(a) PlanControl FAILURE with our request id and plan id, "plan stopped by operator":
    ours, event plan_ended (a warning naming DUNE's info), no more decisions or References
    while states keep coming, nothing restarted, the run's stop set, no standby or MANDONE at
    shutdown (no wait for an answer), and ``mpcasv deploy`` exits 1 saying why."""
    dep, clock, dune = _deploy(tmp_path, request)
    dep.stop_event = stop = asyncio.Event()  # as run() sets it
    _run(dep, clock, dune, 10.0)
    assert dep.phase == RUNNING and dep.steps >= 8 and len(dune.starts()) == 1
    steps, t_end = dep.steps, clock.t
    info = "plan stopped by operator (Neptus)"
    dune.deliver(dune.plan_control(PC.TypeEnum.FAILURE, info))
    dune.answer_references = False
    ended = _events(dep, "plan_ended")
    assert len(ended) == 1, _events(dep)
    assert ended[0]["info"] == info and ended[0]["type"] == "FAILURE"
    assert ended[0]["op"] == "START" and ended[0]["request_id"] == dune.starts()[0].request_id
    assert "plan_ended" in dep.WARNING_EVENTS  # on the console with --quiet too
    assert dep.phase == PLAN_ENDED and stop.is_set()
    _run(dep, clock, dune, 10.0)  # the link lives on until the run has stopped
    assert dep.steps == steps and dune.references(after=t_end) == []
    assert len(dune.starts()) == 1 and dep.phase == PLAN_ENDED  # not restarted
    assert not _events(dep, "followref_lost")
    n_sent = len(dune.sent)
    summary = asyncio.run(dep.shutdown())
    assert len(dune.sent) == n_sent  # no standby, no MANDONE to a maneuver that is not ours
    names = [e["event"] for e in _events(dep)]
    assert "final_standby" not in names and "plan_done_timeout" not in names
    assert info in summary["plan_ended"] and "no_decision" not in summary
    status, err = _exit_status(summary, monkeypatch, capsys)
    assert status == 1
    assert err.count("\n") == 1 and "DUNE ended" in err and info in err, err


@pytest.mark.parametrize("kind,op,info", [
    (PC.TypeEnum.SUCCESS, PC.OperationEnum.STOP, "plan stopped"),
    (PC.TypeEnum.SUCCESS, PC.OperationEnum.START, "plan completed"),
    (PC.TypeEnum.FAILURE, PC.OperationEnum.START, "vehicle errors: GPS"),
])  # fmt: skip
def test_other_ends_of_our_plan_are_ours_too(kind, op, info, tmp_path, request):
    """A STOP's SUCCESS, a "plan completed" we did not ask for (no MANDONE sent), a vehicle
    error's FAILURE: plan_ended; DUNE's second answer to our START ("executing maneuver")
    is not, and is labelled ours."""
    dep, clock, dune = _deploy(tmp_path, request)
    _run(dep, clock, dune, 3.0)
    second = [e for e in _events(dep, "plan_control")
              if e["info"] == "FollowReference: executing maneuver"]  # fmt: skip
    assert len(second) == 1 and second[0]["ours"] is True
    assert dep.phase == RUNNING
    dune.deliver(dune.plan_control(kind, info, op=op))
    assert dep.phase == PLAN_ENDED and _events(dep, "plan_ended")[0]["info"] == info


@pytest.mark.parametrize("limit", [None, 2.0])
def test_followref_lost_ends_the_run_without_a_restart(limit, tmp_path, request, monkeypatch,
                                                       capsys):  # fmt: skip
    """(b) DUNE stops answering our References (the maneuver gone without a word, as when an
    operator stops it from Neptus: DUNE's plan engine answers the operator; its states and
    heartbeat go on): after link.followref_lost_s (default 5 s) of a Reference unanswered,
    one followref_lost event (a warning), then as for plan_ended: no more decisions or
    References, no new START (a restart would undo the operator's stop), the run's stop
    set, ``mpcasv deploy`` exits 1 saying why."""
    link = {} if limit is None else {"followref_lost_s": limit}
    limit = limit or 5.0  # the default
    dep, clock, dune = _deploy(tmp_path, request, **link)
    dep.stop_event = stop = asyncio.Event()  # as run() sets it
    _run(dep, clock, dune, 5.0)
    assert dep.phase == RUNNING and len(dune.starts()) == 1
    first = dune.starts()[0].request_id
    dune.answer_references = False
    t_silent = clock.t
    _run(dep, clock, dune, limit - 0.5)
    assert not _events(dep, "followref_lost") and dep.phase == RUNNING  # within the limit
    _run(dep, clock, dune, 6.0)
    lost = _events(dep, "followref_lost")
    assert len(lost) == 1, [e["event"] for e in _events(dep)]
    assert lost[0]["limit_s"] == limit == dep.cfg.link.followref_lost_s
    # (and the ASV's states at 2 Hz kept coming for longer than the limit after it)
    assert limit < lost[0]["unanswered_s"] <= limit + 0.75
    Tc = dep.cfg.controller.control_period  # the first unanswered Reference: one period on
    assert lost[0]["t"] - t_silent <= Tc + limit + 0.75 and lost[0]["request_id"] == first
    assert "followref_lost" in dep.WARNING_EVENTS
    assert dep.phase == PLAN_ENDED and stop.is_set() and len(dune.starts()) == 1
    steps, t_end = dep.steps, clock.t
    _run(dep, clock, dune, 5.0)
    assert dep.steps == steps and dune.references(after=t_end) == []
    assert len(dune.starts()) == 1 and len(_events(dep, "followref_lost")) == 1
    n_sent = len(dune.sent)
    summary = asyncio.run(dep.shutdown())
    # unlike DUNE's word, a silence may be lost answers only: the standby and MANDONE go out
    assert len(dune.sent) > n_sent
    assert summary["followref_lost"] == 1 and "stopped answering" in summary["plan_ended"]
    status, err = _exit_status(summary, monkeypatch, capsys)
    assert status == 1 and err.count("\n") == 1 and "stopped answering" in err, err


def test_a_radio_dropout_is_asv_stale_not_followref_lost(tmp_path, request):
    """States and answers both stop for 8 s (longer than followref_lost_s, shorter than
    asv_stale_s = 20 s), then come back: no followref_lost, the run goes on (a review: the
    dropout ended the run when asv_stale_s was above followref_lost_s)."""
    dep, clock, dune = _deploy(tmp_path, request)
    dep.cfg = dataclasses.replace(dep.cfg, watchdog=dataclasses.replace(dep.cfg.watchdog,
                                                                      asv_stale_s=20.0))
    _run(dep, clock, dune, 5.0)
    assert dep.phase == RUNNING
    dune.answer_references = False
    _run(dep, clock, dune, 1.0)  # the last decisions before it: their answers are lost
    assert dep.unanswered_since is not None
    for _ in range(32):  # 8 s: no state, no answer, the watchdog ticks
        clock.t += 0.25
        dep.watch()
    dune.answer_references = True
    _run(dep, clock, dune, 5.0)
    assert not _events(dep, "followref_lost") and dep.phase == RUNNING


def test_followref_lost_s_must_cover_two_control_periods(tmp_path):
    """A Reference goes every control period: a limit below two periods would end the run on
    one lost answer (a review: control_period 6 s, the default 5 s, was accepted)."""
    with pytest.raises((ConfigError, ValueError), match="followref_lost_s.*two controller"):
        dry_deploy(tmp_path, controller={"name": "hybrid-single", "preset": "paper1-field",
                                         "control_period": 6.0},
                   link={"followref_timeout": 20.0})  # fmt: skip


def test_no_followref_watch_in_a_dry_run(tmp_path, request):
    """A dry run starts no plan and sends no Reference: nothing is awaited, nothing lost."""
    dep, clock = dry_deploy(tmp_path)
    request.addfinalizer(dep.close)
    dep.link._send_raw = lambda data, addr, p=None: True
    for _ in range(40):  # 20 s, no FollowRefState at all
        clock.t += 0.5
        dep.link.handle_datagram(_state(AUV_ID, clock.t, 1000.0, 0.0), AUV)
        dep.link.handle_datagram(_state(ASV_ID, clock.t, 0.0, 0.5), ASV)
        dep.watch()
    assert dep.phase == RUNNING and dep.steps >= 15
    assert not _events(dep, "followref_lost") and dep.link.sent.get("Reference", 0) == 0


def test_our_mandone_and_plan_completed_unchanged(tmp_path, request, monkeypatch, capsys):
    """(c) The normal shutdown: DUNE answers every Reference; our standby and MANDONE, and
    DUNE's "plan completed" with our request id, end the run as before (plan_completed,
    exit 0); nothing was lost or ended on the way."""
    dep, clock, dune = _deploy(tmp_path, request)
    _run(dep, clock, dune, 20.0)
    assert dep.phase == RUNNING and len(dune.starts()) == 1

    async def shutdown():
        task = asyncio.create_task(dep.shutdown())
        await asyncio.sleep(0)  # begin_shutdown has sent the standby and MANDONE
        dune.deliver()
        return await task

    summary = asyncio.run(shutdown())
    refs = dune.references()
    assert int(refs[-1].flags) & MANDONE and refs[-2].speed.value == 0.0
    done = _events(dep, "plan_completed")
    assert len(done) == 1 and done[0]["info"] == "plan completed"
    assert summary["plan_completed"] is True and "plan_ended" not in summary
    assert summary["followref_lost"] == 0
    names = [e["event"] for e in _events(dep)]
    assert "plan_done_timeout" not in names and "plan_ended" not in names
    assert _exit_status(summary, monkeypatch, capsys)[0] == 0


def test_a_running_deploy_stops_by_itself_when_dune_ends_our_plan(tmp_path):
    """The same through the sockets: ``run`` returns (no Ctrl-C) soon after DUNE's FAILURE
    "plan stopped by operator", its summary saying why (fake vehicles on 127.0.0.1, the
    deploy clock 10 times as fast)."""
    from test_io_link import ASV_ID as L_ASV
    from test_io_link import AUV_ID as L_AUV
    from test_io_link import DEPLOY_ID, Fake, _cfg, _start, run

    async def main():
        dep, stop, task = await _start(_cfg(tmp_path, speedup=10.0), tmp_path)
        to = dep.link.endpoint.address
        asv = await Fake("fake-asv", L_ASV, imcpy.SystemType.USV).open()
        auv = await Fake("fake-auv", L_AUV).open()
        for v in (asv, auv):
            v.announce(to, dep.clock.now())
        request, read = None, 0
        for _ in range(200):  # at most 10 s of wall time
            t = dep.clock.now()
            auv.send(auv.es(t, 1000.0, 0.0), to, t)
            asv.send(asv.es(t, 0.0, 0.0), to, t)
            for m in asv.received[read:]:
                if isinstance(m, PC) and m.type == PC.TypeEnum.REQUEST:
                    request = m.request_id
                    ok = PC()
                    ok.type, ok.op, ok.request_id = PC.TypeEnum.SUCCESS, m.op, request
                    ok.plan_id, ok.info = m.plan_id, "plan loaded"
                    asv.send(ok, to, t, dst=DEPLOY_ID)
                elif isinstance(m, imcpy.Reference):
                    asv.send(FakeDune.followref(FRS.StateEnum.GOTO), to, t, dst=DEPLOY_ID)
            read = len(asv.received)
            if dep.steps >= 3:
                break
            await asyncio.sleep(0.05)
        assert dep.steps >= 3 and request is not None and not task.done()
        stopped = PC()
        stopped.type, stopped.op, stopped.request_id = (PC.TypeEnum.FAILURE,
                                                        PC.OperationEnum.START, request)
        stopped.plan_id, stopped.info = dep.cfg.link.plan_id, "plan stopped by operator"
        asv.send(stopped, to, dep.clock.now(), dst=DEPLOY_ID)
        summary = await asyncio.wait_for(task, 5.0)  # no stop.set() here
        assert stop.is_set() and "plan stopped by operator" in summary["plan_ended"]
        assert not summary["plan_completed"] and summary["sent"]["PlanControl"] == 1

    run(main)


def test_followref_lost_s_is_bounded(tmp_path, request):

    for bad in (0.0, 0.5, 301.0):
        with pytest.raises((ConfigError, ValueError), match="followref_lost_s"):
            dry_deploy(tmp_path, link={"followref_lost_s": bad})
    dep, _ = dry_deploy(tmp_path, link={"followref_lost_s": 2.5})
    request.addfinalizer(dep.close)
    assert dep.cfg.link.followref_lost_s == 2.5
