"""The deploy configuration's sections about the run itself (:mod:`mpcasv.io.config` holds the
file, the vehicles, the link and the limits): which controller runs and how (``[controller]``),
the clock it runs on (``[clock]``) and what it logs (``[log]``). Field by field in
``docs/deploy.md``.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, Strict, field_validator

from mpcasv.config import CONTROL_PERIOD_MAX, Flag, Pos, frozen

__all__ = ["ClockSpec", "ControllerSpec", "LogSpec"]

#: the shortest deploy control period (s): 0.001 s was accepted
CONTROL_PERIOD_MIN = 0.1


@frozen
class ControllerSpec:
    """The supervisory controller, as in the simulator (same registry, same presets)."""

    name: str
    preset: str | None = None  # shipped preset name or TOML path (default: the kind's)
    estimator: str = "perfect"
    # s between decisions (the papers' timers count seconds); at least CONTROL_PERIOD_MIN
    control_period: Pos = 1.0
    scenario: str | None = None  # scenario TOML: the AUVs' plans, for "plan" only (refused else)
    overrides: dict[str, Any] = Field(default_factory=dict)
    # the boat in the water (shipped vessel name or TOML path): controllers that plan with a
    # vessel model (preset field 'vessel', the MPCs) get it as an override; None: the preset's
    vessel: str | None = None
    # feed the learned achievable speed back into the controller's 'speed' (config.SpeedSpec)
    speed_feedback: Flag = False
    # the observation's actuators from DUNE's set-points, thrust proportional to them
    # (asvwatch.dune_actuators); false for a boat whose thrust is not (a vessel identified
    # through DUNE's thruster map, as dune-otter): the controller then does without
    actuator_feedback: Flag = True

    @field_validator("control_period")
    @classmethod
    def _period(cls, v: float) -> float:
        if v < CONTROL_PERIOD_MIN:
            raise ValueError(f"{v:g} s: a control period is at least {CONTROL_PERIOD_MIN:g} s "
                             "(DUNE's stock vehicles send their state about twice a second: "
                             "faster decisions see the same state)")  # fmt: skip
        if v > CONTROL_PERIOD_MAX:
            raise ValueError(f"{v:g} s: a control period is at most {CONTROL_PERIOD_MAX:g} s "
                             "(the papers' is 1 s)")  # fmt: skip
        return v


@frozen
class ClockSpec:
    """``speedup`` > 1 only against a SITL started with the same ``--speedup``."""

    speedup: Pos = 1.0

    @field_validator("speedup")
    @classmethod
    def _speedup(cls, v: float) -> float:
        from mpcasv.io.sitloptions import SPEEDUP_MAX, SPEEDUP_MIN

        if not SPEEDUP_MIN <= v <= SPEEDUP_MAX:
            raise ValueError(f"{v:g}: a clock factor is in [{SPEEDUP_MIN:g}, {SPEEDUP_MAX:g}] "
                             "(1: real time)")  # fmt: skip
        return v


@frozen
class LogSpec:
    dir: str = "runs/deploy"
    flush_s: Annotated[float, Strict(), Field(gt=0, le=1.0)] = 0.5  # wall seconds
    reject_log_per_s: Annotated[int, Strict(), Field(ge=1)] = 50  # detailed lines per reason
    # imc.lsf: "used" = the packets the deploy decodes and everything it sends; "all" = also
    # every other datagram received (DUNE's bus traffic: about 2.5 MB/min from two vehicles)
    lsf: Literal["all", "used"] = "used"
    load_report_s: Pos = 60.0  # a 'load' event (datagrams/s, CPU) this often (deploy clock)
