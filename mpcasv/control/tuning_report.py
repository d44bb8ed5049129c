"""Tables and figures of ``mpcasv tune yaw`` / ``mpcasv tune speed`` (markdown, PNG)."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import control as ct
import matplotlib.pyplot as plt
import numpy as np

from mpcasv.control.tuning_yaw import SETTLE_BAND, yaw_loop, yaw_plant


def _f(v: float, nd: int = 1) -> str:
    return "inf" if not math.isfinite(v) else f"{v:.{nd}f}"


def yaw_table(designs) -> str:
    """Markdown tables: Nomoto models and gains; margins and steps (linear, sampled, nonlinear)."""
    out = ["| u0 (m/s) | K (1/s) | T (s) | T1 (s) | T2 (s) | T3 (s) | wn (rad/s) | Kp | Ki (1/s) "
           "| Kd (s) |", "|" + "---|" * 10]  # fmt: skip
    for d in designs:
        n, g = d.nomoto, d.gains
        out.append(f"| {d.u0:g} | {n.K:.4f} | {n.T:.3f} | {n.T1:.3f} | {n.T2:.3f} | {n.T3:.3f} "
                   f"| {d.wn:.3f} | {g.Kp:.3f} | {g.Ki:.4f} | {g.Kd:.3f} |")  # fmt: skip
    out += ["", "| u0 | GM dB (cont / sampled) | PM deg (cont / sampled) | disk margin "
            "(alpha, GM dB, PM deg) | lin. rise / settle (s), overshoot % | 5 deg dist.: peak "
            "deg, recover s | nonlin. 45 deg: rise / settle (s), overshoot deg, max delta deg |",
            "|" + "---|" * 7]  # fmt: skip
    for d in designs:
        c, s, nl = d.linear, d.sampled, d.nonlinear
        out.append(
            f"| {d.u0:g} | {_f(c['gain_margin_db'])} / {_f(s['gain_margin_db'])} "
            f"| {_f(c['phase_margin_deg'], 0)} / {_f(s['phase_margin_deg'], 0)} "
            f"| {s['disk_margin']:.2f}, {_f(s['disk_gain_margin_db'])}, "
            f"{_f(s['disk_phase_margin_deg'], 0)} "
            f"| {_f(s['rise_s'])} / {_f(s['settling_s'])}, {s['overshoot_pct']:.0f} "
            f"| {s['dist_peak_deg']:.2f}, {_f(s['dist_recover_s'])} "
            f"| {_f(nl['rise_s'])} / {_f(nl['settling_s'])}, {nl['overshoot_deg']:.1f}, "
            f"{nl['max_delta_deg']:.0f} |"
        )
    out.append("")
    out.append("Disk margins, linear steps and disturbance: sampled loop (dt as given), steering "
               "lag included; settle = within ±2 deg of a 45 deg step.")  # fmt: skip
    return "\n".join(out)


def plot_yaw(model, designs, runs, T_f: float, out: Path) -> list[Path]:
    """Bode plots with margins (one per speed), linear and nonlinear 45 deg steps."""
    paths = []
    for d in designs:
        L = yaw_loop(yaw_plant(model, d.u0), d.gains, T_f).L
        fig = plt.figure(figsize=(7, 6))
        ct.bode_plot(
            L,
            omega_limits=(1e-3, 1e2),
            display_margins=True,
            label="L",
            title=f"yaw loop at u0 = {d.u0:g} m/s (broken at steering command)",
        )
        p = out / f"bode_yaw_u{d.u0:g}.png"
        fig.savefig(p, dpi=100)
        plt.close(fig)
        paths.append(p)
    fig, axes = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    for d in designs:
        lp = yaw_loop(yaw_plant(model, d.u0), d.gains, T_f)
        t = np.arange(0, 120, 0.05)
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


def speed_tables(g, loop, grids, best) -> str:
    """Markdown: speed loop margins per speed; turn grid per distance."""
    out = [f"Speed loop: Kp = {g.Kp:.1f} N/(m/s), Ki = {g.Ki:.1f} N/(m/s s)", "",
           "| u0 (m/s) | GM dB (cont / sampled) | PM deg (cont / sampled) | disk margin (sampled) "
           "| 0.5 m/s step: rise / settle (s), overshoot % |", "|" + "---|" * 5]  # fmt: skip
    for u, (c, s) in loop.items():
        out.append(f"| {u:g} | {_f(c['gain_margin_db'])} / {_f(s['gain_margin_db'])} "
                   f"| {_f(c['phase_margin_deg'], 0)} / {_f(s['phase_margin_deg'], 0)} "
                   f"| {s['disk_margin']:.2f} | {_f(s['rise_s'])} / {_f(s['settling_s'])}, "
                   f"{s['overshoot_pct']:.0f} |")  # fmt: skip
    for d, (rows, _) in grids.items():
        angles = list(rows[0].figures)
        out += ["", f"Turns from full speed, waypoint {d:g} m away (time s / path m to stay within "
                "10 deg; P = pirouette)", "",
                "| u_ff | k_u | " + " | ".join(f"{a:g} deg" for a in angles) + " |",
                "|" + "---|" * (2 + len(angles))]  # fmt: skip
        for r in rows:
            cells = [("P " if f["pirouette"] else "") + f"{_f(f['turn_s'])} / {_f(f['turn_m'])}"
                     for f in r.figures.values()]  # fmt: skip
            label = " (no reference model)" if r.k_u == 0 and r is rows[-1] else ""
            out.append(f"| {r.u_ff:g}{label} | {r.k_u:g} | " + " | ".join(cells) + " |")
    out += ["", f"Recommended (grid, pirouette-free, least total turn time): u_ff = {best.u_ff}, "
            f"k_u = {best.k_u}"]  # fmt: skip
    return "\n".join(out)


def plot_speed(model, g, grids, field, best, out: Path) -> list[Path]:
    """Speed loop Bode (design speeds) and turn paths of the field and recommended pairs."""
    from mpcasv.control.tuning_speed import surge_plant

    fig = plt.figure(figsize=(7, 6))
    Ls = [ct.ss(ct.tf([g.Kp, g.Ki], [1.0, 0.0])) * surge_plant(model, u) for u in (0.5, 1.5, 2.5)]
    ct.bode_plot(
        Ls,
        omega_limits=(1e-3, 1e1),
        display_margins=True,
        title="speed loop at 0.5, 1.5, 2.5 m/s (thrust lag incl.)",
    )
    paths = [out / "bode_speed.png"]
    fig.savefig(paths[0], dpi=100)
    plt.close(fig)
    for d, (_rows, runs) in grids.items():
        fig, ax = plt.subplots(1, 1, figsize=(7, 7))
        for (u_ff, k_u, a), r in runs.items():
            if (u_ff, k_u) not in (field, (best.u_ff, best.k_u)) and k_u != 0.0:
                continue
            label = "no ref. model" if k_u == 0 else f"u_ff={u_ff}, k_u={k_u}"
            wp = (d * math.cos(math.radians(a)), d * math.sin(math.radians(a)))
            near = np.hypot(r.X[:, 0] - wp[0], r.X[:, 1] - wp[1]) < 5.0
            n = int(np.argmax(near)) + 1 if near.any() else len(r.t)
            ax.plot(r.X[:n, 1], r.X[:n, 0], label=f"{label}, {a:g} deg")
            ax.plot(wp[1], wp[0], "kx")
        ax.set_aspect("equal")
        ax.set_xlabel("East (m)")
        ax.set_ylabel("North (m)")
        ax.set_title(
            f"turns from full speed, heading north at (0, 0), to waypoints (x) {d:g} m away"
            "\n(paths until 5 m from the waypoint)",
            fontsize=10,
        )
        ax.legend(fontsize=7)
        ax.grid(True, alpha=0.3)
        p = out / f"turns_{d:g}m.png"
        fig.savefig(p, dpi=100)
        plt.close(fig)
        paths.append(p)
    return paths
