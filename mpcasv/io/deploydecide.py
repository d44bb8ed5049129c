"""The deploy loop's supervisory step (:class:`Deciding`, a mixin of
:class:`mpcasv.io.deploy.Deploy`; its state lives there): on the ASV's EstimatedState whose
timestamp reaches the next tick of ``controller.control_period``, the Observation (the AUVs'
estimates, inflated when the watchdogs doubt them), the controller's step (inline, or
scheduled in field mode: :mod:`mpcasv.io.deploystep`), the guard
(:func:`mpcasv.io.watchdog.guard`), the speed cap, the Reference to the ASV (unless a dry
run) and the ``step`` record."""

from __future__ import annotations

import math
import time

from mpcasv.interface import ASVState, Command, Mode, Observation
from mpcasv.io.deployfeedback import cap_command
from mpcasv.io.deployphases import PLAN_ENDED
from mpcasv.io.imc import reference
from mpcasv.io.records import cmd_to_dict, obs_to_dict
from mpcasv.io.watchdog import OK, auv_status, guard, inflate


class Deciding:
    """One decision per supervisory tick (module docstring)."""

    def _maybe_step(self, ts: float, now: float) -> None:
        Tc = self.cfg.controller.control_period
        if ts < self.t_next - 0.1 * Tc:
            return
        on_grid = math.isfinite(self.t_next) and ts < self.t_next + 0.5 * Tc
        self.t_next = self.t_next + Tc if on_grid else ts + Tc
        if self.field_mode:
            self.schedule_step(ts, now)
        else:
            self.step(ts, now)

    def observation(self, ts: float, now: float) -> tuple[Observation, list[str], list[float]]:
        """The Observation at ASV-state time ``ts`` with the watchdogs' verdicts."""
        ages = self.auv_ages(now)
        status = [auv_status(a, self.gp) for a in ages]
        ests = []
        for k, est in enumerate(self.estimators):
            e = est.estimate(ts)
            ests.append(e if status[k] == OK else inflate(e, ages[k], self.gp.v_max))
        a = self.link.asv.nav
        on, self._propeller_source = self._propeller_on(now)
        act = self.actuators(now)
        obs = Observation(ts, ASVState(a.N, a.E, a.psi, a.u, a.v, a.r), on, tuple(ests),
                          actuators=act, usbl_fix_times=tuple(self.usbl.times))
        return obs, status, ages

    def step(self, ts: float, now: float) -> Command | None:
        """One decision at ASV-state time ``ts``, the controller stepped inline; None if the
        controller raised (:meth:`step_failed`: event ``step_error``, as in field mode)."""
        obs, status, ages = self.observation(ts, now)
        c0 = time.perf_counter()
        try:
            raw = self.controller.step(obs)
        except Exception as exc:  # not the input's fault: not a link reject (internal_error)
            self.step_failed(ts, exc)
            return None
        cmd = self._act(ts, now, obs, status, ages, raw, (time.perf_counter() - c0) * 1e3)
        if hasattr(self.controller, "between_steps"):  # after the command is sent
            self.log_between(ts, self.run_between())
        return cmd

    def _act(self, ts, now, obs, status, ages, raw: Command, step_ms: float) -> Command:
        """Guard, cap the speed (``speed_feedback``), send (unless dry run), log."""
        cmd, override = guard(raw, obs, status, ages, self.gp)
        ask = None if self.speed_cap is None else self.speed_ask  # once this step's cap is
        cmd, capped = cap_command(cmd, self.speed_cap, self.cfg.speed.command_max, ask)
        sent = False
        if not self.dry_run and self.phase != PLAN_ENDED:  # (a field-mode step in flight)
            lk = self.cfg.link
            ref = reference(cmd, (obs.asv.N, obs.asv.E), self.link.origin, lk.reference_lead_m,
                            lk.reference_radius_m)  # fmt: skip
            sent = self.link.send(self.link.asv, ref)
            if sent:
                self.reference_sent()
        self.last_cmd = cmd
        # the speed watch judges a commanded speed: a dry run commands none (the boat drifts
        # or runs on someone else's commands, never ours)
        transit = cmd.mode is Mode.TRANSIT and not self.dry_run
        self.speed.command(ts, cmd.speed if transit else None)
        self.steps += 1
        self.overrides += override is not None
        diag = getattr(self.controller, "diagnostics", None)
        diag = diag() if diag else {}  # once per step: the record and current_untested
        self.note_untested_current(ts, diag)
        self.jsonl.write({
            "kind": "step", "t": ts, "clock": now, "step": self.steps,
            "obs": obs_to_dict(obs), "controller_cmd": cmd_to_dict(raw), "cmd": cmd_to_dict(cmd),
            "override": override, "sent": sent, "status": status, "ages": ages,
            "step_ms": step_ms, "followref": self.followref, "diag": diag,
            "propeller_source": self._propeller_source, "thrusters": self.thrusters.values(),
            "speed": self.speed.status(), "speed_cap": self.speed_cap, "speed_capped": capped,
            "speed_ask": ask,
        })  # fmt: skip
        return cmd
