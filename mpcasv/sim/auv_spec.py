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

from pydantic import AfterValidator, model_validator

from mpcasv.config import (
    AUV_SPEED_MAX,
    DISTANCE_MAX,
    DURATION_MAX,
    Coord,
    Depth,
    FieldError,
    FiniteNonNeg,
    Flag,
    Heading,
    Label,
    Length,
    Time,
    between,
    frozen,
)
from mpcasv.models.auv import AccelLimit, AUVLimits, DepthRateLimit, SpeedLimit, TurnRateLimit
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

# Bounds of the numbers below (docs/experiments.md, "Bounds"): depths within the ocean
# (DEPTH_MAX), horizontal coordinates and lengths within what a run can cover (DISTANCE_MAX),
# AUV speeds up to AUV_SPEED_MAX (and the AUV's own limits.speed_max: AUVSpec), times within
# the longest run (DURATION_MAX), headings ten turns either way; nan and inf are "not a finite
# number" everywhere.
#: A speed (m/s): in ``(0, AUV_SPEED_MAX]`` (and within the AUV's limits: :class:`AUVSpec`).
Speed = between(0, AUV_SPEED_MAX, "m/s", "no AUV is faster", lo_open=True)
#: A speed that may be 0 (m/s): ``[0, AUV_SPEED_MAX]``.
Speed0 = between(0, AUV_SPEED_MAX, "m/s", "no AUV is faster")
#: A duration within a run (s): ``(0, DURATION_MAX]``.
Span = between(0, DURATION_MAX, "s", "the longest run is a week", lo_open=True)
#: Legs of one lawnmower: ``[1, LEGS_MAX]`` (``legs = 1e7`` built for ever).
LEGS_MAX = 5000
Legs = between(1, LEGS_MAX, "legs", "a week-long run meets fewer waypoints", integer=True)
#: The distance between two lawnmower legs (m): ``[0, DISTANCE_MAX]``.
Spacing = between(0, DISTANCE_MAX, "m", "what the fastest AUV covers in a week")
#: Waypoints of one plan, all its segments together: a week-long run (the longest) at 2 m/s
#: passing a waypoint every minute meets about 10 000.
WAYPOINTS_MAX = 10_000


@frozen
class Start:
    N: Coord = 0.0  # m
    E: Coord = 0.0  # m
    psi_deg: Heading = 0.0  # deg
    depth: Depth = 0.0  # m (the ASV's: 0, Scenario checks)
    #: m/s: an AUV's within its limits.speed_max (AUVSpec), the ASV's within its vessel's
    #: u_max (Scenario)
    speed: FiniteNonNeg = 0.0


@frozen
class LawnmowerSpec:
    origin: tuple[Coord, Coord]
    length: Length
    spacing: Spacing
    legs: Legs
    heading_deg: Heading = 0.0
    depth: Depth = 0.0
    turn: Literal["right", "left"] = "right"


@frozen
class Segment:
    """One piece of a route: explicit waypoints ``[[N, E, depth], ...]`` (at least one) or a
    lawnmower (whose corners must lie within the coordinate bounds too)."""

    waypoints: tuple[tuple[Coord, Coord, Depth], ...] | None = None
    lawnmower: LawnmowerSpec | None = None

    @model_validator(mode="after")
    def _one(self) -> Segment:
        if (self.waypoints is None) == (self.lawnmower is None):
            raise ValueError("a route segment needs exactly one of 'waypoints' or 'lawnmower'")
        if self.waypoints is not None and not self.waypoints:
            raise FieldError("waypoints", "empty: give at least one [N, E, depth] (or leave "
                             "the segment out)")  # fmt: skip
        if self.lawnmower is not None:
            far = max(abs(float(x)) for x in self.points()[:, :2].ravel())
            if far > DISTANCE_MAX:
                raise FieldError("lawnmower", f"its legs reach {far:.4g} m from the origin, "
                                 f"beyond the allowed {DISTANCE_MAX:g} m (what the fastest AUV "
                                 "covers in a week)")  # fmt: skip
        return self

    def points(self):
        if self.lawnmower is not None:
            lm = self.lawnmower
            return lawnmower(lm.origin, lm.heading_deg, lm.length, lm.spacing, lm.legs,
                             lm.depth, lm.turn)  # fmt: skip
        return list(self.waypoints)


@frozen
class PlanSpec:
    speed: Speed
    route: tuple[Segment, ...]
    acceptance: Length = 5.0
    yoyo: tuple[Depth, Depth] | None = None
    surface: tuple[tuple[Time, Time], ...] = ()
    surface_speed: Speed0 = 0.0

    @model_validator(mode="after")
    def _check(self) -> PlanSpec:
        if not self.route:
            raise FieldError("route", "empty: a plan needs at least one segment")
        n = sum(len(seg.points()) for seg in self.route)
        if n > WAYPOINTS_MAX:
            raise FieldError("route", f"{n} waypoints, more than the allowed {WAYPOINTS_MAX} "
                             "(a week-long run meets fewer)")  # fmt: skip
        if self.yoyo is not None and self.yoyo[0] >= self.yoyo[1]:
            raise ValueError("yoyo must be [d_min, d_max] with d_min < d_max")
        if any(b <= a for a, b in self.surface):
            raise ValueError("surface intervals must be [t_start, t_end] with t_end > t_start")
        return self


@frozen
class PursuerSpec:
    speed: Speed
    depth: Depth = 0.0
    update_period: Time = 0.0  # s between re-aims at the ASV (0: continuous pursuit)


