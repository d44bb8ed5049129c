"""The runs of a controller search (:mod:`mpcasv.experiments.tune_controller`).

- :func:`training_jobs`, :func:`check_presets`: the training set, the jobs of one
  ``[[controllers]]`` entry of a suite, refused when the search could not use them as they are
  (another controller, a grid, figures, an ``[acceptance]``, a held-out seed among them, range
  ends the preset refuses);
- :func:`heldout_jobs`: the held-out set, each training condition realised for the held-out
  seeds;
- :func:`trial_jobs`: the runs of one trial, the base jobs with the trial's values as
  overrides, their ids hashed from the base job and the values (a rerun finds its finished
  runs);
- :func:`invalid_preset`: why the preset refuses a trial's values (the trial fails without a
  run).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json

from mpcasv.config import ConfigError
from mpcasv.experiments.suite import Job, expand
from mpcasv.experiments.tune_space import TuneSpec


def _digest(obj) -> str:
    text = json.dumps(obj, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def training_jobs(spec: TuneSpec) -> list[Job]:
    """The base jobs of the training set: the suite's jobs of the entry ``spec.label``.

    Raises
    ------
    ConfigError
        The suite is invalid, the entry is missing or ambiguous, runs another controller than
        ``spec.controller``, has a grid, or a held-out seed is also a training seed.
    """
    exp = expand(spec.suite)
    from mpcasv.config import load_toml

    raw = load_toml(exp.path, "suite")  # what the file sets itself (not the defaults)
    if raw.get("plots", "none") != "none":  # trial and held-out runs draw no figures
        raise ConfigError(f"{spec.path}: suite {exp.path}: plots = {raw['plots']!r}: tune "
                          "controller draws no run figures, so it would be unused: set plots "
                          "= 'none' or leave it out")  # fmt: skip
    if "acceptance" in raw:  # no suite report here to judge it
        raise ConfigError(f"{spec.path}: suite {exp.path}: [acceptance]: tune controller "
                          "writes no suite report to judge it (its objectives and constraint "
                          "are the range file's), so it would be unused: remove it (judge the "
                          "chosen preset with mpcasv compare)")  # fmt: skip
    labels = sorted({j.label for j in exp.jobs})
    label = spec.label
    if label is None:
        if len(labels) != 1:
            raise ConfigError(f"{spec.path}: the suite has entries {labels}: name one as 'label'")
        label = labels[0]
    jobs = [j for j in exp.jobs if j.label == label]
    if not jobs:
        raise ConfigError(f"{spec.path}: label {label!r} is not an entry of suite {exp.path} "
                          f"(entries: {labels})")  # fmt: skip
    others = sorted({j.controller for j in jobs} - {spec.controller})
    if others:
        raise ConfigError(f"{spec.path}: entry {label!r} of {exp.path} runs {others}, not only "
                          f"{spec.controller!r}")  # fmt: skip
    if any(j.variant != j.label for j in jobs):
        raise ConfigError(f"{spec.path}: entry {label!r} of {exp.path} has a grid; the search "
                          "replaces it (remove the grid)")  # fmt: skip
    clash = sorted(set(spec.heldout_seeds) & set(exp.suite.seeds))
    if clash:
        raise ConfigError(f"{spec.path}: heldout_seeds {clash} are also training seeds of "
                          f"{exp.path}")  # fmt: skip
    return jobs


def check_presets(spec: TuneSpec) -> list[Job]:
    """The training jobs (:func:`training_jobs`), after refusing range ends that their presets
    refuse whatever the other searched fields
    (:func:`~mpcasv.experiments.tune_space.check_range_ends`; such trials failed one by one
    and the search ended with exit 0)."""
    from mpcasv.experiments.tune_space import check_range_ends

    train = training_jobs(spec)
    check_range_ends(spec, [(j.preset, j.overrides) for j in train])
    return train


def heldout_jobs(spec: TuneSpec, train: list[Job]) -> list[Job]:
    """Base jobs of the held-out set: each training condition (scenario, current, estimator)
    realised for every held-out seed (drawn as the suite draws them)."""
    from mpcasv.experiments.conditions import condition_scenario, realisations
    from mpcasv.sim.scenario import load_scenario

    firsts: dict = {}
    for j in train:
        firsts.setdefault((j.scenario_path, j.current_axis, j.current, j.estimator), j)
    out = []
    for base in firsts.values():
        sc = condition_scenario(load_scenario(base.scenario_path), base.current_axis,
                                base.current, base.duration)  # fmt: skip
        reals = realisations(sc, spec.heldout_seeds, f"{spec.path}: heldout_seeds")
        for seed in spec.heldout_seeds:
            real, cur = reals[seed]
            out.append(dataclasses.replace(
                base, seed=seed, realisation=real.id, current_realised=cur, plots=False,
                job_id=_digest([base.job_id, "heldout", seed, real.id]),
                index=len(out)))  # fmt: skip
    return out


def trial_jobs(base: list[Job], number: int, values: dict) -> list[Job]:
    """The runs of trial ``number``: each base job with ``values`` (dotted preset fields) as
    overrides (replacing the entry's own), no figures, and a job id hashed from the base
    job and the values (so a rerun finds its finished runs)."""
    out = []
    for j in base:
        overrides = dict(j.overrides) | values
        out.append(dataclasses.replace(
            j, overrides=tuple(sorted(overrides.items())), plots=False,
            variant=f"{j.label}[trial={number}]",
            job_id=_digest([j.job_id, sorted(values.items())])))  # fmt: skip
    return out


def invalid_preset(spec: TuneSpec, base: list[Job], values: dict) -> str | None:
    """Why the preset refuses ``values`` on some base job (one line), else None."""
    from mpcasv.controllers import load_preset

    for preset, overrides in {(j.preset, j.overrides) for j in base}:
        try:
            load_preset(spec.controller, preset, dict(overrides) | values)
        except ConfigError as exc:
            return "invalid preset: " + " ".join(str(exc).split())
    return None
