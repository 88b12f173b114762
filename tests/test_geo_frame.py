"""`LocalFrame`'s own conversions against pymap3d called as the frame called it before issue 19
(``geodetic2enu``; three fixed-point ``enu2geodetic`` steps to the surface): within 1e-9 degrees
and 1 mm, for points within 100 km of origins at every latitude in (-85, 85) and every longitude
(across the date line too), one point at a time (the ``math`` path) and as arrays (NumPy's)."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from delegation.geo import EARTH_RADIUS_M, LocalFrame

SETTINGS = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
DEG = 1e-9  # degrees
MM = 1e-3  # metres

origins = st.tuples(
    st.floats(min_value=-85.0, max_value=85.0, exclude_min=True, exclude_max=True),
    st.floats(min_value=-180.0, max_value=180.0),
)
# A point within 100 km: distance (m) and bearing (radians) from the origin, as east/north.
offsets = st.tuples(st.floats(min_value=0.0, max_value=100_000.0),
                    st.floats(min_value=0.0, max_value=2 * math.pi))


def en(offset: tuple[float, float]) -> tuple[float, float]:
    r, bearing = offset
    return r * math.sin(bearing), r * math.cos(bearing)


def pymap3d_to_geo(lat0: float, lon0: float, east: object, north: object
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The frame's ``to_geo`` before issue 19, verbatim but for the frame."""
    e = np.asarray(east, dtype=float)
    n = np.asarray(north, dtype=float)
    up = -(e**2 + n**2) / (2.0 * EARTH_RADIUS_M)
    for _ in range(3):
        lat, lon, height = pymap3d.enu2geodetic(e, n, up, lat0, lon0, 0.0)
        up = up - np.asarray(height, dtype=float)
    return np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)


