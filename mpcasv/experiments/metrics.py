"""Run metrics: the one definition of every number in ``metrics.json`` (docs/metrics.md).

Every safety and liveness figure comes from the simulator's ground-truth account (true
positions and depths, plant-step resolution, the SCENARIO's evaluation domain; see
:mod:`mpcasv.sim.account`), the same for every controller whatever its labels. The
controller's own reason labels appear only as diagnostics (``label_*``).

Names are fixed (other tools read them). Scalars aggregate over AUVs as stated in
:data:`METRIC_INFO`; the per-AUV lists carry the suffix ``_auv``. Times are in s, distances
in m, energy in J (propulsive: thrust x speed through the water, integrated at the plant
step). ``None`` (JSON null) means "not defined for this run" (e.g. a domain-based metric of a
scenario without an evaluation domain).
"""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd

from mpcasv.experiments.metric_info import (  # re-exported: the names other modules import
    HEADLINE,
    METRIC_INFO,
    METRIC_NAMES,
    WALL_CLOCK,
    MetricInfo,
    auv_column,
)

__all__ = ["HEADLINE", "METRIC_INFO", "METRIC_NAMES", "SHORT_STAY_S", "WALL_CLOCK", "MetricInfo",
           "age_stats", "auv_column", "compute_metrics", "plan_following", "short_switches"]

#: a commanded mode held less than this (s) before the next change is a short stay
#: (``mode_switches_short``)
SHORT_STAY_S = 5.0


def _path_length(N: np.ndarray, E: np.ndarray) -> float:
    return float(np.sum(np.hypot(np.diff(N), np.diff(E))))


