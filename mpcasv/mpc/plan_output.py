"""From the plan to the command (docs/mpc.md, "Controller step" 5; issue 16 item 4): store
the plan commanded, turn it into STANDBY or TRANSIT, log its near-horizon predictions for the
plan-following metrics, and say why it moves. A mixin of
:class:`~mpcasv.mpc.controller.MPCController`."""

from __future__ import annotations

import math

import numpy as np

from mpcasv.control.execution import wrap
from mpcasv.interface import Command, Mode, Observation, PlannedTrajectory, Reason
from mpcasv.mpc.plan_check import PLAN_CHECK_S, commands_standby, planned_standby
from mpcasv.mpc.problem import NXV
from mpcasv.mpc.worldview import ranges


class PlanOutput:
    """The command from the plan (mixin; state in the controller: ``params``, ``ocp``,
    ``domain``, ``target``, ...)."""

    def _reset_dwell(self) -> None:
        """A run's start for the dwell rule (called by the controller's ``reset``)."""
        #: the last command handed over and when its mode began (s): the dwell rule
        #: (``min_dwell``, :meth:`_dwell`)
        self.cmd_out: Command | None = None
        self.t_mode = -math.inf

    def _store_plan(self, t: float, w: np.ndarray) -> None:
        ocp = self.ocp
        Z, V = ocp.split(w)
        ts = t + ocp.t_stage
        K = ocp.dims.n_auv
        delta = (np.asarray(ocp.plan_steering(Z[:, :NXV].T)).ravel() if ocp.heading
                 else Z[:, 7].copy())  # fmt: skip
        self.plan = PlannedTrajectory(ts, Z[:, 0].copy(), Z[:, 1].copy(), {
            "T": Z[:, 6].copy(), "u": Z[:, 3].copy(), "delta": delta,
            "psi": Z[:, 2].copy(), "tau": Z[:, NXV:NXV + K].copy(),
            "current": self.current.copy(),
        })  # fmt: skip

    def _issued(self, t: float, cmd: Command) -> Command:
        """Note ``cmd``, handed over at ``t`` (s), for the dwell rule."""
        if self.cmd_out is None or cmd.mode is not self.cmd_out.mode:
            self.t_mode = t
        self.cmd_out = cmd
        return cmd

    def _dwell(self, t: float, standby: bool, reason: Reason, source: str) -> bool:
        """The dwell rule (``min_dwell``): whether the plan's mode (``standby`` or a TRANSIT
        for ``reason``) is held back because the mode commanded began less than
        ``min_dwell`` s before ``t``. Never for the escape manoeuvre or a plan no deeper
        than it (``source``), nor for a TRANSIT for AVOIDANCE: leaving an AUV's way is
        never delayed. Fallback steps (the hybrid's command) are not held either."""
        want = Mode.STANDBY if standby else Mode.TRANSIT
        held = (self.cmd_out is not None and want is not self.cmd_out.mode
                and t < self.t_mode + self.params.min_dwell - 1e-9
                and source not in ("escape", "as-escape")
                and not (want is Mode.TRANSIT and reason is Reason.AVOIDANCE))
        self._diag["mpc_dwell_held"] = int(held)
        return held

    def _command(self, obs: Observation, w: np.ndarray, p: np.ndarray,
                 source: str = "plan") -> Command:
        """STANDBY or TRANSIT from the plan (see the module docstring); the mode held for
        ``min_dwell`` s (:meth:`_dwell`): a STANDBY for the rest of the dwell time, a TRANSIT
        towards the waypoint last commanded at the speed last commanded."""
        P, ocp = self.params, self.ocp
        Z, _ = ocp.split(w)
        ts = ocp.t_stage
        par = ocp.unpack_par(p)
        # the AUV served: the target, whose visit the terminal cost asks for (the AUV whose
        # target circle the plan ended nearest, before session 46, changed 20 times in a
        # main-job run whose target changed 3 times: the commands' AUV is what the
        # target_switches metric counts, for every controller)
        served = int(self.target)
        self._log_plan(obs.t)
        here = obs.asv.position
        reason = self._transit_reason(here, par)
        standby = commands_standby(Z[:, 6], ocp.dt, P.standby_time, ocp.T_on)
        if self._dwell(obs.t, standby, reason, source):
            if not standby:  # the plan moves: the standby goes on until the dwell is over
                return Command.standby(auv=served,
                                       standby_time=self.t_mode + P.min_dwell - obs.t)
            self.t_depart = None  # the plan stands by: the transit goes on as commanded
            last = self.cmd_out
            return Command(Mode.TRANSIT, last.waypoint, last.speed, served, reason)
        if standby:
            t_stand = planned_standby(ts, Z[:, 6], ocp.T_on)
            if self.t_depart is None:  # the streak's first standby plan: when it moves off
                self.t_depart = obs.t + t_stand
            return Command.standby(auv=served, standby_time=t_stand)
        self.t_depart = None
        look = min(P.lookahead, ts[-1])
        target = np.array([np.interp(look, ts, Z[:, 0]), np.interp(look, ts, Z[:, 1])])
        delta = target - here
        if ocp.heading:  # M1h: the execution level's line of sight is the planned psi_ref
            psi_cmd = self._heading_command(obs, float(np.interp(min(P.speed_lead, ts[-1]), ts,
                                                                 Z[:, 7])))  # fmt: skip
            delta = np.array([math.cos(psi_cmd), math.sin(psi_cmd)]) * max(np.hypot(*delta), 1)
        elif not P.course_control:  # the planned point as seen in the water: the plan's bow
            delta = delta - par["current"] * look  # points there, crabbing
        dn = float(np.hypot(*delta))
        if dn < 1e-6:  # no bearing to the point (the plan's, or in the water): keep the heading
            delta, dn = np.array([math.cos(obs.asv.psi), math.sin(obs.asv.psi)]), 1.0
        wp = here + delta / dn * max(dn, P.min_carrot)
        if P.speed_rule == "max":
            u_cap = np.max(Z[ts <= look + 1e-9, 3])
        elif P.speed_rule == "ahead":  # the same from the first stage on: not the measured now
            u_cap = np.max(Z[(ts > 1e-9) & (ts <= max(look, ts[1]) + 1e-9), 3])
        elif P.speed_rule == "mean":  # the time average of the planned speed over the lookahead
            u_cap = np.mean(np.interp(np.linspace(0.0, look, 31), ts, Z[:, 3]))
        else:  # "plan": the planned speed at the end of the coming control period
            u_cap = np.interp(min(P.speed_lead, ts[-1]), ts, Z[:, 3])
        speed = float(np.clip(u_cap, P.speed_min, ocp.vessel.u_max))
        if self.u_plan is not None:  # the plan's speed cap (mpcasv/mpc/speedcap.py)
            speed = min(speed, self.u_plan)
        return Command(Mode.TRANSIT, (float(wp[0]), float(wp[1])), speed, served, reason)

    def _heading_command(self, obs: Observation, psi_ref: float) -> float:
        """The heading (rad) the TRANSIT waypoint lies along with M1h: the planned reference
        ``psi_ref``, its error from the present heading clipped to ``3 delta_max / Kp(u)``,
        where M1h's PD has saturated (tanh 0.995): the plant's PD steers the same full lock,
        and its speed reference (eq. 3.1, lower as the error grows) and power turn (beyond
        pi/4) are not driven by an error the plan does not model."""
        ocp = self.ocp
        Kp = ocp.pd_gains(obs.asv.u)[0]
        e_max = 3 * ocp.vessel.delta_max / max(Kp, 1e-6)
        e = float(wrap(psi_ref - obs.asv.psi))
        return obs.asv.psi + float(np.clip(e, -e_max, e_max))

    def _log_plan(self, t: float) -> None:
        """This step's command comes from :attr:`plan`: log its near-horizon predictions
        (``PLAN_CHECK_S``) for the plan-tracking metrics, and keep it for the energy check of
        the next step."""
        plan = self._used_plan = self.plan
        self._diag["mpc_plan_t"] = t
        for h in PLAN_CHECK_S:
            th = t + h
            self._diag |= {f"mpc_plan_N{h}": float(np.interp(th, plan.t, plan.N)),
                           f"mpc_plan_E{h}": float(np.interp(th, plan.t, plan.E)),
                           f"mpc_plan_T{h}": float(np.interp(th, plan.t, plan.extra["T"]))}

    def _transit_reason(self, here: np.ndarray, par: dict) -> Reason:
        """Why the plan moves: AVOIDANCE when an AUV would come within its anti-collision
        radius plus ``eps_minus`` of the ASV held where it is, at some stage of the horizon
        (the predicted AUV positions); else TRACKING (following the AUV served, or going to
        the next one: the MPC has no other reason to run the propeller)."""
        still = ranges(here, par["pa"])
        r_avoid = par["r_lo"] - self.params.margin + self.domain.eps_minus
        return Reason.AVOIDANCE if np.any(still < r_avoid) else Reason.TRACKING
