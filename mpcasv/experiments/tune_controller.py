"""``mpcasv tune controller``: a multi-objective search over a controller's preset fields
(issue 17 items 1 and 4), with Optuna.

A **trial** is one point of the declared ranges (:mod:`mpcasv.experiments.tune_space`). It is
evaluated on the **training set**, the jobs of one ``[[controllers]]`` entry of a suite
(scenarios x seeds: realisations of the scenarios' ``[uncertain]`` tables), each job run with
the trial's values as overrides; its objective values are the means over those runs of the
named ``metrics.json`` keys, and its constraint value is the sum of ``collision_domain_s``
over them, stored with Optuna's ``Trial.set_constraint`` (Optuna 5's replacement of the
samplers' ``constraints_func``; NSGA-II's constrained domination and TPE's feasibility
weighting read it): a trial is feasible when the value is <= 0, i.e. no run entered a
collision domain. No penalty is added to the objectives. A trial whose values the preset
refuses (e.g. ``eps_minus > delta_r``) fails without a run; it counts in the budget (a range
end refused whatever the other fields is refused before the search:
:func:`~mpcasv.experiments.tune_jobs.check_presets`). The trials on the training front are then
run on **held-out** realisations: the same scenarios and conditions, other seeds. The jobs of
both sets and of each trial: :mod:`mpcasv.experiments.tune_jobs`.

Reproducible and resumable:

* the trials are asked in fixed-size **batches** (``batch``, the NSGA-II population) and all
  of a batch's runs are done before the next batch is asked, so the sampler sees the same
  history whatever the number of workers or the order in which runs finish;
* the sampler is rebuilt before each draw with a seed derived from (``seed``, trial number;
  and the field, for a field drawn alone: :func:`draw`), and NSGA-II's parents are in trial
  order however they were obtained (:func:`_nsga2_class`): a resumed search asks the same
  trials as one that was never interrupted, even when it was killed between two of a
  trial's values (until session 45 it did not: see :func:`draw`);
* the study lives in ``DIR/study.db`` (Optuna's RDB storage, SQLite); every finished run is
  written at once as a part (``DIR/train/parts``, ``DIR/heldout/parts``: the runner's store),
  keyed by a job id that is a hash of the base job and the trial's values. Killing the
  command loses no finished run and no finished trial: a rerun evaluates the trials left
  running (only their missing runs) and goes on.

Runs go through the suite runner's machinery (:func:`mpcasv.experiments.runner.run_jobs`):
in this process, on a local process pool, or on Dask.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
from pathlib import Path

import numpy as np

from mpcasv.config import ConfigError
from mpcasv.experiments.suite import Job
from mpcasv.experiments.tune_jobs import (
    check_presets,
    heldout_jobs,
    invalid_preset,
    training_jobs,
    trial_jobs,
)
from mpcasv.experiments.tune_space import TuneSpec
from mpcasv.wording import count

STUDY_NAME = "tune-controller"
#: how a trial's values are drawn (:func:`draw`): 2 since session 45, each value drawn alone
#: from a sampler of its own. A study begun with another way cannot ask or redraw trials
#: that are the same search's (:func:`open_study` refuses it unless it has nothing to draw)
DRAW = 2


def spec_fingerprint(spec: TuneSpec, train: list[Job]) -> dict:
    """What must not change between a search and its resumption (the budget may grow)."""
    return {"controller": spec.controller, "objectives": list(spec.objectives),
            "constraint": spec.constraint, "sampler": spec.sampler, "batch": spec.batch,
            "seed": spec.seed, "params": [dataclasses.asdict(p) for p in spec.params],
            "train_jobs": [j.job_id for j in train], "draw": DRAW}  # fmt: skip


def _trial_seed(seed: int, number: int, field: int | None = None) -> int:
    key = [seed, number] if field is None else [seed, number, field]
    return int(np.random.SeedSequence(key).generate_state(1)[0])


@functools.cache
def _nsga2_class():
    import optuna

    class NSGAIISampler(optuna.samplers.NSGAIISampler):
        """Optuna's NSGA-II, its parent population in trial order however it is obtained.

        Optuna (5.1) caches a generation's parents in the study as trial ids and reads them
        back in trial order, but the ask that first selects them gets them in the elite
        selection's order (rank, then crowding distance): the child crossed from them then
        differs with the order (the parents are picked by index). A search killed after the
        parents were cached and before that trial's values were all written drew it again
        from the cached order: another trial (trial 2's ``eps_plus`` from the other parent,
        tests/test_tune_controller.py). Named as Optuna's class on purpose: its GA base
        class keys the generation and parent-cache attributes by the class name
        (``NSGAIISampler:generation``), so studies stay readable both ways.
        """

        def select_parent(self, study, generation):
            return sorted(super().select_parent(study, generation), key=lambda t: t.number)

    return NSGAIISampler


def make_sampler(spec: TuneSpec, number: int, field: int | None = None):
    """The sampler that asks trial ``number`` (seeded by ``spec.seed`` and ``number``), or,
    with ``field`` (index in ``spec.params``), that draws that field alone (:func:`draw`)."""
    import optuna

    seed = _trial_seed(spec.seed, number, field)
    if spec.sampler == "tpe":
        return optuna.samplers.TPESampler(seed=seed, multivariate=True,
                                          n_startup_trials=spec.batch)  # fmt: skip
    return _nsga2_class()(population_size=spec.batch, seed=seed)


def directions(spec: TuneSpec) -> list[str]:
    from mpcasv.experiments.metrics import METRIC_INFO

    return ["minimize" if METRIC_INFO[m].better == "lower" else "maximize"
            for m in spec.objectives]  # fmt: skip


def study_size(out: Path) -> int:
    """The trials of the search study in ``out/study.db`` (0 without one, or if it cannot be
    read: :func:`open_study` says why later)."""
    db = Path(out).resolve() / "study.db"
    if not db.is_file():
        return 0
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        study = optuna.load_study(study_name=STUDY_NAME, storage=f"sqlite:///{db}")
        return len(study.get_trials(deepcopy=False))
    except Exception:  # another study, or not a study at all: refused by open_study
        return 0


def open_study(spec: TuneSpec, out: Path, train: list[Job]):
    """Create or load the study in ``out/study.db``; refuse one made for another search."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = f"sqlite:///{out / 'study.db'}"
    if (out / "study.db").exists():  # e.g. mpcasv falsify's: another study in the same file
        names = optuna.study.get_all_study_names(storage)
        if names and STUDY_NAME not in names:
            raise ConfigError(f"{out / 'study.db'}: holds the Optuna studies {names}, not a "
                              "search of 'mpcasv tune controller'; use another --out")  # fmt: skip
    study = optuna.create_study(study_name=STUDY_NAME, storage=storage, load_if_exists=True,
                                directions=directions(spec),
                                sampler=make_sampler(spec, 0))  # fmt: skip
    fp = spec_fingerprint(spec, train)
    old = study.user_attrs.get("spec")
    n = len(study.get_trials(deepcopy=False))
    if old is not None and old.get("draw") != DRAW and {**old, "draw": DRAW} == fp:
        done = n >= spec.trials and not study.get_trials(
            deepcopy=False, states=(optuna.trial.TrialState.RUNNING,))  # fmt: skip
        if not done:  # it would ask or redraw trials: they would be neither search's
            raise ConfigError(f"{out / 'study.db'}: a search begun before session 45, which "
                              "drew a trial's values in another way: resumed or extended now "
                              "it would be neither search; use another --out")  # fmt: skip
    elif old is None:
        study.set_user_attr("spec", fp)
    elif old != fp:
        changed = sorted(k for k in fp if fp[k] != old.get(k))
        said = {"train_jobs": "training jobs (the suite's scenarios, seeds, duration, or the "
                              "entry's preset or overrides)",
                "params": "params (the searched fields or their ranges)"}  # fmt: skip
        what = "; ".join(said.get(k, f"{k} {old.get(k)!r} -> {fp[k]!r}") for k in changed)
        raise ConfigError(f"{out / 'study.db'}: holds a search with other {what} than "
                          f"{spec.path}; use another --out")  # fmt: skip
    if n > spec.trials:  # a smaller budget cannot be honoured: the trials are there
        raise ConfigError(f"{out / 'study.db'}: holds {n} trials already, more than the budget "
                          f"{spec.trials} (trials or --trials); give at least {n}")  # fmt: skip
    seeds = out / "heldout" / "seeds.json"  # written by the first held-out runs
    held = json.loads(seeds.read_text()) if seeds.exists() else None
    if held is not None and held != list(spec.heldout_seeds):
        raise ConfigError(f"{out / 'heldout'}: its runs used heldout_seeds {held}, {spec.path} "
                          f"says {list(spec.heldout_seeds)}: the folder would hold both; use "
                          "another --out (copy study.db and train/ there to keep the search's "
                          "trials and runs)")  # fmt: skip
    return study


