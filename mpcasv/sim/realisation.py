"""A realisation of a scenario's uncertainty: the values one seed drew, and the scenario with
them put in.

:class:`Realisation` holds the drawn values (keys such as ``current.speed`` or
``auv.auv1.offset_N``), a digest of the realised world (:func:`world_digest`) and a short id
(recorded in ``run.json`` and the results table); :func:`apply` puts the values into a
scenario. The ``[uncertain]`` table and the draws themselves are in
:mod:`mpcasv.sim.uncertainty`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from typing import Any

from mpcasv.config import ConfigError

__all__ = ["Realisation", "apply", "world_digest"]

#: acoustic channel parameters that may be uncertain (drawn values replace the nominal ones)
ACOUSTIC_FIELDS = ("p_good", "p_sporadic", "propeller_factor", "sigma_bearing_deg",
                   "sigma_range", "d1", "d2")  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Realisation:
    """The values one seed drew for a scenario's uncertain quantities.

    ``values`` maps keys such as ``current.speed``, ``acoustics.p_good``,
    ``auv.auv1.offset_N``, ``auv.auv1.event_time_s.2`` (per event) to the drawn value (SI units,
    degrees where the key says ``_deg``). ``world`` is a digest of the realised scenario (what
    is simulated, e.g. a suite's fixed current and duration included). ``id`` is a short hash of
    all three: equal ids, equal worlds (up to the world's own acoustic draws, from the seed).
    """

    scenario: str
    seed: int | None
    values: dict[str, float]
    world: str = ""

    @property
    def id(self) -> str:
        text = json.dumps({"scenario": self.scenario, "values": self.values,
                           "world": self.world}, sort_keys=True)  # fmt: skip
        return hashlib.sha256(text.encode()).hexdigest()[:10]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (``run.json``'s ``realisation``)."""
        return {"id": self.id, "scenario": self.scenario, "seed": self.seed,
                "values": dict(self.values), "world": self.world}  # fmt: skip

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Realisation:
        """Inverse of :meth:`as_dict` (the id is checked against the values)."""
        values = {k: float(v) for k, v in data["values"].items()}
        real = cls(data["scenario"], data["seed"], values, data.get("world", ""))
        if "id" in data and data["id"] != real.id:
            raise ConfigError(f"realisation {data['id']}: the values do not match the id "
                              f"({real.id})")  # fmt: skip
        return real


def world_digest(sc) -> str:
    """A digest of a (realised) scenario's every value (but a later field at its "as before"
    value: :func:`mpcasv.sim.scenario.digest_plain`)."""
    from mpcasv.sim.scenario import digest_plain

    text = json.dumps(digest_plain(sc), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def apply(sc, real: Realisation):
    """Scenario ``sc`` with the values of ``real`` put in; its ``[uncertain]`` table emptied.

    Raises :class:`~mpcasv.config.ConfigError` when the result is invalid, or when ``real``
    names a world digest and the result differs from it (``real`` was drawn from another
    version of the scenario).

    Current: speed and direction replace the nominal ones (a ``[current_field]`` is kept and
    added). ASV: start offsets. Acoustics: the values replace the nominal ones. AUV ``a``: its
    routes (waypoints, lawnmower origins and headings), loiter points and transit headings are
    turned by ``rotation_deg`` about its nominal start, then moved by ``offset_N/E`` with its
    start; its start moves by ``start_N/E`` and turns by ``rotation_deg + start_psi_deg``;
    ``speed_factor`` scales every plan, pursuer and transit speed;
    ``event_time_s.i`` shifts event ``i``; ``update_period_s`` replaces pursuers' periods.
    """
    from mpcasv.sim.scenario import _to_plain, scenario_from_dict

    v = real.values
    data = _to_plain(sc)
    data["uncertain"] = {}
    if "current.speed" in v or "current.direction_deg" in v:
        speed = v.get("current.speed", math.hypot(*sc.current))
        chi = math.radians(v.get("current.direction_deg",
                                 math.degrees(math.atan2(sc.current[1], sc.current[0]))))
        data["current"] = [speed * math.cos(chi), speed * math.sin(chi)]  # (V_N, V_E)
    start = data["asv"]["start"]
    for k in ("N", "E", "psi_deg"):
        start[k] += v.get(f"asv.start_{k}", 0.0)
    for k in ACOUSTIC_FIELDS:
        if f"acoustics.{k}" in v:
            data["acoustics"][k] = v[f"acoustics.{k}"]
    for a in data["auv"]:
        _apply_auv(a, {k.split(".", 2)[2]: x for k, x in v.items()
                       if k.startswith(f"auv.{a['name']}.")})  # fmt: skip
    try:
        done = scenario_from_dict(data, f"{sc.name} realisation of seed {real.seed}")
    except ConfigError as exc:
        raise ConfigError(f"scenario {sc.name!r}: the values drawn for seed {real.seed} make an "
                          f"invalid scenario: {str(exc).splitlines()[-1].strip()}") from None
    if real.world and world_digest(done) != real.world:
        raise ConfigError(f"scenario {sc.name!r}: realisation {real.id} was drawn from another "
                          "version of the scenario (its world digest differs)")  # fmt: skip
    return done


def _apply_auv(a: dict, v: dict[str, float]) -> None:
    N0, E0 = a["start"]["N"], a["start"]["E"]
    rot = math.radians(v.get("rotation_deg", 0.0))
    dN, dE = v.get("offset_N", 0.0), v.get("offset_E", 0.0)
    c, s = math.cos(rot), math.sin(rot)

    def move(N: float, E: float) -> list[float]:  # turn about the nominal start, then offset
        n, e = N - N0, E - E0
        return [N0 + c * n - s * e + dN, E0 + s * n + c * e + dE]

    a["start"]["N"] = N0 + dN + v.get("start_N", 0.0)
    a["start"]["E"] = E0 + dE + v.get("start_E", 0.0)
    a["start"]["psi_deg"] += v.get("rotation_deg", 0.0) + v.get("start_psi_deg", 0.0)
    f = v.get("speed_factor", 1.0)
    for i, ev in enumerate(a["events"]):
        ev["t"] += v.get(f"event_time_s.{i}", 0.0)
    for b in (a["behaviour"], *a["events"]):
        if b.get("at") is not None:  # a loiter event's point
            b["at"] = move(*b["at"])
        if b.get("loiter") and b["loiter"].get("at") is not None:
            b["loiter"]["at"] = move(*b["loiter"]["at"])
        if b.get("plan"):
            p = b["plan"]
            p["speed"] *= f
            p["surface_speed"] *= f
            for seg in p["route"]:
                if seg.get("waypoints"):
                    seg["waypoints"] = [[*move(w[0], w[1]), w[2]] for w in seg["waypoints"]]
                if seg.get("lawnmower"):
                    lm = seg["lawnmower"]
                    lm["origin"] = move(*lm["origin"])
                    lm["heading_deg"] += v.get("rotation_deg", 0.0)
        if b.get("transit"):
            b["transit"]["speed"] *= f
            b["transit"]["heading_deg"] += v.get("rotation_deg", 0.0)
        if b.get("pursuer"):
            b["pursuer"]["speed"] *= f
            if "update_period_s" in v:
                b["pursuer"]["update_period"] = v["update_period_s"]
