"""Recorded DUNE as a test peer: the UDP datagrams a controller node exchanged with DUNE's
stock Otter ASV and LAUV simulators (LSTS/dune f8080c0, loopback; README in
/work/shared/data/dune-traffic/) go through the link and the deploy with a clock driven by
the capture.

CI uses ``tests/data/dune-traffic-excerpt.jsonl.gz`` (every datagram the deploy decodes,
every Announce, relay and echo, everything sent, 1 in 50 of the rest; built by
``tests/data/make_dune_traffic_excerpt.py``); the full capture (216 527 datagrams) is used
too when it is found (``MPCASV_DUNE_TRAFFIC`` or /work/shared/data/dune-traffic/).
The expected counts are computed from the datagrams' own headers, independently of the link.
"""

from __future__ import annotations

import asyncio
import functools
import gzip
import json
import math
import os
import struct
from pathlib import Path

import imcpy
import pytest

from mpcasv.io.asvwatch import SpeedWatch, Thrusters
from mpcasv.io.config import SpeedSpec, deploy_config_from_dict
from mpcasv.io.deploy import Deploy
from mpcasv.io.imc import udp_services
from mpcasv.io.link import USED, ImcLink
from mpcasv.io.logs import read_jsonl
from mpcasv.io.lsf import read_messages

EXCERPT = Path(__file__).parent / "data" / "dune-traffic-excerpt.jsonl.gz"
FULL = Path(os.environ.get("MPCASV_DUNE_TRAFFIC",
                           "/work/shared/data/dune-traffic/dune-traffic.jsonl.gz"))  # fmt: skip
SOURCES = [pytest.param(EXCERPT, id="excerpt"),
           pytest.param(FULL, id="full", marks=pytest.mark.skipif(
               not FULL.is_file(), reason=f"full capture not at {FULL}"))]  # fmt: skip
US, OTTER, LAUV = 0x4001, 0x0803, 0x00D1
HDR = struct.Struct("<HHHdHBHB")
MANDONE_T = 1795969891.522  # the capture's MANDONE to the otter (README timeline)
STANDBY_T = 1795969856.521  # its first standby Reference (speed 0): no thrust messages after


@functools.cache
def capture(path: Path) -> tuple[tuple, ...]:
    """(t_wall, sent, (ip, port) of the peer, bytes) per datagram, in capture order."""
    out = []
    with gzip.open(path, "rt") as fh:
        for line in fh:
            d = json.loads(line)
            peer = (d["dst_ip"], d["dst_port"]) if d.get("sent") else (d["src_ip"], d["src_port"])
            out.append((d["t_wall"], bool(d.get("sent")), peer, bytes.fromhex(d["hex"])))
    return tuple(out)


class CaptureClock:
    """The deploy clock, set to each datagram's capture time."""

    speedup = 1.0

    def __init__(self, t: float) -> None:
        self.t = t

    def now(self) -> float:
        return self.t

    def wall_seconds(self, s: float) -> float:
        return s


PINNED = [{"role": "asv", "name": "otter", "id": OTTER, "address": "127.0.0.1:6002"},
          {"role": "auv", "name": "lauv-simulator-1", "id": LAUV, "address": "127.0.0.1:6003"}]


def _cfg(tmp_path, vehicles=None, **log):
    return deploy_config_from_dict({
        "identity": {"id": US, "name": "mpcasv-capture"},
        "origin": {"lat_deg": 41.1850, "lon_deg": -8.7062},
        "link": {"bind": "127.0.0.1", "port": 6010, "announce_to": [],
                 "plan_start_timeout": 20.0},
        # names only, as the failing field configuration had them
        "vehicle": vehicles or [{"role": "asv", "name": "otter"},
                                {"role": "auv", "name": "lauv-simulator-1"}],
        "controller": {"name": "hybrid-single", "preset": "paper1-field"},
        "log": {"dir": str(tmp_path / "log")} | log,
    })  # fmt: skip


