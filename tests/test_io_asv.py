"""What the deploy learns about the boat it drives: thrusters, achieved speed (and the
controller's speed capped with it), and the clean shutdown."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import imcpy
import pytest

from mpcasv.interface import ASVState, AUVEstimate, Command, Mode, Observation
from mpcasv.io.asvwatch import ClockRate, SpeedWatch, Thrusters
from mpcasv.io.config import SpeedSpec, deploy_config_from_dict
from mpcasv.io.deploy import Deploy
from mpcasv.io.imc import NavState
from mpcasv.io.logs import read_jsonl


def _cfg(tmp_path, **extra):
    base = {
        "origin": {"lat_deg": 63.4406, "lon_deg": 10.3530},
        "controller": {"name": "hybrid-single", "preset": "paper1-field"},
        "vehicle": [{"role": "asv", "id": 0x2801, "address": "127.0.0.1:6002"},
                    {"role": "auv", "id": 0x2811, "address": "127.0.0.1:6003"}],
        "link": {"port": 0, "announce_to": [], "plan_done_timeout": 0.3},
        "log": {"dir": str(tmp_path)},
    }  # fmt: skip
    for k, v in extra.items():
        base[k] = base.get(k, {}) | v
    return deploy_config_from_dict(base)


def test_thrusters_all_ids_no_stale_before_the_first_message():
    th = Thrusters(stale_s=3.0, threshold=0.05)
    assert th.propeller(0.0, transit_commanded=True) == (True, "command", False)  # none yet
    assert th.propeller(0.0, transit_commanded=False) == (False, "command", False)
    th.update(0, 0.0, 1.0)
    th.update(1, -0.6, 1.0)  # differential thrust: one motor backwards is still "on"
    assert th.propeller(2.0, False) == (True, "thruster", False)
    th.update(0, 0.0, 2.0)
    th.update(1, 0.0, 2.0)
    assert th.propeller(3.0, True) == (False, "thruster", False)
    assert th.propeller(9.0, False) == (False, "command", False)  # standby: DUNE sends none
    assert th.propeller(9.0, True) == (True, "command", True)  # transit, silent: a fault
    assert th.values() == {"0": 0.0, "1": 0.0}


def test_speed_watch_shortfall_recovery_and_cap():
    w = SpeedWatch(SpeedSpec(window_s=10.0, ratio=0.8, persist_s=10.0, settle_s=5.0))
    w.command(0.0, 2.5)
    events = []
    for k in range(0, 601):  # 60 s at 10 Hz: the boat makes 1.2 m/s
        t = 0.1 * k
        ev = w.state(t, 1.25, 1.2)
        if ev:
            events.append((t, ev))
    assert len(events) == 1 and events[0][1]["event"] == "speed_shortfall"
    assert events[0][0] == pytest.approx(25.0, abs=0.11)  # settle + window + persist
    assert w.achievable == pytest.approx(1.2) and w.status()["sog"] == pytest.approx(1.25)
    w.command(60.0, 1.0)  # within what it can do: no shortfall, the cap stays
    for k in range(1, 400):
        assert w.state(60.0 + 0.1 * k, 1.0, 0.98) is None
    assert w.achievable == pytest.approx(1.2)
    w.command(100.0, None)  # standby: no verdict at all
    assert w.state(200.0, 0.0, 0.0) is None and w.status()["commanded"] is None


def _obs(t, asv_N=0.0, auv_N=1000.0):
    auv = AUVEstimate(auv_N, 0.0, 0.0, 0.0, 0.0, (1.0, 0.0, 0.0, 1.0), t)
    return Observation(t, ASVState(asv_N, 0.0, 0.0, 1.2), True, (auv,))


def test_speed_feedback_caps_the_controllers_speed(tmp_path):
    """A persistent shortfall (commanded 2.5, made 1.2) caps the controller's speed with the
    achievable one, in place (its state kept); off by default."""
    for feedback in (False, True):
        dep = Deploy(_cfg(tmp_path / str(feedback), controller={"speed_feedback": feedback}))
        first = dep.controller.step(_obs(0.0))
        assert first.mode is Mode.TRANSIT
        v0 = first.speed
        dep.speed.command(0.0, v0)
        asv = dep.link.asv
        asv.id = 0x2801
        for k in range(1, 400):
            t = 0.1 * k
            nav = NavState(t, 0.12 * k, 0.0, 0.0, 0.0, 1.2, 0, 0, 1.2, 0.0, 0, 0)
            dep._on_state(asv, nav, t)
        later = dep.controller.step(_obs(40.0, 48.0))
        dep.jsonl.flush()
        names = [r["event"] for r in read_jsonl(dep.jsonl.path) if r["kind"] == "event"]
        assert "speed_shortfall" in names
        if feedback:
            assert dep.speed_cap == pytest.approx(1.2) and later.speed == pytest.approx(1.2)
            assert "controller_speed_cap" in names
        else:
            assert dep.speed_cap is None and later.speed == v0 > 1.2
        dep.close()


def test_shutdown_order_and_plan_done_timeout(tmp_path):
    """Standby then MANDONE; without DUNE's answer the wait ends at plan_done_timeout;
    nothing is decided after the shutdown began; ``summary`` is the last record."""
    dep = Deploy(_cfg(tmp_path))
    sent = []
    dep.link._send_raw = lambda data, addr, p=None: sent.append(data) or True
    asv = dep.link.asv
    asv.id = 0x2801
    asv.nav, asv.nav_recv = NavState(0.0, 5.0, 5.0, 0, 0, 0, 0, 0, 0, 0, 0, 0), 0.0
    dep.started, dep.plan_request = True, 7
    dep.last_cmd = Command(Mode.TRANSIT, (100.0, 0.0), 1.5, 0)

    async def main():
        summary = await dep.shutdown()
        return summary

    summary = asyncio.run(main())
    msgs = [imcpy.Packet.deserialize(d) for d in sent]
    assert [type(m).__name__ for m in msgs] == ["Reference", "Reference"]
    assert msgs[0].speed.value == 0.0
    assert msgs[1].flags == int(imcpy.Reference.FlagsBits.MANDONE)
    recs = read_jsonl(tmp_path / "deploy.jsonl")
    names = [r.get("event") for r in recs]
    assert names.index("final_standby") < names.index("plan_done_timeout")
    assert recs[-1]["kind"] == "summary" and summary["plan_completed"] is False
    assert summary["load"]["cpu_s"] >= 0 and math.isfinite(summary["load"]["wall_s"])
    # closing: states no longer decide anything
    steps = dep.steps
    dep._on_state(asv, NavState(9.0, 5.0, 5.0, 0, 0, 0, 0, 0, 0, 0, 0, 0), 9.0)
    assert dep.steps == steps


def test_config_names_the_vessel(tmp_path):
    """``controller.vessel`` is the run's boat (one vessel per run): the controller is built
    for it, not handed it as a preset override; an unknown vessel is refused up front."""
    from mpcasv.config import ConfigError
    from mpcasv.io.config import controller_overrides, deploy_boat
    from mpcasv.models.params import load_vessel

    otter = "/work/shared/cases/vessels/otter.toml"
    shared = Path(__file__).resolve().parents[2] / "shared" / "cases" / "vessels" / "otter.toml"
    otter = str(shared) if shared.is_file() else otter
    if not Path(otter).is_file():
        pytest.skip("shared/cases/vessels/otter.toml not found (optional resource)")
    mpc = _cfg(tmp_path, controller={"name": "mpc-single", "preset": "mpc-single",
                                     "vessel": otter})  # fmt: skip
    assert controller_overrides(mpc) == {}
    assert deploy_boat(mpc).vessel == load_vessel(otter)
    hyb = _cfg(tmp_path, controller={})
    assert deploy_boat(hyb).vessel == load_vessel("gretha")
    with pytest.raises(ConfigError, match="controller: unknown vessel 'no-such-boat'"):
        _cfg(tmp_path, controller={"vessel": "no-such-boat"})


def test_deploy_prepare_builds_and_contacts_nobody(tmp_path, capsys, caplog):
    """``mpcasv deploy CONFIG --prepare``: the controller is built (with progress lines),
    nothing is bound, no log is written, exit 0. A hybrid controller has nothing to compile,
    and the progress line says so (it said "an MPC compiles its library now")."""
    import json
    import logging

    import tomli_w

    from mpcasv.cli import main

    cfg = {
        "origin": {"lat_deg": 63.4406, "lon_deg": 10.3530},
        "controller": {"name": "hybrid-single", "preset": "paper1-field"},
        "vehicle": [{"role": "asv", "id": 0x2801, "address": "127.0.0.1:6002"},
                    {"role": "auv", "id": 0x2811, "address": "127.0.0.1:6003"}],
        "log": {"dir": str(tmp_path / "log")},
    }  # fmt: skip
    path = tmp_path / "deploy.toml"
    path.write_text(tomli_w.dumps(cfg))
    with caplog.at_level(logging.INFO, logger="mpcasv.deploy"):  # progress lines: info
        assert main(["deploy", str(path), "--prepare"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["prepared"]["controller"] == "hybrid-single"
    assert not (tmp_path / "log").exists()
    said = [r.getMessage() for r in caplog.records if r.name == "mpcasv.deploy"]
    assert any("hybrid-single" in m and "nothing to compile" in m for m in said), said
    assert not any("MPC compiles" in m or "compiling" in m for m in said), said


def test_clock_rate_reports_an_asv_clock_running_ahead():
    """A SITL at --speedup 5 against a deploy left at [clock] speedup = 1 decided on time
    stamps five times faster than its own clock and said nothing (a new user's finding,
    session 41): an ASV clock that has run more than 1.5 times as fast since the start (over at
    least 20 s) is reported, once; one in real time, or behind and catching up (a SITL
    waiting for the deploy under --lockstep), is not."""
    rate, t_asv = ClockRate(), 0.0
    for now in range(300):  # real time, waiting (behind by 60 s), then catching up in 20 s
        t_asv += 1.0 if now < 100 else 0.4 if now < 200 else 4.0 if now < 220 else 1.0
        assert rate.state(t_asv, float(now)) is None
    rate, said = ClockRate(), []
    for now in range(100):
        r = rate.state(5.0 * now, float(now))
        if r is not None:
            said.append((now, r))
    assert said == [(20, pytest.approx(5.0))]  # once


def test_the_deploy_says_its_clock_and_the_asvs_disagree(tmp_path):
    from test_io_cases import _es, dry_deploy

    dep, clock = dry_deploy(tmp_path)
    t = clock.t
    for _ in range(60):  # 30 s of deploy clock, 150 s of the ASV's
        clock.t += 0.5
        t += 2.5
        dep.link.handle_datagram(_es(clock, 0x2801, t, 0.0), ("10.0.10.50", 6002))
    dep.jsonl.flush()
    said = [e for e in read_jsonl(tmp_path / "deploy.jsonl", "event") if e["event"] == "clock_rate"]
    assert len(said) == 1 and said[0]["rate"] == pytest.approx(5.0, rel=0.05)
    assert said[0]["speedup"] == 1.0
    dep.close()


def test_clock_rate_reports_an_asv_clock_running_behind():
    """The other direction (a field engineer's trial, session 45): a deploy left at
    ``[clock] speedup = 20`` against a real-time vehicle sees the ASV's clock run 0.05 times
    as fast as its own; reported once, after 20 s of the deploy clock; a clock 1.25 times
    slower (within the factor 1.5 either way) is not."""
    rate = ClockRate()
    for now in range(300):
        assert rate.state(now / 1.25, float(now)) is None
    rate, said = ClockRate(), []
    for k in range(100):  # states at 2 Hz of the ASV's clock, 10 s apart on the deploy's
        r = rate.state(0.5 * k, 10.0 * k)
        if r is not None:
            said.append((10.0 * k, r))
    assert said == [(20.0, pytest.approx(0.05))]


def test_the_deploy_says_its_clock_runs_faster_than_the_asvs(tmp_path, caplog):
    """A deploy at 20 times the ASV's rate: event ``clock_rate`` (rate 0.05, speedup 20) and
    a warning on the console that names ``[clock] speedup``; before session 45, nothing."""
    import logging

    from test_io_cases import _es, dry_deploy

    caplog.set_level(logging.INFO, logger="mpcasv.deploy")
    dep, clock = dry_deploy(tmp_path, clock={"speedup": 20.0})
    t = clock.t
    for _ in range(60):  # 600 s of deploy clock, 30 s of the ASV's
        clock.t += 10.0
        t += 0.5
        dep.link.handle_datagram(_es(clock, 0x2801, t, 0.0), ("10.0.10.50", 6002))
    dep.jsonl.flush()
    said = [e for e in read_jsonl(tmp_path / "deploy.jsonl", "event") if e["event"] == "clock_rate"]
    assert len(said) == 1 and said[0]["rate"] == pytest.approx(0.05, rel=0.05)
    assert said[0]["speedup"] == 20.0 and "[clock] speedup is 20" in said[0]["note"]
    warned = [r for r in caplog.records if r.getMessage().startswith("clock_rate")]
    assert [r.levelno for r in warned] == [logging.WARNING]
    dep.close()


def test_console_warnings_say_they_are_warnings():
    """The deploy's and the SITL's console lines: ``name: message`` for information,
    ``name: warning: message`` for a warning such as ``clock_rate`` (a new user's finding,
    session 41: it looked like the info lines around it), a traceback kept for an error."""
    import logging

    from mpcasv.io.commands import _LevelFormatter

    fmt = _LevelFormatter("%(name)s: %(message)s")

    def line(level, msg, exc_info=None):
        return fmt.format(logging.LogRecord("mpcasv.io.deploy", level, __file__, 1, msg, (),
                                            exc_info))  # fmt: skip

    assert line(logging.INFO, "bound x") == "mpcasv.io.deploy: bound x"
    assert line(logging.WARNING, "clock_rate {}") == "mpcasv.io.deploy: warning: clock_rate {}"
    try:
        raise ValueError("boom")
    except ValueError:
        import sys

        text = line(logging.ERROR, "step failed", sys.exc_info())
    assert text.startswith("mpcasv.io.deploy: error: step failed\nTraceback")
    assert text.endswith("ValueError: boom")


def test_an_auvs_report_velocity_is_its_course_over_ground(tmp_path):
    """An AUV heading north, carried east (EstimatedState: psi 0, ground velocity (0, 1.5)):
    the Kalman estimate's velocity is the ground velocity, east (the report took the heading
    with the speed over ground: 1.5 m/s north)."""
    dep = Deploy(_cfg(tmp_path, controller={"estimator": "kalman"}))
    try:
        auv = dep.link.auvs[0]
        auv.id = 0x2811
        for k in range(1, 31):
            t = 1.0 * k
            dep._on_state(auv, NavState(t, 0.0, 1.5 * t, 10.0, 0.0, 1.0, 0, 0, 0.0, 1.5, 0, 0),
                          t)  # fmt: skip
        est = dep.estimators[0].estimate(30.0)
        assert (est.v_N, est.v_E) == pytest.approx((0.0, 1.5), abs=0.05)
    finally:
        dep.close()
