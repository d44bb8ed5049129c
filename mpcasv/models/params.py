"""Parameters of the Fossen 3-DOF vessel model (frozen, loaded from TOML with provenance).

Sign convention of Fossen (2021): hydrodynamic derivatives such as ``X_udot`` or ``N_r`` are
the partial derivatives of the force/moment, so added-mass and damping derivatives are
negative. ``Y_uv`` etc. are the speed-proportional parts of the linear sway/yaw damping
(Clarke 1982: Y_v = Y'_v * 0.5 rho L^2 U), so the total linear sway damping derivative is
``Y_v + Y_uv * U``.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, Strict

from mpcasv.config import (
    ConfigError,
    FieldError,
    Float,
    NonNeg,
    Pos,
    between,
    frozen,
    load_toml,
    parse,
    resolve,
)

#: Coefficients that enter the equations of motion, in the order of the parameter vector
#: handed to the symbolic model (identification estimates a subset of these).
MODEL_COEFFS: tuple[str, ...] = (
    "m", "I_z", "x_g",
    "X_udot", "Y_vdot", "Y_rdot", "N_vdot", "N_rdot",
    "X_u", "X_uu", "Y_v", "Y_r", "N_v", "N_r",
    "Y_uv", "Y_ur", "N_uv", "N_ur", "Y_vv", "N_rr",
    "x_p", "Y_uudelta", "T_thrust", "T_delta", "eps_abs",
    "X_uu_idle", "T_idle", "k_diff", "N_diff", "alpha_Y", "alpha_N",
)  # fmt: skip

#: actuation kinds a vessel file can name (``actuation = "..."``; docs/vessel.md)
ACTUATIONS = ("steerable", "differential")


@frozen
class VesselParams:
    """Fossen 3-DOF model parameters of one vessel (SI units, Fossen sign convention).

    Attributes are documented in the shipped ``mpcasv/data/vessels/gretha.toml``; each value
    there carries its provenance in the ``[provenance]`` table.
    """

    name: str
    L: Pos  # length (m)
    B: Pos  # beam (m)
    T_draft: Pos  # draught (m)
    m: Pos  # mass incl. ballast (kg)
    I_z: Pos  # yaw moment of inertia about CO (kg m^2)
    x_g: Float  # longitudinal centre of gravity, + forward of CO (m)
    X_udot: Float  # added mass in surge (kg), <= 0
    Y_vdot: Float
    Y_rdot: Float
    N_vdot: Float
    N_rdot: Float
    X_u: Float  # linear surge damping (N s/m), < 0
    X_uu: Float  # quadratic surge damping X_|u|u (N s^2/m^2), < 0
    Y_v: Float  # low-speed linear sway damping (N s/m)
    Y_r: Float
    N_v: Float
    N_r: Float
    Y_uv: Float  # speed-proportional linear damping (Clarke): Y_v(U) = Y_v + Y_uv U
    Y_ur: Float
    N_uv: Float
    N_ur: Float
    Y_vv: Float  # cross-flow drag Y_|v|v
    N_rr: Float  # N_|r|r
    x_p: Float  # propeller position (m), negative = aft of CO
    Y_uudelta: Float  # side force of the steered drive leg per |u|u delta (N s^2/m^2/rad), < 0
    T_max: Pos  # maximum propeller thrust (N)
    T_min: NonNeg  # minimum thrust when running (N); 0 = the propeller can stop
    # steering angle limit (rad; at most 90 deg: 30 given in degrees crashed `tune yaw` with
    # a traceback and passed `deploy --prepare`)
    delta_max: between(0, math.pi / 2, "rad", "90 deg; radians, not degrees", lo_open=True)
    # steering rate limit (rad/s; at most 2 pi: a turn of the drive a second)
    delta_rate_max: between(0, 2 * math.pi, "rad/s", "a full turn a second; radians, not "
                            "degrees", lo_open=True)
    T_thrust: Pos  # thrust first-order lag (s)
    T_delta: Pos  # steering first-order lag (s)
    eps_abs: Pos  # smoothing of |.|: sabs(x) = sqrt(x^2 + eps^2) - eps (m/s or rad/s)
    u_max: Pos  # top speed at T_max in calm water (m/s); checked against the model
    # Idle drive (optional; docs/vessel.md): quadratic surge drag of the stopped propeller and
    # the drive leg, X_uu_idle |u_r| u_r exp(-(T/T_idle)^2), <= 0 (N s^2/m^2). Default 0: a
    # file without it has no idle drag (as third-party files written before it existed).
    X_uu_idle: Annotated[float, Strict(), Field(le=0)] = 0.0
    T_idle: Pos | None = None  # thrust over which the idle drag blends out (N); needed if != 0
    # Actuation (optional; docs/vessel.md): "steerable" = one steerable drive at x_p (default);
    # "differential" = two fixed thrusters at (x_p, -+y_thr) (the Otter): T is their sum and
    # the second input, in [-delta_max, delta_max], their difference T_port - T_stbd =
    # T_max delta / delta_max.
    actuation: Literal["steerable", "differential"] = "steerable"
    y_thr: NonNeg = 0.0  # lateral offset of each thruster from the centreline (m)
    # Fade of the low-speed linear damping (optional; docs/vessel.md): the constant sway terms
    # (Y_v, Y_r) are multiplied by exp(-alpha_Y U_r), the yaw terms (N_v, N_r) by
    # exp(-alpha_N U_r), so that they do not double-count the speed-proportional (Clarke)
    # damping at speed (Fossen 2021 §6.4). s/m, >= 0; default 0: no fade.
    alpha_Y: NonNeg = 0.0
    alpha_N: NonNeg = 0.0
    provenance: dict[str, str] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.actuation == "differential" and self.y_thr <= 0:
            raise ValueError("actuation = 'differential' needs y_thr > 0 (thruster offset, m)")
        if self.X_uu_idle != 0.0 and self.T_idle is None:
            raise ValueError("X_uu_idle given without T_idle (the thrust that blends it out, N)")
        check_physics(self)
        numeric = [f.name for f in dataclasses.fields(self) if f.name not in ("name", "provenance")]
        if self.X_uu_idle == 0.0 and self.T_idle is None:  # optional pair, absent: the default
            numeric = [k for k in numeric if k not in ("X_uu_idle", "T_idle")]
        numeric = [k for k in numeric if k != "actuation"]
        fades = ("alpha_Y", "alpha_N")  # optional, absent when 0
        numeric = [k for k in numeric if not (k in fades and getattr(self, k) == 0)]
        if self.actuation == "steerable" and self.y_thr == 0.0:  # optional, absent
            numeric = [k for k in numeric if k != "y_thr"]
        if self.provenance:
            missing = [k for k in numeric if k not in self.provenance]
            if missing:
                raise ValueError(f"provenance missing for {missing}")

    @property
    def k_diff(self) -> float:
        """1 for differential thrust, 0 for the steerable drive (a switch in the model)."""
        return 1.0 if self.actuation == "differential" else 0.0

    @property
    def N_diff(self) -> float:
        """Yaw moment per unit of the second input, differential thrust (N m/rad):
        ``y_thr T_max / delta_max`` (0 for the steerable drive)."""
        return self.k_diff * self.y_thr * self.T_max / self.delta_max

    def vector(self) -> np.ndarray:
        """The model coefficients in :data:`MODEL_COEFFS` order.

        Without idle drag (``X_uu_idle = 0``) an absent ``T_idle`` enters as 1 N: it only
        scales a term that is multiplied by zero.
        """
        vals = {k: getattr(self, k) for k in MODEL_COEFFS}
        if vals["T_idle"] is None:
            vals["T_idle"] = 1.0
        return np.array([vals[k] for k in MODEL_COEFFS], dtype=float)

    def with_coeffs(self, **values: float) -> VesselParams:
        """A copy with some coefficients changed (provenance dropped: it no longer holds)."""
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        data.update(values)
        data["provenance"] = {}
        return parse(VesselParams, data, f"{self.name} override")


#: diagonal added-mass derivatives (kg, kg, kg m^2): each <= 0 in Fossen's convention
ADDED_MASS_DIAGONAL = ("X_udot", "Y_vdot", "N_rdot")
#: damping derivatives of surge, sway and yaw each alone from rest (linear N s/m, N m s/rad;
#: quadratic N s^2/m^2, N m s^2/rad^2): each <= 0 in Fossen's convention
DAMPING_AT_REST = ("X_u", "Y_v", "N_r", "X_uu", "Y_vv", "N_rr")


def check_physics(p: VesselParams) -> None:
    """Refuse parameters that no hull has, whatever its size (run on every
    :class:`VesselParams`, so at every load: ``load_vessel``, scenarios, suites, ``--vessel``).

    1. Added mass: ``X_udot, Y_vdot, N_rdot <= 0``. The added mass of a body in an ideal fluid
       is ``M_A = M_A^T >= 0`` (Fossen 2021 §6.3; its diagonal is the fluid's kinetic energy
       per unit velocity squared), and ``M_A = -[[X_udot, ...]]`` in Fossen's convention: a
       positive derivative is the added mass entered with the other sign.
    2. Rigid body: ``I_z > m x_g^2``. ``I_z`` is about the body origin CO, ``I_z = I_g + m
       x_g^2`` (parallel-axis theorem), so ``M_RB = M_RB^T > 0`` (Fossen 2021 §3.3).
    3. The model's mass matrix ``M = M_RB + M_A`` (:func:`~mpcasv.models.vessel.mass_matrices`,
       the one definition) is positive definite: ``nu^T M nu > 0`` for every ``nu != 0``
       (kinetic energy; ``M`` invertible). After 1 and 2 only the off-diagonal ``Y_rdot,
       N_vdot`` can break it. ``M`` need not be symmetric (``Y_rdot != N_vdot`` in empirical
       fits, e.g. Clarke et al. 1982): its symmetric part is what is checked.
    4. Damping from rest: ``X_u, Y_v, N_r, X_uu, Y_vv, N_rr <= 0``. Surging, swaying or yawing
       alone from rest (no speed-proportional terms: ``U = 0``) the damping must take energy
       out, at every amplitude (Fossen 2021 §6.4). The cross terms ``Y_r, N_v`` are not
       checked: published models (CyberShip II) have a non-symmetric linear damping whose
       symmetric part is indefinite.

    2b. ``I_g = I_z - m x_g^2 <= m (L^2 + B^2) / 4``: every mass lies within the hull's
       length and beam, and the variance of a distribution on an interval of length ``L`` is
       at most ``L^2 / 4`` (Popoviciu's inequality), in x and in y. A mass entered in tonnes
       (m = 1.4 beside I_z = 1537.9) breaks it by a factor of 100 or more; gretha's radius
       of gyration is 1.28 m against its bound 2.81 m, the Otters' 0.43 / 0.62 m against
       1.14 m.

    No range is imposed on ``m`` or ``I_z`` themselves (a 2-kg model ship is legitimate).

    Raises
    ------
    FieldError
        One line naming the field(s), their values and the rule.
    """
    import numpy as np

    from mpcasv.models.vessel import mass_matrices

    bad = [k for k in ADDED_MASS_DIAGONAL if getattr(p, k) > 0]
    if bad:
        vals = ", ".join(f"{k} = {getattr(p, k):+.6g}" for k in bad)
        fix = ", ".join(f"{k} = {-getattr(p, k):.6g}" for k in bad)
        total = {"X_udot": ("m - X_udot", p.m, "kg"), "Y_vdot": ("m - Y_vdot", p.m, "kg"),
                 "N_rdot": ("I_z - N_rdot", p.I_z, "kg m^2")}
        lost = [f"{total[k][0]} = {total[k][1] - getattr(p, k):.6g} {total[k][2]} <= 0"
                for k in bad if total[k][1] - getattr(p, k) <= 0]
        raise FieldError(bad[0], f"{vals}: added-mass derivatives are <= 0 in Fossen's "
                         "convention (the added masses -X_udot, -Y_vdot, -N_rdot are >= 0; a "
                         "positive value is usually the added mass itself, entered without "
                         "the minus)" + (f", and {', '.join(lost)} leaves the mass matrix "
                                         "not positive definite" if lost else "")
                         + f": did you mean {fix}?")
    if p.I_z <= p.m * p.x_g * p.x_g:
        raise FieldError("I_z", f"I_z = {p.I_z:g} kg m^2 is not above m x_g^2 = "
                         f"{p.m * p.x_g * p.x_g:.6g} kg m^2 (m = {p.m:g} kg, x_g = {p.x_g:g} m): "
                         "I_z is the yaw inertia about the body origin, I_g + m x_g^2 "
                         "(parallel-axis theorem), so the rigid-body mass matrix would not be "
                         "positive definite; check I_z (kg m^2), m (kg) and x_g (m)")
    k_g = math.sqrt((p.I_z - p.m * p.x_g * p.x_g) / p.m)  # radius of gyration about CG (m)
    if k_g > math.hypot(p.L, p.B) / 2:
        raise FieldError("I_z", f"I_z = {p.I_z:g} kg m^2 with m = {p.m:g} kg gives a yaw radius "
                         f"of gyration about the centre of gravity sqrt((I_z - m x_g^2) / m) = "
                         f"{k_g:.4g} m, above sqrt(L^2 + B^2) / 2 = "
                         f"{math.hypot(p.L, p.B) / 2:.4g} m, the most a mass inside an L x B = "
                         f"{p.L:g} m x {p.B:g} m hull can have; check the units (m in kg, not "
                         "tonnes; I_z in kg m^2)")
    M_RB, M_A = mass_matrices({k: float(getattr(p, k)) for k in
                               ("m", "I_z", "x_g", *ADDED_MASS_DIAGONAL, "Y_rdot", "N_vdot")})
    M = np.array(M_RB + M_A, dtype=float)
    lam = float(np.linalg.eigvalsh(0.5 * (M + M.T)).min())
    if not lam > 0:
        off = [k for k in ("Y_rdot", "N_vdot") if getattr(p, k) != 0] or ["x_g"]
        raise FieldError(off[0], "mass matrix M = M_RB + M_A is not positive definite "
                         f"(smallest eigenvalue of its symmetric part {lam:.4g}): the sway-yaw "
                         f"coupling m x_g - Y_rdot = {M[1, 2]:.6g}, m x_g - N_vdot = "
                         f"{M[2, 1]:.6g} is too large for m - Y_vdot = {M[1, 1]:.6g} kg and "
                         f"I_z - N_rdot = {M[2, 2]:.6g} kg m^2; check Y_rdot, N_vdot (kg m) and "
                         "x_g")
    bad = [k for k in DAMPING_AT_REST if getattr(p, k) > 0]
    if bad:
        vals = ", ".join(f"{k} = {getattr(p, k):+.6g}" for k in bad)
        raise FieldError(bad[0], f"{vals}: damping derivatives X_u, Y_v, N_r, X_uu, Y_vv, "
                         "N_rr are <= 0 in Fossen's convention (with a positive one the hull "
                         "gains energy surging, swaying or yawing from rest)")


def load_vessel(name_or_path: str | Path = "gretha") -> VesselParams:
    """Load vessel parameters: a shipped name (``"gretha"``) or a TOML path.

    The TOML has the numbers at top level and a ``[provenance]`` table with one entry per
    number; a missing provenance entry is an error for shipped files. A file written by
    ``mpcasv identify`` has an ``[identification]`` table: one whose validation failed is
    refused unless it says ``use_anyway = true``
    (:func:`mpcasv.models.ident_record.check_identification`).
    """
    from mpcasv.models.ident_record import TABLE, check_identification

    path = resolve("vessels", name_or_path)
    data = load_toml(path, "vessel")
    check_identification(data.pop(TABLE, None), Path(path).read_text(errors="replace"), path)
    try:
        params = parse(VesselParams, data, path)
    except ValueError as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{path}: {exc}") from None
    check_limits(params, path)
    return params


def check_limits(params: VesselParams, source: str | Path) -> None:
    """Refuse a declared top speed ``u_max`` that the model's own top speed at ``T_max``
    contradicts by more than :data:`mpcasv.models.vessel.U_MAX_TOLERANCE` (relative).

    Raises
    ------
    ConfigError
        One line naming the file, both speeds and the tolerance.
    """
    from mpcasv.models.vessel import U_MAX_TOLERANCE, top_speed

    try:
        u_model = top_speed(params)
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    if abs(u_model / params.u_max - 1.0) > U_MAX_TOLERANCE:
        raise ConfigError(
            f"{source}: declared u_max = {params.u_max:g} m/s but the model reaches "
            f"{u_model:.3g} m/s at T_max = {params.T_max:g} N (tolerance "
            f"{100 * U_MAX_TOLERANCE:g} %): fix T_max, u_max or the surge resistance"
        )
