"""Geodesy: GeoPoint as WARA-PS sends it, a mission-local ENU frame, geodesic distances.

Distances are horizontal WGS84 geodesics (altitude ignored, docs/plan.md §2.1). Vectorised work
uses an East-North-Up frame around a mission origin; within 50 km its error is below 0.1 %.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import pymap3d
import pymap3d.vincenty
from pydantic import BaseModel, ConfigDict, Field

#: Mean Earth radius (m), used only for quick estimates, never for reported distances.
EARTH_RADIUS_M = 6_371_008.8


class GeoPoint(BaseModel):
    """A WGS84 position. Reads ``rostype`` or ``type`` markers and ignores other extra fields."""

    model_config = ConfigDict(extra="ignore", frozen=True)

    latitude: float = Field(ge=-90.0, le=90.0, allow_inf_nan=False)
    longitude: float = Field(ge=-180.0, le=180.0, allow_inf_nan=False)
    altitude: float = Field(default=0.0, allow_inf_nan=False)

    def to_wire(self) -> dict[str, Any]:
        """The seed's canonical form (keys sorted, ``rostype`` marker)."""
        return {
            "altitude": self.altitude,
            "latitude": self.latitude,
            "longitude": self.longitude,
            "rostype": "GeoPoint",
        }


def distance_m(a: GeoPoint, b: GeoPoint) -> float:
    """Horizontal geodesic distance in metres on the WGS84 ellipsoid."""
    if a.latitude == b.latitude and a.longitude == b.longitude:
        return 0.0
    dist, _ = pymap3d.vincenty.vdist(a.latitude, a.longitude, b.latitude, b.longitude)
    return float(dist)


def path_length_m(points: Sequence[GeoPoint]) -> float:
    """Geodesic length of a polyline."""
    return sum(distance_m(p, q) for p, q in itertools.pairwise(points))


#: WGS84 as pymap3d has it (``pymap3d.Ellipsoid.from_name("wgs84")``): semi-axes (m).
WGS84_A = 6_378_137.0
WGS84_B = 6_356_752.31424518
_B2_A2 = (WGS84_B / WGS84_A) ** 2  # 1 - e^2
_INV_A2 = 1.0 / WGS84_A**2
_INV_B2 = 1.0 / WGS84_B**2


def _is_scalar(x: Any) -> bool:
    """Python numbers (and NumPy's float64, a float) take the ``math`` path: NumPy's ufuncs cost
    about a microsecond each on a scalar; anything else (arrays, lists) takes NumPy's."""
    return isinstance(x, float | int)


def _beyond_horizon(frame: LocalFrame) -> str:
    return (f"east/north beyond the horizon of the frame at {frame.origin_lat}, "
            f"{frame.origin_lon}: no point of the ellipsoid is there")


