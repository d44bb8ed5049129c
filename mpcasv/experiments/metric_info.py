"""What every run metric means: unit, which way is better, definition and source (the
names of ``metrics.json``; docs/metrics.md is generated from :data:`METRIC_INFO`). The
values are computed in :mod:`mpcasv.experiments.metrics`."""

from __future__ import annotations

from dataclasses import dataclass


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
    "asv_distance_m": _i("m", "lower",
                         "path length of the ASV (from its start, t = 0, through the period ends)"),
    "auv_distance_m": _i("m", None, "path length of the AUVs (from their starts through the "
                         "period ends), mean over AUVs"),
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
    "mode_switches_short": _i("1", "lower", "changes of the commanded mode less than 5 s "
                              "after the previous change (standbys or transits of 1-4 s; "
                              "the run's first change not counted)"),
    "propeller_toggles": _i("1", "lower", "changes of the propeller between on and off "
                            "(true state, sampled at the control periods' ends)"),
    # --- liveness (Paper 2 eq. 9-10) ----------------------------------------------------
    "reliable_fix_age_max_s": _i("s", "lower", "tau_k = time since AUV k's last reliable fix "
                                 "(a fix that arrived while r_k < r_t,k + eps_plus with the "
                                 "propeller off, true range and depth; t = 0 counts as a fix): "
                                 "its largest value over the run, worst AUV", "Paper 2 eq. 9"),
    "reliable_fix_age_p95_s": _i("s", "lower", "95th percentile over time of tau_k (exact "
                                 "for the saw-tooth), worst AUV", "Paper 2 eq. 9"),
    "reliable_fix_age_mean_s": _i("s", "lower", "time average of tau_k, worst AUV",
                                  "Paper 2 eq. 9"),
    "fix_possible_s": _i("s", None, "time a reliable fix was possible: r_k < r_t,k + "
                         "eps_plus with the propeller off (the rule of reliable_fix_age_*), "
                         "true range and depth, plant-step resolution; the AUV with least "
                         "(descriptive: what the fix ages come from; inside the collision "
                         "domain counts too, eq. 9 has no lower limit)", "Paper 2 eq. 9"),
    "revisit_interval_max_s": _i("s", "lower", "longest time one AUV waited for a visit "
                                 "once the ASV had begun its visits (the first reliable fix "
                                 "of any AUV): the wait for its first reliable fix, the gaps "
                                 "between its consecutive ones and the wait from the last one "
                                 "to the end (censored), worst AUV; several AUVs only (null "
                                 "with one AUV; infinite/null if an AUV had no reliable fix)",
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
    "target_switches": _i("1", "lower", "changes of the AUV the commands serve (auv_served: "
                          "the hybrid's selected AUV, the MPC's target; the first is no "
                          "change; chattering shows here)", "issue 16 item 6"),
    "solver_hangs": _i("1", "lower", "MPC solves abandoned as hung by the simulation's hang "
                       "guard (no answer within solver.hang_s s of the solver's CPU time; the "
                       "step then rescued or fell back); each cost that CPU time and is kept "
                       "in the run folder's hung_solves.pkl (mpcasv replay-solve)"),
    "over_budget_steps": _i("1", "lower", "MPC steps whose solve took longer than the field "
                            "budget_ms (wall clock: measured only, it changes no decision in "
                            "simulation)"),
    "current_untested_s": _i("s", None, "time (whole control periods) the MPC planned with "
                             "a current above the 1.0 m/s it has been tested in "
                             "(mpcasv.mpc.worldview.CURRENT_TESTED, the speed rounded to "
                             "0.01 m/s; per step: diagnostic mpc_cur_untested): its figures "
                             "there are outside what was measured; 0 for the controllers that "
                             "plan with no current (the hybrids, an MPC with current = "
                             "'zero')", "docs/mpc.md, \"Known problems\": "
                             "strong currents"),
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
_PER_AUV = ("auv_distance_m", "collision_domain_s", "fix_possible_s", "reliable_fix_age_max_s",
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


def axis_label(name: str) -> str:
    """A figure's axis label of metric ``name``: its unit and which way is better
    (``"energy_J (J, lower is better)"``; the unit only for a descriptive metric)."""
    info = METRIC_INFO[name]
    if info.better is None:
        return f"{name} ({info.unit})"
    return f"{name} ({info.unit}, {info.better} is better)"


def auv_column(name: str, k: int) -> str:
    """Results-table column of AUV ``k``'s value of the per-AUV list metric ``name``
    (``fixes_auv`` -> ``fixes_auv0``; a list name without the ``_auv`` suffix gets it)."""
    return f"{name}{k}" if name.endswith("_auv") else f"{name}_auv{k}"