def draw(study, spec: TuneSpec, trial_id: int, number: int) -> dict:
    """Draw trial ``number``'s values (``trial_id`` its storage id), or those a killed search
    left undrawn: the same values either way.

    The values the sampler draws together (NSGA-II's child of two parents, multivariate
    TPE's) come from the trial's sampler (:func:`make_sampler` with ``number``), which draws
    them again alike from the same history. A value drawn alone (NSGA-II's first generation
    and its mutated fields, TPE's start-up trials) comes from a sampler of its own
    (``number`` and the field's index). Until session 45 one sampler drew them one after
    another, so a search killed after a trial's first value drew the next with the first
    one's random number: another trial than the uninterrupted search's.
    """
    import optuna

    trial = optuna.trial.Trial(study, trial_id)
    study.sampler = make_sampler(spec, number)
    _ = trial.relative_params  # the joint draw, now, by this sampler (the Trial keeps it)
    values = {}
    for i, p in enumerate(spec.params):
        study.sampler = make_sampler(spec, number, i)
        if p.int:
            values[p.name] = trial.suggest_int(p.name, p.low, p.high, log=p.log)
        else:
            values[p.name] = trial.suggest_float(p.name, p.low, p.high, log=p.log)
    return values


def run_batch(jobs: list[Job], out: Path, workers: int, dask: str | None, quiet: bool,
              name: str):  # fmt: skip
    """Run the jobs without a part in ``out`` (the runner's machinery); their rows."""
    from mpcasv.experiments.runner import (
        SweepStats,
        prepare_controllers,
        run_jobs,
        say_untested_current,
    )
    from mpcasv.experiments.store import done_ids, read_parts

    out.mkdir(parents=True, exist_ok=True)
    done = done_ids(out)
    todo = [j for j in jobs if j.job_id not in done]
    if todo:
        prepare_controllers(todo, quiet, dask)
        stats = SweepStats(name, len(jobs), len(jobs) - len(todo), workers=workers)
        run_jobs(sorted(todo, key=lambda j: (-j.cost, j.index)), out, stats, workers, dask,
                 quiet)  # fmt: skip
    rows = read_parts(out, [j.job_id for j in jobs])
    if todo and len(rows):
        say_untested_current(rows[rows["job_id"].isin({j.job_id for j in todo})])
    return rows


