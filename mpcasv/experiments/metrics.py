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
from dataclasses import dataclass

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class MetricInfo:
    """What a metric means: unit, which way is better (``"lower"``, ``"higher"`` or None for
    a descriptive figure), definition and source (paper and equation)."""

    unit: str
    better: str | None
    definition: str
    source: str


_P1, _P2 = "Paper 1", "Paper 2"
_ACC = "ground-truth account, scenario's domain (mpcasv.sim.account)"


def _i(unit, better, definition, source=""):
    return MetricInfo(unit, better, definition, source)


def _per_auv(info: MetricInfo) -> MetricInfo:
    return MetricInfo(info.unit, info.better, f"per AUV: {info.definition}", info.source)


_BASE: dict[str, MetricInfo] = {
    # --- run -----------------------------------------------------------------------------
    "duration_s": _i("s", None, "simulated time (end of the last period)"),
    "asv_distance_m": _i("m", "lower", "path length of the ASV (period ends)"),
    "auv_distance_m": _i("m", None, "path length of the AUVs, mean over AUVs"),
    "distance_ratio": _i("1", "lower", "asv_distance_m / auv_distance_m",
                         "thesis Table 4.1 (ASV/AUV distance)"),
    # --- safety (ground truth) -----------------------------------------------------------
    "min_range_m": _i("m", "higher", "minimum true horizontal ASV-AUV range over AUVs and "
                      "plant steps", "Paper 1 eq. 6; Paper 2 eq. 3"),
    "min_slant_range_m": _i("m", "higher", "minimum true 3-D ASV-AUV range (AUV depth "
                            "included) over AUVs and plant steps", "thesis eq. 2.9 (slant)"),
    "collision_domain_s": _i("s", "lower", "time the ASV is inside at least one AUV's "
                             "collision domain, r_k < r_inner(d_k) (one AUV) / r_avoid,k "
                             "(several), true range and depth, plant-step resolution; " + _ACC,
                             "Paper 1 eq. 5; Paper 2 eqs. 4-5"),
    "collision_domain_longest_s": _i("s", "lower", "longest single continuous stay inside "
                                     "the collision domain(s), plant-step resolution",
                                     "Paper 1 eq. 5; Paper 2 eqs. 4-5"),
    "beyond_outer_s": _i("s", "lower", "time the ASV is beyond r_outer(d_k) of every AUV "
                         "(Paper 2: r_outer of alpha_outer = 1, the modem's rated range)",
                         "Paper 1 eqs. 3, 5"),
    "transit_escape_s": _i("s", "lower", "propeller-on time while inside a collision domain",
                           "geometric split of the papers' 'avoidance' transit"),
    "transit_tracking_s": _i("s", "lower", "propeller-on time while beyond r_outer of every "
                             "AUV", "geometric split of the papers' 'tracking' transit"),
    "transit_reposition_s": _i("s", None, "the rest of the propeller-on time (the "
                               "controller's own choice to move)", "propeller_on_s minus the "
                               "two above"),
    "target_domain_s_auv": _i("s", None, "per AUV: time the ASV is in that AUV's target "
                              "domain r_t,k - eps_minus <= r_k <= r_t,k + eps_plus (where it "
                              "waits; descriptive)", "Paper 1 eq. 10; Paper 2 eq. 7"),
    "label_avoidance_s": _i("s", None, "DIAGNOSTIC: periods commanded 'transit' with the "
                            "controller's reason 'avoidance' (meaning differs between "
                            "controllers; never a safety figure)", "Paper 1 §2.3 labels"),
    "label_tracking_s": _i("s", None, "DIAGNOSTIC: periods commanded 'transit' with reason "
                           "'tracking'", "Paper 1 §2.3 labels"),
    "standby_s": _i("s", None, "DIAGNOSTIC: periods commanded 'standby' (Q1); see "
                    "propeller_on_s for the measured figure", "Paper 1 eq. 11 (Q1)"),
    "standby_fraction": _i("1", None, "DIAGNOSTIC: standby_s / duration_s",
                           "thesis Table 4.1"),
    "mode_switches": _i("1", "lower", "changes of the commanded mode (standby <-> transit)"),
    # --- liveness (Paper 2 eq. 9-10) ----------------------------------------------------
    "reliable_fix_age_max_s": _i("s", "lower", "tau_k = time since AUV k's last reliable fix "
                                 "(a fix that arrived while r_k < r_t,k + eps_plus with the "
                                 "propeller off, true range and depth; t = 0 counts as a fix): "
                                 "its largest value over the run, worst AUV", "Paper 2 eq. 9"),
    "reliable_fix_age_p95_s": _i("s", "lower", "95th percentile over time of tau_k (exact "
                                 "for the saw-tooth), worst AUV", "Paper 2 eq. 9"),
    "reliable_fix_age_mean_s": _i("s", "lower", "time average of tau_k, worst AUV",
                                  "Paper 2 eq. 9"),
    "revisit_interval_max_s": _i("s", "lower", "longest time between two consecutive "
                                 "reliable fixes of one AUV, worst AUV; several AUVs only "
                                 "(null with one AUV, and infinite/null if an AUV had fewer "
                                 "than two reliable fixes)",
                                 "thesis §4.2 Cases 6-7 ('time between consecutive visits')"),
    "fix_age_max_s": _i("s", "lower", "time since the last USBL fix that actually arrived "
                        "(any range, propeller on or off): largest value, worst AUV",
                        "acoustic channel (PAPER-FACTS §1)"),
    "fix_age_p95_s": _i("s", "lower", "95th percentile over time of the fix age, worst AUV",
                        "acoustic channel"),
    "fixes": _i("1", "higher", "USBL fixes that arrived, all AUVs"),
    "reliable_fixes": _i("1", "higher", "of which reliable (Paper 2 eq. 9), all AUVs",
                         "Paper 2 eq. 9"),
    # --- AUV navigation (the AUV's own filter vs truth) -----------------------------------
    "nav_error_rms_m": _i("m", "lower", "RMS of the horizontal error of the AUVs' own "
                          "navigation filters (dead reckoning + Kalman updates with the USBL "
                          "fixes that reach them + GPS at the surface), all AUVs and period "
                          "ends", "thesis §2.5 eq. 2.7, eq. 2.9 (mpcasv.models.auv_nav)"),
    "nav_error_p95_m": _i("m", "lower", "95th percentile of that error, all AUVs and period "
                          "ends", "thesis §2.5"),
    "nav_error_max_m": _i("m", "lower", "largest value of that error", "thesis §2.5"),
    # --- the ASV's belief about the AUVs -------------------------------------------------
    "belief_range_error_rms_m": _i("m", "lower", "RMS of |believed range - true range| "
                                   "(the ASV's estimator), all AUVs and period ends"),
    "belief_range_jump_max_m": _i("m", "lower", "largest jump of the believed range at an "
                                  "estimate update beyond the true range's change (first "
                                  "acquisition left out)", "thesis Case 5 (387 m jump)"),
    # --- effort --------------------------------------------------------------------------
    "propeller_on_s": _i("s", "lower", "time with the actual thrust above the propeller-on "
                         "threshold (n_p != 0), plant-step resolution", "Paper 2 eq. 9 (n_p)"),
    "energy_J": _i("J", "lower", "propulsive energy: thrust x speed through the water, "
                   "integrated at the plant step"),
    # --- compute -------------------------------------------------------------------------
    "controller_step_ms_median": _i("ms", "lower", "median wall time of a controller step "
                                    "(machine-dependent)"),
    "controller_step_ms_p99": _i("ms", "lower", "99th percentile of that time"),
    "between_steps_ms_max": _i("ms", "lower", "longest wall time of a solve a controller "
                               "runs after a step's command, for the next step (an MPC's "
                               "exploration solve and a carried step's work, "
                               "solver.step_iter; null: none ran, or the caller left it to "
                               "the next step); in the field it has the step's budget_ms of "
                               "its own"),
    "fallbacks": _i("1", "lower", "MPC steps handed to the fallback controller"),
    "carried_steps": _i("1", "lower", "MPC steps that followed the previous plan while their "
                        "solve, past solver.step_iter iterations, finished after the command "
                        "(decided by iteration counts, never by wall time)", "issue 16 item 8"),
    "target_switches": _i("1", "lower", "changes of the AUV an MPC targets (0 for the other "
                          "controllers; chattering shows here)", "issue 16 item 6"),
    "solver_hangs": _i("1", "lower", "MPC solves abandoned as hung by the simulation's hang "
                       "guard (no answer within solver.hang_s s of wall time; the step then "
                       "rescued or fell back): where this is not 0 the run depends on wall time"),
    "over_budget_steps": _i("1", "lower", "MPC steps whose solve took longer than the field "
                            "budget_ms (wall clock: measured only, it changes no decision in "
                            "simulation)"),
    # --- does the boat do what the MPC planned? (issue 16 item 4) -------------------------
    "plan_tracking_error_m": _i("m", "lower", "RMS over the MPC's used plans (steps not handed "
                                "to the fallback) and the offsets h = 5, 10, 15 s of the "
                                "horizontal distance between the position the plan made at t "
                                "predicted for t + h and the ASV's true position at t + h "
                                "(period ends); null for a controller without plans",
                                "issue 16 item 4"),
    "plan_thrust_error_N": _i("N", "lower", "RMS, over the same plans and offsets, of the "
                              "planned thrust minus the actual thrust at t + h",
                              "issue 16 item 4"),
    "plan_energy_J": _i("J", None, "propulsive energy (as energy_J) the MPC's used plans meant "
                        "to spend, each over the period until the next step (the part of it "
                        "executed), summed", "issue 16 item 4"),
    "plan_energy_ratio": _i("1", None, "energy actually spent over those same periods (as "
                            "energy_J) / plan_energy_J: 1 = spent as planned, above 1 = the "
                            "boat spent more than its plans (null if plan_energy_J is 0 or "
                            "there are no plans)", "issue 16 item 4"),
}

