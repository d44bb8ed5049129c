"""DUNE's PlanControlState tells an operator's stop from lost answers (mpcasv.io.planstate).

Before, the deploy did not read PlanControlState (IMC 560): stock DUNE answers an operator's
STOP to the operator only, so the deploy saw FollowRefState stop and ended with
``followref_lost`` after ``link.followref_lost_s`` (5 s), its summary guessing at "a word to
us lost". DUNE streams PlanControlState to every node it streams to (the recording: 2.5 Hz
from the Otter, dst 0xFFFF), and its plan engine sets READY, our plan, last outcome FAILURE
at an operator's STOP (``Plan/Engine/Task.cpp``, ``stopPlan``).

The fake DUNE here sends PlanControlState as the recorded Otter does (planstate's docstring):
INITIALIZING (plan "") with the START, EXECUTING our plan after "plan loaded", one with every
delivery while it runs (DUNE: every 0.4 s), READY our plan SUCCESS after MANDONE.
"""

from __future__ import annotations

import asyncio
import json

import imcpy
import pytest
from test_deploy_plan_ended import (
    ASV,
    ASV_ID,
    AUV,
    AUV_ID,
    PC,
    US,
    FakeDune,
    _events,
    _exit_status,
)
from test_deploy_plan_ended import _deploy as _plain_deploy
from test_deploy_plan_ended import _run as _plain_run
from test_deploy_speed_watch import _state
from test_io_cases import dry_deploy
from test_io_dune_recording import EXCERPT, FULL, CaptureClock, _cfg, capture

from mpcasv.io.deploy import PLAN_ENDED, RUNNING, WAITING, Deploy
from mpcasv.io.imc import stamp

PCS = imcpy.PlanControlState
S, O = PCS.StateEnum, PCS.LastPlanOutcomeEnum
FRS = imcpy.FollowRefState
PLAN = "mpcasv-followref"  # link.plan_id's default


def pcs(state, plan_id: str = PLAN, outcome=O.NONE, man_id: str = "") -> PCS:
    m = PCS()
    m.state, m.plan_id, m.last_outcome, m.man_id = state, plan_id, outcome, man_id
    m.man_type, m.plan_progress = 0xFFFF, -1.0
    return m


class PlanStateDune(FakeDune):
    """:class:`FakeDune` with DUNE's PlanControlState: ``engine`` is the message it streams
    (sent with every delivery); ``None``: a DUNE whose PlanControlState does not reach us."""

    def __init__(self, dep, clock) -> None:
        super().__init__(dep, clock)
        self.engine: PCS | None = pcs(S.READY, "")
        self.outcome = O.NONE

    def _receive(self, data: bytes, addr, p=None) -> bool:
        m = imcpy.Packet.deserialize(data)
        start = isinstance(m, PC) and m.type == PC.TypeEnum.REQUEST
        mandone = (isinstance(m, imcpy.Reference) and int(m.flags) & 0x80
                   and self.request is not None)  # fmt: skip
        before = self.engine.plan_id if self.engine is not None else ""
        n = len(self.outbox)
        ok = super()._receive(data, addr, p)
        if start and self.engine is not None:  # as recorded: INITIALIZING with the plan before
            loaded, executing = self.outbox[n:n + 2]  # DUNE's two answers to the START
            self.engine = pcs(S.EXECUTING, m.plan_id, self.outcome, "FollowReference")
            self.outbox[n:n + 2] = [pcs(S.INITIALIZING, before, self.outcome), loaded,
                                    self.engine, executing]  # fmt: skip
        elif mandone and self.engine is not None:
            self.outcome = O.SUCCESS
            self.engine = pcs(S.READY, self.engine.plan_id, O.SUCCESS)
            self.outbox.append(self.engine)
        return ok

    def deliver(self, *extra: imcpy.Message) -> None:
        if self.engine is not None and not extra:
            self.outbox.append(self.engine)  # DUNE's periodic report
        super().deliver(*extra)

    def operator_stop(self) -> None:
        """Neptus stops the plan: DUNE answers Neptus (nothing to us), the maneuver stops
        (no more FollowRefState), the engine is READY with our plan and FAILURE."""
        self.answer_references = False
        self.outcome = O.FAILURE
        self.engine = pcs(S.READY, self.engine.plan_id, O.FAILURE)


def _deploy(tmp_path, request, **link):
    dep, clock, _ = _plain_deploy(tmp_path, request, **link)
    return dep, clock, PlanStateDune(dep, clock)


_run = _plain_run  # states at 2 Hz, DUNE's answers after each, the watchdog every 0.25 s


