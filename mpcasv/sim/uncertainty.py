"""What a scenario leaves uncertain (its ``[uncertain]`` table) and one realisation per seed.

A scenario file states one nominal world. Its optional ``[uncertain]`` table declares, as
distributions, what is not known about that world: the current, the ASV's start, the acoustic
channel, and per AUV where its operation lies (offset, rotation), where it starts, how fast it
goes and when its scripted events (pursuits) happen. A seed draws one realisation: one value per
declared quantity. :func:`realise` gives the realised :class:`~mpcasv.sim.scenario.Scenario`
(the nominal one with the drawn values put in, revalidated) and the
:class:`~mpcasv.sim.realisation.Realisation` (the drawn values and a short id, recorded in
``run.json`` and the results table); how the values are put in is
:func:`mpcasv.sim.realisation.apply`.

Streams. Each quantity has its own random stream, derived from the seed, the scenario's name
and the quantity's key (e.g. ``case6/auv.auv1.offset_N``) with :class:`numpy.random.SeedSequence`
spawn keys; none is one of the world's streams (:mod:`mpcasv.sim.streams`: acoustics, INS
drift) and no
controller draws from them. So (scenario, seed) gives the same realisation for every controller
(paired comparisons), declaring one more uncertain quantity does not change the values drawn
for the others, and two scenarios draw independently for the same seed.

Distributions (``dist = ...``): ``uniform`` (``low``, ``high``), ``normal`` (``mean``, ``sd``
and the bounds ``low``, ``high``: truncated, ``scipy.stats.truncnorm``), ``choice``
(``values``, optional probabilities ``p``). The file format is in ``docs/experiments.md``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from mpcasv.config import DISTANCE_MAX, DURATION_MAX, ConfigError, frozen
from mpcasv.sim.distributions import Choice, Dist, Normal, Uniform, stream
from mpcasv.sim.realisation import Realisation, apply, world_digest


@frozen
class CurrentUncertainty:
    """The current: drawn speed and direction replace the nominal ones."""

    speed: Dist | None = None  # m/s
    direction_deg: Dist | None = None  # the direction it flows towards, from North (deg)


@frozen
class ASVUncertainty:
    """Offsets added to the ASV's start."""

    start_N: Dist | None = None  # m
    start_E: Dist | None = None  # m
    start_psi_deg: Dist | None = None  # deg


@frozen
class AcousticsUncertainty:
    """Channel parameters (see :class:`~mpcasv.models.acoustics.AcousticParams`)."""

    p_good: Dist | None = None
    p_sporadic: Dist | None = None
    propeller_factor: Dist | None = None
    sigma_bearing_deg: Dist | None = None
    sigma_range: Dist | None = None
    d1: Dist | None = None
    d2: Dist | None = None


@frozen
class AUVUncertainty:
    """One AUV (or every AUV, each drawn independently: key ``all``)."""

    offset_N: Dist | None = None  # m; moves its start and its routes together
    offset_E: Dist | None = None  # m
    rotation_deg: Dist | None = None  # turns its routes and headings about its nominal start
    start_N: Dist | None = None  # m; moves its start only (relative to its routes)
    start_E: Dist | None = None  # m
    start_psi_deg: Dist | None = None  # deg
    speed_factor: Dist | None = None  # multiplies every speed of its behaviours
    event_time_s: Dist | None = None  # s; added to each scripted event's time (each drawn)
    update_period_s: Dist | None = None  # s; replaces every pursuer's re-aim period


@frozen
class Uncertain:
    """A scenario's ``[uncertain]`` table."""

    current: CurrentUncertainty = CurrentUncertainty()
    asv: ASVUncertainty = ASVUncertainty()
    acoustics: AcousticsUncertainty = AcousticsUncertainty()
    auv: dict[str, AUVUncertainty] = dataclasses.field(default_factory=dict)  # name or "all"

    def is_empty(self) -> bool:
        return not any(_given(t) for t in (self.current, self.asv, self.acoustics)) and not any(
            _given(t) for t in self.auv.values()
        )


def _given(table) -> dict[str, Any]:
    """The declared (not None) distributions of a table, in field order."""
    return {f.name: getattr(table, f.name) for f in dataclasses.fields(table)
            if getattr(table, f.name) is not None}  # fmt: skip


def auv_uncertainty(unc: Uncertain, name: str) -> dict[str, Any]:
    """The distributions that apply to AUV ``name`` (its own table and ``all``)."""
    none = AUVUncertainty()
    return _given(unc.auv.get("all", none)) | _given(unc.auv.get(name, none))


