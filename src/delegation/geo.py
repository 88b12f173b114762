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


class LocalFrame:
    """A mission-local East-North-Up frame (metres) around an origin; vectorised both ways."""

    def __init__(self, origin_lat: float, origin_lon: float) -> None:
        self.origin_lat = float(origin_lat)
        self.origin_lon = float(origin_lon)

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
        """East and north (m) of latitudes/longitudes (scalars or arrays) on the ellipsoid."""
        e, n, _ = pymap3d.geodetic2enu(
            np.asarray(lat, dtype=float),
            np.asarray(lon, dtype=float),
            0.0,
            self.origin_lat,
            self.origin_lon,
            0.0,
        )
        return np.asarray(e, dtype=float), np.asarray(n, dtype=float)

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
        about a metre at 40 km. A few fixed-point steps find the up value that puts the point on
        the ellipsoid (each step shrinks the height by a factor of ~(d/R)^2).
        """
        e = np.asarray(east, dtype=float)
        n = np.asarray(north, dtype=float)
        up = -(e**2 + n**2) / (2.0 * EARTH_RADIUS_M)  # the sphere's drop: a good first guess
        for _ in range(3):
            lat, lon, height = pymap3d.enu2geodetic(
                e, n, up, self.origin_lat, self.origin_lon, 0.0
            )
            up = up - np.asarray(height, dtype=float)
        return np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)

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
