"""Why a hull's linearised sway-yaw block has no first-order Nomoto model: the words of
``mpcasv tune yaw``'s one-line refusals (:func:`mpcasv.control.tuning_yaw.nomoto`), derived
from the model's own Jacobians and the vessel file's terms (docs/tuning.md, "Tuning any
hull")."""

from __future__ import annotations

import numpy as np

from mpcasv.models.vessel import IX


def no_first_order(A: np.ndarray, u0: float, K: float, T: float, pol: str, poles, P) -> str:
    """Why ``r/delta`` at ``u0`` has no first-order Nomoto form, from the linearised model
    ``A``: a zero steady turn gain (``r/delta`` has a zero at ``s = 0``: a constant steering
    angle gives no steady yaw rate, though the steering moves the yaw acceleration,
    ``b_r = dr_dot/d delta``), or ``T = T1 + T2 - T3 = 0``; with the sway-yaw poles and, for
    Fossen's Otter, the vessel file's ``Y_v = 0`` (no linear sway damping)."""
    b_r, a_vv = A[IX["r"], IX["delta"]], A[IX["v"], IX["v"]]
    rhp = "one in the right half-plane (course-unstable)" if np.any(poles.real > 0) else "stable"
    why = (f"the steady turn gain r/delta(s=0) is zero (K = {K:.2g} 1/s: r/delta has a zero at "
           "s = 0), so a held steering angle gives no steady yaw rate, although the steering "
           f"acts on the yaw acceleration ({b_r:.3g} rad/s^2 per rad)" if abs(K) < 1e-12 else
           f"its first-order time constant T = T1 + T2 - T3 = {T:.3g} s is zero")  # fmt: skip
    damp = f"; linearised sway a_vv = {a_vv:+.3g} 1/s" + (
        f" (Y_v = {P.Y_v:g} in the vessel file: no linear sway damping)" if P.Y_v == 0 else "")
    return (f"at u0={u0:g} m/s {why}; sway-yaw poles {pol} 1/s, {rhp}{damp}: no first-order "
            "Nomoto model K/(1 + T s) to place the PID on; no schedule written")


def sway_yaw_why(a: np.ndarray, P) -> str:
    """Why the linearised sway-yaw block ``a`` (``[[a_vv, a_vr], [a_rv, a_rr]]``) has complex or
    zero poles, in its own entries (true for any 2x2 block: the poles are
    ``(a_vv + a_rr)/2 +- sqrt(((a_vv - a_rr)/2)^2 + a_vr a_rv)``, complex when the coupling
    product is below ``-((a_vv - a_rr)/2)^2``, zero when the determinant is), with the vessel
    file's mass terms that set it (``M = M_RB + M_A``, Fossen 2021 §6.3)."""
    (a_vv, a_vr), (a_rv, a_rr) = a
    half = ((a_vv - a_rr) / 2) ** 2
    if a_vr * a_rv < -half:
        why = (f"the coupling a_vr a_rv = {a_vr:.3g} m/s x {a_rv:.3g} 1/(m s) = "
               f"{a_vr * a_rv:.3g} 1/s^2 is below -((a_vv - a_rr)/2)^2 = {-half:.3g} 1/s^2 "
               f"(a_vv = {a_vv:.3g}, a_rr = {a_rr:.3g} 1/s)")
    else:
        why = (f"the block's determinant a_vv a_rr - a_vr a_rv = {a_vv * a_rr - a_vr * a_rv:.3g} "
               "1/s^2 is zero")
    return (f"{why}; mass terms: m = {P.m:g} kg, added -X_udot = {-P.X_udot:g} kg, -Y_vdot = "
            f"{-P.Y_vdot:g} kg, I_z = {P.I_z:g} kg m^2, -N_rdot = {-P.N_rdot:g} kg m^2, "
            f"x_g = {P.x_g:g} m")
