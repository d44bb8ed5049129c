"""The configured vehicles as the link knows them, and the checks on who sent a datagram.

:class:`PeerDirectory` is the part of :class:`mpcasv.io.link.ImcLink` that learns vehicles
from their Announces (DUNE's: from an ephemeral port of a host its ``imc+udp`` services
name) and classifies every datagram by its header: from which configured vehicle, or a relay
(``echo``, ``not_for_us``, ``third_party``, ``pre_discovery``: counted, silent), or a reject.
The rules are in the module docstring of :mod:`mpcasv.io.link` (checks 2-4).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import imcpy

from mpcasv.io.config import DeployConfig, Vehicle
from mpcasv.io.imc import BROADCAST, BadInput, NavState, udp_services
from mpcasv.io.statecheck import StateTrack
from mpcasv.io.transport import Clock, TcpStream

#: systems that announced and are no configured vehicle, kept by name (``ImcLink.strangers``)
MAX_STRANGERS = 20

__all__ = ["Peer", "PeerDirectory"]

Addr = tuple[str, int]


@dataclass
class Peer:
    """A configured vehicle as the link knows it at run time."""

    spec: Vehicle
    index: int  # AUV index k (file order), -1 for the ASV
    id: int | None = None
    name: str | None = None
    addresses: set[Addr] = field(default_factory=set)
    hosts: set[str] = field(default_factory=set)  # hosts its Announces came from / name
    static: bool = False  # address from the config, not learnt
    last_heard: float = -math.inf  # deploy clock of the last accepted message
    track: StateTrack = field(default_factory=StateTrack)  # last accepted state, checks
    stream: TcpStream | None = None
    announces: int = 0

    @property
    def nav(self) -> NavState | None:
        """The last accepted state."""
        return self.track.nav

    @nav.setter
    def nav(self, value: NavState | None) -> None:
        self.track.nav = value

    @property
    def nav_recv(self) -> float:
        """Deploy clock when the last accepted state arrived."""
        return self.track.recv

    @nav_recv.setter
    def nav_recv(self, value: float) -> None:
        self.track.recv = value

    @property
    def role(self) -> str:
        return self.spec.role

    @property
    def label(self) -> str:
        return self.name or self.spec.label


class PeerDirectory:
    """Mixin of :class:`mpcasv.io.link.ImcLink`: vehicles, Announces, header checks.

    Uses the link's ``cfg``, ``clock``, ``id``, ``peers``, ``relayed``, ``ignored`` and
    ``event``.
    """

    cfg: DeployConfig
    clock: Clock
    id: int
    peers: list[Peer]
    relayed: Counter
    ignored: Counter

    def _route(self, name: str, src: int, dst: int, addr: Addr | None,
               stream_peer: Peer | None) -> Peer | None:  # fmt: skip
        """Checks 2-4 on header fields: the sending vehicle, or None for a relay (counted)."""
        via = stream_peer or (self._peer_by_addr(addr) if addr is not None else None)
        early = via is None and addr is not None and self._awaiting(addr[0])
        if src == self.id or dst not in (self.id, BROADCAST):
            if via is not None:
                self.relayed["echo" if src == self.id else "not_for_us"] += 1
                return None
            if early:
                self.relayed["pre_discovery"] += 1
                return None
            if src == self.id:
                raise BadInput("own_id", f"{name} with our id 0x{src:04X} as src")
            raise BadInput("not_for_us", f"dst 0x{dst:04X}")
        if via is not None and via.id is not None and src != via.id:
            if stream_peer is not None and self._peer_by_id(src) is None:
                raise BadInput("id_mismatch", f"src 0x{src:04X} on {via.label}'s stream")
            self.relayed["third_party"] += 1
            return None
        p = stream_peer or self._peer_by_id(src)
        if p is None:
            raise BadInput("unknown_sender", f"src 0x{src:04X}")
        if addr is not None:
            if not p.addresses and early:
                self.relayed["pre_discovery"] += 1
                return None
            if not p.addresses:
                raise BadInput("not_announced", f"{p.label} has not announced itself")
            if addr not in p.addresses:
                raise BadInput("address_mismatch", f"{p.label} from {addr[0]}:{addr[1]}")
        return p

    def _peer_by_addr(self, addr: Addr) -> Peer | None:
        return next((p for p in self.peers if addr in p.addresses), None)

    def _awaiting(self, host: str) -> bool:
        """A vehicle known from an Announce without ``imc+udp`` service (DUNE's first at
        start-up), from this host, whose data address is not known yet: DUNE streams from
        the moment it has heard our Announce, possibly before its next Announce (10 s)
        names its address. Its datagrams (and relays) until then are ``pre_discovery``."""
        return any(not p.addresses and p.id is not None and host in p.hosts
                   for p in self.peers)  # fmt: skip

    def _peer_by_id(self, src: int) -> Peer | None:
        return next((p for p in self.peers if p.id == src), None)

    def _announce_in(self, msg: imcpy.Announce, addr: Addr | None, stream_peer) -> Peer | None:
        if msg.src == self.id and msg.sys_name == self.cfg.identity.name:
            self.relayed["own_announce"] += 1  # our multicast Announce, looped back
            return None
        p = stream_peer or next((q for q in self.peers if q.spec.name == msg.sys_name), None)
        if p is None:
            p = self._peer_by_id(msg.src)
            if p is None or p.spec.name:  # unknown id, or a configured name that differs
                if len(self.strangers) < MAX_STRANGERS or msg.sys_name in self.strangers:
                    self.strangers[msg.sys_name] = msg.src
                named = f" (0x{msg.src:04X} is configured as {p.spec.name!r})" if p else ""
                raise BadInput("unknown_sender",
                               f"Announce of {msg.sys_name!r} 0x{msg.src:04X}{named}")
        if p.spec.id is not None and msg.src != p.spec.id:
            raise BadInput("id_mismatch", f"{msg.sys_name!r} announces 0x{msg.src:04X}")
        if p.id is not None and msg.src != p.id and self._fresh(p):
            raise BadInput("id_mismatch", f"{p.label} is 0x{p.id:04X}, not 0x{msg.src:04X}")
        services = set(udp_services(msg.services))
        if addr is not None and p.static:
            if addr[0] == "0.0.0.0" and services <= p.addresses:
                # no source address: DUNE's multicast copy on a host with loopback only
                self.ignored["Announce_from_0.0.0.0"] += 1
                return None
            if addr[0] not in {h for h, _ in p.addresses}:
                raise BadInput("address_mismatch", f"{p.label} announced from {addr}")
        elif addr is not None and not services:
            # DUNE's first Announce at start-up, or its multicast copy on a loopback-only
            # host: who it is (and from which host) but not where its data comes from
            if addr[0] != "0.0.0.0":
                p.hosts.add(addr[0])
        elif addr is not None:
            if addr[0] not in {h for h, _ in services}:  # any port: DUNE's Announce socket
                raise BadInput("address_mismatch", f"{p.label} from {addr[0]}:{addr[1]}, "
                               f"services {sorted(services)}")  # fmt: skip
            if p.addresses and services != p.addresses and self._fresh(p):
                raise BadInput("address_mismatch", f"{p.label} re-announced {sorted(services)}")
            if services != p.addresses:
                self.event("discovered", vehicle=p.label, id=msg.src, sys_name=msg.sys_name,
                           addresses=[f"{h}:{q}" for h, q in sorted(services)],
                           announced_from=f"{addr[0]}:{addr[1]}")  # fmt: skip
            p.addresses = services
            p.hosts |= {h for h, _ in services}
        if p.id != msg.src:
            p.id = msg.src
        p.name = msg.sys_name
        p.announces += 1
        return p

    def _fresh(self, p: Peer) -> bool:
        limit = self.cfg.watchdog.asv_stale_s if p.role == "asv" else self.cfg.watchdog.auv_stale_s
        return self.clock.now() - p.last_heard < limit
