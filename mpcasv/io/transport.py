"""Small asyncio transports for IMC: a UDP endpoint and TCP streams (DUNE's backseat port),
and the scaled clock both sides of a rehearsal share.

Bytes only: encoding and decoding are imcpy's (:mod:`mpcasv.io.imc`); a TCP stream is cut
into packets by ``imcpy.Parser``.
"""

from __future__ import annotations

import asyncio
import socket
import time
from collections.abc import Callable

import imcpy

__all__ = ["Clock", "TcpStream", "UdpEndpoint"]

Addr = tuple[str, int]


class Clock:
    """Seconds since the UNIX epoch, running ``speedup`` times faster than the wall clock
    from the moment of construction (speedup 1: the wall clock)."""

    def __init__(self, speedup: float = 1.0) -> None:
        if not speedup > 0:
            raise ValueError(f"speedup must be > 0, got {speedup}")
        self.speedup = float(speedup)
        self._wall0 = time.time()
        self._mono0 = time.monotonic()

    def now(self) -> float:
        return self._wall0 + (time.monotonic() - self._mono0) * self.speedup

    def wall_seconds(self, s: float) -> float:
        """Wall-clock duration of ``s`` clock seconds."""
        return s / self.speedup

    async def sleep(self, s: float) -> None:
        await asyncio.sleep(max(s, 0.0) / self.speedup)

    async def sleep_until(self, t: float) -> None:
        await asyncio.sleep(max(t - self.now(), 0.0) / self.speedup)


class _UdpProtocol(asyncio.DatagramProtocol):
    def __init__(self, on_datagram: Callable[[bytes, Addr], None]) -> None:
        self.on_datagram = on_datagram
        self.errors = 0

    def datagram_received(self, data: bytes, addr) -> None:
        self.on_datagram(data, (addr[0], addr[1]))

    def error_received(self, exc: Exception) -> None:  # ICMP port unreachable etc.
        self.errors += 1


class UdpEndpoint:
    """A UDP socket bound to one address; ``on_datagram(data, (host, port))`` per datagram."""

    def __init__(self, transport: asyncio.DatagramTransport, protocol: _UdpProtocol) -> None:
        self._transport, self._protocol = transport, protocol
        host, port = transport.get_extra_info("sockname")[:2]
        self.address: Addr = (host, port)
        self.send_errors = 0
        self._reader: socket.socket | None = None  # for drain()

    @classmethod
    async def open(cls, host: str, port: int, on_datagram: Callable[[bytes, Addr], None],
                   reuse_port: bool = False) -> UdpEndpoint:  # fmt: skip
        loop = asyncio.get_running_loop()
        transport, protocol = await loop.create_datagram_endpoint(
            lambda: _UdpProtocol(on_datagram), local_addr=(host, port),
            reuse_port=reuse_port or None,
        )  # fmt: skip
        return cls(transport, protocol)

    @classmethod
    async def open_discovery(cls, host: str, port: int, group: str, iface: str,
                             on_datagram: Callable[[bytes, Addr], None]) -> UdpEndpoint:
        """A discovery socket as DUNE's peers use them: ``host:port`` with SO_REUSEADDR,
        joined to the multicast ``group`` on the interface of address ``iface`` (when bound
        to 0.0.0.0; a socket bound to a unicast address gets only unicast Announces, such as
        DUNE's loopback copies to 127.0.0.1:3010x). Raises OSError (port busy: a DUNE on this
        host binds its discovery port without SO_REUSEADDR)."""  # fmt: skip
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
            if host == "0.0.0.0":
                mreq = socket.inet_aton(group) + socket.inet_aton(iface)
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
            sock.setblocking(False)
        except OSError:
            sock.close()
            raise
        loop = asyncio.get_running_loop()
        transport, protocol = await loop.create_datagram_endpoint(
            lambda: _UdpProtocol(on_datagram), sock=sock)
        return cls(transport, protocol)

    def multicast_from(self, iface: str) -> None:
        """Send multicast (our Announce to 224.0.75.69) out of the interface of address
        ``iface`` (the one we are bound to), not wherever the routing table points."""
        sock = self._transport.get_extra_info("socket")
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(iface))

    def sendto(self, data: bytes, addr: Addr) -> bool:
        """Send one datagram; False (counted in ``send_errors``) if the OS refused it."""
        if self._transport.is_closing():
            return False
        try:
            self._transport.sendto(data, addr)
            return True
        except OSError:
            self.send_errors += 1
            return False

    @property
    def closed(self) -> bool:
        """Closed (or closing: the socket is released at the event loop's next pass)."""
        return self._transport.is_closing()

    @property
    def receive_errors(self) -> int:
        return self._protocol.errors

    def drain(self, limit: int = 10_000) -> int:
        """Read the datagrams waiting in the socket now (at most ``limit``), each through
        ``on_datagram`` as the event loop would; return how many.

        The event loop reads one datagram per pass and runs due timers in the same pass: after
        this process was starved of CPU, a watchdog timer ran before the states that had
        arrived meanwhile were read, and called fresh vehicles stale (see
        :meth:`mpcasv.io.deploy.Deploy.watch`).
        """
        if self._transport.is_closing():
            return 0
        if self._reader is None:  # asyncio's wrapper cannot read: a duplicate of the socket
            self._reader = self._transport.get_extra_info("socket").dup()
            self._reader.setblocking(False)
        sock = self._reader
        n = 0
        while n < limit:
            try:
                data, addr = sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self._protocol.errors += 1
                break
            self._protocol.on_datagram(data, (addr[0], addr[1]))
            n += 1
        return n

    def close(self) -> None:
        self._transport.close()
        if self._reader is not None:
            self._reader.close()
            self._reader = None


class TcpStream:
    """One TCP connection carrying IMC packets; ``on_message(msg, packet_bytes)`` per packet.

    Parsing uses ``imcpy.Parser``, which resynchronises on the IMC sync number after garbage;
    ``skipped`` counts the bytes it dropped.
    """

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                 on_message: Callable[[imcpy.Message, bytes], None]) -> None:  # fmt: skip
        self.reader, self.writer, self.on_message = reader, writer, on_message
        peer = writer.get_extra_info("peername")
        self.peer: Addr = (peer[0], peer[1]) if peer else ("?", 0)
        self.skipped = 0
        self.closed = asyncio.Event()

    @classmethod
    async def connect(cls, host: str, port: int, on_message, local_host: str | None = None
                      ) -> TcpStream:  # fmt: skip
        reader, writer = await asyncio.open_connection(
            host, port, local_addr=(local_host, 0) if local_host else None
        )
        return cls(reader, writer, on_message)

    async def run(self) -> None:
        """Read until the peer closes; each decoded packet goes to ``on_message``."""
        parser = imcpy.Parser()
        try:
            while True:
                chunk = await self.reader.read(65536)
                if not chunk:
                    break
                buf = bytes(chunk)
                while buf:
                    msg, used = parser.parse(buf)
                    buf = buf[used:]
                    if msg is not None:
                        self.on_message(msg, msg.serialize())
                    elif used == 0:
                        break
        except (ConnectionError, OSError, RuntimeError):
            pass
        finally:
            self.close()

    def send(self, data: bytes) -> bool:
        if self.writer.is_closing():
            return False
        try:
            self.writer.write(data)
            return True
        except (ConnectionError, OSError):
            return False

    def close(self) -> None:
        if not self.writer.is_closing():
            self.writer.close()
        self.closed.set()
