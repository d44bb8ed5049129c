"""IMC messages in and out of the toolkit: framing checks, decoding, conversions.

Encoding and decoding are imcpy's (DUNE's own codec); this module only checks the framing
of a datagram before handing it over, turns imcpy's errors into a named reason
(:class:`BadInput`), and converts between EstimatedState / Reference and the controller's
local NED frame through absolute latitude/longitude (DUNE moves the reference point of
EstimatedState, so raw ``x``/``y`` are never compared across messages).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import imcpy

from mpcasv.interface import Command, Mode, pushed_waypoint
from mpcasv.io.geo import Origin, absolute_latlon, to_local, to_wgs84

__all__ = [
    "BROADCAST",
    "BadInput",
    "NavState",
    "announce",
    "decode",
    "estimated_state",
    "header",
    "nav_state",
    "non_finite_fields",
    "reference",
    "stamp",
    "udp_services",
    "usbl_fix_extended",
]

BROADCAST = 0xFFFF  # IMC broadcast system id
ANY_ENTITY = 0xFF
_HDR_LE = struct.Struct("<HHHdHBHB")
_HDR_BE = struct.Struct(">HHHdHBHB")
HEADER_SIZE = _HDR_LE.size  # 20
FOOTER_SIZE = 2
_SYNC = imcpy.constants.SYNC  # 0xFE54 read little-endian
RF = imcpy.Reference.FlagsBits
_MAX_ITER = 8


class BadInput(ValueError):
    """An input rejected by the link; ``reason`` is the short counter name."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail


def stamp(msg: imcpy.Message, src: int, dst: int, t: float, src_ent: int = 0,
          dst_ent: int = ANY_ENTITY) -> imcpy.Message:  # fmt: skip
    """Fill the header (a fresh imcpy message has src = dst = 0xFFFF and timestamp -1)."""
    msg.src, msg.src_ent, msg.dst, msg.dst_ent, msg.timestamp = src, src_ent, dst, dst_ent, t
    return msg


def packet_length(data: bytes) -> int:
    """Length of the IMC packet at the start of ``data`` from its header (either byte order).

    Raises
    ------
    BadInput
        ``truncated`` (shorter than a header or than the size it announces) or ``bad_sync``.
    """
    if len(data) < HEADER_SIZE + FOOTER_SIZE:
        raise BadInput("truncated", f"{len(data)} bytes, a packet has at least 22")
    sync = _HDR_LE.unpack_from(data)[0]
    if sync == _SYNC:
        size = _HDR_LE.unpack_from(data)[2]
    elif _HDR_BE.unpack_from(data)[0] == _SYNC:
        size = _HDR_BE.unpack_from(data)[2]
    else:
        raise BadInput("bad_sync", f"sync bytes {data[:2].hex()}")
    n = HEADER_SIZE + size + FOOTER_SIZE
    if len(data) < n:
        raise BadInput("truncated", f"{len(data)} bytes, header announces {n}")
    return n


def header(data: bytes) -> tuple[int, int, int]:
    """(message id, src, dst) from the header of a datagram holding exactly one packet,
    without decoding the payload (imcpy 1.1.2 has no header-only parse; the layout is
    checked against imcpy's in tests/test_io_link.py).

    Raises
    ------
    BadInput
        ``truncated``, ``bad_sync`` or ``trailing_bytes``.
    """
    n = packet_length(data)
    if len(data) > n:
        raise BadInput("trailing_bytes", f"{len(data) - n} bytes after a {n}-byte packet")
    h = _HDR_LE.unpack_from(data) if _HDR_LE.unpack_from(data)[0] == _SYNC else \
        _HDR_BE.unpack_from(data)  # fmt: skip
    return h[1], h[4], h[6]


def decode(data: bytes) -> tuple[imcpy.Message, bytes]:
    """Decode one datagram holding exactly one IMC packet; return (message, packet bytes).

    Raises
    ------
    BadInput
        ``truncated``, ``bad_sync``, ``trailing_bytes``, ``bad_crc`` or ``malformed``
        (imcpy refused the packet: unknown message id, field out of its encoding...).
    """
    n = packet_length(data)
    if len(data) > n:
        raise BadInput("trailing_bytes", f"{len(data) - n} bytes after a {n}-byte packet")
    try:
        msg = imcpy.Packet.deserialize(bytes(data))
    except RuntimeError as exc:
        text = str(exc)
        reason = "bad_crc" if "CRC" in text else "truncated" if "short" in text else "malformed"
        raise BadInput(reason, text) from None
    except Exception as exc:  # imcpy raises other types on odd input (kept, but named)
        raise BadInput("malformed", f"{type(exc).__name__}: {exc}") from None
    if msg is None:
        raise BadInput("malformed", "imcpy returned no message")
    return msg, bytes(data)


def non_finite_fields(msg: imcpy.Message, prefix: str = "") -> list[str]:
    """Names of float fields (also of inline messages) that are NaN or infinite."""
    bad = []
    if not math.isfinite(msg.timestamp):
        bad.append(prefix + "timestamp")
    for name, attr in type(msg).__dict__.items():
        if not isinstance(attr, property):
            continue
        value = getattr(msg, name)
        if isinstance(value, float) and not math.isfinite(value):
            bad.append(prefix + name)
        elif isinstance(value, imcpy.Message):
            bad.extend(non_finite_fields(value, f"{prefix}{name}."))
    return bad


