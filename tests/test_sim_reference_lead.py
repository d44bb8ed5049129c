"""``[sim] reference_lead_m`` (session 42): the simulator's execution level steers at a transit
waypoint pushed as far on as ``mpcasv deploy`` pushes DUNE's Reference (``link.
reference_lead_m``), one definition (:func:`mpcasv.interface.pushed_waypoint`) for both; 0,
the default, steers at the waypoint itself. An MPC's rehearsal had parted from its simulation
within a minute because the SITL's boat steered at the pushed location and ``simulate``'s at
the waypoint (docs/deploy.md, "The ASV's actuators")."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest

from mpcasv.config import ConfigError, load_toml
from mpcasv.controllers.goto import GoTo, GoToParams
from mpcasv.interface import Command, Mode, Reason, pushed_waypoint
from mpcasv.io.geo import Origin, to_local
from mpcasv.io.imc import reference
from mpcasv.io.rehearsal import rehearsal_scenario
from mpcasv.sim.realisation import world_digest
from mpcasv.sim.scenario import digest_plain, load_scenario, scenario_from_dict, scenario_with
from mpcasv.sim.simulator import simulate
from mpcasv.sim.world import World

CASE3 = Path(__file__).resolve().parents[1] / "experiments" / "scenarios" / "case3.toml"


def test_the_pushed_waypoint_keeps_the_bearing():
    assert pushed_waypoint((10.0, 0.0), (0.0, 0.0), 20.0) == pytest.approx((30.0, 0.0))
    N, E = pushed_waypoint((13.0, 14.0), (10.0, 10.0), 20.0)  # 3-4-5 triangle
    assert (N, E) == pytest.approx((13.0 + 12.0, 14.0 + 16.0))
    assert pushed_waypoint((13.0, 14.0), (10.0, 10.0), 0.0) == (13.0, 14.0)
    assert pushed_waypoint((10.0, 10.0), (10.0, 10.0), 20.0) == (10.0, 10.0)  # no line
    assert pushed_waypoint((10.0, 10.0 + 1e-7), (10.0, 10.0), 20.0) == (10.0, 10.0 + 1e-7)
    assert pushed_waypoint((10.0, 10.001), (10.0, 10.0), 20.0) == pytest.approx((10.0, 30.001))


def test_the_deploys_reference_is_the_same_point():
    """The Reference the deploy sends DUNE lies at the pushed waypoint (through WGS-84)."""
    origin = Origin.from_degrees(63.44, 10.35)
    cmd = Command(Mode.TRANSIT, (40.0, -25.0), 1.5, 0, Reason.TRACKING)
    ref = reference(cmd, (10.0, 5.0), origin, lead=20.0)
    N, E, _ = to_local(ref.lat, ref.lon, origin.height, origin)
    assert (N, E) == pytest.approx(pushed_waypoint(cmd.waypoint, (10.0, 5.0), 20.0), abs=1e-6)


@pytest.mark.parametrize("lead", [0.0, 20.0])
def test_simulate_steers_at_the_pushed_waypoint(monkeypatch, lead):
    """Every period's command vector is the controller's transit waypoint pushed ``lead`` m
    on from the ASV's position at that decision (the observation it decided on)."""
    sc = load_scenario(CASE3)
    sc = scenario_with(sc, duration=20.0, sim=dataclasses.replace(sc.sim, reference_lead_m=lead))
    seen, advance = [], World.advance

    def spy(self, cmd):
        seen.append((np.array(cmd, float), self.asv_state().position.copy()))
        return advance(self, cmd)

    monkeypatch.setattr(World, "advance", spy)
    wp = (300.0, 150.0)
    simulate(sc, GoTo(GoToParams(waypoint=wp, speed=1.5)), seed=0)
    assert len(seen) == 20
    for cmd, asv in seen:
        assert cmd[0] == 1.0 and cmd[3] == 1.5
        np.testing.assert_allclose(cmd[1:3], pushed_waypoint(wp, asv, lead), rtol=0, atol=1e-9)
    moved = math.hypot(*(seen[-1][1] - seen[0][1]))
    assert moved > 5.0  # the boat went on, so each decision pushed from another place


@pytest.mark.parametrize("lead", [-1.0, 1001.0, math.nan])
def test_a_bad_lead_is_refused(lead):
    data = load_toml(CASE3)
    data["sim"] = data.get("sim", {}) | {"reference_lead_m": lead}
    with pytest.raises(ConfigError, match="reference_lead_m"):
        scenario_from_dict(data)


def _log(tmp_path, **link) -> Path:
    path = tmp_path / "deploy.jsonl"
    cfg = {"link": {"reference_lead_m": 20.0, "reference_radius_m": 0.0} | link}
    path.write_text(json.dumps({"kind": "event", "event": "started", "t": 0.0, "config": cfg})
                    + "\n")  # fmt: skip
    return path


def test_rehearsal_scenario_takes_the_logged_lead(tmp_path):
    """The scenario to compare a rehearsal with: its duration, the lead its deploy pushed
    DUNE's References by, the actuators at the periods' ends only (a deploy has no samples);
    a log without its start, or a lead ``simulate`` cannot follow (DUNE stops the boat within
    15 m + |radius| of the Reference), is refused."""
    world = load_scenario(CASE3)
    sc = rehearsal_scenario(world, _log(tmp_path), 120.0)
    assert sc.sim.reference_lead_m == 20.0 and sc.duration == 120.0
    assert world.sim.actuator_samples and not sc.sim.actuator_samples  # as a deploy observes
    assert dataclasses.replace(sc.sim, reference_lead_m=0.0, actuator_samples=True) == world.sim
    for link, words in (({"reference_lead_m": 10.0}, "follows a lead of 15 m"),
                        ({"reference_radius_m": -10.0}, "follows a lead of 25 m"),
                        ({"reference_lead_m": 2000.0}, "to 1000 m")):  # fmt: skip
        with pytest.raises(ValueError, match=words):
            rehearsal_scenario(world, _log(tmp_path, **link), 120.0)
    (tmp_path / "deploy.jsonl").write_text("")
    with pytest.raises(ValueError, match="no 'started' event"):
        rehearsal_scenario(world, tmp_path, 120.0)


def test_a_zero_lead_leaves_the_digests_as_before():
    """At 0 the field is left out of the scenario's digests, so that results written before
    it existed keep their job and realisation ids (a review's finding, session 42: they had
    all changed); any other lead is in them."""
    sc = load_scenario(CASE3)
    plain = digest_plain(sc)
    assert "reference_lead_m" not in plain["sim"] and "dt" in plain["sim"]
    old = json.dumps(plain, sort_keys=True, default=str)
    assert world_digest(sc) == hashlib.sha256(old.encode()).hexdigest()[:16]
    led = scenario_with(sc, sim=dataclasses.replace(sc.sim, reference_lead_m=5.0))
    assert digest_plain(led)["sim"]["reference_lead_m"] == 5.0
    assert world_digest(led) != world_digest(sc)
