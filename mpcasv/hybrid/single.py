"""Paper 1's single-AUV hybrid ("donut") tracking controller, eq. 11.

Controller state x = [r_wp, beta_wp, r, beta, q] with q = 1 standby (zero thrust, sensors on)
and q = 2 transit. Written as a :class:`~mpcasv.hybrid.system.HybridAutomaton`:

- Flow Q1: the waypoint follows the ASV's own polar position (r_wp = r, beta_wp = beta).
- Flow Q2: the waypoint is the closest point of the target circle (r_wp = r_t, beta_wp = beta).
- Jump Q2 -> Q1 when |e| < eps, e = r - r_t (eq. 9; target domain eq. 10).
- Jump -> Q2 when r is outside [r_inner, r_outer]: "collision avoidance" when r < r_inner,
  "tracking" when r > r_outer.

The waypoint handed to the execution level is xi_auv + r_wp [cos beta_wp, sin beta_wp] (eq. 7).

Two deliberate, documented refinements of the literal eq. 11 (both keep its behaviour where it
is well posed): the jump Q2 -> Q2 of D2 is expressed as a relabelling of the transit (its reset
equals the Q2 flow, and a literal self-jump would repeat forever); and the jump to Q1 also
requires r in [r_inner, r_outer], so that a target domain reaching past r_outer (a deep AUV)
cannot chatter between the modes.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from mpcasv.config import TransitSpeed, frozen
from mpcasv.controllers import ControllerKind
from mpcasv.hybrid.avoidance import AvoidanceParams, avoidance_radii
from mpcasv.hybrid.domains import DomainParams, point_on_circle, range_bearing
from mpcasv.hybrid.system import HybridAutomaton, Mode, Transition
from mpcasv.interface import Command, Observation, Reason
from mpcasv.interface import Mode as CmdMode

Q1, Q2 = 1, 2  # standby, transit


@frozen
class HybridSingleParams:
    """Preset of the single-AUV controller (PAPER-FACTS §7)."""

    domain: DomainParams
    speed: TransitSpeed = 2.5  # transit speed cap handed to the execution level (m/s)
    # inner boundary: the papers' r_inner (kind "fixed") or an uncertainty-aware domain
    avoidance: AvoidanceParams = AvoidanceParams()


@dataclass(frozen=True, slots=True)
class SingleState:
    """x = [r_wp, beta_wp, r, beta, q] plus the domain radii at the AUV's depth and the
    reason of the current transit."""

    q: int
    r_wp: float
    beta_wp: float
    r: float = math.nan
    beta: float = 0.0
    r_inner: float = 0.0
    r_outer: float = math.inf
    r_t: float = 0.0
    reason: Reason = Reason.NOMINAL


def build_automaton(domain: DomainParams) -> HybridAutomaton:
    """Paper 1 eq. 11 as a hybrid automaton over :class:`SingleState`."""
    rep = dataclasses.replace

    def in_donut(x: SingleState) -> bool:
        return x.r_inner <= x.r <= x.r_outer

    def to_transit(reason):
        return lambda x: rep(x, r_wp=x.r_t, beta_wp=x.beta, reason=reason)

    transitions = [
        Transition(
            Q1, Q2, lambda x: x.r < x.r_inner, to_transit(Reason.AVOIDANCE), "collision avoidance"
        ),  # fmt: skip
        Transition(Q1, Q2, lambda x: x.r > x.r_outer, to_transit(Reason.TRACKING), "tracking"),
        Transition(
            Q2,
            Q2,
            lambda x: x.r < x.r_inner and x.reason != Reason.AVOIDANCE,
            to_transit(Reason.AVOIDANCE),
            "collision avoidance",
        ),  # fmt: skip
        Transition(
            Q2,
            Q2,
            lambda x: x.r > x.r_outer and x.reason != Reason.TRACKING,
            to_transit(Reason.TRACKING),
            "tracking",
        ),  # fmt: skip
        Transition(
            Q2,
            Q1,
            lambda x: _in_target(x, domain) and in_donut(x),
            lambda x: rep(x, r_wp=x.r, beta_wp=x.beta, reason=Reason.NOMINAL),
            "target reached",
        ),  # fmt: skip
    ]
    modes = [
        Mode(Q1, lambda x, dt: rep(x, r_wp=x.r, beta_wp=x.beta)),  # F1
        Mode(Q2, lambda x, dt: rep(x, r_wp=x.r_t, beta_wp=x.beta)),  # F2
    ]
    return HybridAutomaton(modes, transitions)


def _in_target(x: SingleState, domain: DomainParams) -> bool:
    """|e| < eps with e = r - r_t (eqs. 9-10), eps_minus inside and eps_plus outside."""
    return bool(domain.target_reached(x.r, x.r_t))


class HybridSingle:
    """The single-AUV hybrid controller as a :class:`~mpcasv.interface.Controller`."""

    name = "hybrid-single"

    def __init__(self, params: HybridSingleParams):
        self.params = params
        self.domain = params.domain
        self.automaton = build_automaton(params.domain)
        self.state = SingleState(Q1, 0.0, 0.0)

    def reset(self, n_auv: int) -> None:
        if n_auv != 1:
            raise ValueError(f"{self.name} serves one AUV, got {n_auv}")
        self.automaton.clear_log()
        self.state = SingleState(Q1, 0.0, 0.0)

    def observe(self, obs: Observation) -> SingleState:
        """Refresh the measured part of the state (r, beta and the radii at the AUV's depth;
        r_inner from the configured anti-collision domain, the papers' by default)."""
        auv = obs.auvs[0]
        r, beta = range_bearing(obs.asv.position, auv.position)
        dom = self.domain
        r_inner = float(avoidance_radii(self.params.avoidance, dom, obs.auvs, obs.t,
                                        obs.asv.position)[0])  # fmt: skip
        return dataclasses.replace(
            self.state, r=float(r), beta=float(beta), r_inner=r_inner,
            r_outer=float(dom.outer(auv.depth)), r_t=r_inner + dom.delta_r,
        )  # fmt: skip

    def step(self, obs: Observation) -> Command:
        self.state = self.automaton.step(obs.t, self.observe(obs), 1.0)
        x = self.state
        if x.q == Q1:
            return Command.standby(auv=0)
        wp = point_on_circle(obs.auvs[0].position, x.r_wp, x.beta_wp)  # eq. 7
        return Command(CmdMode.TRANSIT, (float(wp[0]), float(wp[1])), self.params.speed, 0,
                       x.reason)  # fmt: skip

    def jump_log(self):
        return self.automaton.jump_log()

    def diagnostics(self) -> dict:
        return {"q": self.state.q}


KIND = ControllerKind(
    "hybrid-single", HybridSingleParams, lambda p, n, boat: HybridSingle(p), "paper1-sim"
)
