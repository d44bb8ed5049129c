"""The controller interface shared by the simulator and the deploy loop.

A controller never sees the simulator or the network: it gets an :class:`Observation` once
per supervisory period and returns a :class:`Command`. Hybrid and MPC controllers implement
the same :class:`Controller` protocol, so every experiment and the deploy loop treat them
alike (DESIGN.md, "How data flows").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True, slots=True)
class ASVState:
    """The ASV's own navigation state (NED, body velocities)."""

    N: float
    E: float
    psi: float
    u: float = 0.0
    v: float = 0.0
    r: float = 0.0

    @property
    def position(self) -> np.ndarray:
        return np.array([self.N, self.E])


@dataclass(frozen=True, slots=True)
class AUVEstimate:
    """What the ASV believes about one AUV at the observation time.

    ``cov`` is the 2x2 horizontal position covariance (m^2); ``t_last_fix`` the time of the
    last acoustic fix or report that updated the estimate (``-inf`` if none yet).
    ``forecast`` (optional) maps offsets ``dt`` (s, array) from the estimate's time to the
    predicted horizontal positions ``(len(dt), 2)`` under the estimator's own motion model
    (the plan-aware estimator: along the known plan); without it :meth:`predict` extrapolates
    the velocity.
    """

    N: float
    E: float
    depth: float
    v_N: float = 0.0
    v_E: float = 0.0
    cov: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    t_last_fix: float = -math.inf
    forecast: Callable[[np.ndarray], np.ndarray] | None = field(default=None, compare=False,
                                                                 repr=False)  # fmt: skip

    def predict(self, dt) -> np.ndarray:
        """Predicted horizontal positions ``(len(dt), 2)`` at offsets ``dt`` (s): the
        estimator's forecast when it has one, else constant velocity."""
        dt = np.atleast_1d(np.asarray(dt, float))
        if self.forecast is not None:
            return np.asarray(self.forecast(dt), float).reshape(len(dt), 2)
        return self.position[None, :] + dt[:, None] * np.array([self.v_N, self.v_E])[None, :]

    @property
    def position(self) -> np.ndarray:
        return np.array([self.N, self.E])

    @property
    def sigma(self) -> float:
        """1-sigma horizontal uncertainty (m): sqrt of the covariance's largest eigenvalue."""
        a, b, _, d = self.cov
        return math.sqrt(max(0.0, 0.5 * (a + d) + math.sqrt(0.25 * (a - d) ** 2 + b * b)))


@dataclass(frozen=True, slots=True)
class Observation:
    """Everything a controller may use at time ``t`` (s).

    ``asv`` is the ASV's navigation state (body velocities ``u``, ``v`` over ground).
    ``actuators`` (optional): the thrust (N) and steering (rad) the execution level applies
    now, as the boat knows them (simulation: the plant's actuator states; deploy: DUNE's
    set-points mapped by the vessel's actuation, :meth:`mpcasv.io.asvwatch.Thrusters.
    actuators`, None where they are unknown). ``actuator_samples`` (optional): their values
    through the interval since the previous observation, ``((t, T, delta), ...)`` in time
    order within it (the observer reads them as linear between samples, and from the
    previous observation's ``actuators`` and to this one's at the interval's ends;
    simulation: the plant's actuator states at every plant step, from the interval's start
    to ``t``; None at the first observation, with ``[sim] actuator_samples =
    false`` and where unknown, as in a deploy): an execution level that steers hard
    within a period (Fossen's Otter flips its steering by +-0.44 rad from one 1-s period to
    the next) is not described by the values at the interval's two ends. ``current_oracle``
    (optional): the TRUE current ``(V_N, V_E)`` (m/s) at the ASV, filled by the simulator
    only for a controller that asks for it (attribute ``needs_current_oracle = True``), for
    ablations; never in the field. ``usbl_fix_times`` (optional): per AUV, the time (s) of the
    last USBL fix the ASV's own USBL obtained (simulation: every successful ping, the start's
    known position at t = 0 included; deploy: the latest timestamp of the ``UsblFixExtended``
    the ASV's DUNE sent for that AUV, on the ASV's clock corrected for its clock steps as its
    states are, ``-inf`` before the first),
    whatever the estimator; a fix is reliable or not by where the ASV was and whether its
    propeller ran (Paper 2 eq. 9), which the controller judges.
    """

    t: float
    asv: ASVState
    propeller_on: bool
    auvs: tuple[AUVEstimate, ...]
    actuators: tuple[float, float] | None = None
    current_oracle: tuple[float, float] | None = None
    usbl_fix_times: tuple[float, ...] | None = None
    actuator_samples: tuple[tuple[float, float, float], ...] | None = None


