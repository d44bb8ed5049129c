"""The IMC link: discovery, contact keeping and input checking for the configured vehicles.

:class:`ImcLink` owns the one socket (UDP bound to ``link.bind``:``link.port``; or a TCP
stream per vehicle to DUNE's backseat port), announces us (Announce every
``announce_period``, to ``announce_to`` and to every vehicle whose address it knows), keeps
us an active contact of every vehicle (Heartbeat every ``heartbeat_period``) and runs every
incoming datagram through the input checks of :mod:`mpcasv.io.linkinput` (their order and
reasons there; :class:`~mpcasv.io.linkinput.InputChecks` is this class's base). A datagram
that fails one is dropped, counted under its reason in :attr:`ImcLink.rejects` and reported
through ``on_event`` (rate-limited per reason); the loop carries on.

Announces are heard on the data socket and, when a vehicle has no configured ``address``,
on DUNE's discovery ports (``link.discovery_ports``, multicast group
``link.discovery_group``): DUNE never announces to a data port.

Accepted EstimatedStates go to ``on_state(vehicle, NavState, recv_time)``; other accepted
messages to ``on_message(vehicle, msg, recv_time)``.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import Counter
from collections.abc import Callable

import imcpy

from mpcasv.io.config import DeployConfig, parse_address
from mpcasv.io.geo import Origin
from mpcasv.io.imc import (
    BROADCAST,
    announce,
    stamp,
)
from mpcasv.io.linkinput import USED, InputChecks
from mpcasv.io.logs import LsfWriter
from mpcasv.io.netcheck import announced_hosts, is_wildcard
from mpcasv.io.peers import Peer
from mpcasv.io.transport import Clock, TcpStream, UdpEndpoint

__all__ = ["USED", "ImcLink", "Peer"]

Addr = tuple[str, int]


class ImcLink(InputChecks):
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