def _expected(data) -> dict:
    """What the link must make of the received datagrams, from their headers."""
    exp = {"echo": 0, "not_for_us": 0, "own_announce": 0, "es": 0, "no_udp_service": 0,
           "vehicle_ports": set(), "announce_ports": set(), "early": 0}  # fmt: skip
    known: set[tuple[str, int]] = set()  # data addresses named by an Announce so far
    for _, sent, peer, raw in data:
        if sent:
            continue
        _, mgid, _, _, src, _, dst, _ = HDR.unpack_from(raw)
        if mgid == imcpy.Factory.id_from_abbrev("Announce"):
            if src == US:
                exp["own_announce"] += 1
                continue
            a = imcpy.Packet.deserialize(raw)
            if udp_services(a.services):
                exp["announce_ports"].add(peer[1])
                known |= set(udp_services(a.services))
            else:
                exp["no_udp_service"] += 1
            continue
        exp["vehicle_ports"].add(peer)
        if peer not in known:
            exp["early"] += 1
            continue
        if src == US:
            exp["echo"] += 1
        elif dst not in (US, 0xFFFF):
            exp["not_for_us"] += 1
        elif mgid == imcpy.Factory.id_from_abbrev("EstimatedState"):
            exp["es"] += 1
    return exp


@pytest.mark.parametrize("path", SOURCES)
def test_recorded_dune_through_the_link(path):
    """Name-only vehicles discovered from DUNE's Announces (sent from ephemeral ports), every
    relay and echo classified, no reject, every EstimatedState accepted."""
    data = capture(path)
    clock = CaptureClock(data[0][0])
    events = []
    link = ImcLink(_cfg(Path("/nonexistent")), clock, on_event=events.append)
    for t, sent, peer, raw in data:
        if not sent:
            clock.t = t
            link.handle_datagram(raw, peer)
    exp = _expected(data)
    assert dict(link.rejects) == {}
    assert (link.asv.id, link.auvs[0].id) == (OTTER, LAUV)
    assert link.asv.addresses == {("127.0.0.1", 6002)}
    assert link.auvs[0].addresses == {("127.0.0.1", 6003)}
    assert exp["vehicle_ports"] == {("127.0.0.1", 6002), ("127.0.0.1", 6003)}
    found = [e for e in events if e["event"] == "discovered"]
    assert len(found) == 2  # once each: the addresses never change
    ephemeral = {int(e["announced_from"].rsplit(":", 1)[1]) for e in found}
    assert ephemeral <= exp["announce_ports"] and not ephemeral & {6002, 6003}
    # before a vehicle's first Announce with its imc+udp service, what it streams (DUNE
    # starts when it has heard us) is held apart as pre_discovery: relays and states alike
    assert link.relayed["pre_discovery"] == exp["early"] > 0
    assert dict(link.relayed) == {"echo": exp["echo"], "not_for_us": exp["not_for_us"],
                                  "own_announce": exp["own_announce"],
                                  "pre_discovery": exp["early"]}  # fmt: skip
    assert link.accepted["EstimatedState"] == exp["es"]
    received = sum(not d[1] for d in data)
    if path == FULL:  # the README's figures (dune-traffic/README.md, "Counts")
        assert received == 215_556  # 813 EstimatedStates, 10 of them before discovery
        assert exp["es"] + sum(1 for d in data if not d[1] and HDR.unpack_from(d[3])[1]
                               == imcpy.Factory.id_from_abbrev("EstimatedState")
                               and d[2] not in {("127.0.0.1", 6002), ("127.0.0.1", 6003)}
                               ) + 10 == 813  # fmt: skip
        assert link.relayed["own_announce"] == 72
    _all_handled(link, received)


def _all_handled(link, received):
    handled = (sum(link.accepted.values()) + sum(link.ignored.values())
               + sum(link.relayed.values()))  # fmt: skip
    assert handled == received


