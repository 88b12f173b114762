"""Boustrophedon coverage paths of polygons in a local east/north frame (metres).

The sweep runs along the long axis of the polygon's minimum rotated rectangle (shapely), so the
number of turns is smallest. The short side ``H`` is split into ``n = ceil(H / w)`` strips of equal
height ``H / n <= w`` and one lane runs through the middle of each strip, from polygon edge to
polygon edge; consecutive lanes are joined by straight connectors at alternating ends. For a
rectangle that is exactly ``A / w + (n - 1) * w`` for ``A`` the area (DESIGN 4); for other convex
polygons it stays within a few per cent of that estimate.

Lanes end where their centre line meets the boundary, so the path never leaves the polygon; at
slanted ends the corners between lanes are left to the camera's along-track footprint. Counting only
the band ``w/2`` either side of the path, a triangle is 99.9 % covered with 19 lanes, 99 % with 5,
96 % with 2 (tests check >= 99 % from about 10 lanes on).

The path is real: the simulator flies it and the maps draw it, and ``coverage_length`` is its
length, not an estimate. Lanes are found with numpy (every lane against every polygon edge at
once), so widths of a metre over kilometre-sized areas stay fast.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry import Polygon

from delegation.errors import InputError

#: More lanes than this means a width far too small for the area: refuse rather than hang.
MAX_LANES = 200_000

#: Vertices of the polygon that stands in for the circle of ``search-around-position``.
CIRCLE_SEGMENTS = 64


def _clean_polygon(polygon_xy: np.ndarray | Sequence[Sequence[float]]) -> np.ndarray:
    poly = np.asarray(polygon_xy, dtype=float)
    if poly.ndim != 2 or poly.shape[1] != 2:
        raise InputError(f"a polygon must be an (N, 2) array of east/north m, not {poly.shape}")
    if len(poly) > 1 and np.allclose(poly[0], poly[-1]):
        poly = poly[:-1]  # closed rings repeat the first point
    if len(poly) < 3:
        raise InputError(f"a polygon needs at least 3 points, got {len(poly)}")
    if not np.all(np.isfinite(poly)):
        raise InputError("a polygon's coordinates must be finite")
    return poly


def _check_width(width: float) -> float:
    w = float(width)
    if not math.isfinite(w) or w <= 0.0:
        raise InputError(f"sweep width must be a positive number of metres, not {width!r}")
    return w


def _lane_count(height: float, width: float) -> int:
    """Strips of height at most ``width`` across ``height`` (at least one; rounding-tolerant)."""
    return max(1, math.ceil(height / width - 1e-9))


def sweep_axes(polygon_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (along, across): the long and short sides of the minimum rotated rectangle.

    ``along`` points east-ish (positive east, or north when exactly north-south) so the result is
    the same for any vertex order.
    """
    poly = _clean_polygon(polygon_xy)
    rect = shapely.minimum_rotated_rectangle(Polygon(poly))
    if isinstance(rect, Polygon) and rect.area > 0.0:
        pts = np.asarray(rect.exterior.coords, dtype=float)
        e1, e2 = pts[1] - pts[0], pts[2] - pts[1]
        along = e1 if np.hypot(*e1) >= np.hypot(*e2) else e2
    else:  # degenerate (collinear points): sweep along the line
        centred = poly - poly.mean(axis=0)
        _, _, vt = np.linalg.svd(centred)
        along = vt[0]
    along = along / np.hypot(*along)
    if along[0] < -1e-12 or (abs(along[0]) <= 1e-12 and along[1] < 0):
        along = -along
    across = np.array([-along[1], along[0]])
    return along, across