class Mode(StrEnum):
    """Supervisory mode: Q1 standby (propeller off) or Q2 transit."""

    STANDBY = "standby"
    TRANSIT = "transit"


class Reason(StrEnum):
    """Why the controller does what it does (reported and logged)."""

    NOMINAL = "nominal"  # standby for a fix, or transit to the nominally chosen AUV
    TRACKING = "tracking"  # transit because the ASV left through r_outer
    AVOIDANCE = "avoidance"  # transit because the ASV entered r_inner / r_avoid
    GOTO = "goto"  # plain go-to (trivial controller, manoeuvres)
    FALLBACK = "fallback"  # MPC safety fallback took over this step


@dataclass(frozen=True, slots=True)
class Command:
    """A supervisory command for the execution level.

    ``waypoint`` is (N, E) in m; ``speed`` is the cruise speed cap in m/s (the surge-speed
    reference model of thesis eq. 3.1 slows down in turns below it). Standby means zero
    thrust; its waypoint and speed are ignored. ``auv`` is the index of the AUV served.
    ``standby_time`` (optional, standby only): how long the controller means to stand by from
    now (s; an MPC: until its plan's thrust next reaches the propeller-on threshold, at most
    its horizon); None: not said (the hybrid controllers).
    """

    mode: Mode
    waypoint: tuple[float, float] | None = None
    speed: float = 0.0
    auv: int | None = None
    reason: Reason = Reason.NOMINAL
    standby_time: float | None = None

    def __post_init__(self) -> None:
        if self.mode is Mode.TRANSIT:
            if self.waypoint is None or not all(map(math.isfinite, self.waypoint)):
                raise ValueError(f"transit needs a finite waypoint, got {self.waypoint}")
            if not (math.isfinite(self.speed) and self.speed > 0):
                raise ValueError(f"transit needs a positive speed, got {self.speed}")

    @classmethod
    def standby(cls, auv: int | None = None, reason: Reason = Reason.NOMINAL,
                standby_time: float | None = None) -> Command:  # fmt: skip
        return cls(Mode.STANDBY, None, 0.0, auv, reason, standby_time)


@dataclass(frozen=True, slots=True)
class PlannedTrajectory:
    """An MPC's plan: times (s) and NED positions (m) of the ASV; ``extra`` holds further
    planned quantities on the same times (an MPC: thrust ``T`` N, surge speed over ground
    ``u`` m/s, heading ``psi`` rad, steering ``delta`` rad, fix ages ``tau`` s, and the
    planned current ``current`` (V_N, V_E) m/s)."""

    t: np.ndarray
    N: np.ndarray
    E: np.ndarray
    extra: dict = field(default_factory=dict)


@runtime_checkable
class Controller(Protocol):
    """A supervisory controller: one :meth:`step` per supervisory period.

    Implementations may also expose ``plan`` (a :class:`PlannedTrajectory` or None),
    ``fallbacks`` (int) and ``diagnostics()`` (a flat dict logged in the time series).
    """

    name: str

    def reset(self, n_auv: int) -> None:
        """Forget all internal state; ``n_auv`` AUVs will be observed."""

    def step(self, obs: Observation) -> Command:
        """Decide the command for the next supervisory period."""


def pushed_waypoint(waypoint, asv_NE, lead: float) -> tuple[float, float]:
    """``waypoint`` (N, E; m) pushed ``lead`` m further along the line from ``asv_NE``: what
    ``mpcasv deploy`` sends DUNE as the Reference's location (DUNE declares arrival within
    15 m and switches its loops off), and what ``[sim] reference_lead_m`` makes the simulator
    steer at. Unchanged for ``lead = 0`` or a waypoint on the ASV (no line). The heading
    towards it is the same from ``asv_NE``, not from where the boat goes on to."""
    N, E = float(waypoint[0]), float(waypoint[1])
    dN, dE = N - float(asv_NE[0]), E - float(asv_NE[1])
    d = math.hypot(dN, dE)
    if lead > 0 and d > 1e-6:
        N, E = N + lead * dN / d, E + lead * dE / d
    return N, E
