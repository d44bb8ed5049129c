"""Falsification: search a family of scenarios for a controller's worst case (issue 14).

A *family* (TOML, e.g. ``experiments/falsify/pursuer-single.toml``) is a template scenario
plus parameter ranges. Each candidate scenario is the template with the parameters written
into dotted fields (``auv.0.events.0.pursuer.speed``; integer parts index lists) and is then
validated by the normal scenario loader, so a family can vary whatever the scenario format
expresses (pursuer speed, aim and timing; crossing AUV paths; depths and rises; current;
acoustic dropouts ...). A ``[[polar]]`` entry writes a pair of fields from a bearing (deg)
and a radius: ``origin + radius [cos b, sin b]`` (an approach direction, a current vector).

The robustness measure of a run (:func:`robustness`), from its time series:

- margin ``min over t, k of (slant_k(t) - r_sep)`` (m): ``slant_k`` the 3-D distance between
  the ASV and AUV k, ``r_sep`` the required separation, by default the radius of the
  controller's collision sphere ``r_in = alpha T0 rdot_max`` (Paper 1 eq. 4; Paper 2's
  ``r_avoid``, eq. 4). Negative: the ASV was inside a collision domain.
- longest stay (s): the longest run of consecutive samples with the ASV inside some AUV's
  anti-collision domain on the surface, ``range_k < r_avoid(d_k) = sqrt(r_sep^2 - d_k^2)``
  (Paper 2 eq. 5; the same set as ``slant_k < r_sep``).

Both are sampled at the logged period (the supervisory period, 1 s by default). The search
(:func:`search`) minimises the margin (or maximises the stay) with Optuna's CMA-ES sampler
over a budget of runs, in batches of ``BATCH`` trials: a batch is asked only once the previous
one is told, and every finished run is told at once into the study's SQLite file, so the
search is reproducible from its seed whatever the number of workers, and a killed search
resumes without losing a finished run. A search finds counterexamples; it proves nothing.
"""

from __future__ import annotations

import copy
import fnmatch
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd

from mpcasv.config import ConfigError, FinitePos, Float, frozen, load_toml, parse
from mpcasv.hybrid.domains import r_avoid

BATCH = 4  # trials asked together (independent of the number of workers: reproducible)
#: scenario fields that are instants of the run (s from its start; fnmatch patterns): a
#: searched value past the run's duration changes nothing
RUN_TIME_FIELDS = ("auv.*.events.*.t",)


@frozen
class ParamSpec:
    """One searched parameter, uniform in ``[low, high]``; written to ``field`` (one dotted
    path or several) if given, plus the value of parameter ``plus`` if given (e.g. a rise
    ``rise_after`` s after ``t_attack``)."""

    name: str
    low: Float
    high: Float
    field: str | tuple[str, ...] | None = None
    integer: bool = False
    plus: str | None = None


@frozen
class PolarSpec:
    """Write ``fields = [f_N, f_E]`` as ``origin + radius [cos b, sin b]``, ``b`` in degrees.

    ``bearing_deg`` and ``radius`` are numbers or names of parameters.
    """

    fields: tuple[str, str]
    bearing_deg: str | Float
    radius: str | Float
    origin: tuple[Float, Float] = (0.0, 0.0)


@frozen
class Family:
    """A family of scenarios: a template (inline ``[scenario]`` or a ``template`` path,
    relative to the family file) and the parameters searched."""

    name: str
    param: tuple[ParamSpec, ...]
    description: str = ""
    template: str | None = None
    scenario: dict[str, Any] | None = None
    polar: tuple[PolarSpec, ...] = ()
    duration: FinitePos | None = None  # replaces the template's duration (s)


@dataclass(frozen=True)
class LoadedFamily:
    """A validated family with its template scenario as a plain dict."""

    spec: Family
    source: Path
    template: dict

    @property
    def name(self) -> str:
        return self.spec.name


