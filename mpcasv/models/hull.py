"""Derive Gretha's default model parameters from her main dimensions, with provenance.

None of these numbers is field-identified: they come from the dimensions (thesis §3.1:
5.2 m x 2.15 m x 0.3 m, 810 kg + ~100 kg ballast aft, observed top speed 2.5 m/s) through
textbook formulas. ``python -m mpcasv.models.hull`` regenerates
``mpcasv/data/vessels/gretha.toml``; ``mpcasv identify`` replaces them with identified values.

Formulas
--------
- Added mass in sway and yaw by strip theory (2-D section added mass rho pi T^2 / 2 of a
  shallow section at the free surface, integrated over a prismatic hull); surge -0.1 m.
- Clarke, Gedling & Hine (1982) regressions for the linear damping derivatives, in the prime
  system (Y_v = Y'_v rho/2 L^2 U, ...), as tabulated in Fossen (2021) §6.4.1. They are
  proportional to speed: the ``Y_uv`` ... ``N_ur`` coefficients.
- Steering: thrust vectoring plus the lift of the steered drive leg (a low-aspect foil,
  -rho/2 A C_L_alpha per rad and per (m/s)^2).
- Drive leg and aft keel as a stabilising fin at x_p: lift -rho/2 A C_L_alpha U (v + x_p r)
  added to the speed-proportional sway/yaw damping. Without it the Munk moment makes this
  wide, shallow hull course-unstable above ~1.5 m/s (checked by ``sway_yaw_eigenvalues``).
- Low-speed linear damping from time constants (Fossen's PythonVehicleSimulator ``otter.py``:
  Y_v = -M22 / T_sway, N_r = -M33 / T_yaw). Not faded out at speed (``alpha_Y = alpha_N = 0``;
  the fade of Fossen 2021 §6.4 is measured in docs/vessel.md).
- Cross-flow drag (Fossen 2021 §6.4.3, strip theory): Y_|v|v = -rho/2 T C_d L,
  N_|r|r = -rho/2 T C_d L^4 / 32.
- Idle drive (propeller stopped): locked-propeller form drag, ``C_prop = 1.0`` on the expanded
  blade area (UFC 4-159-03 "Design: Moorings", 2005, eq. 21), plus the drive leg as a
  streamlined strut (Hoerner 1965, ch. 6), blended out as thrust rises (docs/vessel.md).
- Surge resistance: ITTC-1957 friction line with a form factor and a residual-resistance
  coefficient (guessed for Fn = 0.35), split 10 % linear / 90 % quadratic; T_max is then the
  thrust that gives the observed top speed of 2.5 m/s.
"""

from __future__ import annotations

import math
from pathlib import Path

import tomli_w

RHO = 1025.0  # sea water density (kg/m^3)
NU_WATER = 1.19e-6  # kinematic viscosity at 15 C (m^2/s)


#: idle-drive inputs of :func:`derive_gretha` (docs/vessel.md): propeller diameter (m), expanded
#: area ratio, locked-propeller drag coefficient, drive-leg frontal area (m^2) and C_D
IDLE_DRIVE = {"D_prop": 0.30, "EAR": 0.55, "C_prop": 1.0, "A_leg_x": 0.022, "C_leg": 0.1}


def idle_drag_coeff(D_prop: float, EAR: float, C_prop: float, A_leg_x: float,
                    C_leg: float) -> float:  # fmt: skip
    """``X_uu_idle = -rho/2 (C_prop A_E + C_leg A_leg_x)`` (N s^2/m^2), ``A_E = EAR pi D^2/4``."""
    A_E = EAR * math.pi * D_prop**2 / 4
    return -0.5 * RHO * (C_prop * A_E + C_leg * A_leg_x)


