"""The vessel file and report of an identification through a thruster map
(:mod:`mpcasv.models.ident_thrust`): what the controllers plan with, and its speed figures.

The shared model's thrust ``T`` is a force limited to ``[T_min, T_max]`` with no speed
dependence, while the map's force falls steeply with speed. The written vessel therefore
takes ``T_max`` = the map's total force at full actuation at the speed where it equals the
identified hull's resistance (the top speed): the model then reaches exactly that top speed
at ``T_max`` (the load-time check), and its full-thrust acceleration from rest is at most
``1 - T_max / (n F_max)`` lower than the map's (both thrusters at their force clip). The
differential input's moment ``N_diff delta_max = y_thr T_max`` is set to the map's largest
moment (each thruster's moment clip) through an effective ``y_thr``.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from mpcasv.models.ident_cov import data_name, fixed, report_notes
from mpcasv.models.ident_thrust import MapFit, ThrusterMap
from mpcasv.models.ident_written import gap
from mpcasv.models.params import VesselParams
from mpcasv.models.vessel import resistance, top_speed

#: DUNE's HeadingAndSpeed controller (otter.ini): RPM at actuation 1, the RPM floor while
#: moving, and its largest steady output (feed-forward 120 x 2.5 m/s + integral limit 400)
DUNE_RPM_FULL, DUNE_RPM_FLOOR, DUNE_RPM_LOOP_MAX = 1200.0, 250.0, 120.0 * 2.5 + 400.0


def map_params(fit: MapFit, tmap: ThrusterMap) -> VesselParams:
    """The identified vessel's parameters: the fitted hull with ``T_max``, ``u_max`` and the
    effective ``y_thr`` of the thruster map (module docstring)."""
    P = fit.params
    u_top = tmap.steady_speed(P, 1.0)
    T_max = resistance(P, u_top)
    y_eff = tmap.max_moment() / T_max
    P = P.with_coeffs(T_max=T_max, u_max=u_top, y_thr=y_eff, T_min=0.0)
    if abs(top_speed(P) / u_top - 1) > 1e-6:  # the model's own top speed at T_max
        raise RuntimeError(f"top speed {top_speed(P):.4f} != {u_top:.4f} m/s (a bug)")
    return P


def held_out_text(fit: MapFit, as_written: dict) -> str:
    """The two held-out accuracies, each named (provenance and header): through the map (the
    fit's actuator model, not in the file) and as written (the file's own actuator model,
    :mod:`mpcasv.models.ident_written`), with the held-out signals' spread."""
    m, w, sd = fit.metrics["identified"]["validation"], as_written["validation"], as_written["std"]
    return (f"held-out ({fit.split_s:.0f} s to the end, 30-s replay windows) RMS through "
            f"DUNE's thruster map (the fit's actuator model, not in this file) u {m['u']:.4f} "
            f"m/s, r {m['r']:.4f} rad/s, psi {m['psi']:.3f} rad; AS WRITTEN (this file's own "
            f"linear actuator model, which simulate, tune and the MPC use) u {w['u']:.4f} m/s, "
            f"r {w['r']:.4f} rad/s, psi {w['psi']:.3f} rad (held-out std u {sd['u']:.3f} m/s, "
            f"r {sd['r']:.3f} rad/s)")  # fmt: skip


def gap_warning(fit: MapFit, as_written: dict) -> str | None:
    """One line when the as-written held-out RMS is above
    :data:`~mpcasv.models.ident_written.GAP_FACTOR` times the one through the map (stderr
    and the file's header), else None."""
    g = gap(fit.metrics["identified"]["validation"], as_written["validation"])
    if not g:
        return None
    ratios = ", ".join(f"{c} {r:.3g} x" for c, r in g.items())
    return (f"WARNING: as written (its own linear actuator model) this vessel predicts the "
            f"held-out data far worse than through DUNE's thruster map it was fitted with "
            f"(RMS {ratios}): the file's actuators are not DUNE's map; see docs/deploy.md, "
            "'The vessel file as written'")  # fmt: skip


