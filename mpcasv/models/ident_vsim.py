"""The prior reshaped to DUNE VSIM's ASV structure for an identification through its thruster
map (:func:`vsim_structure`; :mod:`mpcasv.models.ident_thrust` fits the hull, which re-exports
these names)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mpcasv.models.params import VesselParams

if TYPE_CHECKING:
    from mpcasv.models.ident_thrust import ThrusterMap

#: lags of the written vessel (s): VSIM has none (the force follows the actuation at each
#: 0.04 s step); the simulator's model needs a positive lag, so a short one stands in (the
#: MPC's plan has no lags: it drives the set-points through their rates, and its RK4
#: sub-steps follow the hull's fastest pole, mpcasv.mpc.problem.OCP.n_sub)
LAG_S = 0.5
#: sway damping of the written vessel (N s/m): with Y_ur = m - X_udot the sway is never
#: forced, this only makes a disturbance decay (pole -Y_v / m, about -2 1/s for m = 30 kg)
Y_V = -60.0


def vsim_structure(prior: VesselParams, tmap: ThrusterMap) -> tuple[VesselParams, dict]:
    """The prior reshaped to DUNE VSIM's ASV structure, and the provenance of each held value.

    VSIM's ASV (``ASV.cpp``, ``Object.cpp``) has a diagonal inertia, no added mass, no
    Coriolis terms, linear + quadratic surge damping, linear yaw damping, no sway force at all
    (``v`` stays 0: ``|v| < 0.003 m/s`` in the Otter's log) and its engines at
    ``(x_e, y_i)``. In the shared model (Fossen's, with Coriolis terms) that is: no added
    mass, ``x_g = 0``, and ``Y_ur = m - X_udot``, which cancels the centripetal sway force
    ``-(m - X_udot) u r`` for ``u > 0`` (so ``v`` stays 0 and no Munk moment arises), plus a
    small sway damping :data:`Y_V`. Lags :data:`LAG_S`.
    """
    held = {
        "x_g": (0.0, "VSIM's ASV: inertia about the origin, no centre-of-gravity offset"),
        "X_udot": (0.0, "VSIM has no added mass: m is the identified total surge mass"),
        "Y_vdot": (0.0, "VSIM has no added mass (sway never excited: v = 0 in the log)"),
        "Y_rdot": (0.0, "VSIM has no added mass"),
        "N_vdot": (0.0, "VSIM has no added mass"),
        "N_rdot": (0.0, "VSIM has no added mass: I_z is the identified total yaw inertia"),
        "Y_v": (Y_V, "VSIM has no sway force (|v| < 0.003 m/s in the log); small damping so "
                "that a sway disturbance decays (pole about -2 1/s, stable in the MPC's RK4)"),
        "Y_r": (0.0, "VSIM: no sway-yaw coupling"), "N_v": (0.0, "VSIM: no sway-yaw coupling"),
        "Y_uv": (0.0, "VSIM: no speed-proportional damping"),
        "N_uv": (0.0, "VSIM: no speed-proportional damping"),
        "N_ur": (0.0, "VSIM: yaw damping linear (+ N_rr identified), not speed-proportional"),
        "Y_vv": (0.0, "VSIM: no sway drag"),
        "Y_uudelta": (0.0, "no steered leg (fixed thrusters)"),
        "alpha_Y": (0.0, "no low-speed fade"), "alpha_N": (0.0, "no low-speed fade"),
        "X_uu_idle": (0.0, "VSIM: no idle-propeller drag"),
        "T_thrust": (LAG_S, "VSIM has no thrust lag; a short 0.5 s lag stands in (the simulator's "
                     "model needs one; the MPC's plan has none)"),
        "T_delta": (LAG_S, "as T_thrust"),
        "x_p": (tmap.x, "thrusters' longitudinal position (Engine Position), " + tmap.source),
    }
    values = {k: v for k, (v, _) in held.items()}
    values["T_idle"] = None
    values["Y_ur"] = prior.m - 0.0
    shaped = prior.with_coeffs(**values)
    prov = {k: f"held (DUNE VSIM structure): {why}" for k, (_, why) in held.items()}
    prov["Y_ur"] = ("= m - X_udot (tied to the identified m): cancels the model's centripetal "
                    "sway force -(m - X_udot) u r for u > 0, which VSIM (no Coriolis terms, "
                    "v = 0 in the log) does not have")
    return shaped, prov