def test_an_operator_stop_is_read_from_plan_control_state(tmp_path, request, monkeypatch,
                                                          capsys):  # fmt: skip
    """Neptus stops our plan: no PlanControl to us, FollowRefState stops, PlanControlState
    READY / our plan / FAILURE. The run ends with plan_ended (source PlanControlState) at the
    next delivery, not followref_lost 5 s later; no more decisions or References; no standby
    or MANDONE at shutdown (DUNE's own word); exit 1, the one stderr line naming what
    PlanControlState said. (Before: followref_lost after 5 s.)"""
    dep, clock, dune = _deploy(tmp_path, request)
    dep.stop_event = stop = asyncio.Event()
    _run(dep, clock, dune, 10.0)
    assert dep.phase == RUNNING and dep.steps >= 8
    steps, t_stop = dep.steps, clock.t
    dune.operator_stop()
    _run(dep, clock, dune, 1.0)
    ended = _events(dep, "plan_ended")
    assert len(ended) == 1, [e["event"] for e in _events(dep)]
    e = ended[0]
    assert e["source"] == "PlanControlState" and e["state"] == "READY"
    assert e["plan_id"] == PLAN and e["last_outcome"] == "FAILURE"
    assert e["t"] - t_stop <= 0.5  # at its first report (DUNE: within 0.4 s), not 5 s on
    assert "operator" in e["meaning"] and "plan_ended" in dep.WARNING_EVENTS
    executing = _events(dep, "plan_executing")  # (said once, at the start)
    assert len(executing) == 1 and executing[0]["plan_id"] == PLAN
    assert executing[0]["t"] - dune.sent[0][0] <= 0.25
    assert dep.phase == PLAN_ENDED and stop.is_set() and dep.ended_by_dune
    _run(dep, clock, dune, 8.0)  # longer than followref_lost_s: nothing more
    assert not _events(dep, "followref_lost") and len(_events(dep, "plan_ended")) == 1
    assert dep.steps <= steps + 1 and dune.references(after=e["t"]) == []
    assert len(dune.starts()) == 1  # not restarted
    n_sent = len(dune.sent)
    summary = asyncio.run(dep.shutdown())
    assert len(dune.sent) == n_sent  # no standby, no MANDONE
    assert summary["followref_lost"] == 0
    assert "PlanControlState READY" in summary["plan_ended"]
    assert "FAILURE" in summary["plan_ended"] and repr(PLAN) in summary["plan_ended"]
    status, err = _exit_status(summary, monkeypatch, capsys)
    assert status == 1 and err.count("\n") == 1
    assert "PlanControlState READY" in err and "operator" in err, err


@pytest.mark.parametrize("engine,says", [
    (pcs(S.BLOCKED, PLAN, O.FAILURE), "blocked"),  # a vehicle error
    (pcs(S.READY, PLAN, O.SUCCESS), "completed"),  # a MANDONE from another system
    (pcs(S.EXECUTING, "neptus-goto", O.FAILURE, "Goto1"), "'neptus-goto'"),  # another plan
    (pcs(S.INITIALIZING, PLAN, O.FAILURE), "being started"),  # its START, before it runs
    (pcs(S.EXECUTING, "", O.NONE), "another plan"),
])  # fmt: skip
def test_every_state_that_is_not_our_plan_executing_ends_it(engine, says, tmp_path, request):
    """Once our plan was EXECUTING: another state, or another plan, is plan_ended, the message
    saying what PlanControlState said (the FollowRefStates still coming: not a silence)."""
    dep, clock, dune = _deploy(tmp_path, request)
    _run(dep, clock, dune, 3.0)
    assert dep.phase == RUNNING
    dune.engine = engine
    dune.deliver()
    assert dep.phase == PLAN_ENDED
    e = _events(dep, "plan_ended")[0]
    assert (e["state"], e["plan_id"]) == (engine.state.name, engine.plan_id)
    assert says in e["meaning"] and says in dep.plan_ended


