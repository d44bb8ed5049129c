"""The deploy's view of the boat it drives, and of itself: propeller state from the
thrusters (or assumed from the command), the actuators from DUNE's set-points, the ASV's USBL
fixes, the speed actually achieved fed back into the controller, and the deploy's own CPU
use (:class:`BoatFeedback`, a mixin of :class:`mpcasv.io.deploy.Deploy`; the watches
themselves are :mod:`mpcasv.io.asvwatch`).
"""

from __future__ import annotations

import dataclasses
import math
import time

import imcpy
import numpy as np
from scipy.stats import chi2

from mpcasv.interface import Mode
from mpcasv.io.geo import to_local
from mpcasv.io.imc import BadInput
from mpcasv.io.watchdog import OK
from mpcasv.models.acoustics import Fix, usbl_fix

__all__ = ["USBL_AGREE", "USBL_AGREE_SPAN", "USBL_GATE", "BoatFeedback", "cap_command",
           "cap_controller_speed"]

#: a USBL fix whose normalised innovation exceeds this is an outlier (chi-square, 2 degrees
#: of freedom, 99.99 %: -2 ln(1e-4) = 18.42; :meth:`BoatFeedback._implausible`)
USBL_GATE = float(chi2.ppf(0.9999, 2))
#: this many refused fixes of an AUV in a row that agree with each other are taken: the
#: estimate, not the USBL, was wrong (:meth:`BoatFeedback._usbl_position`)
USBL_AGREE = 3
#: ... within this many seconds of each other (a few USBL periods)
USBL_AGREE_SPAN = 30.0


def cap_controller_speed(controller, speed: float,
                         base: float) -> tuple[float, float, float | None]:  # fmt: skip
    """Set ``speed`` in ``controller``'s parameters (and in those of its hybrid fallback, for
    the MPCs) to ``speed`` (m/s), in place, never above ``base`` (its own speed before any
    cap: a cap follows the achievable speed down and back up); an MPC's plan is capped at
    ``speed`` too (:meth:`~mpcasv.mpc.controller.MPCController.set_speed_cap`). Returns
    ``(old, new, plan)``: the speed before and after, and the plan's cap (None for a
    controller without a plan). One definition for the deploy
    (:meth:`BoatFeedback.set_controller_speed`) and its replay (:mod:`mpcasv.io.replay`)."""
    old = float(controller.params.speed)
    new = min(float(base), speed)
    controller.params = dataclasses.replace(controller.params, speed=new)
    fallback = getattr(controller, "hybrid", None)
    if fallback is not None and hasattr(getattr(fallback, "params", None), "speed"):
        fallback.params = dataclasses.replace(fallback.params, speed=new)
    plan = None
    if hasattr(controller, "set_speed_cap"):
        controller.set_speed_cap(speed)
        plan = speed
    return old, new, plan


#: a transit commanded at this fraction of the speed cap or more asks for all the boat makes
#: (:func:`cap_command`): the watch's own tolerance of a speed (10 %)
AT_CAP = 0.9


def cap_command(cmd, speed_cap: float | None, command_max: float | None,
                ask: float | None = None):  # fmt: skip
    """``(cmd, capped)``: a transit's speed as sent to the autopilot.

    - Capped at the lower of ``speed_cap`` (the learned achievable speed,
      ``controller.speed_feedback``) and ``command_max`` (``speed.command_max``, the
      autopilot's limit), either None for none: an MPC's speed comes from its plan, not from
      ``params.speed``, hence the cap on the command too.
    - With ``ask`` (m/s; a controller without a plan: its own speed before the cap, given
      once a cap is applied): a transit at :data:`AT_CAP` x ``speed_cap`` or more, i.e. all
      the boat makes, asks the autopilot for ``ask`` (at most ``command_max``) instead. A
      speed loop that climbs only while behind its set-point (DUNE's Otter: a 250-RPM
      floor, 0.7 m/s, and an integrator of 1 RPM/s per m/s of error) locks at the speed it
      made when asked for it (docs/deploy.md, "Achieved speed").

    ``capped``: the speed was lowered. One definition for the deploy and its replay."""
    transit = cmd.mode is Mode.TRANSIT
    if transit and ask is not None and speed_cap is not None and cmd.speed >= AT_CAP * speed_cap:
        speed = ask if command_max is None else min(ask, command_max)
        return dataclasses.replace(cmd, speed=speed), speed < cmd.speed
    caps = [c for c in (speed_cap, command_max) if c is not None]
    capped = bool(caps) and transit and cmd.speed > min(caps)
    return (dataclasses.replace(cmd, speed=min(caps)) if capped else cmd), capped


