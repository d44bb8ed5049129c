"""Read DUNE LSF logs (``Data.lsf`` / ``Data.lsf.gz``) into tidy pandas tables through imcpy.

:func:`read_lsf` returns one row per EstimatedState, sorted by time, with columns

- ``t`` (s, UNIX time of the IMC header), ``vehicle`` (Announce ``sys_name``, else ``0x00D1``),
  ``src`` (IMC id);
- ``N``, ``E`` (m, local NED around ``origin``; default: the first EstimatedState's absolute
  position), ``depth`` (m), ``lat``, ``lon`` (deg, absolute), ``psi`` (rad from north),
  ``u``, ``v`` (m/s, body), ``r`` (rad/s), ``vx``, ``vy`` (m/s, NED), ``speed_over_ground``;
- per vehicle, the latest earlier value of each command/actuator stream the log contains:
  ``thrust_<id>`` (SetThrusterActuation, -1..1), ``fin_cmd_<id>`` / ``fin_<id>``
  (SetServoPosition / ServoPosition, rad), ``rpm`` (Rpm), ``desired_speed`` (+ ``_units``:
  0 m/s, 1 RPM, 2 %), ``desired_heading`` (rad), ``desired_z`` (+ ``_units``: 1 depth,
  2 altitude, 3 height), ``followref_state``, ``followref_proximity`` (FollowRefState), and
  from Reference messages addressed to the vehicle (``dst``): ``ref_N``, ``ref_E`` (m),
  ``ref_speed`` (+ ``_units``), ``ref_z`` (+ ``_units``), ``ref_radius``, ``ref_flags``.
  A Reference field whose flag is unset keeps the previous value, as in DUNE.
  Values before a stream's first message are missing (NaN/NA).
The shared DUNE LAUV-simulator log has all of these but ``ref_radius`` (thruster 0, fins 0-3).

imcpy's own reader stops silently at a bad sync number or a packet cut short, opens ``.gz``
paths as raw bytes (yielding nothing) and writes an ``.imcpy_idx`` file beside the log. Here the
file is decompressed in memory, every packet's framing is checked first, and any problem raises
:class:`LogError`. CRCs are checked (by imcpy) only for the message types decoded.
"""

from __future__ import annotations

import gzip
import struct
import warnings
import zlib
from collections import defaultdict
from collections.abc import Callable, Iterable
from pathlib import Path

import imcpy
import numpy as np
import pandas as pd
from imcpy.lsf import LSFReader

from mpcasv.errors import LogError
from mpcasv.io.geo import Origin, absolute_latlon, to_local

__all__ = ["LogError", "read_lsf", "read_messages"]

_HEADER = struct.Struct("<HHHdHBHB")  # sync, mgid, size, timestamp, src, src_ent, dst, dst_ent
_FOOTER = 2
_SYNC = imcpy.constants.SYNC
_BROADCAST = 0xFFFF
_RF = imcpy.Reference.FlagsBits


def _load(path: str | Path) -> tuple[Path, bytes, dict[int, int]]:
    """Read (and gunzip) a log, check the packet framing; return bytes and counts per mgid."""
    path = Path(path)
    if not path.is_file():
        raise LogError(f"{path}: no such log file")
    data = path.read_bytes()
    if data[:2] == b"\x1f\x8b":
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError, zlib.error) as exc:
            raise LogError(f"{path}: corrupt or truncated gzip data ({exc})") from exc
    elif path.suffix == ".gz":
        raise LogError(f"{path}: named .gz but is not gzip-compressed")
    if not data:
        raise LogError(f"{path}: empty log")
    counts: dict[int, int] = defaultdict(int)
    off = 0
    while off < len(data):
        if len(data) - off < _HEADER.size:
            raise LogError(f"{path}: truncated: packet at byte {off} cut inside its header")
        sync, mgid, size = _HEADER.unpack_from(data, off)[:3]
        if sync != _SYNC:
            what = "not an LSF (IMC) log" if off == 0 else "corrupt"
            raise LogError(f"{path}: {what}: bad IMC sync 0x{sync:04X} at byte {off}")
        end = off + _HEADER.size + size + _FOOTER
        if end > len(data):
            raise LogError(
                f"{path}: truncated: packet at byte {off} needs {end - off} bytes, "
                f"only {len(data) - off} left"
            )
        counts[mgid] += 1
        off = end
    return path, data, counts


