"""Paper 2's multi-AUV supervisory switching controller, eqs. 8-12.

- Fix-age timers tau_k (eq. 9): tau_k grows while the ASV is outside the outer limit of AUV
  k's target domain or its propeller runs; it resets to 0 when r_k < r_t,k + eps with the
  propeller off (the reliable-fix rule; optionally also requiring an observed fix).
- AUV selection (eq. 8, with the thesis's intent; issue 14, docs/safety.md): nominally
  argmax_k tau_k; as soon as the ASV is inside any AUV's anti-collision radius r_avoid,k, the
  deepest breach argmin_k (r_k - r_avoid,k) over the breached AUVs (rule S1 of
  :mod:`mpcasv.hybrid.clearance`). The printed equation's argmin_k r_k can pick a deeper AUV
  whose smaller (depth-reduced) domain is not breached, and leave the ASV standing by, or
  send it deeper, inside another AUV's domain. After an avoidance the ASV keeps serving that
  AUV until it has stood by there for its fix, then resumes the nominal choice (Paper 2 §2.3).
- Modes (eq. 11): Q1 standby with a countdown tau (set to T on entry, tau_dot = -1, may leave
  only at 0); Q2 transit to the closest point of the selected AUV's target circle (eq. 12).
  Jump to Q1 when |e_i| < eps in Q2; jump to Q2 when (q, tau) = (1, 0) or r_i < r_avoid,i.
  Because i is a breached AUV whenever any domain is breached, the ASV never stands by inside
  a domain. The commanded point is eq. 12's unless it lies within delta_r of another AUV's
  domain; then it is the nearest point (in bearing, then in range) that keeps delta_r clear of
  every domain (rule S2), so an avoidance transit leaves all breached domains at once.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from mpcasv.config import Flag, Pos, TransitSpeed, frozen
from mpcasv.controllers import ControllerKind
from mpcasv.hybrid.avoidance import AvoidanceParams, estimate_shape
from mpcasv.hybrid.clearance import clear_waypoint, deepest_breach
from mpcasv.hybrid.domains import DomainParams, point_on_circle, range_bearing
from mpcasv.hybrid.system import HybridAutomaton, Mode, Transition
from mpcasv.interface import Command, Observation, Reason
from mpcasv.interface import Mode as CmdMode

Q1, Q2 = 1, 2  # standby, transit


@frozen
class HybridMultiParams:
    """Preset of the multi-AUV controller (PAPER-FACTS §7). Paper 2 has no outer boundary:
    ``domain.alpha_outer`` only bounds the domain at the modem's rated range."""

    domain: DomainParams
    T_standby: Pos = 10.0  # T: minimum standby time at an AUV (s)
    speed: TransitSpeed = 2.5  # transit speed cap (m/s)
    require_fix: Flag = False  # tau_k resets only if a fix was also observed (estimator)
    # anti-collision domain: the papers' r_avoid,i (kind "fixed") or an uncertainty-aware one
    avoidance: AvoidanceParams = AvoidanceParams()


@dataclass(frozen=True, slots=True)
class MultiState:
    """x_i = [r_wp,i, beta_wp,i, r_i, beta_i, q, tau] for the selected AUV i, plus the radii."""

    q: int
    tau: float
    i: int = 0
    r_wp: float = 0.0
    beta_wp: float = 0.0
    r: float = math.nan
    beta: float = 0.0
    r_avoid: float = 0.0
    r_t: float = 0.0
    reason: Reason = Reason.NOMINAL


def build_automaton(domain: DomainParams, T: float) -> HybridAutomaton:
    """Paper 2 eq. 11 as a hybrid automaton over :class:`MultiState`."""
    rep = dataclasses.replace

    def transit(reason):
        return lambda x: rep(x, r_wp=x.r_t, beta_wp=x.beta, tau=0.0, reason=reason)

    transitions = [
        # D2, anti-collision part: at any time (a running avoidance is not re-entered)
        Transition(
            (Q1, Q2),
            Q2,
            lambda x: x.r < x.r_avoid and (x.q == Q1 or x.reason != Reason.AVOIDANCE),
            transit(Reason.AVOIDANCE),
            "collision avoidance",
        ),  # fmt: skip
        # D2, countdown part: (q, tau) = (1, 0)
        Transition(Q1, Q2, lambda x: x.tau <= 1e-9, transit(Reason.TRACKING), "standby done"),
        # D1: |e_i| < eps in Q2 (and outside r_avoid,i)
        Transition(
            Q2,
            Q1,
            lambda x: -domain.eps_minus < x.r - x.r_t < domain.eps_plus and x.r >= x.r_avoid,
            lambda x: rep(x, r_wp=x.r, beta_wp=x.beta, tau=T, reason=Reason.NOMINAL),
            "target reached",
        ),  # fmt: skip
    ]
    modes = [
        Mode(Q1, lambda x, dt: rep(x, r_wp=x.r, beta_wp=x.beta, tau=max(x.tau - dt, 0.0))),
        Mode(Q2, lambda x, dt: rep(x, r_wp=x.r_t, beta_wp=x.beta)),
    ]
    return HybridAutomaton(modes, transitions)


