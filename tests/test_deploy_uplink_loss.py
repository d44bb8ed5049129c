"""References lost on the way out, while DUNE's plan engine still shows our plan EXECUTING:
the deploy waits for DUNE's own verdict instead of ending the run at ``followref_lost_s``.

DUNE's ``Maneuver/FollowReference/AUV/Task.cpp`` ends the maneuver (FollowRefState TIMEOUT,
"reference source timed out") when ``Clock::get() - m_last_ref_time > m_spec.timeout``,
``m_last_ref_time`` being the last Reference it *received* and ``m_spec.timeout`` the
FollowReference's own field (``link.followref_timeout``, 10 s); the task has no timeout
parameter of its own ("Loitering Radius", 7.5 m, is a circle's radius). The deploy's
``link.followref_lost_s`` (5 s) is shorter: before, References lost for 5 to 10 s with the
ASV's states still arriving ended the run as "stopped without a word" while DUNE still ran
our maneuver (a limit docs/deploy.md listed since session 47).
"""

from __future__ import annotations

import imcpy
import test_deploy_plan_ended
from test_deploy_plan_ended import FRS, PC, _events
from test_deploy_plan_state import O, S, _deploy, _run, pcs

from mpcasv.io.deploy import RUNNING


def test_references_lost_while_dune_executes_our_plan_wait_for_dunes_timeout(tmp_path,
                                                                             request):  # fmt: skip
    dep, clock, dune = _deploy(tmp_path, request)
    _run(dep, clock, dune, 5.0)
    assert dep.phase == RUNNING and dep.plan_executing and len(dune.starts()) == 1
    received = dune._receive
    uplink = {"up": True, "last": clock.t}  # the last Reference DUNE received (its clock)

    def send(data, addr, p=None):
        m = imcpy.Packet.deserialize(data)
        if isinstance(m, imcpy.Reference) and not uplink["up"]:
            return True  # sent, lost on the way
        if isinstance(m, imcpy.Reference):
            uplink["last"] = clock.t
        return received(data, addr, p)

    dep.link._send_raw = send
    uplink["up"] = False
    timeout = dep.cfg.link.followref_timeout
    assert dep.cfg.link.followref_lost_s < timeout  # the defaults this is about
    # DUNE still executes our plan and says so (PlanControlState with every delivery); its
    # maneuver lives until `timeout` after the last Reference it received
    _run(dep, clock, dune, uplink["last"] + timeout - clock.t - 0.25)
    assert not _events(dep, "followref_lost") and dep.phase == RUNNING
    # DUNE's verdict: FollowRefState TIMEOUT, FAILURE to the starter, READY / FAILURE
    dune.engine = pcs(S.READY, dune.engine.plan_id, O.FAILURE)
    dune.outbox += [dune.followref(FRS.StateEnum.TIMEOUT),
                    dune.plan_control(PC.TypeEnum.FAILURE, "reference source timed out"),
                    dune.engine]  # fmt: skip
    uplink["up"] = True
    _run(dep, clock, dune, 5.0)
    names = [e["event"] for e in _events(dep)]
    assert "followref_timeout" in names and "followref_lost" not in names
    assert "plan_ended" not in names, [e for e in _events(dep, "plan_ended")]
    assert len(dune.starts()) == 2 and dep.phase == RUNNING  # restarted, running again


def _lose_references(dep):
    """From now on every Reference the deploy sends is lost on the way out."""
    received = dep.link._send_raw

    def send(data, addr, p=None):
        if isinstance(imcpy.Packet.deserialize(data), imcpy.Reference):
            return True
        return received(data, addr, p)

    dep.link._send_raw = send


def test_dunes_word_must_be_fresh_when_its_reports_stop(tmp_path, request):
    """EXECUTING read after the first lost Reference, then DUNE's PlanControlState stops
    (its engine task blocked, a filter) while the ASV's states go on: that old word does not
    hold the run for ever (DUNE's own timeout stops the maneuver after 10 s); the silence
    ends it once no report was read within ``followref_lost_s`` of the last state (a review:
    the run went on for 300 s and more)."""
    dep, clock, dune = _deploy(tmp_path, request)
    _run(dep, clock, dune, 5.0)
    _lose_references(dep)
    _run(dep, clock, dune, 1.0)  # EXECUTING reports read after the first unanswered Reference
    assert dep.plan_state["recv"] >= dep.unanswered_since
    dune.engine = None  # the 560 stream stops; the ASV's states go on
    lost = dep.cfg.link.followref_lost_s
    _run(dep, clock, dune, 2 * lost + 2.0)
    assert len(_events(dep, "followref_lost")) == 1


def test_a_dune_clock_stepped_back_does_not_hold_the_run(tmp_path, request, monkeypatch):
    """EXECUTING read, then every later report stamped a minute behind (a DUNE clock stepped
    back): they are all late, not read; the run must not wait on the last one read past
    ``followref_timeout + followref_lost_s`` of silence."""
    dep, clock, dune = _deploy(tmp_path, request)
    _run(dep, clock, dune, 5.0)
    _lose_references(dep)
    _run(dep, clock, dune, 1.0)
    real = test_deploy_plan_ended.stamp
    monkeypatch.setattr(test_deploy_plan_ended, "stamp", lambda m, src, ent, t: real(
        m, src, ent, t - 60.0 if isinstance(m, imcpy.PlanControlState) else t))
    link = dep.cfg.link
    _run(dep, clock, dune, link.followref_timeout + 2 * link.followref_lost_s)
    assert dep.plan_state_late > 0
    assert len(_events(dep, "followref_lost")) == 1


def test_an_old_executing_does_not_hide_an_operators_stop(tmp_path, request):
    """EXECUTING read long ago, then DUNE's PlanControlState stops reaching us, then the
    References go unanswered (the operator stopped the plan): the silence ends the run at
    ``followref_lost_s``, the old report is no word (it was read before the first unanswered
    Reference)."""
    dep, clock, dune = _deploy(tmp_path, request)
    lost = dep.cfg.link.followref_lost_s
    _run(dep, clock, dune, 5.0)
    dune.engine = None
    _run(dep, clock, dune, 2.0)
    dune.answer_references = False
    _run(dep, clock, dune, lost + 2.0)
    assert len(_events(dep, "followref_lost")) == 1