@pytest.mark.parametrize("path", SOURCES)
def test_recorded_dune_through_the_link_pinned(path):
    """The same with ids and addresses pinned (the advice for untrusted networks): no
    reject, nothing before discovery, every EstimatedState accepted, every relay counted."""
    data = capture(path)
    clock = CaptureClock(data[0][0])
    link = ImcLink(_cfg(Path("/nonexistent"), PINNED), clock)
    for t, sent, peer, raw in data:
        if not sent:
            clock.t = t
            link.handle_datagram(raw, peer)
    es_id = imcpy.Factory.id_from_abbrev("EstimatedState")
    assert dict(link.rejects) == {}
    assert link.accepted["EstimatedState"] == sum(
        1 for d in data if not d[1] and HDR.unpack_from(d[3])[1] == es_id)
    assert "pre_discovery" not in link.relayed
    _all_handled(link, sum(not d[1] for d in data))


def _run_deploy(path, tmp_path, lsf="used"):
    """The deploy driven by the capture: its sends are recorded, not transmitted."""
    data = capture(path)
    dep = Deploy(_cfg(tmp_path, lsf=lsf))
    clock = CaptureClock(data[0][0])
    dep.clock = dep.link.clock = clock
    out = []

    def send_raw(raw, addr, p=None):
        out.append((clock.t, addr, imcpy.Packet.deserialize(raw)))
        return True

    dep.link._send_raw = send_raw
    # the recording's node used request id 1 for its wrong-dst test and 2 for the real START:
    # start counting from there so that DUNE's recorded answers carry our request id
    dep.request_id = 1
    next_watch, mandone_at, done = data[0][0], None, None
    for t, sent, peer, raw in data:
        if sent:
            continue
        clock.t = t
        if mandone_at is None and t >= MANDONE_T:
            mandone_at = t
            assert dep.begin_shutdown()
            n_out_at_mandone = len(out)
        while next_watch <= t and mandone_at is None:
            dep.watch()
            next_watch += 0.25
        dep.link.handle_datagram(raw, peer)
        if done is None and dep.plan_done.is_set():
            done = t
    summary = asyncio.run(dep.finish())
    return dep, out, summary, mandone_at, done, n_out_at_mandone


