"""DUNE's PlanControlState read by the deploy (:class:`PlanStateWatch`, a mixin of
:class:`mpcasv.io.deploy.Deploy`; state there): an operator's stop told apart from lost
answers.

DUNE's plan engine (``Plan/Engine``) dispatches PlanControlState (IMC id 560) on its bus at
its "State Report Frequency" (3 Hz by default) and at every change of state, with dst 0xFFFF,
and its UDP transport streams it to every node it streams to: the recording
(``shared/data/dune-traffic``) has 560 from the Otter, one every 0.40 s (2.5 Hz), and the
changes within a millisecond of their cause. Its fields, as the engine sets them:

- ``state``: BLOCKED (a vehicle error, or the vehicle in CALIBRATION or EXTERNAL mode, or no
  VehicleState for 2.5 s), READY (no plan running), INITIALIZING (a START being handled),
  EXECUTING (a plan's maneuver running);
- ``plan_id``: the plan last loaded; it stays after the plan ends (the recording: READY with
  ``mpcasv-followref`` after "plan completed"), and at a START the INITIALIZING state still
  names the plan before (``""`` in the recording: none had run);
- ``last_outcome``: of the plan last ended (NONE, SUCCESS, FAILURE); set FAILURE by an
  operator's STOP, a vehicle error, a maneuver's failure (our FollowReference's TIMEOUT) or
  another plan's START while ours ran, SUCCESS by "plan completed", and *not* reset at a
  START: a plan started again after a failure executes with FAILURE from before. A refused
  request (a PlanControl LOAD while a plan executes: "cannot load plan now") also sets
  FAILURE while our plan goes on executing. So it says how a plan ended, not that it ended:
  the watch reads it for the message only.

Recorded at our START (the Otter, +27.86 s): INITIALIZING (plan ``""``), PlanControl SUCCESS
"plan loaded" (which makes the deploy ``running``), EXECUTING ``mpcasv-followref`` 0.9 ms
later, then "FollowReference: executing maneuver"; after the MANDONE (+217.90 s): PlanControl
SUCCESS "plan completed", then READY ``mpcasv-followref``, SUCCESS, 5 ms later.

The watch: once a PlanControlState from the ASV has shown our plan (``link.plan_id``)
EXECUTING while our maneuver runs (phase ``running``, since our last START: the states of the
start itself, INITIALIZING or READY, are not read as its end), any later one that does not
(another state, or another plan) means the engine no longer executes our plan: event
``plan_ended`` (``source`` "PlanControlState", with its ``state``, ``plan_id``,
``last_outcome``) and the run ends as when a PlanControl says so
(:meth:`mpcasv.io.deployphases.Phases._end_run`; no standby or MANDONE at shutdown: the
vehicle may run someone else's plan). Stock DUNE answers an operator's STOP to the operator
only; this is how it reaches us (READY, our plan, FAILURE) within one report period, where
the FollowRefState silence took ``link.followref_lost_s``. A DUNE that sends no
PlanControlState (or a link that loses them: none read within ``followref_lost_s`` of the
ASV's last state) leaves that silence as the one sign (``followref_lost``), and past
``followref_timeout + followref_lost_s`` of silence it ends the run whatever the last one
said (:meth:`mpcasv.io.deployphases.Phases._followref_silent`). Not in a dry run (we start no
plan: one of ours may be another deploy's).
"""

from __future__ import annotations

import math

import imcpy

from mpcasv.io.deployphases import RUNNING

__all__ = ["PlanStateWatch", "plan_state_fields", "plan_state_meaning"]

_PCS = imcpy.PlanControlState
EXECUTING = _PCS.StateEnum.EXECUTING


def plan_state_fields(msg: imcpy.PlanControlState) -> dict:
    """The fields of ``msg`` the deploy logs: ``state``, ``plan_id``, ``man_id`` and
    ``last_outcome`` (enum names)."""
    return {"state": msg.state.name, "plan_id": msg.plan_id, "man_id": msg.man_id,
            "last_outcome": msg.last_outcome.name}  # fmt: skip


