"""``[sim] reference_lead_m`` (session 42): the simulator's execution level steers at a transit
waypoint pushed as far on as ``mpcasv deploy`` pushes DUNE's Reference (``link.
reference_lead_m``), one definition (:func:`mpcasv.interface.pushed_waypoint`) for both; 0,
the default, steers at the waypoint itself. An MPC's rehearsal had parted from its simulation
within a minute because the SITL's boat steered at the pushed location and ``simulate``'s at
the waypoint (docs/deploy.md, "The ASV's actuators")."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from mpcasv.config import ConfigError, load_toml
from mpcasv.controllers.goto import GoTo, GoToParams
from mpcasv.interface import Command, Mode, Reason, pushed_waypoint
from mpcasv.io.geo import Origin, to_local
from mpcasv.io.imc import reference
from mpcasv.sim.scenario import load_scenario, scenario_from_dict, scenario_with
from mpcasv.sim.simulator import simulate
from mpcasv.sim.world import World

CASE3 = Path(__file__).resolve().parents[1] / "experiments" / "scenarios" / "case3.toml"


def test_the_pushed_waypoint_keeps_the_bearing():
    assert pushed_waypoint((10.0, 0.0), (0.0, 0.0), 20.0) == pytest.approx((30.0, 0.0))
    N, E = pushed_waypoint((13.0, 14.0), (10.0, 10.0), 20.0)  # 3-4-5 triangle
    assert (N, E) == pytest.approx((13.0 + 12.0, 14.0 + 16.0))
    assert pushed_waypoint((13.0, 14.0), (10.0, 10.0), 0.0) == (13.0, 14.0)
    assert pushed_waypoint((10.0, 10.0), (10.0, 10.0), 20.0) == (10.0, 10.0)  # no line


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
