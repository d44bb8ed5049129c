"""Parameters of the execution level, loaded from TOML (``mpcasv/data/execution``)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, Strict, model_validator

from mpcasv.config import Float, NonNeg, Pos, frozen, load, resolve


@frozen
class YawSchedule:
    """Yaw PID gains scheduled on surge speed (linear interpolation, clamped at the ends).

    delta = Kp (psi_d - psi) + Ki * integral(psi_d - psi) - Kd * r_f, with r_f the measured
    yaw rate through a first-order filter of time constant ``T_f``.
    """

    speeds: tuple[Pos, ...]  # m/s, strictly increasing
    Kp: tuple[NonNeg, ...]  # rad/rad
    Ki: tuple[NonNeg, ...]  # rad/(rad s)
    Kd: tuple[NonNeg, ...]  # rad/(rad/s)
    T_f: Pos = 0.5  # derivative (yaw-rate) filter time constant (s)

    @model_validator(mode="after")
    def _check(self) -> YawSchedule:
        n = len(self.speeds)
        if n == 0 or any(len(g) != n for g in (self.Kp, self.Ki, self.Kd)):
            raise ValueError("speeds, Kp, Ki and Kd must be non-empty and of equal length")
        if any(b <= a for a, b in zip(self.speeds, self.speeds[1:], strict=False)):
            raise ValueError("speeds must be strictly increasing")
        return self


@frozen
class SpeedLoop:
    """Surge speed loop: thrust = trim thrust(u_ref) + Kp (u_ref - u) + Ki integral."""

    Kp: NonNeg  # N/(m/s)
    Ki: NonNeg  # N/(m/s s)


@frozen
class SpeedReference:
    """Surge-speed reference model, thesis eq. 3.1 (u_ff feed-forward, k_u gain)."""

    u_ff: NonNeg = 0.6  # m/s
    k_u: NonNeg = 1.59  # m/s


@frozen
class ExecutionParams:
    """Everything the execution level needs besides the vessel model."""

    yaw: YawSchedule
    speed: SpeedLoop
    reference: SpeedReference = SpeedReference()
    propeller_on_threshold: Float = 0.05  # fraction of T_max above which n_p != 0 (~22 % rpm)
    # Fraction of T_max: the MPC's least thrust in transit (its deadband cost,
    # mpcasv/mpc/problem.py). The execution level's own floor is sized from the model
    # (mpcasv.control.steering.lock_thrust, docs/tuning.md "Thrust floor and eq. 3.1").
    thrust_floor: Annotated[float, Strict(), Field(ge=0, lt=1)] = 0.075
    # Steering-authority criterion of the full-lock thrust floor (rad/s): turn 90 deg within
    # (alpha - 1) T0 = 20 s (r_inner = alpha T0 rdot_max, Paper 1 field alpha = 5, T0 = 5 s:
    # one fix period lost to latency), i.e. (pi/2) / 20 s = 4.5 deg/s (docs/tuning.md).
    r_steer: NonNeg = math.radians(4.5)
    # "Power turn" (fraction of T_max): a thrust floor that ramps from 0 to ``turn_thrust``
    # as |psi_e| grows from pi/4 to pi/2. It OVERRIDES eq. 3.1 (it can hold the boat above
    # u_ff in a hard turn), so it is off by default; Gretha's file keeps it at 0.8 because
    # without it her derived (not identified) hull turns too slowly at low speed and the
    # pursuer Cases 4 and 8 collide (docs/tuning.md, "Thrust floor and eq. 3.1").
    turn_thrust: Annotated[float, Strict(), Field(ge=0, le=1)] = 0.0
    # Where the power turn acts: "all" transits, or only "avoidance" transits: escapes, the
    # ASV inside a collision domain now, decided by the world from the true ranges for
    # every controller and the SITL alike (World.advance; a command's reason never reaches
    # the plant), which keeps eq. 3.1 true in every tracking turn (docs/tuning.md, "Why
    # Case 4 and Case 8 still collide").
    turn_scope: Literal["all", "avoidance"] = "all"
    provenance: str = ""


def load_execution(name_or_path: str | Path = "gretha") -> ExecutionParams:
    """Load execution-level parameters: a shipped name or a TOML path.

    Raises
    ------
    mpcasv.config.ConfigError
        Unknown name or missing file (the shipped names listed), or an invalid file.
    """
    path = resolve("execution", name_or_path)
    return load(ExecutionParams, path, "execution")