def _behaviours(spec) -> list:
    """An AUVSpec's behaviour specs that have a speed to scale: the initial one and each
    switch event's (plan/pursuer/transit; a loiter's speed is a station-keeping cap, kept)."""
    return [b.plan or b.pursuer or b.transit for b in (spec.behaviour, *spec.events)]


def check_uncertain(sc) -> None:
    """Refuse an ``[uncertain]`` table that cannot be drawn or would change nothing.

    ``sc`` is a :class:`~mpcasv.sim.scenario.Scenario` (validated otherwise).

    Raises
    ------
    ValueError
        ``uncertain.<field>: <cause>`` for the first problem found.
    """
    unc: Uncertain = sc.uncertain
    names = [a.name for a in sc.auv]
    for key in unc.auv:
        if key != "all" and key not in names:
            raise ValueError(f"uncertain.auv.{key}: no AUV of that name (AUVs: {names}; "
                             "'all' means every AUV)")  # fmt: skip
    if "all" in unc.auv:
        for key, table in unc.auv.items():
            both = set(_given(table)) & set(_given(unc.auv["all"])) if key != "all" else set()
            if both:
                raise ValueError(f"uncertain.auv.{key}: {sorted(both)} also given under "
                                 "uncertain.auv.all (say it once)")  # fmt: skip
    _check_current(sc, unc.current)
    _check_acoustics(sc, unc.acoustics)
    _check_asv(sc, unc.asv)
    for spec in sc.auv:
        _check_auv(spec, auv_uncertainty(unc, spec.name))
        _check_auv_geometry(spec, auv_uncertainty(unc, spec.name))


#: the bound of every heading of a scenario (deg): ten turns either way (mpcasv.config.Heading)
HEADING_MAX = 3600.0


def _span(given: dict[str, Any], key: str) -> tuple[float, float]:
    """The support of ``given[key]``, (0, 0) when it is not uncertain."""
    return given[key].support() if key in given else (0.0, 0.0)


def _check_asv(sc, au: ASVUncertainty) -> None:
    """The ASV's start stays within the coordinate and heading bounds for every draw."""
    given, start = _given(au), sc.asv.start
    for key, nominal, bound in (("start_N", start.N, DISTANCE_MAX),
                                ("start_E", start.E, DISTANCE_MAX),
                                ("start_psi_deg", start.psi_deg, HEADING_MAX)):  # fmt: skip
        lo, hi = _span(given, key)
        if max(abs(nominal + lo), abs(nominal + hi)) > bound:
            raise ValueError(f"uncertain.asv.{key}: support [{lo}, {hi}] may move the start "
                             f"({nominal}) beyond the allowed +-{bound:g}")  # fmt: skip


def _points(spec) -> list[tuple[float, float]]:
    """Every horizontal point of an AUV's specification that its offsets and rotation move:
    its start, its plans' waypoints (lawnmowers' included) and its loiter points."""
    pts = [(spec.start.N, spec.start.E)]
    for b in (spec.behaviour, *spec.events):
        if getattr(b, "plan", None) is not None:
            pts += [(float(p[0]), float(p[1])) for seg in b.plan.route for p in seg.points()]
        loiter = getattr(b, "loiter", None)
        for at in (getattr(b, "at", None), None if loiter is None else loiter.at):
            if at is not None:
                pts.append((at[0], at[1]))
    return pts


def _headings(spec) -> list[float]:
    """The headings a rotation turns: lawnmowers' and transits' (the start's apart)."""
    out = []
    for b in (spec.behaviour, *spec.events):
        if getattr(b, "plan", None) is not None:
            out += [seg.lawnmower.heading_deg for seg in b.plan.route if seg.lawnmower]
        if getattr(b, "transit", None) is not None:
            out.append(b.transit.heading_deg)
    return out