def udp_services(services: str) -> list[tuple[str, int]]:
    """The ``imc+udp://host:port/`` entries of an Announce ``services`` string (';'-separated)."""
    out = []
    for s in services.split(";"):
        s = s.strip()
        if not s.startswith("imc+udp://"):
            continue
        hostport = s[len("imc+udp://") :].strip("/")
        host, _, port = hostport.rpartition(":")
        if host and port.isdigit() and 0 < int(port) < 65536:
            out.append((host, int(port)))
    return out


def announce(name: str, sys_type: imcpy.SystemType, services: list[str], lat: float = 0.0,
             lon: float = 0.0, height: float = 0.0) -> imcpy.Announce:  # fmt: skip
    """An Announce (header to be stamped by the sender)."""
    a = imcpy.Announce()
    a.sys_name, a.sys_type, a.owner = name, sys_type, BROADCAST
    a.lat, a.lon, a.height = lat, lon, height
    a.services = ";".join(services)
    return a


@dataclass(frozen=True, slots=True)
class NavState:
    """A vehicle's navigation state in the local frame (SI units, NED, psi from north)."""

    t: float
    N: float
    E: float
    depth: float
    psi: float
    u: float
    v: float
    r: float
    v_N: float
    v_E: float
    lat: float  # absolute, rad
    lon: float


def nav_state(es: imcpy.EstimatedState, origin: Origin) -> NavState:
    """EstimatedState -> :class:`NavState` around ``origin`` through absolute lat/lon.

    The horizontal position is that of the reference point displaced by ``x``/``y`` only:
    DUNE's ``toWGS84`` also moves lat/lon with ``z`` (by millimetres per metre of depth at a
    kilometre's offset), and the vertical comes from ``depth``.
    """
    fields = {k: getattr(es, k) for k in ("lat", "lon", "height", "x", "y")} | {"z": 0.0}
    lat, lon, h = absolute_latlon(fields)
    N, E, _ = to_local(lat, lon, h, origin)
    return NavState(es.timestamp, N, E, es.depth, es.psi, es.u, es.v, es.r, es.vx, es.vy, lat,
                    lon)  # fmt: skip


def estimated_state(s: NavState, anchor: Origin, origin: Origin) -> imcpy.EstimatedState:
    """The EstimatedState DUNE would send for ``s`` (local to ``origin``) with its reference
    point at ``anchor``: ``lat``/``lon``/``height`` = anchor, ``x``/``y`` = the offsets that
    DUNE's own ``toWGS84`` maps back onto the position (solved by fixed-point iteration, the
    map being the identity to a few mm per km), ``z`` = ``depth``."""
    es = imcpy.EstimatedState()
    es.lat, es.lon, es.height = anchor.lat, anchor.lon, anchor.height
    lat, lon = to_wgs84(s.N, s.E, origin)
    x, y, _ = to_local(lat, lon, anchor.height, anchor)
    base = {"lat": anchor.lat, "lon": anchor.lon, "height": anchor.height, "z": 0.0}
    for _ in range(_MAX_ITER):
        N, E, _ = to_local(*absolute_latlon(base | {"x": x, "y": y}), origin)
        dN, dE = s.N - N, s.E - E
        x, y = x + dN, y + dE
        if math.hypot(dN, dE) < 1e-5:
            break
    es.x, es.y, es.z = x, y, s.depth
    es.depth, es.alt = s.depth, -1.0
    es.psi, es.u, es.v, es.r = s.psi, s.u, s.v, s.r
    es.vx, es.vy, es.vz = s.v_N, s.v_E, 0.0
    return es


def usbl_fix_extended(target: str, N: float, E: float, depth: float, accuracy: float,
                      origin: Origin) -> imcpy.UsblFixExtended:  # fmt: skip
    """The UsblFixExtended a DUNE USBL task dispatches for a fix of system ``target`` at
    ``(N, E)`` (m, local to ``origin``) and ``depth`` (m): WGS-84 ``lat``/``lon`` (rad),
    ``z`` the depth (``z_units`` DEPTH), ``accuracy`` (m) (header to be stamped by the
    sender)."""
    fix = imcpy.UsblFixExtended()
    fix.target = target
    fix.lat, fix.lon = to_wgs84(N, E, origin)
    fix.z, fix.z_units, fix.accuracy = depth, imcpy.ZUnits.DEPTH, accuracy
    return fix


def reference(cmd: Command, asv_NE: tuple[float, float], origin: Origin, lead: float = 0.0,
              radius: float = 0.0) -> imcpy.Reference:  # fmt: skip
    """The Reference for a supervisory command (header to be stamped by the sender).

    Transit: the waypoint (pushed ``lead`` metres further along the line from the ASV, so
    that DUNE's arrival test, |radius| + 15 m, does not switch the loops off before the
    controller decides to stand by; the line-of-sight heading is unchanged) at the command's
    speed in m/s. Standby: the ASV's own position at speed 0, which switches DUNE's loops
    off. Always at the surface (DesiredZ depth 0).
    """
    r = imcpy.Reference()
    if cmd.mode is Mode.TRANSIT:
        N, E = pushed_waypoint(cmd.waypoint, asv_NE, lead)
        speed = cmd.speed
    else:
        N, E = asv_NE
        speed = 0.0
    r.lat, r.lon = to_wgs84(N, E, origin)
    sp = imcpy.DesiredSpeed()
    sp.value, sp.speed_units = float(speed), imcpy.SpeedUnits.METERS_PS
    z = imcpy.DesiredZ()
    z.value, z.z_units = 0.0, imcpy.ZUnits.DEPTH
    r.speed, r.z, r.radius = sp, z, float(radius)
    r.flags = RF.LOCATION | RF.SPEED | RF.Z | (RF.RADIUS if radius else 0)
    return r