class HybridMulti:
    """The multi-AUV supervisory switching controller as a :class:`~mpcasv.interface.Controller`."""

    name = "hybrid-multi"

    def __init__(self, params: HybridMultiParams):
        self.params = params
        self.domain = params.domain
        self.automaton = build_automaton(params.domain, params.T_standby)
        self.reset(1)

    def reset(self, n_auv: int) -> None:
        self.automaton.clear_log()
        self.tau_k = np.zeros(n_auv)  # fix-age timers, eq. 9
        self.last_fix_seen = np.full(n_auv, -math.inf)
        self.latch: int | None = None  # AUV served after an avoidance until its fix
        self.standby_auv = 0
        self.state = MultiState(Q1, 0.0)
        self._t_prev: float | None = None

    def update_timers(self, obs: Observation, r: np.ndarray, r_t: np.ndarray, dt: float) -> None:
        """Eq. 9: tau_k += dt unless r_k < r_t,k + eps with the propeller off (then 0)."""
        ok = self.domain.reliable_fix_possible(r, r_t, obs.propeller_on)  # eq. 9
        if self.params.require_fix:
            seen = np.array([a.t_last_fix for a in obs.auvs])
            ok &= seen > self.last_fix_seen
            self.last_fix_seen = seen
        self.tau_k = np.where(ok, 0.0, self.tau_k + dt)

    def select(self, r: np.ndarray, r_avoid: np.ndarray) -> int:
        """Eq. 8 with the avoid-then-wait latch; inside any domain the deepest breach (S1).

        ``r``, ``r_avoid``: shape (K,), m. The printed eq. 8 takes ``argmin_k r_k`` here.
        """
        breach = deepest_breach(r, r_avoid)  # argmin_k (r_k - r_avoid,k) over r_k < r_avoid,k
        if breach is not None:
            self.latch = breach
            return self.latch
        if self.latch is not None:
            return self.latch
        return int(np.argmax(self.tau_k))

    def step(self, obs: Observation) -> Command:
        dt = 1.0 if self._t_prev is None else obs.t - self._t_prev
        self._t_prev = obs.t
        pos = np.array([a.position for a in obs.auvs])
        r, beta = range_bearing(obs.asv.position, pos)
        shape = estimate_shape(self.params.avoidance, self.domain, obs.auvs, obs.t)
        r_avoid = np.asarray(shape.radius(beta), float)  # r_avoid,k on the bearing to the ASV
        r_t = r_avoid + self.domain.delta_r  # eq. 6
        self.update_timers(obs, r, r_t, dt)
        if self.state.q == Q1 and self.state.tau <= 1e-9 and self.latch == self.standby_auv:
            self.latch = None  # waited for the fix at the avoided AUV: resume nominal choice
        i = self.select(r, r_avoid)
        x = dataclasses.replace(self.state, i=i, r=float(r[i]), beta=float(beta[i]),
                                r_avoid=float(r_avoid[i]), r_t=float(r_t[i]))  # fmt: skip
        q_before = x.q
        x = self.automaton.step(obs.t, x, dt)
        if x.q == Q1 and q_before == Q2:
            self.standby_auv = i
        self.state = x
        if x.q == Q1:
            return Command.standby(auv=self.standby_auv)
        wp = point_on_circle(pos[i], x.r_wp, x.beta_wp)  # eq. 12
        if len(pos) > 1 and np.any(np.delete(shape.signed_distance(wp), i) < self.domain.delta_r):
            wp = clear_waypoint(shape, i, x.beta_wp, self.domain.delta_r)  # S2
        return Command(CmdMode.TRANSIT, (float(wp[0]), float(wp[1])), self.params.speed, i,
                       x.reason)  # fmt: skip

    def jump_log(self):
        return self.automaton.jump_log()

    def diagnostics(self) -> dict:
        d = {"q": self.state.q, "tau": self.state.tau, "i_sel": self.state.i}
        d |= {f"tau{k}": float(v) for k, v in enumerate(self.tau_k)}
        return d


KIND = ControllerKind(
    "hybrid-multi", HybridMultiParams, lambda p, n, boat: HybridMulti(p), "paper2-field", multi=True
)