def _from_start(start, t: pd.Series, N: pd.Series, E: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """``(N, E)`` (m) of a path logged at the period ends, with the scenario's ``start``
    (position at t = 0) before them when the first row is later (every run: the time series
    begins at the first period's end)."""
    N, E = N.to_numpy(float), E.to_numpy(float)
    if len(t) and float(t.iloc[0]) > 0.0:
        N, E = np.r_[start.N, N], np.r_[start.E, E]
    return N, E


def age_stats(event_times, t_end: float) -> tuple[float, float, float]:
    """(max, p95, mean) over ``[0, t_end]`` of the age ``t - (last event <= t)``, with an
    event at ``t = 0`` (the known start).

    The age is a saw-tooth: over a gap ``g`` between events it runs uniformly through
    ``[0, g)``. Hence max = the largest gap, mean = ``sum g^2 / (2 t_end)``, and the p95 is
    exact: the ``x`` at which the fraction of time with age ``<= x``,
    ``sum min(x, g_i) / t_end``, reaches 0.95.
    """
    t = np.asarray(event_times, float)
    t = t[(t > 0) & (t <= t_end)]
    g = np.diff(np.concatenate([[0.0], np.unique(t), [t_end]]))
    g = g[g > 0]
    if t_end <= 0 or not g.size:
        return 0.0, 0.0, 0.0
    return float(g.max()), _sawtooth_quantile(g, t_end, 0.95), float(np.sum(g**2) / (2 * t_end))


def revisit_wait(fix_times, t_end: float, t_start: float) -> float:
    """The longest time (s) one AUV waited for a visit once the ASV had begun its visits at
    ``t_start`` (s: the first reliable fix of any AUV): the wait from ``t_start`` to its first
    reliable fix, the gaps between its consecutive reliable fixes ``fix_times`` (s, in
    ``(0, t_end]``) and the wait from the last one to the run's end ``t_end`` (censored: the
    next visit came later, if at all); infinite without any reliable fix (never visited).
    The ASV's first approach, before ``t_start``, is no one's wait. Paper 2's "time between
    consecutive visits" (thesis §4.2, Cases 6-7). Until session 45 only the gaps between
    fixes counted: an AUV whose only visit gave fixes at 120 and 125 s of a 480-s run scored
    5 s, the best value, for never being revisited (a new user's suite), and one left unvisited
    until the end scored the little time that remained (a review)."""
    t = np.unique(np.asarray(fix_times, float))
    t = t[(t > 0) & (t <= t_end)]
    if not t.size:
        return math.inf
    return float(np.diff(np.concatenate([[min(t_start, t[0])], t, [t_end]])).max())


def _sawtooth_quantile(gaps: np.ndarray, total: float, q: float) -> float:
    """Smallest ``x`` with ``sum min(x, g_i) >= q total`` (time fraction of a saw-tooth)."""
    g = np.sort(gaps)
    target, done = q * total, 0.0  # done: sum of the gaps below the current level
    for j, gj in enumerate(g):
        n_above = len(g) - j  # gaps >= gj each contribute x
        if done + n_above * gj >= target:
            return float((target - done) / n_above)
        done += gj
    return float(g[-1])


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


def short_switches(t: np.ndarray, mode: np.ndarray) -> np.ndarray:
    """Rows (indices) where the commanded ``mode`` (per row at times ``t``, s) changes less
    than :data:`SHORT_STAY_S` after its previous change: standbys or transits too short for
    a propulsion system (the first change of a run is not counted; ``mode_switches_short``
    is their number)."""
    sw = np.flatnonzero(mode[1:] != mode[:-1]) + 1
    return sw[1:][np.diff(t[sw]) < SHORT_STAY_S - 1e-9]


def _max_or_none(ts: pd.DataFrame, *cols: str) -> float | None:
    """Largest per-step sum of time-series columns (absent or NaN values left out); None if
    no step has a value (NaN: nothing measured, e.g. no exploration solve ran), not 0, which
    reads as "took 0 ms"."""
    vals = [ts[c].to_numpy(float) for c in cols if c in ts]
    if not vals:
        return None
    v = np.stack(vals)
    some = (~np.isnan(v)).any(axis=0)
    return float(np.nansum(v, axis=0)[some].max()) if some.any() else None


def _sum(ts: pd.DataFrame, col: str) -> float | None:
    """Sum of an account column; None if the run has no evaluation domain (NaN) or the
    column is missing (a time series from before the account existed)."""
    if col not in ts:
        return None
    v = ts[col].to_numpy(float)
    return None if np.isnan(v).any() else float(v.sum())


def period_rows(ts: pd.DataFrame, sim) -> pd.DataFrame:
    """The time series' rows at the control periods' ends, one per controller step, however
    the run was logged: with ``sim.log_every_step`` (one row per plant step) each period's
    last, which holds the period's diagnostics, belief and fixes (the rows before it hold
    their own plant step's ASV and AUV truth beside the period end's belief)."""
    n_sub = sim.n_sub if sim.log_every_step else 1
    return ts.iloc[n_sub - 1 :: n_sub]


def served_switches(steps: pd.DataFrame) -> int | None:
    """Changes of the AUV the commands serve (column ``auv_served``, one row per control
    period; -1, none served, left out): the hybrid multi-AUV controller's selected AUV, the
    MPC's target (its fallback steps the hybrid's), 0 for a single-AUV run. The first AUV
    served is no change. One definition for every controller: before session 46 the metric
    was the MPC's own counter, 0 for the hybrid controllers whatever they did, and it counted
    the MPC's first choice when that was not AUV 0. None without the column."""
    if "auv_served" not in steps:  # a time series without the commands' AUV: unknown
        return None
    a = steps["auv_served"].to_numpy()
    a = a[a >= 0]
    return int(np.count_nonzero(a[1:] != a[:-1]))


def _at(t: np.ndarray, query: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """Row index of each time in ``query`` in the sorted times ``t`` (-1: no row there)."""
    i = np.clip(np.searchsorted(t, query - tol), 0, len(t) - 1)
    return np.where(np.abs(t[i] - query) <= tol, i, -1)


def plan_following(ts: pd.DataFrame) -> dict:
    """The plan-following metrics (``plan_*``, issue 16 item 4) from the MPC's logged plan
    columns (``mpc_plan_t``, ``mpc_plan_N<h>`` / ``E<h>`` / ``T<h>``: the used plan's
    predictions at offsets h; ``mpc_plan_E_J`` with its period ``mpc_plan_E_t0`` -
    ``mpc_plan_E_t1``) and the cumulative energy ``energy_cum_J``. All None without them."""
    out = dict.fromkeys(("plan_tracking_error_m", "plan_thrust_error_N", "plan_energy_J",
                         "plan_energy_ratio"))  # fmt: skip
    if "mpc_plan_t" not in ts:
        return out
    t = ts["t"].to_numpy(float)
    t_plan = ts["mpc_plan_t"].to_numpy(float)
    offsets = sorted(int(m.group(1)) for c in ts.columns
                     if (m := re.fullmatch(r"mpc_plan_N(\d+)", c)))  # fmt: skip
    d2, dT2 = [], []
    for h in offsets:
        ok = np.isfinite(t_plan)
        j = _at(t, t_plan[ok] + h)
        src, j = np.flatnonzero(ok)[j >= 0], j[j >= 0]
        dn = ts[f"mpc_plan_N{h}"].to_numpy(float)[src] - ts["N"].to_numpy(float)[j]
        de = ts[f"mpc_plan_E{h}"].to_numpy(float)[src] - ts["E"].to_numpy(float)[j]
        d2.append(dn**2 + de**2)
        dT2.append((ts[f"mpc_plan_T{h}"].to_numpy(float)[src] - ts["thrust"].to_numpy(float)[j])
                   ** 2)  # fmt: skip
    if d2 and np.concatenate(d2).size:
        out["plan_tracking_error_m"] = float(np.sqrt(np.mean(np.concatenate(d2))))
        out["plan_thrust_error_N"] = float(np.sqrt(np.mean(np.concatenate(dT2))))
    e_plan = ts["mpc_plan_E_J"].to_numpy(float)
    ok = np.isfinite(e_plan)
    if ok.any() and "energy_cum_J" in ts:
        cum = ts["energy_cum_J"].to_numpy(float)

        def spent_by(times):  # cumulative energy at these times (0 at the start), NaN: no row
            i = _at(t, times)
            return np.where(times <= 1e-9, 0.0, np.where(i >= 0, cum[i], np.nan))

        e_spent = (spent_by(ts["mpc_plan_E_t1"].to_numpy(float)[ok])
                   - spent_by(ts["mpc_plan_E_t0"].to_numpy(float)[ok]))  # fmt: skip
        both = np.isfinite(e_spent)
        out["plan_energy_J"] = float(e_plan[ok][both].sum())
        spent = float(e_spent[both].sum())
        out["plan_energy_ratio"] = spent / out["plan_energy_J"] if out["plan_energy_J"] > 0 \
            else None
    return out


def compute_metrics(result) -> dict:
    """All metrics of a :class:`mpcasv.sim.simulator.RunResult` as a flat JSON-able dict
    (keys: :data:`METRIC_NAMES`; ``None`` where undefined)."""
    ts: pd.DataFrame = result.timeseries
    n_auv = len(result.scenario.auv)
    Tc = result.scenario.sim.row_period  # a row's weight (the plant step with log_every_step)
    t_end = float(ts["t"].iloc[-1])
    steps = period_rows(ts, result.scenario.sim)
    mode, reason = ts["mode"].to_numpy(), ts["reason"].to_numpy()
    standby = mode == "standby"
    transit = ~standby
    # path lengths from the start through the period ends, however the run was logged (with
    # log_every_step through every plant step they were 0.03-0.06 % longer: session 46; the
    # first period's leg was left out until session 47)
    sc = result.scenario
    asv_d = _path_length(*_from_start(sc.asv.start, steps["t"], steps["N"], steps["E"]))
    auv_d = [_path_length(*_from_start(a.start, steps["t"], steps[f"auv{k}_N"],
                                       steps[f"auv{k}_E"])) for k, a in enumerate(sc.auv)]
    mean_auv = float(np.mean(auv_d))

    prop_s = _sum(ts, "prop_on_s")
    if prop_s is None:  # older time series: period-end samples
        prop_s = float(np.sum(ts["propeller_on"].to_numpy()) * Tc)
    coll_s, escape, track = _sum(ts, "coll_s"), _sum(ts, "escape_s"), _sum(ts, "track_s")
    longest = None if coll_s is None else float(ts["coll_stay_s"].max())
    coll_auv = [_sum(ts, f"coll{k}_s") for k in range(n_auv)]
    has_domain = coll_s is not None

    rel = [age_stats(f, t_end) for f in result.reliable_fix_times]
    fix = [age_stats(f, t_end) for f in result.fix_times]
    rel_auv = {s: [r[i] if has_domain else None for r in rel]
               for i, s in enumerate(("max", "p95", "mean"))}  # fmt: skip

    def worst(values, pick=max):
        return None if any(v is None for v in values) else float(pick(values))

    possible = [_sum(ts, f"possible{k}_s") for k in range(n_auv)]

    revisit = None
    if n_auv > 1 and has_domain:
        first = [min(f) for f in result.reliable_fix_times if len(f)]
        t_start = min(first) if first else t_end  # the ASV's first visit of any AUV
        revisit = max(revisit_wait(f, t_end, t_start) for f in result.reliable_fix_times)

    # the belief at the period ends, when the estimators are asked (with log_every_step the
    # true ranges are each plant step's, the belief its period end's)
    nav = np.stack([steps[f"nav_err{k}"].to_numpy() for k in range(n_auv)])
    belief_err = np.stack([np.abs(steps[f"est_range{k}"].to_numpy()
                                  - steps[f"range{k}"].to_numpy()) for k in range(n_auv)])
    belief_jump = np.concatenate([_update_jumps(steps, k) for k in range(n_auv)])
    step_ms = np.asarray(result.step_ms, float)
    n_fix = [len(f) for f in result.fix_times]
    n_rel = [len(f) for f in result.reliable_fix_times]
    return {
        "duration_s": t_end,
        "asv_distance_m": asv_d,
        "auv_distance_m": mean_auv,
        "distance_ratio": asv_d / mean_auv if mean_auv > 0 else math.nan,
        "min_range_m": float(result.min_range_m),
        "min_slant_range_m": float(result.min_slant_range_m),
        "collision_domain_s": coll_s,
        "collision_domain_longest_s": longest,
        "beyond_outer_s": _sum(ts, "beyond_s"),
        "transit_escape_s": escape,
        "transit_tracking_s": track,
        "transit_reposition_s": None if not has_domain else prop_s - escape - track,
        "label_avoidance_s": float(np.sum(transit & (reason == "avoidance")) * Tc),
        "label_tracking_s": float(np.sum(transit & (reason == "tracking")) * Tc),
        "standby_s": float(np.sum(standby) * Tc),
        "standby_fraction": float(np.mean(standby)),
        "mode_switches": int(np.sum(mode[1:] != mode[:-1])),
        "mode_switches_short": len(short_switches(ts["t"].to_numpy(), mode)),
        "propeller_toggles": int(np.sum(np.diff(steps["propeller_on"].fillna(False)
                                                .to_numpy(bool)) != 0)),  # period ends
        "reliable_fix_age_max_s": worst(rel_auv["max"]),
        "reliable_fix_age_p95_s": worst(rel_auv["p95"]),
        "reliable_fix_age_mean_s": worst(rel_auv["mean"]),
        "fix_possible_s": worst(possible, min),
        "revisit_interval_max_s": revisit,
        "fix_age_max_s": float(max(f[0] for f in fix)),
        "fix_age_p95_s": float(max(f[1] for f in fix)),
        "fixes": int(sum(n_fix)),
        "reliable_fixes": int(sum(n_rel)),
        "nav_error_rms_m": float(np.sqrt(np.mean(nav**2))),
        "nav_error_p95_m": float(np.percentile(nav, 95)),
        "nav_error_max_m": float(nav.max()),
        "belief_range_error_rms_m": float(np.sqrt(np.mean(belief_err**2))),
        "belief_range_jump_max_m": float(belief_jump.max()) if belief_jump.size else 0.0,
        "propeller_on_s": prop_s,
        "energy_J": float(result.energy_J),
        "controller_step_ms_median": float(np.median(step_ms)),
        "controller_step_ms_p99": float(np.percentile(step_ms, 99)),
        "between_steps_ms_max": _max_or_none(ts, "mpc_deferred_ms", "mpc_explore_ms"),
        "fallbacks": int(result.fallbacks),
        "carried_steps": int((steps["mpc_source"] == "carried").sum())
        if "mpc_source" in steps else 0,
        "target_switches": served_switches(steps),
        "solver_hangs": int(steps["mpc_hung"].sum()) if "mpc_hung" in steps else 0,
        "over_budget_steps": int(steps["mpc_over_budget"].sum())
        if "mpc_over_budget" in steps else 0,
        # control periods (one row each) whose plan assumed a current above CURRENT_TESTED
        "current_untested_s": (float(steps["mpc_cur_untested"].sum())
                               * result.scenario.sim.control_period)
        if "mpc_cur_untested" in steps else 0.0,
        **plan_following(steps),  # one row per step (with log_every_step: 10x the plans)
        # per-AUV lists
        "auv_distance_m_auv": auv_d,
        "collision_domain_s_auv": coll_auv,
        "target_domain_s_auv": [_sum(ts, f"target{k}_s") for k in range(n_auv)],
        "fix_possible_s_auv": possible,
        "reliable_fix_age_max_s_auv": rel_auv["max"],
        "reliable_fix_age_p95_s_auv": rel_auv["p95"],
        "reliable_fix_age_mean_s_auv": rel_auv["mean"],
        "fix_age_max_s_auv": [f[0] for f in fix],
        "fix_age_p95_s_auv": [f[1] for f in fix],
        "fixes_auv": n_fix,
        "reliable_fixes_auv": n_rel,
        "nav_error_rms_m_auv": [float(np.sqrt(np.mean(e**2))) for e in nav],
        "nav_error_p95_m_auv": [float(np.percentile(e, 95)) for e in nav],
        "nav_error_max_m_auv": [float(e.max()) for e in nav],
    }
