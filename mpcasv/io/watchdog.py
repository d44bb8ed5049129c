"""Watchdogs of the deploy loop and the safety guard applied to the controller's command.

AUV states age between messages. With ``age`` the time since the last accepted state
(deploy clock):

- ``age <= auv_stale_s``: **ok**.
- ``auv_stale_s < age <= auv_lost_s``: **uncertain**. The AUV may have moved up to
  ``v_max age`` (``v_max`` = ``watchdog.auv_speed_max``) from where it was last seen, so the
  estimate handed to the controller gets its covariance inflated by ``(v_max age)^2`` on each
  axis (:func:`inflate`), and ``t_last_fix`` stays the time of that last state: a controller
  whose anti-collision domain grows with the estimate's sigma or fix age (the
  ``uncertainty``/``reachable`` options of :mod:`mpcasv.hybrid.domains`) sees the growth
  itself; with those options the growth is counted twice (sigma and age), which errs on
  the safe side. Whatever the controller's domain, :func:`guard` enforces the grown radius
  of :func:`mpcasv.hybrid.avoidance.r_avoid_uncertain` (keep-out sphere, the AUV may have
  risen at ``w_max`` and moved at ``v_max`` since) around the last position: it moves a
  transit waypoint out of that disc, and if the ASV is inside it, replaces the command by a
  transit straight away from the AUV to ``r_g + guard_margin_m`` ("guard_avoid").
- ``age > auv_lost_s``: **lost**. Reported once; the ASV is kept safe by standing by
  (propeller off: the papers' safe state, in which a surface vehicle drifts slowly and
  predictably and makes no noise for the AUV's modem), after first leaving the grown disc
  (age capped at ``auv_lost_s``) if it is inside it. Normal control resumes by itself when
  the AUV's states return. Decided for every configured AUV: with one AUV lost the
  multi-AUV controller does not go on serving the others (conservative; the operator can
  reconfigure without the lost AUV).

The ASV's own state going stale is handled by the deploy loop: it stops commanding (no
References, so DUNE's FollowReference ends on its ``timeout`` and switches the loops off) and
restarts FollowReference when the state returns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from mpcasv.hybrid.avoidance import r_avoid_uncertain
from mpcasv.interface import AUVEstimate, Command, Mode, Observation, Reason

__all__ = ["OK", "UNCERTAIN", "LOST", "GuardParams", "auv_status", "guard", "guard_sources",
           "inflate"]

OK, UNCERTAIN, LOST = "ok", "uncertain", "lost"


@dataclass(frozen=True)
class GuardParams:
    """What :func:`guard` needs (from the watchdog config and the controller)."""

    stale_s: float
    lost_s: float
    v_max: float  # m/s the AUV may move away from where it was last seen
    w_max: float  # m/s the AUV may rise
    r_keep: float  # keep-out sphere radius around the AUV (m)
    margin_m: float  # clearance beyond the grown radius when moving away
    speed: float  # m/s of a guard transit when the controller gave none


def guard_sources(params, domain) -> tuple[str, str]:
    """Where the guard takes its keep-out sphere and its transit speed from, for a controller
    with parameters ``params`` and anti-collision domain ``domain`` (None: it has none):
    (``"avoid"`` the controller's ``avoid`` option, else ``"domain"`` its domain's ``r_in``,
    else ``"keep_out_m"`` the watchdog's; ``"speed"`` the controller's, else
    ``"guard_speed"`` the watchdog's). One definition for the guard's parameters
    (:func:`mpcasv.io.deploystep.guard_params`) and for the refusal, at load, of the
    ``[watchdog]`` fields the controller never reads."""
    if getattr(params, "avoid", None) is not None:
        keep = "avoid"
    else:
        keep = "domain" if domain is not None else "keep_out_m"
    return keep, "speed" if hasattr(params, "speed") else "guard_speed"


def auv_status(age: float, p: GuardParams) -> str:
    """``ok``, ``uncertain`` or ``lost`` for a state ``age`` seconds old."""
    if age <= p.stale_s:
        return OK
    return UNCERTAIN if age <= p.lost_s else LOST


def inflate(est: AUVEstimate, age: float, v_max: float) -> AUVEstimate:
    """The estimate with ``(v_max age)^2`` added to both position variances."""
    g2 = (v_max * max(age, 0.0)) ** 2
    a, b, c, d = est.cov
    return replace(est, cov=(a + g2, b, c, d + g2))


def grown_radius(est: AUVEstimate, age: float, p: GuardParams) -> float:
    """The anti-collision radius of an AUV last seen ``age`` s ago (capped at ``lost_s``):
    :func:`mpcasv.hybrid.avoidance.r_avoid_uncertain` with the keep-out sphere ``r_keep``, no
    sigma term (the estimate is the last state itself), ``u_age = v_max`` and ``w_max``."""
    a = min(max(age, 0.0), p.lost_s)
    return float(r_avoid_uncertain(est.depth, p.r_keep, 0.0, a, 0.0, p.v_max, p.w_max))


def guard(
    cmd: Command, obs: Observation, status: list[str], ages: list[float], p: GuardParams
) -> tuple[Command, str | None]:
    """Apply the stale/lost AUV policy of the module docstring to ``cmd``.

    Returns the command to send and the name of the override (None: unchanged).
    """
    if all(s == OK for s in status):
        return cmd, None
    q = obs.asv.position
    worst, worst_k, radii = 0.0, None, {}
    for k, s in enumerate(status):
        if s == OK:
            continue
        e = obs.auvs[k]
        r_g = grown_radius(e, ages[k], p)
        radii[k] = r_g
        depth_in = r_g - math.hypot(q[0] - e.N, q[1] - e.E)
        if depth_in > worst:
            worst, worst_k = depth_in, k
    if worst_k is not None:  # inside a grown disc: straight away from that AUV
        e = obs.auvs[worst_k]
        dN, dE = q[0] - e.N, q[1] - e.E
        d = math.hypot(dN, dE)
        uN, uE = (dN / d, dE / d) if d > 1e-6 else (math.cos(obs.asv.psi), math.sin(obs.asv.psi))
        r = radii[worst_k] + p.margin_m
        speed = cmd.speed if cmd.mode is Mode.TRANSIT else p.speed
        wp = (e.N + r * uN, e.E + r * uE)
        return Command(Mode.TRANSIT, wp, speed, worst_k, Reason.AVOIDANCE), "guard_avoid"
    if LOST in status:
        lost = status.index(LOST)
        return Command.standby(auv=lost, reason=Reason.FALLBACK), "auv_lost_standby"
    if cmd.mode is Mode.TRANSIT:  # keep the waypoint out of every grown disc
        wN, wE = cmd.waypoint
        moved = False
        for k, r_g in radii.items():
            e = obs.auvs[k]
            dN, dE = wN - e.N, wE - e.E
            d = math.hypot(dN, dE)
            if d < r_g:
                uN, uE = (dN / d, dE / d) if d > 1e-6 else (1.0, 0.0)
                wN, wE = e.N + (r_g + p.margin_m) * uN, e.E + (r_g + p.margin_m) * uE
                moved = True
        if moved:
            return replace(cmd, waypoint=(wN, wE)), "guard_waypoint"
    return cmd, None
