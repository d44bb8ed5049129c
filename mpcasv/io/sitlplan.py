"""The plan engine of a SITL vehicle: the PlanControlState (IMC 560) DUNE's ``Plan/Engine``
dispatches, which every DUNE node streams to the systems it streams to (pure state, no
sockets: :class:`mpcasv.io.sitlasv.AsvDune` drives the ASV's, and
:meth:`mpcasv.io.sitlpublish.Publishing.publish_plan_states` sends every vehicle's).

What it copies, and from where:

- the rate: DUNE dispatches its PlanControlState every "State Report Frequency" (3 Hz by
  default, ``src/Plan/Engine/Task.cpp``) and at every change of state; the recorded Otter
  (``shared/data/dune-traffic``) sent 560 in 221 s, one every 0.400 s (2.5 Hz), dst 0xFFFF,
  its periodic timer not reset by a change (a change at +27.863 s, the next report at
  +28.124 s): :data:`REPORT_PERIOD_S`;
- the states and fields, recorded: READY (plan ``""``, outcome NONE) before any plan; at a
  START, INITIALIZING still naming the plan before (``""`` in the recording), then EXECUTING
  the started plan (``man_id`` ``FollowReference``, ``man_type`` 478, the maneuver's IMC id);
  after the plan, READY keeping the plan's id, ``man_id`` ``""``, ``man_type`` 0xFFFF;
- ``last_outcome``, from ``Plan/Engine/Task.cpp``: SUCCESS on "plan completed" (our
  MANDONE), FAILURE on an operator's STOP (``stopPlan``: ``last_outcome = LPO_FAILURE``,
  then READY "plan stopped"), on a failed request (``onFailure``: a STOP with no plan
  running, "no plan is running, request ignored"), on a maneuver's error (FollowReference's
  "reference source timed out": the engine's ``onFailure`` of the vehicle's error, then
  READY), and at a START while a plan executes ("switching to new plan"); never reset by a
  START (a plan started after a failure executes with FAILURE from before).

Not simulated: BLOCKED (a vehicle error, CALIBRATION or EXTERNAL mode, no VehicleState for
2.5 s), the plan's progress and ETA (sent as the recorded Otter's, whose "Compute Progress"
was on: ``plan_progress`` -1; EXECUTING ``plan_eta`` -1, ``man_eta`` 65535; READY
``plan_eta`` 0), LOAD/GET requests.
"""

from __future__ import annotations

import imcpy

__all__ = ["REPORT_PERIOD_S", "PlanEngine"]

PCS = imcpy.PlanControlState
_S, _O = PCS.StateEnum, PCS.LastPlanOutcomeEnum
#: seconds between two periodic PlanControlStates: the recorded Otter's (2.5 Hz)
REPORT_PERIOD_S = 0.4
NO_MANEUVER = 0xFFFF  # man_type without a maneuver (DUNE's c_invalid_maneuver)


class PlanEngine:
    """One DUNE node's plan engine, as its PlanControlState shows it (module docstring).

    A fresh engine (a DUNE just started) is READY with no plan and outcome NONE."""

    def __init__(self) -> None:
        self.state = _S.READY
        self.plan_id = ""
        self.man_id = ""
        self.man_type = NO_MANEUVER
        self.last_outcome = _O.NONE

    @property
    def executing(self) -> bool:
        """Whether a plan is running (INITIALIZING or EXECUTING)."""
        return self.state in (_S.INITIALIZING, _S.EXECUTING)

    def initializing(self) -> None:
        """A START is being handled: INITIALIZING, still naming the plan before (recorded);
        a plan running until now ends with FAILURE ("switching to new plan")."""
        if self.executing:
            self.last_outcome = _O.FAILURE
        self.state, self.man_id, self.man_type = _S.INITIALIZING, "", NO_MANEUVER

    def started(self, plan_id: str, maneuver: imcpy.Message) -> None:
        """The START's plan executes ``maneuver`` (its first and only one)."""
        self.state, self.plan_id = _S.EXECUTING, plan_id
        self.man_id, self.man_type = type(maneuver).__name__, int(maneuver.msg_id)

    def ended(self, success: bool) -> None:
        """The plan ended: READY, the plan's id kept; SUCCESS ("plan completed") or FAILURE
        (stopped, failed)."""
        self.state, self.man_id, self.man_type = _S.READY, "", NO_MANEUVER
        self.last_outcome = _O.SUCCESS if success else _O.FAILURE

    def refused(self) -> None:
        """A request answered with FAILURE (DUNE's ``onFailure`` sets the outcome)."""
        self.last_outcome = _O.FAILURE

    def message(self) -> PCS:
        """The PlanControlState now (unstamped: the vehicle stamps what it sends)."""
        m = PCS()
        m.state, m.plan_id, m.last_outcome = self.state, self.plan_id, self.last_outcome
        m.man_id, m.man_type = self.man_id, self.man_type
        # as recorded (the Otter, "Compute Progress" on, yet no ETA): EXECUTING plan_eta -1,
        # man_eta 65535; READY 0, and man_eta 65535 once a plan ran (0 before)
        executing = self.state == _S.EXECUTING
        m.plan_eta, m.plan_progress = (-1 if executing else 0), -1.0
        m.man_eta = 0xFFFF if executing or self.plan_id else 0
        return m
