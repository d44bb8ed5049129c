"""Deploy configuration fields and replay options that were accepted and had no effect, or
an effect nobody was told of: the UDP-only ``[link]`` fields with ``transport = "tcp"``
(refused in one line, exit 2), ``replay --preset`` with the logged overrides (left out and
said), and the deploy's speed caps in a replay (replayed as logged)."""

from __future__ import annotations

import pytest
from test_io_silent_options import _config, _deploy_log, _deploy_refused

from mpcasv.io.config import deploy_config_from_dict

TCP_VEHICLES = [{"role": "asv", "id": 0x2801, "tcp": "127.0.0.1:6001"},
                {"role": "auv", "id": 0x2802, "tcp": "127.0.0.1:6002"}]  # fmt: skip


# --- 1. UDP-only [link] fields with link.transport = "tcp" ----------------------------------

@pytest.mark.parametrize("field, value", [
    ("port", 6010), ("announce_to", ["127.0.0.1:30100"]), ("announce_period", 5.0),
    ("discovery_ports", [30100]), ("discovery_group", "224.0.75.70"),
    ("discovery_bind", "127.0.0.1"),
])  # fmt: skip
def test_a_udp_only_link_field_with_tcp_is_refused(field, value, tmp_path, capsys):
    """With the TCP backseat the link binds no data port, sends no Announce and opens no
    discovery socket (ImcLink.start): these fields, written by the user, were loaded and
    never read. Refused at load naming the field and the transport; with UDP they load."""
    data = _config(vehicle=TCP_VEHICLES, link={"transport": "tcp", field: value})
    _deploy_refused(data, tmp_path, capsys, f"link.{field}", "link.transport = 'tcp'",
                    "transport = 'udp'")  # fmt: skip
    udp = _config(link={field: value})
    assert getattr(deploy_config_from_dict(udp).link, field) == (
        tuple(value) if isinstance(value, list) else value)  # fmt: skip


def test_tcp_with_the_fields_it_reads_loads_and_defaults_are_never_refused():
    """`bind` (the local address of the TCP connections), the timing and the plan fields
    are read with TCP; the UDP-only fields left at their defaults are not refused."""
    link = {"transport": "tcp", "bind": "127.0.0.1", "heartbeat_period": 0.5,
            "followref_timeout": 8.0, "reference_lead_m": 10.0}  # fmt: skip
    cfg = deploy_config_from_dict(_config(vehicle=TCP_VEHICLES, link=link))
    assert cfg.link.transport == "tcp" and cfg.link.port == 6002  # the default, unread
    from mpcasv.io.config import UDP_ONLY  # the refused fields are the ones tested above

    assert set(UDP_ONLY) == {"port", "announce_to", "announce_period", "discovery_ports",
                             "discovery_group", "discovery_bind"}  # fmt: skip


def test_several_udp_only_fields_are_named_together(tmp_path, capsys):
    data = _config(vehicle=TCP_VEHICLES, link={"transport": "tcp", "port": 0,
                                               "announce_to": []})  # fmt: skip
    _deploy_refused(data, tmp_path, capsys, "link.port, link.announce_to", "remove them")


def test_a_vehicle_udp_address_with_tcp_is_refused(tmp_path, capsys):
    """`[[vehicle]] address` (its IMC UDP service) with link.transport = 'tcp' was loaded and
    never used (every message goes over the vehicle's TCP stream); refused, as `tcp` is
    with UDP."""
    veh = [TCP_VEHICLES[0] | {"address": "127.0.0.1:6002"}, TCP_VEHICLES[1]]
    _deploy_refused(_config(vehicle=veh, link={"transport": "tcp"}), tmp_path, capsys,
                    "vehicle.address", "0x2801", "link.transport = 'udp'")  # fmt: skip


# --- 2. replay --preset/--controller and the log's controller.overrides ---------------------