def load_family(path: str | Path) -> LoadedFamily:
    """Load a family TOML file; check every parameter once with its midpoint.

    Raises
    ------
    ConfigError
        Unreadable file, unknown keys, bad ranges, unknown fields or parameters, or a
        template that the scenario loader refuses (the message names the file).
    """
    path = Path(path)
    fam = parse(Family, load_toml(path, "falsification family"), path)
    if (fam.template is None) == (fam.scenario is None):
        raise ConfigError(f"{path}: give exactly one of 'template' (a path) or [scenario]")
    if fam.template is not None:
        template = load_toml(path.parent / fam.template, "scenario")
    else:
        template = copy.deepcopy(fam.scenario)
    if fam.duration is not None:
        template["duration"] = fam.duration
    names = [p.name for p in fam.param]
    if len(set(names)) != len(names) or not names:
        raise ConfigError(f"{path}: parameter names must be unique and at least one given")
    for p in fam.param:
        if not p.low < p.high:
            raise ConfigError(f"{path}: parameter {p.name!r}: low must be < high")
        if p.plus is not None and p.plus not in names:
            raise ConfigError(f"{path}: parameter {p.name!r}: unknown 'plus' {p.plus!r}")
    for pol in fam.polar:
        for ref in (pol.bearing_deg, pol.radius):
            if isinstance(ref, str) and ref not in names:
                raise ConfigError(f"{path}: polar refers to unknown parameter {ref!r}")
    loaded = LoadedFamily(fam, path, template)
    mid = {p.name: 0.5 * (p.low + p.high) for p in fam.param}
    candidate(loaded, mid, "midpoint")  # validates every field path and the template
    for r in time_ranges(loaded):
        if r.low >= r.duration:
            raise ConfigError(f"{path}: parameter {r.name!r} (field {r.field}): its times "
                              f"[{r.low:g}, {r.high:g}] s all lie past the run's duration "
                              f"{r.duration:g} s: nothing searched there happens; lower its "
                              "range or raise 'duration'")  # fmt: skip
    return loaded


@dataclass(frozen=True)
class TimeRange:
    """The instants (s) a parameter writes into a :data:`RUN_TIME_FIELDS` field: ``[low,
    high]``, ``plus`` included (its range added; ``name`` then reads ``"a + b"``), against the
    run's ``duration`` (s)."""

    name: str
    field: str
    low: float
    high: float
    duration: float

    @property
    def past(self) -> bool:
        """Whether part of the range lies past the duration (that part changes nothing)."""
        return self.high > self.duration

    def warning(self, source: str | Path) -> str:
        """One line saying which part of the range lies past the duration."""
        share = (self.high - max(self.low, self.duration)) / (self.high - self.low)
        return (f"warning: {source}: parameter {self.name!r} (field {self.field}): times "
                f"[{self.low:g}, {self.high:g}] s reach past the run's duration "
                f"{self.duration:g} s: {share:.0%} of its range changes nothing")  # fmt: skip


def time_ranges(family: LoadedFamily) -> list[TimeRange]:
    """The ranges of the parameters written into instants of the run (:data:`RUN_TIME_FIELDS`),
    with the duration of the run (the family's, else the template's), one per field."""
    duration = float(family.template["duration"])
    by_name = {p.name: p for p in family.spec.param}
    out = []
    for p in family.spec.param:
        fields = () if p.field is None else (p.field,) if isinstance(p.field, str) else p.field
        plus = by_name[p.plus] if p.plus is not None else None
        low = p.low + (plus.low if plus else 0.0)
        high = p.high + (plus.high if plus else 0.0)
        for f in fields:
            if any(fnmatch.fnmatchcase(f, pattern) for pattern in RUN_TIME_FIELDS):
                name = p.name if plus is None else f"{p.name} + {plus.name}"
                out.append(TimeRange(name, f, low, high, duration))
    return out


def set_dotted(data: dict, field: str, value: Any, source: str = "<family>") -> None:
    """Set ``data[a][b][0][c] = value`` for ``field = "a.b.0.c"`` (in place).

    Dict keys that do not exist are created (the scenario loader then refuses unknown
    ones); list indices must exist.

    Raises
    ------
    ConfigError
        An index out of range or a path through a non-container.
    """
    parts = field.split(".")
    node: Any = data
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise ConfigError(f"{source}: field {field!r}: no item {part!r} in a list of "
                                  f"{len(node)}")  # fmt: skip
            if last:
                node[int(part)] = value
            else:
                node = node[int(part)]
        elif isinstance(node, dict):
            if last:
                node[part] = value
            else:
                node = node.setdefault(part, {})
        else:
            raise ConfigError(f"{source}: field {field!r}: {'.'.join(parts[:i])!r} is a value")


