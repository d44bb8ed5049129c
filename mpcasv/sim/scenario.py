"""Scenario files (TOML under ``experiments/scenarios/``), validated up front.

A scenario says where the ASV starts, which AUVs there are and what they do, the current,
the acoustic channel, the estimator and how long to simulate. Unknown keys, missing fields,
non-numeric values and impossible numbers are refused with the file and field named.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Literal

from pydantic import model_validator

from mpcasv.config import (
    ConfigError,
    Float,
    NonNeg,
    Pos,
    PosInt,
    anchor,
    frozen,
    is_path,
    load_toml,
    parse,
)
from mpcasv.models.acoustics import AcousticParams, NavParams
from mpcasv.models.auv import AUVLimits
from mpcasv.models.behaviours import Plan, Pursuer, Scripted, Transit, lawnmower
from mpcasv.sim.uncertainty import Uncertain, check_uncertain


@frozen
class Start:
    N: Float = 0.0  # m
    E: Float = 0.0  # m
    psi_deg: Float = 0.0
    depth: NonNeg = 0.0  # m
    speed: NonNeg = 0.0  # m/s


@frozen
class LawnmowerSpec:
    origin: tuple[Float, Float]
    length: Pos
    spacing: NonNeg
    legs: PosInt
    heading_deg: Float = 0.0
    depth: NonNeg = 0.0
    turn: Literal["right", "left"] = "right"


@frozen
class Segment:
    """One piece of a route: explicit waypoints ``[[N, E, depth], ...]`` or a lawnmower."""

    waypoints: tuple[tuple[Float, Float, NonNeg], ...] | None = None
    lawnmower: LawnmowerSpec | None = None

    @model_validator(mode="after")
    def _one(self) -> Segment:
        if (self.waypoints is None) == (self.lawnmower is None):
            raise ValueError("a route segment needs exactly one of 'waypoints' or 'lawnmower'")
        return self

    def points(self):
        if self.lawnmower is not None:
            lm = self.lawnmower
            return lawnmower(lm.origin, lm.heading_deg, lm.length, lm.spacing, lm.legs,
                             lm.depth, lm.turn)  # fmt: skip
        return list(self.waypoints)


@frozen
class PlanSpec:
    speed: Pos
    route: tuple[Segment, ...]
    acceptance: Pos = 5.0
    yoyo: tuple[NonNeg, NonNeg] | None = None
    surface: tuple[tuple[NonNeg, NonNeg], ...] = ()
    surface_speed: NonNeg = 0.0

    @model_validator(mode="after")
    def _check(self) -> PlanSpec:
        if not self.route:
            raise ValueError("a plan needs a non-empty route")
        if self.yoyo is not None and self.yoyo[0] >= self.yoyo[1]:
            raise ValueError("yoyo must be [d_min, d_max] with d_min < d_max")
        if any(b <= a for a, b in self.surface):
            raise ValueError("surface intervals must be [t_start, t_end] with t_end > t_start")
        return self


@frozen
class PursuerSpec:
    speed: Pos
    depth: NonNeg = 0.0
    update_period: NonNeg = 0.0  # s between re-aims at the ASV (0: continuous pursuit)


@frozen
class TransitSpec:
    heading_deg: Float
    speed: Pos
    depth: NonNeg = 0.0


@frozen
class Behaviour:
    """Exactly one of ``plan``, ``pursuer``, ``transit``."""

    plan: PlanSpec | None = None
    pursuer: PursuerSpec | None = None
    transit: TransitSpec | None = None

    @model_validator(mode="after")
    def _one(self) -> Behaviour:
        given = [k for k in ("plan", "pursuer", "transit") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of plan, pursuer, transit (got {given or 'none'})")
        return self

    def build(self):
        if self.plan is not None:
            p = self.plan
            pts = [pt for seg in p.route for pt in seg.points()]
            return Plan(pts, p.speed, p.acceptance, p.yoyo, p.surface, p.surface_speed)
        if self.pursuer is not None:
            p = self.pursuer
            return Pursuer(p.speed, p.depth, p.update_period)
        return Transit(self.transit.heading_deg, self.transit.speed, self.transit.depth)


@frozen
class Event:
    """At time ``t`` the AUV switches to another behaviour (scripted waypoint changes)."""

    t: NonNeg
    plan: PlanSpec | None = None
    pursuer: PursuerSpec | None = None
    transit: TransitSpec | None = None

    def behaviour(self) -> Behaviour:
        return Behaviour(self.plan, self.pursuer, self.transit)


@frozen
class AUVSpec:
    name: str
    behaviour: Behaviour
    start: Start = Start()
    limits: AUVLimits = AUVLimits()
    events: tuple[Event, ...] = ()
    modem_at_surface: bool = True  # False: no acoustics while at the surface (Case 5)

    @model_validator(mode="after")
    def _speeds(self) -> AUVSpec:
        for ev in (self.behaviour, *self.events):
            spec = ev.plan or ev.pursuer or ev.transit
            if spec is not None and spec.speed > self.limits.speed_max:
                raise ValueError(
                    f"behaviour speed {spec.speed} exceeds limits.speed_max {self.limits.speed_max}"
                )
        for ev in self.events:
            ev.behaviour()  # validates exactly-one
        return self

    def build_behaviour(self):
        initial = self.behaviour.build()
        if not self.events:
            return initial
        return Scripted(initial, [(ev.t, ev.behaviour().build()) for ev in self.events])


@frozen
class ASVSpec:
    start: Start = Start()
    vessel: str = "gretha"  # shipped name or TOML path
    execution: str = "gretha"  # shipped name or TOML path


@frozen
class SimSpec:
    dt: Pos = 0.1  # plant step (s)
    control_period: Pos = 1.0  # supervisory period (s)
    log_every_step: bool = False  # log at the plant step instead of the supervisory period

    @model_validator(mode="after")
    def _multiple(self) -> SimSpec:
        n = self.control_period / self.dt
        if abs(n - round(n)) > 1e-9 or round(n) < 1:
            raise ValueError("control_period must be a positive multiple of dt")
        return self

    @property
    def n_sub(self) -> int:
        return int(round(self.control_period / self.dt))


@frozen
class Scenario:
    """A complete simulation scenario."""

    name: str
    duration: Pos  # s
    auv: tuple[AUVSpec, ...]
    description: str = ""
    controller: str = "goto"  # default controller for this scenario
    preset: str = "default"  # default preset of that controller
    estimator: str = "perfect"
    current: tuple[Float, Float] = (0.0, 0.0)  # (V_N, V_E), m/s
    asv: ASVSpec = ASVSpec()
    sim: SimSpec = SimSpec()
    acoustics: AcousticParams = AcousticParams()
    navigation: NavParams = NavParams()
    # what is uncertain about it, as distributions; a seed draws one realisation
    # (mpcasv.sim.uncertainty.realise)
    uncertain: Uncertain = Uncertain()
    # what is taken from the papers' text and what is our guess, per topic
    provenance: dict[str, str] = dataclasses.field(default_factory=dict)

    @model_validator(mode="after")
    def _check(self) -> Scenario:
        if not self.auv:
            raise ValueError("a scenario needs at least one [[auv]]")
        names = [a.name for a in self.auv]
        if len(set(names)) != len(names):
            raise ValueError(f"AUV names must be unique, got {names}")
        if math.hypot(*self.current) > 2.0:
            raise ValueError("current above 2 m/s is not supported (the ASV could not hold)")
        if not self.uncertain.is_empty():
            check_uncertain(self)
        return self

    @property
    def n_steps(self) -> int:
        """Number of supervisory periods."""
        return int(math.ceil(self.duration / self.sim.control_period - 1e-9))


def load_scenario(path: str | Path) -> Scenario:
    """Load and validate a scenario TOML file.

    File references inside it (``asv.vessel``, ``asv.execution``, ``preset``) that are paths are
    resolved against the scenario file's folder (not the working directory) and must exist.

    Raises
    ------
    ConfigError
        One line per problem, naming the file and the field.
    """
    data = load_toml(path)
    base = Path(path).resolve().parent
    refs = [(data, "preset")]
    if isinstance(data.get("asv"), dict):
        refs += [(data["asv"], "vessel"), (data["asv"], "execution")]
    for table, key in refs:
        value = table.get(key)
        if isinstance(value, str) and is_path(value):
            table[key] = anchor(value, base)
            if not Path(table[key]).is_file():
                where = f"asv.{key}" if table is not data else key
                raise ConfigError(f"{path}: {where}: no such file {value!r} (looked at "
                                  f"{table[key]}, relative to the scenario's folder)")  # fmt: skip
    return parse(Scenario, data, path)


def scenario_from_dict(data: dict, source: str = "<scenario>") -> Scenario:
    return parse(Scenario, data, source)


def scenario_with(scenario: Scenario, **changes) -> Scenario:
    """A re-validated copy with top-level fields replaced (e.g. ``current=(0.2, 0)``)."""
    data = {f.name: getattr(scenario, f.name) for f in dataclasses.fields(scenario)}
    data.update(changes)
    return parse(Scenario, _to_plain(data), f"{scenario.name} (modified)")


def _to_plain(obj):
    if dataclasses.is_dataclass(obj):
        return {f.name: _to_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {k: _to_plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_to_plain(v) for v in obj]
    return obj


__all__ = ["Scenario", "load_scenario", "scenario_from_dict", "scenario_with", "load_toml"]