def aggregate(spec: TuneSpec, rows) -> tuple[list[float] | None, float, str | None]:
    """(objective means over the runs, summed constraint, error) of one trial's rows; the
    values are None when a run failed or a metric is missing (the trial fails)."""
    bad = rows[rows["status"] != "ok"]
    if len(bad):
        last = str(bad.iloc[0]["error"]).strip().splitlines()[-1]
        return None, float("nan"), f"{len(bad)} run(s) failed: {last}"
    values = []
    for m in spec.objectives:
        col = rows[m].astype(float)
        if col.isna().any():
            return None, float("nan"), f"metric {m} is missing (NaN) in a run"
        values.append(float(col.mean()))
    if not spec.constraint:
        return values, 0.0, None
    col = rows[spec.constraint].astype(float)
    if col.isna().any():  # a sum skips NaN: a run without the measure counted as feasible
        return None, float("nan"), (f"constraint {spec.constraint} is missing (NaN) in a run "
                                    "(a scenario without that domain?)")  # fmt: skip
    return values, float(col.sum()), None


def _ask_batch(study, spec: TuneSpec) -> list:
    """Trials of the current batch still to evaluate (RUNNING), asking the missing ones."""
    from optuna.trial import TrialState

    trials = study.get_trials(deepcopy=False)
    n = len(trials)
    running = [t for t in trials if t.state == TrialState.RUNNING]
    names = {p.name for p in spec.params}
    for t in running:  # killed between asking a trial and drawing all its values: draw them
        if not names <= set(t.params):  # first, as they were drawn before the later trials
            draw(study, spec, t._trial_id, t.number)
    # a batch left running (killed) is finished first, else a new batch starts at trial n
    start = (min(t.number for t in running) // spec.batch) * spec.batch if running else n
    end = min(start + spec.batch, spec.trials)
    while n < end:
        study.sampler = make_sampler(spec, n)
        trial = study.ask()
        draw(study, spec, trial._trial_id, trial.number)
        n += 1
    return [t for t in study.get_trials(deepcopy=False) if t.state == TrialState.RUNNING]


def search(spec: TuneSpec, out: str | Path, workers: int = 1, dask: str | None = None,
           quiet: bool = False):  # fmt: skip
    """Run (or resume) the search until ``spec.trials`` trials are finished.

    Returns
    -------
    optuna.Study
        The study (``DIR/study.db``); its user attribute ``wall_s`` sums the wall time of
        every session, ``sessions`` counts them.
    """
    import optuna
    from optuna.trial import TrialState

    out = Path(out).resolve()
    train = check_presets(spec)
    out.mkdir(parents=True, exist_ok=True)
    study = open_study(spec, out, train)
    t0 = time.perf_counter()
    wall0 = float(study.user_attrs.get("wall_s", 0.0))
    study.set_user_attr("sessions", int(study.user_attrs.get("sessions", 0)) + 1)
    try:
        while True:
            batch = _ask_batch(study, spec)
            if not batch:
                break
            invalid = {t.number: invalid_preset(spec, train, dict(t.params)) for t in batch}
            jobs = {t.number: trial_jobs(train, t.number, dict(t.params)) for t in batch
                    if invalid[t.number] is None}  # fmt: skip
            first, last = batch[0].number, batch[-1].number
            if not quiet:
                print(f"trials {first}-{last} of {spec.trials}: {len(jobs)} x "
                      f"{count(len(train), 'run')} "
                      f"({len(batch) - len(jobs)} refused by the preset)")  # fmt: skip
            rows = run_batch([j for js in jobs.values() for j in js], out / "train", workers,
                             dask, quiet, f"trials {first}-{last}")  # fmt: skip
            by_id = rows.set_index("job_id") if len(rows) else rows
            study.sampler = make_sampler(spec, last)
            for t in batch:  # told in trial order: the same history for any worker count
                handle = optuna.trial.Trial(study, t._trial_id)  # attributes of a stored trial
                if invalid[t.number] is not None:
                    values, c, err = None, None, invalid[t.number]
                else:
                    values, c, err = aggregate(spec, by_id.loc[[j.job_id for j in jobs[t.number]]])
                if values is None:
                    handle.set_user_attr("error", err)
                    study.tell(t.number, state=TrialState.FAIL)
                    continue
                if spec.constraint:
                    handle.set_constraint(spec.constraint, c)
                study.tell(t.number, values)
            study.set_user_attr("wall_s", wall0 + time.perf_counter() - t0)
    finally:
        study.set_user_attr("wall_s", wall0 + time.perf_counter() - t0)
    return study


def front_trials(study) -> list:
    """The training Pareto front: complete, feasible, non-dominated trials (by number)."""
    return sorted(study.best_trials, key=lambda t: t.number)


def evaluate_heldout(spec: TuneSpec, study, out: str | Path, workers: int = 1,
                     dask: str | None = None, quiet: bool = False) -> dict:  # fmt: skip
    """Run the front's trials on the held-out realisations; ``{number: (values, constraint,
    error)}`` (as :func:`aggregate`)."""
    out = Path(out).resolve()
    base = heldout_jobs(spec, training_jobs(spec))
    front = front_trials(study)
    jobs = {t.number: trial_jobs(base, t.number, dict(t.params)) for t in front}
    if not jobs:
        return {}
    (out / "heldout").mkdir(parents=True, exist_ok=True)  # checked by open_study
    (out / "heldout" / "seeds.json").write_text(json.dumps(list(spec.heldout_seeds)) + "\n")
    if not quiet:
        print(f"held-out: {count(len(front), 'front trial')} x {count(len(base), 'run')} (seeds "
              f"{list(spec.heldout_seeds)})")  # fmt: skip
    t0 = time.perf_counter()
    rows = run_batch([j for js in jobs.values() for j in js], out / "heldout", workers, dask,
                     quiet, "held-out").set_index("job_id")  # fmt: skip
    study.set_user_attr("heldout_wall_s", float(study.user_attrs.get("heldout_wall_s", 0.0))
                        + time.perf_counter() - t0)  # fmt: skip
    return {n: aggregate(spec, rows.loc[[j.job_id for j in js]]) for n, js in jobs.items()}