def substitute(family: LoadedFamily, params: dict[str, float]) -> dict:
    """The template with ``params`` written into their fields (a new dict)."""
    data = copy.deepcopy(family.template)
    src = str(family.source)
    for p in family.spec.param:
        if p.field is not None:
            v = params[p.name] + (params[p.plus] if p.plus is not None else 0.0)
            for f in (p.field,) if isinstance(p.field, str) else p.field:
                set_dotted(data, f, int(round(v)) if p.integer else float(v), src)
    for pol in family.spec.polar:
        b = math.radians(_ref(pol.bearing_deg, params))
        rad = _ref(pol.radius, params)
        set_dotted(data, pol.fields[0], float(pol.origin[0] + rad * math.cos(b)), src)
        set_dotted(data, pol.fields[1], float(pol.origin[1] + rad * math.sin(b)), src)
    return data


def _ref(x, params):
    return float(params[x]) if isinstance(x, str) else float(x)


def candidate(family: LoadedFamily, params: dict[str, float], label: str):
    """The validated :class:`~mpcasv.sim.scenario.Scenario` for ``params`` and its dict."""
    from mpcasv.sim.scenario import scenario_from_dict

    data = substitute(family, params)
    return scenario_from_dict(data, f"{family.source} ({label})"), data


@dataclass(frozen=True)
class Robustness:
    """The robustness of one run (see the module docstring).

    ``margin_m``: min over time and AUVs of ``slant - r_sep`` (m); ``t_margin_s`` and
    ``auv_margin`` where it occurred; ``longest_stay_s`` and ``time_inside_s``: inside any
    AUV's anti-collision domain (s).
    """

    margin_m: float
    t_margin_s: float
    auv_margin: int
    longest_stay_s: float
    time_inside_s: float


def robustness(ts: pd.DataFrame, n_auv: int, r_sep: float, period: float) -> Robustness:
    """The robustness of a run's time series.

    Parameters
    ----------
    ts : DataFrame
        Columns ``t``, ``range{k}``, ``slant{k}``, ``auv{k}_depth`` for ``k < n_auv``
        (m, m, m, positive down), one row per logged sample.
    r_sep : float
        Required separation: the collision sphere's radius (m).
    period : float
        Time per row (s).
    """
    slant = np.stack([ts[f"slant{k}"].to_numpy(float) for k in range(n_auv)])  # (K, T)
    rng = np.stack([ts[f"range{k}"].to_numpy(float) for k in range(n_auv)])
    depth = np.stack([ts[f"auv{k}_depth"].to_numpy(float) for k in range(n_auv)])
    margin = slant - r_sep
    k, j = np.unravel_index(int(np.argmin(margin)), margin.shape)
    inside = np.any(rng < r_avoid(depth, r_sep), axis=0)  # Paper 2 eq. 5, any AUV
    return Robustness(float(margin[k, j]), float(ts["t"].iloc[j]), int(k),
                      _longest_run(inside) * period, float(np.sum(inside)) * period)  # fmt: skip


def _longest_run(flags: np.ndarray) -> int:
    """Length of the longest run of True values."""
    best = cur = 0
    for f in flags:
        cur = cur + 1 if f else 0
        best = max(best, cur)
    return best


def required_separation(controller) -> float:
    """The controller's collision-sphere radius ``r_in`` (m), if it has a safety domain."""
    domain = getattr(controller, "domain", None)
    if domain is None:
        raise ConfigError(f"controller {controller.name!r} has no safety domain: give "
                          "--separation")  # fmt: skip
    return float(domain.r_in)


def run_trial(data: dict, source: str, controller: str, preset: str | None, seed: int,
              r_sep: float | None) -> dict:  # fmt: skip
    """Simulate one candidate (a scenario dict) and measure it (runs in a worker process).

    Returns ``{"margin_m", "t_margin_s", "auv_margin", "longest_stay_s", "time_inside_s",
    "r_sep_m", "min_range_m", "fallbacks"}``.
    """
    from mpcasv.controllers import Boat, make_controller
    from mpcasv.sim.scenario import scenario_from_dict
    from mpcasv.sim.simulator import simulate

    scenario = scenario_from_dict(data, source)
    ctrl = make_controller(controller, len(scenario.auv), preset, boat=Boat.of_scenario(scenario))
    sep = required_separation(ctrl) if r_sep is None else float(r_sep)
    result = simulate(scenario, ctrl, seed)
    rob = robustness(result.timeseries, len(scenario.auv), sep, _row_period(scenario))
    return {**rob.__dict__, "r_sep_m": sep, "min_range_m": float(result.min_range_m),
            "fallbacks": int(result.fallbacks)}  # fmt: skip


