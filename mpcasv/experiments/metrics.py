"""Run metrics: the one definition of every number in ``metrics.json``.

Names are fixed (other tools read them). Lists hold one value per AUV. Times are in s,
distances in m, energy in J (propulsive: thrust x speed through the water, integrated at
the plant step).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

METRIC_NAMES = (
    "duration_s", "asv_distance_m", "auv_distance_m", "distance_ratio", "standby_s",
    "transit_tracking_s", "transit_avoidance_s", "standby_fraction", "min_range_m",
    "min_slant_range_m", "time_inside_inner_s", "time_outside_outer_s", "fixes",
    "reliable_fixes", "max_fix_age_s", "max_fix_age_overall_s", "mean_fix_age_s",
    "max_revisit_interval_s", "nav_error_rms_m", "nav_error_max_m", "belief_range_error_rms_m",
    "belief_range_jump_max_m", "propeller_on_s", "energy_J", "mode_switches",
    "controller_step_ms_median", "controller_step_ms_p99", "fallbacks",
)  # fmt: skip


def _path_length(N: np.ndarray, E: np.ndarray) -> float:
    return float(np.sum(np.hypot(np.diff(N), np.diff(E))))


def _max_gap(times, t_end: float) -> float:
    """Longest interval without an event, counted from 0 to ``t_end``."""
    edges = np.concatenate([[0.0], np.asarray(times, float), [t_end]])
    return float(np.max(np.diff(edges)))


def _update_jumps(ts: pd.DataFrame, k: int) -> np.ndarray:
    """Jumps of the believed range of AUV k at the updates of its estimate (a fix or report
    arrived), beyond what the true range did meanwhile. The first update is left out: there
    every estimator acquires the AUV (its velocity is still unknown). Without the update
    times in the series (older runs), every step counts."""
    d_est = np.abs(np.diff(ts[f"est_range{k}"].to_numpy()) - np.diff(ts[f"range{k}"].to_numpy()))
    col = f"est{k}_t_fix"
    if col not in ts:
        return d_est
    t_fix = ts[col].to_numpy()
    updated = np.flatnonzero(t_fix[1:] != t_fix[:-1])
    return d_est[updated[1:]]


def _visit_times(ts: pd.DataFrame, k: int) -> np.ndarray:
    """Times at which the ASV waits in AUV k's target domain with the propeller off (the
    condition that resets Paper 2's fix-age timer tau_k, eq. 9)."""
    return ts["t"].to_numpy()[ts[f"visit{k}"].to_numpy(bool)]


def compute_metrics(result) -> dict:
    """All metrics of a :class:`mpcasv.sim.simulator.RunResult` as a flat JSON-able dict."""
    ts: pd.DataFrame = result.timeseries
    n_auv = len(result.scenario.auv)
    Tc = result.scenario.sim.control_period
    if result.scenario.sim.log_every_step:  # one row per plant step: weight rows by dt
        Tc = result.scenario.sim.dt
    t_end = float(ts["t"].iloc[-1])
    mode, reason = ts["mode"].to_numpy(), ts["reason"].to_numpy()
    standby = mode == "standby"
    transit = ~standby
    asv_d = _path_length(ts["N"].to_numpy(), ts["E"].to_numpy())
    auv_d = [_path_length(ts[f"auv{k}_N"].to_numpy(), ts[f"auv{k}_E"].to_numpy())
             for k in range(n_auv)]  # fmt: skip
    mean_auv = float(np.mean(auv_d))

    inside = outside = 0.0
    if f"r_inner{0}" in ts:
        for k in range(n_auv):
            r = ts[f"range{k}"].to_numpy()
            inside += float(np.sum(r < ts[f"r_inner{k}"].to_numpy()) * Tc)
            outside += float(np.sum(r > ts[f"r_outer{k}"].to_numpy()) * Tc)

    fix_age = np.stack([ts[f"fix_age{k}"].to_numpy() for k in range(n_auv)])
    nav = np.stack([ts[f"nav_err{k}"].to_numpy() for k in range(n_auv)])
    belief_err = np.stack(
        [np.abs(ts[f"est_range{k}"].to_numpy() - ts[f"range{k}"].to_numpy()) for k in range(n_auv)]
    )
    belief_jump = np.concatenate([_update_jumps(ts, k) for k in range(n_auv)])
    step_ms = np.asarray(result.step_ms, float)
    return {
        "duration_s": t_end,
        "asv_distance_m": asv_d,
        "auv_distance_m": auv_d,
        "distance_ratio": asv_d / mean_auv if mean_auv > 0 else math.nan,
        "standby_s": float(np.sum(standby) * Tc),
        "transit_tracking_s": float(np.sum(transit & (reason == "tracking")) * Tc),
        "transit_avoidance_s": float(np.sum(transit & (reason == "avoidance")) * Tc),
        "standby_fraction": float(np.mean(standby)),
        "min_range_m": float(result.min_range_m),
        "min_slant_range_m": float(result.min_slant_range_m),
        "time_inside_inner_s": inside,
        "time_outside_outer_s": outside,
        "fixes": [len(f) for f in result.fix_times],
        "reliable_fixes": [len(f) for f in result.reliable_fix_times],
        "max_fix_age_s": [float(a) for a in fix_age.max(axis=1)],
        "max_fix_age_overall_s": float(fix_age.max()),
        "mean_fix_age_s": float(fix_age.mean()),
        # Paper 2's "time between consecutive visits": longest gap between visits, any AUV
        "max_revisit_interval_s": max(_max_gap(_visit_times(ts, k), t_end) for k in range(n_auv)),
        "nav_error_rms_m": float(np.sqrt(np.mean(nav**2))),
        "nav_error_max_m": float(nav.max()),
        "belief_range_error_rms_m": float(np.sqrt(np.mean(belief_err**2))),
        "belief_range_jump_max_m": float(belief_jump.max()) if belief_jump.size else 0.0,
        "propeller_on_s": float(np.sum(ts["propeller_on"].to_numpy()) * Tc),
        "energy_J": float(result.energy_J),
        "mode_switches": int(np.sum(mode[1:] != mode[:-1])),
        "controller_step_ms_median": float(np.median(step_ms)),
        "controller_step_ms_p99": float(np.percentile(step_ms, 99)),
        "fallbacks": int(result.fallbacks),
    }
