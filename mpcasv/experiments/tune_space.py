"""The range file of ``mpcasv tune controller`` (issue 17 item 1): which preset fields of which
controller to search, over which training set, toward which objectives.

```toml
controller = "hybrid-single"          # registered controller (its preset fields are searched)
suite = "train-c1c3.toml"             # training set: a suite (scenarios x seeds); a name in
                                      # experiments/suites or a path relative to this file
label = "hybrid"                      # the suite's [[controllers]] entry (default: the only one)
heldout_seeds = [100, 101, 102]       # held-out realisations: same scenarios, other seeds
objectives = ["reliable_fix_age_p95_s", "nav_error_rms_m", "energy_J"]  # metrics.json keys
constraint = "collision_domain_s"     # must be 0 on every training run ("" : none)
sampler = "nsga2"                     # "nsga2" (default) or "tpe"
trials = 40                           # budget: trials (each = one run per training job)
batch = 8                             # trials asked and evaluated together (NSGA-II population)
seed = 0                              # the sampler's seed

[params]                              # dotted preset fields: bounds, log scale, integer
"domain.delta_r" = { low = 5.0, high = 150.0 }
"weights.dT" = { low = 0.001, high = 1.0, log = true }
"horizon.N" = { low = 8, high = 20, int = true }
```

Every problem is refused with one line naming the file and the field (:class:`ConfigError`),
among them a range end the preset field does not accept (``speed`` from -1: its type says
> 0) or that the suite's presets refuse whatever the other searched fields are
(:func:`check_range_ends`): such trials failed one by one and the search exited 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mpcasv.config import SEED_MAX, ConfigError, load_toml

#: default objectives (metrics.json keys, all "lower is better"; issue 17 item 1)
DEFAULT_OBJECTIVES = ("reliable_fix_age_p95_s", "nav_error_rms_m", "energy_J")
#: default constraint: no time inside the collision domain (Paper 1 eq. 5; Paper 2 eqs. 4-5)
DEFAULT_CONSTRAINT = "collision_domain_s"
SAMPLERS = ("nsga2", "tpe")
_TOP_KEYS = {"controller", "suite", "label", "heldout_seeds", "objectives", "constraint",
             "sampler", "trials", "batch", "seed", "params"}  # fmt: skip
_RANGE_KEYS = {"low", "high", "log", "int"}


@dataclass(frozen=True)
class ParamRange:
    """One searched preset field: ``low <= value <= high``, optionally on a log scale
    (``low > 0``) and integer."""

    name: str  # dotted preset field, e.g. "domain.delta_r"
    low: float
    high: float
    log: bool = False  # checked by _range (a plain dataclass: no validation here)
    int: bool = False


@dataclass(frozen=True)
class TuneSpec:
    """A validated range file (see the module docstring); ``suite`` is an absolute path or
    a shipped suite name."""

    path: Path
    controller: str
    suite: str
    label: str | None
    heldout_seeds: tuple[int, ...]
    objectives: tuple[str, ...]
    constraint: str | None
    sampler: str
    trials: int
    batch: int
    seed: int
    params: tuple[ParamRange, ...]


def _fail(path: Path, msg: str):
    raise ConfigError(f"{path}: {msg}")


def _number(path: Path, where: str, v: Any, integer: bool) -> float:
    ok = isinstance(v, int) and not isinstance(v, bool)
    if not integer:
        ok = ok or isinstance(v, float)
    if not ok or not math.isfinite(v):
        _fail(path, f"{where}: expected {'an integer' if integer else 'a finite number'}, "
                    f"got {v!r}")  # fmt: skip
    return v


def _range(path: Path, name: str, spec: Any) -> ParamRange:
    where = f"params.{name!r}"
    if not isinstance(spec, dict):
        _fail(path, f"{where}: expected a table {{ low = ..., high = ... }}, got {spec!r}")
    unknown = set(spec) - _RANGE_KEYS
    if unknown:
        _fail(path, f"{where}: unknown keys {sorted(unknown)}; known: {sorted(_RANGE_KEYS)}")
    for key in ("low", "high"):
        if key not in spec:
            _fail(path, f"{where}: '{key}' is missing")
    for key in ("log", "int"):
        if not isinstance(spec.get(key, False), bool):
            _fail(path, f"{where}: '{key}' must be true or false, got {spec[key]!r}")
    integer = spec.get("int", False)
    low = _number(path, f"{where}.low", spec["low"], integer)
    high = _number(path, f"{where}.high", spec["high"], integer)
    if not low < high:
        _fail(path, f"{where}: low = {low!r} must be below high = {high!r}")
    if spec.get("log", False) and low <= 0:
        _fail(path, f"{where}: a log scale needs low > 0, got {low!r}")
    return ParamRange(name, float(low) if not integer else int(low),
                      float(high) if not integer else int(high),
                      spec.get("log", False), integer)  # fmt: skip


def _int_list(path: Path, key: str, v: Any) -> tuple[int, ...]:
    if not isinstance(v, list) or not v:
        _fail(path, f"{key}: expected a non-empty list of seeds, got {v!r}")
    for s in v:
        if not isinstance(s, int) or isinstance(s, bool) or not 0 <= s <= SEED_MAX:
            _fail(path, f"{key}: a seed is an integer in [0, 2**32 - 1], got {s!r}")
    if len(set(v)) != len(v):
        _fail(path, f"{key}: duplicate seeds {v}")
    return tuple(v)


def _check_fields(path: Path, spec: TuneSpec) -> None:
    """Every field exists in the controller's preset and accepts both bounds."""
    from mpcasv.controllers import controller_kind
    from mpcasv.experiments.metrics import METRIC_INFO, WALL_CLOCK

    try:
        controller_kind(spec.controller)
    except ConfigError as exc:
        _fail(path, f"controller: {exc}")
    for m in (*spec.objectives, *([spec.constraint] if spec.constraint else [])):
        if m not in METRIC_INFO:
            _fail(path, f"unknown metric {m!r} (metrics.json keys: see docs/metrics.md)")
        if METRIC_INFO[m].better not in ("lower", "higher"):
            _fail(path, f"metric {m!r} has no better direction: it cannot be an objective")
        if m.endswith("_auv"):  # a list per AUV in metrics.json, not one number per run
            _fail(path, f"metric {m!r} is a per-AUV list: use the run's scalar "
                        f"{m.removesuffix('_auv')!r} (its value over the AUVs)")  # fmt: skip
        if m in WALL_CLOCK:
            _fail(path, f"metric {m!r} is measured in wall time (machine- and load-dependent): "
                        "a search toward it would not be reproducible")  # fmt: skip
    if spec.constraint in spec.objectives:  # its column would hold the sum, not the mean
        _fail(path, f"constraint: {spec.constraint!r} is also an objective; 'summed <= 0' would "
                    "fix that objective at 0 on every feasible trial: drop one of them")
    if spec.constraint and METRIC_INFO[spec.constraint].better != "lower":
        _fail(path, f"constraint: {spec.constraint!r} is better higher; the constraint is "
                    "'summed over the training runs <= 0', so it must be a lower-is-better "
                    "amount (a time or a count, e.g. collision_domain_s)")  # fmt: skip
    params_cls = controller_kind(spec.controller).params_cls
    for p in spec.params:
        kind = _field_type(params_cls, p.name)
        if kind is None:
            _fail(path, f"params.{p.name!r}: {spec.controller} presets have no such field")
        if kind not in (float, int) or (p.int and kind is not int) or (kind is int and not p.int):
            what = {float: "a float: drop 'int'", int: "an integer: add int = true"}.get(
                kind, f"not a number ({getattr(kind, '__name__', kind)})"
            )
            _fail(path, f"params.{p.name!r}: the preset field is {what}")
        _check_bounds(path, spec.controller, p, _field_type(params_cls, p.name, extras=True))
    # ends refused with every setting of the other fields: check_range_ends (needs the
    # suite's presets); other combinations the preset refuses (e.g. eps_minus > delta_r)
    # are found per trial: such a trial fails without a run (mpcasv.experiments.tune_controller)


