"""What the ASV really does, next to what it was told: its actuators, its speed and its USBL.

:class:`Thrusters` keeps the last ``SetThrusterActuation`` of every thruster id the ASV sends
(DUNE's Otter: id 0 port, 1 starboard, about 10 Hz each while its loops are on) and the last
``SetServoPosition`` of every servo id, and says whether the propeller runs, and where that
answer comes from:

- ``thruster``: a thruster message not older than ``asv_stale_s``; on if any ``|value|``
  exceeds ``propeller_on_threshold`` (differential thrust drives one motor backwards);
- ``command``: no fresh thruster message. Before the first one ever (nothing to be stale),
  and in standby (DUNE's loops are off: it sends one 0.0 per thruster and then nothing),
  propeller-off is *assumed* from our standby command; only while we command a transit is
  the silence a fault (``thruster_stale``).

and what the actuators do (:meth:`Thrusters.actuators`: the model's thrust and steering,
``Observation.actuators``, which an MPC plans from and its current observer reads), from the
set-points of the vessel's actuation (:func:`dune_actuators`, the identification's mapping).

:class:`SpeedWatch` compares the speed the ASV achieves, over ground (``|(vx, vy)|``) and
through the water (``u``), with the commanded transit speed (docs: ``[speed]`` of the deploy
configuration, :class:`mpcasv.io.config_limits.SpeedSpec`). A shortfall that persists sets the
*achievable* speed: the mean speed through the water over the window (the boat's own
propulsion; the speed over ground is logged beside it). DUNE's stock Otter asked for
2.0 m/s makes 0.8-0.9 m/s (../shared/data/dune-traffic/README.md, 9).

:class:`UsblFixes` keeps the time of the ASV's last USBL fix of each AUV from the
``UsblFixExtended`` its DUNE dispatches for every USBL position it obtains (DUNE's
``Transports/Evologics`` "always dispatch[es] UsblFixExtended", its ``target`` the AUV's
system name; the Otter's ``Transports.UDP`` list forwards it, ../shared/data/dune-otter-ident/
Config.ini): what ``fix_age_source = "observed"`` (M2o, docs/mpc.md) reads as
``Observation.usbl_fix_times``. The time is the message's own timestamp (the ASV's clock, as
its EstimatedState's, corrected by the same clock-step offset), not its arrival.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from mpcasv.io.config import SpeedSpec
from mpcasv.models.vessel import dune_actuators  # the one definition (re-exported)

__all__ = ["NO_WAY_MS", "ClockRate", "SpeedWatch", "Thrusters", "UsblFixes", "dune_actuators",
           "dune_set_points"]


def dune_set_points(vessel, T: float, delta: float) -> tuple[dict[int, float], dict[int, float]]:
    """Inverse of :func:`dune_actuators`: ``({thruster id: fraction}, {servo id: rad})`` that
    DUNE would send for thrust ``T`` (N) and steering ``delta`` (rad), fractions clipped to
    [-1, 1] (what ``mpcasv sitl``'s ASV sends)."""
    if vessel.actuation == "differential":
        s, d = T / vessel.T_max, delta / vessel.delta_max
        return {0: _unit(s + d), 1: _unit(s - d)}, {}
    return {0: _unit(T / vessel.T_max)}, {0: float(delta)}


def _unit(a: float) -> float:
    """A set-point fraction clipped to [-1, 1] (DUNE's range)."""
    return float(min(1.0, max(-1.0, a)))


@dataclass
class Thrusters:
    """Last value (-1..1) and arrival time of each thruster id."""

    stale_s: float
    threshold: float
    last: dict[int, tuple[float, float]] = field(default_factory=dict)  # id -> (value, recv)
    servos: dict[int, tuple[float, float]] = field(default_factory=dict)  # id -> (rad, recv)

    def update(self, thruster_id: int, value: float, recv: float) -> None:
        self.last[int(thruster_id)] = (float(value), recv)

    def update_servo(self, servo_id: int, value: float, recv: float) -> None:
        self.servos[int(servo_id)] = (float(value), recv)

    def actuators(self, now: float, vessel, transit_commanded: bool) -> tuple[float, float] | None:
        """The model's ``(T, delta)`` (:func:`dune_actuators`) from the set-points the
        vessel's actuation needs (steerable: thruster 0 and servo 0; differential: thrusters
        0 and 1), each fresh (not older than ``stale_s``) or 0.0 (DUNE's last set-point when
        its loops stop: it then sends none). One never heard counts as 0.0 unless a transit
        is commanded (DUNE's loops have not run: assumed from our command, as the propeller
        state is). None when one is stale at another value, or never heard in a transit
        (unknown: the controller then does without)."""
        diff = vessel.actuation == "differential"
        need = [(self.last, 0), (self.last, 1)] if diff else [(self.last, 0), (self.servos, 0)]
        values = []
        for table, i in need:
            if i not in table:
                if transit_commanded:
                    return None
                values.append(0.0)
                continue
            v, t = table[i]
            if now - t > self.stale_s and v != 0.0:
                return None
            values.append(v if table is self.servos else _unit(v))
        T, delta = (dune_actuators(vessel, values[0], values[1]) if diff
                    else dune_actuators(vessel, values[0], servo=values[1]))  # fmt: skip
        return float(T), float(delta)

    def propeller(self, now: float, transit_commanded: bool) -> tuple[bool, str, bool]:
        """(propeller on, source, stale fault): see the module docstring."""
        fresh = [v for v, t in self.last.values() if now - t <= self.stale_s]
        if fresh:
            return any(abs(v) > self.threshold for v in fresh), "thruster", False
        stale = bool(self.last) and transit_commanded
        return transit_commanded, "command", stale

    def values(self) -> dict[str, float]:
        return {str(k): v for k, (v, _) in sorted(self.last.items())}


@dataclass
class ClockRate:
    """How fast the ASV's clock has run against the deploy's since the first ASV state: once
    ``window_s`` s of the deploy clock have passed, a rate above ``ahead`` or below
    ``1 / ahead`` is reported (once per run; the most a real clock was seen to run ahead is
    1.25, a DUNE clock step within ``clock_slack_s``).

    Ahead: a SITL run with ``--speedup 5`` against a deploy whose ``[clock] speedup`` was left
    at 1 decided on time stamps five times faster than its own clock, its staleness limits and
    ``--duration`` in another unit, and said nothing (a new user's finding, session 41).
    Behind: a deploy with ``speedup = 20`` left over from a rehearsal, against a real-time
    vehicle, made 4 decisions in 24 periods, called the ASV stale and back again and
    heart-beat 20 times a second, and said nothing, exit 0 (a field engineer's trial, session
    45); a SITL under ``--lockstep`` that waits for a deploy too slow for its factor runs
    behind too, and that deploy cannot keep up either.
    Taken since the start, not per window: a SITL under ``--lockstep`` falls behind its clock
    while it waits for a slow deploy and then catches up in a burst, faster than real time for
    a while but never ahead of its clock; a short wait is diluted by the time around it. A
    vehicle's silence is not measured (only states that come are): that is ``asv_stale``."""

    window_s: float = 20.0
    ahead: float = 1.5
    ref: tuple[float, float] | None = None  # (ASV state time, deploy clock) at the start
    said: bool = False

    def state(self, t: float, now: float) -> float | None:
        """An ASV state stamped ``t`` (s, the ASV's clock) read at deploy clock ``now`` (s):
        the rate (ASV seconds per deploy second) to report, or None."""
        if self.ref is None or t < self.ref[0]:
            self.ref = (t, now)
            return None
        span = now - self.ref[1]
        if self.said or span < self.window_s:
            return None
        rate = (t - self.ref[0]) / span
        if 1.0 / self.ahead <= rate <= self.ahead:
            return None
        self.said = True
        return rate


#: below this mean speed through the water (m/s) a transit makes no way (drift, a stalled or
#: disengaged propulsion): no achievable speed is learnt from it (:class:`SpeedWatch`). Far
#: below the lowest speed any propulsion makes when it runs: DUNE's Otter makes 0.7 m/s at its
#: 250-RPM floor (docs/deploy.md, "Speeds, commanded against achieved"), the MPCs'
#: ``speed_min`` is 0.5 m/s; a boat drifting backwards measured -0.05 m/s.
NO_WAY_MS = 0.1

#: distinct unmatched USBL targets kept by name (:class:`UsblFixes`)
MAX_UNMATCHED = 20
#: fix times remembered per AUV to recognise a duplicated datagram (:class:`UsblFixes`)
RECENT_FIXES = 32


@dataclass
class UsblFixes:
    """The ASV's last USBL fix time (s, ASV clock) of each of ``n`` AUVs.

    ``times`` starts at ``-inf`` (no fix yet); ``counts`` the fixes per AUV that were newer
    than the one held (a duplicate or reordered one is not counted); ``unmatched`` the fixes
    of targets whose name is none of the AUVs', by name (at most :data:`MAX_UNMATCHED` names,
    the rest under ``"(other)"``). ``positions`` counts the fixes whose position the AUV's
    estimator took (:meth:`taken`: a reordered one too) and ``recv`` is the deploy clock (s)
    when the last of them arrived (``-inf``: none), which keeps the AUV seen for the
    watchdogs as its own states do; ``outliers`` counts the fixes refused as implausible
    (:meth:`mpcasv.io.deployfeedback.BoatFeedback._usbl_position`) and ``refused`` holds
    each AUV's refused fixes since its last taken one.
    """

    n: int
    times: list[float] = field(default_factory=list)
    counts: list[int] = field(default_factory=list)
    unmatched: dict[str, int] = field(default_factory=dict)
    positions: list[int] = field(default_factory=list)
    recv: list[float] = field(default_factory=list)
    outliers: list[int] = field(default_factory=list)
    refused: list[list] = field(default_factory=list)
    _recent: list[deque] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.times = self.times or [-math.inf] * self.n
        self.counts = self.counts or [0] * self.n
        self.positions = self.positions or [0] * self.n
        self.recv = self.recv or [-math.inf] * self.n
        self.outliers = self.outliers or [0] * self.n
        self.refused = self.refused or [[] for _ in range(self.n)]
        self._recent = [deque(maxlen=RECENT_FIXES) for _ in range(self.n)]

    def first_time(self, k: int, t: float) -> bool:
        """Whether AUV ``k``'s fix stamped ``t`` is new (not among the last
        :data:`RECENT_FIXES` seen): a datagram delivered twice would otherwise update the
        estimator twice with one measurement."""
        if t in self._recent[k]:
            return False
        self._recent[k].append(t)
        return True

    def taken(self, k: int, now: float) -> None:
        """AUV ``k``'s estimator took a fix's position, which arrived at ``now`` (deploy
        clock): counted, and the AUV seen."""
        self.positions[k] += 1
        self.recv[k] = max(self.recv[k], now)

    def fix(self, target: str, t: float, names: list[str | None]) -> int | None:
        """A fix of system ``target`` stamped ``t`` (s, the ASV's clock corrected), ``names``
        the AUVs' system names as the link knows them now (None: not known yet): the AUV's
        index, or None for a target that is no AUV (counted in ``unmatched``). A fix older
        than the one held (reordered datagrams) leaves the time as it is."""
        k = names.index(target) if target and target in names else None
        if k is None:
            if target not in self.unmatched and len(self.unmatched) >= MAX_UNMATCHED:
                target = "(other)"
            self.unmatched[target] = self.unmatched.get(target, 0) + 1
            return None
        if t > self.times[k]:
            self.counts[k] += 1
            self.times[k] = float(t)
        return k


@dataclass
class SpeedWatch:
    """Achieved vs commanded speed (see the module docstring).

    A persistent shortfall is one of two verdicts: ``speed_shortfall`` (the boat makes way,
    less than commanded: its mean speed through the water, m/s, is the *achievable* speed)
    or ``speed_no_way`` (its mean speed through the water is below :data:`NO_WAY_MS`: it
    drifts, the propulsion does not drive it; nothing is learnt, the achievable speed stays
    what it was). A speed that small (or negative: a boat drifting backwards measured -0.05
    m/s) is no speed to plan transits with, and a controller refuses a speed cap that is not
    positive."""

    spec: SpeedSpec
    commanded: float | None = None  # m/s of the transit being commanded, None in standby
    since: float = -math.inf  # ASV-state time the commanded speed was first sent
    samples: deque = field(default_factory=deque)  # (t, sog, stw)
    short_since: float | None = None
    verdict: str | None = None  # "speed_shortfall" / "speed_no_way" while persistent
    achievable: float | None = None  # learned (m/s, >= NO_WAY_MS), None until a shortfall
    _mean: tuple[float, float] | None = None

    @property
    def persistent(self) -> bool:
        """Whether a shortfall (either verdict) persists."""
        return self.verdict is not None

    def command(self, t: float, speed: float | None) -> None:
        """The command just sent at ASV-state time ``t`` (s; ``speed`` m/s, None / 0:
        standby or nothing sent, as in a dry run)."""
        speed = speed if speed and speed > 0 else None
        if speed != self.commanded:  # a new commanded speed gets a verdict of its own
            self.commanded, self.since = speed, t
            self.short_since, self.verdict = None, None
            self.samples.clear()

    def state(self, t: float, sog: float, stw: float) -> dict | None:
        """One ASV state at ``t`` (s), its speed over ground ``sog`` and through the water
        ``stw`` (m/s); returns an event dict (``speed_shortfall`` / ``speed_no_way`` /
        ``speed_recovered``) when the verdict changes."""
        s = self.spec
        self.samples.append((t, sog, stw))
        while self.samples and self.samples[0][0] < t - s.window_s:
            self.samples.popleft()
        if self.commanded is None or t - self.since < s.settle_s + s.window_s:
            self._mean = None
            return None
        n = len(self.samples)
        self._mean = (sum(x[1] for x in self.samples) / n, sum(x[2] for x in self.samples) / n)
        sog_m, stw_m = self._mean
        if stw_m < s.ratio * self.commanded:
            if self.short_since is None:
                self.short_since = t
            if t - self.short_since < s.persist_s:
                return None
            verdict = "speed_shortfall" if stw_m >= NO_WAY_MS else "speed_no_way"
            if verdict == "speed_shortfall":
                self.achievable = stw_m
            if verdict == self.verdict:
                return None
            self.verdict = verdict
            ev = {"event": verdict, "commanded": self.commanded, "sog": sog_m, "stw": stw_m,
                  "for_s": t - self.short_since}  # fmt: skip
            if verdict == "speed_shortfall":
                return ev | {"achievable": stw_m}
            return ev | {"achievable": self.achievable, "no_way_ms": NO_WAY_MS,
                         "note": "the boat makes no way through the water at the commanded "
                         "speed (drifting; propulsion stalled, off or fouled?): no speed cap "
                         "is learnt from it"}  # fmt: skip
        self.short_since = None
        if self.achievable is not None and stw_m > self.achievable:
            self.achievable = stw_m  # it made more than we thought: raise the cap
        if self.verdict is not None:
            self.verdict = None
            return {"event": "speed_recovered", "commanded": self.commanded, "sog": sog_m,
                    "stw": stw_m}  # fmt: skip
        return None

    def status(self) -> dict:
        """The log field ``speed`` of a decision."""
        sog, stw = self._mean if self._mean is not None else (None, None)
        return {"commanded": self.commanded, "sog": sog, "stw": stw,
                "shortfall": self.persistent, "achievable": self.achievable}  # fmt: skip
