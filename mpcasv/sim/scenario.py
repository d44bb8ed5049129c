"""Scenario files (TOML under ``experiments/scenarios/``), validated up front.

A scenario says where the ASV starts, which AUVs there are and what they do, the current,
the acoustic channel, the estimator and how long to simulate. Unknown keys, missing fields,
non-numeric values and impossible numbers are refused with the file and field named.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from pydantic import field_validator, model_validator

from mpcasv.config import (
    AUV_COUNT_MAX,
    CONTROL_PERIOD_MAX,
    REFERENCE_LEAD_MAX,
    ConfigError,
    Duration,
    FieldError,
    Flag,
    Float,
    PathName,
    anchor,
    between,
    frozen,
    is_path,
    load_toml,
    parse,
    problems,
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
    """The ASV: where it starts (at the surface: ``depth`` 0; ``speed`` through the water, at
    most the vessel's ``u_max``: the simulator starts it carried by the current as well), its
    vessel and its execution level (shipped names or TOML paths, loaded and
    checked when the scenario is: an unknown one is refused naming the field and the shipped
    names)."""

    start: Start = Start()
    vessel: str = "gretha"  # shipped name or TOML path
    execution: str = "gretha"  # shipped name or TOML path

    @field_validator("vessel")
    @classmethod
    def _vessel(cls, v: str) -> str:
        from mpcasv.models.params import load_vessel

        _loads(load_vessel, v)
        return v

    @field_validator("execution")
    @classmethod
    def _execution(cls, v: str) -> str:
        from mpcasv.control.params import load_execution

        _loads(load_execution, v)
        return v


def _loads(load, name: str):
    """``load(name)``; its ConfigError as one line (a ValueError: the field is named by
    :func:`~mpcasv.config.parse`)."""
    try:
        return load(name)
    except ConfigError as exc:
        raise ValueError(problems(exc)) from None


#: The plant step's bounds (s). The execution level (guidance, yaw PID, speed loop) samples at
#: ``dt``: every shipped gain is tuned at 0.1 s (the autopilot's 10 Hz, docs/tuning.md) and the
#: yaw PID's derivative filter (explicit Euler, time constant ``yaw.T_f``: 0.2 s for Gretha) is
#: stable only below 2 T_f and free of overshoot up to T_f. Case 3 runs the same (0.1 %) at
#: 0.2 s as at 0.1 s; at 0.5 s the yaw loop fails (600 s of propeller instead of 220 s). The
#: vessel's RK4 itself is sub-stepped to its fastest pole (models/envelope.py) at any dt.
#: Below 1 ms (no autopilot samples faster) a run is millions of steps.
DT_MIN, DT_MAX = 0.001, 0.2
#: The most plant steps per supervisory period: they are compiled into one CasADi function
#: (1000 take about 8 s; ``dt = 1e-6`` hung building a million)
N_SUB_MAX = 1000


@frozen
class SimSpec:
    dt: between(DT_MIN, DT_MAX, "s", "the execution level samples at dt") = 0.1  # plant step
    #: supervisory period (s): a multiple of dt
    control_period: between(0, CONTROL_PERIOD_MAX, "s", "seconds, not hours",
                            lo_open=True) = 1.0  # fmt: skip
    log_every_step: Flag = False  # log at the plant step instead of the supervisory period
    #: the observation carries the ASV's actuators at every plant step of the period
    #: (``Observation.actuator_samples``, which the MPC's current observer integrates); false:
    #: at the period's ends only, as ``mpcasv deploy`` gives them (docs/mpc.md, "Known
    #: problems", the current estimate with Fossen's Otter)
    actuator_samples: Flag = True
    #: the execution level steers at a transit's waypoint pushed this far (m) further along
    #: the line from the ASV at the decision, as ``mpcasv deploy`` sends DUNE its Reference
    #: (``link.reference_lead_m``, 20 m: DUNE stops a boat within 15 m of its Reference);
    #: 0, the default: at the waypoint itself (the thesis's execution level). To simulate a
    #: rehearsal's world as its DUNE (or SITL) steered it (docs/deploy.md, section 2)
    reference_lead_m: between(0, REFERENCE_LEAD_MAX, "m", "a lead beyond 1 km is no waypoint"
                              ) = 0.0  # fmt: skip

    @model_validator(mode="after")
    def _multiple(self) -> SimSpec:
        n = self.control_period / self.dt
        if abs(n - round(n)) > 1e-9 or round(n) < 1:
            raise FieldError("control_period", f"{self.control_period:g} s: a positive "
                             f"multiple of dt ({self.dt:g} s) is needed")  # fmt: skip
        if round(n) > N_SUB_MAX:
            raise FieldError("control_period", f"{self.control_period:g} s is {round(n)} plant "
                             f"steps of dt = {self.dt:g} s, more than the allowed {N_SUB_MAX} "
                             "(each period's steps are compiled into one function)")  # fmt: skip
        return self

    @property
    def n_sub(self) -> int:
        return int(round(self.control_period / self.dt))

    @property
    def row_period(self) -> float:
        """The time (s) one row of a run's time series stands for: the plant step with
        ``log_every_step``, else the supervisory period."""
        return self.dt if self.log_every_step else self.control_period


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
            raise FieldError("auv", "empty: a scenario needs at least one [[auv]]")
        if len(self.auv) > AUV_COUNT_MAX:
            raise FieldError("auv", f"{len(self.auv)} AUVs: at most {AUV_COUNT_MAX} (the "
                             "supervisory controllers visit them in turn and the MPC compiles "
                             "one problem per AUV count: docs/experiments.md, "
                             "'Bounds')")  # fmt: skip
        from mpcasv.controllers.registry import unknown_controller

        if (why := unknown_controller(self.controller)) is not None:
            raise FieldError("controller", why)
        from mpcasv.estimation import ESTIMATORS  # here, not at import: estimation imports sim

        if self.estimator not in ESTIMATORS:
            raise FieldError("estimator", f"unknown estimator {self.estimator!r}; known: "
                             f"{sorted(ESTIMATORS)}")  # fmt: skip
        names = [a.name for a in self.auv]
        if len(set(names)) != len(names):
            raise FieldError("auv", f"AUV names must be unique, got {names}")
        if math.hypot(*self.current) > V_MAX:
            raise FieldError("current", "above 2 m/s is not supported (the ASV could not hold)")
        if self.current_field is not None:
            top = math.hypot(*self.current) + self.current_field.extra_max()
            if top > V_MAX:
                raise FieldError("current_field", f"the current may reach {top:.3g} m/s "
                                 "(|current| + largest knot + ||gradient|| x radius), above "
                                 "2 m/s (the ASV could not hold)")  # fmt: skip
        self._check_asv()
        if not self.uncertain.is_empty():
            try:
                check_uncertain(self)
            except ValueError as exc:  # "uncertain.<field>: <cause>": name the field
                field, _, cause = str(exc).partition(": ")
                raise FieldError(field, cause) from None
        return self

    def _check_asv(self) -> None:
        """The ASV at the surface, no faster than its vessel, and a plant step its execution
        level can sample at (the files are loaded: :class:`ASVSpec` has checked them)."""
        from mpcasv.control.params import load_execution
        from mpcasv.models.params import load_vessel

        start = self.asv.start
        if start.depth != 0.0:
            raise FieldError("asv.start.depth", f"{start.depth:g} m: the ASV is at the surface "
                             "(depth belongs to an AUV's start)")  # fmt: skip
        u_max = load_vessel(self.asv.vessel).u_max
        if start.speed > u_max:
            raise FieldError("asv.start.speed", f"{start.speed:g} m/s exceeds the top speed "
                             f"u_max = {u_max:g} m/s of vessel {self.asv.vessel!r}")  # fmt: skip
        T_f = load_execution(self.asv.execution).yaw.T_f
        if self.sim.dt > T_f:
            raise FieldError("sim.dt", f"{self.sim.dt:g} s is above the yaw derivative filter's "
                             f"T_f = {T_f:g} s of execution {self.asv.execution!r} (its Euler "
                             "step needs dt <= T_f)")  # fmt: skip

    @property
    def n_steps(self) -> int:
        """Number of supervisory periods."""
        return int(math.ceil(self.duration / self.sim.control_period - 1e-9))


def anchor_refs(data: dict, base: Path, source: str | Path) -> None:
    """Make the file references of scenario dict ``data`` (``preset``, ``asv.vessel``,
    ``asv.execution``) that are relative paths absolute, against ``base`` (the folder of the
    file that names them), in place: a scenario written elsewhere (``mpcasv falsify``'s worst
    cases) then names the same files.

    Raises
    ------
    ConfigError
        A path that names no file (``source`` and the field named).
    """
    refs = [(data, "preset")]
    if isinstance(data.get("asv"), dict):
        refs += [(data["asv"], "vessel"), (data["asv"], "execution")]
    for table, key in refs:
        value = table.get(key)
        if isinstance(value, str) and is_path(value):
            table[key] = anchor(value, base)
            if not Path(table[key]).is_file():
                where = f"asv.{key}" if table is not data else key
                raise ConfigError(f"{source}: {where}: no such file {value!r} (looked at "
                                  f"{table[key]}, relative to the scenario's folder)")  # fmt: skip


def past_the_end(scenario: Scenario) -> list[str]:
    """What a (realised) scenario schedules at or after its duration, which never happens:
    each AUV's events and plan surface intervals (the plan's own and a switch event's), one
    line each. Not refused (a suite's ``duration`` or ``--duration`` cuts a run short on
    purpose); ``mpcasv simulate`` says them (an abort at 500 s of a 60-s run went unsaid)."""
    T, out = scenario.duration, []
    for a in scenario.auv:
        plans = [(a.behaviour.plan, "behaviour.plan")] + [
            (e.plan, f"events[{i}].plan") for i, e in enumerate(a.events) if e.plan is not None]
        for i, e in enumerate(a.events):
            if e.t >= T:
                out.append(f"AUV {a.name!r} events[{i}] ({e.kind}) at t = {e.t:g} s")
        for plan, where in plans:
            for t0, _ in plan.surface if plan is not None else ():
                if t0 >= T:
                    out.append(f"AUV {a.name!r} {where}.surface from t = {t0:g} s")
    return [f"{w}: at or after the run's end ({T:g} s), it never happens" for w in out]


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
    anchor_refs(data, Path(path).resolve().parent, path)
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


#: Scenario fields added after results were first written, per table, with the value that
#: means "as before": left out of the digests at that value (:func:`digest_plain`), so that a
#: results folder written before keeps its job and realisation ids (resumed sweeps,
#: ``--baseline``, ``tune compare``); any other value is in the digest.
DIGEST_DEFAULTS = {"sim": {"reference_lead_m": 0.0}}


def digest_plain(scenario: Scenario) -> dict:
    """The scenario as plain data for a digest: every field, but those of
    :data:`DIGEST_DEFAULTS` at their "as before" value."""
    data = _to_plain(scenario)
    for table, fields in DIGEST_DEFAULTS.items():
        for name, before in fields.items():
            if data[table].get(name) == before:
                del data[table][name]
    return data


__all__ = ["DIGEST_DEFAULTS", "Scenario", "digest_plain", "load_scenario", "scenario_from_dict",
           "scenario_with", "load_toml"]