def derive_gretha() -> tuple[dict[str, float | str], dict[str, str]]:
    """Return (values, provenance) for Gretha."""
    L, B, T = 5.2, 2.15, 0.3
    m_hull, m_ballast, x_ballast = 810.0, 100.0, -2.0
    U_top = 2.5
    m = m_hull + m_ballast
    x_g = m_ballast * x_ballast / m
    C_B = m / RHO / (L * B * T)
    I_z = m * (0.25 * L) ** 2

    k = math.pi * (T / L) ** 2  # Clarke's common factor
    half = 0.5 * RHO
    Yv_p = -k * (1 + 0.40 * C_B * B / T)
    Yr_p = -k * (-0.5 + 2.2 * B / L - 0.080 * B / T)
    Nv_p = -k * (0.5 + 2.4 * T / L)
    Nr_p = -k * (0.25 + 0.039 * B / T - 0.56 * B / L)

    # Added mass by strip theory: 2-D sway added mass of a section of draught T at the free
    # surface, a22 = rho pi T^2 / 2 per metre, over a prismatic hull of length L. (Clarke's
    # added-mass regressions were fitted for B/L < 0.2 and give N_rdot > 0 at B/L = 0.41.)
    a22 = RHO * math.pi * T**2 / 2
    Y_vdot = -a22 * L
    Y_rdot = N_vdot = 0.0  # fore-aft symmetric strips
    N_rdot = -a22 * L**3 / 12
    X_udot = -0.1 * m

    T_sway, T_yaw = 3.0, 3.0
    A_leg, C_L_alpha = 0.06, 3.0  # steered drive leg: lateral area (m^2), lift slope (1/rad)
    A_fin = 0.10  # drive leg + aft keel, lateral area acting as a stabilising fin at x_p (m^2)
    x_p = -L / 2
    k_fin = half * A_fin * C_L_alpha  # fin lift per (m/s) of local sway at x_p, per m/s of U
    Y_v = -(m - Y_vdot) / T_sway
    N_r = -(I_z - N_rdot) / T_yaw
    Y_uv = Yv_p * half * L**2 - k_fin
    N_ur = Nr_p * half * L**4 - k_fin * x_p**2
    # Fade of the low-speed terms, exp(-alpha U) (Fossen 2021 §6.4): measured, not shipped.
    # alpha_N = N_ur / N_r (2.05 s/m, the fastest fade keeping the yaw damping monotone in U)
    # gives more yaw authority at low speed, but the yaw schedule tune yaw places on that model
    # makes eq. 3.1's turns pirouette (docs/vessel.md, "Low-speed damping"): 0 until low-speed
    # turning logs identify it.
    alpha_N_fossen = N_ur / N_r

    S = L * (1.7 * T + C_B * B)  # Mumford wetted surface
    Re = U_top * L / NU_WATER
    C_F = 0.075 / (math.log10(Re) - 2) ** 2
    form, C_R = 1.2, 0.012  # C_R: guess for a beamy semi-displacement hull at Fn = 0.35
    C_T = form * C_F + C_R
    R_top = half * S * C_T * U_top**2
    X_u = -0.1 * R_top / U_top
    X_uu = -0.9 * R_top / U_top**2
    C_d = 1.0
    # Idle drive (docs/vessel.md): locked propeller, form drag on the expanded blade area,
    # C_prop = 1.0 (UFC 4-159-03, 2005, eq. 21); drive leg (strut + lower unit) as a
    # streamlined body, C_D ~ 0.1 on frontal area (Hoerner 1965, ch. 6). The propeller's size
    # is a guess for a ~2 kW drive that pushes this hull at 2.5 m/s.
    D_prop, EAR, C_prop = IDLE_DRIVE["D_prop"], IDLE_DRIVE["EAR"], IDLE_DRIVE["C_prop"]
    A_leg_x, C_leg = IDLE_DRIVE["A_leg_x"], IDLE_DRIVE["C_leg"]
    A_E = EAR * math.pi * D_prop**2 / 4
    X_uu_idle = idle_drag_coeff(**IDLE_DRIVE)
    values: dict[str, float | str] = {
        "name": "gretha",
        "L": L, "B": B, "T_draft": T, "m": m, "I_z": I_z, "x_g": x_g,
        "X_udot": X_udot, "Y_vdot": Y_vdot, "Y_rdot": Y_rdot, "N_vdot": N_vdot, "N_rdot": N_rdot,
        "X_u": X_u, "X_uu": X_uu, "Y_v": Y_v, "Y_r": 0.0, "N_v": 0.0, "N_r": N_r,
        "Y_uv": Y_uv, "Y_ur": Yr_p * half * L**3 - k_fin * x_p,
        "N_uv": Nv_p * half * L**3 - k_fin * x_p, "N_ur": N_ur,
        "Y_vv": -half * T * C_d * L, "N_rr": -half * T * C_d * L**4 / 32,
        "x_p": x_p, "Y_uudelta": -half * A_leg * C_L_alpha, "T_max": R_top, "T_min": 0.0,
        "delta_max": math.radians(30.0), "delta_rate_max": math.radians(30.0),
        "T_thrust": 0.5, "T_delta": 0.3, "eps_abs": 0.01, "u_max": U_top,
        "X_uu_idle": X_uu_idle, "T_idle": 0.05 * R_top,
        "actuation": "steerable", "y_thr": 0.0, "alpha_Y": 0.0, "alpha_N": 0.0,
    }  # fmt: skip
    clarke = "Clarke et al. (1982) regression, Fossen (2021) §6.4.1"
    fin = (
        f"plus the lift of drive leg + aft keel as a fin at x_p (A = {A_fin} m^2, guess), "
        "without which the hull is course-unstable above 1.5 m/s (Munk moment)"
    )
    prov = {
        "L": "thesis §3.1 (Pioner 17 length)",
        "B": "thesis §3.1 (beam)",
        "T_draft": "thesis §3.1 (draught)",
        "m": f"thesis §3.1: {m_hull:g} kg without payload + {m_ballast:g} kg ballast",
        "I_z": "m (0.25 L)^2: radius of gyration 0.25 L (as Fossen's otter.py)",
        "x_g": f"ballast {m_ballast:g} kg placed {x_ballast:g} m from midships (guess)",
        "X_udot": "-0.1 m (rule of thumb, Fossen's otter.py)",
        "Y_vdot": "strip theory: -a22 L, a22 = rho pi T^2/2 (Faltinsen 1990; Fossen §6.4)",
        "Y_rdot": "strip theory, fore-aft symmetric strips: 0",
        "N_vdot": "strip theory, fore-aft symmetric strips: 0",
        "N_rdot": "strip theory: -a22 L^3/12",
        "X_u": f"10 % of resistance {R_top:.1f} N at 2.5 m/s "
        "(ITTC-57 C_F, 1+k=1.2, C_R=0.012 guessed for Fn=0.35)",
        "X_uu": "90 % of the same resistance, quadratic",
        "Y_v": "low-speed sway damping, time constant 3 s (otter.py approach, guessed T)",
        "Y_r": "0: no low-speed coupling assumed",
        "N_v": "0: no low-speed coupling assumed",
        "N_r": "low-speed yaw damping, time constant 3 s (otter.py approach, guessed T)",
        "Y_uv": f"{clarke}: Y'_v rho/2 L^2, C_B = {C_B:.3f} from displacement; {fin}",
        "Y_ur": f"{clarke}: Y'_r rho/2 L^3; {fin}",
        "N_uv": f"{clarke}: N'_v rho/2 L^3; {fin}",
        "N_ur": f"{clarke}: N'_r rho/2 L^4; {fin}",
        "Y_vv": "cross-flow drag, C_d = 1: -rho/2 T C_d L",
        "N_rr": "cross-flow drag, C_d = 1: -rho/2 T C_d L^4/32",
        "x_p": "stern propeller at -L/2",
        "Y_uudelta": "lift of the steered drive leg: -rho/2 A C_L_alpha, "
        "A = 0.06 m^2, C_L_alpha = 3/rad (guess)",
        "T_max": "thrust that gives the observed top speed 2.5 m/s (thesis: 4.9 kn with ballast)",
        "T_min": "0: the propeller can stop (standby)",
        "delta_max": "30 deg steering limit (guess, typical steerable drive)",
        "delta_rate_max": "30 deg/s steering rate limit (guess)",
        "T_thrust": "0.5 s thrust lag (guess: a small propeller spins up and down fast)",
        "T_delta": "0.3 s steering lag (guess)",
        "eps_abs": "smoothing of |.| (numerical choice, 0.01 m/s)",
        "u_max": "thesis: observed maximum 4.9 kn = 2.5 m/s with ballast",
        "X_uu_idle": f"idle drive, -rho/2 (C_prop A_E + C_leg A_leg): locked propeller C_prop = "
        f"{C_prop:g} on expanded blade area A_E = {A_E:.4f} m^2 (UFC 4-159-03 eq. 21; D = "
        f"{D_prop:g} m, EAR = {EAR:g}: guess) + drive leg C_leg = {C_leg:g} on frontal "
        f"{A_leg_x:g} m^2 (Hoerner 1965 ch. 6, streamlined strut; area a guess); docs/vessel.md",
        "actuation": "thesis §3.1: one propeller at the stern, steerable drive",
        "y_thr": "0: one drive on the centreline",
        "alpha_Y": "0: the low-speed sway damping Y_v is not faded (fading it at the monotone "
        "limit Y_uv / Y_v makes the hull much less course-stable at speed: Nomoto T 1.5 -> 2.9 s "
        "at 2.5 m/s); docs/vessel.md, Low-speed damping",
        "alpha_N": f"0: N_r not faded. Fossen 2021 §6.4 would fade it as exp(-alpha_N U), "
        f"alpha_N = N_ur / N_r = {alpha_N_fossen:.2f} s/m (more low-speed yaw authority), but the "
        "yaw schedule placed on that model makes eq. 3.1's turns pirouette; to be identified from "
        "low-speed turning logs (docs/vessel.md, Low-speed damping)",
        "T_idle": "idle drag blends out as exp(-(T/T_idle)^2): T_idle = 5 % of T_max, the thrust "
        "below which the propeller counts as stopped (n_p = 0)",
    }
    return values, prov


