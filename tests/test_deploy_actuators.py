"""The ASV's actuators in the field: ``mpcasv deploy`` turns DUNE's set-points
(SetThrusterActuation ids 0 and 1, SetServoPosition id 0) into the model's thrust and steering
(``Observation.actuators``) by the vessel's actuation, as the identification reads them; an
MPC plans from them and its current observer reads them, as in ``mpcasv simulate``. Before
session 41 the deploy passed none: an MPC's rehearsal then estimated another current from its
first step on than its simulation did (Case 3, lockstep: 0.138 against 0.150 m/s). DUNE's
recorded Otter: tests/test_io_dune_recording.py::test_recorded_otter_thrusters."""

from __future__ import annotations

import dataclasses
import json

import pytest

from mpcasv.interface import ASVState, AUVEstimate, Observation
from mpcasv.io.asvwatch import Thrusters, dune_actuators, dune_set_points
from mpcasv.io.records import obs_from_dict, obs_to_dict
from mpcasv.models.params import load_vessel

GRETHA, OTTER_VESSEL = load_vessel("gretha"), load_vessel("dune-otter")


@pytest.mark.parametrize("vessel", [GRETHA, OTTER_VESSEL], ids=["steerable", "differential"])
def test_set_points_and_actuators_are_inverse(vessel):
    for T, delta in ((0.0, 0.0), (0.4 * vessel.T_max, 0.2), (0.3 * vessel.T_max, -0.3)):
        thr, servos = dune_set_points(vessel, T, delta)
        a0, a1, s0 = thr[0], thr.get(1, 0.0), servos.get(0, 0.0)
        assert dune_actuators(vessel, a0, a1, s0) == pytest.approx((T, delta))
    thr, _ = dune_set_points(vessel, 1.2 * vessel.T_max, -0.5)  # beyond what DUNE can send
    assert all(-1.0 <= a <= 1.0 for a in thr.values()) and max(map(abs, thr.values())) == 1.0
    assert set(dune_set_points(vessel, 1.0, 0.1)[0]) == ({0, 1} if vessel is OTTER_VESSEL
                                                          else {0})  # fmt: skip


def test_actuators_fresh_stopped_or_unknown():
    th = Thrusters(stale_s=3.0, threshold=0.05)
    # nothing heard: DUNE's loops have not run, unless we command a transit
    assert th.actuators(0.0, GRETHA, transit_commanded=False) == (0.0, 0.0)
    assert th.actuators(0.0, GRETHA, transit_commanded=True) is None
    th.update(0, 0.5, 1.0)
    assert th.actuators(1.0, GRETHA, True) is None  # the steering servo never heard
    th.update_servo(0, -0.2, 1.0)
    assert th.actuators(2.0, GRETHA, True) == (0.5 * GRETHA.T_max, -0.2)
    assert th.actuators(9.0, GRETHA, True) is None  # stale, and not DUNE's final 0.0
    th.update(0, 0.0, 9.0)
    th.update_servo(0, 0.0, 9.0)
    assert th.actuators(30.0, GRETHA, False) == (0.0, 0.0)  # loops off: none sent since
    th.update(0, 0.6, 31.0)
    th.update(1, 0.2, 31.0)
    T, delta = th.actuators(31.5, OTTER_VESSEL, True)
    assert T == pytest.approx(0.4 * OTTER_VESSEL.T_max)
    assert delta == pytest.approx(0.2 * OTTER_VESSEL.delta_max)


def test_records_keep_the_actuators():
    auv = AUVEstimate(200.0, 50.0, 10.0, t_last_fix=0.0)
    obs = Observation(3.0, ASVState(0.0, 0.0, 0.0), True, (auv,), actuators=(123.4, -0.25))
    d = json.loads(json.dumps(obs_to_dict(obs)))
    assert d["actuators"] == [123.4, -0.25] and obs_from_dict(d) == obs
    bare = dataclasses.replace(obs, actuators=None)
    assert "actuators" not in obs_to_dict(bare) and obs_from_dict(obs_to_dict(bare)) == bare
    through = dataclasses.replace(obs, actuator_samples=((2.0, 100.0, 0.1), (3.0, 123.4, -0.25)))
    d = json.loads(json.dumps(obs_to_dict(through)))  # the samples too, bit for bit
    assert d["actuator_samples"] == [[2.0, 100.0, 0.1], [3.0, 123.4, -0.25]]
    assert obs_from_dict(d) == through and "actuator_samples" not in obs_to_dict(obs)


