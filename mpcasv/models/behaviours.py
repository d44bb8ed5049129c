"""AUV behaviours: what each AUV tries to do, evaluated once per supervisory period.

A behaviour turns (time, AUV state, ASV position) into a set-point ``(N_t, E_t, U_d, d_d)``
for the kinematics in :mod:`mpcasv.models.auv`. Behaviours: a waypoint plan (optionally built
from lawnmower patterns, with a depth yoyo and surface intervals), straight transit, a pursuer
that heads for the ASV (the papers' adversarial cases), loitering in place, and events at given
times: behaviour switches, an abort (stop and rise), a loiter that resumes, limit changes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np


def lawnmower(
    origin: Sequence[float], heading_deg: float, length: float, spacing: float, legs: int,
    depth: float = 0.0, turn: str = "right",
) -> np.ndarray:  # fmt: skip
    """Waypoints ``(N, E, depth)`` of a lawnmower: ``legs`` parallel legs of ``length`` m,
    ``spacing`` m apart, the first leg along ``heading_deg`` from ``origin``, stepping to the
    right (or left) of the first leg."""
    if legs < 1 or length <= 0 or spacing < 0:
        raise ValueError("lawnmower needs legs >= 1, length > 0, spacing >= 0")
    h = math.radians(heading_deg)
    along = np.array([math.cos(h), math.sin(h)])
    side = np.array([-math.sin(h), math.cos(h)]) * (1 if turn == "right" else -1)
    pts, p = [], np.asarray(origin, float)
    for k in range(legs):
        start = p + side * spacing * k
        end = start + along * length
        pts.extend([start, end] if k % 2 == 0 else [end, start])
    return np.array([[n, e, depth] for n, e in pts])


@dataclass
class Plan:
    """Follow waypoints ``(N, E, depth)`` at ``speed``; hold at the last one (speed 0).

    A waypoint counts as reached within ``acceptance`` m of it (the circle of acceptance),
    or once the AUV has turned a full circle (2 pi of heading, one way) going for it
    without reaching it: an AUV whose turn radius ``U / r_max`` keeps it out of the circle
    (e.g. lawnmower legs closer than about twice the radius) would otherwise circle the
    waypoint for the rest of the run, as the kinematics steer straight at it. A real
    vehicle's path controller does not circle either (DUNE declares arrival from the
    along-track distance to the end). Going for a waypoint ahead, behind or across a current
    the AUV turns less than a circle, so every plan it can follow switches where it always
    did. The turn is the change of the AUV's heading ``s[3]``, which the kinematics
    (:mod:`mpcasv.models.auv`) integrate without wrapping, so it is exact whatever the
    supervisory period; it counts from the set-point at which the waypoint became the
    target, and afresh after :meth:`resume` (a pause: :class:`Scripted`).

    ``yoyo = (d_min, d_max)`` replaces the waypoint depths with a saw-tooth between the two
    depths; ``surface`` lists ``(t_start, t_end)`` intervals spent at the surface (depth 0,
    moving at ``surface_speed``).
    """

    waypoints: np.ndarray
    speed: float
    acceptance: float = 5.0
    yoyo: tuple[float, float] | None = None
    surface: tuple[tuple[float, float], ...] = ()
    surface_speed: float = 0.0
    index: int = 0
    _yoyo_down: bool = field(default=True, repr=False)
    #: the AUV's heading (rad, unwrapped) when going for the current waypoint began
    _psi0: float | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.waypoints = np.atleast_2d(np.asarray(self.waypoints, float))
        if self.waypoints.shape[1] != 3 or len(self.waypoints) == 0:
            raise ValueError("a plan needs waypoints as rows (N, E, depth)")

    @property
    def finished(self) -> bool:
        return self.index >= len(self.waypoints)

    def resume(self) -> None:
        """Count the heading turned afresh from the next set-point (after a pause)."""
        self._psi0 = None

    def setpoint(self, t: float, s: np.ndarray, asv_NE: np.ndarray) -> tuple[float, ...]:
        N, E, d, psi = s[0], s[1], s[2], float(s[3])
        if self._psi0 is None:
            self._psi0 = psi
        while not self.finished and (
            math.hypot(self.waypoints[self.index, 0] - N, self.waypoints[self.index, 1] - E)
            < self.acceptance
            or abs(psi - self._psi0) >= 2 * math.pi  # circling it: move on (class docstring)
        ):
            self.index += 1
            self._psi0 = psi
        wp = self.waypoints[min(self.index, len(self.waypoints) - 1)]
        speed = 0.0 if self.finished else self.speed
        depth = wp[2]
        if self.yoyo is not None:
            d_min, d_max = self.yoyo
            if self._yoyo_down and d >= d_max - 0.5:
                self._yoyo_down = False
            elif not self._yoyo_down and d <= d_min + 0.5:
                self._yoyo_down = True
            depth = d_max if self._yoyo_down else d_min
        if any(a <= t < b for a, b in self.surface):  # (a plan done stays stopped: it
            depth, speed = 0.0, 0.0 if self.finished else self.surface_speed  # circled)
        return wp[0], wp[1], speed, depth


@dataclass
class Transit:
    """Go straight along ``heading_deg`` at ``speed`` and ``depth``."""

    heading_deg: float
    speed: float
    depth: float = 0.0

    def setpoint(self, t: float, s: np.ndarray, asv_NE: np.ndarray) -> tuple[float, ...]:
        h = math.radians(self.heading_deg)
        return s[0] + 1e4 * math.cos(h), s[1] + 1e4 * math.sin(h), self.speed, self.depth


@dataclass
class Pursuer:
    """Head for the ASV at ``speed`` and ``depth`` (the papers' adversarial cases).

    With ``update_period = 0`` the AUV re-aims at the ASV's true position continuously (a
    perfect pursuer); with ``update_period = P`` it heads for where the ASV was when its
    waypoint was last set, re-set every P seconds (an operator changing waypoints by hand, as
    in the papers' Cases 4 and 8).
    """

    speed: float
    depth: float = 0.0
    update_period: float = 0.0
    _target: tuple[float, float] | None = field(default=None, repr=False)
    _t_set: float = field(default=-math.inf, repr=False)

    def setpoint(self, t: float, s: np.ndarray, asv_NE: np.ndarray) -> tuple[float, ...]:
        if self._target is None or t - self._t_set >= self.update_period:
            self._target, self._t_set = (float(asv_NE[0]), float(asv_NE[1])), t
        return self._target[0], self._target[1], self.speed, self.depth


#: the AUV holds its loiter point to within this horizontal distance (m), without moving
LOITER_RADIUS = 2.0
#: speed set-point per metre outside the loiter radius (1/s), before the loiter speed cap
LOITER_GAIN = 0.1


def _latched_heading_point(s: np.ndarray, psi: float) -> tuple[float, float]:
    """A point far ahead along heading ``psi`` from ``s`` (no turn while the AUV stops)."""
    return s[0] + 1e4 * math.cos(psi), s[1] + 1e4 * math.sin(psi)


@dataclass
class Loiter:
    """Hold position: go back to ``at`` (N, E), or to where the AUV is when the loiter starts,
    and stay within :data:`LOITER_RADIUS` at ``depth`` (or its depth then).

    Outside the radius it heads for the point at ``min(speed, LOITER_GAIN * excess)`` (a
    current carrying the AUV is thus fought back); inside, it stops without turning.
    """

    at: tuple[float, float] | None = None
    depth: float | None = None
    speed: float = 0.5  # m/s, the fastest it moves back to its point
    _hold: tuple[float, float, float] | None = field(default=None, repr=False)
    _psi: float = field(default=0.0, repr=False)

    def setpoint(self, t: float, s: np.ndarray, asv_NE: np.ndarray) -> tuple[float, ...]:
        if self._hold is None:  # latched at the first call (the loiter's start)
            N, E = self.at if self.at is not None else (float(s[0]), float(s[1]))
            self._hold = (N, E, float(s[2]) if self.depth is None else self.depth)
            self._psi = float(s[3])
        N, E, d = self._hold
        excess = math.hypot(N - s[0], E - s[1]) - LOITER_RADIUS
        if excess <= 0.0:
            return (*_latched_heading_point(s, float(s[3])), 0.0, d)
        return N, E, min(self.speed, LOITER_GAIN * excess), d


@dataclass
class Abort:
    """Abort: stop where you are (speed 0, keeping the heading) and rise to the surface.

    ``rise_rate`` (m/s) replaces the AUV's depth-rate limit while the abort lasts (None: keep
    the limit in force); the depth loop of :mod:`mpcasv.models.auv` then rises at that rate
    until the last ``rise_rate / K_DEPTH`` metres, which it closes exponentially.
    """

    rise_rate: float | None = None
    _psi: float | None = field(default=None, repr=False)

    def setpoint(self, t: float, s: np.ndarray, asv_NE: np.ndarray) -> tuple[float, ...]:
        if self._psi is None:
            self._psi = float(s[3])
        return (*_latched_heading_point(s, self._psi), 0.0, 0.0)


@dataclass(frozen=True)
class SetLimits:
    """Event action: replace some of the AUV's limits ``{index: value}`` (indices of
    :meth:`mpcasv.models.auv.AUVLimits.vector`: 0 speed, 1 turn rate (rad/s), 2 depth rate,
    3 acceleration) from the event's time on."""

    values: tuple[tuple[int, float], ...]


