"""AUV behaviours: what each AUV tries to do, evaluated once per supervisory period.

A behaviour turns (time, AUV state, ASV position) into a set-point ``(N_t, E_t, U_d, d_d)``
for the kinematics in :mod:`mpcasv.models.auv`. Behaviours: a waypoint plan (optionally built
from lawnmower patterns, with a depth yoyo and surface intervals), straight transit, a pursuer
that heads for the ASV (the papers' adversarial cases), and scripted switches at given times.
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

    def __post_init__(self) -> None:
        self.waypoints = np.atleast_2d(np.asarray(self.waypoints, float))
        if self.waypoints.shape[1] != 3 or len(self.waypoints) == 0:
            raise ValueError("a plan needs waypoints as rows (N, E, depth)")

    @property
    def finished(self) -> bool:
        return self.index >= len(self.waypoints)

    def setpoint(self, t: float, s: np.ndarray, asv_NE: np.ndarray) -> tuple[float, ...]:
        N, E, d = s[0], s[1], s[2]
        while (
            not self.finished
            and math.hypot(self.waypoints[self.index, 0] - N, self.waypoints[self.index, 1] - E)
            < self.acceptance
        ):
            self.index += 1
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
        if any(a <= t < b for a, b in self.surface):
            depth, speed = 0.0, self.surface_speed
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


@dataclass
class Scripted:
    """Switch to another behaviour at given times: ``events = [(t, behaviour), ...]``."""

    initial: object
    events: list[tuple[float, object]]
    switches: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.events = sorted(self.events, key=lambda ev: ev[0])
        self.current = self.initial

    def setpoint(self, t: float, s: np.ndarray, asv_NE: np.ndarray) -> tuple[float, ...]:
        while self.events and t >= self.events[0][0]:
            t_ev, self.current = self.events.pop(0)
            self.switches.append(t_ev)
        return self.current.setpoint(t, s, asv_NE)

    @property
    def plan(self) -> Plan | None:
        return self.current if isinstance(self.current, Plan) else None
