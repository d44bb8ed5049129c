"""Suites: which scenarios, controllers (with presets and parameter grids), currents,
estimators and seeds to run, as TOML under ``experiments/suites/``; expanded into jobs.

A suite is validated completely before any job starts: every scenario is loaded, every
controller looked up and every (preset, overrides) combination validated against the
controller's parameter class, so an unknown scenario, an unknown controller, an empty grid or
an unknown key is refused with a :class:`~mpcasv.config.ConfigError` naming the file and the
field. See ``docs/experiments.md`` for the file format.

Each :class:`Job` has an id: a hash of what determines its numbers (the validated scenario
after the suite's changes, the controller name and its validated parameters, the seed, the
estimator) plus its label, so a sweep can be resumed and an edited preset or scenario file is
never served stale results.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from pydantic import model_validator

from mpcasv.config import (
    ConfigError,
    Duration,
    Flag,
    Float,
    PathName,
    Seed,
    frozen,
    load_toml,
    parse,
)
from mpcasv.experiments.acceptance import Acceptance

#: the repository's ``experiments`` folder (scenarios and suites by name)
EXPERIMENTS_DIR = Path(__file__).resolve().parents[2] / "experiments"
SCENARIOS_DIR = EXPERIMENTS_DIR / "scenarios"
SUITES_DIR = EXPERIMENTS_DIR / "suites"

#: rough run time per simulated second relative to the hybrid controllers (for scheduling
#: the longest jobs first, so that a sweep does not end with one worker on one long job)
RELATIVE_COST = {"mpc-single": 10.0, "mpc-multi": 20.0}
_LABEL = re.compile(r"^[A-Za-z0-9_.+-]+$")


def _flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"domain": {"delta_r": 1}}`` and ``{"domain.delta_r": 1}`` both give the latter."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out |= _flatten(v, key + ".")
        else:
            out[key] = v
    return out


@frozen
class ControllerEntry:
    """One controller of a suite (``[[controllers]]``).

    ``name`` is used for every scenario; or ``single`` for one-AUV scenarios and ``multi`` for
    several-AUV ones (e.g. ``hybrid-single`` / ``hybrid-multi``). ``preset``: ``"default"``
    (the controller's default preset), ``"scenario"`` (the scenario's own preset, which must
    belong to the same controller) or a shipped name / TOML path; ``presets`` overrides it per
    scenario. ``overrides`` fix single parameters (dotted keys), ``grid`` lists values to
    sweep (cartesian product). ``domain_from = "scenario"``: take the ``domain`` table (the
    donut: alpha_inner, alpha_outer, delta_r, eps) of the scenario's own preset as overrides,
    so that a controller compared on a case uses the case's published domain (explicit
    ``overrides`` and ``grid`` keys win). ``optional``: skip the entry, saying so, when the
    controller is registered but cannot be imported (e.g. the MPC before it is installed).
    ``front`` (with ``at`` and ``level``): run the point of a tuned front (the output folder
    of ``mpcasv tune controller``, relative to the suite) whose mean of metric ``at`` is
    nearest ``level``, with its preset (:mod:`mpcasv.experiments.tune_match`: comparison at
    matched operating points); ``preset``, ``presets``, ``overrides``, ``grid`` and
    ``domain_from`` are then the front's and may not be given. ``front_means = "training"``
    chooses among the training front by training means even when the folder has held-out runs.
    """

    label: str
    name: str | None = None
    single: str | None = None
    multi: str | None = None
    preset: str = "default"
    presets: dict[str, str] = dataclasses.field(default_factory=dict)
    overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    grid: dict[str, Any] = dataclasses.field(default_factory=dict)
    scenarios: tuple[str, ...] | None = None
    domain_from: Literal["preset", "scenario"] = "preset"
    optional: Flag = False
    front: str | None = None  # folder of a tuned front (mpcasv.experiments.tune_match)
    at: str | None = None  # the matched metric of the front (None: energy_J; only with front)
    level: Float | None = None  # its level (the metric's unit)
    front_means: Literal["heldout", "training"] | None = None  # whose means (default heldout)

    @model_validator(mode="after")
    def _check(self) -> ControllerEntry:
        if not _LABEL.match(self.label):
            raise ValueError(f"label {self.label!r} must match {_LABEL.pattern}")
        if self.name is not None and (self.single or self.multi):
            raise ValueError("give either 'name' or 'single'/'multi', not both")
        if self.name is None and not (self.single or self.multi):
            raise ValueError("give 'name' (or 'single' and/or 'multi'): which controller?")
        for key, values in _flatten(self.grid).items():
            if not isinstance(values, (list, tuple)):
                raise ValueError(f"grid.{key}: give a list of values, got {values!r}")
            if len(values) == 0:
                raise ValueError(f"grid.{key}: empty list of values (an empty grid has no jobs)")
        if self.front is None and (self.level is not None or self.front_means is not None
                                   or self.at is not None):
            given = [k for k, v in (("at", self.at), ("level", self.level),
                                    ("front_means", self.front_means)) if v is not None]
            raise ValueError(f"{given} without 'front': which tuned front? ('at', 'level' and "
                             "'front_means' choose a point of a tuned front)")
        if self.front is not None:
            if self.level is None:
                raise ValueError("'front' needs 'level': the level of 'at' to match")
            given = [k for k, v in (("preset", self.preset != "default"),
                                    ("presets", self.presets), ("overrides", self.overrides),
                                    ("grid", self.grid),
                                    ("domain_from", self.domain_from != "preset")) if v]
            if given:
                raise ValueError(f"'front' runs the chosen point's preset as it is: drop {given}")
        clash = set(_flatten(self.grid)) & set(_flatten(self.overrides))
        if clash:
            raise ValueError(f"keys both in overrides and grid: {sorted(clash)}")
        return self

    def controller_for(self, n_auv: int) -> str | None:
        """The controller name for a scenario with ``n_auv`` AUVs (None: no entry for it)."""
        if self.name is not None:
            return self.name
        return self.multi if n_auv > 1 else self.single

    def combinations(self) -> list[dict[str, Any]]:
        """The parameter-grid combinations (each a dict of dotted key -> value)."""
        grid = _flatten(self.grid)
        keys = list(grid)
        return [dict(zip(keys, vals, strict=True)) for vals in itertools.product(*grid.values())]


Current = Literal["scenario", "off"] | tuple[Float, Float]


@frozen
class Suite:
    """A suite file. Lists are cartesian products: every scenario x current x estimator x
    controller (x its grid) x seed is one job."""

    name: PathName
    scenarios: tuple[str, ...]
    controllers: tuple[ControllerEntry, ...]
    seeds: tuple[Seed, ...]
    description: str = ""
    current: tuple[Current, ...] = ("scenario",)  # "scenario", "off" or [V_N, V_E] (m/s)
    estimator: tuple[str, ...] = ("scenario",)  # "scenario" or an estimator name
    duration: Duration | None = None  # s; replaces every scenario's duration when given
    plots: Literal["all", "representative", "none"] = "all"  # run figures (first seed only)
    acceptance: Acceptance | None = None  # targets the report judges (acceptance.py)

    @model_validator(mode="after")
    def _check(self) -> Suite:
        for field in ("scenarios", "controllers", "seeds", "current", "estimator"):
            if not getattr(self, field):
                raise ValueError(f"'{field}' is empty: the suite would have no jobs")
        for field in ("scenarios", "seeds", "estimator"):
            vals = getattr(self, field)
            if len(set(vals)) != len(vals):
                raise ValueError(f"'{field}' has duplicates: {list(vals)}")
        labels = [c.label for c in self.controllers]
        if len(set(labels)) != len(labels):
            raise ValueError(f"controller labels must be unique, got {labels}")
        return self


@dataclasses.dataclass(frozen=True)
class Job:
    """One simulation of a suite: everything a worker needs, as plain values."""

    job_id: str
    index: int  # position in the suite's expansion (the results table's order)
    suite: str
    scenario: str  # scenario name
    scenario_path: str  # absolute path of its TOML
    label: str  # controller entry label
    variant: str  # label plus the grid values, e.g. "hybrid[domain.delta_r=40]"
    controller: str  # registered controller name
    preset: str | None  # shipped name or absolute TOML path (None: the controller's default)
    overrides: tuple[tuple[str, Any], ...]  # fixed overrides and grid values, sorted
    current: tuple[float, float]  # (V_N, V_E) m/s, nominal (an uncertain current is drawn)
    estimator: str
    seed: int
    duration: float  # s
    n_auv: int
    auv_names: tuple[str, ...]
    plots: bool
    cost: float  # rough relative run time, for scheduling long jobs first
    current_axis: str = "scenario"  # the suite's current value: "scenario", "off" or "V_N,V_E"
    realisation: str = ""  # id of the drawn realisation (mpcasv.sim.uncertainty.Realisation)
    current_realised: tuple[float, float] | None = None  # (V_N, V_E) m/s simulated (drawn)

    @property
    def run_name(self) -> str:
        """Folder name of the run under ``DIR/runs``."""
        cur = "nocur" if self.current == (0.0, 0.0) else "cur{:g}_{:g}".format(*self.current)
        name = f"{self.scenario}-{self.variant}-{cur}-s{self.seed}-{self.job_id[:8]}"
        return re.sub(r"[^A-Za-z0-9_.+-]", "_", name.replace("]", ""))

    def scenario_changes(self) -> dict[str, Any]:
        return {"current": self.current, "duration": self.duration}

    def realised_scenario(self):
        """``(Scenario, Realisation)`` this job simulates: its scenario file with the suite's
        current and duration, realised for its seed (the same function :func:`expand` used, so
        the realisation id equals :attr:`realisation`).

        Raises
        ------
        ConfigError
            The file no longer validates, or the realisation does not match the expansion's
            (the file changed since the suite was expanded).
        """
        from mpcasv.experiments.conditions import condition_scenario
        from mpcasv.sim.scenario import load_scenario
        from mpcasv.sim.uncertainty import realise

        sc = condition_scenario(load_scenario(self.scenario_path), self.current_axis,
                                self.current, self.duration)  # fmt: skip
        scenario, real = realise(sc, self.seed)
        if self.realisation and real.id != self.realisation:
            raise ConfigError(f"{self.scenario_path}: realisation {real.id} of seed {self.seed} "
                              f"differs from the suite's {self.realisation} (file changed since "
                              "the expansion?)")  # fmt: skip
        return scenario, real


@dataclasses.dataclass(frozen=True)
class Expansion:
    """A suite's jobs, plus what the expansion left out, one line each with why: optional
    controller entries that are unavailable, and estimator 'plan' on a scenario whose AUVs
    have no plan (it would run the Kalman filter under the name "plan")."""

    suite: Suite
    path: Path
    jobs: list[Job]
    skipped: list[str]
    fronts: list = dataclasses.field(default_factory=list)  # tune_match.FrontChoice per entry


def suite_path(name_or_path: str | Path) -> Path:
    """A suite by name (``experiments/suites/<name>.toml``) or by path."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.exists():
            raise ConfigError(f"{p}: no such suite file")
        return p.resolve()
    shipped = SUITES_DIR / f"{name_or_path}.toml"
    if shipped.exists():
        return shipped
    known = sorted(f.stem for f in SUITES_DIR.glob("*.toml"))
    raise ConfigError(f"unknown suite {str(name_or_path)!r}: not a file, and not one of {known}")


