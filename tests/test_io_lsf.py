"""Tests of mpcasv.io.lsf / mpcasv.io.geo on the shared DUNE log and on crafted logs."""

from __future__ import annotations

import gzip
import math
import struct
from pathlib import Path

import imcpy
import numpy as np
import pytest
from imcpy.coordinates import WGS84

from mpcasv.io.geo import Origin, absolute_latlon, to_local, to_wgs84
from mpcasv.io.lsf import LogError, read_lsf, read_messages

SHARED_LOG = next((d / "dune-lauv-followref.lsf.gz" for d in (
    Path(__file__).resolve().parents[2] / "shared" / "data", Path("/work/shared/data"))
    if (d / "dune-lauv-followref.lsf.gz").is_file()),
    Path(__file__).resolve().parents[2] / "shared" / "data" / "dune-lauv-followref.lsf.gz")
ORIGIN = Origin.from_degrees(41.185, -8.7062, 10.0)
T0 = 1.7e9


def _stamp(msg: imcpy.Message, t: float, src: int = 0x00D1) -> imcpy.Message:
    msg.timestamp, msg.src, msg.src_ent, msg.dst, msg.dst_ent = t, src, 1, 0xFFFF, 0xFF
    return msg


def _estate(t: float, lat: float, lon: float, x: float, y: float) -> imcpy.EstimatedState:
    es = _stamp(imcpy.EstimatedState(), t)
    es.lat, es.lon, es.height, es.x, es.y, es.z = lat, lon, 0.0, x, y, 0.0
    es.vx, es.vy, es.u, es.psi = 1.0, 0.5, 1.1, math.atan2(0.5, 1.0)
    return es


def _write(path: Path, msgs: list[imcpy.Message]) -> Path:
    path.write_bytes(b"".join(m.serialize() for m in msgs))
    return path


def _boundaries(data: bytes, count: int) -> list[int]:
    """Byte offsets of the first ``count`` packets (20-byte header, size at byte 4, 2-byte CRC)."""
    offsets, off = [], 0
    for _ in range(count):
        offsets.append(off)
        off += 22 + struct.unpack_from("<H", data, off + 4)[0]
    return offsets


@pytest.fixture(scope="module")
def shared_df():
    if not SHARED_LOG.is_file():
        pytest.skip(f"shared DUNE log not found at {SHARED_LOG}")
    return read_lsf(SHARED_LOG)


@pytest.fixture(scope="module")
def raw_log() -> bytes:
    if not SHARED_LOG.is_file():
        pytest.skip(f"shared DUNE log not found at {SHARED_LOG}")
    return gzip.decompress(SHARED_LOG.read_bytes())


# --- the real DUNE log ---------------------------------------------------------------------


def test_shared_log_tidy_table(shared_df):
    df = shared_df
    nav = ["t", "vehicle", "src", "N", "E", "depth", "lat", "lon", "psi", "u", "v", "r"]
    assert list(df.columns[:15]) == [*nav, "vx", "vy", "speed_over_ground"]
    assert len(df) > 100
    assert df["t"].is_monotonic_increasing and df["t"].iloc[0] > 1.5e9
    assert set(df["vehicle"]) == {"lauv-simulator-1"} and set(df["src"]) == {0x00D1}
    assert df[["N", "E"]].iloc[0].abs().max() < 1e-6  # default origin: first position
    assert df[["N", "E"]].abs().max().max() < 5000.0
    assert df["speed_over_ground"].between(0.0, 5.0).all() and df["u"].abs().max() < 5.0
    assert df["psi"].between(-math.pi, math.pi).all()
    assert df["depth"].between(-1.0, 100.0).all()
    assert df["lat"].between(-90, 90).all() and df["lon"].between(-180, 180).all()
    # positions agree with the integrated NED velocities (DUNE's navigation also applies ~1 Hz
    # GPS corrections of ~0.15 m at the surface: the track runs ~8 % ahead of the integral)
    for pos, vel in (("N", "vx"), ("E", "vy")):
        travelled = df[pos].iloc[-1] - df[pos].iloc[0]
        assert travelled == pytest.approx(np.trapezoid(df[vel], df["t"]), rel=0.15)