def plan_state_meaning(fields: dict, ours: str) -> str:
    """What a PlanControlState that no longer shows our plan ``ours`` EXECUTING says, in a
    few words (DUNE's ``Plan/Engine``; module docstring)."""
    state, plan, outcome = fields["state"], fields["plan_id"], fields["last_outcome"]
    if state == "INITIALIZING":  # (it still names the plan before: not the one starting)
        return "a plan is being started (a START from another system)"
    if plan != ours and state == "EXECUTING":
        return f"another plan ({plan!r}) was started"
    if state == "BLOCKED":
        return "the plan engine is blocked (a vehicle error, or CALIBRATION or EXTERNAL mode)"
    if outcome == "SUCCESS":
        return "the plan completed (a MANDONE we did not send)"
    if outcome == "FAILURE":
        return "the plan was stopped (an operator's STOP is answered to the operator) or failed"
    return "no plan is running"


class PlanStateWatch:
    """The ASV's PlanControlState watch (mixin; module docstring)."""

    def init_plan_state(self) -> None:
        """The watch's state (the deploy's constructor)."""
        self.plan_executing = False  # our plan shown EXECUTING since our last START
        self.plan_state: dict | None = None  # the ASV's last PlanControlState (fields, recv)
        self.plan_state_stamp = -math.inf  # the newest one's timestamp (DUNE's clock), s
        self.plan_state_late = 0  # older or repeated ones, not read (summary)
        self.plan_state_unarmed = False  # said once: another plan EXECUTING while we run

    def plan_shown_running(self, since: float) -> bool:
        """Whether a PlanControlState read at or after ``since`` (deploy clock, s) shows our
        plan EXECUTING: the newest one read does (any other would have ended the run) and
        it came then (the caller makes ``since`` recent enough to be news). Read by the
        FollowRefState silence (``followref_lost``): DUNE's engine still executing our plan
        means our References do not reach it (its own timeout will end the maneuver) or its
        answers do not reach us, not that it ended."""
        return (self.plan_executing and self.plan_state is not None
                and self.plan_state["recv"] >= since)  # fmt: skip

    def plan_state_reset(self) -> None:
        """A START of ours was sent: its plan is not yet shown EXECUTING."""
        self.plan_executing = False

    def _plan_control_state(self, p, msg: imcpy.PlanControlState, now: float) -> None:
        """A PlanControlState from the ASV (the link accepts it from the ASV only). One
        stamped before the newest one read is not read, only counted
        (``plan_state_late``): a datagram reordered on the way, or arriving over a second
        route, told the end of a plan that was executing (our START's own INITIALIZING after
        its EXECUTING; a READY from before a TIMEOUT's restart: a review). A DUNE clock
        stepped back leaves the watch deaf until its stamps pass the newest again
        (``followref_lost`` still ends a stopped run: the last one read goes stale)."""
        stamp = float(msg.timestamp)
        if stamp < self.plan_state_stamp:  # (equal stamps: read in arrival order)
            self.plan_state_late += 1
            return
        self.plan_state_stamp = stamp
        fields = plan_state_fields(msg)
        self.plan_state = fields | {"recv": now}
        if self.phase != RUNNING or self.dry_run or self.closing:
            return
        ours = self.cfg.link.plan_id
        if msg.state == EXECUTING and msg.plan_id == ours:
            if not self.plan_executing:
                self.plan_executing = True
                self.event("plan_executing", vehicle=p.label, request_id=self.plan_request,
                           **fields)  # fmt: skip
            return
        if not self.plan_executing:  # our START is still being handled (INITIALIZING, an
            # older READY); another plan EXECUTING while we run: a DUNE naming our plan
            # otherwise leaves the watch unarmed, said once (a review)
            if msg.state == EXECUTING and not self.plan_state_unarmed:
                self.plan_state_unarmed = True
                self.event("plan_state_unarmed", vehicle=p.label, **fields,
                           note=f"PlanControlState shows plan {msg.plan_id!r} EXECUTING, not "
                                f"ours ({ours!r}): an operator's stop is then seen only as "
                                "followref_lost")  # fmt: skip
            return
        meaning = plan_state_meaning(fields, ours)
        self.ended_by_dune = True
        self.event("plan_ended", source="PlanControlState", vehicle=p.label,
                   request_id=self.plan_request, **fields, meaning=meaning,
                   note="no more decisions or References; the plan is not restarted")
        self._end_run(f"DUNE's plan engine no longer executes our FollowReference plan "
                      f"{ours!r}: PlanControlState {fields['state']}, plan "
                      f"{fields['plan_id']!r}, last outcome {fields['last_outcome']}: "
                      f"{meaning}")  # fmt: skip
