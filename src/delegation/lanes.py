"""The lanes of a sweep, in the sweep's own frame (east/north metres rotated so that the lanes run
along x): the frame of a polygon for a direction, the lanes spread in ``n = ceil(H / w)`` equal
strips across it and clipped to it (numpy, even-odd crossings of its edges), and the lanes that
the strips a concave area's arms leave between two lanes need (``_gap_lanes``). What
``delegation.coverage`` groups into cells and flies; pure geometry, no clock.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon

from delegation.errors import InputError

#: More lanes than this means a width far too small for the area: refuse rather than hang.
MAX_LANES = 200_000

def _clean_polygon(polygon_xy: np.ndarray | Sequence[Sequence[float]]) -> np.ndarray:
    poly = np.asarray(polygon_xy, dtype=float)
    if poly.ndim != 2 or poly.shape[1] != 2:
        raise InputError(f"a polygon must be an (N, 2) array of east/north m, not {poly.shape}")
    if len(poly) > 1 and _close(poly[0].tolist(), poly[-1].tolist()):
        poly = poly[:-1]  # closed rings repeat the first point
    if len(poly) < 3:
        raise InputError(f"a polygon needs at least 3 points, got {len(poly)}")
    if not np.all(np.isfinite(poly)):
        raise InputError("a polygon's coordinates must be finite")
    return poly


def _close(a: Sequence[float], b: Sequence[float]) -> bool:
    """``np.allclose(a, b)`` for two points, in plain Python (numpy's costs ~20 us a call, and
    every coverage path asks twice)."""
    for x, y in zip(a, b, strict=True):
        if math.isfinite(x) and math.isfinite(y):
            if not abs(x - y) <= 1e-8 + 1e-5 * abs(y):
                return False
        elif x != y:
            return False
    return True


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
    # GEOS divides by zero for collinear points; that case is handled below, without the warning.
    with np.errstate(divide="ignore", invalid="ignore"):
        rect = shapely.minimum_rotated_rectangle(Polygon(poly))
    if isinstance(rect, Polygon) and rect.area > 0.0:
        pts = shapely.get_coordinates(rect)  # (the exterior ring: a rectangle has no holes)
        e1, e2 = pts[1] - pts[0], pts[2] - pts[1]
        along = e1 if np.hypot(*e1) >= np.hypot(*e2) else e2
    else:  # degenerate (collinear points): sweep along the line
        centred = poly - poly.mean(axis=0)
        _, _, vt = np.linalg.svd(centred)
        along = vt[0]
    along = _canonical(along)
    across = np.array([-along[1], along[0]])
    return along, across


@dataclass(frozen=True)
class _SweepFrame:
    """What a polygon's sweep needs whatever the width: the axes, the polygon's edges in the sweep
    frame and its extent."""

    along: np.ndarray
    across: np.ndarray
    origin: np.ndarray
    x_lo: float
    x_hi: float
    y_lo: float
    y_hi: float
    #: (E, 4) every edge (x0, y0, x1, y1) of the polygon's ring, in the sweep frame (a ring that
    #: crosses itself is read even-odd, as GEOS's make_valid reads it).
    edges: np.ndarray


def _sweep_frame(poly: np.ndarray, along: np.ndarray | None = None) -> _SweepFrame:
    """The sweep frame of a cleaned polygon with lanes along ``along`` (default: the minimum
    rectangle's long axis), remembered for the last polygons seen: the cost tables sweep each area
    once per distinct sweep width of the fleet, and planning a mission again (bids, re-delegation,
    maps) sweeps the same areas."""
    key = None if along is None else (float(along[0]), float(along[1]))
    return _sweep_frame_of(np.ascontiguousarray(poly, dtype=float).tobytes(), len(poly), key)


def _canonical(along: np.ndarray) -> np.ndarray:
    """``along`` as a unit vector pointing east-ish (positive east, or north when exactly
    north-south), so a direction and its opposite give the same lanes."""
    along = along / np.hypot(*along)
    if along[0] < -1e-12 or (abs(along[0]) <= 1e-12 and along[1] < 0):
        along = -along
    return np.asarray(along)


@functools.lru_cache(maxsize=1024)
def _sweep_frame_of(data: bytes, n: int, key: tuple[float, float] | None) -> _SweepFrame:
    if key is None:
        along = sweep_axes(np.frombuffer(data, dtype=float).reshape(n, 2))[0]
    else:
        along = _canonical(np.array(key, dtype=float))
    return _frame_along(data, n, float(along[0]), float(along[1]))


@functools.lru_cache(maxsize=1024)
def _frame_along(data: bytes, n: int, ax: float, ay: float) -> _SweepFrame:
    """The sweep frame along the unit vector (ax, ay), already canonical: the direction search
    asks for the rectangle's long axis by default and again by name, the same frame."""
    poly = np.frombuffer(data, dtype=float).reshape(n, 2)
    along = np.array([ax, ay])
    across = np.array([-along[1], along[0]])
    origin = poly.mean(axis=0)
    rel = poly - origin
    qx = rel @ along
    qy = rel @ across
    edges = np.empty((n, 4))  # (np.column_stack and np.roll: the same, slower)
    edges[:, 0], edges[:, 1] = qx, qy
    edges[:-1, 2:], edges[-1, 2:] = edges[1:, :2], edges[0, :2]
    for array in (along, across, origin, edges):
        array.setflags(write=False)
    return _SweepFrame(along, across, origin, float(qx.min()), float(qx.max()),
                       float(qy.min()), float(qy.max()), edges)


#: Lanes x edges handled at once when clipping (bounds the memory of the crossing table).
_CLIP_CHUNK = 2_000_000


def _clip_lanes(edges: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The horizontal lanes ``y = ys`` clipped to the area whose ring edges are ``edges``: (x0,
    x1, lane index) of each piece, unsorted. Even-odd crossings, each edge counting its lower end
    and not its upper (a lane through a vertex crosses once, or twice at a spike); an edge lying
    on a lane is a piece too (the closed area holds its boundary, as GEOS clips). Pure numpy: a
    GEOS intersection per lane cost ~0.2 ms against a 50-vertex area."""
    x0, y0, x1, y1 = edges.T
    flat = y0 == y1
    lo, hi = np.minimum(y0, y1), np.maximum(y0, y1)
    slope = np.where(flat, 0.0, (x1 - x0) / np.where(flat, 1.0, y1 - y0))
    crossing = ~flat
    on_lane = np.flatnonzero(flat)  # (edges along a lane: few or none)
    starts, ends, lanes = [], [], []
    step = max(1, _CLIP_CHUNK // max(1, len(edges)))
    for a in range(0, len(ys), step):
        y = ys[a:a + step, None]
        hit = (y >= lo) & (y < hi) & crossing
        lane, edge = np.nonzero(hit)
        xs = x0[edge] + (ys[a + lane] - y0[edge]) * slope[edge]
        order = np.lexsort((xs, lane))
        xs, lane = xs[order], lane[order]
        starts.append(xs[0::2])
        ends.append(xs[1::2])
        lanes.append(lane[0::2] + a)
        if len(on_lane) == 0:
            continue
        lane, k = np.nonzero(y == y0[on_lane])  # edges along a lane
        edge = on_lane[k]
        starts.append(np.minimum(x0[edge], x1[edge]))
        ends.append(np.maximum(x0[edge], x1[edge]))
        lanes.append(lane + a)
    return np.concatenate(starts), np.concatenate(ends), np.concatenate(lanes)


def _segments(
    poly: np.ndarray, width: float, along: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The lanes clipped to the polygon: (segments (m, 2, 2) in the world frame, each segment's lane
    index (m,)), ordered by lane and, within a lane, along the sweep; every segment points along.

    ``along`` is the lanes' direction; None: the minimum rectangle's long axis."""
    w = _check_width(width)
    frame = _sweep_frame(poly, along)
    along, across, origin = frame.along, frame.across, frame.origin
    y_lo, y_hi = frame.y_lo, frame.y_hi
    height = y_hi - y_lo
    n = _lane_count(height, w)
    if n > MAX_LANES:
        raise InputError(
            f"sweep width {w:g} m is too small for an area {height:.0f} m wide ({n} lanes)"
        )
    ys = y_lo + (np.arange(n) + 0.5) * (height / n)

    # Clip every lane (a horizontal line in the sweep frame) to the area; a lane the area splits
    # comes back in several pieces.
    x_lo, x_hi = frame.x_lo, frame.x_hi
    pad = max(1.0, x_hi - x_lo)
    x0s, x1s, lane = _clip_lanes(frame.edges, ys)
    keep = x1s > x0s  # (no touch points)
    x0s, x1s, lane = x0s[keep], x1s[keep], lane[keep]
    if len(lane) == 0:  # a degenerate (zero-area) polygon: one lane along it
        x0s, x1s = np.array([x_lo]), np.array([x_hi])
        lane, seg_y = np.array([0]), np.array([(y_lo + y_hi) / 2.0])
    else:
        order = np.lexsort((x0s, lane))
        x0s, x1s, lane = x0s[order], x1s[order], lane[order]
        # Pieces that touch (a lane running along a boundary edge) are one segment.
        joined = np.zeros(len(lane), dtype=bool)
        joined[1:] = (lane[1:] == lane[:-1]) & (x0s[1:] <= x1s[:-1] + 1e-9 * pad)
        first = np.flatnonzero(~joined)
        x0s = x0s[first]
        x1s = np.maximum.reduceat(x1s, first)
        lane = lane[first]
        seg_y = ys[lane]
    starts = origin + x0s[:, None] * along + seg_y[:, None] * across
    ends = origin + x1s[:, None] * along + seg_y[:, None] * across
    segments = np.empty((len(starts), 2, 2))
    segments[:, 0], segments[:, 1] = starts, ends
    return segments, lane


#: A strip the lanes leave unseen gets a lane of its own from this area, in w^2 (a strip 0.4 w
#: high and 7.5 w long along an arm's edge): the slivers at slanted lane ends stay (each under
#: ~2.5 w^2 on the benchmark polygons, together a few tenths of a percent of an area), as a lane
#: for each cost up to 9 % more path for 0.3 % more area seen.
GAP_MIN_AREA = 3.0


def _gap_lanes(poly: np.ndarray, width: float, along: np.ndarray, segments: np.ndarray,
               lane: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The lanes with lanes added through any strip of a concave area that they leave unseen.

    Lanes are spaced evenly across the whole polygon, so an arm of it whose edge runs along the
    lanes can fall between two: the next lane lies just outside the arm and the strip between the
    last lane's footprint and the edge is never seen (a 16 m x 400 m strip of one part of the L
    in ``benchmarks/team_search.py``). Each such strip gets its own evenly spaced lanes, clipped
    to it; the lanes are then numbered again across the area. Returns (segments, lane) as
    ``_segments`` does; unchanged when nothing is left unseen."""
    if len(segments) == 0:
        return segments, lane
    w = _check_width(width)
    frame = _sweep_frame(poly, along)
    fx = (segments - frame.origin) @ frame.along  # (m, 2) positions along the lanes
    fy = (segments[:, 0] - frame.origin) @ frame.across  # (m,) each lane's offset across
    x0, x1 = np.minimum(fx[:, 0], fx[:, 1]), np.maximum(fx[:, 0], fx[:, 1])
    first = np.flatnonzero(np.r_[True, lane[1:] != lane[:-1]])
    levels = fy[first]
    pairs = _missing_between(frame.edges, w, levels, first, x0, x1).tolist()
    if not pairs:
        return segments, lane
    area = shapely.make_valid(shapely.Polygon(frame.edges[:, :2]))
    ends = np.r_[first, len(x0)]
    gaps: list[shapely.Geometry] = []
    for i in pairs:  # GEOS only between the two lanes, with their segments' reach
        s, e = int(ends[i]), int(ends[i + 2])
        band = shapely.box(frame.x_lo - 1.0, levels[i], frame.x_hi + 1.0, levels[i + 1])
        seen = shapely.box(x0[s:e] - w / 2.0, fy[s:e] - w / 2.0, x1[s:e] + w / 2.0,
                           fy[s:e] + w / 2.0)
        unseen = shapely.difference(shapely.intersection(area, band), shapely.union_all(seen))
        gaps.extend(g for g in shapely.get_parts(unseen) if g.area > GAP_MIN_AREA * w * w)
    added = _lanes_through(gaps, w)
    if len(added) == 0:
        return segments, lane
    ys = np.concatenate([fy, added[:, 2]])
    starts = np.concatenate([x0, added[:, 0]])
    stops = np.concatenate([x1, added[:, 1]])
    order = np.lexsort((starts, ys))
    ys, starts, stops = ys[order], starts[order], stops[order]
    renumbered = np.concatenate([[0], np.cumsum(np.diff(ys) > 1e-9)])
    out = np.empty((len(ys), 2, 2))
    out[:, 0] = frame.origin + starts[:, None] * frame.along + ys[:, None] * frame.across
    out[:, 1] = frame.origin + stops[:, None] * frame.along + ys[:, None] * frame.across
    return out, renumbered


def _lanes_through(gaps: list[shapely.Geometry], w: float) -> np.ndarray:
    """Evenly spaced lanes across each unseen strip (sweep frame), clipped to it: (k, 3) rows of
    (x0, x1, y)."""
    rows = []
    for gap in gaps:
        x_lo, y_lo, x_hi, y_hi = gap.bounds
        k = _lane_count(y_hi - y_lo, w)
        for y in y_lo + (np.arange(k) + 0.5) * ((y_hi - y_lo) / k):
            line = shapely.LineString([(x_lo - 1.0, y), (x_hi + 1.0, y)])
            for piece in shapely.get_parts(shapely.intersection(gap, line)):
                xs = shapely.get_coordinates(piece)[:, 0]
                if len(xs) >= 2 and xs.max() > xs.min():
                    rows.append((float(xs.min()), float(xs.max()), float(y)))
    return np.array(rows, dtype=float).reshape(-1, 3)


def _missing_between(edges: np.ndarray, w: float, levels: np.ndarray, first: np.ndarray,
                     x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
    """The neighbouring lanes (i, i + 1) between which the area may be left unseen, by more than
    ``GAP_MIN_AREA``: a quick estimate before GEOS looks. Between two lanes, the offsets nearer
    to one than the other's reach are seen only by that one (its segments and ``w/2`` past their
    ends); the area out of its reach is sampled at two offsets in each such zone and summed.
    ``levels``: each lane's offset, ``first``: its first segment (the rest follow up to the next
    lane's first)."""
    gap = levels[1:] - levels[:-1]
    wide = np.flatnonzero(gap > w / 2.0)  # (closer lanes each reach past the other)
    if len(wide) == 0:
        return wide
    zone = gap[wide] - w / 2.0
    lo_i, hi_i = levels[wide], levels[wide + 1]
    probes = np.concatenate([lo_i + 0.25 * zone, lo_i + 0.75 * zone,  # lane i alone reaches
                             hi_i - 0.25 * zone, hi_i - 0.75 * zone])  # lane i + 1 alone
    by = np.concatenate([wide, wide, wide + 1, wide + 1])
    pair = np.tile(np.arange(len(wide)), 4)
    weight = np.tile(zone / 2.0, 4)
    a, b, k = _clip_lanes(edges, probes)
    if len(k) == 0:
        return wide[:0]
    ends = np.r_[first, len(x0)]
    lane = by[k]
    count = ends[lane + 1] - ends[lane]  # segments of the reaching lane, per chord piece
    piece = np.repeat(np.arange(len(k)), count)
    span = ends[lane][piece] + (np.arange(len(piece)) - np.repeat(np.cumsum(count) - count, count))
    inside = np.clip(np.minimum(b[piece], x1[span] + w / 2.0)
                     - np.maximum(a[piece], x0[span] - w / 2.0), 0.0, None)
    out = np.maximum((b - a) - np.bincount(piece, inside, minlength=len(k)), 0.0)
    unseen = np.bincount(pair[k], out * weight[k], minlength=len(wide))
    return wide[unseen > GAP_MIN_AREA * w * w]
