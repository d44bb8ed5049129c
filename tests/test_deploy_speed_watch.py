"""The speed watch judges only a speed that was commanded, never learns a speed the boat
does not make, and an error in the deploy's own handling of a message is said on the console
(a field engineer's dry run with ``speed_feedback = true``, session 45: a 2.5 m/s transit that
was never sent was judged against the boat's drift, capped the controller at -0.05 m/s, which
its validation refused, and the ASV's state was dropped as ``rejects {'internal_error': 1}``,
silently)."""

from __future__ import annotations

import logging

import pytest
from test_io_cases import FakeClock, dry_deploy

from mpcasv.interface import Mode
from mpcasv.io.asvwatch import NO_WAY_MS, SpeedWatch
from mpcasv.io.config import SpeedSpec
from mpcasv.io.deploy import RUNNING
from mpcasv.io.geo import Origin, to_wgs84
from mpcasv.io.imc import NavState, estimated_state, stamp
from mpcasv.io.logs import read_jsonl

ORIGIN = Origin.from_degrees(41.18, -8.70)  # dry_deploy's
T0 = FakeClock().t  # its clock at the start (s)


def _state(src: int, t: float, N: float, u: float) -> bytes:
    """An EstimatedState of vehicle ``src`` stamped ``t`` (s) at ``N`` (m) moving north at
    ``u`` (m/s, through the water and over ground)."""
    anchor = Origin(*to_wgs84(0.0, 0.0, ORIGIN), 0.0)
    es = estimated_state(NavState(t, N, 0.0, 0.0, 0.0, u, 0, 0, u, 0, 0, 0), anchor, ORIGIN)
    return stamp(es, src, 0xFFFF, t).serialize()


def _drift(dep, clock, seconds: float, u: float = -0.046) -> None:
    """``seconds`` of the ASV drifting at ``u`` (m/s) at 2 Hz, lockstep with the deploy clock
    (FakeClock), the AUV 1000 m north (the controller transits towards it)."""
    t0 = clock.t
    for k in range(1, int(2 * seconds) + 1):
        clock.t = t0 + 0.5 * k
        N = u * (clock.t - T0)
        dep.link.handle_datagram(_state(0x2811, clock.t, 1000.0, 0.0), ("10.0.10.60", 6002))
        dep.link.handle_datagram(_state(0x2801, clock.t, N, u), ("10.0.10.50", 6002))


def _events(dep, tmp_path) -> list[dict]:
    dep.jsonl.flush()
    return read_jsonl(tmp_path / "deploy.jsonl", "event")


def test_speed_watch_never_learns_a_speed_the_boat_does_not_make():
    """Drifting backwards (-0.046 m/s through the water) under a 2.5 m/s command: verdict
    ``speed_no_way``, nothing learnt (was: ``speed_shortfall`` with achievable -0.046, a
    negative cap); the boat then making 1.2 m/s: ``speed_shortfall``, achievable 1.2."""
    w = SpeedWatch(SpeedSpec(window_s=10.0, ratio=0.8, persist_s=10.0, settle_s=5.0))
    w.command(0.0, 2.5)
    said = [ev for k in range(400) if (ev := w.state(0.1 * k, 0.08, -0.046))]
    assert [e["event"] for e in said] == ["speed_no_way"]
    assert w.achievable is None and said[0]["achievable"] is None and w.persistent
    said = [ev for k in range(400, 800) if (ev := w.state(0.1 * k, 1.25, 1.2))]
    assert [e["event"] for e in said] == ["speed_shortfall"]
    assert w.achievable == pytest.approx(1.2) and w.achievable >= NO_WAY_MS


def test_a_dry_run_commands_no_speed_to_judge(tmp_path):
    """``--dry-run`` with ``speed_feedback = true``, the boat drifting backwards for 60 s
    while the controller decides 2.5-m/s transits that are never sent: no speed verdict, no
    cap, no reject, every ASV state taken (the field engineer's run: ``speed_shortfall``,
    then ``rejects {'internal_error': 1}``)."""
    dep, clock = dry_deploy(tmp_path, controller={"name": "hybrid-single",
                                                  "preset": "paper1-field",
                                                  "speed_feedback": True})  # fmt: skip
    _drift(dep, clock, 60.0)
    assert dep.phase == RUNNING and dep.steps > 50
    assert dep.last_cmd.mode is Mode.TRANSIT and dep.last_cmd.speed == pytest.approx(2.5)
    names = {e["event"] for e in _events(dep, tmp_path)}
    assert not names & {"speed_shortfall", "speed_no_way", "controller_speed_cap"}, names
    assert dict(dep.link.rejects) == {} and dep.speed_cap is None
    assert dep.speed.status()["commanded"] is None
    # nor a propeller: with no thruster message the drifting boat's propeller is off, as in
    # standby (it was taken as on from the transits never sent), and nothing is stale
    dep.jsonl.flush()
    steps = read_jsonl(tmp_path / "deploy.jsonl", "step")
    assert len(steps) > 50 and not any(s["obs"]["propeller_on"] for s in steps)
    assert "thruster_stale" not in names
    dep.close()


def test_a_stalled_boat_drifting_backwards_is_said_and_never_caps(tmp_path, caplog):
    """A real run (References sent), the boat drifting backwards under a 2.5 m/s transit:
    event ``speed_no_way``, a warning on the console, the controller's speed untouched, no
    reject (the same code path as the dry run's: a cap of -0.05 m/s the controller's own
    validation refused, dropping the ASV's state)."""
    caplog.set_level(logging.INFO, logger="mpcasv.deploy")
    dep, clock = dry_deploy(tmp_path, controller={"name": "hybrid-single",
                                                  "preset": "paper1-field",
                                                  "speed_feedback": True})  # fmt: skip
    dep.dry_run = False  # a real run: its References go nowhere
    sent = []
    dep.link._send_raw = lambda data, addr, p=None: sent.append(data) or True
    dep.pending = None
    _drift(dep, clock, 10.0)  # discovery, PlanControl (never answered: started by hand)
    dep.phase, dep.started, dep.pending = RUNNING, True, None
    _drift(dep, clock, 60.0)
    events = _events(dep, tmp_path)
    no_way = [e for e in events if e["event"] == "speed_no_way"]
    assert len(no_way) == 1 and no_way[0]["stw"] < 0 and no_way[0]["commanded"] == 2.5
    assert not [e for e in events if e["event"] in ("speed_shortfall", "controller_speed_cap")]
    assert dict(dep.link.rejects) == {} and dep.speed_cap is None
    assert dep.controller.params.speed == pytest.approx(2.5)
    warned = [r for r in caplog.records if r.getMessage().startswith("speed_no_way")]
    assert [r.levelno for r in warned] == [logging.WARNING]
    dep.close()


def test_an_internal_error_is_said_on_the_console(tmp_path, caplog):
    """A bug in the deploy's handling of a valid message (here: its state handler raises)
    drops that message and is counted, and is said on the console as an error naming the
    message (before, only the counter ``rejects {'internal_error': 1}`` and the log knew)."""
    caplog.set_level(logging.INFO, logger="mpcasv.deploy")
    dep, clock = dry_deploy(tmp_path)

    def broken(p, nav, now):
        raise ValueError("speed: -0.05 m/s is outside (0, 10]")

    dep.link.on_state = broken
    clock.t += 0.5
    dep.link.handle_datagram(_state(0x2801, clock.t, 0.0, 0.0), ("10.0.10.50", 6002))
    assert dict(dep.link.rejects) == {"internal_error": 1}
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "EstimatedState" in errors[0] and "-0.05" in errors[0], errors
    dep.close()
