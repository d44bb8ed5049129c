"""Output of :func:`mpcasv.models.identify.identify`: the vessel TOML with provenance, the
replay plot and the report table (``mpcasv identify``)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from mpcasv.models.ident_checks import PRIOR_MARGIN, validation_failures, worse_than_prior
from mpcasv.models.ident_cov import data_name, fixed, report_notes
from mpcasv.models.identify import OUTPUTS, Identification, mass_terms
from mpcasv.models.params import VesselParams

#: the 1-sigma basis in one coefficient's provenance (the header gives the method in full)
SIGMA_BASIS = "Newey-West HAC within replay windows"


def write_params(path: Path, res: Identification, prior: VesselParams, sources: list[str]) -> None:
    """Write the identified parameters as a vessel TOML (loads with ``load_vessel``).

    Every number keeps a provenance entry: identified ones name the logs, the method, the
    1-sigma uncertainty and the validation fit; the others are the prior's, marked as held.
    A model that failed its validation (a held-out fit below 0 %,
    :func:`mpcasv.models.ident_checks.validation_failures`, or a held-out error above the
    prior's; ``mpcasv identify`` exits 1) says so in the header, in every identified
    coefficient's provenance and, machine-readable, in its ``[identification]`` table
    (``validation = "failed"``, :mod:`mpcasv.models.ident_record`): loading refuses it unless
    the user sets ``use_anyway = true`` there. The validation fits are of the model as
    written: the logs' set-points are its own inputs (a DUNE log's through
    :func:`mpcasv.models.vessel.dune_actuators`, its own actuator model).
    """
    import tomli_w

    val = res.metrics["simulation_error"]["validation"]
    fit = ", ".join(f"{c} {fixed(v['fit_pct'], 1)} %" for c, v in val.items())
    failed = validation_failures(res.metrics)
    worse = worse_than_prior(res.validation_error)
    if failed:
        fit += " (VALIDATION FAILED: fit < 0 %)"
    if worse:
        fit += f" (VALIDATION FAILED: held-out weighted error {worse:.3g} x the prior's)"
    from mpcasv.models.vessel import top_speed

    data = {f.name: getattr(res.params, f.name) for f in dataclasses.fields(res.params)}
    data.pop("provenance")
    data = {k: v for k, v in data.items() if v is not None}  # absent optional (T_idle)
    data["name"] = f"{prior.name}-identified"
    # the declared top speed is checked against the model at load: the identified resistance
    # moves it (set-points are fractions of the prior's T_max, so it is the full-throttle speed
    # the identified model predicts)
    data["u_max"] = round(top_speed(res.params), 4)
    prov = {}
    for key in data:
        if key == "name":
            continue
        if key == "u_max":
            prov[key] = (f"top speed of the identified model at T_max = {prior.T_max:g} N "
                         f"(prior declared {prior.u_max:g} m/s: {prior.provenance.get(key, '')})")
        elif key in res.coeffs:
            b = res.at_bound.get(key)
            sd = (f"1-sigma {100 * res.rel_std[key]:.1f} % ({SIGMA_BASIS}; variance "
                  f"{res.var_ratio.get(key, math.nan):.3g} x the independent-residual one)"
                  if b is None else f"at its bound {b['bound']:.6g} (the fit would put it at "
                  f"{b['free']:.4g}, {b['z']:+.1f} sigma past it; identify.md says what that "
                  "tells)")  # fmt: skip
            prov[key] = (f"identified by mpcasv identify from {', '.join(sources)}: simulation-"
                         f"error least squares, {sd}; "
                         f"validation fit {fit}; prior {getattr(prior, key):.6g}")  # fmt: skip
        else:
            prov[key] = "held at the prior: " + prior.provenance.get(key, "(no provenance)")
    header = (f"# Identified by `mpcasv identify` from {', '.join(sources)}.\n"
              f"# 1-sigma: {res.sigma_method}.\n"
              f"# Estimated constant current V_N = {fixed(res.current[0])} m/s, "
              f"V_E = {fixed(res.current[1])} m/s (not a vessel parameter).\n")  # fmt: skip
    if failed:
        header += (f"# VALIDATION FAILED: held-out fit below 0 % for {', '.join(failed)}: this "
                   "model predicts the validation data worse than their mean; do not use it as "
                   "is.\n")  # fmt: skip
    if worse:
        header += (f"# VALIDATION FAILED: held-out weighted error {worse:.3g} x the prior's: this "
                   "model predicts the validation data worse than the prior does; keep the "
                   "prior.\n")  # fmt: skip
    reasons = []
    if failed:
        fits_txt = ", ".join(f"{c} {fixed(v, 1)} %" for c, v in failed.items())
        reasons.append(f"held-out fit below 0 % for {fits_txt}")
    if worse:
        reasons.append(f"held-out weighted error {worse:.3g} x the prior's")
    why = "; ".join(reasons)
    record = ({"validation": "failed", "why": why, "use_anyway": False} if why
              else {"validation": "passed"})  # fmt: skip
    if why:
        header += ("# [identification] validation = \"failed\": every mpcasv command refuses "
                   "this file unless you set use_anyway = true there.\n")  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(header + tomli_w.dumps({**data, "provenance": prov,
                                            "identification": record}))  # fmt: skip


def plot_replay(res: Identification, out: Path) -> Path:
    """Measured vs simulated outputs over the training and validation windows."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 2, figsize=(13, 9), sharex="col")
    scale = {"psi": (math.degrees(1), "deg"), "u": (1, "m/s"), "v": (1, "m/s"),
             "r": (math.degrees(1), "deg/s")}  # fmt: skip
    for j, part in enumerate(("train", "validation")):
        Y, Ys = res.replay[part]
        k = np.arange(Y.shape[1]) * 0.1
        for i, c in enumerate(OUTPUTS):
            f, unit = scale[c]
            ax = axes[i, j]
            ax.plot(k, Y[i] * f, ".", ms=1, color="0.6", label="measured")
            ax.plot(k, Ys[i] * f, lw=0.8, color="tab:blue", label="simulated (identified)")
            ax.set_ylabel(f"{c} ({unit})")
            fit = res.metrics["simulation_error"][part][c]["fit_pct"]
            ax.set_title(f"{part}: {c}, fit {fit:.1f} %", fontsize=9)
        axes[3, j].set_xlabel("time over the replay windows, concatenated (s)")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    p = out / "identify_replay.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p


