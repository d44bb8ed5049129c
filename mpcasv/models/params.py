"""Parameters of the Fossen 3-DOF vessel model (frozen, loaded from TOML with provenance).

Sign convention of Fossen (2021): hydrodynamic derivatives such as ``X_udot`` or ``N_r`` are
the partial derivatives of the force/moment, so added-mass and damping derivatives are
negative. ``Y_uv`` etc. are the speed-proportional parts of the linear sway/yaw damping
(Clarke 1982: Y_v = Y'_v * 0.5 rho L^2 U), so the total linear sway damping derivative is
``Y_v + Y_uv * U``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from mpcasv.config import ConfigError, Float, NonNeg, Pos, frozen, load_toml, parse, resolve

#: Coefficients that enter the equations of motion, in the order of the parameter vector
#: handed to the symbolic model (identification estimates a subset of these).
MODEL_COEFFS: tuple[str, ...] = (
    "m", "I_z", "x_g",
    "X_udot", "Y_vdot", "Y_rdot", "N_vdot", "N_rdot",
    "X_u", "X_uu", "Y_v", "Y_r", "N_v", "N_r",
    "Y_uv", "Y_ur", "N_uv", "N_ur", "Y_vv", "N_rr",
    "x_p", "Y_uudelta", "T_thrust", "T_delta", "eps_abs",
)  # fmt: skip


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
    delta_max: Pos  # steering angle limit (rad)
    delta_rate_max: Pos  # steering rate limit (rad/s)
    T_thrust: Pos  # thrust first-order lag (s)
    T_delta: Pos  # steering first-order lag (s)
    eps_abs: Pos  # smoothing of |.|: sabs(x) = sqrt(x^2 + eps^2) - eps (m/s or rad/s)
    u_max: Pos  # top speed at T_max in calm water (m/s); checked against the model
    provenance: dict[str, str] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        numeric = [f.name for f in dataclasses.fields(self) if f.name not in ("name", "provenance")]
        if self.provenance:
            missing = [k for k in numeric if k not in self.provenance]
            if missing:
                raise ValueError(f"provenance missing for {missing}")

    def vector(self) -> np.ndarray:
        """The model coefficients in :data:`MODEL_COEFFS` order."""
        return np.array([getattr(self, k) for k in MODEL_COEFFS], dtype=float)

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
    data = load_toml(path)
    try:
        return parse(VesselParams, data, path)
    except ValueError as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{path}: {exc}") from None
