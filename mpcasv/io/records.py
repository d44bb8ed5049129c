"""Observations and commands as plain dicts (the deploy JSONL) and back, exactly.

Python floats survive a JSON round trip bit for bit, so :func:`obs_from_dict` rebuilds the
very Observation the controller saw (the JSON log stores NaN and infinities as null: they come
back as NaN, and as ``-inf`` for ``t_last_fix`` and the ASV's USBL fix times, "no fix yet").
"""

from __future__ import annotations

import math

from mpcasv.interface import ASVState, AUVEstimate, Command, Mode, Observation, Reason

__all__ = ["cmd_from_dict", "cmd_to_dict", "obs_from_dict", "obs_to_dict", "same_command"]


def _f(v, missing: float = math.nan) -> float:
    return missing if v is None else float(v)


def _times(ts) -> list[float | None]:
    return [t if math.isfinite(t) else None for t in ts]


def obs_to_dict(obs: Observation) -> dict:
    """An observation as the deploy log writes it; ``actuators`` (thrust N, steering rad, from
    the ASV's set-points), ``actuator_samples`` (``[[t, T, delta], ...]`` through the period)
    and ``usbl_fix_times`` (the ASV's own USBL fixes, ``fix_age_source = "observed"``) only
    when the observation has them."""
    a = obs.asv
    d = {
        "t": obs.t,
        "asv": {"N": a.N, "E": a.E, "psi": a.psi, "u": a.u, "v": a.v, "r": a.r},
        "propeller_on": obs.propeller_on,
        "auvs": [
            {"N": e.N, "E": e.E, "depth": e.depth, "v_N": e.v_N, "v_E": e.v_E,
             "cov": list(e.cov), "t_last_fix": _times([e.t_last_fix])[0]}
            for e in obs.auvs
        ],
    }  # fmt: skip
    if obs.actuators is not None:
        d["actuators"] = list(obs.actuators)
    if obs.usbl_fix_times is not None:
        d["usbl_fix_times"] = _times(obs.usbl_fix_times)
    if obs.actuator_samples is not None:
        d["actuator_samples"] = [list(x) for x in obs.actuator_samples]
    return d


def obs_from_dict(d: dict) -> Observation:
    """Inverse of :func:`obs_to_dict` (a log written before the deploy read the actuators or
    the USBL fixes: ``actuators`` / ``usbl_fix_times`` None)."""
    auvs = tuple(
        AUVEstimate(
            *(_f(e[k]) for k in ("N", "E", "depth", "v_N", "v_E")),
            tuple(_f(c) for c in e["cov"]),
            _f(e["t_last_fix"], -math.inf),
        )
        for e in d["auvs"]
    )
    fixes, act, smp = d.get("usbl_fix_times"), d.get("actuators"), d.get("actuator_samples")
    return Observation(d["t"], ASVState(**d["asv"]), bool(d["propeller_on"]), auvs,
                       actuators=None if act is None else (float(act[0]), float(act[1])),
                       usbl_fix_times=None if fixes is None
                       else tuple(_f(t, -math.inf) for t in fixes),
                       actuator_samples=None if smp is None
                       else tuple(tuple(float(v) for v in x) for x in smp))  # fmt: skip


def cmd_to_dict(cmd: Command) -> dict:
    """A command as the deploy log writes it; ``standby_time`` (s, or None) is what an MPC's
    STANDBY planned (the field log keeps it: the References sent carry no duration,
    docs/mpc.md "Plan following")."""
    return {
        "mode": str(cmd.mode), "waypoint": list(cmd.waypoint) if cmd.waypoint else None,
        "speed": cmd.speed, "auv": cmd.auv, "reason": str(cmd.reason),
        "standby_time": cmd.standby_time,
    }  # fmt: skip


def cmd_from_dict(d: dict) -> Command:
    """Inverse of :func:`cmd_to_dict` (logs written before ``standby_time`` was kept: None)."""
    wp = tuple(d["waypoint"]) if d["waypoint"] is not None else None
    st = d.get("standby_time")
    return Command(Mode(d["mode"]), wp, float(d["speed"]), d["auv"], Reason(d["reason"]),
                   None if st is None else float(st))  # fmt: skip


def same_command(a: Command, b: Command, tol_m: float = 0.5, tol_speed: float = 1e-6) -> bool:
    """Same mode, AUV and reason; transit waypoints within ``tol_m`` and equal speeds."""
    if (a.mode, a.auv, a.reason) != (b.mode, b.auv, b.reason):
        return False
    if a.mode is Mode.STANDBY:
        return True
    dist = math.hypot(a.waypoint[0] - b.waypoint[0], a.waypoint[1] - b.waypoint[1])
    return dist <= tol_m and abs(a.speed - b.speed) <= tol_speed
