"""The yaw gain schedule beyond its design points (``mpcasv tune yaw``): where the pole
placement was given up, and the margins off the schedule speeds.

* **Kd clipped.** :func:`mpcasv.control.tuning_yaw.place_pid` clips a negative ``Kd`` to 0
  (the execution level takes ``Kd >= 0``): the hull alone is then faster than the requested
  poles (Gretha at 0.5 m/s: the formula gives ``Kd = -2.05``). With ``Kd = 0`` the closed loop
  on the first-order Nomoto model is ``T s^3 + s^2 + K Kp s + K Ki`` and its poles are not
  the requested ``(s^2 + 2 zeta wn s + wn^2)(s + a)``: :func:`kd_clip` says which they are.
* **Off the schedule.** The execution level interpolates the gains linearly between the
  schedule speeds and holds them below the lowest and above the highest
  (:func:`mpcasv.control.execution.pwlinear`, on the measured surge speed), so the loop at
  0.3 m/s runs the 0.5 m/s gains on a slower hull, and a schedule that ends below the top
  speed runs its last gains on a faster one. :func:`off_schedule` checks the margins
  there (continuous and sampled, steering lag included) against the same bar as the schedule
  speeds, PM >= 45 deg and GM >= 6 dB.
"""

from __future__ import annotations

import numpy as np

#: speeds below the lowest schedule speed that are checked, as fractions of it
BELOW = (0.4, 0.6, 0.8)
#: speeds above the highest schedule speed that are checked, as fractions of the way from it
#: to the vessel's top speed (the last: the top speed itself)
ABOVE = (1 / 3, 2 / 3, 1.0)
#: the acceptance bar of the yaw loop (deg, dB)
PM_MIN, GM_MIN = 45.0, 6.0


def kd_clip(nm, g, wn: float, zeta: float, integral_ratio: float) -> dict | None:
    """``None`` if the placed ``Kd`` is the formula's; else the formula's ``Kd`` (s) and the
    requested and achieved closed-loop poles (1/s, as ``[real, imag]`` pairs: JSON) on the
    first-order Nomoto model ``nm`` with the gains ``g`` as clipped (module docstring)."""
    from mpcasv.control.tuning_yaw import closed_loop_polynomial, pid_formula, target_polynomial

    kd = pid_formula(nm, wn, zeta, integral_ratio).Kd
    if kd >= 0:
        return None
    want = np.roots(target_polynomial(wn, zeta, integral_ratio))
    got = np.roots(closed_loop_polynomial(nm, g))
    return {"Kd_formula": float(kd),
            "poles_requested": [[float(p.real), float(p.imag)] for p in want + 0j],
            "poles_achieved": [[float(p.real), float(p.imag)] for p in got + 0j]}  # fmt: skip


def poles_text(poles) -> str:
    """Poles (``[real, imag]`` pairs or complex) as ``-0.12, -0.05 ± 0.2j`` (1/s), slowest
    last, a complex pair once."""
    out, seen = [], []
    poles = [complex(*p) if isinstance(p, list | tuple) else complex(p) for p in poles]
    for p in sorted(poles, key=lambda p: (-abs(p.real), abs(p.imag))):
        if abs(p.imag) <= 1e-6 * abs(p):  # a double real pole's roots: +-1e-9j
            out.append(f"{p.real:.3g}")
            continue
        if any(abs(p - q.conjugate()) <= 1e-6 * abs(p) for q in seen):
            continue
        seen.append(p)
        out.append(f"{p.real:.3g} ± {abs(p.imag):.3g}j")
    return ", ".join(out)


def off_speeds(speeds, top: float) -> list[tuple[float, str]]:
    """The speeds off the schedule that are checked: :data:`BELOW` times the lowest, the
    midpoints between schedule speeds and, when the highest is below the vessel's top speed
    ``top`` (m/s), :data:`ABOVE` of the way from it to ``top`` (the gains are held there in
    every transit faster than the schedule), each with "below" / "between" / "above"."""
    s = sorted(float(u) for u in speeds)
    below = [(round(f * s[0], 4), "below (gains held)") for f in BELOW]
    mid = [(round((a + b) / 2, 4), "between (gains interpolated)") for a, b in zip(s, s[1:],
                                                                                 strict=False)]
    # rounded, above the schedule and once each (a top speed a hair above the last schedule
    # speed gave three equal rows, a review)
    above = dict.fromkeys(u for f in ABOVE if (u := round(s[-1] + f * (top - s[-1]), 4)) > s[-1])
    return below + mid + [(u, "above (gains held)") for u in above]