def written_vessel(fit: MapFit, tmap: ThrusterMap, name: str, held: dict[str, str],
                   sources: list[str], prior: VesselParams,
                   as_written: dict) -> tuple[VesselParams, dict]:  # fmt: skip
    """(parameters, TOML data with ``[provenance]`` and ``[identification]``) of the
    identified vessel.

    ``held``: provenance of the values :func:`~mpcasv.models.ident_thrust.vsim_structure`
    set; identified coefficients name the logs, the method, the 1-sigma and the held-out
    errors, through the map and as written (``as_written``:
    :func:`mpcasv.models.ident_written.written_accuracy` of :func:`map_params`); the others
    keep the prior's provenance, marked as held. ``[identification]``
    (:mod:`mpcasv.models.ident_record`): no acceptance bar (``validation = "not checked"``),
    both held-out accuracies and the held-out spread.
    """
    P = map_params(fit, tmap)
    u_top, y_eff = P.u_max, P.y_thr
    held_out = held_out_text(fit, as_written)
    src = ", ".join(sources)
    prov = {}
    data = {f.name: getattr(P, f.name) for f in dataclasses.fields(P)}
    data.pop("provenance")
    data = {k: (float(f"{v:.6g}") if isinstance(v, float) else v) for k, v in data.items()
            if v is not None}  # six significant digits: far below the 1-sigma
    data["name"] = name
    for key in data:
        if key == "name":
            continue
        if key in fit.coeffs:
            b = fit.at_bound.get(key)
            sd_txt = (f"1-sigma {100 * fit.rel_std[key]:.1f} % (Newey-West HAC within replay "
                      f"windows; variance {fit.var_ratio[key]:.3g} x the independent-residual "
                      "one)" if b is None else f"at its sign bound {b['bound']:.6g} (the fit "
                      f"would put it at {b['free']:.4g}, {b['z']:+.1f} sigma past it; the "
                      "report says what that tells)")  # fmt: skip
            prov[key] = (f"identified by mpcasv identify from {src} through DUNE's thruster "
                         f"map ({tmap.source}): simulation-error least squares, {sd_txt}; "
                         f"{held_out}")  # fmt: skip
        elif key in held:
            prov[key] = held[key]
        elif key == "T_max":
            prov[key] = (f"the thruster map's total force at full actuation (a = 1) at the "
                         f"top speed {u_top:.3f} m/s (= the identified resistance there); from "
                         f"rest the map gives up to {len(tmap.y) * tmap.F_max:g} N (force clip)")
        elif key == "u_max":
            prov[key] = (f"top speed at full actuation through the thruster map and the "
                         f"identified hull ({u_top:.3f} m/s); DUNE's speed loop holds at most "
                         f"{speed_at_rpm(P, tmap, DUNE_RPM_LOOP_MAX):.2f} m/s "
                         "(docs/deploy.md)")  # fmt: skip
        elif key == "y_thr":
            prov[key] = (f"effective arm {y_eff:.4f} m = largest differential moment "
                         f"{tmap.max_moment():g} N m (moment clip {tmap.Q_max:g} N m per "
                         f"thruster) / T_max; geometric arm {abs(tmap.y[0]):g} m")  # fmt: skip
        elif key == "T_min":
            prov[key] = "0: DUNE's speed loop never commands astern thrust in transit"
        else:
            prov[key] = "held at the prior: " + prior.provenance.get(key, "(no provenance)")
    def sig(d: dict) -> dict:
        return {c: float(f"{v:.4g}") for c, v in d.items()}

    record = {"validation": "not checked",
              "held_out_from_s": round(fit.split_s, 1),
              "held_out_rms_through_map": sig(fit.metrics["identified"]["validation"]),
              "held_out_rms_as_written": sig(as_written["validation"]),
              "held_out_std": sig(as_written["std"])}  # fmt: skip
    return P, {**data, "provenance": prov, "identification": record}


def speed_at_rpm(P: VesselParams, tmap: ThrusterMap, rpm: float) -> float:
    """Steady speed (m/s) of ``P`` through ``tmap`` with both thrusters at DUNE's ``rpm``
    (actuation ``rpm / 1200``, otter.ini ``RPMs at Maximum Thrust``)."""
    return tmap.steady_speed(P, rpm / DUNE_RPM_FULL)


def write_vessel(path: Path, data: dict, header: str) -> None:
    """Write the TOML (``tomli_w``)."""
    import tomli_w

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(header + tomli_w.dumps(data))


