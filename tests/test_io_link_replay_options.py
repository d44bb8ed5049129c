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

    data = _config(vehicle=[{"role": "asv", "id": 0x2801, "address": "127.0.0.1:6002"},
                            {"role": "auv", "id": 0x2811, "address": "127.0.0.1:6003"}],
                   link={"port": 0, "announce_to": [], "plan_done_timeout": 0.3},
                   controller={"speed_feedback": True}, speed={"command_max": 2.0},
                   log={"dir": str(tmp_path)})  # fmt: skip
    dep = Deploy(deploy_config_from_dict(data))
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
    dep.jsonl.close()
    dep.lsf.close()
    logged = [r["cmd"]["speed"] for r in read_jsonl(dep.jsonl.path, "step")]
    assert logged == [2.0, 1.2, 1.2]  # both caps at work (the preset's speed is 2.5 m/s)
    rep = replay(dep.jsonl.path)
    assert (rep.n_steps, rep.n_differ) == (3, 0), rep.table
    (note,) = rep.notes
    assert "controller_speed_cap" in note and "1.2 m/s" in note and "command_max 2 m/s" in note
