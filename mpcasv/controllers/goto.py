"""The trivial controller: go to a fixed waypoint, then stand by (exercises the simulator)."""

from __future__ import annotations

import math

from mpcasv.config import Float, Pos, TransitSpeed, frozen
from mpcasv.controllers.registry import ControllerKind
from mpcasv.interface import Command, Mode, Observation, Reason


@frozen
class GoToParams:
    waypoint: tuple[Float, Float]  # (N, E), m
    speed: TransitSpeed = 2.5  # m/s
    radius: Pos = 10.0  # arrival radius (m)


class GoTo:
    """Transit to ``waypoint``; once within ``radius``, stand by for good."""

    name = "goto"

    def __init__(self, params: GoToParams):
        self.params = params
        self.arrived = False

    def reset(self, n_auv: int) -> None:
        self.arrived = False

    def step(self, obs: Observation) -> Command:
        wp = self.params.waypoint
        if (
            not self.arrived
            and math.hypot(wp[0] - obs.asv.N, wp[1] - obs.asv.E) < self.params.radius
        ):
            self.arrived = True
        if self.arrived:
            return Command.standby(reason=Reason.GOTO)
        return Command(Mode.TRANSIT, wp, self.params.speed, None, Reason.GOTO)


KIND = ControllerKind("goto", GoToParams, lambda p, n, boat: GoTo(p), "goto", multi=True)