def report_table(res: Identification, prior: VesselParams, truth: VesselParams | None = None):
    """Markdown: coefficients (prior, identified, 1-sigma, truth error if known), fits."""
    lines = ["| coefficient | prior | identified | 1-sigma % |" + (" true | error % |" if truth
             else ""), "|---|---|---|---|" + ("---|---|" if truth else "")]  # fmt: skip
    rows = [(c, getattr(prior, c), getattr(res.params, c), 100 * res.rel_std[c],
             getattr(truth, c) if truth else None) for c in res.coeffs]  # fmt: skip
    mp, mi = mass_terms(prior), mass_terms(res.params)
    mt = mass_terms(truth) if truth else {}
    rows += [(k, mp[k], mi[k], math.nan, mt.get(k)) for k in mp]
    for c, p0, pi, sd, pt in rows:
        sd_txt = ("at bound" if c in res.at_bound else "derived" if math.isnan(sd)
                  else fixed(sd, 1))  # fmt: skip
        line = f"| {c} | {p0:.4g} | {pi:.4g} | {sd_txt} |"
        if truth:
            err = fixed(100 * (pi / pt - 1), 1)
            line += f" {pt:.4g} | {'' if err.startswith('-') or float(err) == 0 else '+'}{err} |"
        lines.append(line)
    source = data_name(len(res.sources)) if res.sources else "these logs"
    lines += report_notes(res.coeffs, res.rel_std, res.var_ratio, source, res.sigma_rel_sd,
                          res.at_bound, res.sigma_lag, res.sigma_n)  # fmt: skip
    lines += ["", f"Current: V_N = {fixed(res.current[0])} m/s, V_E = {fixed(res.current[1])} m/s",
              "", "| stage | split | " + " | ".join(f"{c} fit % (RMSE)" for c in OUTPUTS) + " |",
              "|---|---|" + "---|" * len(OUTPUTS)]  # fmt: skip
    for stage, d in res.metrics.items():
        for part, m in d.items():
            lines.append(
                f"| {stage} | {part} | "
                + " | ".join(f"{fixed(m[c]['fit_pct'], 1)} ({m[c]['rmse']:.3g})" for c in OUTPUTS)
                + " |"
            )
    lines.append("RMSE in rad, m/s, m/s, rad/s; fits over replay windows re-initialised every "
                 "window from the smoothed measurement.")  # fmt: skip
    failed = validation_failures(res.metrics)
    lines.append("Validation (held-out fit >= 0 % on every channel): " + (
        "FAIL: " + ", ".join(f"{c} {fixed(v, 1)} %" for c, v in failed.items()) +
        " (the model predicts the held-out data worse than their mean)" if failed else "PASS"))
    lines.append(prior_line(res.validation_error))
    return "\n".join(lines)


def prior_line(verr: dict) -> str:
    """The report's second validation bar: the held-out weighted error (the fit's criterion)
    of the identified model against the prior's
    (:func:`mpcasv.models.ident_checks.worse_than_prior`)."""
    if not verr:
        return "Validation against the prior: not recorded"
    e0, e1 = verr["prior"], verr["identified"]
    ratio = e1 / e0 if e0 > 0 else math.inf
    verdict = ("FAIL (the identified model predicts the held-out data worse than the prior: "
               "keep the prior)" if worse_than_prior(verr) else "PASS")  # fmt: skip
    return (f"Validation against the prior (held-out weighted error, the fit's criterion, 1 at "
            f"the noise level; at most the prior's + {PRIOR_MARGIN:g} x the larger of the "
            f"prior's and 1): {e1:.3g} against {e0:.3g}, {ratio:.3g} x: {verdict}")
