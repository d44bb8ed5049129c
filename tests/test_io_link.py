"""The deploy loop's IMC link in-process, against fake vehicles on 127.0.0.1 sockets:
discovery, rejection of bad input with a counted and logged reason, a 10 000-datagram fuzz,
only configured vehicles driving the controller, dry run, log flushing."""

from __future__ import annotations

import asyncio
import math
import struct
import time

import imcpy
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mpcasv.io.config import deploy_config_from_dict
from mpcasv.io.deploy import WAITING, Deploy
from mpcasv.io.geo import Origin, to_wgs84
from mpcasv.io.imc import BROADCAST, BadInput, NavState, announce, decode, estimated_state, stamp
from mpcasv.io.logs import read_jsonl
from mpcasv.io.transport import UdpEndpoint

ORIGIN_DEG = (63.4406, 10.3530)
ORIGIN = Origin.from_degrees(*ORIGIN_DEG)
ASV_ID, AUV_ID, DEPLOY_ID = 0x2801, 0x2811, 0x4001


def _cfg(tmp_path, speedup=1.0, **watchdog):
    return deploy_config_from_dict({
        "identity": {"id": DEPLOY_ID},
        "origin": {"lat_deg": ORIGIN_DEG[0], "lon_deg": ORIGIN_DEG[1]},
        # the fakes announce to our data port; no discovery ports (parallel tests, other
        # programs on this host): test_discovery_socket_* opens one on a free port
        "link": {"bind": "127.0.0.1", "port": 0, "announce_to": [], "discovery_ports": []},
        "vehicle": [{"role": "asv", "name": "fake-asv", "id": ASV_ID},
                    {"role": "auv", "name": "fake-auv"}],
        "controller": {"name": "hybrid-single", "preset": "paper1-field"},
        "watchdog": watchdog, "clock": {"speedup": speedup},
        "log": {"dir": str(tmp_path / "log"), "flush_s": 0.2},
    })  # fmt: skip


class Fake:
    """A vehicle (or an intruder) with its own UDP socket (closed by :func:`run`)."""

    opened: list[Fake] = []  # every Fake opened and not yet closed

    def __init__(self, name: str, imc_id: int, sys_type=imcpy.SystemType.UUV):
        self.name, self.id, self.sys_type = name, imc_id, sys_type
        self.received: list[imcpy.Message] = []
        self.anchor = None

    async def open(self):
        self.ep = await UdpEndpoint.open("127.0.0.1", 0, self._recv)
        Fake.opened.append(self)
        return self

    def close(self):
        self.ep.close()

    def _recv(self, data, addr):
        self.received.append(decode(data)[0])

    def send(self, msg, to, t, dst=BROADCAST, src=None):
        stamp(msg, self.id if src is None else src, dst, t)
        self.ep.sendto(msg.serialize(), to)

    def send_raw(self, data: bytes, to):
        self.ep.sendto(data, to)

    def announce(self, to, t):
        host, port = self.ep.address
        self.send(announce(self.name, self.sys_type, [f"imc+udp://{host}:{port}/"]), to, t)

    def es(self, t, N, E, depth=0.0, psi=0.0, speed=1.0):
        if self.anchor is None:
            self.anchor = Origin(*to_wgs84(N, E, ORIGIN), 0.0)
        nav = NavState(t, N, E, depth, psi, speed, 0, 0, speed * math.cos(psi),
                       speed * math.sin(psi), 0, 0)  # fmt: skip
        return estimated_state(nav, self.anchor, ORIGIN)

    def kinds(self) -> set[str]:
        return {type(m).__name__ for m in self.received}


def run(main):
    """``asyncio.run(main())``; the fakes it opened are closed at its end, passed or failed
    (the deploy it started is closed by its run: stopped, or aborted when cancelled)."""

    async def closing():
        try:
            return await main()
        finally:
            while Fake.opened:
                Fake.opened.pop().close()

    return asyncio.run(closing())