def test_the_start_itself_ends_nothing(tmp_path, request):
    """DUNE's states of our START, INITIALIZING (the plan before) and a READY report sent
    just before it, reach us after "plan loaded" (which makes the deploy ``running``): they
    end nothing until our plan has shown EXECUTING; then a READY does."""
    dep, clock, dune = _deploy(tmp_path, request)
    dune.engine = None  # only what is delivered by hand below
    _run(dep, clock, dune, 1.5)
    assert dep.phase == RUNNING
    for m in (pcs(S.INITIALIZING, ""), pcs(S.READY, ""), pcs(S.READY, PLAN, O.FAILURE)):
        dune.deliver(m)
        assert dep.phase == RUNNING and not _events(dep, "plan_ended")
    assert not _events(dep, "plan_executing")
    dune.deliver(pcs(S.EXECUTING, PLAN, O.FAILURE, "FollowReference"))  # a stale outcome
    assert dep.phase == RUNNING
    _run(dep, clock, dune, 2.0)
    dune.deliver(pcs(S.READY, PLAN, O.FAILURE))
    assert dep.phase == PLAN_ENDED and _events(dep, "plan_ended")[0]["state"] == "READY"
    assert len(_events(dep, "plan_executing")) == 1


def test_a_restart_after_a_timeout_watches_the_new_start(tmp_path, request):
    """Our FollowReference timed out (FollowRefState TIMEOUT: restarted, as before): DUNE's
    READY / FAILURE after it, and the INITIALIZING of our new START (our plan, FAILURE from
    before), end nothing; the restarted plan EXECUTING with that old FAILURE runs on."""
    dep, clock, dune = _deploy(tmp_path, request)
    _run(dep, clock, dune, 3.0)
    dune.deliver(FakeDune.followref(FRS.StateEnum.TIMEOUT))
    assert dep.phase == WAITING
    dune.outcome = O.FAILURE  # DUNE: the TIMEOUT, then the engine's READY (FollowReference's
    dune.engine = pcs(S.READY, PLAN, O.FAILURE)  # signalError after it)
    dune.deliver()
    _run(dep, clock, dune, 4.0)
    assert len(dune.starts()) == 2 and dep.phase == RUNNING
    assert len(_events(dep, "plan_executing")) == 2  # once per START
    assert dune.engine.state == S.EXECUTING and dune.engine.last_outcome == O.FAILURE
    _run(dep, clock, dune, 4.0)
    assert dep.phase == RUNNING and not _events(dep, "plan_ended")


def test_a_late_plan_control_state_ends_nothing(tmp_path, request):
    """A READY DUNE stamped 1 s before (UDP reordering, a second route, a report from before
    our START) delivered after our plan's EXECUTING ended the run, with no standby or
    MANDONE sent (a review); it is counted now, not read."""
    dep, clock, dune = _deploy(tmp_path, request)
    _run(dep, clock, dune, 3.0)
    assert dep.phase == RUNNING and _events(dep, "plan_executing")
    late = stamp(pcs(S.READY, ""), ASV_ID, US, clock.t - 1.0).serialize()
    dep.link.handle_datagram(late, ASV)
    assert dep.phase == RUNNING and not _events(dep, "plan_ended")
    assert dep.plan_state_late == 1


def test_the_starts_own_states_swapped_end_nothing(tmp_path, request):
    """Our START's INITIALIZING and the EXECUTING DUNE sent 0.9 ms after it, delivered the
    other way round: the INITIALIZING read last ended the run (a review)."""
    dep, clock, dune = _deploy(tmp_path, request)
    dune.engine = None
    _run(dep, clock, dune, 1.5)
    assert dep.phase == RUNNING
    t = clock.t
    for msg, at in ((pcs(S.EXECUTING, PLAN, O.NONE, "FollowReference"), t + 0.0009),
                    (pcs(S.INITIALIZING, ""), t)):  # fmt: skip
        dep.link.handle_datagram(stamp(msg, ASV_ID, US, at).serialize(), ASV)
    assert dep.phase == RUNNING and _events(dep, "plan_executing")
    assert not _events(dep, "plan_ended") and dep.plan_state_late == 1


def test_another_plan_executing_while_we_run_is_said_once(tmp_path, request):
    """A DUNE reporting another plan id EXECUTING while our maneuver runs (a plan named
    otherwise) never arms the watch; an event says so once (a review)."""
    dep, clock, dune = _deploy(tmp_path, request)
    dune.engine = None
    _run(dep, clock, dune, 1.5)
    for dt in (0.0, 0.4):
        msg = pcs(S.EXECUTING, "vehicle-plan-7", O.NONE, "FollowReference")
        dep.link.handle_datagram(stamp(msg, ASV_ID, US, clock.t + dt).serialize(), ASV)
    said = _events(dep, "plan_state_unarmed")
    assert len(said) == 1 and "'vehicle-plan-7' EXECUTING" in said[0]["note"]
    assert dep.phase == RUNNING and not _events(dep, "plan_ended")


