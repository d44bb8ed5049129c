"""Up-front checks of the local addresses and ports ``mpcasv deploy`` and ``mpcasv sitl`` bind.

A bind that fails only once the run is under way ended in a bare ``Cannot assign requested
address`` or ``Name or service not known`` (naming neither the option nor the address), an
``OverflowError`` traceback for a port above 65535, and a half-written output folder. These
helpers try the bind first (a socket bound and closed at once: nothing stays open) and refuse
in one line naming the option or field, the value and the cause
(:class:`mpcasv.config.ConfigError`).
"""

from __future__ import annotations

import errno
import ipaddress
import socket

import psutil

from mpcasv.config import ConfigError

__all__ = ["PORT_MAX", "announced_hosts", "check_bindable", "check_ipv4", "check_port",
           "is_wildcard", "local_hosts"]

PORT_MAX = 65535


def check_ipv4(host: str, what: str) -> str:
    """``host`` if it is an IPv4 literal (``127.0.0.1``, ``0.0.0.0``, ...); else ConfigError
    naming ``what`` (the option or field) and the value."""
    try:
        ipaddress.IPv4Address(host)
    except ValueError:
        raise ConfigError(f"{what} {host!r}: not an IPv4 address (e.g. 127.0.0.1, or this "
                          "host's address on the vehicles' network)") from None  # fmt: skip
    return host


def check_port(port: int, what: str, top: int = PORT_MAX, why: str = "") -> int:
    """``port`` if it is an integer in ``[0, top]`` (``top`` below 65535 when ports above it
    are used too, ``why`` says so); else ConfigError naming ``what`` and the value."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= top:
        raise ConfigError(f"{what} {port}: a port is an integer in [0, {top}]"
                          + (f" ({why})" if why else ""))  # fmt: skip
    return port


def check_bindable(host: str, port: int, what: str, kind: int = socket.SOCK_DGRAM) -> None:
    """Bind a socket (UDP by default) to ``host:port`` and close it at once.

    Raises
    ------
    ConfigError
        One line naming ``what``, the address and the cause: not an IPv4 address, not an
        address of this host, the port in use, or a privileged port.
    """
    check_ipv4(host, what)
    sock = socket.socket(socket.AF_INET, kind)
    try:
        sock.bind((host, port))
    except OSError as exc:
        cause = {
            errno.EADDRNOTAVAIL: f"{host} is not an address of this host (give one of its "
                                 "own addresses: 127.0.0.1, or its address on the vehicles' "
                                 "network)",
            errno.EADDRINUSE: f"port {port} is in use on {host} (another mpcasv or DUNE?)",
            errno.EACCES: f"port {port} needs privileges (use a port above 1023)",
        }.get(exc.errno, exc.strerror or str(exc))  # fmt: skip
        shown = host if port == 0 else f"{host}:{port}"  # port 0: the address alone
        raise ConfigError(f"{what} {shown}: cannot bind: {cause}") from None
    finally:
        sock.close()


def is_wildcard(host: str) -> bool:
    """Whether ``host`` (an IPv4 literal) is the wildcard address 0.0.0.0 (every local one)."""
    return ipaddress.IPv4Address(host).is_unspecified


def announced_hosts(bind: str, remotes, what: str) -> list[str]:
    """The local addresses to announce in our ``imc+udp`` services when bound to ``bind``.

    DUNE's UDP transport streams to a node only at the one ``imc+udp`` address of its
    Announce that the node's datagrams come from (``Transports/UDP/Node.hpp``,
    ``activate()``), and a datagram never comes from 0.0.0.0. Bound to a concrete address,
    that address; bound to the wildcard, for each remote ``(host, port)`` (the vehicles'
    addresses) the local address a UDP socket connected to it gets (the route's source
    address; ``connect()`` sends nothing), deduplicated, in the remotes' order.

    Raises
    ------
    ConfigError
        One line naming ``what``: a remote the OS has no route to (or none given).
    """
    if not is_wildcard(bind):
        return [bind]
    hosts: list[str] = []
    for host, port in remotes:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.connect((host, port))
            local = sock.getsockname()[0]
        except OSError as exc:
            raise ConfigError(f"{what} {bind}: cannot tell which address of this host {host} "
                              f"would see our datagrams from ({exc.strerror or exc}): bind to "
                              "this host's address on the vehicles' network") from None
        finally:
            sock.close()
        if local not in hosts and not is_wildcard(local):
            hosts.append(local)
    if not hosts:
        raise ConfigError(f"{what} {bind}: no vehicle address to announce ourselves to (DUNE "
                          "streams only to an imc+udp address of our Announce, never to "
                          f"{bind}): bind to this host's address on the vehicles' network")
    return hosts


def local_hosts(bind: str) -> list[str]:
    """The addresses of this host a peer can send to when we are bound to ``bind``: ``bind``
    itself, or bound to the wildcard, every IPv4 address of this host's interfaces
    (``psutil.net_if_addrs``), loopback last (a wildcard bind is for peers on other hosts,
    and ``mpcasv sitl`` prints its addresses at the first: a review), else in the
    interfaces' order, none twice, never 0.0.0.0. Which of them a given peer sees us from
    is :func:`announced_hosts`'s (the route's source address)."""
    if not is_wildcard(bind):
        return [bind]
    found = [a.address for addrs in psutil.net_if_addrs().values() for a in addrs
             if a.family == socket.AF_INET]  # fmt: skip
    hosts = sorted(set(found), key=lambda h: (ipaddress.IPv4Address(h).is_loopback,
                                              found.index(h)))  # fmt: skip
    return [h for h in hosts if not is_wildcard(h)] or ["127.0.0.1"]