def _decode(path: Path, data: bytes, types: Iterable[type]) -> dict[type, list]:
    """Decode the messages of ``types`` (in file order) with imcpy, grouped by type."""
    out: dict[type, list] = defaultdict(list)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("error", "Invalid synchronization")  # imcpy would stop
            with LSFReader(data, use_index=False, save_index=False) as reader:
                for msg in reader.read_message(types=list(types)):
                    out[type(msg)].append(msg)
    except (RuntimeError, UserWarning) as exc:
        raise LogError(f"{path}: undecodable packet ({exc})") from exc
    return out


def _msg_type(msg_type: type | str) -> type:
    cls = getattr(imcpy, msg_type, None) if isinstance(msg_type, str) else msg_type
    if not (isinstance(cls, type) and issubclass(cls, imcpy.Message) and cls is not imcpy.Message):
        raise ValueError(f"not an imcpy message type: {msg_type!r}")
    return cls


def _missing(path: Path, cls: type, counts: dict[int, int]) -> LogError:
    present = ", ".join(sorted(imcpy.Factory.abbrev_from_id(i) for i in counts))
    return LogError(f"{path}: missing messages: no {cls.__name__} (log has: {present})")


def _plain(value: object) -> object:
    return int(value) if hasattr(value, "__members__") else value  # enums and bitfields


def _fields(obj: object, prefix: str = "") -> dict[str, object]:
    """Message fields as a flat dict: enums as int, inline messages as ``field.sub``."""
    row: dict[str, object] = {}
    for name, attr in type(obj).__dict__.items():
        if not isinstance(attr, property):
            continue
        value = getattr(obj, name)
        if value is None:  # unset inline message: its sub-fields stay missing
            continue
        if isinstance(value, imcpy.Message):
            row.update(_fields(value, f"{prefix}{name}."))
        else:
            row[prefix + name] = _plain(value)
    return row


def read_messages(path: str | Path, msg_type: type | str) -> pd.DataFrame:
    """All messages of one type as a DataFrame, sorted by time.

    Parameters
    ----------
    path : str or Path
        ``.lsf`` or ``.lsf.gz`` log.
    msg_type : imcpy message class or str
        E.g. ``imcpy.Reference`` or ``"Reference"``.

    Returns
    -------
    pandas.DataFrame
        Columns ``t`` (s, UNIX), ``src``, ``src_ent``, ``dst``, ``dst_ent`` and the message's
        fields as stored (rad, m, ...); enums as int, inline messages flattened to
        ``field.sub`` (e.g. ``speed.value``), message lists kept as Python lists.

    Raises
    ------
    LogError
        Unreadable log, or no message of that type in it.
    """
    cls = _msg_type(msg_type)
    path, data, counts = _load(path)
    msgs = _decode(path, data, [cls])[cls]
    if not msgs:
        raise _missing(path, cls, counts)
    head = ("src", "src_ent", "dst", "dst_ent")
    df = pd.DataFrame(
        [{"t": m.timestamp} | {k: getattr(m, k) for k in head} | _fields(m) for m in msgs]
    )
    return df.sort_values("t", kind="stable", ignore_index=True)


def _attrs(**columns: str) -> Callable[[imcpy.Message, Origin], dict]:
    """Stream columns taken from message attributes: ``column=attribute``."""
    return lambda m, o: {c: _plain(getattr(m, a)) for c, a in columns.items()}


def _by_id(prefix: str) -> Callable[[imcpy.Message, Origin], dict]:
    return lambda m, o: {f"{prefix}_{m.id}": m.value}


def _reference(m: imcpy.Reference, origin: Origin) -> dict:
    flags = int(m.flags)
    row: dict[str, float] = {"ref_flags": flags}
    if flags & _RF.LOCATION:
        row["ref_N"], row["ref_E"], _ = to_local(m.lat, m.lon, origin.height, origin)
    if flags & _RF.SPEED and m.speed is not None:
        row["ref_speed"], row["ref_speed_units"] = m.speed.value, int(m.speed.speed_units)
    if flags & _RF.Z and m.z is not None:
        row["ref_z"], row["ref_z_units"] = m.z.value, int(m.z.z_units)
    if flags & _RF.RADIUS:
        row["ref_radius"] = m.radius
    return row


