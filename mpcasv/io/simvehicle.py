"""One simulated vehicle of ``mpcasv sitl`` as an IMC system, behaving as DUNE's transports do.

It has its own UDP socket (its ``imc+udp`` service) and IMC id, learns other systems from
their Announce (and answers a new one with its own Announce at once), takes datagrams only
from systems it has learnt, from the address their Announce names, and streams only to
systems that sent it a Heartbeat in the last 30 s (and to every TCP backseat client).
As DUNE does (recorded: ../shared/data/dune-traffic/README.md, 1 and 5), its Announces
leave from a socket of their own (an ephemeral port, not the ``imc+udp`` service), and it
relays every Heartbeat and PlanControl it takes in, whatever their ``dst`` and ours
included, to every system it streams to (DUNE's ``Transports`` list with ``Local Messages
Only = false``).
What the vehicle does with a message is up to its owner, :class:`mpcasv.io.sitl.Sitl`.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import imcpy

from mpcasv.config import ConfigError
from mpcasv.io.geo import Origin, to_wgs84
from mpcasv.io.imc import BROADCAST, BadInput, announce, decode, udp_services
from mpcasv.io.imc import stamp as _stamp
from mpcasv.io.netcheck import announced_hosts
from mpcasv.io.sitlplan import PlanEngine
from mpcasv.io.transport import TcpStream, UdpEndpoint

if TYPE_CHECKING:
    from mpcasv.io.sitl import Sitl

__all__ = ["HEARD_S", "Node", "SimVehicle"]

Addr = tuple[str, int]
HEARD_S = 30.0  # DUNE streams to systems heard from in the last 30 s
RELAYED = (imcpy.Heartbeat, imcpy.PlanControl)  # relayed back as DUNE's UDP transport does


@dataclass
class Node:
    """A system a simulated vehicle knows from its Announce."""

    id: int
    name: str
    services: list[Addr]
    last_hb: float = -math.inf
    active: Addr | None = None  # the service its datagrams last came from

    @property
    def dest(self) -> Addr:
        """Where to send: as DUNE's UDP transport (``Node::activate``), the ``imc+udp``
        service the node's datagrams come from (an Announce may name several)."""
        return self.active if self.active in self.services else self.services[0]