async def _until(pred, timeout=3.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if pred():
            return True
        await asyncio.sleep(0.002)
    return False


async def _start(cfg, tmp_path, dry_run=False):
    dep = Deploy(cfg, dry_run, tmp_path / "log")
    stop = asyncio.Event()
    task = asyncio.create_task(dep.run(stop))
    assert await _until(lambda: dep.link.endpoint is not None)
    return dep, stop, task


def test_bad_input_rejected_counted_logged(tmp_path):
    """Each kind of bad input is rejected under its reason, logged, and the loop goes on."""

    async def main():
        dep, stop, task = await _start(_cfg(tmp_path), tmp_path)
        to = dep.link.endpoint.address
        assert to[0] == "127.0.0.1"  # bound to the configured address only
        asv, auv = await Fake("fake-asv", ASV_ID, imcpy.SystemType.USV).open(), await Fake(
            "fake-auv", AUV_ID).open()  # fmt: skip
        other = await Fake("intruder", 0x7777).open()
        now = dep.clock.now
        link = dep.link

        expected = []

        async def expect(reason, send):
            expected.append(reason)
            before = link.rejects[reason]
            send()
            assert await _until(lambda: link.rejects[reason] == before + 1), (
                reason,
                dict(link.rejects),
            )

        # the ASV is configured by id but has not announced its address yet; the AUV is
        # configured by name only: before its Announce its id means nothing
        await expect("not_announced", lambda: asv.send(asv.es(now(), 0, 0), to, now()))
        await expect("unknown_sender", lambda: auv.send(auv.es(now(), 0, 0), to, now()))
        auv.announce(to, now())
        asv.announce(to, now())
        assert await _until(lambda: link.auvs[0].id == AUV_ID and link.asv.addresses)
        t0 = now()
        auv.send(auv.es(t0, 100.0, 50.0), to, t0)
        assert await _until(lambda: link.accepted["EstimatedState"] == 1)
        good = imcpy.Heartbeat()
        stamp(good, AUV_ID, DEPLOY_ID, t0)
        packet = good.serialize()
        flipped = bytearray(packet)
        flipped[21] ^= 0x10
        await expect("bad_sync", lambda: auv.send_raw(b"\x00" * 40, to))
        await expect("truncated", lambda: auv.send_raw(packet[:-3], to))
        await expect("truncated", lambda: auv.send_raw(packet[:10], to))
        await expect("bad_crc", lambda: auv.send_raw(bytes(flipped), to))
        await expect("trailing_bytes", lambda: auv.send_raw(packet + b"\x01", to))
        await expect("unknown_sender", lambda: other.send(other.es(t0, 0, 0), to, t0))
        await expect("unknown_sender", lambda: other.announce(to, t0))
        await expect("address_mismatch", lambda: other.send(auv.es(t0 + 0.2, 100, 50), to,
                                                            t0 + 0.2, src=AUV_ID))  # fmt: skip
        await expect("not_for_us", lambda: other.send(other.es(t0 + 0.2, 100, 50), to,
                                                      t0 + 0.2, dst=0x1234))  # fmt: skip
        await expect("own_id", lambda: other.send(imcpy.Heartbeat(), to, t0, dst=ASV_ID,
                                                  src=DEPLOY_ID))  # fmt: skip
        # DUNE's relays from a vehicle's own address are not rejects: counted apart, silent
        auv.send(auv.es(t0 + 0.2, 100, 50), to, t0 + 0.2, dst=0x1234)
        auv.send(imcpy.Heartbeat(), to, t0, dst=AUV_ID, src=DEPLOY_ID)  # echo of ours
        auv.send(imcpy.Heartbeat(), to, t0, src=0x0999)  # another system's, relayed
        assert await _until(lambda: dict(link.relayed) == {"not_for_us": 1, "echo": 1,
                                                           "third_party": 1}), link.relayed
        nan = auv.es(t0 + 0.3, 100, 50)
        nan.x = float("nan")
        await expect("non_finite", lambda: auv.send(nan, to, t0 + 0.3))
        inf = auv.es(t0 + 0.3, 100, 50)
        inf.u = float("inf")
        await expect("non_finite", lambda: auv.send(inf, to, t0 + 0.3))
        late = auv.es(t0 + 0.3, 100, 50)
        await expect("non_finite", lambda: auv.send(late, to, float("nan")))
        await expect("jump", lambda: auv.send(auv.es(t0 + 0.5, 10_100, 50), to, t0 + 0.5))
        await expect("out_of_area", lambda: auv.send(auv.es(t0 + 0.5, 30_000, 0), to, t0 + 0.5))
        await expect("out_of_order", lambda: auv.send(auv.es(t0 - 1.0, 100, 50), to, t0 - 1.0))
        await expect("out_of_order", lambda: auv.send(auv.es(t0, 100.5, 50), to, t0))
        # the accepted state again (UDP delivers a datagram twice at times): no reject, counted
        auv.send(auv.es(t0, 100, 50), to, t0)
        assert await _until(lambda: dict(link.duplicates) == {"fake-auv": 1})
        await expect("time_jump", lambda: auv.send(auv.es(t0 + 1e3, 100, 50), to, t0 + 1e3))
        bad_lat = auv.es(t0 + 0.6, 100, 50)
        bad_lat.lat = 2.0
        await expect("out_of_range", lambda: auv.send(bad_lat, to, t0 + 0.6))
        # the loop keeps running: the next good state is taken
        auv.send(auv.es(t0 + 0.7, 101.0, 50.0), to, t0 + 0.7)
        assert await _until(lambda: link.accepted["EstimatedState"] == 2)
        assert link.auvs[0].nav.N == __import__("pytest").approx(101.0, abs=1e-3)
        await asyncio.sleep(0.4)  # > log.flush_s: the rejects are on disk before the end
        on_disk = read_jsonl(tmp_path / "log" / "deploy.jsonl", "event")
        reasons = {r["reason"] for r in on_disk if r["event"] == "reject"}
        assert reasons == set(link.rejects), (reasons, dict(link.rejects))
        assert not {"PlanControl", "Reference"} & asv.kinds()
        stop.set()
        summary = await task
        assert summary["rejects"] == dict(link.rejects)
        assert sum(summary["rejects"].values()) == len(expected)
        assert set(summary["rejects"]) == set(expected)

    run(main)


def _random_message(rng: np.random.Generator) -> imcpy.Message:
    kind = rng.integers(7)
    if kind == 0:
        m = imcpy.EstimatedState()
        for f in ("lat", "lon", "x", "y", "z", "psi", "u", "v", "vx", "vy", "depth"):
            setattr(
                m,
                f,
                float(
                    rng.choice(
                        [rng.normal(0, 1e4), np.nan, np.inf, -np.inf, rng.uniform(-4, 4)],
                        p=[0.4, 0.1, 0.1, 0.1, 0.3],
                    )
                ),
            )
    elif kind == 1:
        m = imcpy.Heartbeat()
    elif kind == 2:
        m = announce(rng.choice(["fake-asv", "fake-auv", "x", ""]), imcpy.SystemType.USV,
                     [f"imc+udp://127.0.0.1:{rng.integers(1, 65535)}/"])  # fmt: skip
    elif kind == 3:
        m = imcpy.PlanControl()
        m.type, m.request_id = imcpy.PlanControl.TypeEnum.SUCCESS, int(rng.integers(0, 4))
    elif kind == 4:
        m = imcpy.FollowRefState()
        m.state = imcpy.FollowRefState.StateEnum.TIMEOUT
        m.control_src = DEPLOY_ID
    elif kind == 5:
        m = imcpy.SetThrusterActuation()
        m.value = float(rng.uniform(-1, 1))
    else:
        m = imcpy.Reference()
        m.lat, m.lon = float(rng.uniform(-1, 1)), float(rng.uniform(-3, 3))
    return m


def _fuzz_datagram(rng, from_vehicle: bool, t: float) -> bytes:
    """One datagram. From a vehicle's own socket only input that must fail a check (single
    bit flips or bursts < 16 bits are always caught by the CRC); from the intruder's socket
    anything, including well-formed messages that claim a configured vehicle's id."""
    choice = rng.integers(5)
    msg = _random_message(rng)
    src = int(rng.choice([ASV_ID, AUV_ID, int(rng.integers(0, 0xFFFF))]))
    dst = int(rng.choice([DEPLOY_ID, BROADCAST, int(rng.integers(0, 0xFFFF))]))
    stamp(msg, src, dst, t + float(rng.normal(0, 100)))
    packet = bytearray(msg.serialize())
    if choice == 0:
        return rng.bytes(int(rng.integers(1, 300)))  # (asyncio does not send empty ones)
    if choice == 1:  # bit flip / short burst inside the packet
        i = int(rng.integers(0, len(packet)))
        packet[i] ^= int(rng.integers(1, 256))
        return bytes(packet)
    if choice == 2:
        return bytes(packet[: int(rng.integers(1, len(packet)))])
    if choice == 3:
        return bytes(packet) + rng.bytes(int(rng.integers(1, 20)))
    if from_vehicle:  # a whole message, but one that is wrong: NaN, out of range, not for us
        es = imcpy.EstimatedState()
        es.lat, es.lon = float(rng.choice([np.nan, 3.0, 0.0])), 0.2
        es.x = float(rng.choice([np.nan, np.inf, 1e9]))
        stamp(es, src, int(rng.choice([DEPLOY_ID, 0x1234])), t)
        return es.serialize()
    return bytes(packet)


def test_fuzz_10000_datagrams(tmp_path):
    """10 000 random datagrams: every one rejected with a reason, or (from a vehicle's own
    address only) counted as a relay or as a message the deploy does not use (those are
    checked on their header alone); nothing accepted but Heartbeats, nothing sent to the ASV
    but Heartbeats and Announces, the loop alive at the end; then 1000 from the intruder
    alone are all rejected."""
    n = 10_000
    rng = np.random.default_rng(12345)

    async def main():
        dep, stop, task = await _start(_cfg(tmp_path), tmp_path)
        to = dep.link.endpoint.address
        asv = await Fake("fake-asv", ASV_ID, imcpy.SystemType.USV).open()
        auv = await Fake("fake-auv", AUV_ID).open()
        intruder = await Fake("intruder", 0x7777).open()
        for v in (asv, auv):
            v.announce(to, dep.clock.now())
        assert await _until(lambda: dep.link.auvs[0].id == AUV_ID and dep.link.asv.addresses)
        link, sent = dep.link, 0

        def handled():
            return (sum(link.rejects.values()) + sum(link.relayed.values())
                    + sum(link.ignored.values()))  # fmt: skip

        for batch in range(n // 50):
            for v in (asv, auv):  # stay fresh (an address can only be re-bound when stale)
                v.send(imcpy.Heartbeat(), to, dep.clock.now(), dst=DEPLOY_ID)
            for _ in range(50):
                sender = [asv, auv, intruder][int(rng.integers(3))]
                data = _fuzz_datagram(rng, sender is not intruder, dep.clock.now())
                sender.send_raw(data, to)
                sent += 1
            ok = await _until(lambda n=sent: handled() == n)
            assert ok, f"batch {batch}: {handled()} handled of {sent}: {dict(link.rejects)} " \
                f"{dict(link.accepted)} accepted, {dict(link.ignored)} ignored"  # fmt: skip
        assert sent == n
        assert set(link.accepted) == {"Announce", "Heartbeat"}, link.accepted
        assert link.accepted["Announce"] == 2
        before = sum(link.rejects.values())
        for i in range(1000):
            intruder.send_raw(_fuzz_datagram(rng, False, dep.clock.now()), to)
            if i % 50 == 49:
                assert await _until(lambda b=before + i + 1: sum(link.rejects.values()) == b)
        assert set(link.accepted) == {"Announce", "Heartbeat"}, link.accepted
        assert dep.phase == WAITING and dep.steps == 0
        assert not {"PlanControl", "Reference"} & asv.kinds(), asv.kinds()
        assert link.accepted["EstimatedState"] == 0
        t = dep.clock.now()
        auv.send(auv.es(t, 10.0, 20.0), to, t)  # still alive and listening
        assert await _until(lambda: link.accepted["EstimatedState"] == 1)
        stop.set()
        summary = await task
        print("fuzz rejects:", summary["rejects"], "relayed", summary["relayed"], "ignored",
              summary["ignored"])  # fmt: skip
        assert handled() == n + 1000 and sum(summary["rejects"].values()) > 0.8 * n
        assert len(summary["rejects"]) >= 8
        lines = [r for r in read_jsonl(tmp_path / "log" / "deploy.jsonl", "event")
                 if r["event"] == "reject"]  # fmt: skip
        assert set(r["reason"] for r in lines) == set(summary["rejects"])

    run(main)


@given(st.binary(max_size=400))
@settings(max_examples=3000, deadline=None)
def test_decode_never_raises_anything_else(data):
    try:
        msg, raw = decode(data)
    except BadInput as bad:
        assert bad.reason in {"truncated", "bad_sync", "trailing_bytes", "bad_crc", "malformed"}
    else:
        assert isinstance(msg, imcpy.Message) and raw == data


@given(st.integers(0, 55), st.integers(1, 255), st.integers(0, 5))
@settings(max_examples=1000, deadline=None)
def test_decode_catches_corruption(i, mask, cut):
    es = imcpy.EstimatedState()
    stamp(es, AUV_ID, BROADCAST, 1.7e9)
    packet = bytearray(es.serialize())
    i = i % len(packet)
    packet[i] ^= mask
    try:
        decode(bytes(packet[: len(packet) - cut]))
        raise AssertionError("a corrupted packet was decoded")
    except BadInput as bad:
        assert bad.reason in {"truncated", "bad_sync", "trailing_bytes", "bad_crc"}


def test_only_configured_vehicles_drive_the_controller(tmp_path):
    """An unconfigured AUV sending valid states is rejected and never reaches the
    Observation; with --dry-run the decisions are logged and nothing is commanded."""

    async def main():
        cfg = _cfg(tmp_path, speedup=10.0)
        dep, stop, task = await _start(cfg, tmp_path, dry_run=True)
        to = dep.link.endpoint.address
        asv = await Fake("fake-asv", ASV_ID, imcpy.SystemType.USV).open()
        auv = await Fake("fake-auv", AUV_ID).open()
        intruder = await Fake("intruder", 0x2899).open()
        for v in (asv, auv, intruder):
            v.announce(to, dep.clock.now())
        for i in range(40):
            t = dep.clock.now()
            auv.send(auv.es(t, 200.0 + i, 0.0), to, t)
            intruder.send(intruder.es(t, 5.0, 5.0), to, t)
            th = imcpy.SetThrusterActuation()
            th.id, th.value = 0, 0.0
            asv.send(th, to, t)
            asv.send(asv.es(t, 0.0, 0.0, psi=0.3), to, t)
            await asyncio.sleep(0.05)  # 0.5 s of the deploy clock
        stop.set()
        summary = await task
        steps = read_jsonl(tmp_path / "log" / "deploy.jsonl", "step")
        assert len(steps) >= 10
        for s in steps:
            assert len(s["obs"]["auvs"]) == 1
            assert s["obs"]["auvs"][0]["N"] > 199.9  # the configured AUV, not the intruder
            assert s["sent"] is False
        assert steps[-1]["cmd"]["mode"] == "transit"  # 200 m+ away: beyond r_outer -> track
        assert summary["rejects"]["unknown_sender"] >= 40
        assert summary["sent"].get("Reference", 0) == 0
        assert summary["sent"].get("PlanControl", 0) == 0
        assert not {"PlanControl", "Reference"} & asv.kinds()
        assert "Heartbeat" in asv.kinds()

    run(main)


def test_header_layout_matches_imcpy():
    """The framing check reads imcpy's header: sync, id, size (guards a codec change)."""
    hb = imcpy.Heartbeat()
    stamp(hb, 1, 2, 3.0)
    sync, mgid, size = struct.unpack_from("<HHH", hb.serialize())
    assert (sync, mgid, size) == (imcpy.constants.SYNC, hb.msg_id, 0)


def test_discovery_socket_learns_a_name_only_vehicle(tmp_path):
    """As with DUNE: the vehicle announces on the discovery port (here a free one on
    127.0.0.1), from a socket that is not its data socket; the link learns the data address
    from the imc+udp service and then takes the vehicle's states from there."""
    import dataclasses
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:  # a free port (0 is no
        sock.bind(("127.0.0.1", 0))  # discovery port: refused at load)
        free = sock.getsockname()[1]
    cfg = _cfg(tmp_path)
    cfg = dataclasses.replace(cfg, link=dataclasses.replace(cfg.link, discovery_ports=(free,)))

    async def main():
        dep, stop, task = await _start(cfg, tmp_path)
        link = dep.link
        assert await _until(lambda: link.discovery)
        disc = link.discovery[0].address
        assert disc[0] == "127.0.0.1" and disc != link.endpoint.address
        auv = await Fake("fake-auv", AUV_ID).open()  # its data socket
        announcer = await Fake("fake-auv", AUV_ID).open()  # DUNE's Announce task socket
        host, port = auv.ep.address
        announcer.send(announce("fake-auv", imcpy.SystemType.UUV, [f"imc+udp://{host}:{port}/"]),
                       disc, dep.clock.now())  # fmt: skip
        assert await _until(lambda: link.auvs[0].addresses == {(host, port)})
        t = dep.clock.now()
        auv.send(auv.es(t, 10.0, 20.0), link.endpoint.address, t)
        assert await _until(lambda: link.accepted["EstimatedState"] == 1)
        assert dict(link.rejects) == {}
        stop.set()
        await task
        events = [r["event"] for r in read_jsonl(tmp_path / "log" / "deploy.jsonl", "event")]
        assert "discovery" in events and "discovered" in events

    run(main)
