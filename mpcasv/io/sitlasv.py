"""The SITL ASV's side of DUNE (a mixin of :class:`mpcasv.io.sitl.Sitl`): PlanControl
START FollowReference / STOP answered as recorded DUNE answers them, References fed to
:class:`mpcasv.io.dune.FollowRefManeuver`, "plan completed" after MANDONE, and the command
vector the world advances with (zeros without a maneuver); the ASV's DUNE killed and
restarted (the outages)."""

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
                self.maneuver = FollowRefManeuver(msg.arg, now, self.origin,
                                                  self.world.model.params.u_max)  # fmt: skip
                self.plan_owner = (msg.request_id, msg.plan_id, node, stream)
                self.event("maneuver_started", src=msg.src, timeout=msg.arg.timeout)
                for info in ("plan loaded", "FollowReference: executing maneuver"):  # DUNE's
                    ans.type, ans.info = _PC.TypeEnum.SUCCESS, info
                    v.reply(ans, node, stream)
                v.publish(self.maneuver.state_message())
            elif msg.op == _PC.OperationEnum.STOP:
                self.maneuver = None
                ans.type, ans.info = _PC.TypeEnum.SUCCESS, "plan stopped"
                self.event("maneuver_stopped", src=msg.src)
                v.reply(ans, node, stream)
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
        req, plan_id, node, stream = self.plan_owner
        ans = imcpy.PlanControl()
        ans.type, ans.op, ans.request_id = _PC.TypeEnum.SUCCESS, _PC.OperationEnum.START, req
        ans.plan_id, ans.info = plan_id, "plan completed"
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
