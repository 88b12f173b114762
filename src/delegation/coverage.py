"""Boustrophedon coverage paths of polygons in a local east/north frame (metres).

The lanes' direction is chosen per polygon and width (``sweep_direction``): among the two axes of
the polygon's minimum rotated rectangle (shapely) and its edges' directions, the one whose whole
path (turns and transitions included) is shortest; a caller may also give it (``along``). Across
the lanes the polygon's extent ``H`` is split into ``n = ceil(H / w)`` strips of equal height
``H / n <= w`` and one lane runs through the middle of each strip. Every lane is clipped to
the polygon (numpy, even-odd crossings of its edges), so each lane segment lies inside the
area; a lane that a concave area splits (the arms of a U) becomes several segments.

The segments are grouped into cells (a boustrophedon cell decomposition: a segment continues the
cell of the previous lane's segment when each is the other's only overlap). Each cell is flown as
a boustrophedon, consecutive lanes joined by straight connectors at alternating ends; the cells are
flown one after another, each from the cell and end nearest to where the path is, joined by
straight transitions. A convex polygon is a single cell: for a rectangle swept along its long side
the path is exactly ``A / w + (n - 1) * w`` for ``A`` the area (docs/plan.md §2.4), for other
convex polygons within a few per cent of that estimate. For a concave polygon the path is usually
longer than the estimate by its transitions.

What stays inside the area: every lane segment. Connectors and transitions are straight lines; in
a convex polygon they stay inside it, but over a concave area they may cross outside it (from one
arm of a U to the other, or around a notch), as the vehicle flies to the next cell. At slanted
ends the corners between lanes are left to the camera's along-track footprint. Counting only the
band ``w/2`` either side of the path, a triangle is 99.9 % covered with 19 lanes, 99 % with 5,
96 % with 2 (tests check >= 99 % from about 10 lanes on).

A unit flies the sweep from the end that suits where it is (``flown_ways``, ``pick_way``: of the
first cell's four variants, each flown forwards or backwards, the one whose flight to its start
plus its length is least), not from a fixed corner; the planner's schedule chooses from where the
unit's previous task left it, the simulated unit from where it is, with the same rule.

The lanes themselves (the sweep's frame, the strips, clipping, and the lanes a concave area's
missed strips need) are `delegation.lanes`; the shortest way inside the area for a transition
that would cross a notch is `delegation.ways_inside`.

The path is real: the simulator flies it and the maps draw it, and ``coverage_length`` is its
length, not an estimate. Lanes are clipped with numpy (even-odd crossings of the area's edges), so
widths of a metre over kilometre-sized areas stay fast.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry import Polygon

from delegation.errors import InputError
from delegation.lanes import MAX_LANES as MAX_LANES  # (re-exported)
from delegation.lanes import (
    _canonical,
    _check_width,
    _clean_polygon,
    _gap_lanes,
    _lane_count,
    _segments,
    _sweep_frame,
)
from delegation.lanes import sweep_axes as sweep_axes  # (re-exported)
from delegation.ways_inside import transitions_inside as transitions_inside  # (re-exported)

#: Vertices of the polygon that stands in for the circle of ``search-around-position``.
CIRCLE_SEGMENTS = 64


def _direction(poly: np.ndarray, width: float, along: np.ndarray | None) -> np.ndarray:
    """``along`` if given, else the direction ``sweep_direction`` chooses."""
    if along is not None:
        return _canonical(np.asarray(along, dtype=float))
    return _best_direction(np.ascontiguousarray(poly, dtype=float).tobytes(), len(poly),
                           _check_width(width))


def sweep_lanes(
    polygon_xy: np.ndarray | Sequence[Sequence[float]], width: float,
    along: np.ndarray | None = None,
) -> np.ndarray:
    """The lanes of the sweep clipped to the polygon: an (m, 2, 2) array of [start, end] points,
    all pointing ``along`` (default: ``sweep_direction``), ordered across the polygon from one
    side to the other and, where the polygon splits a lane into several segments (concave areas),
    along the lane.

    For a convex polygon ``m`` is the lane count ``n``, one segment per lane."""
    poly = _clean_polygon(polygon_xy)
    return _segments(poly, width, _direction(poly, width, along))[0]


def sweep_cells(
    polygon_xy: np.ndarray | Sequence[Sequence[float]], width: float,
    along: np.ndarray | None = None,
) -> list[np.ndarray]:
    """The lane segments grouped into cells, each an (k, 2, 2) array flown as one boustrophedon.

    A segment continues the cell of a segment in the previous lane when each is the other's only
    overlapping segment in that lane (a boustrophedon cell decomposition: cells split and merge
    where the area does), or when both lanes are a single segment (so a convex polygon is one
    cell, flown exactly as before). Cells are listed in the order their first lanes come.
    ``along``: the lanes' direction (default: ``sweep_direction``).
    """
    poly = _clean_polygon(polygon_xy)
    return [cell.copy() for cell in _swept_cells(poly, width, along)]


def _swept_cells(poly: np.ndarray, width: float, along: np.ndarray | None
                 ) -> tuple[np.ndarray, ...]:
    """``sweep_cells`` of a cleaned polygon, the remembered read-only arrays (``_swept``)."""
    w = _check_width(width)
    direction = _direction(poly, w, along)
    return _swept(np.ascontiguousarray(poly, dtype=float).tobytes(), len(poly), w,
                  float(direction[0]), float(direction[1]), True)[0]


def _cells(segments: np.ndarray, lane: np.ndarray) -> list[np.ndarray]:
    """``sweep_cells`` of lane segments and their lane indices (``_segments``)."""
    if len(segments) == 0:
        return []
    if bool(np.all(lane[1:] != lane[:-1])):  # one segment per lane (sorted by lane): one cell
        return [segments]
    along = segments[:, 1] - segments[:, 0]
    # Positions along the sweep of each segment's ends (any common origin will do).
    direction = along[np.argmax(np.hypot(*along.T))]
    direction = direction / max(float(np.hypot(*direction)), 1e-300)
    x0 = (segments[:, 0] @ direction).tolist()
    x1 = (segments[:, 1] @ direction).tolist()
    lanes = lane.tolist()
    # Plain Python: lanes hold a few segments each, and numpy's per-call cost dominated here.
    per_lane: list[list[int]] = []
    for s, k in enumerate(lanes):
        if per_lane and lanes[per_lane[-1][0]] == k:
            per_lane[-1].append(s)
        else:
            per_lane.append([s])
    cell_of = [-1] * len(lanes)
    cells: list[list[int]] = []
    previous: list[int] = []
    for current in per_lane:
        if previous and lanes[current[0]] != lanes[previous[0]] + 1:
            previous = []  # a lane with nothing in it breaks every cell
        # overlaps[i]: the previous lane's segments that segment i of this lane overlaps
        overlaps = [[j for j, p in enumerate(previous)
                     if min(x1[s], x1[p]) > max(x0[s], x0[p])] for s in current]
        single = len(current) == 1 and len(previous) == 1
        for i, s in enumerate(current):
            js = overlaps[i]
            if single or (len(js) == 1 and sum(js[0] in o for o in overlaps) == 1):
                p = previous[0] if single else previous[js[0]]
                cell_of[s] = cell_of[p]
                cells[cell_of[s]].append(s)
            else:
                cell_of[s] = len(cells)
                cells.append([s])
        previous = current
    return [segments[ix] for ix in cells]


def serpentine(lanes: np.ndarray, variant: int = 0) -> np.ndarray:
    """Join lanes into one boustrophedon path (K, 2).

    ``variant`` picks one of the four ways to fly the same lanes: bit 0 starts from the last lane
    instead of the first, bit 1 flies the first lane backwards.
    """
    order = lanes[::-1] if variant & 1 else lanes
    flown = order.copy()
    back = 0 if variant & 2 else 1  # the first lane flown backwards
    flown[back::2] = order[back::2, ::-1]
    return _drop_repeats(flown.reshape(-1, 2))


def _drop_repeats(path: np.ndarray) -> np.ndarray:
    """Drop repeated points (a lane of zero length at a vertex, a cell starting where one ended)."""
    keep = np.ones(len(path), dtype=bool)
    moved = np.abs(path[1:] - path[:-1]) > 1e-9  # (np.diff and np.any(axis=1): same, slower)
    keep[1:] = moved[:, 0] | moved[:, 1]
    return np.asarray(path[keep])


def _variant_starts(cell: np.ndarray) -> np.ndarray:
    """Where ``serpentine(cell, v)`` starts, for v = 0..3: (4, 2)."""
    return np.stack([cell[0, 0], cell[-1, 0], cell[0, 1], cell[-1, 1]])


def _fly_cells(
    cells: list[np.ndarray], variant: int, start: np.ndarray | None = None
) -> np.ndarray:
    """One path through all cells: each cell a boustrophedon, straight transitions between them.

    Without ``start`` the first cell is the first (bit 0 of ``variant`` clear) or the last (set) in
    the lanes' order, flown in ``variant``; with it, the cell and variant starting nearest to
    ``start``. Then, greedily, the cell and variant whose start is nearest to where the path is.
    """
    if not cells:
        return np.zeros((0, 2))
    left = list(range(len(cells)))
    parts: list[np.ndarray] = []
    if start is None:
        first = left.pop(-1 if variant & 1 else 0)
        parts.append(serpentine(cells[first], variant))
    every = np.stack([_variant_starts(c) for c in cells]) if left else None  # (cells, 4, 2)
    while left:
        here = parts[-1][-1] if parts else start
        assert here is not None and every is not None
        starts = every[left]
        gaps = np.hypot(starts[..., 0] - here[0], starts[..., 1] - here[1])
        i, v = np.unravel_index(int(np.argmin(gaps)), gaps.shape)
        parts.append(serpentine(cells[left.pop(int(i))], int(v)))
    if len(parts) == 1:
        return parts[0]  # (serpentine dropped its repeats already)
    return _drop_repeats(np.concatenate(parts, axis=0))


def coverage_path(
    polygon_xy: np.ndarray | Sequence[Sequence[float]], width: float, variant: int = 0,
    along: np.ndarray | None = None,
) -> np.ndarray:
    """The boustrophedon path (K, 2) covering the polygon with sweep width ``width`` (m).

    ``variant`` (0..3) is ``serpentine``'s, applied to the first cell; ``along`` the lanes'
    direction (default: ``sweep_direction``, the shortest path's).
    """
    if variant != 0:
        return _fly_cells(sweep_cells(polygon_xy, width, along), variant)
    poly = _clean_polygon(polygon_xy)
    w = _check_width(width)
    direction = _direction(poly, w, along)
    _, path, _ = _swept(np.ascontiguousarray(poly, dtype=float).tobytes(), len(poly), w,
                        float(direction[0]), float(direction[1]), True)
    return path.copy()


@functools.lru_cache(maxsize=1024)
def _swept(data: bytes, n: int, width: float, ax: float, ay: float, fill: bool, /
           ) -> tuple[tuple[np.ndarray, ...], np.ndarray, int]:
    """(cells, variant 0's path, lane segments) of the sweep along (ax, ay), read-only:
    remembered, as choosing the direction sweeps the winner already, and the cost tables then
    fly its cells (``flown_sweep``) or ask for its path. ``fill``: with lanes through the strips
    the even lanes leave unseen (``_gap_lanes``; False only to screen directions quickly).
    Its arguments are positional only, none defaulted: ``lru_cache`` keys a defaulted or named
    argument apart from a positional one, and the winner of ``_best_direction`` was swept twice."""
    poly = np.frombuffer(data, dtype=float).reshape(n, 2)
    along = np.array([ax, ay])
    segments, lane = _segments(poly, width, along)
    if fill and _convex_area_of(poly) is None:  # (a convex area has no arm to miss)
        segments, lane = _gap_lanes(poly, width, along, segments, lane)
    cells = tuple(_cells(segments, lane))
    path = _fly_cells(list(cells), 0)
    for array in (*cells, path):
        array.setflags(write=False)
    return cells, path, len(segments)


# --------------------------------------------------------------------------- turns inside

#: Ways of flying a sweep that cost within this many metres of each other from where the unit
#: is (its flight to the way's start plus the way's length) are equally good, and the first
#: listed is flown: the planner and the unit compute in frames a few kilometres apart, whose
#: lengths differ by millimetres, and must choose the same way (``pick_way``).
WAY_TIE_M = 1.0


def flown_sweep(polygons: Sequence[np.ndarray], width: float,
                near: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
    """The path a unit flies to search ``polygons`` (one: ``coverage_path``'s lanes; several:
    ``multi_coverage_path``'s order) with its turns inside the area (``turns_inside``): what the
    cost model counts and the simulated units fly (``costs.task_path``).

    ``near``: where the unit is when the task starts (east, north m): of the ways to fly the
    sweep (``flown_ways``) the one that costs least from there (``pick_way``); None: the
    shortest."""
    ways = flown_ways(polygons, width)
    if not ways:
        return np.zeros((0, 2))
    here = None if near is None else (float(near[0]), float(near[1]))
    return ways[pick_way(way_ends(ways), here)].copy()


def way_ends(ways: Sequence[np.ndarray]) -> list[tuple[float, float, float, float, float]]:
    """Per way: (start east, start north, end east, end north, length m), what ``pick_way``
    and the cost tables read."""
    out = []
    for way in ways:
        (sx, sy), (ex, ey) = way[0].tolist(), way[-1].tolist()
        out.append((sx, sy, ex, ey, path_length(way)))
    return out


def pick_way(ends: Sequence[Sequence[float]], here: tuple[float, float] | None) -> int:
    """The way (index into ``ends``, rows of ``way_ends``) a unit at ``here`` flies: the least
    flight to its start plus its length, the first listed within ``WAY_TIE_M`` of that; from
    nowhere (None) the shortest. The planner's schedule (from where the unit's previous task
    left it) and the simulated unit (from where it is) both choose with this. Plain Python: the
    schedule asks for every search it simulates."""
    if here is None:
        costs = [row[4] for row in ends]
    else:
        x, y = here
        costs = [math.hypot(row[0] - x, row[1] - y) + row[4] for row in ends]
    best = min(costs)
    return next(k for k, c in enumerate(costs) if c <= best + WAY_TIE_M)


def flown_ways(polygons: Sequence[np.ndarray], width: float) -> tuple[np.ndarray, ...]:
    """Every way a unit may fly the sweep of ``polygons`` (issue 21: from the end nearest to it,
    not from a fixed corner), read-only: the four ``serpentine`` variants of the first cell (its
    first or its last lane first, either way along it), the other cells then each from the
    nearest end, each path flown forwards and then backwards (a variant that is the reverse of
    an earlier one is listed once).
    Remembered per polygons and width: the cost tables, the sharing of a search and the
    simulated unit ask for the same sweeps."""
    cleaned = [_clean_polygon(poly) for poly in polygons]
    key = tuple((np.ascontiguousarray(c, dtype=float).tobytes(), len(c)) for c in cleaned)
    return _flown_ways(key, _check_width(width))


@functools.lru_cache(maxsize=1024)
def _flown_ways(key: tuple[tuple[bytes, int], ...], width: float) -> tuple[np.ndarray, ...]:
    polys = [np.frombuffer(data, dtype=float).reshape(n, 2) for data, n in key]
    if not polys:
        return ()
    cells = [turns_inside(list(_swept_cells(p, width, None)), width) for p in polys]
    convex = [_convex_area_of(p) is not None for p in polys]
    flown: list[np.ndarray] = []  # (the variants' paths, before their transitions go inside)
    ways: list[np.ndarray] = []
    for variant in range(4):
        parts: list[np.ndarray] = []
        for poly_cells in cells:
            parts.append(_fly_cells(poly_cells, variant) if not parts
                         else _fly_cells(poly_cells, 0, start=parts[-1][-1]))
        path = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=0)  # (each fresh)
        if any(_same_way(path, seen) or _same_way(path[::-1], seen) for seen in flown):
            continue  # (one cell: its last lane first is the reverse of its first lane first)
        flown.append(path)
        # Over a convex area every leg between two points inside stays inside: the way inside
        # is the path itself (``transitions_inside`` would find every leg covered).
        inside = [part if is_convex else transitions_inside(part, poly)
                  for poly, part, is_convex in zip(polys, parts, convex, strict=True)]
        whole = inside[0] if len(inside) == 1 else np.concatenate(inside, axis=0)
        ways += [np.ascontiguousarray(whole), np.ascontiguousarray(whole[::-1])]
    for way in ways:
        way.setflags(write=False)
    return tuple(ways)


def _same_way(a: np.ndarray, b: np.ndarray) -> bool:
    """The same points in the same order (a cell's variants often are: the reverse of one is
    another, to the bit)."""
    return a.shape == b.shape and bool((a == b).all())  # (np.array_equal: same, slower)


def _convex_area_of(poly: np.ndarray) -> float | None:
    """``_convex_area`` (None also for a flat polygon), remembered per polygon."""
    area = _convex_area_cached(np.ascontiguousarray(poly, dtype=float).tobytes(), len(poly))
    return area if area is not None and area > 0.0 else None


@functools.lru_cache(maxsize=1024)
def _convex_area_cached(data: bytes, n: int) -> float | None:
    return _convex_area(np.frombuffer(data, dtype=float).reshape(n, 2))


def turns_inside(cells: list[np.ndarray], width: float) -> list[np.ndarray]:
    """The cells' lanes as flown: each lane end pulled back along the lane so that the unit turns
    inside the area (issue 21: turns on a shared search's part border swept the neighbour's part).

    The footprint is about ``w`` long as well as ``w`` wide (``costs.footprint_width``), so a lane
    ending ``w/2`` before a border perpendicular to it still images up to that border, and the
    connector to the next lane runs ``w/2`` inside it instead of on it. Where the border slants
    across the lane's strip (half-way to each neighbouring lane of the cell) the end is pulled
    back less, so that the footprint still reaches the border's farthest point in the strip
    (cover first: the rest of the overshoot stays). A lane shorter than its pull-backs shrinks to
    its middle point. ``sweep_cells``/``sweep_lanes`` keep the lanes as clipped, and
    ``coverage_path`` flies them as clipped; ``flown_sweep`` flies these."""
    return [_pull_back(cell, _check_width(width)) for cell in cells]


def footprint(track_xy: np.ndarray, width: float) -> shapely.Geometry:
    """What a camera ``width`` m wide (and about as long) sees along the track."""
    if len(track_xy) == 0:
        return shapely.Polygon()
    if len(track_xy) == 1:
        return shapely.Point(track_xy[0]).buffer(width / 2.0, cap_style="square")
    return shapely.LineString(track_xy).buffer(width / 2.0, cap_style="square",
                                               join_style="mitre", mitre_limit=1.5)


def _pull_back(cell: np.ndarray, w: float) -> np.ndarray:
    if len(cell) < 2:  # (no neighbour tells how the border runs: fly it as clipped)
        return cell
    vec = cell[:, 1] - cell[:, 0]
    length = np.hypot(vec[:, 0], vec[:, 1])
    longest = float(length.max())
    if longest <= 0.0:
        return cell
    along = vec[int(np.argmax(length))] / longest  # (every segment of a cell points along)
    x0, x1 = cell[:, 0] @ along, cell[:, 1] @ along
    # Where the border is at the strip's edges: half-way to the neighbouring lanes' ends (the
    # cell's outer lanes: as far again, outwards).
    end_reach, start_reach = _strip_reach(x1, np.maximum), _strip_reach(x0, np.minimum)
    # (np.minimum of np.maximum: np.clip's, without its ~5 us of dispatch)
    pull_end = np.minimum(np.maximum(w / 2.0 - (end_reach - x1), 0.0), w / 2.0)
    pull_start = np.minimum(np.maximum(w / 2.0 - (x0 - start_reach), 0.0), w / 2.0)
    total = pull_end + pull_start
    scale = np.where(total > length, length / np.where(total > 0.0, total, 1.0), 1.0)
    out = cell.copy()
    out[:, 0] += along * (pull_start * scale)[:, None]
    out[:, 1] -= along * (pull_end * scale)[:, None]
    return out


def _strip_reach(x: np.ndarray, farthest: np.ufunc) -> np.ndarray:
    """Per lane (of at least two): the farthest of its end ``x`` and the border's position at
    its strip's two edges, interpolated between neighbouring lanes (extrapolated at the first
    and the last)."""
    mid = (x[1:] + x[:-1]) / 2.0
    # (np.concatenate: np.r_ costs ~10 us a call, and every flown sweep asks four times)
    before = np.concatenate(([x[0] + (x[0] - x[1]) / 2.0], mid))
    after = np.concatenate((mid, [x[-1] + (x[-1] - x[-2]) / 2.0]))
    return np.asarray(farthest(farthest(x, before), after))


# --------------------------------------------------------------------------- sweep direction

#: Most directions tried per polygon (the edges with the most length in their direction win).
MAX_DIRECTIONS = 8
#: Paths whose lengths differ by less than this fraction are equally short (rounding noise).
_SAME_LENGTH = 1e-6
#: Directions closer than this (radians, modulo pi) are one candidate.
_SAME_DIRECTION = 1e-3
#: With more candidates than ``_SCREEN_KEEP`` and more lanes than ``_SCREEN_LANES``, the
#: candidates are first compared at a coarser width (``_SCREEN_LANES`` lanes across the polygon),
#: and only the best few are swept at the real width: the ranking of directions changes little
#: with the width, and a polygon with many edges would otherwise cost one full sweep per edge.
_SCREEN_LANES = 30
_SCREEN_KEEP = 3


def candidate_directions(polygon_xy: np.ndarray | Sequence[Sequence[float]]) -> np.ndarray:
    """Lane directions worth trying (k, 2) unit vectors: the minimum rectangle's two axes and
    every edge's direction (lanes parallel to an edge leave no slanted ends along it: Bahnemann
    et al. 2021), one per direction modulo pi: the long axis first, the short one, then the edge
    directions by angle; at most ``MAX_DIRECTIONS`` of them, those with the most edge length.

    The order and the choice do not depend on rounding noise (the same polygon in another local
    frame, a regular polygon's equal edges): weights are compared to 6 significant digits."""
    poly = _clean_polygon(polygon_xy)
    return _candidates(poly, *sweep_axes(poly))


@functools.lru_cache(maxsize=1024)
def _candidates_of(data: bytes, n: int) -> np.ndarray:
    """``_candidates`` of a cleaned polygon, read-only, remembered: an area is swept at each
    distinct width of the fleet."""
    poly = np.frombuffer(data, dtype=float).reshape(n, 2)
    frame = _sweep_frame(poly)
    out = _candidates(poly, frame.along, frame.across)
    out.setflags(write=False)
    return out


def _candidates(poly: np.ndarray, along: np.ndarray, across: np.ndarray) -> np.ndarray:
    """``candidate_directions`` of a cleaned polygon whose rectangle's axes are known (plain
    Python: a polygon has a few to a few dozen edges, where numpy's per-call cost dominated)."""
    pts: list[list[float]] = poly.tolist()
    n = len(pts)
    pairs = []
    for i in range(n):
        dx, dy = pts[(i + 1) % n][0] - pts[i][0], pts[(i + 1) % n][1] - pts[i][1]
        length = math.hypot(dx, dy)
        if length > 0.0:
            pairs.append((math.atan2(dy, dx) % math.pi, length))
    chosen: list[float] = []
    weight: list[float] = []
    for a, ln in sorted(pairs, key=lambda x: -x[1]):
        for i, b in enumerate(chosen):
            d = abs(a - b) % math.pi
            if min(d, math.pi - d) < _SAME_DIRECTION:
                weight[i] += ln
                break
        else:
            chosen.append(a)
            weight.append(ln)
    top = max(weight, default=1.0)
    ranked = sorted(range(len(chosen)), key=lambda i: (-round(weight[i] / top, 6), chosen[i]))
    kept = sorted(chosen[i] for i in ranked[:MAX_DIRECTIONS])
    out = [(float(along[0]), float(along[1])), (float(across[0]), float(across[1]))]
    same = math.cos(_SAME_DIRECTION)
    for a in kept:
        x, y = math.cos(a), math.sin(a)
        h = math.hypot(x, y)
        x, y = x / h, y / h
        if x < -1e-12 or (abs(x) <= 1e-12 and y < 0):  # (``_canonical``)
            x, y = -x, -y
        if all(abs(x * ux + y * uy) < same for ux, uy in out):
            out.append((x, y))
    return np.array(out)


def _flown_length(poly: np.ndarray, width: float, along: np.ndarray, fill: bool = False
                  ) -> tuple[float, int]:
    """(path length, lane segments) of the sweep along ``along``: the criterion for choosing
    (``fill``: with the lanes for unseen strips, ``_swept``; a convex area has none, and is
    remembered as filled: the winner's cells are then asked for filled, ``_swept_cells``)."""
    fill = fill or _convex_area_of(poly) is not None
    _, path, segments = _swept(np.ascontiguousarray(poly, dtype=float).tobytes(), len(poly),
                               float(width), float(along[0]), float(along[1]), fill)
    return path_length(path), segments


def sweep_direction(polygon_xy: np.ndarray | Sequence[Sequence[float]], width: float) -> np.ndarray:
    """The lane direction (a unit vector) whose coverage path is the shortest among
    ``candidate_directions``, turns and transitions between cells included (fewer lane segments
    break ties). Remembered per polygon and width."""
    poly = _clean_polygon(polygon_xy)
    return _direction(poly, width, None)


@functools.lru_cache(maxsize=1024)
def _best_direction(data: bytes, n: int, width: float) -> np.ndarray:
    poly = np.frombuffer(data, dtype=float).reshape(n, 2)
    frame = _sweep_frame(poly)
    every = _candidates_of(data, n)
    candidates = every
    short_side = frame.y_hi - frame.y_lo
    if short_side / width > _SCREEN_LANES and len(candidates) > _SCREEN_KEEP:
        coarse = short_side / _SCREEN_LANES
        rough = np.array([_flown_length(poly, coarse, v)[0] for v in candidates])
        bar = np.sort(rough)[_SCREEN_KEEP - 1] * (1.0 + _SAME_LENGTH)
        keep = rough <= bar
        keep[0] = True  # (the long axis always stays)
        # (not ``np.union1d``: numpy 2's ``unique`` imports ``numpy.ma`` on first use, 30-50 ms
        # of the first plan in a process)
        candidates = candidates[np.flatnonzero(keep)]
    area = _convex_area_cached(data, n)
    scores: dict[int, tuple[float, int]] = {}  # candidate -> (path length, lane segments)
    shortest = math.inf
    for i, v in enumerate(candidates):
        if (area is not None and shortest < math.inf
                and _convex_floor(poly, area, width, v) > shortest * (1 + _SAME_LENGTH)):
            continue  # (it cannot be among the shortest: not swept)
        scores[i] = _flown_length(poly, width, v)
        shortest = min(shortest, scores[i][0])
    if area is None:
        unfilled = shortest
        scores, shortest = _with_gap_lanes(poly, width, candidates, scores)
        if shortest > unfilled * (1 + _SAME_LENGTH) and len(candidates) < len(every):
            # The screen ranked the directions without those lanes: all are swept after all.
            candidates = every
            scores = {i: _flown_length(poly, width, v) for i, v in enumerate(every)}
            scores, shortest = _with_gap_lanes(poly, width, candidates, scores)
    near = [i for i, (length, _) in scores.items() if length <= shortest * (1 + _SAME_LENGTH)]
    best = min(near, key=lambda i: (scores[i][1], i))  # fewer segments, then the earlier
    chosen = np.array(candidates[best])
    chosen.setflags(write=False)
    return chosen


def _with_gap_lanes(poly: np.ndarray, width: float, candidates: np.ndarray,
                    scores: dict[int, tuple[float, int]]
                    ) -> tuple[dict[int, tuple[float, int]], float]:
    """A concave area's candidates judged with the lanes its unseen strips need
    (``_gap_lanes``): in order of their length without them, until that length alone is longer
    than the shortest found with them (adding lanes never shortens a path), so only the few that
    can win pay for GEOS. Returns (scores with them, the shortest)."""
    judged: dict[int, tuple[float, int]] = {}
    shortest = math.inf
    for i in sorted(scores, key=lambda i: (scores[i][0], i)):
        if scores[i][0] > shortest * (1 + _SAME_LENGTH):
            break
        judged[i] = _flown_length(poly, width, candidates[i], fill=True)
        shortest = min(shortest, judged[i][0])
    return judged, shortest


def _convex_area(poly: np.ndarray) -> float | None:
    """The polygon's area when it is convex (every turn the same way, once around), else None.
    Plain Python: polygons have a few to a few dozen vertices, where numpy's per-call cost
    dominated."""
    pts: list[list[float]] = poly.tolist()
    n = len(pts)
    edges = [(pts[(i + 1) % n][0] - pts[i][0], pts[(i + 1) % n][1] - pts[i][1]) for i in range(n)]
    left = right = False
    turning = 0.0
    for i in range(n):
        (ax, ay), (bx, by) = edges[i], edges[(i + 1) % n]
        cross = ax * by - ay * bx
        left, right = left or cross > 0.0, right or cross < 0.0
        if left and right:
            return None
        turning += math.atan2(cross, ax * bx + ay * by)
    if abs(abs(turning) - 2.0 * math.pi) > 1e-6:
        return None  # (a star: it winds more than once)
    twice = sum(pts[i][0] * pts[(i + 1) % n][1] - pts[(i + 1) % n][0] * pts[i][1]
                for i in range(n))
    return 0.5 * abs(twice)


def _convex_floor(poly: np.ndarray, area: float, width: float, along: np.ndarray) -> float:
    """A lower bound of the sweep's path along ``along`` over a convex polygon, without clipping
    a lane: the chord length across a convex polygon is a concave function, so the ``n`` lanes
    through the middles of strips of height ``h = H / n`` are together at least ``A / h`` long
    (the midpoint rule over-estimates a concave integral), and each of the ``n - 1`` connectors
    is at least ``h``."""
    along = _canonical(np.asarray(along, dtype=float))
    across = np.array([-along[1], along[0]])
    qy = poly @ across
    height = float(qy.max()) - float(qy.min())
    n = _lane_count(height, width)
    if height <= 0.0:
        return 0.0
    h = height / n
    return area / h + (n - 1) * h


def path_length(path_xy: np.ndarray) -> float:
    """Length (m) of a polyline given as (K, 2) east/north."""
    path = np.asarray(path_xy, dtype=float)
    if len(path) < 2:
        return 0.0
    step = path[1:] - path[:-1]  # (np.diff and np.hypot(*step.T): the same, slower)
    return float(np.hypot(step[:, 0], step[:, 1]).sum())


def coverage_length(
    polygon_xy: np.ndarray | Sequence[Sequence[float]], width: float,
    along: np.ndarray | None = None,
) -> float:
    """The length (m) of ``coverage_path(polygon_xy, width, along=along)``."""
    return path_length(coverage_path(polygon_xy, width, along=along))


def coverage_estimate(
    polygon_xy: np.ndarray | Sequence[Sequence[float]], width: float,
    along: np.ndarray | None = None,
) -> float:
    """The closed-form estimate ``A / w + (n - 1) * w`` (docs/plan.md §2.4), for checks and quick
    bounds.

    ``A`` is the polygon's own area (not its convex hull's) and ``n`` the lane count of
    ``sweep_lanes`` (along ``along``, default ``sweep_direction``). It matches ``coverage_length``
    within a few per cent for convex polygons; for a concave one the path also has transitions
    between its cells and is usually longer.
    """
    poly = _clean_polygon(polygon_xy)
    w = _check_width(width)
    along = _direction(poly, w, along)
    across = np.array([-along[1], along[0]])
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

    The first polygon is flown as ``coverage_path`` flies it; each later one starting from the
    cell and variant nearest to where the previous one ended; straight connectors between them.
    """
    parts: list[np.ndarray] = []
    for poly in polygons:
        cells = sweep_cells(poly, width)
        if not parts:
            parts.append(_fly_cells(cells, 0))
        else:
            parts.append(_fly_cells(cells, 0, start=parts[-1][-1]))
    if not parts:
        return np.zeros((0, 2))
    return np.concatenate(parts, axis=0)
