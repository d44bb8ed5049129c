"""The IMC link: discovery, contact keeping and input checking for the configured vehicles.

:class:`ImcLink` owns the one socket (UDP bound to ``link.bind``:``link.port``; or a TCP
stream per vehicle to DUNE's backseat port), announces us (Announce every
``announce_period``, to ``announce_to`` and to every vehicle whose address it knows), keeps
us an active contact of every vehicle (Heartbeat every ``heartbeat_period``) and runs every
incoming datagram through the checks below. A datagram that fails one is dropped, counted
under its reason in :attr:`ImcLink.rejects` and reported through ``on_event`` (rate-limited
per reason); the loop carries on.

Checks, in order (reason names in brackets):

1. framing from the header [``truncated``, ``bad_sync``, ``trailing_bytes``]. Only the
   messages the deploy uses (:data:`USED`) are decoded by imcpy [``bad_crc``,
   ``malformed``]; the others (DUNE's bus traffic, 97 % of what a vehicle streams) go
   through checks 2-4 on their header alone and are counted in ``ignored`` by name;
2. relays, silent (counted in ``relayed``, not rejects): DUNE forwards every message of its
   ``Transports`` list on its bus to every active node, whatever its ``dst``, our own
   Heartbeats and PlanControls included. From a configured vehicle's address, a message with
   our own id as ``src`` is an ``echo``, one addressed to another system ``not_for_us``, one
   from a system other than that vehicle ``third_party``. From any other address these are
   rejects [``own_id``, ``not_for_us``];
3. sender is a configured vehicle: by IMC id, or by system name through its Announce
   [``unknown_sender``, ``id_mismatch``]; Announces of other systems are counted too;
4. the datagram comes from the vehicle's address (static in the config, or the ``imc+udp``
   service of its Announce) [``not_announced``, ``address_mismatch``]. DUNE writes its
   Announce from its own socket (an ephemeral port), so an Announce is accepted from any
   port of a host its ``imc+udp`` services name (of the configured address's host); one
   without an ``imc+udp`` service (DUNE's first Announce at start-up, or the multicast copy
   on a host with loopback only) teaches nothing and is counted in ``ignored``. A vehicle
   silent for longer than its stale limit may re-announce a new address (a DUNE restart);
5. no NaN/inf in any float field [``non_finite``];
6. EstimatedState only: :mod:`mpcasv.io.statecheck` [``out_of_range``, ``out_of_area``,
   ``out_of_order``, ``time_jump``, ``jump``], with recovery from a vehicle clock step
   (event ``clock_step`` with the offset). An exact copy of the vehicle's last accepted
   state (UDP delivers a datagram twice at times) is no reject: dropped silently and counted
   in ``duplicates`` by vehicle.

Announces are heard on the data socket and, when a vehicle has no configured ``address``,
on DUNE's discovery ports (``link.discovery_ports``, multicast group
``link.discovery_group``): DUNE never announces to a data port.

Accepted EstimatedStates go to ``on_state(vehicle, NavState, recv_time)``; other accepted
messages to ``on_message(vehicle, msg, recv_time)``.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections import Counter
from collections.abc import Callable

import imcpy

from mpcasv.io.config import DeployConfig, parse_address
from mpcasv.io.geo import Origin
from mpcasv.io.imc import (
    BROADCAST,
    BadInput,
    announce,
    decode,
    header,
    non_finite_fields,
    stamp,
)
from mpcasv.io.logs import LsfWriter
from mpcasv.io.netcheck import announced_hosts, is_wildcard
from mpcasv.io.peers import Peer, PeerDirectory
from mpcasv.io.statecheck import Duplicate, check_state
from mpcasv.io.transport import Clock, TcpStream, UdpEndpoint

__all__ = ["USED", "ImcLink", "Peer"]

Addr = tuple[str, int]
_ACCEPTED = {
    "asv": {"EstimatedState", "Heartbeat", "PlanControl", "PlanControlState", "FollowRefState",
            "SetThrusterActuation", "SetServoPosition", "UsblFixExtended"},
    "auv": {"EstimatedState", "Heartbeat"},
}  # fmt: skip
#: IMC message ids the deploy decodes (imcpy's ids); every other id is handled on its header.
USED = {imcpy.Factory.id_from_abbrev(n): n for n in
        set().union(*_ACCEPTED.values()) | {"Announce"}}  # fmt: skip


class ImcLink(PeerDirectory):
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
                p.hosts.add(p.spec.address.rpartition(":")[0])
                p.static = True
            self.peers.append(p)
        self.asv = next(p for p in self.peers if p.role == "asv")
        self.auvs = [p for p in self.peers if p.role == "auv"]
        self.rejects: Counter[str] = Counter()
        self.accepted: Counter[str] = Counter()
        self.ignored: Counter[str] = Counter()
        self.relayed: Counter[str] = Counter()
        self.sent: Counter[str] = Counter()
        #: exact copies of a vehicle's last accepted EstimatedState, by vehicle: dropped
        #: silently (no reject, no event; statecheck.Duplicate)
        self.duplicates: Counter[str] = Counter()
        #: systems that announced themselves and are no configured vehicle: name -> IMC id
        #: (at most peers.MAX_STRANGERS; for the run's "no decision" line: a misspelt name)
        self.strangers: dict[str, int] = {}
        self.datagrams = 0  # received, all sockets
        #: TCP: the last failed connection, ``(vehicle label, error)``; None: none failed
        self.tcp_error: tuple[str, str] | None = None
        self._names: dict[int, str] = {}  # message id -> name (imcpy.Factory), memoised
        self._reject_window: dict[str, tuple[float, int]] = {}
        self.endpoint: UdpEndpoint | None = None
        #: the local addresses our Announce names (UDP; set by :meth:`start`)
        self.hosts: list[str] = []
        self.discovery: list[UdpEndpoint] = []
        self._tasks: list[asyncio.Task] = []

    # --- life cycle ------------------------------------------------------------------------
    async def start(self) -> None:
        """Bind (UDP) or connect (TCP) and start announcing and heart-beating. If it fails
        (or is cancelled) part way, whatever it had opened is closed (:meth:`close`) before
        the exception goes on: a failed start leaves no socket behind."""
        try:
            await self._start()
        except BaseException:
            self.close()
            raise

    async def _start(self) -> None:
        link = self.cfg.link
        if link.transport == "udp":
            # bound to 0.0.0.0, the addresses the vehicles see us from (DUNE streams only to
            # an imc+udp address of our Announce that our datagrams come from): before binding
            self.hosts = announced_hosts(link.bind, [parse_address(v.address) for v in
                                                     self.cfg.vehicle if v.address],
                                         "link.bind")  # fmt: skip
            self.endpoint = await UdpEndpoint.open(link.bind, link.port, self.handle_datagram)
            if not is_wildcard(link.bind):
                self.endpoint.multicast_from(link.bind)
            self.event("bound", address=f"{self.endpoint.address[0]}:{self.endpoint.address[1]}",
                       services=self.services)  # fmt: skip
            if any(not p.static for p in self.peers):
                await self._open_discovery()
        else:
            for p in self.peers:
                self._tasks.append(asyncio.create_task(self._tcp_keep(p)))
        self._tasks.append(asyncio.create_task(self._every(link.announce_period, self.announce)))
        self._tasks.append(asyncio.create_task(self._every(link.heartbeat_period, self.heartbeat)))

    async def stop(self) -> None:
        """Stop the Announce/Heartbeat (and TCP) tasks, wait for them to end, then
        :meth:`close`."""
        for t in self._tasks:
            t.cancel()
        for t in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await t
        self.close()

    def close(self) -> None:
        """Cancel the tasks (without waiting for them: callable outside the event loop, or
        while it is being torn down) and close every socket and TCP stream. Safe to call
        repeatedly."""
        for t in self._tasks:
            if not t.done():  # (one ended with its event loop needs nothing)
                t.cancel()
        self._tasks.clear()
        for p in self.peers:
            if p.stream is not None:
                p.stream.close()
        if self.endpoint is not None:
            self.endpoint.close()
        for ep in self.discovery:
            ep.close()
        self.discovery.clear()

    def stop_receiving(self) -> None:
        """Close the discovery sockets and stop the Announce/Heartbeat tasks (shutdown: the
        data socket stays open for the answer to MANDONE)."""
        for t in self._tasks:
            t.cancel()
        for ep in self.discovery:
            ep.close()
        self.discovery.clear()

    async def _open_discovery(self) -> None:
        """Listen on DUNE's discovery ports for vehicles configured without an address."""
        link = self.cfg.link
        host = link.discovery_host
        iface = link.bind if host == "0.0.0.0" else host
        bound, busy = [], []
        for port in link.discovery_ports:
            try:
                self.discovery.append(await UdpEndpoint.open_discovery(
                    host, port, link.discovery_group, iface, self.handle_datagram))  # fmt: skip
                bound.append(port)
            except OSError as exc:
                busy.append(f"{port}: {exc.strerror or exc}")
        self.event("discovery", host=host, group=link.discovery_group, ports=bound, busy=busy)
        if not bound:
            names = [p.label for p in self.peers if not p.static]
            self.event("discovery_unavailable", vehicles=names,
                       note="no discovery port: these vehicles are learnt only from an "
                       "Announce sent to our data port, which DUNE never does")  # fmt: skip

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
                self.tcp_error = (p.label, str(exc))
                self.event("tcp_connect_failed", vehicle=p.label, error=str(exc))
            p.stream = None
            await self.clock.sleep(2.0)

    # --- output ----------------------------------------------------------------------------
    @property
    def services(self) -> list[str]:
        """Our Announce's ``imc+udp`` services: the data port at each of :attr:`hosts` (the
        bound address; bound to 0.0.0.0, the addresses the vehicles see us from:
        :func:`~mpcasv.io.netcheck.announced_hosts`). DUNE splits them at ';' and keeps one
        per address (``Transports/UDP/Node.hpp``)."""
        if self.endpoint is None:
            return []
        port = self.endpoint.address[1]
        return [f"imc+udp://{h}:{port}/" for h in self.hosts]

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
    def drain(self) -> int:
        """Read every datagram waiting in the data socket now (:meth:`UdpEndpoint.drain`);
        return how many. TCP streams and discovery sockets are left to the event loop."""
        return self.endpoint.drain() if self.endpoint is not None else 0

    def handle_datagram(self, data: bytes, addr: Addr) -> None:
        """Entry point of every UDP datagram (never raises)."""
        self.datagrams += 1
        try:
            mgid, src, dst = header(data)
        except BadInput as bad:
            self.reject(bad.reason, bad.detail, addr=addr, size=len(data),
                        head=bytes(data[:24]).hex())  # fmt: skip
            return
        if mgid not in USED:
            name = self._name(mgid)
            if name is not None:
                self._unused(data, name, src, dst, addr)
                return
        try:
            msg, raw = decode(data)
        except BadInput as bad:
            self.reject(bad.reason, bad.detail, addr=addr, size=len(data),
                        head=bytes(data[:24]).hex())  # fmt: skip
            return
        self.handle_message(msg, raw, addr, None)

    def _name(self, mgid: int) -> str | None:
        if mgid not in self._names:
            try:
                self._names[mgid] = imcpy.Factory.abbrev_from_id(mgid)
            except RuntimeError:  # unknown id: imcpy's decode names it (malformed)
                return None
        return self._names[mgid]

    def _unused(self, data: bytes, name: str, src: int, dst: int, addr: Addr) -> None:
        """A message the deploy does not use: header checks 2-4, then counted in ``ignored``
        (and logged with ``log.lsf = "all"``)."""
        if self.lsf is not None and self.cfg.log.lsf == "all":
            self.lsf.write(data)
        try:
            if self._route(name, src, dst, addr, None) is not None:
                self.ignored[name] += 1
        except BadInput as bad:
            self.reject(bad.reason, bad.detail, addr=addr, src=src, msg=name)

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
                wd = self.cfg.watchdog
                vmax = wd.asv_speed_max if p.role == "asv" else wd.auv_speed_max
                nav, step = check_state(msg, p.track, now, self.origin, vmax, wd, raw)
                if step is not None:
                    self.event("clock_step", vehicle=p.label, offset_s=step.offset,
                               states=step.states, t_old=step.t_old, t_new=step.t_new)  # fmt: skip
            p.last_heard = now
            self.accepted[name] += 1
            if name == "EstimatedState":
                self.on_state(p, p.nav, now)
            elif name != "Announce":
                self.on_message(p, msg, now)
        except Duplicate:  # UDP delivered it twice: nothing wrong, nothing new
            self.duplicates[p.label] += 1
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
        p = self._route(name, msg.src, msg.dst, addr, stream_peer)
        if p is None:
            return None
        if name not in _ACCEPTED[p.role]:
            self.ignored[name] += 1
            return None
        bad = non_finite_fields(msg)
        if bad:
            raise BadInput("non_finite", ",".join(bad))
        return p

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
            "ignored": dict(self.ignored), "relayed": dict(self.relayed),
            "sent": dict(self.sent), "duplicates": dict(self.duplicates),
            "datagrams": self.datagrams,
            "send_errors": self.endpoint.send_errors if self.endpoint else 0,
        }  # fmt: skip