def _set_point(kind: str, src: int, i: int, value: float, t: float) -> bytes:
    import imcpy

    from mpcasv.io.imc import stamp

    msg = imcpy.SetThrusterActuation() if kind == "thruster" else imcpy.SetServoPosition()
    msg.id, msg.value = i, value
    return stamp(msg, src, 0xFFFF, t).serialize()


@pytest.mark.parametrize("vessel", ["gretha", "dune-otter"])
def test_the_deploy_observes_the_asvs_set_points(tmp_path, vessel):
    """DUNE's set-points through the link into the decisions' observations: the vessel's
    actuation decides which it needs; in a transit one never heard leaves the actuators
    unknown (one event ``actuators_unknown`` with the ids heard); set-points beyond DUNE's
    [-1, 1] are clipped; ``controller.actuator_feedback = false`` reads none (a review's
    findings, session 41)."""
    from test_io_cases import dry_deploy, feed_states

    from mpcasv.interface import Command, Mode, Reason
    from mpcasv.io.logs import read_jsonl

    asv = ("10.0.10.50", 6002)
    vp = load_vessel(vessel)
    dep, clock = dry_deploy(tmp_path, controller={"name": "hybrid-single", "preset":
                                                  "paper1-field", "vessel": vessel})  # fmt: skip
    dep.dry_run = False  # a real run (a dry run commands no transit): its sends go nowhere
    t = feed_states(dep, clock, clock.t, 2)
    assert dep.observation(t, clock.t)[0].actuators == (0.0, 0.0)  # none heard, no transit
    dep.last_cmd = Command(Mode.TRANSIT, (100.0, 0.0), 1.5, 0, Reason.NOMINAL)
    dep.link.handle_datagram(_set_point("thruster", 0x2801, 0, 1.3, t), asv)  # beyond 1
    assert dep.observation(t, clock.t)[0].actuators is None  # the second input never heard
    dep.link.handle_datagram(_set_point("thruster", 0x2801, 0, 0.5, t), asv)
    second = ("thruster", 1, 0.2) if vessel == "dune-otter" else ("servo", 0, -0.1)
    dep.link.handle_datagram(_set_point(second[0], 0x2801, second[1], second[2], t), asv)
    assert dep.link.rejects == {}
    expected = (dune_actuators(vp, 0.5, 0.2) if vessel == "dune-otter"
                else dune_actuators(vp, 0.5, servo=-0.1))  # fmt: skip
    assert dep.observation(t, clock.t)[0].actuators == pytest.approx(expected, rel=1e-6)
    dep.link.handle_datagram(_set_point("thruster", 0x2801, 0, 1.7, t), asv)
    assert dep.observation(t, clock.t)[0].actuators[0] == pytest.approx(
        dune_actuators(vp, 1.0, 0.2 if vessel == "dune-otter" else 0.0)[0])  # fmt: skip
    dep.jsonl.flush()
    unknown = [e for e in read_jsonl(tmp_path / "deploy.jsonl", "event")
               if e["event"] == "actuators_unknown"]  # fmt: skip
    assert len(unknown) == 1 and unknown[0]["thrusters"] == [0] and unknown[0]["servos"] == []
    dep.close()
    off, clock = dry_deploy(tmp_path / "off", controller={
        "name": "hybrid-single", "preset": "paper1-field", "actuator_feedback": False})
    t = feed_states(off, clock, clock.t, 2)
    off.link.handle_datagram(_set_point("thruster", 0x2801, 0, 0.5, t), asv)
    off.link.handle_datagram(_set_point("servo", 0x2801, 0, 0.1, t), asv)
    assert off.observation(t, clock.t)[0].actuators is None
    off.close()