class LocalFrame:
    """A mission-local East-North-Up frame (metres) around an origin; vectorised both ways.

    The conversions are done here, not by ``pymap3d``: its generic path cost ~0.3 ms for one point
    (a simulated unit converts its position on every status tick, issue 19). The origin's ECEF
    position and ENU axes are computed once per frame; ENU <-> ECEF is then a rotation, and
    ``to_geo`` solves for the surface point in closed form (a quadratic) instead of iterating
    ``enu2geodetic``. The formulas are pymap3d's (same ellipsoid, same geodetic -> ECEF), so the
    results agree with it to well below a millimetre (tests/test_geo_frame.py).
    """

    __slots__ = ("_east", "_north", "_o_d_u", "_origin_lat", "_origin_lon", "_ox", "_oy", "_oz",
                 "_u_d_u", "_up")

    def __init__(self, origin_lat: float, origin_lon: float) -> None:
        self._origin_lat = float(origin_lat)
        self._origin_lon = float(origin_lon)
        phi, lam = math.radians(self._origin_lat), math.radians(self._origin_lon)
        sp, cp, sl, cl = math.sin(phi), math.cos(phi), math.sin(lam), math.cos(lam)
        n0 = WGS84_A**2 / math.hypot(WGS84_A * cp, WGS84_B * sp)  # prime vertical radius
        self._ox, self._oy, self._oz = n0 * cp * cl, n0 * cp * sl, n0 * _B2_A2 * sp
        self._east = (-sl, cl, 0.0)
        self._north = (-sp * cl, -sp * sl, cp)
        self._up = (cp * cl, cp * sl, sp)
        # For the surface point along `up` (see `to_geo`): U'DU and O'DU with
        # D = diag(1/a^2, 1/a^2, 1/b^2); O'DU = n0/a^2 exactly, as O lies on the ellipsoid.
        self._u_d_u = cp * cp * _INV_A2 + sp * sp * _INV_B2
        self._o_d_u = n0 * _INV_A2

    @property
    def origin_lat(self) -> float:
        """The origin's latitude (degrees); read-only, as the frame's axes are derived from it."""
        return self._origin_lat

    @property
    def origin_lon(self) -> float:
        """The origin's longitude (degrees); read-only."""
        return self._origin_lon

    @classmethod
    def around(cls, points: Iterable[GeoPoint]) -> LocalFrame:
        """A frame centred on the bounding box of ``points`` (0, 0 for no points)."""
        pts = list(points)
        if not pts:
            return cls(0.0, 0.0)
        lats = [p.latitude for p in pts]
        lons = [p.longitude for p in pts]
        return cls((min(lats) + max(lats)) / 2.0, (min(lons) + max(lons)) / 2.0)

    def to_xy(self, lat: Any, lon: Any) -> tuple[np.ndarray, np.ndarray]:
        """East and north (m) of latitudes/longitudes (scalars or arrays) on the ellipsoid.

        As ``pymap3d.geodetic2enu(lat, lon, 0, origin_lat, origin_lon, 0)``: the points' ECEF
        positions less the origin's, rotated into the origin's east/north axes."""
        ex, ey, _ = self._east
        nx, ny, nz = self._north
        if _is_scalar(lat) and _is_scalar(lon):
            phi, lam = math.radians(lat), math.radians(lon)
            sp, cp = math.sin(phi), math.cos(phi)
            n = WGS84_A**2 / math.hypot(WGS84_A * cp, WGS84_B * sp)
            dx = n * cp * math.cos(lam) - self._ox
            dy = n * cp * math.sin(lam) - self._oy
            dz = n * _B2_A2 * sp - self._oz
            return (np.asarray(ex * dx + ey * dy),
                    np.asarray(nx * dx + ny * dy + nz * dz))
        phi = np.radians(np.asarray(lat, dtype=float))
        lam = np.radians(np.asarray(lon, dtype=float))
        sp, cp = np.sin(phi), np.cos(phi)
        n = WGS84_A**2 / np.hypot(WGS84_A * cp, WGS84_B * sp)
        dx = n * cp * np.cos(lam) - self._ox
        dy = n * cp * np.sin(lam) - self._oy
        dz = n * _B2_A2 * sp - self._oz
        return (np.asarray(ex * dx + ey * dy, dtype=float),
                np.asarray(nx * dx + ny * dy + nz * dz, dtype=float))

    def point_xy(self, p: GeoPoint) -> tuple[float, float]:
        """East/north of one point."""
        e, n = self.to_xy(p.latitude, p.longitude)
        return float(e), float(n)

    def points_xy(self, points: Sequence[GeoPoint]) -> np.ndarray:
        """An (N, 2) array of east/north for ``points``."""
        if not points:
            return np.zeros((0, 2))
        e, n = self.to_xy([p.latitude for p in points], [p.longitude for p in points])
        return np.column_stack([np.atleast_1d(e), np.atleast_1d(n)])

    def to_geo(self, east: Any, north: Any) -> tuple[np.ndarray, np.ndarray]:
        """Latitudes/longitudes of the surface points whose east/north are given.

        The inverse of ``to_xy``: that drops the (negative) up component of surface points, so
        the point at up = 0 lies above the surface, and its latitude/longitude would be off by
        about a metre at 40 km. The point ``O + e E + n N + u U`` (origin O, axes E, N, U) is on
        the ellipsoid ``P'DP = 1`` (D = diag(1/a^2, 1/a^2, 1/b^2)) where
        ``(U'DU) u^2 + 2 (O'DU + d'DU) u + d'Dd = 0`` with ``d = e E + n N`` (``O'Dd = 0``: E and N
        are tangent at O): the root near 0, in the form without cancellation. On the surface,
        the geodetic latitude is ``atan2(z, (1 - e^2) p)`` exactly (the normal is ``DP``).
        Beyond the horizon (about 6,400 km from the origin) no surface point has the given
        east/north: a ValueError (pymap3d's steps returned some point there, hundreds of km off).
        """
        ex, ey, _ = self._east
        nx, ny, nz = self._north
        ux, uy, uz = self._up
        if _is_scalar(east) and _is_scalar(north):
            dx, dy, dz = ex * east + nx * north, ey * east + ny * north, nz * north
            c = (dx * dx + dy * dy) * _INV_A2 + dz * dz * _INV_B2
            b = self._o_d_u + (dx * ux + dy * uy) * _INV_A2 + dz * uz * _INV_B2
            disc = b * b - self._u_d_u * c
            if disc < 0.0:
                raise ValueError(_beyond_horizon(self))
            u = -c / (b + math.sqrt(disc))
            x, y, z = self._ox + dx + u * ux, self._oy + dy + u * uy, self._oz + dz + u * uz
            return (np.asarray(math.degrees(math.atan2(z, _B2_A2 * math.hypot(x, y)))),
                    np.asarray(math.degrees(math.atan2(y, x))))
        e = np.asarray(east, dtype=float)
        n = np.asarray(north, dtype=float)
        dx, dy, dz = ex * e + nx * n, ey * e + ny * n, nz * n
        c = (dx * dx + dy * dy) * _INV_A2 + dz * dz * _INV_B2
        b = self._o_d_u + (dx * ux + dy * uy) * _INV_A2 + dz * uz * _INV_B2
        disc = b * b - self._u_d_u * c
        if np.any(disc < 0.0):  # NaN inputs compare False: NaN out, as before
            raise ValueError(_beyond_horizon(self))
        u = -c / (b + np.sqrt(disc))
        x, y, z = self._ox + dx + u * ux, self._oy + dy + u * uy, self._oz + dz + u * uz
        return (np.asarray(np.degrees(np.arctan2(z, _B2_A2 * np.hypot(x, y))), dtype=float),
                np.asarray(np.degrees(np.arctan2(y, x)), dtype=float))

    def geopoint(self, east: float, north: float, altitude: float = 0.0) -> GeoPoint:
        """The GeoPoint at east/north (m) in this frame."""
        lat, lon = self.to_geo(east, north)
        return GeoPoint(latitude=float(lat), longitude=float(lon), altitude=altitude)


