"""Sharing one search area among several units (DESIGN 3.11): how much each unit gets, and where.

Pure geometry and arithmetic (numpy, shapely): no network, no clock.

How much: each unit ``i`` that may take part can start sweeping at ``a_i`` (when it is free of
what it must do first, plus its flight to the area) and sweeps ``r_i`` m2/s (speed x sweep width,
over the sweep's overhead); it can sweep at most ``cap_i`` m2 within its endurance. All parts end
together at the ``T`` with ``sum_i min(cap_i, r_i max(0, T - a_i)) = A`` (water filling: a unit
busy elsewhere, slow or with a narrow sweep gets less, or nothing when ``a_i >= T``). A part under
``MIN_SHARE`` of the area is not worth a unit's flight: that unit is left out and the rest
re-filled. Without ``cap`` the same equation with the raw rates is the lower bound of 3.11.

Where: recursive bisection. The units are ordered by where they come from along the area's long
axis and split in two groups of about equal share; the area is cut across its long axis where the
first group's share of it lies on the near side; each side is divided among its group the same
way. Parts are therefore compact (cut across their longest extent each time), inside the area, and
cover it exactly (up to the cut's numerical tolerance); a cut through a concave area can leave a
part in several pieces (sent as a ``search-areas``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon

#: The tasks that may be shared, and the task a part is sent as (one piece; several pieces:
#: ``search-areas``).
SHAREABLE = ("search-area", "search-areas", "search-around-position")
#: Sweep overhead (path / (A / w)) assumed when sizing parts: benchmarks/team_search.py measures
#: 1.07 on concave areas, parts being smaller than whole areas pay a little more for their turns.
PLAN_OVERHEAD = 1.10
#: A part smaller than this fraction of the area is not worth a unit's flight there.
MIN_SHARE = 0.04
#: Relative tolerance of a cut's area.
_CUT_TOL = 1e-6


@dataclass(frozen=True, slots=True)
class Sharer:
    """A unit that may sweep part of an area: ``key`` identifies it to the caller."""

    key: int
    arrive: float  # s from mission start until it can start sweeping (travel included)
    rate: float  # m2/s it sweeps
    cap: float = math.inf  # m2 it can sweep within its endurance
    point: tuple[float, float] = (0.0, 0.0)  # where it comes from (east, north, m)


def fill_time(area: float, sharers: Sequence[Sharer]) -> float:
    """The ``T`` at which ``sum_i min(cap_i, rate_i max(0, T - arrive_i)) = area`` (inf when
    the caps together are short of it; the earliest arrival when ``area`` is 0).

    Exact, in plain Python: the left side is piecewise linear in ``T`` (each unit adds its rate
    from its arrival until its cap is swept), so one pass over those breakpoints in time order
    finds the segment where it reaches ``area`` (a numpy bisection cost ~0.5 ms a call; the
    planner asks once per search and unit set)."""
    if not sharers:
        return math.inf
    if area <= 0.0:
        return min(s.arrive for s in sharers)
    sweeping = [s for s in sharers if s.rate > 0.0 and s.cap > 0.0]
    if sum(s.cap for s in sweeping) < area * (1.0 - 1e-12):
        return math.inf
    events: list[tuple[float, float]] = []  # (time, change of the swept rate)
    for s in sweeping:
        events.append((s.arrive, s.rate))
        if math.isfinite(s.cap):
            events.append((s.arrive + s.cap / s.rate, -s.rate))
    events.sort()
    swept, slope, now = 0.0, 0.0, events[0][0]
    for when, change in events:
        reach = swept + slope * (when - now)
        if reach >= area and slope > 0.0:
            return now + (area - swept) / slope
        swept, now, slope = reach, when, slope + change
    if swept >= area * (1.0 - 1e-12):  # (the caps together are just enough)
        return now
    # Only uncapped units sweep on (their rates: the capped ones' cancelled out, up to rounding).
    return now + (area - swept) / sum(s.rate for s in sweeping if not math.isfinite(s.cap))


def shares(area: float, sharers: Sequence[Sharer]) -> dict[int, float]:
    """Area (m2) per sharer key, the water filling of the module docstring: every part ends at
    the same time, none is smaller than ``MIN_SHARE`` of the area; empty when the sharers' caps
    together are short of it."""
    left = list(sharers)
    while left:
        t = fill_time(area, left)
        if not math.isfinite(t):
            return {}
        got = {s.key: min(s.cap, s.rate * max(0.0, t - s.arrive)) for s in left}
        small = [s for s in left if got[s.key] < MIN_SHARE * area]
        if not small:
            total = sum(got.values())
            return {k: v * area / total for k, v in got.items()}  # (exact sum despite bisection)
        # Drop the smallest useful-looking part only, then fill again: the others grow.
        drop = min(small, key=lambda s: got[s.key])
        left = [s for s in left if s.key != drop.key]
    return {}


def lower_bound(area: float, sharers: Sequence[Sharer]) -> float:
    """DESIGN 3.11's bound: ``sum_i r_i max(0, T - a_i) = A`` with no caps and no minimum part."""
    return fill_time(area, [Sharer(s.key, s.arrive, s.rate) for s in sharers])


