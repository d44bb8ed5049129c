"""The ASV's own USBL fixes in the field: ``mpcasv deploy`` reads the UsblFixExtended its DUNE
dispatches for every USBL position (``target`` the AUV's system name; the Otter's
``Transports.UDP`` list forwards it), puts the time of each AUV's last fix into the
observations (``Observation.usbl_fix_times``, what ``fix_age_source = "observed"``, M2o,
reads), logs it with each decision, and ``mpcasv replay`` replays M2o on such a log; the SITL's
ASV sends one per USBL fix of its world. Before session 41 the deploy read none and refused M2o.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import math
from pathlib import Path

import pytest
from test_io_cases import dry_deploy, feed_states

from mpcasv.config import ConfigError
from mpcasv.interface import ASVState, AUVEstimate, Observation
from mpcasv.io.asvwatch import MAX_UNMATCHED, UsblFixes
from mpcasv.io.geo import Origin
from mpcasv.io.imc import stamp, usbl_fix_extended
from mpcasv.io.logs import read_jsonl
from mpcasv.io.records import obs_from_dict, obs_to_dict
from mpcasv.io.replay import replay

ASV, AUV = ("10.0.10.50", 6002), ("10.0.10.60", 6002)
VEHICLES = [{"role": "asv", "id": 0x2801, "name": "otter", "address": "10.0.10.50:6002"},
            {"role": "auv", "id": 0x2811, "name": "lauv-xplore-1",
             "address": "10.0.10.60:6002"}]  # fmt: skip
ORIGIN = Origin.from_degrees(41.18, -8.70)


def _fix(src: int, target: str, t: float) -> bytes:
    msg = usbl_fix_extended(target, 100.0, 0.0, 20.0, 1.5, ORIGIN)
    return stamp(msg, src, 0xFFFF, t).serialize()


def test_the_tracker_keeps_each_auvs_latest_fix():
    fx = UsblFixes(2)
    assert fx.times == [-math.inf, -math.inf] and fx.counts == [0, 0]
    names = ["auv-a", None]  # the second AUV's name not known yet
    assert fx.fix("auv-a", 10.0, names) == 0
    assert fx.fix("auv-a", 8.0, names) == 0  # reordered: older than the one held
    assert fx.fix("auv-a", 10.0, names) == 0  # the same datagram twice
    assert fx.times == [10.0, -math.inf] and fx.counts == [1, 0]  # one fix
    assert fx.fix("auv-b", 12.0, names) is None  # not (yet) known as an AUV
    assert fx.fix("auv-b", 13.0, ["auv-a", "auv-b"]) == 1
    assert fx.times == [10.0, 13.0] and fx.unmatched == {"auv-b": 1}
    for i in range(30):  # a flood of strange targets keeps at most MAX_UNMATCHED names
        fx.fix(f"x{i}", 1.0, names)
    assert len(fx.unmatched) == MAX_UNMATCHED + 1 and fx.unmatched["(other)"] == 11


def test_the_deploy_puts_the_asvs_usbl_fixes_into_its_observations(tmp_path):
    """States at 2 Hz, then UsblFixExtended from the ASV: each decision's observation (and its
    log record) has the AUV's last fix time by the ASV's clock, ``-inf`` before the first;
    a fix sent by the AUV itself is not the ASV's USBL (ignored), a fix of another system is
    one event ``usbl_fix_unknown`` however often it comes, and the summary counts both. A fix
    stamped later than the ASV's clock can be is rejected (a review's finding, session 41:
    held as the latest, it hid every real fix after it)."""
    dep, clock = dry_deploy(tmp_path, vehicle=VEHICLES)
    t = feed_states(dep, clock, clock.t, 4)
    assert dep.steps > 0
    assert dep.observation(t, clock.t)[0].usbl_fix_times == (-math.inf,)
    t_fix = t + 0.2
    dep.link.handle_datagram(_fix(0x2801, "lauv-xplore-1", t_fix), ASV)
    dep.link.handle_datagram(_fix(0x2811, "lauv-xplore-1", t + 0.4), AUV)  # not the ASV's
    for _ in range(3):
        dep.link.handle_datagram(_fix(0x2801, "lauv-other", t + 0.3), ASV)
    assert dep.link.rejects == {}
    assert dep.link.ignored["UsblFixExtended"] == 1
    t = feed_states(dep, clock, t, 4)
    assert dep.observation(t, clock.t)[0].usbl_fix_times == (t_fix,)
    # a fix from the future (6 s past the last state: clock_slack_s is 5 s) is refused
    dep.link.handle_datagram(_fix(0x2801, "lauv-xplore-1", t + 6.0), ASV)
    assert dep.link.rejects == {"usbl_fix_time": 1}
    assert dep.observation(t, clock.t)[0].usbl_fix_times == (t_fix,)
    asyncio.run(dep.finish())
    steps = read_jsonl(tmp_path / "deploy.jsonl", "step")
    logged = [s["obs"]["usbl_fix_times"] for s in steps]
    assert logged[0] == [None] and [t_fix] in logged  # -inf is written as null
    assert obs_from_dict(steps[0]["obs"]).usbl_fix_times == (-math.inf,)
    unknown = [e for e in read_jsonl(tmp_path / "deploy.jsonl", "event")
               if e["event"] == "usbl_fix_unknown"]  # fmt: skip
    assert len(unknown) == 1 and unknown[0]["target"] == "lauv-other"
    # 'perfect' takes no fix position, and needs none while the AUV's states come (a
    # review's finding, session 42: the advice to switch had come on every such run)
    assert not [e for e in read_jsonl(tmp_path / "deploy.jsonl", "event")
                if e["event"] == "usbl_fix_positions_unused"]  # fmt: skip
    assert unknown[0]["auvs"] == ["lauv-xplore-1"]
    summary = read_jsonl(tmp_path / "deploy.jsonl", "summary")[-1]
    assert summary["usbl_fixes"] == [1] and summary["usbl_fixes_unmatched"] == {"lauv-other": 3}


def test_fixes_follow_the_asvs_clock_step(tmp_path):
    """The ASV's clock steps 100 s ahead: its states are taken on the new base after
    ``clock_step_states`` (3) that agree, corrected by the offset; a fix sent while that check
    runs is rejected (its time base in doubt), one after it is corrected as the states are
    (a review's finding, session 41: the first fixes after the step were held 100 s in the
    future and hid every real one)."""
    dep, clock = dry_deploy(tmp_path, vehicle=VEHICLES)
    t = feed_states(dep, clock, clock.t, 6)
    for k in range(5):  # the ASV's clock now reads 100 s ahead
        t = feed_states(dep, clock, t, 1, asv_ahead=100.0)
        if k == 0:
            assert dep.link.asv.track.chain  # the step is being checked
            dep.link.handle_datagram(_fix(0x2801, "lauv-xplore-1", t + 100.2), ASV)
            assert dep.link.rejects["usbl_fix_time"] == 1
    assert dep.link.asv.track.offset == pytest.approx(100.0, abs=0.01)
    assert not dep.link.asv.track.chain
    dep.link.handle_datagram(_fix(0x2801, "lauv-xplore-1", t + 100.2), ASV)
    assert dep.observation(t, clock.t)[0].usbl_fix_times == (t + 100.2 - dep.link.asv.track.offset,)
    assert abs(dep.usbl.times[0] - (t + 0.2)) < 0.01
    dep.close()


def test_observed_fixes_need_every_auvs_name(tmp_path):
    """UsblFixExtended names its target by system name: an AUV configured by IMC id only
    would never match, and M2o would run on the model's ages without a word (a review's
    finding, session 41). Refused at load, in one line."""
    from test_deploy_field import _mpc_cfg

    from mpcasv.io.config import deploy_config_from_dict

    data = _mpc_cfg(tmp_path)
    data["controller"]["overrides"]["fix_age_source"] = "observed"
    data["vehicle"][1] = {"role": "auv", "id": 0x2811}
    with pytest.raises(ConfigError, match="give AUV 0's \\[\\[vehicle\\]\\] a name"):
        deploy_config_from_dict(data)


def test_records_keep_the_fix_times_and_older_logs_have_none():
    auv = AUVEstimate(200.0, 50.0, 10.0, t_last_fix=0.0)
    obs = Observation(3.0, ASVState(0.0, 0.0, 0.0), False, (auv, auv),
                      usbl_fix_times=(1.5, -math.inf))  # fmt: skip
    d = json.loads(json.dumps(obs_to_dict(obs)))
    assert d["usbl_fix_times"] == [1.5, None]
    assert obs_from_dict(d) == obs
    bare = Observation(3.0, ASVState(0.0, 0.0, 0.0), False, (auv,))
    assert "usbl_fix_times" not in obs_to_dict(bare)
    assert obs_from_dict(obs_to_dict(bare)).usbl_fix_times is None


def _log(tmp_path, fix_times: bool):
    """A deploy log of mpc-single's decisions on an AUV 65 m away (inside its reliable-fix
    range, r_t = 69 m) with the ASV quiet, one USBL fix logged at t = 2 s (``fix_times``:
    the observations carry the ASV's fix times, as since session 41; else as an older
    log's)."""
    from mpcasv.controllers import make_controller
    from mpcasv.io.config import WatchdogSpec
    from mpcasv.io.records import cmd_to_dict

    ctl = make_controller("mpc-single", 1, "mpc-single", {"fix_age_source": "observed"})
    ctl.reset(1)
    auv = AUVEstimate(65.0, 0.0, 10.0, t_last_fix=0.0)
    config = {"controller": {"name": "mpc-single", "preset": "mpc-single",
                             "overrides": {"fix_age_source": "observed"}},
              "watchdog": dataclasses.asdict(WatchdogSpec())}  # fmt: skip
    guard = {"stale_s": 5.0, "lost_s": 60.0, "v_max": 1.5, "w_max": 0.5, "r_keep": 10.0,
             "margin_m": 5.0, "speed": 1.5}  # fmt: skip
    records = [{"kind": "event", "event": "started", "guard": guard, "config": config}]
    for t in range(4):
        obs = Observation(float(t), ASVState(0.0, 0.0, 0.0), False, (auv,),
                          usbl_fix_times=(-math.inf,) if t < 2 else (2.0,))  # fmt: skip
        d = obs_to_dict(obs)
        if not fix_times:
            del d["usbl_fix_times"]
        records.append({"kind": "step", "t": float(t), "clock": float(t), "obs": d,
                        "cmd": cmd_to_dict(ctl.step(obs)), "override": None, "status": ["ok"],
                        "ages": [0.0]})  # fmt: skip
    records.append({"kind": "summary", "t": 4.0})  # a deploy that ended normally
    log = tmp_path / "deploy.jsonl"
    log.write_text("".join(json.dumps(r) + "\n" for r in records))
    return log, ctl


def test_replay_replays_observed_fixes_from_a_log_that_has_them(tmp_path):
    """M2o replayed on a log with the ASV's fix times: the same decisions (the fix at t = 2 s
    reset the age the logged decisions were made with); on an older log without them, one
    line (ConfigError)."""
    log, ctl = _log(tmp_path, fix_times=True)
    assert ctl.diagnostics()["mpc_tau0"] < 2.0  # the fix reset the age (else about 3 s)
    rep = replay(log)
    assert rep.n_steps == 4 and rep.n_differ == 0
    # the logged preset given by its path is the logged preset: its overrides kept (they
    # were dropped, with a note, as for another preset: a new user's finding, session 41)
    import mpcasv

    shipped = Path(mpcasv.__file__).parent / "data" / "presets" / "mpc-single.toml"
    rep = replay(log, preset=str(shipped))
    assert rep.n_differ == 0 and not rep.notes, rep.notes
    old, _ = _log(tmp_path, fix_times=False)
    with pytest.raises(ConfigError, match="fix_age_source = 'observed'.*do not carry"):
        replay(old)


def test_the_sitl_asv_sends_a_fix_message_per_world_fix():
    """The SITL's ASV publishes each of its world's USBL fixes once, as a UsblFixExtended
    naming the AUV's system, at the fix's own time (``ts_offset`` + world time), up to the
    tick being published; none before the world starts and none while its DUNE is down."""
    from types import SimpleNamespace

    from mpcasv.io.sitlpublish import Publishing
    from mpcasv.models.acoustics import Fix

    sent = []

    class Vehicle(SimpleNamespace):
        def publish(self, msg, t=None):
            if self.alive:
                sent.append((msg.target, t, msg.z))

    fixes = [Fix(1.0, 0, 100.0, 0.0, 20.0, (1.0, 0.0, 0.0, 1.0), 102.0),
             Fix(5.0, 0, 101.0, 0.0, 20.0, (1.0, 0.0, 0.0, 1.0), 103.0),
             Fix(9.0, 0, 102.0, 0.0, 20.0, (1.0, 0.0, 0.0, 1.0), 104.0)]  # fmt: skip
    sitl = SimpleNamespace(ts_offset=None, tick=0.0, fixes_sent=[0], origin=ORIGIN,
                           opt=SimpleNamespace(usbl_delay=0.0),
                           world=SimpleNamespace(fixes=[fixes]),
                           asv=Vehicle(alive=True), auvs=[Vehicle(index=0, name="sitl-auv")])
    sitl.now = lambda: sitl.tick
    Publishing.publish_fixes(sitl)  # the world has not started
    sitl.ts_offset, sitl.tick = 1000.0, 1005.0
    Publishing.publish_fixes(sitl)
    assert sent == [("sitl-auv", 1001.0, 20.0), ("sitl-auv", 1005.0, 20.0)]
    sitl.asv.alive, sitl.tick = False, 1010.0  # its DUNE down: the fix is lost
    Publishing.publish_fixes(sitl)
    Publishing.publish_fixes(sitl)
    assert len(sent) == 2 and sitl.fixes_sent == [3]


@pytest.mark.parametrize("propeller", ["command", "thruster"])
def test_observed_fixes_judged_by_our_own_command_are_said(tmp_path, monkeypatch, caplog,
                                                           propeller):  # fmt: skip
    """With ``watchdog.propeller = "command"`` M2o judges each fix by our own command, not by
    the thrusters DUNE reports: accepted, and said at start in one warning (a new user's
    finding, session 41: the run's energy changed 80 -> 47 kJ with it, silently)."""
    import logging

    import mpcasv.io.deploy as deploy_mod

    built = deploy_mod.build_controller

    def m2o(cfg, log=None):
        ctl = built(cfg, log=log)
        ctl.needs_usbl_fixes = True  # as an MPC with fix_age_source = "observed"
        return ctl

    monkeypatch.setattr(deploy_mod, "build_controller", m2o)
    caplog.set_level(logging.WARNING, logger="mpcasv.deploy")
    dep, _ = dry_deploy(tmp_path, vehicle=VEHICLES, watchdog={"propeller": propeller})
    dep.close()
    said = [r for r in caplog.records if "judges each USBL fix" in r.getMessage()]
    assert len(said) == (propeller == "command")


def test_a_repeated_asv_state_does_not_hide_a_fix(tmp_path):
    """A repeated (or reordered) ASV state starts a clock-step chain behind the accepted time;
    the fixes then were rejected as if the clock were stepping (a review's finding, session
    41). A fix before the ASV's first state is rejected (its clock not known yet)."""
    from test_io_cases import _es

    dep, clock = dry_deploy(tmp_path, vehicle=VEHICLES)
    dep.link.handle_datagram(_fix(0x2801, "lauv-xplore-1", clock.t), ASV)
    assert dep.link.rejects == {"usbl_fix_time": 1}
    t = feed_states(dep, clock, clock.t, 4)
    dep.link.handle_datagram(_es(clock, 0x2801, t - 0.5, 0.0), ASV)  # an older one again
    assert dep.link.rejects["out_of_order"] == 1 and dep.link.asv.track.chain
    dep.link.handle_datagram(_fix(0x2801, "lauv-xplore-1", t + 0.1), ASV)
    assert dep.link.rejects["usbl_fix_time"] == 1
    assert dep.usbl.times == [t + 0.1]
    dep.close()
