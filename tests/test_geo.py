"""Geodesy against independent numbers: published geodesic examples, the ellipsoid's own
formulas integrated here, and a spherical haversine; the ENU frame round trip and its accuracy."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from pydantic import ValidationError

from delegation.geo import (
    EARTH_RADIUS_M,
    GeoPoint,
    LocalFrame,
    distance_m,
    haversine_m,
    pairwise_xy_distances,
    path_length_m,
)

WGS84_A = 6_378_137.0
WGS84_F = 1 / 298.257223563
WGS84_E2 = WGS84_F * (2 - WGS84_F)


def P(lat: float, lon: float, alt: float = 0.0) -> GeoPoint:
    return GeoPoint(latitude=lat, longitude=lon, altitude=alt)


def dms(deg: int, minutes: int, seconds: float) -> float:
    sign = -1.0 if deg < 0 else 1.0
    return sign * (abs(deg) + minutes / 60 + seconds / 3600)


def meridian_arc(lat1: float, lat2: float) -> float:
    """Meridian arc length (m) between two latitudes: the ellipsoid's integral, done here."""
    phi = np.linspace(math.radians(lat1), math.radians(lat2), 20_001)
    m = WGS84_A * (1 - WGS84_E2) / (1 - WGS84_E2 * np.sin(phi) ** 2) ** 1.5
    return float(np.sum((m[1:] + m[:-1]) / 2 * np.diff(phi)))


def test_vincenty_published_example() -> None:
    # Flinders Peak -> Buninyong, Vincenty (1975) as worked by Geoscience Australia: 54 972.271 m.
    flinders = P(dms(-37, 57, 3.72030), dms(144, 25, 29.52440))
    buninyong = P(dms(-37, 39, 10.15610), dms(143, 55, 35.38390))
    assert distance_m(flinders, buninyong) == pytest.approx(54_972.271, abs=0.01)
    assert distance_m(buninyong, flinders) == pytest.approx(54_972.271, abs=0.01)


def test_one_degree_along_the_equator() -> None:
    # The equator is a geodesic: one degree is a * pi / 180.
    assert distance_m(P(0, 0), P(0, 1)) == pytest.approx(WGS84_A * math.pi / 180, abs=1e-3)


@pytest.mark.parametrize(("lat1", "lat2"), [(0.0, 1.0), (57.76, 57.77), (-45.0, -44.0)])
def test_along_a_meridian(lat1: float, lat2: float) -> None:
    assert distance_m(P(lat1, 16.68), P(lat2, 16.68)) == pytest.approx(
        meridian_arc(lat1, lat2), abs=1e-3
    )


def test_zero_and_symmetry() -> None:
    a, b = P(57.7605, 16.6815, 40.0), P(57.7611, 16.6805, 0.0)
    assert distance_m(a, a) == 0.0
    assert distance_m(a, b) == pytest.approx(distance_m(b, a), abs=1e-6)
    # Altitude is ignored (docs/plan.md §2.1).
    assert distance_m(a, b) == distance_m(P(57.7605, 16.6815), b)


def test_across_the_date_line() -> None:
    expected = haversine_m(10.0, 179.9, 10.0, -179.9)
    assert distance_m(P(10.0, 179.9), P(10.0, -179.9)) == pytest.approx(expected, rel=5e-3)
    assert distance_m(P(10.0, 179.9), P(10.0, -179.9)) < 30_000


def test_haversine_itself() -> None:
    assert haversine_m(0.0, 0.0, 1.0, 0.0) == pytest.approx(EARTH_RADIUS_M * math.pi / 180)
    assert haversine_m(0.0, 0.0, 0.0, 90.0) == pytest.approx(EARTH_RADIUS_M * math.pi / 2)


@pytest.mark.parametrize("lat", [-70.0, -30.0, 0.0, 10.0, 35.0, 57.76, 80.0])
@pytest.mark.parametrize("dist_deg", [1e-4, 0.01, 0.3, 5.0])
@pytest.mark.parametrize("bearing", [0.0, 45.0, 90.0, 200.0])
def test_geodesic_close_to_haversine(lat: float, dist_deg: float, bearing: float) -> None:
    """Within 0.5 % of a sphere of mean radius, except north-south near the equator where the
    ellipsoid's meridian radius is up to 0.56 % below the mean radius (so 0.6 % there)."""
    lat2 = lat + dist_deg * math.cos(math.radians(bearing))
    lon2 = 16.0 + dist_deg * math.sin(math.radians(bearing)) / math.cos(math.radians(lat))
    geodesic = distance_m(P(lat, 16.0), P(lat2, lon2))
    tolerance = 5e-3 if abs(lat) >= 20.0 or bearing == 90.0 else 6e-3
    assert geodesic == pytest.approx(haversine_m(lat, 16.0, lat2, lon2), rel=tolerance)