@dataclass(frozen=True)
class Pause:
    """Event action: run ``behaviour`` for ``duration`` s, then resume the one it interrupted
    (``duration`` None: until the next event or the end)."""

    behaviour: object
    duration: float | None


@dataclass
class Scripted:
    """Events at given times: ``events = [(t, action), ...]``.

    An action is a behaviour (switch to it), a :class:`Pause` (a loiter that may resume the
    interrupted behaviour) or a :class:`SetLimits`. ``limits`` (shape (4,), see
    :meth:`mpcasv.models.auv.AUVLimits.vector`) are the AUV's limits at t = 0; :meth:`limits_now`
    gives the ones in force (an :class:`Abort`'s rise rate included). Events at equal times
    apply in the order given.
    """

    initial: object
    events: list[tuple[float, object]]
    switches: list[float] = field(default_factory=list)
    limits: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.events = sorted(self.events, key=lambda ev: ev[0])  # stable: file order on ties
        self.current = self.initial
        self._lim = None if self.limits is None else np.array(self.limits, float)
        self._resume: tuple[float, object] | None = None

    def setpoint(self, t: float, s: np.ndarray, asv_NE: np.ndarray) -> tuple[float, ...]:
        if self._resume is not None and t >= self._resume[0]:
            self.current, self._resume = self._resume[1], None
            if isinstance(self.current, Plan):
                self.current.resume()
        while self.events and t >= self.events[0][0]:
            t_ev, action = self.events.pop(0)
            if isinstance(action, SetLimits):
                if self._lim is None:
                    raise ValueError("a limits event needs Scripted(limits=...)")
                for i, value in action.values:
                    self._lim[i] = value
                continue
            self.switches.append(t_ev)
            if isinstance(action, Pause):
                end = None if action.duration is None else t_ev + action.duration
                interrupted = self._resume[1] if self._resume is not None else self.current
                self._resume = None if end is None else (end, interrupted)
                self.current = action.behaviour
            else:
                self.current, self._resume = action, None
        return self.current.setpoint(t, s, asv_NE)

    def limits_now(self) -> np.ndarray | None:
        """The limits in force after the last :meth:`setpoint` (None without ``limits``)."""
        if self._lim is None:
            return None
        if isinstance(self.current, Abort) and self.current.rise_rate is not None:
            lim = self._lim.copy()
            lim[2] = self.current.rise_rate
            return lim
        return self._lim

    @property
    def plan(self) -> Plan | None:
        return self.current if isinstance(self.current, Plan) else None