def load_suite(name_or_path: str | Path) -> tuple[Suite, Path]:
    """Load and validate a suite file (not yet expanded)."""
    path = suite_path(name_or_path)
    return parse(Suite, load_toml(path, "suite"), path), path


def _scenario_file(entry: str, base: Path, where: str) -> Path:
    if entry.endswith(".toml"):
        p = Path(entry)
        p = p if p.is_absolute() else base / p
        if not p.exists():
            raise ConfigError(f"{where}: scenario file {entry!r} not found (looked at {p})")
        return p.resolve()
    p = SCENARIOS_DIR / f"{entry}.toml"
    if not p.exists():
        known = sorted(f.stem for f in SCENARIOS_DIR.glob("*.toml"))
        raise ConfigError(f"{where}: unknown scenario {entry!r}; known: {known}")
    return p




def _digest(obj) -> str:
    text = json.dumps(obj, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _plain(obj):
    if dataclasses.is_dataclass(obj):
        return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return repr(obj)
    return obj


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _check_estimators(suite: Suite, path: Path) -> None:
    from mpcasv.estimation import ESTIMATORS

    for i, est in enumerate(suite.estimator):
        if est != "scenario" and est not in ESTIMATORS:
            known = ["scenario", *sorted(ESTIMATORS)]
            raise ConfigError(f"{path}: estimator[{i}]: unknown estimator {est!r}; known: {known}")


def _load_scenarios(suite: Suite, path: Path) -> list:
    """[(Scenario, file)] of the suite, loaded and validated."""
    from mpcasv.sim.scenario import load_scenario

    out = []
    for i, entry in enumerate(suite.scenarios):
        file = _scenario_file(entry, path.parent, f"{path}: scenarios[{i}]")
        out.append((load_scenario(file), file))
    names = [sc.name for sc, _ in out]
    if len(set(names)) != len(names):
        raise ConfigError(f"{path}: scenarios: two files share a scenario name: {names}")
    return out










def expand(name_or_path: str | Path) -> Expansion:
    """Load, validate and expand a suite into its jobs (nothing runs).

    Raises
    ------
    ConfigError
        Naming the suite file and the offending field: unknown scenario, unknown or unusable
        controller, bad preset or override key, empty list or grid, unknown estimator.
    """
    from mpcasv.controllers import load_preset
    from mpcasv.controllers.registry import check_auv_count
    from mpcasv.estimation import has_plan
    from mpcasv.experiments.conditions import conditions, realisations
    from mpcasv.experiments.suite_entries import (
        _controller_and_preset,
        _front_choices,
        _scenario_domain,
        _usable_controllers,
    )

    suite, path = load_suite(name_or_path)
    _check_estimators(suite, path)
    scenarios = _load_scenarios(suite, path)
    usable, skipped = _usable_controllers(suite, path, [sc.name for sc, _ in scenarios])
    fronts = _front_choices(usable, path)
    jobs: list[Job] = []
    seen: dict[str, int] = {}
    for sc0, file in scenarios:
        for sc, current, axis, estimator in conditions(suite, sc0, path, file):
            if estimator == "plan" and not has_plan(sc0):  # it would be the Kalman filter
                note = (f"estimator 'plan' on scenario {sc.name!r}: no AUV of it has a plan "
                        "(waypoints), the plan estimator would be the Kalman filter")
                if note not in skipped:
                    skipped.append(note)
                continue
            sc_digest = _digest(_plain(sc))
            reals = realisations(sc, suite.seeds, f"{path}: scenario {file}")
            for i, entry in usable:
                if entry.scenarios is not None and sc.name not in entry.scenarios:
                    continue
                where = f"{path}: controllers[{i}] ({entry.label}) with scenario {sc.name!r}"
                cname, preset = _controller_and_preset(entry, sc, where, path.parent,
                                                       fronts.get(i))  # fmt: skip
                for combo in entry.combinations():
                    overrides = _scenario_domain(entry, sc, where) | _flatten(entry.overrides)
                    overrides |= combo
                    try:
                        params = load_preset(cname, preset, overrides)
                        check_auv_count(cname, len(sc.auv), params, preset)  # e.g. the order's
                    except ConfigError as exc:
                        raise ConfigError(f"{where}: {exc}") from None
                    grid = ",".join(f"{k}={_fmt(v)}" for k, v in combo.items())
                    variant = f"{entry.label}[{grid}]" if grid else entry.label
                    p_digest = _digest(_plain(params))
                    for seed in suite.seeds:
                        real, current_realised = reals[seed][0].id, reals[seed][1]
                        jid = _digest([sc_digest, cname, p_digest, seed, estimator, variant, real])
                        if jid in seen:
                            raise ConfigError(f"{where}: job duplicates job #{seen[jid]} "
                                              "(same scenario, parameters, seed)")  # fmt: skip
                        seen[jid] = len(jobs)
                        jobs.append(Job(
                            job_id=jid, index=len(jobs), suite=suite.name, scenario=sc.name,
                            scenario_path=str(file), label=entry.label, variant=variant,
                            controller=cname, preset=preset,
                            overrides=tuple(sorted(overrides.items())), current=current,
                            estimator=estimator, seed=seed, duration=float(sc.duration),
                            n_auv=len(sc.auv), auv_names=tuple(a.name for a in sc.auv),
                            plots=suite.plots == "all"
                            or (suite.plots == "representative" and seed == suite.seeds[0]),
                            cost=float(sc.duration) * (1.0 + 0.2 * len(sc.auv))
                            * RELATIVE_COST.get(cname, 1.0),
                            current_axis=axis, realisation=real,
                            current_realised=current_realised,
                        ))  # fmt: skip
    if not jobs:
        raise ConfigError(f"{path}: the suite expands to no jobs (skipped: {skipped})")
    return Expansion(suite, path, jobs, skipped, list(fronts.values()))