@dataclass
class SimVehicle:
    """One simulated vehicle as an IMC system."""

    sitl: Sitl
    name: str
    id: int
    role: str  # "asv" or "auv"
    index: int
    port: int = 0
    endpoint: UdpEndpoint | None = None
    announcer: UdpEndpoint | None = None  # DUNE's Announce task writes from its own socket
    nodes: dict[int, Node] = field(default_factory=dict)
    anchor: Origin | None = None
    alive: bool = False
    tcp_server: asyncio.base_events.Server | None = None
    tcp_port: int = 0
    tcp_clients: list[TcpStream] = field(default_factory=list)
    engine: PlanEngine = field(default_factory=PlanEngine)  # its PlanControlState

    @property
    def sys_type(self):
        return imcpy.SystemType.USV if self.role == "asv" else imcpy.SystemType.UUV

    async def open(self, host: str) -> None:
        self.endpoint = await UdpEndpoint.open(host, self.port, self.on_datagram)
        self.port = self.endpoint.address[1]
        self.announcer = await UdpEndpoint.open(host, 0, lambda data, addr: None)
        self.nodes.clear()
        self.engine = PlanEngine()  # a fresh DUNE: no plan, outcome NONE
        self.alive = True

    def close(self) -> None:
        self.alive = False
        if self.endpoint is not None:
            self.endpoint.close()
            self.endpoint = None
        if self.announcer is not None:
            self.announcer.close()
            self.announcer = None

    def services(self, to: Addr) -> list[str]:
        """Our ``imc+udp`` service as seen from ``to``: at ``--bind``, or bound to the
        wildcard, at the address datagrams from us to ``to`` come from (the route's source
        address: :func:`~mpcasv.io.netcheck.announced_hosts`, as the deploy's link.bind; a
        DUNE peer streams only to an address of our Announce that our datagrams come from,
        never to 0.0.0.0). ConfigError if this host has no route to ``to``."""
        hosts = announced_hosts(self.sitl.opt.bind, [to], "--bind")
        return [f"imc+udp://{h}:{self.port}/" for h in hosts]

    def stamp(self, msg: imcpy.Message, dst: int = BROADCAST) -> imcpy.Message:
        return _stamp(msg, self.id, dst, self.sitl.now(), src_ent=1)

    def _send(self, msg: imcpy.Message, addr: Addr) -> None:
        data = msg.serialize()
        if self.endpoint is not None and self.endpoint.sendto(data, addr):
            self.sitl.lsf.write(data)

    def announce_to(self, addrs) -> None:
        """Our Announce to each of ``addrs``, naming the service that address can reach
        (:meth:`services`); an address this host has no route to is skipped and counted
        (``announce_no_route``)."""
        if not self.alive:
            return
        lat, lon = to_wgs84(*self.sitl.position(self), self.sitl.origin)
        for a in addrs:
            try:
                services = self.services(a)
            except ConfigError:
                self.sitl.count("announce_no_route")
                continue
            data = self.stamp(announce(self.name, self.sys_type, services, lat, lon)).serialize()
            if self.announcer is not None and self.announcer.sendto(data, a):
                self.sitl.lsf.write(data)

    def publish(self, msg: imcpy.Message, t: float | None = None) -> None:
        """To every system heard from in the last 30 s (and every backseat client), stamped
        now or at ``t`` (a timestamp: a USBL fix obtained between two ticks)."""
        if not self.alive:
            return
        now = self.sitl.now()
        self.stamp(msg)
        if t is not None:
            msg.timestamp = t
        for node in self.nodes.values():
            if now - node.last_hb <= HEARD_S and node.services:
                self._send(msg, node.dest)
        data = msg.serialize()
        for c in list(self.tcp_clients):
            if c.send(data):
                self.sitl.lsf.write(data)

    def reply(self, msg: imcpy.Message, node: Node | None, stream: TcpStream | None) -> None:
        self.stamp(msg, node.id if node else BROADCAST)
        if stream is not None:
            stream.send(msg.serialize())
            self.sitl.lsf.write(msg.serialize())
        elif node is not None and node.services:
            self._send(msg, node.dest)

    def learn(self, msg: imcpy.Announce) -> None:
        if msg.src == self.id:
            return
        services = udp_services(msg.services)
        node = self.nodes.get(msg.src)
        new = node is None
        if new:
            node = self.nodes[msg.src] = Node(msg.src, msg.sys_name, services)
        node.name, node.services = msg.sys_name, services
        if new and services:
            self.announce_to(services[:1])

    def on_datagram(self, data: bytes, addr: Addr) -> None:
        try:
            msg, raw = decode(data)
        except BadInput as bad:
            self.sitl.count(f"drop_{bad.reason}")
            return
        self.sitl.lsf.write(raw)
        if not self.alive:
            return
        if isinstance(msg, imcpy.Announce):
            if msg.dst in (self.id, BROADCAST):
                self.learn(msg)
            return
        node = self.nodes.get(msg.src)
        if node is None or addr not in node.services:  # DUNE: only announced systems
            self.sitl.count("drop_unannounced")
            return
        node.active = addr
        if isinstance(msg, imcpy.Heartbeat):
            node.last_hb = self.sitl.now()
        if isinstance(msg, RELAYED):  # on DUNE's bus, so relayed back, whatever its dst
            self.relay(raw)
        if msg.dst not in (self.id, BROADCAST):
            self.sitl.count("drop_not_for_me")
            return
        self.on_message(msg, node, None)

    def relay(self, raw: bytes) -> None:
        """A packet as received, unchanged, to every system heard from in the last 30 s."""
        now = self.sitl.now()
        for node in self.nodes.values():
            if now - node.last_hb <= HEARD_S and node.services and self.endpoint is not None:
                if self.endpoint.sendto(raw, node.dest):
                    self.sitl.lsf.write(raw)
                    self.sitl.count("relayed")

    def on_message(self, msg, node: Node | None, stream: TcpStream | None) -> None:
        if isinstance(msg, imcpy.Heartbeat):
            if node is not None:
                node.last_hb = self.sitl.now()
        elif self.role == "asv":
            self.sitl.asv_message(self, msg, node, stream)

    async def serve_tcp(self, host: str) -> None:
        """Serve DUNE's TCP backseat port on ``host`` (``tcp_port``; 0: any free port).

        A client still connected when the SITL ends has its handler cancelled by
        ``asyncio.run``; the handler then ends quietly, its connection closed: Python 3.11's
        ``StreamReaderProtocol`` calls ``exception()`` on the cancelled handler and logged a
        ``CancelledError`` traceback per client on every normal end of ``mpcasv sitl --tcp``
        (a field engineer's trial, session 45)."""

        async def client(reader, writer):
            stream = TcpStream(reader, writer, lambda m, raw: self._on_tcp(m, raw, stream))
            self.tcp_clients.append(stream)
            try:
                await stream.run()
            except asyncio.CancelledError:  # the SITL's end: nothing awaits this handler
                stream.close()
            finally:
                if stream in self.tcp_clients:
                    self.tcp_clients.remove(stream)

        self.tcp_server = await asyncio.start_server(client, host, self.tcp_port)
        self.tcp_port = self.tcp_server.sockets[0].getsockname()[1]

    def _on_tcp(self, msg, raw: bytes, stream: TcpStream) -> None:
        self.sitl.lsf.write(raw)
        if self.alive and msg.dst in (self.id, BROADCAST):
            self.on_message(msg, self.nodes.get(msg.src), stream)
