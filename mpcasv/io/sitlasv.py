"""The SITL ASV's side of DUNE (a mixin of :class:`mpcasv.io.sitl.Sitl`): PlanControl
START FollowReference / STOP answered as recorded DUNE answers them, References fed to
:class:`mpcasv.io.dune.FollowRefManeuver`, "plan completed" after MANDONE, FAILURE after
its TIMEOUT, the plan engine's PlanControlState (:mod:`mpcasv.io.sitlplan`) at every change,
and the command vector the world advances with (zeros without a maneuver); the ASV's DUNE
killed and restarted (the outages).

The order of what goes out, as recorded (``shared/data/dune-traffic``, the Otter at
+27.86 s and +217.90 s) and in ``Plan/Engine/Task.cpp``:

- START FollowReference: PlanControlState INITIALIZING (the plan before), PlanControl
  SUCCESS "plan loaded", PlanControlState EXECUTING (our plan), PlanControl SUCCESS
  "FollowReference: executing maneuver", FollowRefState WAIT;
- MANDONE: FollowRefState, PlanControl SUCCESS "plan completed" (op START, the start's
  request id), PlanControlState READY (our plan, SUCCESS);
- an operator's STOP (any system's): PlanControl SUCCESS "plan stopped" to *that* system
  only, then PlanControlState READY (the plan, FAILURE): to the deploy, the
  PlanControlState is the one word of it (:mod:`mpcasv.io.planstate`); a STOP with no plan
  running is refused (FAILURE "no plan is running, request ignored");
- no Reference for the FollowReference's ``timeout``: FollowRefState TIMEOUT, PlanControl
  FAILURE "reference source timed out" (the maneuver's error, op START, the start's request
  id) to the system that started it, PlanControlState READY (FAILURE)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import imcpy
import numpy as np

from mpcasv.io.dune import FollowRefManeuver

if TYPE_CHECKING:
    from mpcasv.io.simvehicle import Node, SimVehicle

_PC = imcpy.PlanControl


class AsvDune:
    """What the ASV's DUNE does with our messages; state (``maneuver``, ``plan_owner``,
    ``ref_event``, ...) lives in the SITL."""

    # --- PlanControl, Reference, the command vector ---------------------------------
    def asv_message(self, v: SimVehicle, msg, node: Node | None, stream) -> None:
        now = self.now()
        if isinstance(msg, imcpy.PlanControl):
            if msg.type != _PC.TypeEnum.REQUEST:
                return
            ans = imcpy.PlanControl()
            ans.op, ans.request_id, ans.plan_id = msg.op, msg.request_id, msg.plan_id
            if msg.op == _PC.OperationEnum.START and isinstance(msg.arg, imcpy.FollowReference):
                v.engine.initializing()
                v.publish(v.engine.message())
                self.maneuver = FollowRefManeuver(msg.arg, now, self.origin,
                                                  self.world.model.params.u_max)  # fmt: skip
                self.plan_owner = (msg.request_id, msg.plan_id, node, stream)
                self.event("maneuver_started", src=msg.src, timeout=msg.arg.timeout)
                ans.type, ans.info = _PC.TypeEnum.SUCCESS, "plan loaded"
                v.reply(ans, node, stream)
                v.engine.started(msg.plan_id, msg.arg)
                v.publish(v.engine.message())
                ans.info = "FollowReference: executing maneuver"
                v.reply(ans, node, stream)
                v.publish(self.maneuver.state_message())
            elif msg.op == _PC.OperationEnum.STOP:
                if not v.engine.executing:  # (DUNE's stopPlan)
                    v.engine.refused()
                    ans.type, ans.info = _PC.TypeEnum.FAILURE, "no plan is running, request ignored"
                    v.reply(ans, node, stream)
                    return
                self.maneuver, self.plan_owner = None, None  # its owner hears nothing of it
                ans.type, ans.info = _PC.TypeEnum.SUCCESS, "plan stopped"
                self.event("maneuver_stopped", src=msg.src)
                v.reply(ans, node, stream)
                v.engine.ended(success=False)
                v.publish(v.engine.message())
            else:
                ans.type, ans.info = _PC.TypeEnum.FAILURE, "only START FollowReference / STOP"
                v.reply(ans, node, stream)
        elif isinstance(msg, imcpy.Reference):
            m = self.maneuver
            if m is None or m.done:
                self.count("reference_without_maneuver")
                return
            if m.on_reference(msg, now, self.position(self.asv)):
                self.count("references")
                if not self.in_window and not self.held:
                    self.count("late_references")
                self.ref_event.set()
                v.publish(m.state_message(msg))
                if m.done:
                    self.event("maneuver_done", how="MANDONE")
                    self._plan_completed(v)

    def _plan_completed(self, v: SimVehicle) -> None:
        """DUNE answers MANDONE with PlanControl SUCCESS "plan completed" (op START, the
        request id of the start) to the system that started the plan."""
        if self.plan_owner is None:
            return
        self._answer_starter(v, _PC.TypeEnum.SUCCESS, "plan completed")
        v.engine.ended(success=True)
        v.publish(v.engine.message())

    def maneuver_timeout(self) -> None:
        """No Reference for the maneuver's ``timeout`` (checked every tick): FollowRefState
        TIMEOUT, then, as DUNE's engine fails a plan whose maneuver failed, PlanControl
        FAILURE "reference source timed out" (op START, the start's request id) to the
        system that started it and PlanControlState READY, FAILURE."""
        if self.maneuver is None or not self.maneuver.check_timeout(self.now()):
            return
        self.event("maneuver_timeout")
        v = self.asv
        v.publish(self.maneuver.state_message())
        if self.plan_owner is not None:
            self._answer_starter(v, _PC.TypeEnum.FAILURE, "reference source timed out")
        v.engine.ended(success=False)
        v.publish(v.engine.message())

    def _answer_starter(self, v: SimVehicle, kind, info: str) -> None:
        """PlanControl ``kind`` with ``info`` (op START, the start's request id) to the system
        that started the plan, which then has none."""
        req, plan_id, node, stream = self.plan_owner
        ans = imcpy.PlanControl()
        ans.type, ans.op, ans.request_id = kind, _PC.OperationEnum.START, req
        ans.plan_id, ans.info = plan_id, info
        v.reply(ans, node, stream)
        self.plan_owner = None

    def command_vector(self) -> np.ndarray:
        if not self.asv.alive or self.maneuver is None:
            return np.zeros(4)
        return self.maneuver.command_vector()

    # --- outages (SIGUSR1 / SIGUSR2, --asv-outage) -------------------------------------
    def kill_asv(self) -> None:
        """The ASV's DUNE is gone: its socket closed, no maneuver (loops off)."""
        if self.asv.alive:
            self.asv.close()
            self.maneuver = None
            self.event("asv_killed")

    async def restart_asv(self) -> None:
        """A fresh DUNE: the socket open again (the same port), no known systems; it
        announces itself to those that announced to the discovery socket."""
        if not self.asv.alive:
            await self.asv.open(self.opt.bind)
            self.event("asv_restarted", port=self.asv.port)
            self.asv.announce_to([a[0] for a in self.directory.values() if a])