def _check_auv_geometry(spec, given: dict[str, Any]) -> None:
    """An AUV's offsets, rotation and start shifts keep every point within the coordinate
    bound and every heading within ten turns, for every draw (conservatively: a rotated point
    may lie anywhere on its circle about the start)."""
    keys = [k for k in ("offset_N", "offset_E", "rotation_deg", "start_N", "start_E",
                        "start_psi_deg") if k in given]  # fmt: skip
    if not keys:
        return
    where = f"uncertain.auv ({spec.name})"
    N0, E0 = spec.start.N, spec.start.E
    rot = max(abs(x) for x in _span(given, "rotation_deg"))
    for i, (axis, origin) in enumerate((("N", N0), ("E", E0))):
        off = _span(given, f"offset_{axis}")
        shift = _span(given, f"start_{axis}")
        for k, p in enumerate(_points(spec)):
            r = math.hypot(p[0] - N0, p[1] - E0)
            lo, hi = (-r, r) if rot > 0 else (p[i] - origin, p[i] - origin)
            extra = shift if k == 0 else (0.0, 0.0)  # start_N/E move the start only
            reach = max(abs(origin + lo + off[0] + extra[0]), abs(origin + hi + off[1] + extra[1]))
            if reach > DISTANCE_MAX:
                raise ValueError(f"{where}: {', '.join(keys)} may move a point of the AUV to "
                                 f"{axis} = {reach:.4g} m, beyond the allowed +-{DISTANCE_MAX:g} "
                                 "m (what the fastest AUV covers in a week)")  # fmt: skip
    psi = max(abs(x) for x in _span(given, "start_psi_deg"))
    for h in [spec.start.psi_deg + math.copysign(psi, spec.start.psi_deg), *_headings(spec)]:
        if abs(h) + rot > HEADING_MAX:
            raise ValueError(f"{where}: {', '.join(keys)} may turn a heading ({h} deg) beyond "
                             f"the allowed +-{HEADING_MAX:g} deg (ten turns either way)")


def _check_current(sc, cu: CurrentUncertainty) -> None:
    if cu.speed is not None:
        lo, hi = cu.speed.support()
        extra = 0.0 if sc.current_field is None else sc.current_field.extra_max()
        if lo < 0 or hi + extra > 2.0:
            field = f" minus the current_field's {extra:.3g} m/s" if extra else ""
            raise ValueError(f"uncertain.current.speed: support [{lo}, {hi}] m/s must lie in "
                             f"[0, 2{field}] (above 2 m/s the ASV could not hold)")  # fmt: skip
        if cu.direction_deg is None and math.hypot(*sc.current) == 0.0:
            raise ValueError("uncertain.current.speed: the nominal current is zero, so it has no "
                             "direction: give uncertain.current.direction_deg too")  # fmt: skip
    elif cu.direction_deg is not None and math.hypot(*sc.current) == 0.0:
        raise ValueError("uncertain.current.direction_deg: the nominal current is zero, so a "
                         "direction changes nothing: give uncertain.current.speed too")  # fmt: skip


def _check_acoustics(sc, au: AcousticsUncertainty) -> None:
    from mpcasv.config import parse
    from mpcasv.models.acoustics import AcousticParams

    nominal = dataclasses.asdict(sc.acoustics)
    given = _given(au)
    for name, dist in given.items():
        if name in ("sigma_bearing_deg", "sigma_range") and not sc.acoustics.usbl:
            raise ValueError(f"uncertain.acoustics.{name}: the scenario has no USBL fixes "
                             "(acoustics.usbl = false), so it changes nothing")  # fmt: skip
        for value in dist.support():
            try:
                parse(AcousticParams, nominal | {name: value}, "acoustics")
            except ConfigError as exc:
                cause = str(exc).splitlines()[-1].split(": ", 2)[-1]
                raise ValueError(f"uncertain.acoustics.{name}: the value {value} of its support "
                                 f"is not allowed: {cause}") from None  # fmt: skip
    d1 = given["d1"].support()[1] if "d1" in given else sc.acoustics.d1
    d2 = given["d2"].support()[0] if "d2" in given else sc.acoustics.d2
    if d1 > d2:
        raise ValueError(f"uncertain.acoustics: d1 may reach {d1} m, above d2's {d2} m "
                         "(d2 >= d1 is required for every draw)")  # fmt: skip