@pytest.mark.parametrize("path", SOURCES)
def test_recorded_dune_drives_the_deploy(path, tmp_path):
    """FollowReference started and answered as real DUNE answers it; decisions while it runs;
    shutdown: nothing decided or sent after MANDONE, DUNE's "plan completed" heard,
    ``summary`` last; no reject, no stale-thruster alarm before the first thrust message."""
    dep, out, summary, mandone_at, done, n_mandone = _run_deploy(path, tmp_path)
    recs = read_jsonl(tmp_path / "log" / "deploy.jsonl")
    ev = [r for r in recs if r["kind"] == "event"]
    names = [r["event"] for r in ev]
    assert summary["rejects"] == {} and "reject" not in names
    pcs = [(t, a, m) for t, a, m in out if isinstance(m, imcpy.PlanControl)]
    assert len(pcs) == 1  # answered at the first attempt: no retry
    t_pc, addr, pc = pcs[0]
    assert addr == ("127.0.0.1", 6002) and pc.dst == OTTER and pc.src == US
    assert (pc.type, pc.op, pc.request_id) == (imcpy.PlanControl.TypeEnum.REQUEST,
                                               imcpy.PlanControl.OperationEnum.START, 2)
    assert isinstance(pc.arg, imcpy.FollowReference) and pc.arg.control_src == US
    started = [r for r in ev if r["event"] == "plan_started"]
    assert len(started) == 1 and started[0]["info"] == "plan loaded"
    assert started[0]["request_id"] == 2
    # DUNE's echoes of our PlanControl (the wrong-dst one and ours) were not taken as answers
    assert summary["relayed"]["echo"] > 0
    steps = [r for r in recs if r["kind"] == "step"]
    assert steps and all(r["t"] < mandone_at for r in steps)
    refs = [m for t, a, m in out if isinstance(m, imcpy.Reference)]
    assert len(refs) == len(steps) + 2  # one per decision, then standby and MANDONE
    assert refs[-1].flags == int(imcpy.Reference.FlagsBits.MANDONE)
    assert refs[-2].speed.value == 0.0
    assert all(m.dst == OTTER and a == ("127.0.0.1", 6002) for _, a, m in out
               if not isinstance(m, imcpy.Announce))  # fmt: skip
    assert len(out) == n_mandone  # nothing at all (no Heartbeat either) after MANDONE
    assert done is not None and 0 <= done - mandone_at < 0.01  # recorded 2 ms after MANDONE
    assert "plan_completed" in names and summary["plan_completed"]
    assert recs[-1]["kind"] == "summary"
    # thrusters: both of the Otter's read, no stale alarm before the first thrust message
    assert set(steps[-1]["thrusters"]) == {"0", "1"}
    first_thrust = next(t for t, sent, _, raw in capture(path) if not sent
                        and HDR.unpack_from(raw)[1] == imcpy.Factory.id_from_abbrev(
                            "SetThrusterActuation"))  # fmt: skip
    stale = [r["t"] for r in ev if r["event"] == "thruster_stale"]
    # our decisions do not drive the recorded boat: a stale alarm is right only where we
    # command a transit and the recording's own node had put the Otter in standby
    assert all(t > STANDBY_T for t in stale) and first_thrust < STANDBY_T
    during = [r for r in steps if first_thrust + 0.5 < r["clock"] < STANDBY_T]
    assert during and all(r["propeller_source"] == "thruster" for r in during)
    # in the recorded standby (no thrust messages) with our standby commands: assumed, said
    assumed = [r for r in steps if r["clock"] > STANDBY_T + 3.5 and r["cmd"]["mode"] ==
               "standby"]  # fmt: skip
    assert all(r["propeller_source"] == "command" and not r["obs"]["propeller_on"]
               for r in assumed)  # fmt: skip
    if assumed:
        assert "propeller_assumed" in names


@pytest.mark.parametrize("lsf", ["used", "all"])
def test_recorded_dune_lsf_used_or_all(lsf, tmp_path):
    """``log.lsf = "used"`` keeps the decoded packets and ours; "all" also the rest."""
    data = capture(EXCERPT)
    dep, out, summary, *_ = _run_deploy(EXCERPT, tmp_path, lsf=lsf)
    n_recv = sum(not d[1] for d in data)
    used = sum(not d[1] and HDR.unpack_from(d[3])[1] in USED for d in data)
    written = dep.lsf.packets
    if lsf == "used":
        assert written == used + sum(summary["sent"].values())
    else:
        assert written == n_recv + sum(summary["sent"].values())
    hb = read_messages(tmp_path / "log" / "imc.lsf", imcpy.Heartbeat)
    assert len(hb) > 0


def _recorded_otter(data):
    """The otter's (t, sog, u) states and the (t, commanded speed) of every recorded
    Reference to it (MANDONE excluded), on the otter's time base."""
    states, cmds = [], []
    for _t, sent, _peer, raw in data:
        m = imcpy.Packet.deserialize(raw) if (sent or HDR.unpack_from(raw)[1] in USED) else None
        if sent and isinstance(m, imcpy.Reference) and m.dst == OTTER \
                and m.flags & imcpy.Reference.FlagsBits.SPEED:  # fmt: skip
            cmds.append((m.timestamp, m.speed.value))
        elif isinstance(m, imcpy.EstimatedState) and m.src == OTTER:
            states.append((m.timestamp, math.hypot(m.vx, m.vy), m.u))
    return states, cmds


