"""Scenario files (TOML under ``experiments/scenarios/``), validated up front.

A scenario says where the ASV starts, which AUVs there are and what they do, the current,
the acoustic channel, the estimator and how long to simulate. Unknown keys, missing fields,
non-numeric values and impossible numbers are refused with the file and field named.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from pydantic import model_validator

from mpcasv.config import (
    ConfigError,
    Duration,
    Flag,
    Float,
    PathName,
    Pos,
    anchor,
    frozen,
    is_path,
    load_toml,
    parse,
    resolve,
)
from mpcasv.models.acoustics import AcousticParams, NavParams
from mpcasv.models.current import V_MAX, CurrentField
from mpcasv.sim.auv_spec import (  # noqa: F401  (re-exported: the format's one namespace)
    AUVSpec,
    Behaviour,
    Event,
    LawnmowerSpec,
    LoiterSpec,
    PlanSpec,
    PursuerSpec,
    Segment,
    Start,
    TransitSpec,
)
from mpcasv.sim.uncertainty import Uncertain, check_uncertain


@frozen
class ASVSpec:
    start: Start = Start()
    vessel: str = "gretha"  # shipped name or TOML path
    execution: str = "gretha"  # shipped name or TOML path


@frozen
class SimSpec:
    dt: Pos = 0.1  # plant step (s)
    control_period: Pos = 1.0  # supervisory period (s)
    log_every_step: Flag = False  # log at the plant step instead of the supervisory period

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

    name: PathName  # part of default output paths (runs/<name>-<controller>-<seed>)
    duration: Duration  # s (at most a week: DURATION_MAX)
    auv: tuple[AUVSpec, ...]
    description: str = ""
    controller: str = "goto"  # default controller for this scenario
    preset: str = "default"  # default preset of that controller
    estimator: str = "perfect"
    current: tuple[Float, Float] = (0.0, 0.0)  # (V_N, V_E), m/s
    # optional: a time profile and spatial gradient added to it, carrying the AUVs too
    # (mpcasv.models.current)
    current_field: CurrentField | None = None
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
        from mpcasv.estimation import ESTIMATORS  # here, not at import: estimation imports sim

        if self.estimator not in ESTIMATORS:
            raise ValueError(f"estimator: unknown estimator {self.estimator!r}; known: "
                             f"{sorted(ESTIMATORS)}")  # fmt: skip
        names = [a.name for a in self.auv]
        if len(set(names)) != len(names):
            raise ValueError(f"AUV names must be unique, got {names}")
        if math.hypot(*self.current) > V_MAX:
            raise ValueError("current above 2 m/s is not supported (the ASV could not hold)")
        if self.current_field is not None:
            top = math.hypot(*self.current) + self.current_field.extra_max()
            if top > V_MAX:
                raise ValueError(f"current_field: the current may reach {top:.3g} m/s (|current| "
                                 "+ largest knot + ||gradient|| x radius), above 2 m/s (the ASV "
                                 "could not hold)")  # fmt: skip
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
    data = load_toml(path, "scenario")
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
    preset = data.get("preset")
    if isinstance(preset, str) and preset != "default" and not is_path(preset):
        try:  # the run judges by this preset's domain whatever controller runs: name it now
            resolve("presets", preset)
        except ConfigError as exc:
            raise ConfigError(f"{path}: preset: {exc}") from None
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