# --------------------------------------------------------------------------- geometry


def _long_axis(region: shapely.Geometry) -> np.ndarray:
    """The unit vector along the longer side of the region's minimum rotated rectangle."""
    with np.errstate(divide="ignore", invalid="ignore"):
        rect = shapely.minimum_rotated_rectangle(region)
    pts = shapely.get_coordinates(rect)
    if len(pts) < 3:
        return np.array([1.0, 0.0])
    e1, e2 = pts[1] - pts[0], pts[2] - pts[1]
    along = e1 if np.hypot(*e1) >= np.hypot(*e2) else e2
    norm = float(np.hypot(*along))
    return np.array([1.0, 0.0]) if norm == 0.0 else along / norm


def _half(region: shapely.Geometry, axis: np.ndarray, cut: float, far: bool = False
          ) -> shapely.Geometry:
    """The part of ``region`` whose projection on ``axis`` is at most ``cut`` (``far``: at
    least): both sides are intersections with a rectangle, which GEOS computes robustly (a
    ``difference`` of nearly touching polygons can come out wrong)."""
    xy = shapely.get_coordinates(region)
    proj = xy @ axis
    across = np.array([-axis[1], axis[0]])
    side = xy @ across
    lo, hi = (cut, float(proj.max()) + 1.0) if far else (float(proj.min()) - 1.0, cut)
    bottom, top = float(side.min()) - 1.0, float(side.max()) + 1.0
    corners = np.array([[lo, bottom], [hi, bottom], [hi, top], [lo, top]])
    world = corners[:, :1] * axis + corners[:, 1:] * across
    return shapely.intersection(region, Polygon(world))


def band(region: shapely.Geometry, axis: np.ndarray, lo: float, hi: float) -> shapely.Geometry:
    """The part of ``region`` whose projection on ``axis`` lies between ``lo`` and ``hi``."""
    near = _areal(_half(region, axis, hi))
    return near if near.is_empty else _areal(_half(near, axis, lo, far=True))


def extent(region: shapely.Geometry, axis: np.ndarray) -> tuple[float, float]:
    """The smallest and largest projection of ``region``'s points on ``axis``."""
    proj = shapely.get_coordinates(region) @ axis
    return float(proj.min()), float(proj.max())


def cut(region: shapely.Geometry, axis: np.ndarray, fraction: float
        ) -> tuple[shapely.Geometry, shapely.Geometry]:
    """(near, far): ``region`` cut across ``axis`` so that ``near`` (low projections) holds
    ``fraction`` of its area; ``far`` is the rest (the other side of the same line).

    The near side's area grows monotonically with the line's position: regula falsi (the
    Illinois variant) finds it in a few intersections where halving the interval took ~20."""
    lo, hi = extent(region, axis)
    total = float(region.area)
    target = fraction * total

    def near_less_target(line: float) -> float:
        return float(_half(region, axis, line).area) - target

    def close(f: float, lo: float, hi: float) -> bool:
        return abs(f) <= _CUT_TOL * total or hi - lo <= _CUT_TOL * max(1.0, abs(hi))

    _, line = falsi(near_less_target, (lo, -target), (hi, total - target), 80, close)
    near, far = _half(region, axis, line), _half(region, axis, line, far=True)
    return _areal(near), _areal(far)


def falsi(f: Callable[[float], float], low: tuple[float, float], high: tuple[float, float],
          steps: int, done: Callable[[float, float, float], bool]) -> tuple[float, float]:
    """Regula falsi (the Illinois variant) for where the increasing ``f`` crosses 0 between
    ``low`` and ``high`` ((x, f(x)) each, f negative at ``low``, positive at ``high``): at most
    ``steps`` evaluations, stopping at the first ``x`` where ``done(f(x), lo, hi)`` (the
    bracket before it). Returns (the last ``x`` found with ``f(x) <= 0``, or ``low``'s; the
    last ``x`` tried). ``cut`` places its line with it, ``share_plan`` a strip's edge."""
    (lo, f_lo), (hi, f_hi) = low, high
    side, line = 0, 0.5 * (lo + hi)
    for _ in range(steps):
        line = hi - f_hi * (hi - lo) / (f_hi - f_lo) if f_hi != f_lo else 0.5 * (lo + hi)
        if not lo < line < hi:
            line = 0.5 * (lo + hi)
        value = f(line)
        if done(value, lo, hi):
            return (line if value <= 0.0 else lo), line
        if value < 0.0:
            lo, f_lo = line, value
            if side == -1:
                f_hi *= 0.5
            side = -1
        else:
            hi, f_hi = line, value
            if side == 1:
                f_lo *= 0.5
            side = 1
    return lo, line


