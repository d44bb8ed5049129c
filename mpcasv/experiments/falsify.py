"""Falsification: search a family of scenarios for a controller's worst case (issue 14).

The family (a template scenario and parameter ranges) is :mod:`mpcasv.experiments.falsify_family`
(its names are re-exported here).

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

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd

from mpcasv.config import ConfigError
from mpcasv.experiments.falsify_family import (  # noqa: F401 (re-exported)
    RUN_TIME_FIELDS,
    Family,
    LoadedFamily,
    ParamSpec,
    PolarSpec,
    TimeRange,
    candidate,
    load_family,
    set_dotted,
    substitute,
    time_ranges,
)
from mpcasv.hybrid.domains import r_avoid

BATCH = 4  # trials asked together (independent of the number of workers: reproducible)

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
    rob = robustness(result.timeseries, len(scenario.auv), sep, scenario.sim.row_period)
    return {**rob.__dict__, "r_sep_m": sep, "min_range_m": float(result.min_range_m),
            "fallbacks": int(result.fallbacks)}  # fmt: skip


Objective = Literal["margin", "stay"]


def objective_value(measures: dict, objective: Objective) -> float:
    """The minimised value: the margin (m), or minus the longest stay (s)."""
    return measures["margin_m"] if objective == "margin" else -measures["longest_stay_s"]


@dataclass
class SearchSetup:
    """What one search runs: family, controller, preset, seed, required separation.

    ``preset``: the controller's preset (a shipped name, or an absolute path), which is also
    the scenario's ``preset`` in every run, so the world judges by its ``[domain]`` (the
    escape power turn, the domain metrics): a run is the scenario :meth:`scenario` gives,
    the one written as a worst case, which ``mpcasv simulate`` reproduces. None: the
    controller's defaults and no evaluation domain (no power turn; domain metrics null).
    """

    family: LoadedFamily
    controller: str
    preset: str | None
    seed: int = 0
    r_sep: float | None = None
    objective: Objective = "margin"
    #: the preset as the user named it (``--params``; None: the family's or none), in the
    #: study's name: the same command resumes its study from any working folder
    named: str | None = None

    def scenario(self, params: dict, label: str):
        """``(Scenario, dict)`` of one candidate as it is run and written: the family's
        template with ``params``, this controller and this preset. Until session 44 the runs
        took the family's template as it was (no preset: no domain, no power turn) and the
        written worst case named the preset: ``simulate`` of it ran another world (the
        hybrid's worst margin -36.72 m in the search, -34.28 m in the file).

        Raises
        ------
        ConfigError
            ``params`` give an invalid scenario (``label`` names the candidate).
        """
        from mpcasv.sim.scenario import scenario_from_dict

        data = {**substitute(self.family, params), "controller": self.controller}
        data.pop("preset", None)
        if self.preset is not None:
            data["preset"] = self.preset
        return scenario_from_dict(data, f"{self.family.source} ({label})"), data

    def trial_args(self, params: dict, number: int) -> tuple:
        _, data = self.scenario(params, f"trial {number}")
        return (data, f"{self.family.source} (trial {number})", self.controller, self.preset,
                self.seed, self.r_sep)  # fmt: skip


def _complete(study, trials, dists: dict, seed: int) -> None:
    """Draw the parameters ``trials`` (RUNNING) lack, by the CMA-ES sampler seeded with
    ``seed``: a search killed while a batch was being asked left a trial with some of them
    (every resume then failed in a traceback on the first missing one, a new user's
    Ctrl-C, session 47)."""
    import optuna

    study.sampler = optuna.samplers.CmaEsSampler(seed=seed, warn_independent_sampling=False)
    for t in trials:
        trial = optuna.trial.Trial(study, t._trial_id)
        for name, d in dists.items():
            if name in t.params:
                continue
            if isinstance(d, optuna.distributions.IntDistribution):
                trial.suggest_int(name, d.low, d.high)
            else:
                trial.suggest_float(name, d.low, d.high)


def search(setup: SearchSetup, storage_path: Path, budget: int, workers: int = 1,
           progress: Callable[[int, dict], None] | None = None,
           timeout: float | None = None):  # fmt: skip
    """Run (or resume) the CMA-ES search until ``budget`` runs are finished; return the study.

    ``timeout`` (s of wall clock per run, None: no limit): a run that takes longer is
    recorded as failed with a ``timeout`` error (see :mod:`mpcasv.experiments.falsify_pool`).
    ``workers``: at most ``min(BATCH, budget)`` processes start (no more runs go at once).

    The study lives in the SQLite file ``storage_path`` (Optuna RDB storage). Finished trials
    (complete, or failed with their ``error``) are kept and counted (more of them than
    ``budget``: :class:`~mpcasv.config.ConfigError`). Trials a killed search
    left running are run again first, with their parameters and under their numbers, and
    each batch's sampler is seeded from the search's seed and the number of trials asked
    before it (:func:`batch_seed`), so a search killed while its runs go and resumed asks and
    runs what the search run at once does. Not if it was stopped while a batch was being asked
    (milliseconds between runs): the parameters its trials lack are drawn then
    (:func:`_complete`) and the batches after it start from other trial counts; nor when
    a finished search's budget, not a multiple of :data:`BATCH`, is raised (its last batch was
    short). (Until session 44 the interrupted trials were marked failed and
    others asked in their place, and the sampler's generator ran on from its seed in each
    process: a resumed search was another search, and its worst case could be missed.)
    """
    import optuna

    from mpcasv.experiments.falsify_pool import WorkerPool, run_batch
    from mpcasv.experiments.workers import pool_size

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = optuna.storages.RDBStorage(f"sqlite:///{storage_path}")
    named = setup.named or (Path(setup.preset).stem if setup.preset else "default")
    name = f"{setup.family.name}-{setup.controller}-{named}-{setup.objective}"
    study = optuna.create_study(study_name=name, storage=storage, direction="minimize",
                                load_if_exists=True)  # fmt: skip
    study_id = storage.get_study_id_from_name(name)
    if (done := n_finished(study)) > budget:  # the runs are there: a smaller budget is no
        # search's (its summary said budget B above more finished runs, session 47)
        raise ConfigError(f"{storage_path}: holds {done} finished runs already, more than "
                          f"--budget {budget}; give at least {done}")  # fmt: skip
    dists = {p.name: (optuna.distributions.IntDistribution(int(p.low), int(p.high))
                      if p.integer else optuna.distributions.FloatDistribution(p.low, p.high))
             for p in setup.family.spec.param}  # fmt: skip

    def tell(trial, measures, error):
        tid = storage.get_trial_id_from_study_id_trial_number(study_id, trial.number)
        if error is not None:
            storage.set_trial_user_attr(tid, "error", error)
            study.tell(trial.number, state=optuna.trial.TrialState.FAIL)
        else:
            for k, v in measures.items():
                storage.set_trial_user_attr(tid, k, v)
            study.tell(trial.number, objective_value(measures, setup.objective))
        if progress is not None:
            progress(trial.number, measures if error is None else {"error": error})

    def items(trials):
        return [(t, (lambda t=t: setup.trial_args(t.params, t.number))) for t in trials]

    with WorkerPool(pool_size(workers, min(BATCH, budget)), timeout) as pool:
        left = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,))
        partial = [t for t in left if set(t.params) != set(dists)]
        if partial:  # killed while its batch was being asked: draw what was not drawn
            _complete(study, partial, dists, batch_seed(setup.seed, min(t.number for t in
                                                                       partial)))  # fmt: skip
            left = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,))
        if left:  # a killed search's unfinished batch, as it was asked
            run_batch(items(left), pool, tell)
        while (done := n_finished(study)) < budget:
            study.sampler = optuna.samplers.CmaEsSampler(
                seed=batch_seed(setup.seed, len(study.get_trials(deepcopy=False))),
                warn_independent_sampling=False)  # fmt: skip
            run_batch(items([study.ask(dists) for _ in range(min(BATCH, budget - done))]),
                      pool, tell)  # fmt: skip
    return study


def batch_seed(seed: int, asked: int) -> int:
    """The sampler's seed for a batch asked after ``asked`` trials of a search seeded
    ``seed`` (a 32-bit integer, as numpy takes)."""
    return int(np.random.SeedSequence([seed, asked]).generate_state(1)[0])


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