def pymap3d_to_xy(lat0: float, lon0: float, lat: object, lon: object
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The frame's ``to_xy`` before issue 19."""
    e, n, _ = pymap3d.geodetic2enu(np.asarray(lat, dtype=float), np.asarray(lon, dtype=float),
                                   0.0, lat0, lon0, 0.0)
    return np.asarray(e, dtype=float), np.asarray(n, dtype=float)


def lon_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Longitude differences (degrees), 180 and -180 being the same meridian."""
    return np.asarray(np.abs((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0))


def check_point(origin: tuple[float, float], east: float, north: float) -> None:
    frame = LocalFrame(*origin)
    lat, lon = frame.to_geo(east, north)
    ref_lat, ref_lon = pymap3d_to_geo(*origin, east, north)
    assert isinstance(lat, np.ndarray) and lat.shape == () and lon.shape == ()
    assert abs(float(lat) - float(ref_lat)) <= DEG
    assert float(lon_diff(lon, ref_lon)) <= DEG
    # to_xy of the reference's point: pymap3d's east/north, and the given ones (a round trip).
    x, y = frame.to_xy(float(ref_lat), float(ref_lon))
    ref_x, ref_y = pymap3d_to_xy(*origin, float(ref_lat), float(ref_lon))
    assert isinstance(x, np.ndarray) and x.shape == () and y.shape == ()
    assert abs(float(x) - float(ref_x)) <= MM and abs(float(y) - float(ref_y)) <= MM
    assert abs(float(x) - east) <= MM and abs(float(y) - north) <= MM


@SETTINGS
@given(origins, offsets)
@example((0.0, 0.0), (0.0, 0.0))  # the origin itself
@example((84.99, 179.9), (100_000.0, math.pi / 2))  # far north, east across the date line
@example((-84.99, -179.95), (100_000.0, 1.5 * math.pi))  # far south, west across it
@example((45.0, 180.0), (100_000.0, 0.0))  # due north at the date line
def test_one_point_agrees_with_pymap3d(origin: tuple[float, float],
                                       offset: tuple[float, float]) -> None:
    check_point(origin, *en(offset))


@SETTINGS
@given(origins, st.lists(offsets, min_size=1, max_size=30))
def test_arrays_agree_with_pymap3d(origin: tuple[float, float],
                                   points: list[tuple[float, float]]) -> None:
    frame = LocalFrame(*origin)
    east, north = np.array([en(p) for p in points]).T
    lat, lon = frame.to_geo(east, north)
    ref_lat, ref_lon = pymap3d_to_geo(*origin, east, north)
    assert lat.shape == lon.shape == east.shape
    assert np.max(np.abs(lat - ref_lat)) <= DEG
    assert np.max(lon_diff(lon, ref_lon)) <= DEG
    x, y = frame.to_xy(ref_lat, ref_lon)
    ref_x, ref_y = pymap3d_to_xy(*origin, ref_lat, ref_lon)
    assert x.shape == y.shape == east.shape
    assert np.max(np.abs(x - ref_x)) <= MM and np.max(np.abs(y - ref_y)) <= MM
    # The array path and the one-point path give the same numbers.
    one = [frame.to_geo(float(e), float(n)) for e, n in zip(east, north, strict=True)]
    assert np.max(np.abs(lat - [float(a) for a, _ in one])) <= 1e-12
    assert np.max(lon_diff(lon, np.array([float(b) for _, b in one]))) <= 1e-12


def test_inputs_of_other_kinds_and_shapes() -> None:
    """Lists, 0-d and 2-d arrays, NumPy integer and float32 scalars, and broadcasting, as
    pymap3d took them; a list of one point gives an array of one."""
    frame = LocalFrame(57.76, 16.68)
    lat, lon = frame.to_geo([1000.0, -2500.0], [300.0, 40_000.0])
    ref = pymap3d_to_geo(57.76, 16.68, [1000.0, -2500.0], [300.0, 40_000.0])
    assert lat.shape == (2,) and np.max(np.abs(lat - ref[0])) <= DEG
    assert np.max(np.abs(lon - ref[1])) <= DEG
    grid = np.arange(6, dtype=float).reshape(2, 3) * 5000.0
    lat2, lon2 = frame.to_geo(grid, 100.0)  # broadcast north
    ref2 = pymap3d_to_geo(57.76, 16.68, grid, np.full((2, 3), 100.0))
    assert lat2.shape == (2, 3) and np.max(np.abs(lat2 - ref2[0])) <= DEG
    assert np.max(np.abs(lon2 - ref2[1])) <= DEG
    for e, n in [(np.int64(1200), np.int64(-800)), (np.float32(1200.0), np.float32(-800.0)),
                 (np.array(1200.0), np.array(-800.0)), (1200, -800)]:
        la, lo = frame.to_geo(e, n)
        r = pymap3d_to_geo(57.76, 16.68, 1200.0, -800.0)
        assert la.shape == () and abs(float(la) - float(r[0])) <= DEG
        assert abs(float(lo) - float(r[1])) <= DEG
        x, y = frame.to_xy(la, lo)  # 0-d arrays in
        assert x.shape == () and abs(float(x) - 1200.0) <= MM and abs(float(y) + 800.0) <= MM
    for lat_in, lon_in in [(np.float32(57.8), np.float32(16.7)), (np.int64(58), np.int64(17)),
                           (58, 17)]:
        x, y = frame.to_xy(lat_in, lon_in)
        rx, ry = pymap3d_to_xy(57.76, 16.68, lat_in, lon_in)
        assert x.shape == () and abs(float(x) - float(rx)) <= MM and abs(float(y) - float(ry)) <= MM
    one = frame.points_xy([frame.geopoint(10.0, 20.0)])
    assert one.shape == (1, 2) and np.allclose(one, [[10.0, 20.0]], atol=MM, rtol=0)


def test_the_origin_is_fixed() -> None:
    """The frame's axes are computed once from its origin, so the origin cannot be moved under
    them."""
    frame = LocalFrame(57.76, 16.68)
    assert (frame.origin_lat, frame.origin_lon) == (57.76, 16.68)
    with pytest.raises(AttributeError):
        frame.origin_lat = 0.0  # type: ignore[misc]


def test_beyond_the_horizon_is_an_error_not_a_point() -> None:
    """No surface point has east/north 7,000 km from the origin (the tangent plane's up line
    misses the Earth): an error, one point or an array; NaN stays NaN, as with pymap3d. At
    3,000 km the point is still found exactly (pymap3d's three steps had not converged there)."""
    frame = LocalFrame(57.76, 16.68)
    with pytest.raises(ValueError, match="beyond the horizon"):
        frame.to_geo(7_000_000.0, 0.0)
    with pytest.raises(ValueError, match="beyond the horizon"):
        frame.to_geo([0.0, 7_000_000.0], [0.0, 0.0])
    lat, lon = frame.to_geo([math.nan, 10.0], [0.0, 10.0])
    assert math.isnan(lat[0]) and math.isnan(lon[0]) and not math.isnan(lat[1])
    x, y = frame.to_xy(*frame.to_geo(3_000_000.0, -1_000_000.0))
    assert abs(float(x) - 3_000_000.0) <= MM and abs(float(y) + 1_000_000.0) <= MM
