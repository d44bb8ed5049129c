"""The SITL's vehicles behave towards the network as DUNE does (in-process, loopback):
Announce-gated input, Heartbeat-gated EstimatedState at 2 Hz, PlanControl answers,
FollowReference timeout, speed 0 = loops off."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import imcpy
import numpy as np
import pytest

from mpcasv.io.imc import BROADCAST, announce, decode, stamp
from mpcasv.io.logs import read_jsonl
from mpcasv.io.sitl import Sitl, SitlOptions
from mpcasv.io.transport import UdpEndpoint
from mpcasv.sim.scenario import load_scenario

CASE3 = Path(__file__).resolve().parents[1] / "experiments" / "scenarios" / "case3.toml"
ME = 0x4001
PC = imcpy.PlanControl


class Node:
    opened: list[Node] = []  # every Node opened and not yet closed (by _run)

    def __init__(self):
        self.got: list[imcpy.Message] = []
        self.sources: dict[str, set] = {}  # message name -> (host, port) it came from

    async def open(self):
        self.ep = await UdpEndpoint.open("127.0.0.1", 0, self._recv)
        Node.opened.append(self)
        return self

    def _recv(self, data, addr):
        m = decode(data)[0]
        self.got.append(m)
        self.sources.setdefault(type(m).__name__, set()).add(addr)

    def send(self, msg, to, dst=BROADCAST, src=ME):
        stamp(msg, src, dst, time.time())
        self.ep.sendto(msg.serialize(), to)

    def announce(self, to):
        h, p = self.ep.address
        self.send(announce("tester", imcpy.SystemType.CCU, [f"imc+udp://{h}:{p}/"]), to)

    def of(self, cls, src=None):
        return [m for m in self.got if isinstance(m, cls) and (src is None or m.src == src)]


async def _until(pred, timeout=5.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if pred():
            return True
        await asyncio.sleep(0.005)
    return False


def _run(tmp_path, body, **opt):
    sc = load_scenario(CASE3)

    async def main():
        sitl = Sitl(sc, SitlOptions(speedup=20.0, discovery_port=0, out=tmp_path, **opt))
        stop = asyncio.Event()
        task = asyncio.create_task(sitl.run(stop))
        assert await _until(lambda: sitl.epoch > 0)
        try:
            await body(sitl)
        finally:
            stop.set()
            while Node.opened:
                Node.opened.pop().ep.close()
            await task
        return sitl

    return asyncio.run(main())


def test_streams_only_to_announced_heartbeating_systems(tmp_path):
    async def body(sitl):
        asv = ("127.0.0.1", sitl.asv.port)
        disc = sitl.discovery.address
        quiet, node = await Node().open(), await Node().open()
        quiet.announce(disc)  # announced, never heartbeats
        node.send(imcpy.Heartbeat(), asv, dst=sitl.asv.id)  # not announced yet: dropped
        assert await _until(lambda: sitl.counts.get("drop_unannounced", 0) >= 1)
        node.announce(disc)
        assert await _until(lambda: node.of(imcpy.Announce, sitl.asv.id))  # answered at once
        for _ in range(8):
            node.send(imcpy.Heartbeat(), asv, dst=sitl.asv.id)
            await asyncio.sleep(0.05)
        es = node.of(imcpy.EstimatedState, sitl.asv.id)
        assert len(es) >= 5
        dt = np.diff([m.timestamp for m in es])
        assert np.all(dt == 0.5)  # 2 Hz, exact timestamps
        assert not quiet.of(imcpy.EstimatedState)
        # as DUNE: no thruster messages while the loops are off (no maneuver yet); the
        # Announce from a socket of its own; our Heartbeats relayed back to us
        assert not node.of(imcpy.SetThrusterActuation, sitl.asv.id)
        assert ("127.0.0.1", sitl.asv.port) not in node.sources["Announce"]
        assert len(node.of(imcpy.Heartbeat, ME)) >= 7
        # AUVs stream only to systems that heart-beat them, too
        assert not node.of(imcpy.EstimatedState, sitl.auvs[0].id)

    _run(tmp_path, body, duration=1000.0)


async def _heard(sitl):
    """(the SITL ASV's address, a node it has heard: announced, then a Heartbeat to it)."""
    asv = ("127.0.0.1", sitl.asv.port)
    node = await Node().open()
    node.announce(sitl.discovery.address)
    assert await _until(lambda: node.of(imcpy.Announce, sitl.asv.id))
    node.send(imcpy.Heartbeat(), asv, dst=sitl.asv.id)
    return asv, node


def test_plan_control_followreference_timeout_and_speed_zero(tmp_path):
    async def body(sitl):
        asv, node = await _heard(sitl)

        def start(req, dst, arg=True):
            pc = imcpy.PlanControl()
            pc.type, pc.op, pc.request_id, pc.plan_id = (
                PC.TypeEnum.REQUEST,
                PC.OperationEnum.START,
                req,
                "p",
            )
            if arg:
                fr = imcpy.FollowReference()
                fr.control_src, fr.control_ent, fr.timeout = ME, 0xFF, 5.0
                pc.arg = fr
            node.send(pc, asv, dst=dst)

        start(7, dst=0x1234)  # not for this vehicle: not answered (as DUNE), but relayed
        start(8, dst=sitl.asv.id, arg=False)
        assert await _until(lambda: node.of(imcpy.PlanControl, sitl.asv.id))
        await asyncio.sleep(0.05)
        answers = node.of(imcpy.PlanControl, sitl.asv.id)
        assert [(a.request_id, a.type) for a in answers] == [(8, PC.TypeEnum.FAILURE)]
        echoes = node.of(imcpy.PlanControl, ME)  # DUNE echoes every PlanControl it takes in
        assert [(e.request_id, e.dst) for e in echoes] == [(7, 0x1234), (8, sitl.asv.id)]
        start(9, dst=sitl.asv.id)
        assert await _until(lambda: len(node.of(imcpy.PlanControl, sitl.asv.id)) == 3)
        ok = node.of(imcpy.PlanControl, sitl.asv.id)[1:]  # answered twice, as recorded DUNE
        assert [(a.request_id, a.type, a.plan_id, a.info) for a in ok] == [
            (9, PC.TypeEnum.SUCCESS, "p", "plan loaded"),
            (9, PC.TypeEnum.SUCCESS, "p", "FollowReference: executing maneuver")]
        assert sitl.maneuver is not None and not np.any(sitl.command_vector())  # WAIT

        def ref(N, E, speed):
            from mpcasv.interface import Command, Mode
            from mpcasv.io.imc import reference

            cmd = Command(Mode.TRANSIT, (N, E), speed) if speed > 0 else Command.standby()
            x = sitl.world.x
            node.send(reference(cmd, (x[0], x[1]), sitl.origin), asv, dst=sitl.asv.id)

        ref(0.0, 0.0, 2.0)
        assert await _until(lambda: sitl.command_vector()[0] == 1.0)
        frs = node.of(imcpy.FollowRefState)
        assert frs[-1].state == imcpy.FollowRefState.StateEnum.GOTO
        assert await _until(lambda: any(m.value > 0 for m in node.of(
            imcpy.SetThrusterActuation, sitl.asv.id)))  # fmt: skip
        n_on = len(node.of(imcpy.SetThrusterActuation))
        ref(0.0, 0.0, 0.0)  # speed 0: loops off, the boat drifts
        assert await _until(lambda: not np.any(sitl.command_vector()))
        # one 0.0 per thruster when the loops stop, then none (as DUNE's Otter in HOVER)
        assert await _until(lambda: len(node.of(imcpy.SetThrusterActuation)) > n_on
                            and node.of(imcpy.SetThrusterActuation)[-1].value == 0.0)
        n_th = len(node.of(imcpy.SetThrusterActuation))
        await asyncio.sleep(0.1)  # 2 s of the SITL clock
        assert len(node.of(imcpy.SetThrusterActuation)) == n_th
        # no Reference for longer than the timeout (5 s = 0.25 s of wall clock at 20x)
        assert await _until(lambda: sitl.maneuver.done, timeout=2.0)
        # the TIMEOUT state is announced (over UDP: wait for it to arrive, do not race it)
        timeout = imcpy.FollowRefState.StateEnum.TIMEOUT
        assert await _until(lambda: node.of(imcpy.FollowRefState)[-1].state == timeout)
        assert not np.any(sitl.command_vector())

    sitl = _run(tmp_path, body, duration=1000.0)
    assert sitl.counts.get("references", 0) == 2


@pytest.mark.parametrize("hold", [True, False])
def test_hold_keeps_the_world_still_until_the_first_reference(tmp_path, hold):
    async def body(sitl):
        await asyncio.sleep(0.3)  # 6 s of the SITL clock

    sitl = _run(tmp_path, body, duration=1000.0, hold=hold)
    assert (len(sitl.rows) == 0) == hold
    assert (sitl.ts_offset is None) == hold


@pytest.mark.parametrize("nominal", [False, True])
def test_the_sitl_runs_the_world_mpcasv_simulate_runs(tmp_path, nominal):
    """Same seed and duration, same world: the scenario realised for the seed (or its nominal
    values with ``nominal``), recorded in ``run/run.json`` as ``mpcasv simulate`` records it.
    The SITL ran the nominal values whatever the seed (a new user's docs walk-through,
    session 24), so a rehearsal compared with ``mpcasv simulate --seed S`` met another
    world (Case 3, seed 3: a current where the SITL had none)."""
    import json

    from mpcasv.sim.uncertainty import run_scenario

    sc = load_scenario(CASE3)
    assert sc.uncertain.current.speed is not None  # else this test shows nothing

    async def body(sitl):
        await asyncio.sleep(0.3)  # a few periods at speedup 20

    sitl = _run(tmp_path, body, seed=3, duration=30.0, nominal=nominal)
    world, real = run_scenario(sc, 3, nominal, 30.0)
    assert sitl.realisation == real and sitl.sc == world
    drawn = not np.array_equal(np.asarray(world.current), np.asarray(sc.current))
    assert drawn != nominal  # seed 3 draws a current the nominal scenario does not have
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run["realisation"] == real.as_dict()
    # the world's acoustic channel for the deploy's [acoustics] (session 41: a rehearsal's MPC
    # planned with the default channel where mpcasv simulate of the seed plans with the drawn
    # one; a new user's finding): in acoustics.toml and in the ready information
    import dataclasses

    from mpcasv.config import load_toml
    from mpcasv.io.rehearsal import deploy_config_for

    channel = dataclasses.asdict(world.acoustics)
    assert load_toml(tmp_path / "acoustics.toml")["acoustics"] == channel
    ready = [r for r in read_jsonl(tmp_path / "sitl.jsonl", "event") if r["event"] == "ready"]
    assert ready[0]["acoustics"] == channel
    assert deploy_config_for(ready[0], {}, tmp_path, 1.0)["acoustics"] == channel
    if not nominal:  # seed 3 draws another channel than the scenario's
        assert channel != dataclasses.asdict(sc.acoustics)


@pytest.mark.parametrize(("change", "match"), [
    ({"preset": "no-such-preset"}, "no-such-preset"),
    ({"preset": "mpc-multi"}, "mpc-multi"),  # a preset of another controller
])
def test_a_scenario_whose_controller_cannot_run_is_refused_without_building_it(
        tmp_path, monkeypatch, change, match):
    """The SITL validates the scenario's controller and preset as ``simulate`` would, and
    builds no controller (the deploy does): an MPC scenario loaded its solver for nothing."""
    import dataclasses

    import mpcasv.controllers as controllers
    import mpcasv.controllers.registry as registry
    from mpcasv.config import ConfigError

    sc = load_scenario(Path(__file__).parents[1] / "experiments/scenarios/case3.toml")
    built = []
    for module in (controllers, registry):
        monkeypatch.setattr(module, "make_controller", lambda *a, **k: built.append(a))
    opt = SitlOptions(discovery_port=0, out=tmp_path)
    with pytest.raises(ConfigError, match=match):
        Sitl(dataclasses.replace(sc, **change), opt)
    mpc = dataclasses.replace(sc, controller="mpc-single", preset="mpc-single")
    sitl = Sitl(mpc, opt)
    sitl.close()
    assert built == []


def test_a_sitl_stopped_while_held_says_why_it_wrote_no_run(tmp_path):
    """``--hold`` and no deploy: stopped (SIGTERM) while the world stands at t = 0, the SITL
    writes no ``run/`` (no period to write) and says so, on stderr and in its ``finished``
    event, and exits 1 (a new user's finding, session 41: it exited 0 and said nothing)."""
    import signal

    from mpcasv.io.rehearsal import start_sitl

    out = tmp_path / "sitl"
    proc, _ = start_sitl(CASE3, out, "--hold", "--quiet")
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(60) == 1
    err = (out / "sitl.stderr").read_text()
    assert "mpcasv sitl: no run written to" in err and "(--hold): no Reference came" in err
    assert not (out / "run").exists()
    finished = [e for e in read_jsonl(out / "sitl.jsonl", "event") if e["event"] == "finished"]
    assert finished[0]["no_run"] == "the world stood at t = 0 (--hold): no Reference came"


def test_a_tcp_client_connected_at_the_end_ends_quietly():
    """``mpcasv sitl --tcp`` ending with the deploy still connected (a normal end): its
    sockets closed as the SITL closes them, the client's handler is cancelled by
    ``asyncio.run`` and ends without an error for the loop (before session 45: one
    ``CancelledError`` traceback per connected vehicle on stderr, from Python 3.11's
    ``StreamReaderProtocol``; a field engineer's trial)."""
    from mpcasv.io.simvehicle import SimVehicle

    errors = []

    async def main():
        asyncio.get_running_loop().set_exception_handler(lambda loop, ctx: errors.append(ctx))
        v = SimVehicle(sitl=None, name="sitl-asv", id=0x2801, role="asv", index=0)
        await v.serve_tcp("127.0.0.1")
        _, writer = await asyncio.open_connection("127.0.0.1", v.tcp_port)
        for _ in range(10_000):  # the server's handler has started (loop turns, no clock)
            if v.tcp_clients:
                break
            await asyncio.sleep(0)
        assert v.tcp_clients
        v.tcp_server.close()  # as Sitl.close_sockets
        for stream in list(v.tcp_clients):
            stream.close()
        return writer  # the client side still open

    asyncio.run(main())
    assert [e.get("message") for e in errors] == []