def pairwise_xy_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distances (m) between rows of (N, 2) ``a`` and (M, 2) ``b``: an (N, M) array."""
    diff = a[:, None, :] - b[None, :, :]
    return np.asarray(np.hypot(diff[..., 0], diff[..., 1]))


def great_circle_matrix_m(a: Sequence[GeoPoint], b: Sequence[GeoPoint]) -> np.ndarray:
    """Spherical (haversine) distances (m) between every point of ``a`` and of ``b``: an
    (len(a), len(b)) array, vectorised. Within 0.5 % of the geodesic: for plausibility checks
    ("thousands of km away"), where a Vincenty call per pair cost tens of ms per mission."""
    la = np.radians(np.array([[p.latitude, p.longitude] for p in a], dtype=float).reshape(-1, 2))
    lb = np.radians(np.array([[p.latitude, p.longitude] for p in b], dtype=float).reshape(-1, 2))
    p1, p2 = la[:, None, 0], lb[None, :, 0]
    dp, dl = p2 - p1, lb[None, :, 1] - la[:, None, 1]
    h = np.sin(dp / 2) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dl / 2) ** 2
    return np.asarray(2 * EARTH_RADIUS_M * np.arcsin(np.minimum(1.0, np.sqrt(h))))


def haversine_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Spherical distance; a cheap cross-check for tests, not used for plans."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp, dl = p2 - p1, math.radians(lon2 - lon1)
    h = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * EARTH_RADIUS_M * math.asin(min(1.0, math.sqrt(h)))