def test_shared_log_commands(shared_df):
    df = shared_df
    for col in ("thrust_0", "fin_cmd_0", "fin_0", "desired_heading", "ref_N", "ref_speed"):
        assert df[col].notna().any(), col
    assert df["thrust_0"].dropna().between(-1.0, 1.0).all()
    assert df["thrust_0"].max() > 0.1
    assert df["ref_speed"].dropna().eq(1.5).all()
    assert df["ref_flags"].dropna().eq(0x07).all()  # LOCATION | SPEED | Z
    # the reference point lies ahead of the vehicle's heading
    bearing = math.atan2(df["ref_E"].iloc[-1], df["ref_N"].iloc[-1])
    assert abs(bearing - df["psi"].iloc[-1]) < 0.2


def test_shared_log_plain_lsf_and_origin(shared_df, raw_log, tmp_path):
    plain = tmp_path / "Data.lsf"
    plain.write_bytes(raw_log)
    first = Origin(math.radians(shared_df["lat"][0]), math.radians(shared_df["lon"][0]))
    moved = Origin(*to_wgs84(100.0, -50.0, first))
    df = read_lsf(plain, origin=moved)
    assert np.allclose(df["N"], shared_df["N"] - 100.0, atol=0.02)
    assert np.allclose(df["E"], shared_df["E"] + 50.0, atol=0.02)
    assert not list(tmp_path.glob("*.imcpy_idx"))  # imcpy's index side file is not written


def test_read_messages(raw_log, tmp_path):
    path = tmp_path / "Data.lsf"
    path.write_bytes(raw_log)
    refs = read_messages(path, "Reference")
    assert refs.equals(read_messages(path, imcpy.Reference))
    assert set(refs["dst"]) == {0x00D1} and refs["t"].is_monotonic_increasing
    assert refs["speed.value"].eq(1.5).all() and refs["z.z_units"].eq(1).all()
    with pytest.raises(LogError, match="missing messages: no GpsFixRejection"):
        read_messages(path, "GpsFixRejection")
    with pytest.raises(ValueError, match="not an imcpy message type"):
        read_messages(path, "NoSuchMessage")


# --- geodesy ---------------------------------------------------------------------------------


@pytest.mark.parametrize("north, east", [(0.0, 0.0), (57.3, 28.7), (-1500.0, 800.0), (9e3, -7e3)])
def test_origin_round_trip(north, east):
    lat, lon = to_wgs84(north, east, ORIGIN)
    n, e, _ = to_local(lat, lon, ORIGIN.height, ORIGIN)
    assert math.hypot(n - north, e - east) < 1e-3
    lat2, lon2 = to_wgs84(n, e, ORIGIN)
    assert math.hypot((lat2 - lat) * 6.4e6, (lon2 - lon) * 6.4e6) < 1e-3


def test_origin_units():
    assert Origin.from_degrees(41.0, -8.0).lat == pytest.approx(math.radians(41.0))
    with pytest.raises(ValueError, match="radians"):
        Origin(41.185, -8.7062)
    with pytest.raises(AttributeError):
        ORIGIN.lat = 0.0  # frozen


def test_moved_reference_point_gives_continuous_track(tmp_path):
    """DUNE re-anchors lat/lon and shifts x/y: the absolute track must not jump."""
    anchor_b = WGS84.displace(ORIGIN.lat, ORIGIN.lon, 1000.0, 400.0)
    msgs = []
    for k in range(10):
        n, e = 990.0 + 2.0 * k, 390.0 + 1.0 * k  # true positions relative to ORIGIN
        if k < 5:
            msgs.append(_estate(T0 + k, ORIGIN.lat, ORIGIN.lon, n, e))
        else:  # compensating offsets from the new reference point
            lat, lon = WGS84.displace(ORIGIN.lat, ORIGIN.lon, n, e)
            x, y, _ = WGS84.displacement(*anchor_b, 0.0, lat, lon, 0.0)
            msgs.append(_estate(T0 + k, *anchor_b, x, y))
    assert abs(msgs[5].x - msgs[4].x) > 900.0  # raw offsets jump
    fields = {k: getattr(msgs[7], k) for k in ("lat", "lon", "height", "x", "y", "z")}
    assert absolute_latlon(fields) == absolute_latlon(msgs[7])

    df = read_lsf(_write(tmp_path / "moved.lsf", msgs), origin=Origin(ORIGIN.lat, ORIGIN.lon))
    steps = np.diff(df[["N", "E"]].to_numpy(), axis=0)
    assert np.allclose(steps, [2.0, 1.0], atol=0.02)
    assert df["N"].iloc[-1] == pytest.approx(1008.0, abs=0.05)
    assert set(df["vehicle"]) == {"0x00D1"}  # no Announce in this log: hex IMC id


