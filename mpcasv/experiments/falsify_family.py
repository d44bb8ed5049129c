"""Falsification families (issue 14): a template scenario plus the parameter ranges searched.

A *family* (TOML, e.g. ``experiments/falsify/pursuer-single.toml``) is a template scenario
plus parameter ranges. Each candidate scenario is the template with the parameters written
into dotted fields (``auv.0.events.0.pursuer.speed``; integer parts index lists) and is then
validated by the normal scenario loader, so a family can vary whatever the scenario format
expresses (pursuer speed, aim and timing; crossing AUV paths; depths and rises; current;
acoustic dropouts ...). A ``[[polar]]`` entry writes a pair of fields from a bearing (deg)
and a radius: ``origin + radius [cos b, sin b]`` (an approach direction, a current vector).

A family is checked whole before any run (:func:`load_family`): its ``name`` is a path name
(:data:`mpcasv.config.PathName`: it names the default output folder and the worst cases'
files ``falsified-<family>-<controller>-<rank>``), and the template with the parameters at
both ends of every range (the others at their midpoints), and at the box's corners, must be a
valid scenario (:func:`check_range_ends`; invalid corners of the box are warned of,
:func:`corner_warning`): a range reaching past what the scenario accepts
(``p_good`` up to 1.5) was found only at its midpoint, and the trials beyond were recorded as
"invalid scenario" while the search reported success.
"""

from __future__ import annotations

import copy
import fnmatch
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mpcasv.config import (
    ConfigError,
    FinitePos,
    Flag,
    Float,
    PathName,
    frozen,
    load_toml,
    parse,
    problems,
)

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
    integer: Flag = False
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
    relative to the family file) and the parameters searched. ``name`` is part of output
    paths (:data:`~mpcasv.config.PathName`)."""

    name: PathName
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
    """Load a family TOML file; check the template with every parameter at both ends of its
    range and at the corners of the box (:func:`check_range_ends`).

    Raises
    ------
    ConfigError
        Unreadable file, unknown keys, a name that cannot be part of a path, bad ranges,
        unknown fields or parameters, a template that the scenario loader refuses, or a
        range end (or corner) giving an invalid scenario (the message names the file and the
        parameter).
    """
    from mpcasv.sim.scenario import anchor_refs

    path = Path(path)
    fam = parse(Family, load_toml(path, "falsification family"), path)
    if (fam.template is None) == (fam.scenario is None):
        raise ConfigError(f"{path}: give exactly one of 'template' (a path) or [scenario]")
    if fam.template is not None:
        template_path = path.parent / fam.template
        template = load_toml(template_path, "scenario")
        anchor_refs(template, template_path.resolve().parent, template_path)
    else:
        template = copy.deepcopy(fam.scenario)
        anchor_refs(template, path.resolve().parent, path)
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
    check_range_ends(loaded)
    for r in time_ranges(loaded):
        if r.low >= r.duration:
            raise ConfigError(f"{path}: parameter {r.name!r} (field {r.field}): its times "
                              f"[{r.low:g}, {r.high:g}] s all lie past the run's duration "
                              f"{r.duration:g} s: nothing searched there happens; lower its "
                              "range or raise 'duration'")  # fmt: skip
    return loaded


#: the most corners of the parameter box :func:`check_range_ends` tries (2**12: ~0.5 s)
MAX_CORNERS = 2**12


def _ends(p: ParamSpec) -> tuple[float, float]:
    """The ends of a parameter's range as the search draws them (integers: Optuna's)."""
    return (int(p.low), int(p.high)) if p.integer else (p.low, p.high)


def _cause(exc: ConfigError) -> str:
    """A scenario loader's refusal in one line, without its 'invalid configuration' head."""
    return problems(exc)


def check_range_ends(family: LoadedFamily) -> None:
    """Refuse a family whose template is not a valid scenario at an end of some range, each
    parameter tried at its low and its high end with the others at their midpoints (the
    corners of the box are only warned of: :func:`corner_warning`).

    Raises
    ------
    ConfigError
        One line naming the file, the parameter, the end and its value, and the scenario
        loader's cause.
    """
    from mpcasv.estimation import check_plan_estimator

    params = family.spec.param
    mid = {p.name: 0.5 * (p.low + p.high) for p in params}
    # the estimator "plan" on AUVs none of which has a plan: every trial would fail late
    check_plan_estimator(candidate(family, mid, "midpoints")[0], None,
                         f"{family.source}: estimator 'plan'", "estimator = 'kalman'")  # fmt: skip
    for p in params:
        for end, value in zip(("low", "high"), _ends(p), strict=True):
            try:
                candidate(family, mid | {p.name: value}, f"{p.name} = {value:g}")
            except ConfigError as exc:
                raise ConfigError(f"{family.source}: parameter {p.name!r}: its {end} end "
                                  f"{value:g} (the others at their midpoints) gives an "
                                  f"invalid scenario: {_cause(exc)}; narrow its range") from None


def corner_warning(family: LoadedFamily) -> str | None:
    """One line if some corners of the parameter box (all parameters at an end, up to
    :data:`MAX_CORNERS`; for more parameters the all-low and all-high corners) give an
    invalid scenario: ends bad only together (e.g. ``t_attack + rise_after``, a polar
    radius with its bearing, ``d1 <= d2``). Said, not refused: a box cannot describe a
    search space that is not one (a review: ``d1`` in [300, 700] with ``d2`` in [600, 1000]
    is invalid in 3 % of the box, and was refused whole); such trials are recorded as
    invalid scenarios. None when every corner is valid."""
    params = family.spec.param
    if 2 ** len(params) <= MAX_CORNERS:
        corners = list(itertools.product((0, 1), repeat=len(params)))
    else:
        corners = [(0,) * len(params), (1,) * len(params)]
    bad, first = 0, None
    for corner in corners:
        values = {p.name: _ends(p)[i] for p, i in zip(params, corner, strict=True)}
        try:
            candidate(family, values, "a corner of the ranges")
        except ConfigError as exc:
            bad += 1
            if first is None:
                where = ", ".join(f"{p.name} = {values[p.name]:g} ({('low', 'high')[i]})"
                                  for p, i in zip(params, corner, strict=True))  # fmt: skip
                first = f"{where}: {_cause(exc)}"
    if not bad:
        return None
    return (f"warning: {family.source}: {bad} of {len(corners)} corners of the parameter box "
            f"give an invalid scenario (e.g. {first}); trials there are recorded as invalid")


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
