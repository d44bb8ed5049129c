"""What the ASV really does, next to what it was told: its thrusters, its speed and its USBL.

:class:`Thrusters` keeps the last ``SetThrusterActuation`` of every thruster id the ASV sends
(DUNE's Otter: id 0 port, 1 starboard, about 10 Hz each while its loops are on) and says
whether the propeller runs, and where that answer comes from:

- ``thruster``: a thruster message not older than ``asv_stale_s``; on if any ``|value|``
  exceeds ``propeller_on_threshold`` (differential thrust drives one motor backwards);
- ``command``: no fresh thruster message. Before the first one ever (nothing to be stale),
  and in standby (DUNE's loops are off: it sends one 0.0 per thruster and then nothing),
  propeller-off is *assumed* from our standby command; only while we command a transit is
  the silence a fault (``thruster_stale``).

:class:`SpeedWatch` compares the speed the ASV achieves, over ground (``|(vx, vy)|``) and
through the water (``u``), with the commanded transit speed (docs: ``[speed]`` of the deploy
configuration, :class:`mpcasv.io.config.SpeedSpec`). A shortfall that persists sets the
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

__all__ = ["SpeedWatch", "Thrusters", "UsblFixes"]


@dataclass
class Thrusters:
    """Last value (-1..1) and arrival time of each thruster id."""

    stale_s: float
    threshold: float
    last: dict[int, tuple[float, float]] = field(default_factory=dict)  # id -> (value, recv)

    def update(self, thruster_id: int, value: float, recv: float) -> None:
        self.last[int(thruster_id)] = (float(value), recv)

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
class UsblFixes:
    """The ASV's last USBL fix time (s, ASV clock) of each of ``n`` AUVs.

    ``times`` starts at ``-inf`` (no fix yet); ``counts`` the fixes per AUV; ``unmatched``
    the fixes of targets that are none of the AUVs, by name.
    """

    n: int
    times: list[float] = field(default_factory=list)
    counts: list[int] = field(default_factory=list)
    unmatched: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.times = self.times or [-math.inf] * self.n
        self.counts = self.counts or [0] * self.n

    def fix(self, target: str, t: float, names: list[str | None]) -> int | None:
        """A fix of system ``target`` stamped ``t`` (s, the ASV's clock corrected), ``names``
        the AUVs' system names as the link knows them now (None: not known yet): the AUV's
        index, or None for a target that is no AUV (counted in ``unmatched``). A fix older
        than the one held (reordered datagrams) leaves the time as it is."""
        k = names.index(target) if target and target in names else None
        if k is None:
            self.unmatched[target] = self.unmatched.get(target, 0) + 1
            return None
        self.counts[k] += 1
        self.times[k] = max(self.times[k], float(t))
        return k


@dataclass
class SpeedWatch:
    """Achieved vs commanded speed (see the module docstring)."""

    spec: SpeedSpec
    commanded: float | None = None  # m/s of the transit being commanded, None in standby
    since: float = -math.inf  # ASV-state time the commanded speed was first sent
    samples: deque = field(default_factory=deque)  # (t, sog, stw)
    short_since: float | None = None
    persistent: bool = False
    achievable: float | None = None  # learned (m/s), None until a persistent shortfall
    _mean: tuple[float, float] | None = None

    def command(self, t: float, speed: float | None) -> None:
        """The command just sent at ASV-state time ``t`` (None / 0: standby)."""
        speed = speed if speed and speed > 0 else None
        if speed != self.commanded:  # a new commanded speed gets a verdict of its own
            self.commanded, self.since = speed, t
            self.short_since, self.persistent = None, False
            self.samples.clear()

    def state(self, t: float, sog: float, stw: float) -> dict | None:
        """One ASV state; returns an event dict (``speed_shortfall`` / ``speed_recovered``)
        when the verdict changes."""
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
            if t - self.short_since >= s.persist_s:
                self.achievable = stw_m
                if not self.persistent:
                    self.persistent = True
                    return {"event": "speed_shortfall", "commanded": self.commanded,
                            "sog": sog_m, "stw": stw_m, "achievable": stw_m,
                            "for_s": t - self.short_since}  # fmt: skip
            return None
        self.short_since = None
        if self.achievable is not None and stw_m > self.achievable:
            self.achievable = stw_m  # it made more than we thought: raise the cap
        if self.persistent:
            self.persistent = False
            return {"event": "speed_recovered", "commanded": self.commanded, "sog": sog_m,
                    "stw": stw_m}  # fmt: skip
        return None

    def status(self) -> dict:
        """The log field ``speed`` of a decision."""
        sog, stw = self._mean if self._mean is not None else (None, None)
        return {"commanded": self.commanded, "sog": sog, "stw": stw,
                "shortfall": self.persistent, "achievable": self.achievable}  # fmt: skip