def test_without_plan_control_state_followref_lost_remains(tmp_path, request):
    """A DUNE whose PlanControlState does not reach us: the operator's stop is still the
    FollowRefState silence (followref_lost after link.followref_lost_s)."""
    dep, clock, dune = _deploy(tmp_path, request)
    dune.engine = None
    _run(dep, clock, dune, 5.0)
    dune.answer_references = False
    _run(dep, clock, dune, 7.0)
    assert len(_events(dep, "followref_lost")) == 1 and dep.phase == PLAN_ENDED
    assert all(e.get("source") != "PlanControlState" for e in _events(dep, "plan_ended"))


def test_the_auvs_plan_state_and_a_dry_run_end_nothing(tmp_path, request):
    """An AUV's engine runs its own plans (the recorded LAUV streams its PlanControlState
    too): not read. A dry run starts no plan: a plan of our name EXECUTING then READY (another
    deploy's?) ends nothing."""
    dep, clock, dune = _deploy(tmp_path, request)
    _run(dep, clock, dune, 3.0)
    for m in (pcs(S.EXECUTING, PLAN), pcs(S.READY, PLAN, O.FAILURE)):
        dep.link.handle_datagram(stamp(m, AUV_ID, US, clock.t).serialize(), AUV)
    assert dep.phase == RUNNING and dep.link.ignored["PlanControlState"] == 2
    dry, dclock = dry_deploy(tmp_path / "dry")
    request.addfinalizer(dry.close)
    dry.link._send_raw = lambda data, addr, p=None: True
    for k in range(20):
        dclock.t += 0.5
        dry.link.handle_datagram(_state(AUV_ID, dclock.t, 1000.0, 0.0), AUV)
        dry.link.handle_datagram(_state(0x2801, dclock.t, 0.0, 0.5), ASV)
        m = pcs(S.EXECUTING, PLAN) if k < 10 else pcs(S.READY, PLAN, O.FAILURE)
        dry.link.handle_datagram(stamp(m, 0x2801, 0xFFFF, dclock.t).serialize(), ASV)
        dry.watch()
    assert dry.phase == RUNNING and not _events(dry, "plan_ended") and dry.steps >= 5


@pytest.mark.parametrize("path", [pytest.param(EXCERPT, id="excerpt"), pytest.param(
    FULL, id="full", marks=pytest.mark.skipif(not FULL.is_file(), reason="no full capture"))])
def test_recorded_plan_control_state_ends_a_plan_ended_elsewhere(path, tmp_path):
    """The recorded Otter, its PlanControl answers to us dropped after the START's (as when
    another system ends the plan: DUNE answers that system) and our own shutdown not run: the
    recorded READY / mpcasv-followref / SUCCESS (+217.91 s, 7 ms after the recording's
    MANDONE) ends the run at once. Before: followref_lost, 5 s of silence later."""
    data = capture(path)
    dep = Deploy(_cfg(tmp_path))
    clock = CaptureClock(data[0][0])
    dep.clock = dep.link.clock = clock
    dep.link._send_raw = lambda raw, addr, p=None: True
    dep.request_id = 1  # the recording's START was request 2 (test_io_dune_recording)
    pc_id = imcpy.Factory.id_from_abbrev("PlanControl")
    next_watch = data[0][0]
    try:
        for t, sent, peer, raw in data:
            if sent:
                continue
            clock.t = t
            while next_watch <= t:
                dep.watch()
                next_watch += 0.25
            answered = dep.started and int.from_bytes(raw[2:4], "little") == pc_id
            if answered and t > 1795969701.49:  # after the START's two answers
                continue
            dep.link.handle_datagram(raw, peer)
    finally:
        dep.close()
    events = [r for r in map(json.loads, (tmp_path / "log" / "deploy.jsonl").read_text()
                             .splitlines()) if r["kind"] == "event"]  # fmt: skip
    ended = [e for e in events if e["event"] == "plan_ended"]
    assert len(ended) == 1 and ended[0]["source"] == "PlanControlState", [
        e["event"] for e in events]  # fmt: skip
    executing = [e for e in events if e["event"] == "plan_executing"]
    assert len(executing) == 1  # recorded 1.2 ms after "plan loaded", and 2.5 Hz after it
    assert 0 <= executing[0]["t"] - 1795969701.4823 < 0.01
    assert (ended[0]["state"], ended[0]["plan_id"], ended[0]["last_outcome"]) == (
        "READY", PLAN, "SUCCESS")
    assert 0 <= ended[0]["t"] - 1795969891.522 < 0.6  # the MANDONE (README timeline)
    assert not [e for e in events if e["event"] == "followref_lost"]
