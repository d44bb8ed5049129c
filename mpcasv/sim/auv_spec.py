"""The AUV part of a scenario file: start, limits, behaviours and events (``[[auv]]``),
validated up front; :mod:`mpcasv.sim.scenario` holds the rest of the format.

Behaviours: ``plan``, ``pursuer``, ``transit``, ``loiter`` (exactly one). Events
(``[[auv.events]]``) by ``kind``: ``switch`` (default; to a plan, pursuer or transit),
``abort`` (stop and rise to the surface at ``rise_rate``), ``loiter`` (hold position for
``duration``, then resume), ``limits`` (replace some limits). The format is in
``docs/experiments.md`` (Scenario files); the behaviour objects in
:mod:`mpcasv.models.behaviours`.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, Strict, model_validator

from mpcasv.config import Flag, Float, Label, NonNeg, Pos, PosInt, frozen
from mpcasv.models.auv import AUVLimits
from mpcasv.models.behaviours import (
    Abort,
    Loiter,
    Pause,
    Plan,
    Pursuer,
    Scripted,
    SetLimits,
    Transit,
    lawnmower,
)


@frozen
class Start:
    N: Float = 0.0  # m
    E: Float = 0.0  # m
    #: heading (deg); ten turns either way at most (1e20 left the boat unable to turn: a yaw
    #: step of 0.01 rad is lost in a float of that size)
    psi_deg: Annotated[float, Strict(), Field(ge=-3600, le=3600, allow_inf_nan=False)] = 0.0
    depth: NonNeg = 0.0  # m
    speed: NonNeg = 0.0  # m/s


@frozen
class LawnmowerSpec:
    origin: tuple[Float, Float]
    length: Pos
    spacing: NonNeg
    legs: PosInt
    heading_deg: Float = 0.0
    depth: NonNeg = 0.0
    turn: Literal["right", "left"] = "right"


@frozen
class Segment:
    """One piece of a route: explicit waypoints ``[[N, E, depth], ...]`` or a lawnmower."""

    waypoints: tuple[tuple[Float, Float, NonNeg], ...] | None = None
    lawnmower: LawnmowerSpec | None = None

    @model_validator(mode="after")
    def _one(self) -> Segment:
        if (self.waypoints is None) == (self.lawnmower is None):
            raise ValueError("a route segment needs exactly one of 'waypoints' or 'lawnmower'")
        return self

    def points(self):
        if self.lawnmower is not None:
            lm = self.lawnmower
            return lawnmower(lm.origin, lm.heading_deg, lm.length, lm.spacing, lm.legs,
                             lm.depth, lm.turn)  # fmt: skip
        return list(self.waypoints)


@frozen
class PlanSpec:
    speed: Pos
    route: tuple[Segment, ...]
    acceptance: Pos = 5.0
    yoyo: tuple[NonNeg, NonNeg] | None = None
    surface: tuple[tuple[NonNeg, NonNeg], ...] = ()
    surface_speed: NonNeg = 0.0

    @model_validator(mode="after")
    def _check(self) -> PlanSpec:
        if not self.route:
            raise ValueError("a plan needs a non-empty route")
        if self.yoyo is not None and self.yoyo[0] >= self.yoyo[1]:
            raise ValueError("yoyo must be [d_min, d_max] with d_min < d_max")
        if any(b <= a for a, b in self.surface):
            raise ValueError("surface intervals must be [t_start, t_end] with t_end > t_start")
        return self


@frozen
class PursuerSpec:
    speed: Pos
    depth: NonNeg = 0.0
    update_period: NonNeg = 0.0  # s between re-aims at the ASV (0: continuous pursuit)


@frozen
class TransitSpec:
    heading_deg: Float
    speed: Pos
    depth: NonNeg = 0.0


@frozen
class LoiterSpec:
    """Hold position at ``at`` (default: where the AUV is when it starts loitering) and
    ``depth`` (default: its depth then), moving back at up to ``speed`` when pushed away."""

    at: tuple[Float, Float] | None = None  # (N, E), m
    depth: NonNeg | None = None  # m
    speed: Pos = 0.5  # m/s


@frozen
class Behaviour:
    """Exactly one of ``plan``, ``pursuer``, ``transit``, ``loiter``."""

    plan: PlanSpec | None = None
    pursuer: PursuerSpec | None = None
    transit: TransitSpec | None = None
    loiter: LoiterSpec | None = None

    @model_validator(mode="after")
    def _one(self) -> Behaviour:
        given = [k for k in BEHAVIOURS if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of {', '.join(BEHAVIOURS)} "
                             f"(got {given or 'none'})")  # fmt: skip
        return self

    @property
    def spec(self):
        return self.plan or self.pursuer or self.transit or self.loiter

    def build(self):
        if self.plan is not None:
            p = self.plan
            pts = [pt for seg in p.route for pt in seg.points()]
            return Plan(pts, p.speed, p.acceptance, p.yoyo, p.surface, p.surface_speed)
        if self.pursuer is not None:
            p = self.pursuer
            return Pursuer(p.speed, p.depth, p.update_period)
        if self.loiter is not None:
            return Loiter(self.loiter.at, self.loiter.depth, self.loiter.speed)
        return Transit(self.transit.heading_deg, self.transit.speed, self.transit.depth)


BEHAVIOURS = ("plan", "pursuer", "transit", "loiter")
#: the fields each event kind may give (besides ``t`` and ``kind``)
EVENT_FIELDS = {
    "switch": ("plan", "pursuer", "transit"),
    "abort": ("rise_rate",),
    "loiter": ("at", "depth", "speed", "duration"),
    "limits": ("speed_max", "turn_rate_max_deg", "depth_rate_max", "accel_max"),
}
#: index of each limit in :meth:`AUVLimits.vector` (turn rate converted to rad/s)
LIMIT_INDEX = {"speed_max": 0, "turn_rate_max_deg": 1, "depth_rate_max": 2, "accel_max": 3}


@frozen
class Event:
    """What happens to an AUV at time ``t`` (s), by ``kind``:

    - ``switch`` (default): it switches to the behaviour given (exactly one of ``plan``,
      ``pursuer``, ``transit``);
    - ``abort``: it stops where it is and rises to the surface, at ``rise_rate`` m/s if given
      (replacing its depth-rate limit while the abort lasts), and stays there;
    - ``loiter``: it holds position (``at``, ``depth``, ``speed`` as in ``[behaviour.loiter]``)
      for ``duration`` s and then resumes what it was doing (no ``duration``: until the next
      event or the end);
    - ``limits``: the limits given (``speed_max``, ``turn_rate_max_deg``, ``depth_rate_max``,
      ``accel_max``) replace the ones in force from then on.
    """

    t: NonNeg
    kind: Literal["switch", "abort", "loiter", "limits"] = "switch"
    plan: PlanSpec | None = None
    pursuer: PursuerSpec | None = None
    transit: TransitSpec | None = None
    rise_rate: Pos | None = None  # m/s (abort)
    at: tuple[Float, Float] | None = None  # (N, E) m (loiter)
    depth: NonNeg | None = None  # m (loiter)
    speed: Pos | None = None  # m/s (loiter)
    duration: Pos | None = None  # s (loiter)
    speed_max: Pos | None = None  # m/s (limits)
    turn_rate_max_deg: Pos | None = None  # deg/s (limits)
    depth_rate_max: Pos | None = None  # m/s (limits)
    accel_max: Pos | None = None  # m/s^2 (limits)

    @model_validator(mode="after")
    def _kind(self) -> Event:
        allowed = EVENT_FIELDS[self.kind]
        for kind, names in EVENT_FIELDS.items():
            for name in names:
                if name not in allowed and getattr(self, name) is not None:
                    raise ValueError(f"{name} belongs to kind = {kind!r} events, not to "
                                     f"kind = {self.kind!r}")  # fmt: skip
        if self.kind == "switch":
            given = [k for k in allowed if getattr(self, k) is not None]
            if len(given) != 1:
                raise ValueError("a switch event (no kind, or kind = 'switch') needs exactly one "
                                 "of plan, pursuer, transit (or give kind = 'abort', 'loiter' "
                                 f"or 'limits'); got {given or 'none'}")  # fmt: skip
        if self.kind == "limits" and not any(getattr(self, k) is not None for k in allowed):
            raise ValueError(f"a limits event needs at least one of {', '.join(allowed)}")
        return self

    def behaviour(self) -> Behaviour:
        """The behaviour a switch event switches to."""
        return Behaviour(self.plan, self.pursuer, self.transit)

    def action(self):
        """What :class:`~mpcasv.models.behaviours.Scripted` does at ``t``."""
        if self.kind == "switch":
            return self.behaviour().build()
        if self.kind == "abort":
            return Abort(self.rise_rate)
        if self.kind == "loiter":
            loiter = Loiter(self.at, self.depth, 0.5 if self.speed is None else self.speed)
            return Pause(loiter, self.duration)
        return SetLimits(tuple(
            (i, math.radians(v) if name == "turn_rate_max_deg" else v)
            for name, i in LIMIT_INDEX.items() if (v := getattr(self, name)) is not None
        ))  # fmt: skip


@frozen
class AUVSpec:
    name: Label
    behaviour: Behaviour
    start: Start = Start()
    limits: AUVLimits = AUVLimits()
    events: tuple[Event, ...] = ()
    modem_at_surface: Flag = True  # False: no acoustics while at the surface (Case 5)

    @model_validator(mode="after")
    def _speeds(self) -> AUVSpec:
        """Every behaviour's speed within the speed_max in force when it starts (a later limits
        event may lower it: the kinematics then clip the speed)."""
        u_max, where = self.limits.speed_max, "limits.speed_max"
        spec = self.behaviour.spec
        if spec.speed > u_max:
            raise ValueError(f"behaviour speed {spec.speed} exceeds {where} {u_max}")
        for i, ev in sorted(enumerate(self.events), key=lambda iev: iev[1].t):
            if ev.kind == "limits" and ev.speed_max is not None:
                u_max, where = ev.speed_max, f"speed_max of events[{i}] (t = {ev.t} s)"
            speed = ev.speed if ev.kind == "loiter" else (
                ev.behaviour().spec.speed if ev.kind == "switch" else None)  # fmt: skip
            if speed is not None and speed > u_max:
                raise ValueError(f"events[{i}] (t = {ev.t} s): speed {speed} exceeds {where} "
                                 f"{u_max} in force then")  # fmt: skip
        return self

    def build_behaviour(self):
        """The behaviour object (:mod:`mpcasv.models.behaviours`); a ``Scripted`` one, which
        also gives the limits in force, when the AUV has events."""
        initial = self.behaviour.build()
        if not self.events:
            return initial
        return Scripted(initial, [(ev.t, ev.action()) for ev in self.events],
                        limits=self.limits.vector())  # fmt: skip


__all__ = ["Start", "LawnmowerSpec", "Segment", "PlanSpec", "PursuerSpec", "TransitSpec",
           "LoiterSpec", "Behaviour", "Event", "AUVSpec", "BEHAVIOURS", "EVENT_FIELDS",
           "LIMIT_INDEX"]  # fmt: skip