#: per-AUV lists (suffix ``_auv``) of these scalars
_PER_AUV = ("auv_distance_m", "collision_domain_s", "reliable_fix_age_max_s",
            "reliable_fix_age_p95_s", "reliable_fix_age_mean_s", "fix_age_max_s",
            "fix_age_p95_s", "fixes", "reliable_fixes", "nav_error_rms_m", "nav_error_p95_m",
            "nav_error_max_m")  # fmt: skip

#: every name in ``metrics.json`` with its meaning (docs/metrics.md is generated from this)
METRIC_INFO: dict[str, MetricInfo] = _BASE | {
    f"{m}_auv": _per_auv(_BASE[m]) for m in _PER_AUV
}

#: metrics measured in wall time (machine- and load-dependent): a search toward them would
#: not be reproducible (``mpcasv tune controller`` refuses them as objectives or constraint)
WALL_CLOCK: tuple[str, ...] = ("controller_step_ms_median", "controller_step_ms_p99",
                               "between_steps_ms_max", "over_budget_steps",
                               "solver_hangs")  # fmt: skip

#: the headline metrics of the report, in order
HEADLINE: tuple[str, ...] = (
    "min_range_m", "collision_domain_s", "reliable_fix_age_p95_s", "reliable_fix_age_max_s",
    "nav_error_rms_m", "nav_error_p95_m", "energy_J", "propeller_on_s",
)  # fmt: skip