def _check_auv(spec, given: dict[str, Any]) -> None:
    where = f"uncertain.auv ({spec.name})"
    behaviours = [b for b in _behaviours(spec) if b is not None]
    if "speed_factor" in given:
        lo, hi = given["speed_factor"].support()
        top = max((max(b.speed, getattr(b, "surface_speed", 0.0)) for b in behaviours),
                  default=0.0)  # fmt: skip
        if not behaviours:
            raise ValueError(f"{where}.speed_factor: the AUV has no plan, pursuer or transit, so "
                             "it changes nothing")  # fmt: skip
        if lo <= 0 or hi * top > spec.limits.speed_max:
            raise ValueError(f"{where}.speed_factor: support [{lo}, {hi}] must be > 0 and keep "
                             f"its fastest speed {top} m/s within limits.speed_max "
                             f"{spec.limits.speed_max} m/s")  # fmt: skip
    if "event_time_s" in given:
        lo, hi = given["event_time_s"].support()
        times = sorted(ev.t for ev in spec.events)
        if not times:
            raise ValueError(f"{where}.event_time_s: the AUV has no events, so it changes nothing")
        gap = min((b - a for a, b in zip(times, times[1:], strict=False)), default=math.inf)
        if times[0] + lo < 0 or times[-1] + hi > DURATION_MAX or hi - lo >= gap:
            raise ValueError(f"{where}.event_time_s: support [{lo}, {hi}] s must keep the events "
                             f"at 0 <= t <= {DURATION_MAX:g} s (a week, the longest run) and in "
                             f"order (first at {times[0]} s, last at {times[-1]} s, closest two "
                             f"{gap} s apart)")  # fmt: skip
    if "update_period_s" in given:
        if not any(hasattr(b, "update_period") for b in behaviours):
            raise ValueError(f"{where}.update_period_s: the AUV never pursues, so it changes "
                             "nothing")  # fmt: skip
        lo, hi = given["update_period_s"].support()
        if lo < 0 or hi > DURATION_MAX:
            raise ValueError(f"{where}.update_period_s: support [{lo}, {hi}] s must lie in "
                             f"[0, {DURATION_MAX:g}] s (a week, the longest run)")  # fmt: skip


# ----------------------------------------------------------------------------- drawing


def distributions(sc) -> dict[str, Any]:
    """Every uncertain quantity of scenario ``sc`` as ``{key: distribution}`` (draw order)."""
    unc: Uncertain = sc.uncertain
    out = {f"current.{k}": d for k, d in _given(unc.current).items()}
    out |= {f"asv.{k}": d for k, d in _given(unc.asv).items()}
    out |= {f"acoustics.{k}": d for k, d in _given(unc.acoustics).items()}
    for spec in sc.auv:
        for k, d in auv_uncertainty(unc, spec.name).items():
            if k == "event_time_s":
                out |= {f"auv.{spec.name}.{k}.{i}": d for i in range(len(spec.events))}
            else:
                out[f"auv.{spec.name}.{k}"] = d
    return out


def draw(sc, seed: int) -> Realisation:
    """The realisation of scenario ``sc`` for ``seed`` (nothing is simulated)."""
    return realise(sc, seed)[1]


def realise(sc, seed: int):
    """``(realised scenario, Realisation)`` of scenario ``sc`` for ``seed``.

    Raises
    ------
    ConfigError
        The drawn values make an invalid scenario (a combination the load-time checks cannot
        rule out), naming the scenario, seed and cause.
    """
    values = {k: d.draw(stream(seed, f"{sc.name}/{k}")) for k, d in distributions(sc).items()}
    done = apply(sc, Realisation(sc.name, seed, values))
    return done, Realisation(sc.name, seed, values, world_digest(done))


def nominal(sc):
    """``(scenario without its uncertainty, the empty Realisation)``: the file's own values."""
    done = apply(sc, Realisation(sc.name, None, {}))
    return done, Realisation(sc.name, None, {}, world_digest(done))


def run_scenario(sc, seed: int, nominal_values: bool = False, duration: float | None = None):
    """``(scenario, Realisation)`` that a run of ``sc`` with ``seed`` simulates: its first
    ``duration`` s (None: the whole), realised for ``seed`` (:func:`realise`), or its nominal
    values (:func:`nominal`). The one definition for ``mpcasv simulate`` and ``mpcasv sitl``,
    so that a rehearsal and a simulation of the same scenario, seed and duration run the same
    world (the SITL ran the nominal values before session 24). ``duration`` is put in before
    the draw, as it is part of the realised scenario (its id)."""
    if duration is not None:
        sc = dataclasses.replace(sc, duration=float(duration))
    return nominal(sc) if nominal_values else realise(sc, seed)


def without_current(sc):
    """``sc`` with its current no longer uncertain nor varying (a suite that fixes the current
    to its ``current``): the ``[uncertain.current]`` table and the ``[current_field]``'s knots
    and gradient are dropped (its ``auv_factor``, whether the current carries the AUVs, is
    kept)."""
    from mpcasv.sim.scenario import scenario_with

    changes = {}
    if sc.uncertain.current != CurrentUncertainty():
        changes["uncertain"] = dataclasses.replace(sc.uncertain, current=CurrentUncertainty())
    cf = sc.current_field
    if cf is not None and (cf.knots or cf.gradient is not None):
        changes["current_field"] = dataclasses.replace(cf, knots=(), gradient=None)
    return scenario_with(sc, **changes) if changes else sc


__all__ = ["Uncertain", "Uniform", "Normal", "Choice", "draw", "realise", "nominal",
           "run_scenario", "without_current", "distributions", "stream",
           "check_uncertain"]  # fmt: skip
