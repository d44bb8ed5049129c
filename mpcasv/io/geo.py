"""WGS-84 <-> local NED conversions around an origin, through imcpy's (DUNE's) geodesy.

Latitudes and longitudes are in radians, heights in metres above the WGS-84 ellipsoid and local
coordinates in metres North/East/Down of an :class:`Origin`.

Notes
-----
DUNE's ``WGS84::displace`` (lat/lon + N/E -> lat/lon) and ``WGS84::displacement`` (ECEF NED
between two points) are not exact inverses of each other (about 6 mm per km), and the height
that ``toWGS84`` returns for an EstimatedState drifts by about 3 mm per metre of north offset
(DUNE rotates with the geocentric latitude). :func:`to_wgs84` therefore refines ``displace``
with a few Newton steps on ``displacement`` so that it inverts :func:`to_local` to well below a
millimetre, and vertical positions should come from EstimatedState ``depth``, not heights.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import imcpy
from imcpy.coordinates import WGS84, toWGS84

__all__ = ["Origin", "absolute_latlon", "to_local", "to_wgs84"]

_TOL_M = 1e-6  # convergence of the to_wgs84 refinement (m)
_MAX_ITER = 10


@dataclass(frozen=True)
class Origin:
    """Origin of a local NED frame.

    Parameters
    ----------
    lat, lon : float
        WGS-84 latitude and longitude (rad).
    height : float, default 0.0
        Height above the WGS-84 ellipsoid (m).
    """

    lat: float
    lon: float
    height: float = 0.0

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (self.lat, self.lon, self.height)):
            raise ValueError(f"Origin must be finite, got {self}")
        if abs(self.lat) > math.pi / 2 or abs(self.lon) > 2 * math.pi:
            raise ValueError(f"Origin lat/lon must be in radians (use Origin.from_degrees): {self}")

    @classmethod
    def from_degrees(cls, lat_deg: float, lon_deg: float, height: float = 0.0) -> Origin:
        """Build an origin from latitude/longitude in degrees and height in metres."""
        return cls(math.radians(lat_deg), math.radians(lon_deg), float(height))


_ES_FIELDS = ("lat", "lon", "height", "x", "y", "z")


def absolute_latlon(msg_or_fields: imcpy.EstimatedState | Mapping[str, Any]) -> tuple[float, ...]:
    """Absolute position of an EstimatedState: its reference point displaced by x/y/z.

    Parameters
    ----------
    msg_or_fields : imcpy.EstimatedState or mapping
        The message, or a mapping (dict, pandas row) with ``lat``, ``lon`` (rad), ``height``,
        ``x``, ``y``, ``z`` (m).

    Returns
    -------
    lat, lon, height : float
        Absolute WGS-84 position (rad, rad, m), as DUNE's ``Coordinates::toWGS84`` computes it.
    """
    if isinstance(msg_or_fields, imcpy.EstimatedState):
        msg = msg_or_fields
    else:
        missing = [k for k in _ES_FIELDS if k not in msg_or_fields]
        if missing:
            raise KeyError(f"EstimatedState fields missing: {missing}")
        msg = imcpy.EstimatedState()
        for k in _ES_FIELDS:
            setattr(msg, k, float(msg_or_fields[k]))
    return tuple(float(v) for v in toWGS84(msg))


def to_local(lat: float, lon: float, height: float, origin: Origin) -> tuple[float, float, float]:
    """NED displacement (m) of a WGS-84 point (rad, rad, m) from ``origin``."""
    n, e, d = WGS84.displacement(origin.lat, origin.lon, origin.height, lat, lon, height)
    return float(n), float(e), float(d)


def to_wgs84(
    north: float, east: float, origin: Origin, height: float | None = None
) -> tuple[float, float]:
    """Latitude and longitude (rad) of the point ``north``/``east`` metres from ``origin``.

    Parameters
    ----------
    north, east : float
        Local coordinates (m).
    origin : Origin
        Frame origin.
    height : float, optional
        Ellipsoidal height of the point (m), ``origin.height`` by default. It only matters at
        the sub-millimetre level, for exact agreement with :func:`to_local`.

    Returns
    -------
    lat, lon : float
        The point such that ``to_local(lat, lon, height, origin)[:2] == (north, east)``.
    """
    h = origin.height if height is None else height
    lat, lon = WGS84.displace(origin.lat, origin.lon, north, east)
    for _ in range(_MAX_ITER):
        n, e, _d = WGS84.displacement(origin.lat, origin.lon, origin.height, lat, lon, h)
        dn, de = north - n, east - e
        if math.hypot(dn, de) < _TOL_M:
            return float(lat), float(lon)
        lat, lon = WGS84.displace(lat, lon, dn, de)
    raise ArithmeticError(f"to_wgs84 did not converge for N={north}, E={east} around {origin}")