# --- bad logs ----------------------------------------------------------------------------------


def _raises(path: Path, match: str) -> LogError:
    with pytest.raises(LogError, match=match) as info:
        read_lsf(path)
    assert path.name in str(info.value)
    return info.value


def test_nonexistent_file(tmp_path):
    _raises(tmp_path / "nope.lsf.gz", "no such log file")


@pytest.mark.parametrize(
    "name, content, match",
    [
        ("empty.lsf", b"", "empty log"),
        ("text.lsf", b"time,lat,lon\n0,41.1,-8.7\n" * 20, "not an LSF"),
        ("random.lsf", np.random.default_rng(1).bytes(4096), "not an LSF"),
        ("plain.lsf.gz", b"not compressed at all", "not gzip"),
        ("empty_gz.lsf.gz", gzip.compress(b"", mtime=0), "empty log"),
    ],
)
def test_not_a_log(tmp_path, name, content, match):
    path = tmp_path / name
    path.write_bytes(content)
    _raises(path, match)


@pytest.mark.parametrize("inside", [7, 31], ids=["cut-in-header", "cut-in-body"])
def test_truncated_log(raw_log, tmp_path, inside):
    cut = _boundaries(raw_log, 2000)[-1] + inside
    path = tmp_path / "truncated.lsf"
    path.write_bytes(raw_log[:cut])
    _raises(path, f"truncated: packet at byte {cut - inside}")


def test_truncated_gzip(tmp_path):
    if not SHARED_LOG.is_file():
        pytest.skip(f"shared DUNE log not found at {SHARED_LOG}")
    data = SHARED_LOG.read_bytes()
    path = tmp_path / "Data.lsf.gz"
    path.write_bytes(data[: len(data) // 2])
    _raises(path, "truncated gzip")


def test_corrupt_log(raw_log, tmp_path):
    offsets = _boundaries(raw_log, 3000)
    path = tmp_path / "garbage.lsf"
    path.write_bytes(raw_log[: offsets[-1]] + b"\x00" * 40 + raw_log[offsets[-1] :])
    _raises(path, f"corrupt: bad IMC sync 0x0000 at byte {offsets[-1]}")

    es_id = imcpy.Factory.id_from_abbrev("EstimatedState")
    pos = next(o for o in offsets if struct.unpack_from("<H", raw_log, o + 2)[0] == es_id)
    flipped = bytearray(raw_log)
    flipped[pos + 30] ^= 0xFF  # payload byte: framing intact, CRC wrong
    path = tmp_path / "badcrc.lsf"
    path.write_bytes(bytes(flipped))
    _raises(path, "undecodable packet .*CRC")


def test_log_without_estimated_state(tmp_path):
    announce = _stamp(imcpy.Announce(), T0)
    announce.sys_name, announce.services = "lauv-x", "imc+udp://127.0.0.1:6002/"
    ref = _stamp(imcpy.Reference(), T0 + 1, src=0x4001)
    ref.flags, ref.lat, ref.lon = imcpy.Reference.FlagsBits.LOCATION, ORIGIN.lat, ORIGIN.lon
    path = _write(tmp_path / "no_state.lsf", [announce, _stamp(imcpy.Heartbeat(), T0 + 2), ref])
    err = _raises(path, "missing messages: no EstimatedState")
    assert "Announce, Heartbeat, Reference" in str(err)