def sweep_lanes(polygon_xy: np.ndarray | Sequence[Sequence[float]], width: float) -> np.ndarray:
    """The lanes of the sweep: an (n, 2, 2) array of [start, end] points, all pointing ``along``,
    ordered across the polygon from one side to the other."""
    poly = _clean_polygon(polygon_xy)
    w = _check_width(width)
    along, across = sweep_axes(poly)
    origin = poly.mean(axis=0)
    rel = poly - origin
    qx = rel @ along
    qy = rel @ across
    y_lo, y_hi = float(qy.min()), float(qy.max())
    height = y_hi - y_lo
    n = _lane_count(height, w)
    if n > MAX_LANES:
        raise InputError(
            f"sweep width {w:g} m is too small for an area {height:.0f} m wide ({n} lanes)"
        )
    ys = y_lo + (np.arange(n) + 0.5) * (height / n)

    # Every lane against every edge: where the lane's line crosses the edge, if it does.
    x0, y0 = qx, qy
    x1, y1 = np.roll(qx, -1), np.roll(qy, -1)
    dy = y1 - y0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ys[:, None] - y0[None, :]) / dy[None, :]
    hits = (dy[None, :] != 0.0) & (t >= 0.0) & (t <= 1.0)
    xs = np.where(hits, x0[None, :] + t * (x1 - x0)[None, :], np.nan)
    found = hits.any(axis=1)
    if not found.all():  # only numerically possible for a lane on a degenerate polygon
        xs, ys = xs[found], ys[found]
    if len(ys) == 0:
        lo, hi = float(qx.min()), float(qx.max())
        xs = np.array([[lo, hi]])
        ys = np.array([(y_lo + y_hi) / 2.0])
    x_start = np.nanmin(xs, axis=1)
    x_end = np.nanmax(xs, axis=1)
    starts = origin + x_start[:, None] * along + ys[:, None] * across
    ends = origin + x_end[:, None] * along + ys[:, None] * across
    return np.stack([starts, ends], axis=1)


def serpentine(lanes: np.ndarray, variant: int = 0) -> np.ndarray:
    """Join lanes into one boustrophedon path (K, 2).

    ``variant`` picks one of the four ways to fly the same lanes: bit 0 starts from the last lane
    instead of the first, bit 1 flies the first lane backwards.
    """
    order = lanes[::-1] if variant & 1 else lanes
    n = len(order)
    backwards = (np.arange(n) % 2 == 1) ^ bool(variant & 2)
    flown = np.where(backwards[:, None, None], order[:, ::-1, :], order)
    path = flown.reshape(-1, 2)
    # Drop repeated points (a lane of zero length at a vertex).
    keep = np.ones(len(path), dtype=bool)
    keep[1:] = np.any(np.abs(np.diff(path, axis=0)) > 1e-9, axis=1)
    return np.asarray(path[keep])


def coverage_path(
    polygon_xy: np.ndarray | Sequence[Sequence[float]], width: float, variant: int = 0
) -> np.ndarray:
    """The boustrophedon path (K, 2) covering the polygon with sweep width ``width`` (m)."""
    return serpentine(sweep_lanes(polygon_xy, width), variant)


def path_length(path_xy: np.ndarray) -> float:
    """Length (m) of a polyline given as (K, 2) east/north."""
    path = np.asarray(path_xy, dtype=float)
    if len(path) < 2:
        return 0.0
    return float(np.hypot(*np.diff(path, axis=0).T).sum())


def coverage_length(polygon_xy: np.ndarray | Sequence[Sequence[float]], width: float) -> float:
    """The length (m) of ``coverage_path(polygon_xy, width)``."""
    return path_length(coverage_path(polygon_xy, width))


def coverage_estimate(polygon_xy: np.ndarray | Sequence[Sequence[float]], width: float) -> float:
    """The closed-form estimate ``A / w + (n - 1) * w`` (DESIGN 4), for checks and quick bounds."""
    poly = _clean_polygon(polygon_xy)
    w = _check_width(width)
    _, across = sweep_axes(poly)
    qy = (poly - poly.mean(axis=0)) @ across
    n = _lane_count(float(qy.max()) - float(qy.min()), w)
    return float(Polygon(poly).area) / w + (n - 1) * w


def circle_polygon(
    center_xy: Sequence[float] | np.ndarray, radius: float, segments: int = CIRCLE_SEGMENTS
) -> np.ndarray:
    """A regular polygon (segments, 2) standing in for a circle."""
    if not math.isfinite(radius) or radius <= 0.0:
        raise InputError(f"radius must be a positive number of metres, not {radius!r}")
    angles = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
    c = np.asarray(center_xy, dtype=float)
    return np.column_stack([c[0] + radius * np.cos(angles), c[1] + radius * np.sin(angles)])


def multi_coverage_path(polygons: Sequence[np.ndarray], width: float) -> np.ndarray:
    """One path over several polygons in the given order (``search-areas``).

    The first polygon is flown in the canonical variant; each later one in the variant whose start
    is nearest to where the previous one ended; straight connectors between them.
    """
    parts: list[np.ndarray] = []
    for poly in polygons:
        lanes = sweep_lanes(poly, width)
        if not parts:
            parts.append(serpentine(lanes, 0))
            continue
        last = parts[-1][-1]
        options = [serpentine(lanes, v) for v in range(4)]
        parts.append(min(options, key=lambda p: float(np.hypot(*(p[0] - last)))))
    if not parts:
        return np.zeros((0, 2))
    return np.concatenate(parts, axis=0)