# message -> (columns of one message, vehicle key: "src" of the sender or "dst" of a command)
_STREAMS: dict[type, tuple[Callable[[imcpy.Message, Origin], dict], str]] = {
    imcpy.SetThrusterActuation: (_by_id("thrust"), "src"),
    imcpy.SetServoPosition: (_by_id("fin_cmd"), "src"),
    imcpy.ServoPosition: (_by_id("fin"), "src"),
    imcpy.Rpm: (_attrs(rpm="value"), "src"),
    imcpy.DesiredSpeed: (_attrs(desired_speed="value", desired_speed_units="speed_units"), "src"),
    imcpy.DesiredHeading: (_attrs(desired_heading="value"), "src"),
    imcpy.DesiredZ: (_attrs(desired_z="value", desired_z_units="z_units"), "src"),
    imcpy.FollowRefState: (_attrs(followref_state="state", followref_proximity="proximity"), "src"),
    imcpy.Reference: (_reference, "dst"),
}
_ES_KEYS = ("timestamp", "src", "depth", "psi", "u", "v", "r", "vx", "vy")
_NAV_COLUMNS = ("t", "vehicle", "src", "N", "E", "depth", "lat", "lon", "psi", "u", "v", "r")
_NAV_COLUMNS += ("vx", "vy", "speed_over_ground")


def read_lsf(path: str | Path, origin: Origin | None = None) -> pd.DataFrame:
    """Tidy navigation + command table of a DUNE log, one row per EstimatedState.

    Parameters
    ----------
    path : str or Path
        ``.lsf`` or ``.lsf.gz`` log.
    origin : Origin, optional
        Local frame origin; by default the first EstimatedState's absolute position.

    Returns
    -------
    pandas.DataFrame
        Columns as listed in the module docstring, sorted by ``t``.

    Raises
    ------
    LogError
        Missing, empty, non-LSF, truncated or corrupt file, or no EstimatedState in it.
    """
    path, data, counts = _load(path)
    msgs = _decode(path, data, [imcpy.EstimatedState, imcpy.Announce, *_STREAMS])
    states = sorted(msgs[imcpy.EstimatedState], key=lambda m: m.timestamp)
    if not states:
        raise _missing(path, imcpy.EstimatedState, counts)
    names = {m.src: m.sys_name for m in msgs[imcpy.Announce]}
    absolute = np.array([absolute_latlon(m) for m in states])
    if origin is None:
        origin = Origin(*absolute[0])
    df = pd.DataFrame([{k: getattr(m, k) for k in _ES_KEYS} for m in states])
    df["t"] = df["timestamp"]
    df["vehicle"] = [names.get(s, f"0x{s:04X}") for s in df["src"]]
    df[["N", "E"]] = [to_local(*a, origin)[:2] for a in absolute]
    df["lat"], df["lon"] = np.degrees(absolute[:, 0]), np.degrees(absolute[:, 1])
    df["speed_over_ground"] = np.hypot(df["vx"], df["vy"])
    df = df[list(_NAV_COLUMNS)]
    for cls, (columns, key) in _STREAMS.items():
        df = _join(df, msgs[cls], columns, key, origin)
    return df


def _join(df: pd.DataFrame, msgs: list, columns: Callable, key: str, origin: Origin):
    """Join a command stream to ``df`` by the latest earlier message of the same vehicle."""
    if not msgs:
        return df
    rows = []
    for m in msgs:
        vid = getattr(m, key)
        for v in df["src"].unique() if vid == _BROADCAST else [vid]:
            rows.append({"t": m.timestamp, "src": v} | columns(m, origin))
    ints = {k for r in rows for k, v in r.items() if isinstance(v, int) and k != "src"}
    stream = pd.DataFrame(rows).sort_values("t", kind="stable", ignore_index=True)
    stream["src"] = stream["src"].astype(df["src"].dtype)
    merged = []
    for name in stream.columns.drop(["t", "src"]):  # one message may not carry every column
        part = stream[["t", "src", name]].copy()
        if key == "dst":  # Reference semantics: unset fields keep the previous value
            part[name] = part.groupby("src")[name].ffill()
        part = part.dropna(subset=[name]).astype({name: "Int64" if name in ints else float})
        merged.append(pd.merge_asof(df[["t", "src"]], part, on="t", by="src")[name])
    return pd.concat([df, *merged], axis=1)