def _check_bounds(path: Path, controller: str, p: ParamRange, annotation) -> None:
    """Both bounds of ``p`` are values the preset field (its annotated type) accepts."""
    from pydantic import TypeAdapter, ValidationError

    for end, value in (("low", p.low), ("high", p.high)):
        try:
            TypeAdapter(annotation).validate_python(value)
        except ValidationError as exc:
            cause = "; ".join(e["msg"] for e in exc.errors())
            _fail(path, f"params.{p.name!r}: {end} = {value!r} is outside what {controller} "
                        f"presets accept for {p.name} ({cause})")  # fmt: skip


def check_range_ends(spec: TuneSpec, presets) -> None:
    """Refuse a range end that the preset refuses whatever the other searched fields are.

    ``presets``: the training jobs' ``(preset, overrides)`` pairs. Each end of each range is
    loaded with the other searched fields at the preset's own values, at their lows, their
    midpoints and their highs; an end refused in all four (a trial there could never run) is
    refused before the search, naming the file, the field, the end and the preset's cause.

    Raises
    ------
    ConfigError
        One line: ``FILE: params.'speed': low = -1.0 is refused by ...: <cause>``.
    """
    from mpcasv.controllers import load_preset

    def mid(q: ParamRange):
        return (q.low + q.high) // 2 if q.int else 0.5 * (q.low + q.high)

    others = {"lows": lambda q: q.low, "midpoints": mid, "highs": lambda q: q.high}
    for preset, overrides in sorted(set(presets), key=str):
        for p in spec.params:
            for end, value in (("low", p.low), ("high", p.high)):
                contexts = [{}] + [{q.name: f(q) for q in spec.params if q is not p}
                                   for f in others.values()]  # fmt: skip
                causes = []
                for ctx in contexts:
                    try:
                        load_preset(spec.controller, preset,
                                    dict(overrides) | ctx | {p.name: value})  # fmt: skip
                        break
                    except ConfigError as exc:
                        causes.append(" ".join(str(exc).split()).removeprefix(
                            "invalid configuration "))  # fmt: skip
                else:
                    _fail(spec.path, f"params.{p.name!r}: {end} = {value!r} is refused by the "
                                     f"{spec.controller} preset {preset or 'default'} whatever "
                                     "the other searched fields (at the preset's values, their "
                                     f"lows, midpoints or highs): {causes[0]}")  # fmt: skip