def _areal(geom: shapely.Geometry) -> shapely.Geometry:
    """Only the polygons of ``geom`` (a cut may leave lines or points on the boundary)."""
    parts = [p for p in shapely.get_parts(geom) if isinstance(p, Polygon) and p.area > 0.0]
    if len(parts) == 1:
        return parts[0]
    return MultiPolygon(parts) if parts else Polygon()


def divide(region: shapely.Geometry, wanted: dict[int, float],
           points: dict[int, tuple[float, float]], axis: np.ndarray | None = None,
           order: Sequence[int] | None = None) -> dict[int, shapely.Geometry]:
    """Key -> part of ``region`` with area proportional to ``wanted[key]`` (recursive bisection,
    module docstring); ``points`` (where each key's unit comes from) orders the keys along each
    cut's axis so that a unit gets the side it comes from. With ``axis`` every cut is across it
    (strips) instead of across each piece's long axis; with ``order`` the keys lie along the axis
    in that order instead (``share_plan`` tries other cuts when the usual parts do not fit their
    units' endurance)."""
    keys = [k for k, v in wanted.items() if v > 0.0]
    if not keys:
        return {}
    if len(keys) == 1:
        return {keys[0]: region}
    along = _long_axis(region) if axis is None else axis
    if order is None:
        keys.sort(key=lambda k: (float(np.dot(points[k], along)), k))
    else:
        rank = {k: i for i, k in enumerate(order)}
        keys.sort(key=lambda k: (rank.get(k, len(rank)), k))
    weights = np.array([wanted[k] for k in keys], dtype=float)
    running = np.cumsum(weights)[:-1] / weights.sum()
    split = int(np.argmin(np.abs(running - 0.5))) + 1  # the two groups of closest share
    near, far = cut(region, along, float(running[split - 1]))
    out = divide(near, {k: wanted[k] for k in keys[:split]}, points, axis, order)
    out.update(divide(far, {k: wanted[k] for k in keys[split:]}, points, axis, order))
    return out


def pieces_xy(part: shapely.Geometry) -> list[np.ndarray]:
    """The part's polygons as (N, 2) exterior rings (not closed), largest first."""
    polys = sorted((p for p in shapely.get_parts(part) if isinstance(p, Polygon)),
                   key=lambda p: -p.area)
    return [np.asarray(shapely.get_coordinates(p.exterior))[:-1] for p in polys]


def region_of(polygons: Sequence[np.ndarray]) -> shapely.Geometry:
    """One (valid) shapely region from a search's polygons (their union). Remembered for the
    last areas seen: planning asks for the same search's region several times (its bound, its
    sharers, each refinement), and the geometry is immutable."""
    key = tuple((np.ascontiguousarray(p, dtype=float).tobytes(), len(p)) for p in polygons)
    return _region_of(key)


@functools.lru_cache(maxsize=256)
def _region_of(key: tuple[tuple[bytes, int], ...]) -> shapely.Geometry:
    polygons = [np.frombuffer(data, dtype=float).reshape(n, 2) for data, n in key]
    shapes = [shapely.make_valid(Polygon(p)) for p in polygons]
    return _areal(shapely.union_all(shapes)) if len(shapes) > 1 else _areal(shapes[0])


def thinness(part: shapely.Geometry) -> float:
    """The short side of the part's minimum rotated rectangle (m): how thin it is."""
    with np.errstate(divide="ignore", invalid="ignore"):
        rect = shapely.minimum_rotated_rectangle(part)
    pts = shapely.get_coordinates(rect)
    if len(pts) < 3:
        return 0.0
    return float(min(np.hypot(*(pts[1] - pts[0])), np.hypot(*(pts[2] - pts[1]))))


__all__ = ["MIN_SHARE", "PLAN_OVERHEAD", "SHAREABLE", "Sharer", "band", "cut", "divide", "extent",
           "falsi", "fill_time", "lower_bound", "pieces_xy", "region_of", "shares", "thinness"]