def write_gretha(path: Path | None = None) -> Path:
    """Write the default parameter file (``mpcasv/data/vessels/gretha.toml``)."""
    path = path or Path(__file__).resolve().parent.parent / "data" / "vessels" / "gretha.toml"
    values, prov = derive_gretha()
    header = (
        "# Gretha (Maritime Robotics Pioner 17): Fossen 3-DOF model parameters, SI units,\n"
        "# Fossen sign convention. DERIVED FROM DIMENSIONS, NOT FIELD-IDENTIFIED.\n"
        "# Generated by `python -m mpcasv.models.hull`; every number's provenance is in\n"
        "# [provenance]. Replace with `mpcasv identify` output once logs exist.\n"
    )
    rounded = {k: (round(v, 6) if isinstance(v, float) else v) for k, v in values.items()}
    path.write_text(header + tomli_w.dumps({**rounded, "provenance": prov}))
    return path


def stopping_table(params=None) -> str:
    """Markdown: coasting distance/time from 2.5 and 1.5 m/s, propeller off, and their
    sensitivity to the idle-drive inputs (``python -m mpcasv.models.hull --stopping``)."""
    from mpcasv.models.params import load_vessel
    from mpcasv.models.vessel import VesselModel

    base = params or load_vessel("gretha")
    rows = [("shipped (D 0.30 m, EAR 0.55, C_prop 1.0)", base.X_uu_idle)]
    for key, vals in (("C_prop", (0.8, 1.2)), ("D_prop", (0.25, 0.35)), ("EAR", (0.40, 0.70))):
        for v in vals:
            rows.append((f"{key} = {v:g}", idle_drag_coeff(**{**IDLE_DRIVE, key: v})))
    rows.append(("no idle drag (before issue 13)", 0.0))
    out = ["| idle drive | X_uu_idle (N s^2/m^2) | 2.5 m/s: to 0.5 / to 0.2 m/s | "
           "1.5 m/s: to 0.5 / to 0.2 m/s |", "|---|---|---|---|"]  # fmt: skip
    for label, X in rows:
        m = VesselModel(base.with_coeffs(X_uu_idle=X))
        cells = []
        for u0 in (2.5, 1.5):
            (d5, t5), (d2, t2) = m.stopping(u0, 0.5), m.stopping(u0, 0.2)
            cells.append(f"{d5:.1f} m, {t5:.0f} s / {d2:.1f} m, {t2:.0f} s")
        out.append(f"| {label} | {X:.2f} | {cells[0]} | {cells[1]} |")
    return "\n".join(out)


if __name__ == "__main__":
    import sys

    print(stopping_table() if "--stopping" in sys.argv[1:] else write_gretha())