def fixes_agree(fixes: list[Fix], v_max: float) -> bool:
    """Whether USBL ``fixes`` of one AUV agree with each other: each pair in time order
    within :data:`USBL_GATE` of each other, with both covariances and ``(v_max dt)^2`` for
    the AUV's motion between them (``v_max``: m/s, ``watchdog.auv_speed_max``)."""
    fs = sorted(fixes, key=lambda f: f.t)
    for a, b in zip(fs, fs[1:], strict=False):
        S = (np.reshape(a.cov, (2, 2)) + np.reshape(b.cov, (2, 2))
             + np.eye(2) * (v_max * (b.t - a.t)) ** 2)  # fmt: skip
        d = np.array([b.N - a.N, b.E - a.E])
        if float(d @ np.linalg.solve(S, d)) > USBL_GATE:
            return False
    return True


class BoatFeedback:
    """Mixin of :class:`mpcasv.io.deploy.Deploy` (uses its ``cfg``, ``link``, ``controller``,
    ``thrusters``, ``speed``, ``usbl``, ``estimators``, ``status``, ``last_cmd`` and
    ``event``)."""

    def load(self, since: tuple[float, float, int] | None = None) -> dict:
        """The deploy's own CPU use and input rate since ``since`` (default: the start):
        process CPU seconds, wall seconds, CPU fraction of one core, datagrams/s."""
        cpu0, wall0, n0 = since or (self._cpu0, self._wall0, 0)
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        n = self.link.datagrams - n0
        return {"cpu_s": cpu, "wall_s": wall, "cpu_fraction": cpu / wall if wall > 0 else None,
                "datagrams": n, "datagrams_per_s": n / wall if wall > 0 else None}  # fmt: skip

    def first(self, what: str) -> bool:
        """Whether ``what`` (an event said once per run) is said now for the first time."""
        if what in self._said:
            return False
        self._said.add(what)
        return True

    def _transit_commanded(self) -> bool:
        """Whether the ASV was sent a transit (its last command; never in a dry run, which
        sends nothing: the boat's propeller was taken as on from a transit never sent, and a
        silent thruster as stale, before session 46)."""
        return (not self.dry_run and self.last_cmd is not None
                and self.last_cmd.mode is Mode.TRANSIT)  # fmt: skip

    def actuators(self, now: float) -> tuple[float, float] | None:
        """The model's thrust and steering from DUNE's set-points (:meth:`mpcasv.io.asvwatch.
        Thrusters.actuators`, by the deploy vessel's actuation); None with ``controller.
        actuator_feedback = false`` or ``watchdog.propeller = "command"`` (the thruster
        messages are not read). The first transit decision without them is reported
        (event ``actuators_unknown``, with the ids heard: a servo that is not id 0, a
        differential boat's second thruster never heard, the wrong vessel actuation)."""
        if not self.cfg.controller.actuator_feedback or self.cfg.watchdog.propeller != "thruster":
            return None
        transit = self._transit_commanded()
        act = self.thrusters.actuators(now, self.vessel, transit)
        if act is None and transit and self.first("actuators_unknown"):
            self.event("actuators_unknown", actuation=self.vessel.actuation,
                       thrusters=sorted(self.thrusters.last), servos=sorted(self.thrusters.servos),
                       note="no fresh set-points for the vessel's actuation (steerable: thruster "
                       "0 and servo 0; differential: thrusters 0 and 1): the controller does "
                       "without")  # fmt: skip
        return act

    def _usbl_fix(self, p, msg) -> None:
        """The ASV's USBL fixed an AUV (``target``: its system name) at the message's time on
        the ASV's clock (corrected as its states are). Rejected (``usbl_fix_time``): a fix
        before the ASV's first state, one while a forward step of the ASV's clock is being
        checked (its time base is in doubt), or one stamped later than the ASV's clock can be
        now (its last state's time, plus the time since that state arrived, plus
        ``clock_slack_s``): a future time would be held as the latest fix and hide the real
        ones after it. A target that is no AUV known by
        that name is reported once (event ``usbl_fix_unknown``) and counted."""
        t = msg.timestamp - p.track.offset
        nav = p.nav
        if nav is None:
            raise BadInput("usbl_fix_time", f"UsblFixExtended for {msg.target!r} before the "
                           "ASV's first state (its clock not known yet)")  # fmt: skip
        latest = nav.t + (self.clock.now() - p.nav_recv) + self.cfg.watchdog.clock_slack_s
        # a forward step being checked (a reordered or repeated state starts a chain too,
        # behind the accepted time: that one leaves the time base as it is)
        stepping = any(s.t > nav.t for s, _ in p.track.chain)
        if stepping or t > latest:
            raise BadInput("usbl_fix_time",
                           f"UsblFixExtended for {msg.target!r} stamped {t:.3f} s: "
                           + ("the ASV's clock is in a step check" if stepping else
                              f"later than the ASV's clock can be ({latest:.3f} s)"))  # fmt: skip
        names = [a.name or a.spec.name for a in self.link.auvs]
        k = self.usbl.fix(msg.target, t, names)
        if k is None:
            if self.usbl.unmatched.get(msg.target) == 1:
                self.event("usbl_fix_unknown", vehicle=p.label, target=msg.target, auvs=names)
            return
        if self.cfg.controller.estimator == "perfect":
            # once per run, and only when it matters: the AUV fixed is not seen by its states
            if self.status[k] not in (OK, "missing") and self.first("positions_unused"):
                self.event("usbl_fix_positions_unused", estimator="perfect",
                           note="the ASV's USBL fixes arrive, and estimator 'perfect' takes "
                           "none of their positions: an AUV is seen by its own states only "
                           "(under water, out of radio contact: estimator 'kalman')")
        elif self.usbl.first_time(k, t):
            self._usbl_position(k, self._fix(k, msg, t, nav))

    def _usbl_position(self, k: int, fix: Fix) -> None:
        """Hand AUV ``k``'s ``fix`` to its estimator, unless it is implausible
        (:meth:`_implausible`: counted in ``usbl.outliers``, event ``usbl_fix_outlier`` for
        an AUV's first). :data:`USBL_AGREE` fixes refused by the gate in a row, within
        :data:`USBL_AGREE_SPAN` s, with no state of the AUV's own between them
        (``usbl.refused`` is cleared by each: :meth:`mpcasv.io.deploy.Deploy._on_state`),
        that agree with each other (:func:`fixes_agree`) restart the AUV's estimator from
        them, event ``usbl_fixes_agree``: the estimate was wrong (a stale estimate; an AUV's
        navigation drifted while under water), not the USBL, whose fixes it would otherwise
        refuse for good (taken as measurements, they moved an estimate confident in the
        AUV's 1-m reports a fraction of the way). While the AUV's own states come, they are
        trusted over repeated fixes elsewhere (a multipath reflection that stays put). Each
        refusal is counted in ``usbl.outliers``, those later taken too."""
        label, refused = self.link.auvs[k].label, self.usbl.refused[k]
        why, gated = self._implausible(k, fix)
        if why is None:
            refused.clear()
            self._take_fix(k, fix)
            return
        self.usbl.outliers[k] += 1
        if self.usbl.outliers[k] == 1:
            self.event("usbl_fix_outlier", vehicle=label, auv=k, fix_t=fix.t,
                       N=round(fix.N, 1), E=round(fix.E, 1), why=why)  # fmt: skip
        if not gated:  # off the map: never evidence against the estimate
            return
        refused.append(fix)
        del refused[:-USBL_AGREE]  # the last ones only
        span = max(f.t for f in refused) - min(f.t for f in refused)
        if (len(refused) == USBL_AGREE and span <= USBL_AGREE_SPAN
                and fixes_agree(refused, self.gp.v_max)):  # fmt: skip
            taken = sorted(refused, key=lambda f: f.t)
            refused.clear()
            self.event("usbl_fixes_agree", vehicle=label, auv=k, fixes=len(taken),
                       fix_t=[f.t for f in taken], why=why,
                       note="refused fixes in a row agree with each other: the estimator "
                       "restarts from them, the estimate was wrong")  # fmt: skip
            old, self.estimators[k] = self.estimators[k], self.new_estimator(k)
            self.estimators[k].reordered, self.estimators[k].dropped = old.reordered, old.dropped
            for f in taken:
                self._take_fix(k, f)

    def _take_fix(self, k: int, fix: Fix) -> None:
        """AUV ``k``'s estimator takes ``fix`` unless it is older than its window (event
        ``usbl_fix_dropped`` for an AUV's first). Only a fix the estimator took keeps the AUV
        seen for the watchdogs and brings an uncertain or lost one back (``auv_fresh`` by
        ``usbl_fix``)."""
        label = self.link.auvs[k].label
        est = self.estimators[k]
        if not est.on_fix(fix):
            if est.dropped == 1:
                self.event("usbl_fix_dropped", vehicle=label, auv=k, fix_t=fix.t,
                           window_s=est.window_s, note="older than the estimator's window "
                           "before its newest measurement: an AUV's clock off the ASV's?")
            return
        self.usbl.taken(k, self.clock.now())
        if self.status[k] not in (OK, "missing"):  # seen again, by the ASV's USBL
            note = {}
            if self.first("fresh_by_fix"):  # the first time: the limit is below the gaps
                note = {"note": "uncertain between two USBL fixes: with the AUVs under water, "
                        "watchdog.auv_stale_s should exceed the gaps between fixes (several "
                        "[acoustics] T0: a fix fails often while the propeller runs)"}
            self.event("auv_fresh", vehicle=label, auv=k, was=self.status[k], by="usbl_fix",
                       **note)  # fmt: skip
            self.status[k] = OK

    def _implausible(self, k: int, fix: Fix) -> tuple[str | None, bool]:
        """``(why, gated)``: why AUV ``k``'s ``fix`` cannot be right (None: it can) and
        whether the USBL gate said so (False: off the map). Refused: further from the origin
        than
        ``watchdog.max_distance_m`` (as a state would be), or outside the USBL gate: its
        normalised innovation against the estimate at the fix's time, with the estimate's
        covariance grown by ``(auv_speed_max age)^2`` (``age``: since the estimate's last
        measurement) and the fix's own, above :data:`USBL_GATE` (chi-square, 2 dof,
        99.99 %). A real USBL has outliers (multipath); the simulator's have none."""
        r, r_max = math.hypot(fix.N, fix.E), self.cfg.watchdog.max_distance_m
        if r > r_max:
            return f"{r:.0f} m from the origin (max_distance_m {r_max:g})", False
        e = self.estimators[k].estimate(fix.t)
        if not (math.isfinite(e.N) and math.isfinite(e.E)):
            return None, False  # nothing to compare with yet
        age = max(fix.t - e.t_last_fix, 0.0) if math.isfinite(e.t_last_fix) else 0.0
        S = (np.reshape(e.cov, (2, 2)) + np.reshape(fix.cov, (2, 2))
             + np.eye(2) * (self.gp.v_max * age) ** 2)  # fmt: skip
        d = np.array([fix.N - e.N, fix.E - e.E])
        nis = float(d @ np.linalg.solve(S, d))
        if nis > USBL_GATE:
            return (f"{math.hypot(*d):.1f} m from the estimate (normalised innovation "
                    f"{nis:.1f} > {USBL_GATE:.1f})"), True
        return None, False

    def _fix(self, k: int, msg, t: float, asv) -> Fix:
        """The :class:`~mpcasv.models.acoustics.Fix` of AUV ``k`` a UsblFixExtended ``msg``
        (stamped ``t``, the ASV's corrected clock) gives, for its estimator as the
        simulator's fixes are (:meth:`mpcasv.sim.world.World._acoustics`): ``lat``/``lon``
        (rad) to N, E about the link's origin; the depth ``z`` if in DEPTH units (DUNE's
        ``UsblTools::toFix``: the ASV's depth plus the USBL's down offset), else the AUV's
        last reported depth (event ``usbl_fix_depth`` once); the covariance from
        ``accuracy`` (m) taken as the horizontal RMS error, ``accuracy^2 / 2`` on each axis
        (the SITL sends ``sqrt(trace R)``), or, where DUNE leaves it 0, thesis eq. 2.9 with
        the deploy's ``[acoustics]`` seen from the ASV's last state ``asv``
        (:func:`~mpcasv.models.acoustics.usbl_fix`'s, the simulator's fixes' covariance);
        the depth's variance from the same map's vertical row (DUNE's depth is the USBL's,
        as the simulator's; NaN for a depth taken from the AUV's report)."""
        N, E, _ = to_local(msg.lat, msg.lon, self.link.origin.height, self.link.origin)
        usbl_depth = msg.z_units == imcpy.ZUnits.DEPTH and math.isfinite(msg.z)
        if usbl_depth:
            depth = float(msg.z)
        else:
            auv = self.link.auvs[k].nav
            depth = auv.depth if auv is not None else 0.0
            if self.first("fix_depth"):
                self.event("usbl_fix_depth", target=msg.target, z_units=str(msg.z_units),
                           depth=depth, note="not a depth: the AUV's last reported depth "
                           "is used (0 before its first state)")  # fmt: skip
        # the simulator's fix at the measured position, without an error: its covariance and
        # depth variance (DUNE's fix depth is the USBL's too, UsblTools toFix)
        fix = usbl_fix(t, k, (asv.N, asv.E), (N, E, depth), self.cfg.acoustics, np.zeros(3))
        acc = float(msg.accuracy)
        if math.isfinite(acc) and acc > 0:
            fix = dataclasses.replace(fix, cov=(acc**2 / 2, 0.0, 0.0, acc**2 / 2))
        if not usbl_depth:  # the AUV's last report: no depth measured
            fix = dataclasses.replace(fix, depth_var=math.nan)
        return fix

    def _propeller_on(self, now: float) -> tuple[bool, str]:
        """(propeller on, source): :class:`mpcasv.io.asvwatch.Thrusters`; reported once per
        stretch: ``thruster_stale`` (a transit commanded, the thrusters silent) and
        ``propeller_assumed`` (no thruster message: propeller-off assumed from our command,
        as in standby, when DUNE's loops are off and it sends none)."""
        transit = self._transit_commanded()
        if self.cfg.watchdog.propeller == "command":
            return transit, "command"
        on, source, stale = self.thrusters.propeller(now, transit)
        note = None
        if stale:
            note = "thruster_stale"
        elif source == "command":
            note = "propeller_assumed"
        if note != self._propeller_note:
            self._propeller_note = note
            if note == "thruster_stale":
                self.event("thruster_stale", thrusters=self.thrusters.values(),
                           note="a transit is commanded and no thruster message is fresh: "
                           "propeller_on taken from our command")  # fmt: skip
            elif note == "propeller_assumed":
                self.event("propeller_assumed", on=on, thrusters=self.thrusters.values(),
                           note="no fresh thruster message (none yet, or DUNE's loops are "
                           "off in standby; 'thrusters' are the last values heard): "
                           "propeller state assumed from our command")  # fmt: skip
        return on, source

    @property
    def speed_ask(self) -> float | None:
        """What a transit at the cap asks the autopilot for (m/s, :func:`cap_command`): a
        controller without a plan (the hybrids) its own speed before the first cap; None for
        an MPC (its command comes from its plan) and before any cap."""
        return None if hasattr(self.controller, "set_speed_cap") else self.speed_base

    def _speed_feedback(self) -> None:
        """``controller.speed_feedback``: cap the controller's transit speed with the learned
        achievable speed (:meth:`set_controller_speed`) when it is more than 10 % lower than
        its ``speed`` or, for an MPC, than the highest speed its plan may use
        (``speed_limit``: the vessel's top speed until capped); from then on the cap follows
        the achievable speed, down or up, whenever they differ by more than 10 %, never above
        the controller's own top speed. A controller without a plan (the hybrids) always
        commands its ``speed``: a command of it at the cap asks the autopilot for its own
        speed (``speed_ask``, :func:`cap_command`). An MPC's command comes from its plan and
        the speed it makes (``speed_rule``): it is not read as "all the boat makes", and is
        sent capped (a review: with the ask, a capped MPC asked DUNE for full speed whatever
        its plan wanted, and could not slow the boat)."""
        cap = self.speed.achievable
        if not self.cfg.controller.speed_feedback or cap is None:
            return
        if self.speed_base is None:  # no cap yet
            current = float(getattr(self.controller.params, "speed", math.inf))
            plan = float(getattr(self.controller, "speed_limit", -math.inf))
            if cap < 0.9 * max(current, plan):
                self.speed_base = current
                self.speed_top = max(v for v in (current, plan) if math.isfinite(v))
                self.set_controller_speed(round(cap, 2))
            return
        new = round(min(cap, self.speed_top), 2)
        now = self.cap_pending if self.cap_pending is not None else self.speed_cap
        if now is None or abs(new - now) > 0.1 * now:
            self.set_controller_speed(new)

    def set_controller_speed(self, speed: float) -> None:
        """Set ``speed`` in the controller's parameters (and in those of its hybrid
        fallback, for the MPCs) to ``speed`` (m/s; never above its own speed before the first
        cap) without rebuilding it: its state (modes,
        timers, warm start) is kept; an MPC's plan is capped at it too
        (:meth:`~mpcasv.mpc.controller.MPCController.set_speed_cap`: the planned thrust held
        to the steady thrust of that speed). Logged as ``controller_speed_cap`` (``plan``:
        the plan's cap, None for a controller without a plan; :func:`cap_controller_speed`).

        Between steps only: while a field-mode step is solving in the step thread (which
        reads the controller's parameters), the cap waits and is applied before the next step
        starts (:meth:`~mpcasv.io.deploystep.FieldMode.schedule_step`), so a decision sees
        one cap throughout, on its controller and on its command, and its step record says
        which (``speed_cap``: what :mod:`mpcasv.io.replay` applies)."""
        if self.step_in_flight():
            self.cap_pending = speed
            return
        self.cap_pending = None
        old, new, plan = cap_controller_speed(self.controller, speed, self.speed_base)
        self.speed_cap = speed
        self.event("controller_speed_cap", old=old, new=new, plan=plan)
