"""The IMC link: discovery, contact keeping and input checking for the configured vehicles.

:class:`ImcLink` owns the one socket (UDP bound to ``link.bind``:``link.port``; or a TCP
stream per vehicle to DUNE's backseat port), announces us (Announce every
``announce_period``, to ``announce_to`` and to every vehicle whose address it knows), keeps
us an active contact of every vehicle (Heartbeat every ``heartbeat_period``) and runs every
incoming datagram through the checks below. A datagram that fails one is dropped, counted
under its reason in :attr:`ImcLink.rejects` and reported through ``on_event`` (rate-limited
per reason); the loop carries on.

Checks, in order (reason names in brackets):

1. framing and decoding by imcpy [``truncated``, ``bad_sync``, ``trailing_bytes``,
   ``bad_crc``, ``malformed``];
2. addressed to us or broadcast (Announces: any destination, DUNE sends them with 0)
   [``not_for_us``];
3. sender is a configured vehicle: by IMC id, or by system name through its Announce
   [``unknown_sender``, ``id_mismatch``]; Announces of other systems are counted too;
4. the datagram comes from the vehicle's address (static in the config, or its Announce's
   ``imc+udp`` services) [``not_announced``, ``address_mismatch``]; a vehicle silent for
   longer than its stale limit may re-announce from a new address (a DUNE restart);
5. no NaN/inf in any float field [``non_finite``];
6. EstimatedState only: lat/lon in range [``out_of_range``], within ``max_distance_m`` of the
   origin [``out_of_area``], newer than the last accepted one [``out_of_order``], not ahead
   of it by more than the arrival clock allows [``time_jump``], and not further from it
   than the vehicle's top speed allows [``jump``].

Accepted EstimatedStates go to ``on_state(vehicle, NavState, recv_time)``; other accepted
messages to ``on_message(vehicle, msg, recv_time)``.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import imcpy

from mpcasv.io.config import DeployConfig, Vehicle, parse_address
from mpcasv.io.geo import Origin
from mpcasv.io.imc import (
    BROADCAST,
    BadInput,
    NavState,
    announce,
    decode,
    nav_state,
    non_finite_fields,
    stamp,
    udp_services,
)
from mpcasv.io.logs import LsfWriter
from mpcasv.io.transport import Clock, TcpStream, UdpEndpoint

__all__ = ["ImcLink", "Peer"]

Addr = tuple[str, int]
_ACCEPTED = {
    "asv": {"EstimatedState", "Heartbeat", "PlanControl", "FollowRefState",
            "SetThrusterActuation"},
    "auv": {"EstimatedState", "Heartbeat"},
}  # fmt: skip


@dataclass
class Peer:
    """A configured vehicle as the link knows it at run time."""

    spec: Vehicle
    index: int  # AUV index k (file order), -1 for the ASV
    id: int | None = None
    name: str | None = None
    addresses: set[Addr] = field(default_factory=set)
    static: bool = False  # address from the config, not learnt
    last_heard: float = -math.inf  # deploy clock of the last accepted message
    nav: NavState | None = None  # last accepted state
    nav_recv: float = -math.inf  # deploy clock when it arrived
    stream: TcpStream | None = None
    announces: int = 0

    @property
    def role(self) -> str:
        return self.spec.role

    @property
    def label(self) -> str:
        return self.name or self.spec.label


class ImcLink:
    """See the module docstring.

    Parameters
    ----------
    cfg : DeployConfig
    clock : Clock
        The deploy clock (scaled in rehearsals).
    lsf : LsfWriter, optional
        Every packet in and out is appended as it happens.
    on_state, on_message, on_event : callable, optional
        Callbacks for accepted states, other accepted messages and reports.
    """

    def __init__(self, cfg: DeployConfig, clock: Clock, lsf: LsfWriter | None = None,
                 on_state: Callable | None = None, on_message: Callable | None = None,
                 on_event: Callable[[dict], None] | None = None) -> None:  # fmt: skip
        self.cfg, self.clock, self.lsf = cfg, clock, lsf
        o = cfg.origin
        self.origin = Origin.from_degrees(o.lat_deg, o.lon_deg, o.height)
        self.on_state = on_state or (lambda *a: None)
        self.on_message = on_message or (lambda *a: None)
        self.on_event = on_event or (lambda e: None)
        self.id = cfg.identity.id
        self.peers: list[Peer] = []
        k = 0
        for v in cfg.vehicle:
            p = Peer(v, -1 if v.role == "asv" else k, v.id, v.name)
            k += v.role == "auv"
            if v.address:
                p.addresses.add(parse_address(v.address))
                p.static = True
            self.peers.append(p)
        self.asv = next(p for p in self.peers if p.role == "asv")
        self.auvs = [p for p in self.peers if p.role == "auv"]
        self.rejects: Counter[str] = Counter()
        self.accepted: Counter[str] = Counter()
        self.ignored: Counter[str] = Counter()
        self.sent: Counter[str] = Counter()
        self._reject_window: dict[str, tuple[float, int]] = {}
        self.endpoint: UdpEndpoint | None = None
        self._tasks: list[asyncio.Task] = []

    # --- life cycle ------------------------------------------------------------------------
    async def start(self) -> None:
        """Bind (UDP) or connect (TCP) and start announcing and heart-beating."""
        link = self.cfg.link
        if link.transport == "udp":
            self.endpoint = await UdpEndpoint.open(link.bind, link.port, self.handle_datagram)
            self.event("bound", address=f"{self.endpoint.address[0]}:{self.endpoint.address[1]}")
        else:
            for p in self.peers:
                self._tasks.append(asyncio.create_task(self._tcp_keep(p)))
        self._tasks.append(asyncio.create_task(self._every(link.announce_period, self.announce)))
        self._tasks.append(asyncio.create_task(self._every(link.heartbeat_period, self.heartbeat)))

    async def stop(self) -> None:
        for t in self._tasks:
            t.cancel()
        for t in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await t
        self._tasks.clear()
        for p in self.peers:
            if p.stream is not None:
                p.stream.close()
        if self.endpoint is not None:
            self.endpoint.close()

    async def _every(self, period: float, fn: Callable[[], None]) -> None:
        while True:
            fn()
            await self.clock.sleep(period)

    async def _tcp_keep(self, p: Peer) -> None:
        """Keep a backseat connection to ``p`` open (reconnect every 2 s of the clock)."""
        host, port = parse_address(p.spec.tcp)
        while True:
            try:
                p.stream = await TcpStream.connect(
                    host, port, lambda m, raw, p=p: self.handle_message(m, raw, None, p),
                    local_host=self.cfg.link.bind,
                )  # fmt: skip
                self.event("tcp_connected", vehicle=p.label, address=p.spec.tcp)
                await p.stream.run()
                self.event("tcp_closed", vehicle=p.label)
            except OSError as exc:
                self.event("tcp_connect_failed", vehicle=p.label, error=str(exc))
            p.stream = None
            await self.clock.sleep(2.0)

    # --- output ----------------------------------------------------------------------------
    @property
    def services(self) -> list[str]:
        if self.endpoint is None:
            return []
        host, port = self.endpoint.address
        return [f"imc+udp://{host}:{port}/"]

    def announce(self) -> None:
        """Announce us to the discovery addresses and to every vehicle with an address."""
        o = self.origin
        msg = announce(self.cfg.identity.name, imcpy.SystemType.CCU, self.services, o.lat, o.lon,
                       o.height)  # fmt: skip
        stamp(msg, self.id, BROADCAST, self.clock.now())
        data = msg.serialize()
        targets = {parse_address(a) for a in self.cfg.link.announce_to}
        for p in self.peers:
            targets |= p.addresses
        if self.endpoint is not None:
            for addr in sorted(targets):
                self._send_raw(data, addr, None)
            self._log_out(data, "Announce")

    def heartbeat(self) -> None:
        for p in self.peers:
            if p.id is not None and (p.addresses or p.stream is not None):
                self.send(p, imcpy.Heartbeat())

    def send(self, p: Peer, msg: imcpy.Message) -> bool:
        """Stamp (src = us, dst = the vehicle, now) and send ``msg`` to vehicle ``p``."""
        if p.id is None:
            return False
        stamp(msg, self.id, p.id, self.clock.now())
        data = msg.serialize()
        ok = False
        if p.stream is not None:
            ok = p.stream.send(data)
        else:
            for addr in sorted(p.addresses):
                ok = self._send_raw(data, addr, p) or ok
        if ok:
            self._log_out(data, type(msg).__name__)
        return ok

    def _send_raw(self, data: bytes, addr: Addr, p: Peer | None) -> bool:
        return self.endpoint is not None and self.endpoint.sendto(data, addr)

    def _log_out(self, data: bytes, name: str) -> None:
        self.sent[name] += 1
        if self.lsf is not None:
            self.lsf.write(data)

    # --- input -----------------------------------------------------------------------------
    def handle_datagram(self, data: bytes, addr: Addr) -> None:
        """Entry point of every UDP datagram (never raises)."""
        try:
            msg, raw = decode(data)
        except BadInput as bad:
            self.reject(bad.reason, bad.detail, addr=addr, size=len(data),
                        head=bytes(data[:24]).hex())  # fmt: skip
            return
        self.handle_message(msg, raw, addr, None)

    def handle_message(self, msg: imcpy.Message, raw: bytes, addr: Addr | None,
                       stream_peer: Peer | None) -> None:  # fmt: skip
        """Checks 2-6 of the module docstring on a decoded message (never raises)."""
        name = type(msg).__name__
        try:
            if self.lsf is not None:
                self.lsf.write(raw)
            p = self._check(msg, name, addr, stream_peer)
            if p is None:
                return
            now = self.clock.now()
            if name == "EstimatedState":
                nav = self._check_state(msg, p, now)
                p.nav, p.nav_recv = nav, now
            p.last_heard = now
            self.accepted[name] += 1
            if name == "EstimatedState":
                self.on_state(p, p.nav, now)
            elif name != "Announce":
                self.on_message(p, msg, now)
        except BadInput as bad:
            self.reject(bad.reason, bad.detail, addr=addr, src=msg.src, msg=name)
        except Exception as exc:  # a bug must not stop the loop: counted and reported
            self.reject("internal_error", f"{type(exc).__name__}: {exc}", addr=addr, msg=name)

    def _check(self, msg, name: str, addr: Addr | None, stream_peer: Peer | None) -> Peer | None:
        if name == "Announce":  # DUNE multicasts its Announce with dst 0: any dst is fine
            bad = non_finite_fields(msg)
            if bad:
                raise BadInput("non_finite", ",".join(bad))
            return self._announce_in(msg, addr, stream_peer)
        if msg.dst not in (self.id, BROADCAST):
            raise BadInput("not_for_us", f"dst 0x{msg.dst:04X}")
        p = stream_peer or self._peer_by_id(msg.src)
        if p is None:
            raise BadInput("unknown_sender", f"src 0x{msg.src:04X}")
        if stream_peer is not None and p.id is not None and msg.src != p.id:
            raise BadInput("id_mismatch", f"src 0x{msg.src:04X} on {p.label}'s stream")
        if addr is not None:
            if not p.addresses:
                raise BadInput("not_announced", f"{p.label} has not announced itself")
            if addr not in p.addresses:
                raise BadInput("address_mismatch", f"{p.label} from {addr[0]}:{addr[1]}")
        if name not in _ACCEPTED[p.role]:
            self.ignored[name] += 1
            return None
        bad = non_finite_fields(msg)
        if bad:
            raise BadInput("non_finite", ",".join(bad))
        return p

    def _peer_by_id(self, src: int) -> Peer | None:
        return next((p for p in self.peers if p.id == src), None)

    def _announce_in(self, msg: imcpy.Announce, addr: Addr | None, stream_peer) -> Peer | None:
        p = stream_peer or next((q for q in self.peers if q.spec.name == msg.sys_name), None)
        if p is None:
            p = self._peer_by_id(msg.src)
            if p is None or p.spec.name:  # unknown id, or a configured name that differs
                raise BadInput("unknown_sender", f"Announce of {msg.sys_name!r} 0x{msg.src:04X}")
        if p.spec.id is not None and msg.src != p.spec.id:
            raise BadInput("id_mismatch", f"{msg.sys_name!r} announces 0x{msg.src:04X}")
        if p.id is not None and msg.src != p.id and self._fresh(p):
            raise BadInput("id_mismatch", f"{p.label} is 0x{p.id:04X}, not 0x{msg.src:04X}")
        services = set(udp_services(msg.services))
        if addr is not None and not p.static:
            if p.addresses and addr not in p.addresses and self._fresh(p):
                raise BadInput("address_mismatch", f"{p.label} re-announced from {addr}")
            if addr not in services:  # DUNE sends from its service port
                raise BadInput("address_mismatch", f"{p.label} from {addr}, services {services}")
            if services != p.addresses:
                self.event("discovered", vehicle=p.label, id=msg.src,
                           addresses=[f"{h}:{q}" for h, q in sorted(services)])  # fmt: skip
            p.addresses = services
        elif addr is not None and addr not in p.addresses:
            raise BadInput("address_mismatch", f"{p.label} announced from {addr}")
        if p.id != msg.src:
            p.id = msg.src
        p.name = msg.sys_name
        p.announces += 1
        return p

    def _fresh(self, p: Peer) -> bool:
        limit = self.cfg.watchdog.asv_stale_s if p.role == "asv" else self.cfg.watchdog.auv_stale_s
        return self.clock.now() - p.last_heard < limit

    def _check_state(self, es: imcpy.EstimatedState, p: Peer, now: float) -> NavState:
        wd = self.cfg.watchdog
        if abs(es.lat) > math.pi / 2 or abs(es.lon) > math.pi or es.depth > 12000:
            raise BadInput("out_of_range", f"lat {es.lat} lon {es.lon} depth {es.depth}")
        nav = nav_state(es, self.origin)
        if not all(map(math.isfinite, (nav.N, nav.E))):
            raise BadInput("non_finite", "position after conversion")
        if math.hypot(nav.N, nav.E) > wd.max_distance_m:
            raise BadInput("out_of_area", f"{math.hypot(nav.N, nav.E):.0f} m from the origin")
        prev = p.nav
        if prev is not None:
            dt = nav.t - prev.t
            if dt <= 0:
                raise BadInput("out_of_order", f"t {nav.t:.3f} <= last {prev.t:.3f}")
            if dt > (now - p.nav_recv) + wd.clock_slack_s:
                raise BadInput("time_jump", f"+{dt:.1f} s after {now - p.nav_recv:.1f} s")
            vmax = wd.asv_speed_max if p.role == "asv" else wd.auv_speed_max
            dist = math.hypot(nav.N - prev.N, nav.E - prev.E)
            if dist > vmax * dt + wd.jump_margin_m:
                raise BadInput("jump", f"{dist:.0f} m in {dt:.2f} s")
        return nav

    def reject(self, reason: str, detail: str = "", **info) -> None:
        """Count a rejected input and report it (at most ``log.reject_log_per_s`` per reason
        per wall second in detail; the rest are in the counters)."""
        self.rejects[reason] += 1
        wall = time.monotonic()
        t0, n = self._reject_window.get(reason, (wall, 0))
        if wall - t0 >= 1.0:
            t0, n = wall, 0
        self._reject_window[reason] = (t0, n + 1)
        if n < self.cfg.log.reject_log_per_s:
            self.event("reject", reason=reason, detail=detail, count=self.rejects[reason],
                       **{k: (f"{v[0]}:{v[1]}" if k == "addr" and v else v)
                          for k, v in info.items()})  # fmt: skip

    def event(self, name: str, **info) -> None:
        self.on_event({"kind": "event", "event": name, "t": self.clock.now()} | info)

    def counters(self) -> dict:
        return {
            "rejects": dict(self.rejects), "accepted": dict(self.accepted),
            "ignored": dict(self.ignored), "sent": dict(self.sent),
            "send_errors": self.endpoint.send_errors if self.endpoint else 0,
        }  # fmt: skip
