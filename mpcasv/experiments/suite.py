"""Suites expanded into jobs: every scenario x current x estimator x controller (x its grid)
x seed of a suite file (:mod:`mpcasv.experiments.suite_file`) is one :class:`Job`.

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
import json
import math
import re
from pathlib import Path
from typing import Any

from mpcasv.config import ConfigError
from mpcasv.experiments.suite_file import SCENARIOS_DIR, Suite, _flatten, load_suite

#: rough run time per simulated second relative to the hybrid controllers (for scheduling
#: the longest jobs first, so that a sweep does not end with one worker on one long job)
RELATIVE_COST = {"mpc-single": 10.0, "mpc-multi": 20.0}


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
    realisation: str = ""  # id of the drawn realisation (mpcasv.sim.realisation.Realisation)
    current_realised: tuple[float, float] | None = None  # (V_N, V_E) m/s simulated (drawn)

    @property
    def run_name(self) -> str:
        """Folder name of the run under ``DIR/runs``: scenario, variant, the current simulated
        (``cur{V_N}_{V_E}`` in m/s, 3 significant digits, the drawn one where the scenario
        draws it; ``nocur`` for none), seed and the job id's first 8 characters. Until
        session 45 it named the nominal current: a drawn 0.2 m/s current read ``nocur``."""
        v = self.current_realised if self.current_realised is not None else self.current
        cur = "nocur" if tuple(v) == (0.0, 0.0) else "cur{:.3g}_{:.3g}".format(*v)
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


#: The world's random streams a job's run draws from, in its id: 2 since session 48, the
#: synchronised streams of :mod:`mpcasv.sim.streams` (common random numbers). A results
#: folder written before holds runs of the old draws under the old ids: resumed, its jobs
#: run again rather than pair old-noise runs with new ones (a review). 3 since session 49: the
#: same draws, but a fix's three normals are its range, across and elevation errors on the 3-D
#: line of sight (:func:`mpcasv.models.acoustics.usbl_error_map`) and the AUVs' reports carry
#: their course and speed over ground: every run with fixes means another world.
WORLD_STREAMS = 3


#: The shipped vessel and execution files, by name, whose content as of session 44 (their
#: :func:`~mpcasv.controllers.registry.parameter_hash`) leaves a job id as it was before the
#: boat's content was in it (frozen: a shipped file edited since has another hash, and its
#: jobs other ids). Until then a job id hashed the scenario's ``asv.vessel`` and
#: ``asv.execution`` as named, not their content: a resumed sweep served the results of a
#: vessel file as it was before an edit (m 910 -> 1500 kg, a new user's finding). A folder
#: written before a shipped file last changed (dune-otter.toml: 2e408ce) is still served as it
#: was: the id held no content then.
BOAT_AS_BEFORE = {
    ("vessel", "gretha"): "218eea6e38a6bb98",
    ("vessel", "dune-otter"): "73e7e76be2487952",
    ("vessel", "otter"): "f93134a3933d5309",
    ("execution", "gretha"): "91e3a909697bdb5e",
}


def boat_digest(sc) -> list[str]:
    """What a job id holds of scenario ``sc``'s boat: ``[]`` when it names shipped files (by
    name, not path) whose content is still session 44's (:data:`BOAT_AS_BEFORE`: the ids of
    earlier results folders stay), else both parameter hashes (any file given as a path, so
    a user's copy swapped between two shipped vessels' contents changes the id too).

    Raises
    ------
    ConfigError
        A vessel or execution file that no longer loads.
    """
    from mpcasv.controllers.registry import Boat, parameter_hash

    boat = Boat.load(sc.asv.vessel, sc.asv.execution)
    hashes = {"vessel": parameter_hash(boat.vessel), "execution": parameter_hash(boat.execution)}
    named = {"vessel": str(sc.asv.vessel), "execution": str(sc.asv.execution)}
    if all(BOAT_AS_BEFORE.get((k, named[k])) == h for k, h in hashes.items()):
        return []
    return [f"{k}={h}" for k, h in sorted(hashes.items())]


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
    from mpcasv.sim.scenario import digest_plain

    suite, path = load_suite(name_or_path)
    _check_estimators(suite, path)
    scenarios = _load_scenarios(suite, path)
    usable, skipped = _usable_controllers(suite, path, [sc.name for sc, _ in scenarios])
    fronts = _front_choices(usable, path)
    jobs: list[Job] = []
    seen: dict[str, int] = {}
    for sc0, file in scenarios:
        boat = boat_digest(sc0)  # the files' content, not only their names (one per file:
        # the conditions change the current, duration and estimator, never the boat)
        for sc, current, axis, estimator in conditions(suite, sc0, path, file):
            if estimator == "plan" and not has_plan(sc0):  # it would be the Kalman filter
                note = (f"estimator 'plan' on scenario {sc.name!r}: no AUV of it has a plan "
                        "(waypoints), the plan estimator would be the Kalman filter")
                if note not in skipped:
                    skipped.append(note)
                continue
            sc_digest = _digest(_plain(digest_plain(sc)))
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
                        jid = _digest([sc_digest, cname, p_digest, seed, estimator, variant,
                                       real, *boat, ["streams", WORLD_STREAMS]])  # fmt: skip
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