@frozen
class TransitSpec:
    heading_deg: Heading
    speed: Speed
    depth: Depth = 0.0


@frozen
class LoiterSpec:
    """Hold position at ``at`` (default: where the AUV is when it starts loitering) and
    ``depth`` (default: its depth then), moving back at up to ``speed`` when pushed away."""

    at: tuple[Coord, Coord] | None = None  # (N, E), m
    depth: Depth | None = None  # m
    speed: Speed = 0.5  # m/s


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

    t: Time
    kind: Literal["switch", "abort", "loiter", "limits"] = "switch"
    plan: PlanSpec | None = None
    pursuer: PursuerSpec | None = None
    transit: TransitSpec | None = None
    rise_rate: DepthRateLimit | None = None  # m/s (abort)
    at: tuple[Coord, Coord] | None = None  # (N, E) m (loiter)
    depth: Depth | None = None  # m (loiter)
    speed: Speed | None = None  # m/s (loiter)
    duration: Span | None = None  # s (loiter)
    speed_max: SpeedLimit | None = None  # m/s (limits)
    turn_rate_max_deg: TurnRateLimit | None = None  # deg/s (limits)
    depth_rate_max: DepthRateLimit | None = None  # m/s (limits)
    accel_max: AccelLimit | None = None  # m/s^2 (limits)

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


def _auv_name(name: str) -> str:
    """An AUV's name is a key in ``[uncertain.auv.NAME]``, in realisation values
    (``auv.NAME.offset_N``) and in the results table's comma-joined ``auv_names``: a ``.``
    left every drawn value of ``lauv.v2`` unapplied while run.json listed them, a ``,``
    crashed compare's report (two names read as three), and ``all`` is the table of every
    AUV (a new user's findings, session 44)."""
    if "." in name or "," in name:
        raise ValueError(f"{name!r}: an AUV's name has no '.' or ',' (it is a key in "
                         "[uncertain.auv.NAME] and in the results' AUV list)")  # fmt: skip
    if name == "all":
        raise ValueError("'all': [uncertain.auv.all] means every AUV; name the AUV otherwise")
    return name


#: An AUV's name: a :data:`~mpcasv.config.Label` without '.' or ',', and not ``all``
AUVName = Annotated[Label, AfterValidator(_auv_name)]


@frozen
class AUVSpec:
    name: AUVName
    behaviour: Behaviour
    start: Start = Start()
    limits: AUVLimits = AUVLimits()
    events: tuple[Event, ...] = ()
    modem_at_surface: Flag = True  # False: no acoustics while at the surface (Case 5)

    @model_validator(mode="after")
    def _speeds(self) -> AUVSpec:
        """Every speed (the start's, each behaviour's and a plan's surface speed) within the
        speed_max in force when it starts (a later limits event may lower it: the kinematics
        then clip the speed); and the behaviour objects build (the check of last resort: a
        model's own refusal, named by field, at load rather than mid-run)."""
        u_max, where = self.limits.speed_max, "limits.speed_max"
        if self.start.speed > u_max:
            raise FieldError("start.speed", f"{self.start.speed} m/s exceeds {where} {u_max}")
        for field, speed in _speeds_of(self.behaviour.spec, "behaviour"):
            if speed > u_max:
                raise FieldError(field, f"{speed} m/s exceeds {where} {u_max}")
        for i, ev in sorted(enumerate(self.events), key=lambda iev: iev[1].t):
            if ev.kind == "limits" and ev.speed_max is not None:
                u_max, where = ev.speed_max, f"speed_max of events[{i}] (t = {ev.t} s)"
            if ev.kind == "loiter" and ev.speed is not None:
                speeds = [(f"events.{i}.speed", ev.speed)]
            elif ev.kind == "switch":
                speeds = _speeds_of(ev.behaviour().spec, f"events.{i}")
            else:
                speeds = []
            for field, speed in speeds:
                if speed > u_max:
                    raise FieldError(field, f"(t = {ev.t} s): {speed} m/s exceeds {where} "
                                     f"{u_max} in force then")  # fmt: skip
        try:
            self.build_behaviour()
        except ValueError as exc:  # every model refusal is a bug of these checks: name it
            raise FieldError("behaviour", f"refused by the AUV model: {exc}") from None
        return self

    def build_behaviour(self):
        """The behaviour object (:mod:`mpcasv.models.behaviours`); a ``Scripted`` one, which
        also gives the limits in force, when the AUV has events."""
        initial = self.behaviour.build()
        if not self.events:
            return initial
        return Scripted(initial, [(ev.t, ev.action()) for ev in self.events],
                        limits=self.limits.vector())  # fmt: skip


def _speeds_of(spec, where: str) -> list[tuple[str, float]]:
    """``(field, speed)`` of a behaviour spec (of ``where``, ``behaviour`` or ``events.i``):
    its speed, and a plan's surface speed."""
    kind = type(spec).__name__.removesuffix("Spec").lower()
    out = [(f"{where}.{kind}.speed", spec.speed)]
    if isinstance(spec, PlanSpec):
        out.append((f"{where}.plan.surface_speed", spec.surface_speed))
    return out


__all__ = ["Start", "LawnmowerSpec", "Segment", "PlanSpec", "PursuerSpec", "TransitSpec",
           "LoiterSpec", "Behaviour", "Event", "AUVSpec", "BEHAVIOURS", "EVENT_FIELDS",
           "LIMIT_INDEX"]  # fmt: skip
