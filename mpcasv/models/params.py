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


def load_vessel(name_or_path: str | Path = "gretha") -> VesselParams:
    """Load vessel parameters: a shipped name (``"gretha"``) or a TOML path.

    The TOML has the numbers at top level and a ``[provenance]`` table with one entry per
    number; a missing provenance entry is an error for shipped files.
    """
    path = resolve("vessels", name_or_path)
    data = load_toml(path, "vessel")
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
