"""The deploy configuration's limits (:mod:`mpcasv.io.config` holds the file, the vehicles and
the link): the watchdogs' limits and input plausibility checks (``[watchdog]``) and the
achieved-speed watch (``[speed]``). Field by field in ``docs/deploy.md``.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, Strict, model_validator

from mpcasv.config import (
    AUV_SPEED_MAX,
    DISTANCE_MAX,
    TRANSIT_SPEED_MAX,
    NonNeg,
    Pos,
    between,
    frozen,
)

__all__ = ["SpeedSpec", "WatchdogSpec"]


@frozen
class WatchdogSpec:
    """Limits (s of the deploy clock, m, m/s) and input plausibility checks."""

    # no ASV state for this long: stop commanding, report. DUNE's stock vehicles send their
    # EstimatedState about twice a second (shared/data/dune-traffic): 0.001 s made every gap
    # a verdict (298 plan starts in 15 s), 1e5 s switched the watchdog off
    asv_stale_s: between(1, 60, "s", "DUNE sends its state about twice a second; a minute "
                         "without it is no watchdog") = 3.0
    # AUV state older: uncertain (radius grows with its age); under water, with acoustic
    # status reports every 30 s or more, tens of seconds (docs/deploy.md)
    auv_stale_s: between(0.5, 600, "s", "ten minutes without a word is no watchdog") = 3.0
    auv_lost_s: between(1, 3600, "s", "an hour without a word is no watchdog") = 30.0
    # how fast an AUV may move away from its last state (jump check; the uncertain disc
    # grows at it). 1e9 m/s made the jump check and the guard meaningless
    auv_speed_max: between(0.1, AUV_SPEED_MAX, "m/s", "a glider makes 0.25 m/s; 5 m/s is "
                           "the fastest AUV, as in a scenario") = 2.0
    auv_rise_rate: NonNeg = 0.5  # how fast it may rise (m/s) towards the surface
    # faster apparent motion is rejected as a jump (1e-9 m/s: every transit a jump)
    asv_speed_max: between(1, 2 * TRANSIT_SPEED_MAX, "m/s", "below 1 m/s, slower than a "
                           "transit, the ASV's own motion over a gap in its states is a jump; "
                           "beyond 40 knots the jump check is off") = 6.0
    # GPS/nav slack added to speed x dt in the jump check (1e12 m switched it off)
    jump_margin_m: between(0, 1000, "m", "a navigation error beyond a kilometre is no "
                           "position: the jump check would be off") = 50.0
    # states further from the origin are rejected (1e-9 m: every state)
    max_distance_m: between(100, DISTANCE_MAX, "m", "below 100 m the ASV's own manoeuvres "
                            "leave the area; beyond, what the fastest AUV covers in a "
                            "week") = 20000.0
    # a timestamp may run ahead of the arrival clock by this (1e12 s switched the time check
    # off)
    clock_slack_s: between(0.5, 60, "s", "below half a second arrival jitter makes time "
                           "jumps and no clock step is proven; beyond a minute the time check "
                           "is off, and DUNE steps a clock more than 4 s off") = 5.0
    # self-consistent states on a new time base that prove a vehicle clock step (re-anchor);
    # each is a state rejected before it (100000: a clock step never recovered)
    clock_step_states: between(2, 20, "", "each is a state rejected before the re-anchor: "
                               "20 at DUNE's 2 Hz are 10 s without the vehicle's state",
                               integer=True) = 3
    propeller: Literal["thruster", "command"] = "thruster"  # where propeller_on comes from
    propeller_on_threshold: Annotated[float, Strict(), Field(gt=0, lt=1)] = 0.05
    report_sigma_m: NonNeg = 1.0  # 1-sigma of an AUV's own navigation (Report.nav_sigma)
    keep_out_m: Pos = 50.0  # keep-out sphere for controllers without a domain (m)
    guard_margin_m: NonNeg = 10.0  # clearance beyond the grown radius when moving away
    guard_speed: Pos = 1.5  # m/s of a guard transit when the controller commanded none

    @model_validator(mode="after")
    def _order(self) -> WatchdogSpec:
        if self.auv_lost_s <= self.auv_stale_s:
            raise ValueError("auv_lost_s must be longer than auv_stale_s")
        return self


@frozen
class SpeedSpec:
    """Achieved vs commanded speed of the ASV (:class:`mpcasv.io.asvwatch.SpeedWatch`).

    While the same transit speed has been commanded for ``window_s``, the achieved speed is
    the mean over that window of the speed over ground (``|(vx, vy)|``) and through the
    water (``u``); a shortfall is ``achieved < ratio x commanded``. ``persist_s`` of shortfall
    in a row make it persistent (event ``speed_shortfall``); the achievable speed is then the
    achieved one, and ``controller.speed_feedback`` caps the controller's speed with it
    (unless the boat makes no way, event ``speed_no_way``: :class:`mpcasv.io.asvwatch.
    SpeedWatch`). A dry run commands no speed: nothing is judged.
    """

    window_s: Pos = 10.0
    ratio: Annotated[float, Strict(), Field(gt=0, le=1)] = 0.8
    persist_s: Pos = 10.0
    settle_s: NonNeg = 5.0  # after a change of commanded speed, before the window opens
    # the autopilot's own limit (DUNE: [General] Maximum Absolute Speed, 2.5 m/s for the
    # Otter): every transit speed sent is capped at it (a plan may ask for the model's u_max)
    command_max: between(0, TRANSIT_SPEED_MAX, "m/s", "the Otter's is 2.5 m/s; 10 m/s is "
                         "the fastest transit a controller may ask for", lo_open=True
                         ) | None = None  # fmt: skip
