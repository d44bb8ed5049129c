"""The suite file: which scenarios, controllers (with presets and parameter grids), currents,
estimators and seeds to run, as TOML under ``experiments/suites/``.

:class:`Suite` (one file) and :class:`ControllerEntry` (one ``[[controllers]]`` table) validate
each field on their own (labels, names, grids, front choices, duplicates, empty lists);
:func:`suite_path` finds a suite by name or path and :func:`load_suite` loads and validates it.
What needs the other files (scenarios, controllers and their presets) is checked when the suite
is expanded into jobs (:func:`mpcasv.experiments.suite.expand`). See ``docs/experiments.md``
for the file format.
"""

from __future__ import annotations

import dataclasses
import itertools
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