def off_schedule(model, ep, dt: float) -> list[dict]:
    """Margins of the yaw loop at :func:`off_speeds` (up to the vessel's top speed, the least
    of its top speed at ``T_max`` and ``u_max``) with the gains the execution level uses
    there (interpolated, held at the ends), continuous and sampled at ``dt``.

    Returns one dict per speed: ``u0``, ``where``, ``gains`` (Kp, Ki, Kd), the continuous and
    sampled ``phase_margin_deg``, ``gain_margin_db``, ``stable``, and ``ok`` (both loops stable
    and at or above :data:`PM_MIN`, :data:`GM_MIN`)."""
    from mpcasv.control.execution import pwlinear
    from mpcasv.control.tuning_yaw import PIDGains, loop_figures, yaw_loop, yaw_plant

    ys = ep.yaw
    rows = []
    top = min(model.top_speed, model.params.u_max)
    for u, where in off_speeds(ys.speeds, top):  # the execution level's own schedule lookup
        g = PIDGains(*(float(pwlinear(u, ys.speeds, k)) for k in (ys.Kp, ys.Ki, ys.Kd)))
        P = yaw_plant(model, u)
        c, s = loop_figures(yaw_loop(P, g, ys.T_f)), loop_figures(yaw_loop(P, g, ys.T_f, dt))
        ok = all(f["stable"] and f["phase_margin_deg"] >= PM_MIN
                 and f["gain_margin_db"] >= GM_MIN for f in (c, s))  # fmt: skip
        rows.append({"u0": u, "where": where, "gains": (g.Kp, g.Ki, g.Kd),
                     "pm": (c["phase_margin_deg"], s["phase_margin_deg"]),
                     "gm": (c["gain_margin_db"], s["gain_margin_db"]),
                     "stable": c["stable"] and s["stable"], "ok": bool(ok)})  # fmt: skip
    return rows


def schedule_notes(designs, rows) -> list[str]:
    """Markdown lines: every speed where ``Kd`` was clipped (the poles achieved instead),
    and the off-schedule margins with PASS/FAIL against the bar."""
    out = []
    for d in designs:
        clip = getattr(d, "kd_clip", None)
        if clip:
            out += ["", f"Pole placement NOT achieved at u0 = {d.u0:g} m/s: the formula gives "
                    f"Kd = {clip['Kd_formula']:.2f} s, clipped to 0 (the hull alone is faster "
                    "than the requested poles); on the first-order Nomoto model the closed-loop "
                    f"poles are {poles_text(clip['poles_achieved'])} 1/s instead of the requested "
                    f"{poles_text(clip['poles_requested'])} 1/s."]  # fmt: skip
    out += ["", f"Margins off the schedule speeds (the gains the execution level uses there; "
            f"bar PM >= {PM_MIN:g} deg, GM >= {GM_MIN:g} dB, stable):", "",
            "| u0 (m/s) | where | Kp, Ki (1/s), Kd (s) | PM deg (cont / sampled) "
            "| GM dB (cont / sampled) | bar |", "|" + "---|" * 6]  # fmt: skip
    for r in rows:
        out.append(f"| {r['u0']:g} | {r['where']} | {', '.join(f'{x:.3g}' for x in r['gains'])} "
                   f"| {r['pm'][0]:.1f} / {r['pm'][1]:.1f} | {r['gm'][0]:.1f} / {r['gm'][1]:.1f} "
                   f"| {'PASS' if r['ok'] else 'FAIL'} |")  # fmt: skip
    bad = [r for r in rows if not r["ok"]]
    if bad:
        out += ["", "Off the schedule the loop FAILS the bar at "
                + ", ".join(f"{r['u0']:g}" for r in bad) + " m/s" + (
                    " (below the lowest schedule speed the gains are held; a slower schedule "
                    "speed in --speeds may cover it, not checked here)"
                    if any(r["where"].startswith("below") for r in bad) else "") + (
                    " (above the highest schedule speed the gains are held in every faster "
                    "transit: this fails the acceptance; add a schedule speed up to the top "
                    "speed to --speeds)" if any(r["where"].startswith("above") for r in bad)
                    else "") + "."]
    return out


def above_ok(rows) -> bool:
    """Whether the loop passes the bar at every checked speed above the schedule (part of
    ``tune yaw``'s acceptance: unlike below the lowest, where the boat only passes when it
    leaves standby, the held gains run every transit faster than the schedule)."""
    return all(r["ok"] for r in rows if r["where"].startswith("above"))


def off_schedule_summary(rows) -> str:
    """The words for the summary line: PASS, or the speeds that fail with their margins."""
    bad = [r for r in rows if not r["ok"]]
    if not bad:
        return f"off the schedule ({len(rows)} speeds): PASS"
    return "off the schedule: FAIL at " + ", ".join(
        f"{r['u0']:g} m/s (PM {min(r['pm']):.1f} deg, GM {min(r['gm']):.1f} dB)" for r in bad)