def test_the_largest_sphere_error_is_north_south_at_the_equator() -> None:
    ratio = distance_m(P(-0.5, 0.0), P(0.5, 0.0)) / haversine_m(-0.5, 0.0, 0.5, 0.0)
    assert ratio == pytest.approx(meridian_arc(-0.5, 0.5) / (EARTH_RADIUS_M * math.radians(1.0)))
    assert 0.994 < ratio < 0.995


def test_path_length_is_the_sum_of_legs() -> None:
    pts = [P(57.7605, 16.6815), P(57.7611, 16.6805), P(57.7620, 16.6790), P(57.7605, 16.6815)]
    legs = [distance_m(a, b) for a, b in itertools.pairwise(pts)]
    assert path_length_m(pts) == pytest.approx(sum(legs))
    assert path_length_m(pts[:1]) == 0.0
    assert path_length_m([]) == 0.0


# --------------------------------------------------------------------------- ENU frame


def test_enu_origin_and_axes() -> None:
    frame = LocalFrame(57.76, 16.68)
    assert frame.point_xy(P(57.76, 16.68)) == pytest.approx((0.0, 0.0), abs=1e-6)
    east, north = frame.point_xy(P(57.77, 16.68))
    assert east == pytest.approx(0.0, abs=1e-6)
    assert north == pytest.approx(meridian_arc(57.76, 57.77), abs=0.01)
    east, north = frame.point_xy(P(57.76, 16.69))
    assert east > 0
    # A small step east along the parallel: radius of the parallel times the angle.
    n = WGS84_A / math.sqrt(1 - WGS84_E2 * math.sin(math.radians(57.76)) ** 2)
    assert east == pytest.approx(n * math.cos(math.radians(57.76)) * math.radians(0.01), rel=1e-6)


def test_enu_round_trip() -> None:
    frame = LocalFrame(57.76, 16.68)
    rng = np.random.default_rng(7)
    lat = 57.76 + rng.uniform(-0.4, 0.4, 500)
    lon = 16.68 + rng.uniform(-0.8, 0.8, 500)
    east, north = frame.to_xy(lat, lon)
    lat2, lon2 = frame.to_geo(east, north)
    assert np.max(np.abs(lat2 - lat)) < 1e-9
    assert np.max(np.abs(lon2 - lon)) < 1e-9
    back = frame.geopoint(1234.5, -678.9, altitude=40.0)
    assert frame.point_xy(back) == pytest.approx((1234.5, -678.9), abs=1e-6)
    assert back.altitude == 40.0


def test_enu_distances_within_a_tenth_of_a_percent_within_50_km() -> None:
    frame = LocalFrame(57.76, 16.68)
    rng = np.random.default_rng(11)
    pts = [P(57.76 + a, 16.68 + b) for a, b in rng.uniform(-0.3, 0.3, (40, 2))]
    xy = frame.points_xy(pts)
    assert xy.shape == (40, 2)
    assert np.max(np.hypot(xy[:, 0], xy[:, 1])) < 50_000
    flat = pairwise_xy_distances(xy, xy)
    for i in range(0, 40, 3):
        for j in range(1, 40, 4):
            if i != j:
                assert flat[i, j] == pytest.approx(distance_m(pts[i], pts[j]), rel=1e-3)


def test_frame_around_and_empty_inputs() -> None:
    frame = LocalFrame.around([P(57.0, 16.0), P(58.0, 17.0), P(57.5, 16.2)])
    assert (frame.origin_lat, frame.origin_lon) == (57.5, 16.5)
    assert (LocalFrame.around([]).origin_lat, LocalFrame.around([]).origin_lon) == (0.0, 0.0)
    assert frame.points_xy([]).shape == (0, 2)


def test_pairwise_distances_match_hypot() -> None:
    a = np.array([[0.0, 0.0], [3.0, 4.0]])
    b = np.array([[0.0, 0.0], [6.0, 8.0], [-3.0, 0.0]])
    assert pairwise_xy_distances(a, b) == pytest.approx(
        np.array([[0.0, 10.0, 3.0], [5.0, 5.0, math.hypot(6.0, 4.0)]])
    )


# --------------------------------------------------------------------------- GeoPoint


@pytest.mark.parametrize("marker", [{"rostype": "GeoPoint"}, {"type": "GeoPoint"}, {}])
def test_geopoint_reads_either_marker(marker: dict[str, str]) -> None:
    p = GeoPoint.model_validate({"latitude": 57.0, "longitude": 16.0, **marker})
    assert (p.latitude, p.longitude, p.altitude) == (57.0, 16.0, 0.0)
    assert p.to_wire() == {
        "altitude": 0.0,
        "latitude": 57.0,
        "longitude": 16.0,
        "rostype": "GeoPoint",
    }


@pytest.mark.parametrize(
    ("lat", "lon"),
    [
        (90.01, 0.0),
        (-90.01, 0.0),
        (0.0, 180.01),
        (0.0, -180.01),
        (float("nan"), 0.0),
        (0.0, float("inf")),
    ],
)
def test_geopoint_rejects_out_of_range(lat: float, lon: float) -> None:
    with pytest.raises(ValidationError):
        GeoPoint(latitude=lat, longitude=lon)
