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


def test_without_dunes_word_the_silence_still_ends_the_run(tmp_path, request):
    """A DUNE whose PlanControlState does not reach us: the silence is the one sign left
    (``followref_lost`` after ``followref_lost_s``), as before."""
    dep, clock, dune = _deploy(tmp_path, request)
    dune.engine = None
    _run(dep, clock, dune, 5.0)
    assert dep.phase == RUNNING
    dune.answer_references = False
    _run(dep, clock, dune, dep.cfg.link.followref_lost_s + 2.0)
    assert len(_events(dep, "followref_lost")) == 1