def _spy_overrides(monkeypatch) -> list:
    """The overrides every controller the replay builds is given."""
    from mpcasv.io import replay as replay_mod

    seen = []
    real = replay_mod.make_controller

    def spy(name, n_auv, preset=None, overrides=None, **kw):
        seen.append(overrides)
        return real(name, n_auv, preset, overrides, **kw)

    monkeypatch.setattr(replay_mod, "make_controller", spy)
    return seen


def test_replay_with_another_preset_leaves_the_logged_overrides_out_and_says_so(
        tmp_path, monkeypatch, capsys):  # fmt: skip
    """The log's controller.overrides were written for the logged preset; `replay --preset Y`
    applied them on top of Y, silently (a field of the logged preset's tuning carried into
    another). Y is now replayed as it is, and the first lines say the overrides were left
    out; the logged preset, given or not, still gets them."""
    from mpcasv.cli import main
    from mpcasv.io.replay import replay

    ctl = {"name": "hybrid-single", "preset": "paper1-field", "overrides": {"speed": 1.0}}
    log = _deploy_log(tmp_path, ctl)
    seen = _spy_overrides(monkeypatch)
    rep = replay(log, preset="paper1-sim")
    assert rep.preset == "paper1-sim" and seen == [None]
    (note,) = rep.notes
    assert "controller.overrides {'speed': 1.0} are not applied" in note
    assert "hybrid-single with preset paper1-field" in note
    assert main(["replay", str(log), "--preset", "paper1-sim"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1].startswith("note: the logged controller.overrides {'speed': 1.0}")
    seen.clear()
    for given in (None, "paper1-field"):  # the logged preset: its overrides, nothing to say
        rep = replay(log, preset=given)
        assert rep.notes == () and seen[-1] == {"speed": 1.0}


# --- 3. replay and the deploy's speed caps --------------------------------------------------

def test_replay_applies_the_logged_speed_caps(tmp_path):
    """The deploy caps every transit at speed.command_max and, with speed_feedback, caps the
    controller at the achievable speed it learned (event controller_speed_cap); replay ran
    the controller uncapped, so a log with caps replayed with differences in every capped
    decision. The caps are now replayed as logged: nothing differs, and it is said."""
    import dataclasses

    from mpcasv.interface import ASVState, AUVEstimate, Observation
    from mpcasv.io.deploy import Deploy
    from mpcasv.io.imc import NavState
    from mpcasv.io.logs import read_jsonl
    from mpcasv.io.replay import replay

    dep = Deploy(deploy_config_from_dict(_cap_config(tmp_path)))
    dep.event("started", config=dataclasses.asdict(dep.cfg), guard=dataclasses.asdict(dep.gp))

    def decide(t: float, asv_N: float) -> None:
        auv = AUVEstimate(1000.0, 0.0, 0.0, 0.0, 0.0, (1.0, 0.0, 0.0, 1.0), t)
        obs = Observation(t, ASVState(asv_N, 0.0, 0.0, 1.2), True, (auv,))
        dep._act(t, t, obs, ["ok"], [0.0], dep.controller.step(obs), 0.0)

    decide(0.0, 0.0)
    dep.link.asv.id = 0x2801
    for k in range(1, 400):  # commanded 2.0 (capped), made 1.2: a persistent shortfall
        t = 0.1 * k
        dep._on_state(dep.link.asv, NavState(t, 0.12 * k, 0, 0, 0, 1.2, 0, 0, 1.2, 0, 0, 0), t)
    decide(40.0, 48.0)
    decide(41.0, 49.2)
    dep.close()
    steps = read_jsonl(dep.jsonl.path, "step")
    assert [r["controller_cmd"]["speed"] for r in steps] == [2.5, 1.2, 1.2]  # capped at 1.2
    # sent: at most command_max; at the cap the controller's own 2.5 m/s is asked for (a
    # speed loop like DUNE's Otter's locks at the speed it made when asked for just that)
    assert [r["cmd"]["speed"] for r in steps] == [2.0, 2.0, 2.0]
    assert [r["speed_ask"] for r in steps] == [None, 2.5, 2.5]
    rep = replay(dep.jsonl.path)
    assert (rep.n_steps, rep.n_differ) == (3, 0), rep.table
    # (a Deploy driven here, never run to its end: also the note that it has no summary)
    (note,) = [n for n in rep.notes if n.startswith("speed caps")]
    assert "controller_speed_cap" in note and "1.2 m/s" in note and "command_max 2 m/s" in note


# --- 4. session-25 review: replay's guard, caps, speeds and the logged controller ----------

def _spy_guard(monkeypatch) -> list:
    """The guard parameters every replayed decision is guarded with."""
    from mpcasv.io import replay as replay_mod

    seen = []
    real = replay_mod.guard

    def spy(cmd, obs, status, ages, p):
        seen.append(p)
        return real(cmd, obs, status, ages, p)

    monkeypatch.setattr(replay_mod, "guard", spy)
    return seen


def test_replay_with_another_preset_gets_that_presets_whole_guard(tmp_path, monkeypatch):
    """`replay LOG --preset paper1-sim` on a paper1-field log took the guard speed from
    paper1-sim and the keep-out sphere (and every watchdog limit) from the logged guard:
    two guards mixed. The replayed controller's guard is now built as the deploy builds it
    (guard_params), from it and the logged [watchdog]: paper1-sim's r_in is 30 m."""
    from mpcasv.controllers import make_controller
    from mpcasv.io.config import WatchdogSpec
    from mpcasv.io.deploystep import guard_params
    from mpcasv.io.replay import replay

    log = _deploy_log(tmp_path, {"name": "hybrid-single", "preset": "paper1-field"})
    seen = _spy_guard(monkeypatch)
    replay(log, preset="paper1-sim")
    want = guard_params(WatchdogSpec(), make_controller("hybrid-single", 1, "paper1-sim"))
    assert seen == [want] and want.r_keep == pytest.approx(30.0)
    seen.clear()
    replay(log)  # the logged controller and preset: the logged guard, as the deploy had it
    assert seen[0].r_keep == 10.0 and seen[0].speed == 1.5


def test_replay_with_a_controller_when_the_logged_one_is_unknown(tmp_path, capsys):
    """A log of a controller this version does not know ('hybrid-old', renamed since):
    `replay LOG --controller hybrid-single` exited 2 "unknown controller 'hybrid-old'"
    (the logged preset was resolved for the logged name). It replays again."""
    import json

    from mpcasv.cli import main

    log = _deploy_log(tmp_path, {"name": "hybrid-single", "overrides": {"speed": 1.0}})
    recs = [json.loads(line) for line in log.read_text().splitlines()]
    recs[0]["config"]["controller"]["name"] = "hybrid-old"  # its default preset, logged None
    log.write_text("".join(json.dumps(r) + "\n" for r in recs))
    assert main(["replay", str(log), "--controller", "hybrid-single"]) == 0
    out = capsys.readouterr().out
    assert "with hybrid-single (preset paper1-sim)" in out  # hybrid-single's default
    assert "written for hybrid-old with its default preset" in out


def test_replay_shows_the_logged_and_replayed_speeds(tmp_path, capsys):
    """A decision that differed only in its speed showed a row with the same mode, reason,
    AUV and waypoint (0.0 m): the speeds were not in the table. They are now, printed and in
    --json."""
    import json

    import pandas as pd

    from mpcasv.cli import main

    log = _deploy_log(tmp_path, {"name": "hybrid-single", "preset": "paper1-field"})
    recs = [json.loads(line) for line in log.read_text().splitlines()]
    assert recs[1]["cmd"]["mode"] == "transit" and recs[1]["cmd"]["speed"] == 2.5
    recs[1]["cmd"]["speed"] = 1.75  # the deploy sent another speed
    log.write_text("".join(json.dumps(r) + "\n" for r in recs))
    out_json = tmp_path / "cmp.jsonl"
    assert main(["replay", str(log), "--json", str(out_json)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "logged_speed" in out[-2] and "replay_speed" in out[-2]
    assert out[-1].split()[-2:] == ["1.8", "2.5"]  # 1.75 at one decimal
    row = pd.read_json(out_json, lines=True).iloc[0]
    assert (row["logged_speed"], row["replay_speed"]) == (1.75, 2.5)


def _cap_config(tmp_path) -> dict:
    """A hybrid-single deploy configuration with speed_feedback and command_max 2 m/s, its
    log in ``tmp_path``."""
    return _config(vehicle=[{"role": "asv", "id": 0x2801, "address": "127.0.0.1:6002"},
                            {"role": "auv", "id": 0x2811, "address": "127.0.0.1:6003"}],
                   link={"port": 0, "announce_to": [], "plan_done_timeout": 0.3},
                   controller={"speed_feedback": True}, speed={"command_max": 2.0},
                   log={"dir": str(tmp_path)})  # fmt: skip


def _cap_deploy(tmp_path, monkeypatch):
    """A hybrid-single deploy (speed_feedback, command_max 2 m/s) on a clock the test sets
    (``now[0]``), with a ``decide(t, asv_N)`` writing a decision at deploy clock 1000 + t."""
    import dataclasses

    from mpcasv.interface import ASVState, AUVEstimate, Observation
    from mpcasv.io.deploy import Deploy

    dep = Deploy(deploy_config_from_dict(_cap_config(tmp_path)))
    now = [1000.0]
    monkeypatch.setattr(dep.clock, "now", lambda: now[0])
    dep.event("started", config=dataclasses.asdict(dep.cfg), guard=dataclasses.asdict(dep.gp))

    def decide(t: float, asv_N: float) -> None:
        now[0] = 1000.0 + t
        auv = AUVEstimate(1000.0, 0.0, 0.0, 0.0, 0.0, (1.0, 0.0, 0.0, 1.0), t)
        obs = Observation(t, ASVState(asv_N, 0.0, 0.0, 1.2), True, (auv,))
        dep._act(t, now[0], obs, ["ok"], [0.0], dep.controller.step(obs), 0.0)

    return dep, now, decide


class _Task:
    """A stand-in for the field mode's step task."""

    def __init__(self, done: bool) -> None:
        self._done = done

    def done(self) -> bool:
        return self._done


def _speed_spy(monkeypatch) -> list:
    """The replayed controller's ``params.speed`` at each of its decisions, appended to the
    returned list (``replay``'s ``make_controller`` wrapped)."""
    from mpcasv.io import replay as replay_mod

    speeds = []
    real = replay_mod.make_controller

    def spy(*a, **kw):
        ctl = real(*a, **kw)
        step = ctl.step
        ctl.step = lambda obs: (speeds.append(ctl.params.speed), step(obs))[1]
        return ctl

    monkeypatch.setattr(replay_mod, "make_controller", spy)
    return speeds


def test_a_cap_during_a_field_step_waits_for_the_next_step_and_replays(tmp_path, monkeypatch):
    """Field mode: the controller steps in the step thread while the event loop's
    _speed_feedback capped it (controller.params replaced mid-step) and logged
    controller_speed_cap BEFORE the step in flight wrote its record; replay, in log order,
    capped the replayed controller before a decision that had not seen the cap. The deploy now
    applies a cap between steps (before the next one starts) and every step record holds the
    cap its decision saw (speed_cap), which replay applies. The replay's note gives the cap's
    time in the table's units (s after the first decision), not on the deploy clock."""
    import asyncio

    from mpcasv.io import replay as replay_mod
    from mpcasv.io.imc import NavState
    from mpcasv.io.logs import read_jsonl

    dep, now, decide = _cap_deploy(tmp_path, monkeypatch)
    decide(0.0, 0.0)
    dep.link.asv.id = 0x2801
    dep._step_task = _Task(done=False)  # a field-mode step is solving
    for k in range(1, 400):  # commanded 2.0 (capped), made 1.2: a persistent shortfall
        t = 0.1 * k
        now[0] = 1000.0 + t
        dep._on_state(dep.link.asv, NavState(t, 0.12 * k, 0, 0, 0, 1.2, 0, 0, 1.2, 0, 0, 0),
                      now[0])  # fmt: skip
    assert dep.cap_pending == 1.2 and dep.speed_cap is None  # waits for the step in flight
    assert dep.controller.params.speed == 2.5
    decide(40.0, 48.0)  # the step in flight writes its decision: no cap seen
    dep._step_task = _Task(done=True)
    seen = []

    async def step_async(ts, now_):
        seen.append(dep.controller.params.speed)

    monkeypatch.setattr(dep, "step_async", step_async)

    async def tick():
        now[0] = 1040.9
        dep.schedule_step(40.9, now[0])
        await dep._step_task

    asyncio.run(tick())
    assert seen == [1.2] and dep.speed_cap == 1.2 and dep.cap_pending is None
    decide(41.0, 49.2)
    dep.close()
    steps = read_jsonl(dep.jsonl.path, "step")
    assert [r["speed_cap"] for r in steps] == [None, None, 1.2]
    assert [r["controller_cmd"]["speed"] for r in steps] == [2.5, 2.5, 1.2]
    assert [r["speed_ask"] for r in steps] == [None, None, 2.5]  # at the cap: the own 2.5
    assert [r["cmd"]["speed"] for r in steps] == [2.0, 2.0, 2.0]  # at most command_max
    speeds = _speed_spy(monkeypatch)  # the replayed controller's speed at each decision
    rep = replay_mod.replay(dep.jsonl.path)
    assert (rep.n_steps, rep.n_differ) == (3, 0), rep.table
    assert speeds == [2.5, 2.5, 1.2]
    (note,) = [n for n in rep.notes if n.startswith("speed caps")]  # (and: no summary)
    assert "1.2 m/s 40.9 s after the first decision" in note, note


def test_replay_of_an_older_log_places_a_cap_by_time(tmp_path, monkeypatch):
    """A log written before the step records held their cap: a controller_speed_cap logged
    before a step whose decision began earlier (its clock; the cap came while it was solving)
    reaches the replayed controller from the next decision on; the commands are capped in log
    order, as the older deploy capped them."""
    import json

    from mpcasv.io import replay as replay_mod

    log = _deploy_log(tmp_path, {"name": "hybrid-single", "preset": "paper1-field"})
    started, step, summary = [json.loads(line) for line in log.read_text().splitlines()]
    s1 = step | {"t": 1.0, "clock": 1.0, "cmd": step["cmd"] | {"speed": 1.2}}
    s2 = step | {"t": 2.0, "clock": 2.0, "cmd": step["cmd"] | {"speed": 1.2}}
    cap = {"kind": "event", "event": "controller_speed_cap", "t": 1.5, "old": 2.5, "new": 1.2,
           "plan": None}  # fmt: skip
    log.write_text("".join(json.dumps(r) + "\n" for r in (started, step, cap, s1, s2, summary)))
    speeds = _speed_spy(monkeypatch)
    rep = replay_mod.replay(log)
    assert speeds == [2.5, 2.5, 1.2]  # the decision at clock 1.0 began before the cap
    assert rep.n_differ == 0, rep.table  # its command capped as logged
    assert "1.2 m/s 1.5 s after the first decision" in rep.notes[0]


def test_a_tcp_run_that_connects_nowhere_names_link_bind_and_the_error(tmp_path, capsys):
    """Vehicles' backseat servers on another network (192.0.2.10) with link.bind left at
    127.0.0.1: every connection fails at once (EINVAL: no route from a loopback address).
    The run's last line asked only whether DUNE was running at the 'tcp' addresses; it now
    names link.bind and the last connection error."""
    import tomli_w

    from mpcasv.cli import main

    veh = [{"role": "asv", "id": 0x2801, "tcp": "192.0.2.10:6001"},
           {"role": "auv", "id": 0x2802, "tcp": "192.0.2.10:6002"}]  # fmt: skip
    data = _config(vehicle=veh, link={"transport": "tcp"}, clock={"speedup": 20.0},
                   log={"dir": str(tmp_path / "log")})  # fmt: skip
    path = tmp_path / "deploy.toml"
    path.write_text(tomli_w.dumps(data))
    assert main(["deploy", str(path), "--dry-run", "--duration", "4", "--quiet"]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "no vehicle heard" in line and "192.0.2.10:6001" in line
    assert "link.bind 127.0.0.1" in line and "The last connection failed: " in line, line


# --- 5. session-25 review: the link fields a transport never reads, in one check ------------

def _refusal(data: dict) -> str:
    from mpcasv.config import ConfigError

    with pytest.raises(ConfigError) as err:
        deploy_config_from_dict(data, "deploy.toml")
    return str(err.value)


def test_tcp_refuses_unread_link_fields_and_addresses_in_one_line_with_advice_that_works(
        tmp_path, capsys):  # fmt: skip
    """With TCP a vehicle's `address` was refused by the model validator ("invalid
    configuration; FILE: (top level): ...") and the UDP-only [link] fields later, in a
    second round with another prefix; both advised "or set transport = 'udp'", which then
    got the vehicles' `tcp` refused. Now one line names them all, and either advice loads."""
    veh = [TCP_VEHICLES[0] | {"address": "127.0.0.1:6002"}, TCP_VEHICLES[1]]
    data = _config(vehicle=veh, link={"transport": "tcp", "port": 6010})
    _deploy_refused(data, tmp_path, capsys, "deploy.toml: link.port, vehicle.address (of "
                    "0x2801): not read with link.transport = 'tcp'", "remove them")  # fmt: skip
    assert "invalid configuration" not in _refusal(data)
    # the advice: remove them; or UDP, with every 'tcp' removed
    assert deploy_config_from_dict(_config(vehicle=TCP_VEHICLES, link={"transport": "tcp"}))
    assert "remove every 'tcp'" in _refusal(data)
    udp = _config(vehicle=[{k: v for k, v in x.items() if k != "tcp"} for x in veh],
                  link={"transport": "udp", "port": 6010})  # fmt: skip
    assert deploy_config_from_dict(udp).link.transport == "udp"
    # with every vehicle addressed, the UDP advice names the discovery fields too
    both = [v | {"address": f"127.0.0.1:{6002 + k}"} for k, v in enumerate(TCP_VEHICLES)]
    msg = _refusal(_config(vehicle=both, link={"transport": "tcp", "discovery_group":
                                               "224.0.75.70"}))  # fmt: skip
    assert "remove every 'tcp' and link.discovery_group" in msg, msg


def test_udp_with_a_vehicle_tcp_advises_what_tcp_needs(tmp_path, capsys):
    """A vehicle's `tcp` with UDP: refused in the same check (same prefix); the advice to
    switch to TCP says what else TCP needs (every vehicle's 'tcp' and 'id', no 'address')."""
    veh = [{"role": "asv", "id": 0x2801, "tcp": "127.0.0.1:6001", "address": "127.0.0.1:6002"},
           {"role": "auv", "id": 0x2802}]  # fmt: skip
    msg = _refusal(_config(vehicle=veh))
    assert msg.startswith("deploy.toml: vehicle.tcp (of 0x2801): read only with "), msg
    assert "give every vehicle a 'tcp' and an 'id', and remove every 'address'" in msg


@pytest.mark.parametrize("field, value", [
    ("discovery_ports", [30102]), ("discovery_group", "224.0.75.70"),
    ("discovery_bind", "127.0.0.1"),
])  # fmt: skip
def test_udp_discovery_fields_with_every_vehicle_addressed_are_refused(field, value, tmp_path,
                                                                       capsys):  # fmt: skip
    """Under UDP the discovery sockets are opened only for a vehicle without `address`
    (ImcLink.start): with every vehicle addressed the discovery fields, written, were never
    read. Refused in the same check; with one vehicle unaddressed, or left at their
    defaults, they load."""
    addressed = [{"role": "asv", "id": 0x2801, "address": "127.0.0.1:6002"},
                 {"role": "auv", "id": 0x2802, "address": "127.0.0.1:6003"}]  # fmt: skip
    _deploy_refused(_config(vehicle=addressed, link={field: value}), tmp_path, capsys,
                    f"link.{field}: not read when every vehicle has an 'address'",
                    "remove it")  # fmt: skip
    learnt = [addressed[0], {"role": "auv", "id": 0x2802}]
    assert deploy_config_from_dict(_config(vehicle=learnt, link={field: value}))
    assert deploy_config_from_dict(_config(vehicle=addressed))  # defaults: never refused


def test_the_shipped_deploy_configurations_load():
    """experiments/deploy/*.toml (dune-otter.toml wrote discovery_ports with both vehicles
    addressed: unread)."""
    from pathlib import Path

    from mpcasv.io.config import load_deploy_config

    files = sorted((Path(__file__).parents[1] / "experiments" / "deploy").glob("*.toml"))
    assert len(files) >= 3
    for f in files:
        load_deploy_config(f)


def test_rehearsal_config_for_a_tcp_base_leaves_out_the_vehicles_addresses():
    """deploy_config_for removed a TCP base's UDP-only [link] fields but kept the vehicles'
    `address` (refused with TCP): the rehearsal's configuration did not load."""
    from mpcasv.io.rehearsal import deploy_config_for

    base = _config(vehicle=[v | {"address": f"127.0.0.1:{7000 + k}"}
                            for k, v in enumerate(TCP_VEHICLES)],
                   link={"transport": "tcp", "port": 6010})  # fmt: skip
    cfg = deploy_config_for({"discovery": "127.0.0.1:30100"}, base, "/tmp/x", 4.0)
    loaded = deploy_config_from_dict(cfg)
    assert all(v.address is None for v in loaded.vehicle)
    assert (loaded.clock.speedup, loaded.log.dir) == (4.0, "/tmp/x")
    udp = deploy_config_for({"discovery": "127.0.0.1:30100"},
                            _config(vehicle=[{k: v for k, v in x.items() if k != "tcp"}
                                             for x in base["vehicle"]]), "/tmp/x", 4.0)  # fmt: skip
    assert "discovery_ports" not in udp["link"]  # every vehicle addressed: none to open
    assert deploy_config_from_dict(udp)


@pytest.mark.parametrize("line, said", [
    ('current = "oracle"', "current = 'oracle'"),
    ('fix_age_source = "observed"', "fix_age_source = 'observed'"),
])  # fmt: skip
def test_replay_refuses_a_preset_that_reads_what_only_a_simulator_observes(tmp_path, capsys,
                                                                           line, said):  # fmt: skip
    """A deploy log's observations carry no true current, and a log written before the
    deploy read DUNE's UsblFixExtended (as this one) no USBL fix times; `replay --preset P`
    with such a P ended in a traceback at its first step (exit 1, a new user's finding,
    session 40). Refused in one line, exit 2 (a log with fix times replays M2o:
    tests/test_deploy_usbl.py)."""
    from pathlib import Path

    import mpcasv
    from mpcasv.cli import main

    log = _deploy_log(tmp_path, {"name": "mpc-single", "preset": "mpc-single"})
    text = (Path(mpcasv.__file__).parent / "data" / "presets" / "mpc-single.toml").read_text()
    preset = tmp_path / "sim-only.toml"
    key = line.split(" = ")[0]
    kept = [x for x in text.splitlines() if not x.startswith(f"{key} = ")]  # the preset's own
    preset.write_text("\n".join(kept).replace('controller = "mpc-single"',
                                              f'controller = "mpc-single"\n{line}', 1))
    assert main(["replay", str(log), "--preset", str(preset)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and said in err[0], err