def test_recorded_otter_speed_shortfall():
    """DUNE's Otter asked for 0.5/1.0/2.0/2.0 m/s made 0.69/0.68/0.80/0.88 m/s (README 9):
    the speed watch (default [speed] settings: 25 s from a new speed to a verdict) reports a
    persistent shortfall from leg 2 on, with an achievable speed equal to the mean speed
    through the water over its window, none in leg 1 or standby."""
    states, cmds = _recorded_otter(capture(EXCERPT))
    w = SpeedWatch(SpeedSpec())
    events, j = [], 0
    for t, sog, u in states:
        while j < len(cmds) and cmds[j][0] <= t:
            w.command(cmds[j][0], cmds[j][1])
            j += 1
        ev = w.state(t, sog, u)
        if ev:
            events.append((t, w.commanded, ev))
    short = [(c, e) for _, c, e in events if e["event"] == "speed_shortfall"]
    # legs 3 and 4 are one stretch at 2.0 m/s (only the bearing changes): one verdict
    assert [c for c, _ in short] == [1.0, 2.0], events
    assert not [e for _, _, e in events if e["event"] == "speed_recovered"]
    for c, e in short:
        assert e["stw"] < 0.8 * c and 0.5 < e["achievable"] < 1.0
        assert e["achievable"] == e["stw"]
        print(f"commanded {c} m/s: achieved {e['stw']:.2f} m/s through the water, "
              f"{e['sog']:.2f} m/s over ground")
    assert w.achievable is not None and 0.7 < w.achievable < 1.0


def test_recorded_otter_thrusters():
    """All of the Otter's thrusters read (ids 0 and 1); while transits are commanded they
    are never stale; in the recorded standby DUNE sends none and the propeller is assumed
    off from the command. The actuators (session 41): with the differential vessel every
    moment of its transits has them, the mapping of its two thrusters' last set-points; in
    its standby (loops off, none sent after the final 0.0s) they are zero; with a steerable
    vessel (no steering servo on the Otter) none during the transits."""
    from mpcasv.io.asvwatch import dune_actuators
    from mpcasv.models.params import load_vessel

    otter, gretha = load_vessel("dune-otter"), load_vessel("gretha")
    data = capture(EXCERPT)
    th = Thrusters(3.0, 0.05)
    transit, seen, stale, standby_sources = False, set(), 0, set()
    t_standby = None
    during, standby_act, steerable = [], set(), set()
    for t, sent, _peer, raw in data:
        if not (sent or HDR.unpack_from(raw)[1] in USED):
            continue
        m = imcpy.Packet.deserialize(raw)
        if sent and isinstance(m, imcpy.Reference) and m.dst == OTTER:
            was = transit
            transit = bool(m.flags & imcpy.Reference.FlagsBits.SPEED) and m.speed.value > 0
            if was and not transit and t_standby is None:
                t_standby = t
        elif isinstance(m, imcpy.SetThrusterActuation) and m.src == OTTER:
            th.update(m.id, m.value, t)
            seen.add(m.id)
        on, source, is_stale = th.propeller(t, transit)
        stale += is_stale
        # (the final 0.0s come 1 ms after the standby Reference: at +3.0 s they are 2.999 s
        # old, fresh for a 3-s limit; the excerpt has a message there since session 48)
        if t_standby is not None and t > t_standby + 3.5 and t < MANDONE_T:
            standby_sources.add((on, source))
            standby_act.add(th.actuators(t, otter, transit))
        elif transit and t_standby is None and {0, 1} <= set(th.last):
            a0, a1 = th.last[0][0], th.last[1][0]
            during.append((th.actuators(t, otter, transit), dune_actuators(otter, a0, a1)))
            steerable.add(th.actuators(t, gretha, transit))
    assert seen == {0, 1}
    assert stale == 0
    assert standby_sources == {(False, "command")}
    assert len(during) > 100 and all(a == pytest.approx(b) for a, b in during)
    assert max(abs(a[1]) for a, _ in during) > 0.05  # it did steer
    assert standby_act == {(0.0, 0.0)} and steerable == {None}