METRIC_NAMES: tuple[str, ...] = tuple(METRIC_INFO)


def auv_column(name: str, k: int) -> str:
    """Results-table column of AUV ``k``'s value of the per-AUV list metric ``name``
    (``fixes_auv`` -> ``fixes_auv0``; a list name without the ``_auv`` suffix gets it)."""
    return f"{name}{k}" if name.endswith("_auv") else f"{name}_auv{k}"


def _path_length(N: np.ndarray, E: np.ndarray) -> float:
    return float(np.sum(np.hypot(np.diff(N), np.diff(E))))


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


def _last_int(ts: pd.DataFrame, col: str) -> int:
    """The last value of a cumulative counter column (0 if the controller logs none)."""
    return int(ts[col].iloc[-1]) if col in ts and len(ts) else 0


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
    Tc = result.scenario.sim.control_period
    if result.scenario.sim.log_every_step:  # one row per plant step: weight rows by dt
        Tc = result.scenario.sim.dt
    t_end = float(ts["t"].iloc[-1])
    # one row per controller step (the diagnostics' counts): with one row per plant step the
    # period's last (each holds its period's diagnostics)
    n_sub = result.scenario.sim.n_sub if result.scenario.sim.log_every_step else 1
    steps = ts.iloc[n_sub - 1 :: n_sub]
    mode, reason = ts["mode"].to_numpy(), ts["reason"].to_numpy()
    standby = mode == "standby"
    transit = ~standby
    asv_d = _path_length(ts["N"].to_numpy(), ts["E"].to_numpy())
    auv_d = [_path_length(ts[f"auv{k}_N"].to_numpy(), ts[f"auv{k}_E"].to_numpy())
             for k in range(n_auv)]  # fmt: skip
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

    def worst(values):
        return None if any(v is None for v in values) else float(max(values))

    revisit = None
    if n_auv > 1 and has_domain:
        gaps = [np.diff(np.unique(f)) if len(f) >= 2 else np.array([math.inf])
                for f in result.reliable_fix_times]  # fmt: skip
        revisit = float(max(g.max() if g.size else math.inf for g in gaps))

    nav = np.stack([ts[f"nav_err{k}"].to_numpy() for k in range(n_auv)])
    belief_err = np.stack(
        [np.abs(ts[f"est_range{k}"].to_numpy() - ts[f"range{k}"].to_numpy()) for k in range(n_auv)]
    )
    belief_jump = np.concatenate([_update_jumps(ts, k) for k in range(n_auv)])
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
        "reliable_fix_age_max_s": worst(rel_auv["max"]),
        "reliable_fix_age_p95_s": worst(rel_auv["p95"]),
        "reliable_fix_age_mean_s": worst(rel_auv["mean"]),
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
        "target_switches": _last_int(ts, "mpc_target_switches"),
        "solver_hangs": int(steps["mpc_hung"].sum()) if "mpc_hung" in steps else 0,
        "over_budget_steps": int(steps["mpc_over_budget"].sum())
        if "mpc_over_budget" in steps else 0,
        **plan_following(ts),
        # per-AUV lists
        "auv_distance_m_auv": auv_d,
        "collision_domain_s_auv": coll_auv,
        "target_domain_s_auv": [_sum(ts, f"target{k}_s") for k in range(n_auv)],
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
