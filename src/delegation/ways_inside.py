"""The shortest way inside a polygon between two points (issue 21): a sweep's transition between
cells that would cut across a concave notch goes round it instead, so that a unit stays over
its own part of a shared search. A visibility graph over the region's reflex corners (and its
holes' vertices) searched with Dijkstra; pure geometry (shapely, numpy), no clock.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import shapely
from shapely.geometry import Polygon


def transitions_inside(path: np.ndarray, polygon_xy: np.ndarray) -> np.ndarray:
    """``path`` with every straight leg that leaves the polygon (a transition between cells
    across a concave notch) replaced by the shortest way inside it, through its corners: the
    unit stays over its own part instead of flying over a neighbour's."""
    if len(path) < 3:
        return path
    poly = np.ascontiguousarray(polygon_xy, dtype=float)
    room = _room(poly.tobytes(), len(poly))
    legs = shapely.linestrings(np.stack([path[:-1], path[1:]], axis=1))
    out_of = ~shapely.covers(room, legs)
    if not out_of.any():
        return path
    corners, among = _graph(poly.tobytes(), len(poly))
    out = [path[:1]]
    for k in range(len(path) - 1):
        if out_of[k]:
            out.append(_route_inside(path[k], path[k + 1], corners, room, among)[1:])
        else:
            out.append(path[k + 1 : k + 2])
    return np.concatenate(out, axis=0)


@functools.lru_cache(maxsize=256)
def _room(data: bytes, n: int) -> shapely.Geometry:
    """The region (a hair larger, prepared) in which a leg is inside, remembered per polygon:
    each way to fly a sweep (``coverage.flown_ways``) asks about the same area."""
    poly = np.frombuffer(data, dtype=float).reshape(n, 2)
    scale = max(1.0, float(np.ptp(poly, axis=0).max()))
    room = shapely.make_valid(Polygon(poly)).buffer(1e-6 * scale)
    shapely.prepare(room)
    return room


@functools.lru_cache(maxsize=256)
def _graph(data: bytes, n: int) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """(the corners where a way inside may bend, the pairs of them that see each other),
    remembered per polygon."""
    poly = np.frombuffer(data, dtype=float).reshape(n, 2)
    corners = _corners(shapely.make_valid(Polygon(poly)))
    i, j = np.triu_indices(len(corners), k=1)
    seen = _sight(_room(data, n), corners[i], corners[j])
    return corners, (i[seen], j[seen])


def _corners(shape: shapely.Geometry) -> np.ndarray:
    """Where a shortest way inside the region may bend: its exteriors' reflex vertices and its
    holes' vertices."""
    out = []
    for p in shapely.get_parts(shape):
        if not isinstance(p, Polygon):
            continue
        ring = np.asarray(shapely.get_coordinates(p.exterior))[:-1]
        d_in, d_out = ring - np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0) - ring
        turn = d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0]
        ccw = p.exterior.is_ccw
        out.append(ring[turn < 0] if ccw else ring[turn > 0])
        out += [np.asarray(shapely.get_coordinates(r))[:-1] for r in p.interiors]
    return np.concatenate(out) if out else np.zeros((0, 2))


def _sight(room: shapely.Geometry, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a),) True where the straight leg a[k] -> b[k] stays inside ``room``."""
    if len(a) == 0:
        return np.zeros(0, dtype=bool)
    return np.asarray(shapely.covers(room, shapely.linestrings(np.stack([a, b], axis=1))))


def _route_inside(a: np.ndarray, b: np.ndarray, corners: np.ndarray, room: shapely.Geometry,
                  among: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The shortest polyline from ``a`` to ``b`` inside ``room`` bending only at ``corners``
    (Dijkstra on the visibility graph; ``among``: the corner pairs that see each other); the
    straight leg when there is none."""
    n = len(corners) + 2
    nodes = np.vstack([a[None, :], b[None, :], corners])
    ends = np.repeat([0, 1], len(corners))
    others = np.tile(np.arange(2, n), 2)
    seen = _sight(room, nodes[ends], nodes[others])
    i = np.concatenate([ends[seen], among[0] + 2])
    j = np.concatenate([others[seen], among[1] + 2])
    length = np.hypot(*(nodes[i] - nodes[j]).T)
    near: list[list[tuple[int, float]]] = [[] for _ in range(n)]
    for u, v, d in zip(i.tolist(), j.tolist(), length.tolist(), strict=True):
        near[u].append((v, d))
        near[v].append((u, d))
    best, before, done = [math.inf] * n, [-1] * n, [False] * n
    best[0] = 0.0
    while True:
        u = min((k for k in range(n) if not done[k]), key=lambda k: best[k], default=-1)
        if u < 0 or not math.isfinite(best[u]) or u == 1:
            break
        done[u] = True
        for v, d in near[u]:
            if best[u] + d < best[v]:
                best[v], before[v] = best[u] + d, u
    if not math.isfinite(best[1]):
        return np.stack([a, b])
    way = [1]
    while way[-1] != 0:
        way.append(before[way[-1]])
    return nodes[way[::-1]]