def _field_type(cls: type, dotted: str, extras: bool = False):
    """The (unwrapped) type of the dotted field of parameter dataclass ``cls``; None: none.
    ``extras``: the field's annotation as declared (constraints kept, Optional kept)."""
    import dataclasses
    import typing

    for part in dotted.split("."):
        if not dataclasses.is_dataclass(cls):
            return None
        hints = typing.get_type_hints(cls, include_extras=True)
        if part not in hints:
            return None
        cls = hints[part]
    if extras:
        return cls

    def bare(t):  # Annotated[float, Gt(0)] -> float
        return typing.get_args(t)[0] if typing.get_origin(t) is typing.Annotated else t

    cls = bare(cls)
    args = typing.get_args(cls)  # Optional[float] (None: off): a number when searched
    if type(None) in args and len(args) == 2:
        cls = bare(next(a for a in args if a is not type(None)))
    return cls


def load_spec(path: str | Path, trials: int | None = None, done: int = 0) -> TuneSpec:
    """Load and validate a range file; ``trials`` replaces its budget when given. ``done``:
    the trials the output folder's study holds already (a budget below it is refused later,
    so a hint never offers one).

    Raises
    ------
    ConfigError
        One line: the file and the offending field (missing file, bad TOML, unknown key or
        metric or preset field, a non-numeric field, low >= high, log with low <= 0, a
        non-integer bound of an integer field, empty ranges or seeds).
    """
    path = Path(path).resolve()
    if not path.exists():
        raise ConfigError(f"{path}: no such range file")
    try:
        data = load_toml(path, "tuning range")
    except ConfigError as exc:
        raise ConfigError(" ".join(str(exc).split())) from None
    unknown = set(data) - _TOP_KEYS
    if unknown:
        _fail(path, f"unknown keys {sorted(unknown)}; known: {sorted(_TOP_KEYS)}")
    for key in ("controller", "suite", "heldout_seeds", "params"):
        if key not in data:
            _fail(path, f"'{key}' is missing")
    for key in ("controller", "suite", "label", "constraint", "sampler"):
        if key in data and not isinstance(data[key], str):
            _fail(path, f"{key}: expected a string, got {data[key]!r}")
    params = data["params"]
    if not isinstance(params, dict) or not params:
        _fail(path, "params: give at least one field to search")
    objectives = data.get("objectives", list(DEFAULT_OBJECTIVES))
    if (not isinstance(objectives, list) or not objectives
            or not all(isinstance(o, str) for o in objectives)):  # fmt: skip
        _fail(path, f"objectives: expected a non-empty list of metric names, got {objectives!r}")
    if len(set(objectives)) != len(objectives):
        _fail(path, f"objectives: duplicates {objectives}")
    sampler = data.get("sampler", "nsga2")
    if sampler not in SAMPLERS:
        _fail(path, f"sampler: {sampler!r} is not one of {list(SAMPLERS)}")
    n_trials = _number(path, "trials", data.get("trials", 40), True)
    batch = _number(path, "batch", data.get("batch", 8), True)
    seed = _number(path, "seed", data.get("seed", 0), True)
    for key, v, lo in (("trials", n_trials, 1), ("batch", batch, 2), ("seed", seed, 0)):
        if v < lo:
            _fail(path, f"{key}: must be >= {lo}, got {v}")
    if trials is not None:
        if trials < 1:
            raise ConfigError(f"--trials {trials}: must be >= 1")
        n_trials = trials
    if n_trials % batch:  # a partial last batch: extending it later would ask its trials
        # after the earlier ones are told, not as an uninterrupted search does (measured)
        lo, hi = (n_trials // batch) * batch, (n_trials // batch + 1) * batch
        least = -(-done // batch) * batch  # the smallest multiple not below the study's trials
        offer = sorted({v for v in (lo, hi) if v >= max(least, 1)} or {least})
        where = "--trials" if trials is not None else f"{path}: trials"
        held = f" (the study holds {done} trials already)" if done > lo else ""
        raise ConfigError(f"{where} = {n_trials} is not a multiple of batch = {batch}: a "
                          "partial last batch makes a later extension ask other trials than an "
                          f"uninterrupted search; use {' or '.join(map(str, offer))}{held}")
    suite = data["suite"]
    if suite.endswith(".toml") and not Path(suite).is_absolute():
        suite = str((path.parent / suite).resolve())
    spec = TuneSpec(
        path=path, controller=data["controller"], suite=suite, label=data.get("label"),
        heldout_seeds=_int_list(path, "heldout_seeds", data["heldout_seeds"]),
        objectives=tuple(objectives), constraint=data.get("constraint", DEFAULT_CONSTRAINT) or None,
        sampler=sampler, trials=int(n_trials), batch=int(batch), seed=int(seed),
        params=tuple(_range(path, k, v) for k, v in params.items()),
    )  # fmt: skip
    _check_fields(path, spec)
    return spec