def report(fit: MapFit, P: VesselParams, tmap: ThrusterMap, prior: VesselParams,
           phases: list[dict] | None = None, as_written: dict | None = None) -> str:  # fmt: skip
    """Markdown: coefficients, held-out errors against the prior's (and as written:
    ``as_written``, :func:`mpcasv.models.ident_written.written_accuracy`), speed figures."""
    lines = ["| coefficient | start (prior) | identified | 1-sigma % |", "|---|---|---|---|"]
    for c in fit.coeffs:
        sd = "at bound" if c in fit.at_bound else fixed(100 * fit.rel_std[c], 1)
        lines.append(f"| {c} | {getattr(prior, c):.4g} | {getattr(P, c):.4g} | {sd} |")
    lines += report_notes(fit.coeffs, fit.rel_std, fit.var_ratio, data_name(1), fit.sigma_rel_sd,
                          fit.at_bound, fit.sigma_lag, fit.sigma_n)  # fmt: skip
    lines += ["", "| model | part | u RMS (m/s) | r RMS (rad/s) | psi RMS (rad) |",
              "|---|---|---|---|---|"]  # fmt: skip
    for stage, d in fit.metrics.items():
        for part, m in d.items():
            lines.append(f"| {stage} (through the map) | {part} | {m['u']:.4f} | {m['r']:.4f} "
                         f"| {m['psi']:.3f} |")  # fmt: skip
    if as_written is not None:
        m, sd = as_written["validation"], as_written["std"]
        lines.append(f"| identified, AS WRITTEN (the file's own linear actuator model) | "
                     f"validation | {m['u']:.4f} | {m['r']:.4f} | {m['psi']:.3f} |")
        lines.append(f"| held-out std of the log | validation | {sd['u']:.4f} | {sd['r']:.4f} "
                     "| |")  # fmt: skip
    lines += ["", f"Held out: from {fit.split_s:.1f} s (log time) to the end; replay windows "
              "re-initialised from the measurement; psi is reported, not fitted. \"Through "
              "the map\": the log's actuations through DUNE's thruster map, as fitted (the map "
              "is not in the vessel file); \"as written\": through the vessel file's own "
              "actuator model, what simulate, tune and the MPC use."]
    warn = gap_warning(fit, as_written) if as_written is not None else None
    if warn:
        lines += ["", warn + "."]
    lines += ["",
              "| both thrusters at | actuation | steady speed, identified model (m/s) |",
              "|---|---|---|"]  # fmt: skip
    for label, rpm in (("DUNE's RPM floor", DUNE_RPM_FLOOR),
                       ("DUNE speed loop's largest steady output", DUNE_RPM_LOOP_MAX),
                       ("full actuation", DUNE_RPM_FULL)):  # fmt: skip
        lines.append(f"| {label} ({rpm:g} RPM) | {rpm / DUNE_RPM_FULL:.3f} | "
                     f"{speed_at_rpm(P, tmap, rpm):.3f} |")
    lines += ["", f"Written: T_max = {P.T_max:.3f} N, u_max = {P.u_max:.3f} m/s, "
              f"y_thr = {P.y_thr:.4f} m (effective)."]  # fmt: skip
    if phases:
        lines += ["", "| phase from (s) | commanded (m/s) | achieved u, last 10 s (m/s) | "
                  "mean actuation | model at that actuation (m/s) |", "|---|---|---|---|---|"]
        for ph in phases:
            model = speed_at_rpm(P, tmap, ph["a"] * DUNE_RPM_FULL) if ph["a"] > 0 else 0.0
            lines.append(f"| {ph['t0']:.0f} | {ph['commanded']:.2f} | {ph['u']:.3f} | "
                         f"{ph['a']:.3f} | {model:.3f} |")
    return "\n".join(lines)


def phase_speeds(t: np.ndarray, commanded: np.ndarray, u: np.ndarray, a: np.ndarray,
                 last_s: float = 10.0) -> list[dict]:
    """Per stretch of one commanded speed: start, commanded, mean ``u`` and mean actuation
    ``a`` (both thrusters' mean) over the stretch's last ``last_s`` s."""
    out = []
    edges = [0, *(np.flatnonzero(np.diff(commanded) != 0) + 1), len(t)]
    for i0, i1 in zip(edges[:-1], edges[1:], strict=True):
        if i1 - i0 < 2 or not math.isfinite(commanded[i0]):
            continue
        sel = slice(i0, i1)
        tail = t[sel] >= t[i1 - 1] - last_s
        out.append({"t0": float(t[i0]), "commanded": float(commanded[i0]),
                    "u": float(u[sel][tail].mean()), "a": float(a[sel][tail].mean())})
    return out


def plot_map_replay(fit: MapFit, out: Path) -> Path:
    """Measured and replayed speed, yaw rate and heading over the training and the held-out
    windows (``identify_replay.png`` in ``out``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 2, figsize=(13, 7.5), sharex="col")
    scale = {"psi": (math.degrees(1), "deg"), "u": (1.0, "m/s"), "r": (math.degrees(1), "deg/s")}
    for j, part in enumerate(("train", "validation")):
        Y, Ys = fit.replay[part]
        k = np.arange(Y.shape[1]) * 0.1
        m = fit.metrics["identified"][part]
        for i, c in enumerate(("u", "r", "psi")):
            row = ("psi", "u", "r").index(c)
            f, unit = scale[c]
            ax = axes[i, j]
            ax.plot(k, Y[row] * f, ".", ms=1, color="0.55", label="DUNE log (EstimatedState)")
            ax.plot(k, Ys[row] * f, lw=0.8, color="tab:blue", label="identified model")
            ax.set_ylabel(f"{c} ({unit})")
            ax.set_title(f"{'held out' if part == 'validation' else 'fit'}: {c}, RMS "
                         f"{m[c] * f:.3g} {unit}", fontsize=9)  # fmt: skip
        axes[2, j].set_xlabel("time over the 30-s replay windows, concatenated (s)")
    axes[0, 0].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    p = out / "identify_replay.png"
    fig.savefig(p, dpi=90)
    plt.close(fig)
    return p
