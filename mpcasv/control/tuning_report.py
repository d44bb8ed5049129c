"""Tables and figures of ``mpcasv tune yaw`` / ``mpcasv tune speed`` (markdown, PNG)."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import control as ct
import matplotlib.pyplot as plt
import numpy as np

from mpcasv.control.tuning import ILL
from mpcasv.control.tuning_speed import (
    ARRIVAL_RADIUS,
    TURN_BAND,
    TURN_T_END,
    arrival,
    in_circle,
    u_cmd_max,
    within,
)  # fmt: skip
from mpcasv.control.tuning_yaw import SETTLE_BAND, yaw_loop, yaw_plant


def _f(v: float, nd: int = 1) -> str:
    if math.isnan(v):
        return "n/a"
    return "inf" if not math.isfinite(v) else f"{v:.{nd}f}"


def _t(v: float) -> str:
    """A time that may never come: 'not reached'."""
    return "not reached" if not math.isfinite(v) else f"{v:.1f}"


def yaw_table(designs) -> str:
    """Markdown tables: Nomoto models and gains; margins and steps (linear, sampled, nonlinear)."""
    out = ["| u0 (m/s) | K (1/s) | T (s) | T1 (s) | T2 (s) | T3 (s) | wn (rad/s) | Kp | Ki (1/s) "
           "| Kd (s) |", "|" + "---|" * 10]  # fmt: skip
    for d in designs:
        n, g = d.nomoto, d.gains
        out.append(f"| {d.u0:g} | {n.K:.4f} | {n.T:.3f} | {n.T1:.3f} | {n.T2:.3f} | {n.T3:.3f} "
                   f"| {d.wn:.3f} | {g.Kp:.3f} | {g.Ki:.4f} | {g.Kd:.3f} |")  # fmt: skip
    out += ["", "| u0 (m/s) | GM dB (cont / sampled) | PM deg (cont / sampled) | disk margin "
            "(alpha, GM dB, PM deg) | lin. 45 deg: rise / settle (s), overshoot (% of step) "
            "| 5 deg dist.: peak deg, recover s | nonlin. 45 deg: rise / settle (s), overshoot "
            "(deg), max delta (deg), min u (m/s) |", "|" + "---|" * 7]  # fmt: skip
    for d in designs:
        c, s, nl = d.linear, d.sampled, d.nonlinear
        out.append(
            f"| {d.u0:g} | {_f(c['gain_margin_db'])} / {_f(s['gain_margin_db'])} "
            f"| {_f(c['phase_margin_deg'], 0)} / {_f(s['phase_margin_deg'], 0)} "
            f"| {s['disk_margin']:.2f}, {_f(s['disk_gain_margin_db'])}, "
            f"{_f(s['disk_phase_margin_deg'], 0)} "
            f"| {_t(s['rise_s'])} / {_t(s['settling_s'])}, {s['overshoot_pct']:.0f} % "
            f"| {s['dist_peak_deg']:.2f}, {_t(s['dist_recover_s'])} "
            f"| {_t(nl['rise_s'])} / {_t(nl['settling_s'])}, {nl['overshoot_deg']:.1f} deg, "
            f"{nl['max_delta_deg']:.0f} deg, {nl['min_u']:.2f} |"
        )
    out.append("")
    out.append("Disk margins, linear steps and disturbance: sampled loop (dt as given), steering "
               "lag included; settle = within ±2 deg of a 45 deg step. Overshoot: in % of the "
               "step (linear), in deg (nonlinear).")  # fmt: skip
    out.append(_nonlinear_step_note(designs))
    out += _margin_notes((d.u0, kind, f) for d in designs
                         for kind, f in (("continuous", d.linear), ("sampled", d.sampled)))
    return "\n".join(out)


def _nonlinear_step_note(designs) -> str:
    """Why the nonlinear 45 deg step rises slower than the linear one: the steering saturates
    (at delta_max) and, where eq. 3.1 cuts the speed reference below u0, the boat slows
    during the step (the yaw dynamics are slower at lower speed)."""
    sat = [d for d in designs if d.nonlinear["max_delta_deg"] >= 0.999 * d.nonlinear.get(
        "delta_max_deg", math.inf)]  # fmt: skip
    slowed = [d for d in designs if d.nonlinear.get("min_u_ref", d.u0) < d.u0 - 1e-3]
    parts = ["Nonlinear step: the execution level as simulated (guidance, eq. 3.1, PID, speed "
             "loop) with the steering limit."]
    if sat:
        parts.append(f"The steering saturates (delta_max = {sat[0].nonlinear['delta_max_deg']:.0f}"
                     " deg) at u0 = " + ", ".join(f"{d.u0:g}" for d in sat) + " m/s.")
    if slowed:
        parts.append("It is also a speed change: eq. 3.1 cuts the speed reference at a large "
                     "heading error, to " + ", ".join(
                         f"{d.nonlinear['min_u_ref']:.2f} (boat down to "
                         f"{d.nonlinear['min_u']:.2f})" for d in slowed)
                     + " m/s at u0 = " + ", ".join(f"{d.u0:g}" for d in slowed)
                     + " m/s, and the yaw dynamics are slower at the lower speed: both slow the "
                     "rise against the linear loop at constant u0.")  # fmt: skip
    return " ".join(parts)


def _margin_notes(items) -> list[str]:
    """Lines for every loop whose margins python-control and the frequency sweep disagree on,
    for closed loops that are unstable, and one for the loops whose margins python-control
    computed from the frequency response (``margin_method`` "frd")."""
    lines, frd, ill = [], [], []
    for u, kind, f in items:
        method = f.get("margin_method", "poly")
        if method.startswith("frd"):
            frd.append(f"{u:g} m/s ({kind})")
        if method.endswith(ILL):
            ill.append(f"{u:g} m/s ({kind})")
        if f.get("margin_check", "python-control = sweep") != "python-control = sweep":
            lines.append(f"- u0 = {u:g} m/s, {kind}: {f['margin_check']}")
        if not f.get("stable", True):
            lines.append(f"- u0 = {u:g} m/s, {kind}: closed loop UNSTABLE")
    out = (["", "Margin cross-check (python-control vs frequency sweep):", *lines]
           if lines else ["", "Margin cross-check: python-control and the frequency sweep agree."])
    if frd:
        out.append(f"python-control computed the margins at u0 = {', '.join(frd)} from the "
                   "frequency response: it judged its polynomial method numerically unreliable "
                   "for these sampled loops; the frequency sweep checks them.")  # fmt: skip
    if ill:
        out.append(f"Loop transfer functions at u0 = {', '.join(ill)} have badly conditioned "
                   "coefficients (scipy's BadCoefficients, e.g. Kp = 0); the frequency sweep "
                   "checks their margins.")  # fmt: skip
    return out


def bode_figure(loops: dict, title: str, omega_limits: tuple[float, float]):
    """A Bode plot (magnitude in dB, phase in deg) of the loops ``loops`` (name -> SISO
    loop transfer function) with their classical margins marked, and one line per loop above
    the axes: its name, gain margin (dB) and phase margin (deg), each at its frequency
    (python-control's margins); ``title`` is the figure's title. Returns the figure (drawn
    on a new one; the caller saves and closes it)."""
    fig = plt.figure(figsize=(7, 6))
    # python-control labels a trace and its margins with the response's system name (an
    # unnamed system's is "sys[372]"); a system's own name may hold no "." ("2.5 m/s"), the
    # response's sysname may. bode_plot computes the same response from a system.
    responses = ct.frequency_response(list(loops.values()), omega_limits=omega_limits)
    for name, r in zip(loops, responses, strict=True):
        r.sysname = name
    # dB: the gain margin in dB (python-control's default states it as a ratio)
    ct.bode_plot(responses, omega_limits=omega_limits, display_margins=True, dB=True, deg=True,
                 title=title)  # fmt: skip
    ax = fig.axes[0]  # a margin without its crossover: python-control says "inf (at nan)"
    ax.title.set_text(ax.get_title().replace("inf dB (at nan rad/s)", "inf (no phase crossover)")
                      .replace("inf deg (at nan rad/s)", "inf (no gain crossover)"))  # fmt: skip
    return fig


def bode_yaw_figure(model, d, T_f: float):
    """The Bode plot of design ``d``'s yaw loop (:func:`bode_figure`): broken at the steering
    command, continuous time (the sampled loop's margins are in yaw.md)."""
    return bode_figure({f"L (u0 = {d.u0:g} m/s)": yaw_loop(yaw_plant(model, d.u0), d.gains,
                                                            T_f).L},
                       f"yaw loop at u0 = {d.u0:g} m/s (broken at steering command)",
                       (1e-3, 1e2))  # fmt: skip


def plot_yaw(model, designs, runs, T_f: float, out: Path) -> list[Path]:
    """Bode plots with margins (one per speed), linear and nonlinear 45 deg steps."""
    paths = []
    for d in designs:
        fig = bode_yaw_figure(model, d, T_f)
        p = out / f"bode_yaw_u{d.u0:g}.png"
        fig.savefig(p, dpi=100)
        plt.close(fig)
        paths.append(p)
    fig, axes = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    for d in designs:
        lp = yaw_loop(yaw_plant(model, d.u0), d.gains, T_f)
        t = np.arange(0, 120, 0.05)
        with np.errstate(over="ignore", invalid="ignore"):  # unstable: off the axes
            y = ct.step_response(lp.T_ref, t).outputs * 45.0
        axes[0].plot(t, y, label=f"u0 = {d.u0:g} m/s")
        r = runs[d.u0]
        axes[1].plot(r.t, np.degrees(np.unwrap(r.X[:, 2])), label=f"u0 = {d.u0:g} m/s "
                     f"(settles {d.nonlinear['settling_s']:.1f} s)")  # fmt: skip
    for ax, title in zip(
        axes,
        ("linear loop (steering lag, filter)", "nonlinear closed loop (execution level + model)"),
        strict=True,
    ):
        ax.axhspan(45 - math.degrees(SETTLE_BAND), 45 + math.degrees(SETTLE_BAND), color="0.9")
        ax.set_ylabel("heading (deg)")
        ax.set_title(f"45 deg heading step: {title}")
        ax.legend(fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[1].set_xlabel("time (s)")
    fig.tight_layout()
    p = out / "step_yaw.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    paths.append(p)
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for d in designs:
        r = runs[d.u0]
        axes[0].plot(r.t, np.degrees(r.X[:, 7]), label=f"u0 = {d.u0:g} m/s")
        axes[1].plot(r.t, r.X[:, 3])
    axes[0].set_ylabel("steering delta (deg)")
    axes[1].set_ylabel("surge u (m/s)")
    axes[1].set_xlabel("time (s)")
    axes[0].legend(fontsize=8)
    axes[0].set_title("nonlinear 45 deg step: actuator and speed")
    fig.tight_layout()
    p = out / "step_yaw_inputs.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return [*paths, p]


def speed_tables(g, loop, grids, best, steps=None, limits=None, bound: float = math.inf,
                 notes=(), hull: tuple[str, float] | None = None) -> str:  # fmt: skip
    """Markdown: speed loop margins per speed; speed steps, linear beside nonlinear
    (``steps``: :func:`~mpcasv.control.tuning_speed.speed_step` figures per speed, ``limits``
    the words on the thrust limits and the straight-course top speed); turn grid per
    distance, its arrival radius beside the vessel's name and length ``hull`` (m); the
    recommendation under the ``u_cmd,max`` ``bound`` (m/s) and its ``notes``
    (:func:`~mpcasv.control.tuning_speed.edge_notes`)."""
    out = [f"Speed loop: Kp = {g.Kp:.1f} N/(m/s), Ki = {g.Ki:.1f} N/(m/s s)", "",
           "| u0 (m/s) | GM dB (cont / sampled) | PM deg (cont / sampled) | disk margin "
           "(sampled) |", "|" + "---|" * 4]  # fmt: skip
    for u, (c, s) in loop.items():
        out.append(f"| {u:g} | {_f(c['gain_margin_db'])} / {_f(s['gain_margin_db'])} "
                   f"| {_f(c['phase_margin_deg'], 0)} / {_f(s['phase_margin_deg'], 0)} "
                   f"| {s['disk_margin']:.2f} |")  # fmt: skip
    out += _margin_notes((u, kind, f) for u, (c, s) in loop.items()
                         for kind, f in (("continuous", c), ("sampled", s)))
    out += _step_table(loop, steps or {}, limits)
    for d, (rows, _) in grids.items():
        angles = list(rows[0].figures)
        R = next(iter(rows[0].figures.values()))["radius"]
        length = f"; {hull[0]} is {hull[1]:g} m long" if hull else ""
        out += ["", f"Turns from full speed, waypoint {d:g} m away (time s / path m until on "
                f"course, within {math.degrees(TURN_BAND):g} deg, or within {R:g} m of the "
                f"waypoint, a fixed radius for every vessel{length}; P = pirouette: a full "
                f"circle of turning without heading for it; NR = not within {R:g} m in the run, "
                f"{TURN_T_END:g} s + {d:g} m / min(u_ff, u_max))", "",
                "| u_ff | k_u | u_ff + k_u pi/2 | " + " | ".join(f"{a:g} deg" for a in angles)
                + " |", "|" + "---|" * (3 + len(angles))]  # fmt: skip
        for r in rows:
            cells = [("P " if f["pirouette"] else "") + ("" if f["reached"] else "NR ")
                     + f"{_f(f['turn_s'])} / {_f(f['turn_m'])}" for f in r.figures.values()]
            base = r.k_u == 0 and r is rows[-1]
            label = " (no reference model)" if base else ""
            top = u_cmd_max(r.u_ff, r.k_u)
            over = "" if base or within(r.u_ff, r.k_u, bound) else " (above the bound)"
            out.append(f"| {r.u_ff:g}{label} | {r.k_u:g} | {top:.2f}{over} | "
                       + " | ".join(cells) + " |")
    rule = (f"every turn reached without a pirouette, u_ff + k_u pi/2 <= {bound:.4g} m/s "
            "(--u-cmd-max), least total turn time")
    out += ["", f"Recommended (grid; {rule}): u_ff = {best.u_ff}, k_u = {best.k_u}" if best
            else f"Recommended: none (no pair of the grid with {rule.split(', least')[0]})"]
    out += [f"- {n}" for n in notes]
    return "\n".join(out)


def _step_table(loop, steps: dict, limits: str | None) -> list[str]:
    """The speed steps: the sampled linear loop's (no thrust limits, so the same up and
    down) beside the nonlinear ones, with the time at a thrust limit and the unreachable."""
    from mpcasv.control.tuning_speed import SPEED_STEP, STEP_T_END

    out = ["", f"Speed steps of {SPEED_STEP:g} m/s from each speed u0: rise (10-90 %) / "
           "settle (2 %) in s, overshoot in % of the step. Linear: the sampled loop "
           "linearised at u0 with the feed-forward of u_ref, without thrust limits (the same "
           "up and down). Nonlinear: the "
           "execution level and vessel model as simulated, thrust limits included "
           f"({limits}); thrust at a limit: time at it in the {STEP_T_END:g}-s run (the "
           "linear figures hold only where it is none).", "",
           "| u0 (m/s) | step | linear: rise / settle (s), overshoot % | nonlinear: rise / "
           "settle (s), overshoot % | thrust at a limit: s (% of run) |", "|" + "---|" * 5]
    for u, (_, s) in loop.items():
        lin = f"{_t(s['rise_s'])} / {_t(s['settling_s'])}, {s['overshoot_pct']:.0f}"
        for st in steps.get(u, []):
            step = f"{st['direction']} to {st['u1']:g} m/s"
            if not st["reachable"]:
                out.append(f"| {u:g} | {step} | {lin} | {st['why']} | - |")
                continue
            sat = [f"{k} {st[f'at_{k}'] * st['t_end']:.1f} s ({100 * st[f'at_{k}']:.1f} %)"
                   for k in ("T_max", "T_min") if st[f"at_{k}"] > 0]  # fmt: skip
            out.append(f"| {u:g} | {step} | {lin} | {_t(st['rise_s'])} / "
                       f"{_t(st['settling_s'])}, {st['overshoot_pct']:.0f} | "
                       + (f"SATURATED: {', '.join(sat)}" if sat else "none") + " |")
    return out


def plot_speed(model, g, grids, field, best, out: Path) -> list[Path]:
    """Speed loop Bode (design speeds) and turn paths of the field and recommended pairs."""
    from mpcasv.control.tuning_speed import pi_tf, surge_plant

    loops = {f"L (u = {u:g} m/s)": ct.ss(pi_tf(g)) * surge_plant(model, u)
             for u in (0.5, 1.5, 2.5)}  # fmt: skip
    fig = bode_figure(loops, "speed loop at 0.5, 1.5, 2.5 m/s (thrust lag incl.)", (1e-3, 1e1))
    paths = [out / "bode_speed.png"]
    fig.savefig(paths[0], dpi=100)
    plt.close(fig)
    R = ARRIVAL_RADIUS
    for d, (rows, runs) in grids.items():
        pir = {(r.u_ff, r.k_u, a) for r in rows for a, f in r.figures.items() if f["pirouette"]}
        # one panel per turn angle: in one, the "no ref. model" 90 deg circle lay under the
        # 180 deg run's first half (a new user, session 46)
        angles = sorted({a for (_, _, a) in runs})
        fig, axes = plt.subplots(1, len(angles), figsize=(5.5 * len(angles), 6.2), squeeze=False)
        for ax, a in zip(axes[0], angles, strict=True):
            wp = (d * math.cos(math.radians(a)), d * math.sin(math.radians(a)))
            for (u_ff, k_u, a_run), r in runs.items():
                if a_run != a or ((u_ff, k_u) not in (field, (best.u_ff, best.k_u) if best
                                                       else field) and k_u != 0.0):  # fmt: skip
                    continue
                label = ("no ref. model" if k_u == 0 else f"u_ff={u_ff}, k_u={k_u}") + (
                    ": PIROUETTE (circles the waypoint)" if (u_ff, k_u, a) in pir else "")
                _, first = arrival(r.X, wp, R)
                reached = first < len(r.t)
                n = first + 1 if reached else len(r.t)
                (line,) = ax.plot(r.X[:n, 1], r.X[:n, 0], ls="--" if k_u == 0 else "-",
                                  lw=1.0 if k_u == 0 else 1.6, zorder=3 if k_u == 0 else 2,
                                  label=label + ("" if reached else f" (never within "
                                                 f"{R:g} m, {r.t[-1]:.0f} s)"))  # fmt: skip
                if reached and (u_ff, k_u, a) in pir:  # its verdict is in what follows (a
                    # review: the path stopped 5 m short of the waypoint, labelled PIROUETTE)
                    ax.plot(r.X[n - 1:, 1], r.X[n - 1:, 0], ls=":", lw=0.8,
                            color=line.get_color(), zorder=1)  # fmt: skip
            ax.plot(wp[1], wp[0], "kx", ms=9, zorder=4, label="waypoint")
            ax.plot(0, 0, "ko", ms=5, zorder=4, label="start (heading north)")
            ax.set_aspect("equal")
            ax.set_xlabel("East (m)")
            ax.set_ylabel("North (m)")
            ax.set_title(f"{a:g} deg turn", fontsize=10)
            ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.12))
            ax.grid(True, alpha=0.3)
        fig.set_layout_engine("constrained")
        fig.suptitle(f"turns from full speed, heading north at (0, 0), to a waypoint (x) {d:g} "
                     f"m away (paths until {R:g} m from it; a pirouette's whole run dotted "
                     "after)", fontsize=10)  # fmt: skip
        p = out / f"turns_{d:g}m.png"
        fig.savefig(p, dpi=100)
        plt.close(fig)
        paths.append(p)
    return paths


def _circling(dist: np.ndarray, n: int | None, R: float = ARRIVAL_RADIUS) -> np.ndarray:
    """The distances (m) from the waypoint of a pirouette's circling: after the pass (the
    first ``n`` samples reach ``R`` m), from the sample where it is ``R`` m or more away
    again, so that the pass's own samples inside are not counted; the whole run if it never
    came within ``R`` (``n`` None); empty if it stayed inside to the end."""
    if n is None:
        return dist
    again = np.nonzero(~in_circle(dist[n - 1:], R))[0]
    return dist[n - 1 + again[0]:] if len(again) else dist[:0]


def plot_pirouette(checks: dict, wp, out: Path, title: str) -> Path:
    """Paths, speeds and heading errors of :func:`mpcasv.control.tuning_speed.pirouette_check`
    (hard turn while accelerating, with and without eq. 3.1).

    Each run is drawn solid as far as :func:`~mpcasv.control.tuning_speed.turn` counted it
    (until it got on course, or came within ARRIVAL_RADIUS of the waypoint); a pirouette's
    rest of the run is drawn dashed, and its label says what the whole run does (a new user,
    session 46: "circles it, never on course" beside a trace that ended at 21 s, where it
    passed 5 m from the waypoint)."""
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 6.2))
    ax2 = ax1.twinx()
    for key, color in (("with", "C0"), ("without", "C3")):
        run, f = checks[key]
        R = f.get("radius", ARRIVAL_RADIUS)
        dist, first = arrival(run.X, wp, R)  # as turn() counts
        reached = first < len(run.t)
        n = first + 1 if reached else len(run.t)
        if f["pirouette"]:
            total = float(np.degrees(np.sum(np.abs(np.diff(np.unwrap(run.X[:, 2]))))))
            c = _circling(dist, n if reached else None, R)
            what = ("PIROUETTE, circles the waypoint:\n" + (
                f"within {R:g} m of the waypoint at {run.t[n - 1]:.0f} s, heading error "
                f"{abs(math.degrees(run.psi_error[n - 1])):.0f} deg, then (dashed)\n"
                if reached else "") + (f"circles it {c.min():.1f}-{c.max():.1f} m away"
                if len(c) else f"stays within {R:g} m of it") + f" to {run.t[-1]:.0f} s, turned "
                f"{total:.0f} deg")  # fmt: skip
        else:
            what = (f"turn done after {f['turn_s']:.0f} s, turned {f['total_turn_deg']:.0f} "
                    "deg" + (f", within {R:g} m of the waypoint at "
                             f"{run.t[n - 1]:.0f} s" if reached else ""))  # fmt: skip
        label = f"{key} eq. 3.1: {what}"
        ax0.plot(run.X[:n, 1], run.X[:n, 0], color=color, label=label)
        ax1.plot(run.t[:n], run.X[:n, 3], color=color, label=f"u, {key} eq. 3.1")
        ax2.plot(run.t[:n], np.degrees(np.abs(run.psi_error[:n])), color=color, ls=":", lw=1)
        if f["pirouette"] and n < len(run.t):
            ax0.plot(run.X[n - 1:, 1], run.X[n - 1:, 0], color=color, ls="--", lw=0.8, alpha=0.6)
            ax1.plot(run.t[n - 1:], run.X[n - 1:, 3], color=color, ls="--", lw=0.8, alpha=0.6)
    ax0.plot(wp[1], wp[0], "k*", ms=12, zorder=5,
             label=f"waypoint (reached: within {R:g} m)")
    ax0.plot(0, 0, "ko", zorder=5, label="start (heading north)")
    ax0.set_aspect("equal")
    ax0.set_xlabel("E (m)")
    ax0.set_ylabel("N (m)")
    # below both panels: inside, it covered the start and the waypoint
    fig.legend(*ax0.get_legend_handles_labels(), fontsize=8, loc="lower left", ncol=2,
               bbox_to_anchor=(0.02, 0.0), frameon=False)
    ax0.grid(True, alpha=0.3)
    ax0.set_title(title, fontsize=9)
    ax1.set_xlabel("time (s)")
    ax1.set_ylabel(f"surge u (m/s), solid (dashed: after {R:g} m)")
    ax2.set_ylabel("|heading error| (deg), dotted")
    ax1.legend(fontsize=8, loc="upper right")
    ax1.grid(True, alpha=0.3)
    fig.tight_layout(rect=(0, 0.17, 1, 1))
    out.mkdir(parents=True, exist_ok=True)
    p = out / "pirouette.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p
