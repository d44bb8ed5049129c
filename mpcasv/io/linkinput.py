"""The IMC link's input checks (:class:`InputChecks`, a base of
:class:`mpcasv.io.link.ImcLink`; its counters and callbacks live there): every incoming
datagram or TCP message is checked before the deploy sees it. A datagram that fails one is
dropped, counted under its reason in ``rejects`` and reported through ``on_event``
(rate-limited per reason); the loop carries on.

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
"""

from __future__ import annotations

import time

import imcpy

from mpcasv.io.imc import BadInput, decode, header, non_finite_fields
from mpcasv.io.peers import Peer, PeerDirectory
from mpcasv.io.statecheck import Duplicate, check_state

__all__ = ["USED", "InputChecks"]

Addr = tuple[str, int]
_ACCEPTED = {
    "asv": {"EstimatedState", "Heartbeat", "PlanControl", "PlanControlState", "FollowRefState",
            "SetThrusterActuation", "SetServoPosition", "UsblFixExtended"},
    "auv": {"EstimatedState", "Heartbeat"},
}  # fmt: skip
#: IMC message ids the deploy decodes (imcpy's ids); every other id is handled on its header.
USED = {imcpy.Factory.id_from_abbrev(n): n for n in
        set().union(*_ACCEPTED.values()) | {"Announce"}}  # fmt: skip


class InputChecks(PeerDirectory):
    """Checks 1-6 of the module docstring; the routing of checks 2-4 is
    :class:`~mpcasv.io.peers.PeerDirectory`'s."""

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