def _row_period(scenario) -> float:
    return scenario.sim.dt if scenario.sim.log_every_step else scenario.sim.control_period


Objective = Literal["margin", "stay"]


def objective_value(measures: dict, objective: Objective) -> float:
    """The minimised value: the margin (m), or minus the longest stay (s)."""
    return measures["margin_m"] if objective == "margin" else -measures["longest_stay_s"]


@dataclass
class SearchSetup:
    """What one search runs: family, controller, preset, seed, required separation."""

    family: LoadedFamily
    controller: str
    preset: str | None
    seed: int = 0
    r_sep: float | None = None
    objective: Objective = "margin"

    def trial_args(self, params: dict, number: int) -> tuple:
        _, data = candidate(self.family, params, f"trial {number}")
        return (data, f"{self.family.source} (trial {number})", self.controller, self.preset,
                self.seed, self.r_sep)  # fmt: skip


def search(setup: SearchSetup, storage_path: Path, budget: int, workers: int = 1,
           progress: Callable[[int, dict], None] | None = None,
           timeout: float | None = None):  # fmt: skip
    """Run (or resume) the CMA-ES search until ``budget`` runs are finished; return the study.

    ``timeout`` (s of wall clock per run, None: no limit): a run that takes longer is
    recorded as failed with a ``timeout`` error (see :mod:`mpcasv.experiments.falsify_pool`).

    The study lives in the SQLite file ``storage_path`` (Optuna RDB storage). Trials left
    running by a killed search are marked failed (``interrupted``) and not counted; finished
    ones (complete, or failed with their ``error``) are kept and counted.
    """
    import optuna

    from mpcasv.experiments.falsify_pool import WorkerPool, run_batch

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = optuna.storages.RDBStorage(f"sqlite:///{storage_path}")
    sampler = optuna.samplers.CmaEsSampler(seed=setup.seed, warn_independent_sampling=False)
    name = f"{setup.family.name}-{setup.controller}-{setup.preset or 'default'}-{setup.objective}"
    study = optuna.create_study(study_name=name, storage=storage, sampler=sampler,
                                direction="minimize", load_if_exists=True)  # fmt: skip
    for ft in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,)):
        study.tell(ft.number, state=optuna.trial.TrialState.FAIL)  # interrupted: not counted
    dists = {p.name: (optuna.distributions.IntDistribution(int(p.low), int(p.high))
                      if p.integer else optuna.distributions.FloatDistribution(p.low, p.high))
             for p in setup.family.spec.param}  # fmt: skip

    def tell(trial, measures, error):
        if error is not None:
            trial.set_user_attr("error", error)
            study.tell(trial, state=optuna.trial.TrialState.FAIL)
        else:
            for k, v in measures.items():
                trial.set_user_attr(k, v)
            study.tell(trial, objective_value(measures, setup.objective))
        if progress is not None:
            progress(trial.number, measures if error is None else {"error": error})

    with WorkerPool(workers, timeout) as pool:
        while (done := n_finished(study)) < budget:
            trials = [study.ask(dists) for _ in range(min(BATCH, budget - done))]
            items = [(t, (lambda t=t: setup.trial_args(t.params, t.number))) for t in trials]
            run_batch(items, pool, tell)
    return study


def n_finished(study) -> int:
    """Finished runs: complete trials and failed ones that recorded an error."""
    import optuna

    S = optuna.trial.TrialState
    trials = study.get_trials(deepcopy=False)
    return sum(t.state == S.COMPLETE or (t.state == S.FAIL and "error" in t.user_attrs)
               for t in trials)  # fmt: skip


def trials_table(study) -> pd.DataFrame:
    """One row per finished trial: number, parameters, measures, error (sorted by margin)."""
    import optuna

    rows = []
    for t in study.get_trials(deepcopy=False):
        if t.state not in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.FAIL):
            continue
        if t.state == optuna.trial.TrialState.FAIL and "error" not in t.user_attrs:
            continue
        rows.append({"trial": t.number, "state": t.state.name.lower(), **t.params,
                     **t.user_attrs})  # fmt: skip
    df = pd.DataFrame(rows)
    if "margin_m" in df:
        df = df.sort_values(["margin_m", "trial"], na_position="last").reset_index(drop=True)
    return df
