"""What the SITL's vehicles send on their own, as DUNE's do (a mixin of
:class:`mpcasv.io.sitl.Sitl`; its state lives there): the AUVs' and the ASV's EstimatedState
(reference points re-anchored every ``--reanchor`` m), the ASV's actuator set-points while its
loops run (:func:`mpcasv.io.asvwatch.dune_set_points`: SetThrusterActuation, SetServoPosition;
one 0.0 each when they stop, then none), a UsblFixExtended per USBL fix of the world
(DUNE's ``Transports/Evologics`` dispatches one per USBL position) and every vehicle's
PlanControlState at its plan engine's rate (:meth:`Publishing.publish_plan_states`)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import imcpy
import numpy as np

from mpcasv.io.asvwatch import dune_set_points
from mpcasv.io.geo import Origin, to_local, to_wgs84
from mpcasv.io.imc import NavState, estimated_state, usbl_fix_extended
from mpcasv.io.sitlplan import REPORT_PERIOD_S
from mpcasv.models.frames import body_to_ned

if TYPE_CHECKING:
    from mpcasv.io.simvehicle import SimVehicle


class Publishing:
    """The vehicles' own messages, one tick at a time (:meth:`publish_states`)."""

    def position(self, v: SimVehicle) -> tuple[float, float]:
        if v.role == "asv":
            return float(self.world.x[0]), float(self.world.x[1])
        return float(self.world.S[0, v.index]), float(self.world.S[1, v.index])

    def _nav_asv(self, x: np.ndarray) -> NavState:
        N, E, psi, u, v, r = (float(a) for a in x[:6])
        vN, vE = body_to_ned(psi, u, v)
        return NavState(self.now(), N, E, 0.0, psi, u, v, r, vN, vE, math.nan, math.nan)

    def _nav_auv(self, S: np.ndarray, k: int) -> NavState:
        """AUV ``k``'s state (``S`` the world's AUV states, shape (5, K)): heading and surge
        speed through the water, ``vx``, ``vy`` over ground with the current carrying it
        (as the world's reports, :meth:`mpcasv.sim.world.World.auv_course_over_ground`)."""
        N, E, d, psi, U = (float(a) for a in S[:, k])
        c_N, c_E = (float(c) for c in self.world.C_auv[:, k])
        return NavState(self.now(), N, E, d, psi, U, 0.0, 0.0, U * math.cos(psi) + c_N,
                        U * math.sin(psi) + c_E, math.nan, math.nan)  # fmt: skip

    def _es(self, v: SimVehicle, nav: NavState) -> imcpy.EstimatedState:
        if v.anchor is None or math.hypot(*self._offset(v, nav)) > self.opt.reanchor_m:
            lat, lon = to_wgs84(nav.N, nav.E, self.origin)
            v.anchor = Origin(lat, lon, self.origin.height)
        return estimated_state(nav, v.anchor, self.origin)

    def _offset(self, v: SimVehicle, nav: NavState) -> tuple[float, float]:
        lat, lon = to_wgs84(nav.N, nav.E, self.origin)
        n, e, _ = to_local(lat, lon, v.anchor.height, v.anchor)
        return n, e

    def publish_states(self, mid: bool) -> None:
        """AUVs first, then the ASV's thrust and state (a deploy loop that steps on the ASV's
        state then has the AUVs' of the same instant)."""
        w, P = self.world, self.period
        if mid and P is not None:
            j = w.n_sub // 2 - 1
            x = P.X[:, j]
            S = 0.5 * (self.prev_S + w.S)
            S[3] = w.S[3]
        else:
            x, S = w.x, w.S
        if self.opt.auv_states == "acoustic" and not self.dived and self.maneuver is not None \
                and self.maneuver.got_reference:  # fmt: skip
            self.dived = True  # the reports made until now were on radio already
            self.reports_sent = [len(r) for r in w.reports]
        if not self.dived:
            for v in self.auvs:
                v.publish(self._es(v, self._nav_auv(S, v.index)))
        else:
            self.publish_reports()
        self.publish_fixes()
        if self.asv.alive:
            loops = bool(self.command_vector()[0] > 0.5)
            if loops or self.loops_on:  # as DUNE: one 0.0 when the loops stop, then none
                thr, servos = dune_set_points(w.model.params, float(x[6]), float(x[7]))
                for i, value in thr.items():
                    th = imcpy.SetThrusterActuation()
                    th.id, th.value = i, value if loops else 0.0
                    self.asv.publish(th)
                for i, value in servos.items():
                    sp = imcpy.SetServoPosition()
                    sp.id, sp.value = i, value if loops else 0.0
                    self.asv.publish(sp)
            self.loops_on = loops
            self.asv.publish(self._es(self.asv, self._nav_asv(x)))

    async def publish_plan_states(self) -> None:
        """Every :data:`~mpcasv.io.sitlplan.REPORT_PERIOD_S` of the SITL clock, each live
        vehicle's PlanControlState (:mod:`mpcasv.io.sitlplan`), as every DUNE node's plan
        engine reports it (the changes go out as they happen: :mod:`mpcasv.io.sitlasv`).
        Stamped, as everything the SITL sends, at its tick time (:meth:`now`): in order with
        the changes, at the ticks' resolution."""
        while True:
            await self.clock.sleep(REPORT_PERIOD_S)
            for v in self.vehicles:
                v.publish(v.engine.message())

    def publish_reports(self) -> None:
        """``--auv-states acoustic``, once the AUVs dived (the ASV's first Reference): each
        AUV's status reports of the world up to this tick that got through, each as its
        EstimatedState stamped at the report's time (the AUV's own navigation: the true
        position plus its navigation error; its course and speed over ground, ``vx``, ``vy``
        as DUNE's; ``psi`` the course too, the report carrying no heading): what the
        deploy's estimators get in place of 2 Hz states. A report made while the ASV's DUNE
        is down is lost (it would come through the ASV's modem)."""
        t_tick = self.now() - self.ts_offset
        for v in self.auvs:
            for r in _due(self.world.reports[v.index], self.reports_sent, v.index, t_tick):
                if not self.asv.alive:
                    continue
                U = r.speed
                nav = NavState(self.ts_offset + r.t, r.N, r.E, r.depth, r.psi, U, 0.0, 0.0,
                               U * math.cos(r.psi), U * math.sin(r.psi), math.nan, math.nan)
                v.publish(self._es(v, nav), t=nav.t)

    def publish_fixes(self) -> None:
        """The ASV's USBL fixes of the world up to this tick, each as the UsblFixExtended its
        DUNE dispatches (``target`` the AUV's system name), stamped at the fix's own time:
        what ``fix_age_source = "observed"`` reads in ``mpcasv deploy``, sent ``--usbl-delay``
        s after it (AUV states stamped later may then come first, as from a real DUNE: the
        deploy's estimators take them in time order). Fixes while the ASV's DUNE is down are
        lost (none is sent)."""
        if self.ts_offset is None:  # the world has not started
            return
        t_tick = self.now() - self.ts_offset - self.opt.usbl_delay
        for v in self.auvs:
            for f in _due(self.world.fixes[v.index], self.fixes_sent, v.index, t_tick):
                self.asv.publish(usbl_fix_extended(v.name, f.N, f.E, f.depth,
                                                   math.sqrt(f.cov[0] + f.cov[3]), self.origin),
                                 t=self.ts_offset + f.t)  # fmt: skip


def _due(items: list, sent: list[int], k: int, t: float):
    """The world's ``items`` of AUV ``k`` (fixes or reports, in time order) made up to world
    time ``t`` and not yet handed out, each once: ``sent[k]`` counts those handed out."""
    while sent[k] < len(items) and items[sent[k]].t <= t + 1e-9:
        sent[k] += 1
        yield items[sent[k] - 1]
