"""What the ASV knows of an AUV's survey plan, and the path it describes.

- :class:`KnownPlan`: the plan as the ASV knows it (waypoints, speed, planned surface
  intervals: in the field, the Neptus plan), a copy, never the live behaviour object;
- :func:`known_plan`, :func:`scenario_plans`, :func:`has_plan`, :func:`check_plan_estimator`:
  which AUVs of a scenario have one (the one definition, for the simulator, the suites and
  deploy), and the refusal of the ``plan`` estimator where none has;
- :class:`Polyline`: the piecewise-linear path ``xi(s)`` through the plan's waypoints, by arc
  length, that :class:`~mpcasv.estimation.plan.PlanEstimator` predicts along.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["KnownPlan", "Polyline", "check_plan_estimator", "has_plan", "known_plan",
           "scenario_plans"]


@dataclass(frozen=True)
class KnownPlan:
    """What the ASV knows of an AUV's plan (a copy, never the live behaviour object).

    ``waypoints`` rows ``(N, E[, depth])``; ``surface`` planned ``(t_start, t_end)`` surface
    intervals during which the AUV moves at ``surface_speed``.
    """

    waypoints: np.ndarray
    speed: float
    acceptance: float = 5.0
    surface: tuple[tuple[float, float], ...] = ()
    surface_speed: float = 0.0

    def __post_init__(self) -> None:
        wp = np.atleast_2d(np.asarray(self.waypoints, float))
        if wp.ndim != 2 or wp.shape[1] not in (2, 3) or len(wp) == 0:
            raise ValueError("KnownPlan.waypoints: rows (N, E) or (N, E, depth) expected")
        if not (self.speed > 0 and math.isfinite(self.speed)):
            raise ValueError(f"KnownPlan.speed must be positive, got {self.speed}")
        object.__setattr__(self, "waypoints", wp[:, :2].copy())

    def speed_integral(self, t0: float, t1: float) -> float:
        """``int_t0^t1 u_p dt`` (m) over the planned speed profile (P1), before clipping."""
        d = self.speed * (t1 - t0)
        for a, b in self.surface:
            overlap = max(0.0, min(b, t1) - max(a, t0))
            d -= (self.speed - self.surface_speed) * overlap
        return d

    def speed_at(self, t: float) -> float:
        """Planned along-track speed at ``t`` (m/s)."""
        return self.surface_speed if any(a <= t < b for a, b in self.surface) else self.speed


def known_plan(behaviour) -> KnownPlan | None:
    """The plan of a behaviour as the ASV would know it: a :class:`~mpcasv.models.behaviours.
    Plan` (or the initial plan of a ``Scripted`` one: later changes are *not* known); None
    for a pursuer, a transit or anything without waypoints."""
    from mpcasv.models.behaviours import Plan, Scripted

    if isinstance(behaviour, Scripted):
        behaviour = behaviour.initial
    if not isinstance(behaviour, Plan):
        return None
    return KnownPlan(
        copy.deepcopy(behaviour.waypoints), float(behaviour.speed), float(behaviour.acceptance),
        tuple(tuple(map(float, iv)) for iv in behaviour.surface), float(behaviour.surface_speed),
    )  # fmt: skip


def scenario_plans(scenario) -> list[KnownPlan | None]:
    """The plans of a scenario's AUVs as the ASV knows them (:func:`known_plan` of each
    ``[[auv]]``'s behaviour, in order): the one definition of "which AUVs have a plan", used
    by the simulator, the suites and deploy (``controller.scenario``)."""
    return [known_plan(a.build_behaviour()) for a in scenario.auv]


def has_plan(scenario) -> bool:
    """Whether at least one AUV of ``scenario`` has a plan (the ``plan`` estimator is more
    than its Kalman filter)."""
    return any(p is not None for p in scenario_plans(scenario))


def check_plan_estimator(scenario, estimator: str | None, what: str,
                         fix: str = "estimator 'kalman'") -> None:
    """Refuse the ``plan`` estimator on a scenario in which NO AUV has a plan (waypoints):
    every AUV would run the Kalman filter under the name "plan". ``estimator`` None means the
    scenario's own; ``what`` names where the choice came from (e.g. "--estimator plan") and
    ``fix`` the way out in the caller's terms.
    Some AUVs without a plan beside planned ones stay allowed (those run the Kalman filter).

    Raises
    ------
    ConfigError
        One line naming ``what`` and the way out.
    """
    from mpcasv.config import ConfigError

    if (estimator or scenario.estimator) != "plan":
        return
    if has_plan(scenario):
        return
    behaviours = [a.build_behaviour() for a in scenario.auv]
    kinds = sorted({type(getattr(b, "initial", b)).__name__.lower() for b in behaviours})
    raise ConfigError(f"{what}: no AUV of scenario {scenario.name!r} has a plan (waypoints; its "
                      f"AUVs: {', '.join(kinds)}), so every AUV would run the Kalman filter: "
                      f"use {fix}")  # fmt: skip


class Polyline:
    """A piecewise-linear path ``xi(s)`` with arc length ``s`` (zero-length segments dropped)."""

    def __init__(self, vertices: np.ndarray):
        v = np.asarray(vertices, float)[:, :2]
        keep = np.concatenate([[True], np.hypot(*np.diff(v, axis=0).T) > 1e-6])
        self.v = v[keep]
        seg = np.diff(self.v, axis=0)
        self.len = np.hypot(*seg.T) if len(seg) else np.zeros(0)
        self.T = seg / self.len[:, None] if len(seg) else np.zeros((0, 2))
        self.S = np.concatenate([[0.0], np.cumsum(self.len)])  # arc length at the vertices
        self.length = float(self.S[-1])

    def segment(self, s: float) -> int:
        """Index of the segment containing arc length ``s`` (clipped to the path)."""
        if len(self.len) == 0:
            return -1
        return int(np.clip(np.searchsorted(self.S, s, side="right") - 1, 0, len(self.len) - 1))

    def point(self, s: float) -> tuple[np.ndarray, np.ndarray]:
        """``(xi(s), T(s))`` with ``s`` clipped to ``[0, length]``; T = 0 past the end."""
        if len(self.len) == 0:
            return self.v[0].copy(), np.zeros(2)
        i = self.segment(s)
        sc = min(max(s, 0.0), self.length)
        T = self.T[i] if s < self.length else np.zeros(2)
        return self.v[i] + self.T[i] * (sc - self.S[i]), T

    def corner_distance(self, s: float) -> float:
        """Arc-length distance from ``s`` to the nearest vertex after the start (a turn, or
        the stop at the end; inf if none)."""
        ends = self.S[1:]
        return float(np.min(np.abs(ends - s))) if len(ends) else math.inf

    def project(self, p, s_lo: float = -math.inf, s_hi: float = math.inf) -> tuple[float, float]:
        """Arc length of the point of the path nearest ``p`` with ``s`` in ``[s_lo, s_hi]``,
        and its distance (m)."""
        if len(self.len) == 0:
            return 0.0, float(np.hypot(*(np.asarray(p) - self.v[0])))
        lo, hi = max(s_lo, 0.0), min(s_hi, self.length)
        if hi < lo:
            lo = hi = min(max(lo, 0.0), self.length)
        w = np.asarray(p, float) - self.v[:-1]
        a = np.einsum("ij,ij->i", w, self.T)
        a = np.clip(a, np.maximum(lo - self.S[:-1], 0.0), np.minimum(hi - self.S[:-1], self.len))
        valid = (self.S[:-1] <= hi) & (self.S[1:] >= lo)
        d = np.hypot(*(w - self.T * a[:, None]).T)
        d = np.where(valid, d, np.inf)
        i = int(np.argmin(d))
        return float(self.S[i] + a[i]), float(d[i])
