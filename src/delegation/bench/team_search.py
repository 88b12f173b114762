"""The team-search family (DESIGN 3.11, issue 21): concave areas and heterogeneous fleets.

Deterministic (fixed seeds), shared by ``benchmarks/team_search.py``, ``benchmarks/flown.py`` and
``delegation bench --generate --family team-search``. The polygons are coastline-like radial
shapes with bays, and L, U, comb, crescent and star shapes, each scaled to 0.2-4 km2 (the
published multi-robot coverage benchmark's polygons cannot be downloaded here). A fleet is 3-6
units placed 0.5-2.5 km from the area: drones at 2.5-4 m/s standard (37 m lanes), and a boat
(9 m lanes) in every other fleet.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from shapely.geometry import Point, Polygon

from delegation.fleet import UnitState, make_unit
from delegation.geo import GeoPoint, LocalFrame
from delegation.tst import TstNode, make_node

#: Where the family's areas are placed (Gränsö).
FRAME = LocalFrame(57.76, 16.68)
#: What every unit of the family offers.
TASKS = ("move-to", "move-path", "search-area", "search-areas", "search-around-position")
#: Areas (km2) the shapes are scaled to, in turn.
AREAS_KM2 = (0.2, 0.5, 1.0, 2.0, 4.0)


def _coast(seed: int, n: int = 48) -> np.ndarray:
    """A star-shaped polygon with a ragged, coastline-like boundary and two or three deep bays."""
    rng = random.Random(seed)
    bays = [(rng.uniform(0, 2 * math.pi), rng.uniform(0.25, 0.5), rng.uniform(0.2, 0.45))
            for _ in range(rng.randint(2, 3))]
    pts = []
    for i in range(n):
        a = 2 * math.pi * i / n
        r = 1.0 + 0.12 * rng.uniform(-1, 1)
        for centre, width, depth in bays:
            d = abs((a - centre + math.pi) % (2 * math.pi) - math.pi)
            if d < width:
                r -= depth * (1 - d / width)
        stretch = 1.6 if seed % 2 else 1.0
        pts.append((stretch * r * math.cos(a), r * math.sin(a)))
    return np.array(pts)


def _shapes() -> dict[str, np.ndarray]:
    shapes = {
        "L": np.array([[0, 0], [3, 0], [3, 1], [1, 1], [1, 3], [0, 3]], dtype=float),
        "U": np.array([[0, 0], [3, 0], [3, 2], [2, 2], [2, 1], [1, 1], [1, 2], [0, 2]],
                      dtype=float),
        "comb": np.array([[0, 0], [5, 0], [5, 3], [4, 3], [4, 1], [3, 1], [3, 3], [2, 3],
                          [2, 1], [1, 1], [1, 3], [0, 3]], dtype=float),
        "crescent": np.array(
            [[math.cos(a), math.sin(a)] for a in np.linspace(0.0, math.pi, 24)]
            + [[0.6 * math.cos(a), 0.45 * math.sin(a)] for a in np.linspace(math.pi, 0.0, 24)]
        ),
        "star": np.array([[(1.0 if i % 2 == 0 else 0.5) * math.cos(math.pi * i / 5 + 0.3),
                           (1.0 if i % 2 == 0 else 0.5) * math.sin(math.pi * i / 5 + 0.3)]
                          for i in range(10)]),
    }
    for seed in range(5):
        shapes[f"coast{seed}"] = _coast(seed)
    return shapes


def concave_polygons() -> dict[str, np.ndarray]:
    """Name -> (N, 2) polygon in metres (east/north in ``FRAME``): every shape rotated by a fixed
    angle and scaled to one of ``AREAS_KM2`` in turn (deterministic)."""
    out = {}
    for i, (name, shape) in enumerate(sorted(_shapes().items())):
        area_km2 = AREAS_KM2[i % len(AREAS_KM2)]
        a = math.radians(17.0 * i + 5.0)
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        centred = (shape - shape.mean(axis=0)) @ rot.T
        scale = math.sqrt(area_km2 * 1e6 / Polygon(centred).area)
        out[f"{name}-{area_km2:g}km2"] = centred * scale
    return out


def geo_at(x: float, y: float, altitude: float = 40.0) -> dict[str, float]:
    """The wire GeoPoint of (east, north) m in ``FRAME``."""
    lat, lon = FRAME.to_geo(x, y)
    return {"latitude": float(lat), "longitude": float(lon), "altitude": altitude}


def unit_at(name: str, kind: str, x: float, y: float, **kw: object) -> UnitState:
    """A unit of type ``kind`` offering ``TASKS`` at (east, north) m in ``FRAME``."""
    lat, lon = FRAME.to_geo(x, y)
    point = GeoPoint(latitude=float(lat), longitude=float(lon), altitude=0.0)
    return make_unit(name, kind, point, TASKS, **kw)  # type: ignore[arg-type]


def fleet(seed: int, poly: np.ndarray, endurance: float | None = None) -> list[UnitState]:
    """3-6 units around the area: drones at 2.5-4 m/s standard (``endurance`` s each, None: no
    limit), one boat in every other fleet."""
    rng = random.Random(seed)
    n = 3 + seed % 4
    reach = float(np.hypot(*(poly - poly.mean(axis=0)).T).max())
    units = []
    for i in range(n):
        a = rng.uniform(0.0, 2.0 * math.pi)
        r = reach + rng.uniform(500.0, 2500.0)
        boat = i == n - 1 and seed % 2 == 0
        std = rng.uniform(2.5, 4.0) if not boat else 2.5
        units.append(unit_at(f"{'usv' if boat else 'dji'}{i}", "surface" if boat else "air",
                             r * math.cos(a), r * math.sin(a),
                             speeds={"slow": std / 2, "standard": std, "fast": 2 * std},
                             endurance=None if boat else endurance))
    return units


def search_node(poly: np.ndarray) -> TstNode:
    """A free ``search-area`` over ``poly`` (execunit ``*``): the family's mission."""
    return make_node("search-area", execunit="*", params={
        "area": [geo_at(x, y) for x, y in poly], "speed": "standard", "target-size": 2.0})


# --------------------------------------------------------------------------- bench --generate

#: Every third generated case (seed % 3 == 2) gives each drone its flight to the area and this
#: share of what it would need to sweep the area alone (at a 1.1 sweep overhead): no drone can
#: do it alone, two or more together can, with slack (the boat has no limit).
ENDURANCE_SHARE = 0.5
#: Drones' sweep width (m) in the family (40 m up, a 60 degree camera).
DRONE_WIDTH = 37.0


def _wire(x: float, y: float, altitude: float) -> dict[str, float]:
    point = geo_at(x, y, altitude)
    return {k: round(v, 7) if k != "altitude" else v for k, v in point.items()}


def _short_endurance(poly: np.ndarray, units: Sequence[UnitState]) -> list[UnitState]:
    """The drones of ``units`` with an endurance (s, whole) of their flight to the area and
    ``ENDURANCE_SHARE`` of their own sweep of it alone (at a 1.1 sweep overhead)."""
    area = Polygon(poly)
    out = []
    for u in units:
        if u.agent_type == "air":
            speed = u.speeds["standard"]
            flight = area.distance(Point(FRAME.point_xy(u.position))) / speed
            alone = 1.1 * float(area.area) / (DRONE_WIDTH * speed)
            u = replace(u, endurance=float(round(flight + ENDURANCE_SHARE * alone)))
        out.append(u)
    return out


def team_scenario(seed: int) -> dict[str, Any]:
    """One team-search case as a scenario dict (docs/scenarios.md): the ``seed``-th polygon of
    ``concave_polygons`` (in turn), a 3-6 unit ``fleet`` from ``seed``, one free
    ``search-area``; every third seed an endurance case (``ENDURANCE_SHARE``)."""
    polygons = concave_polygons()
    name = sorted(polygons)[seed % len(polygons)]
    poly = polygons[name]
    units = fleet(seed, poly)
    endurance_case = seed % 3 == 2
    if endurance_case:
        units = _short_endurance(poly, units)
    agents = []
    for u in units:
        x, y = FRAME.point_xy(u.position)
        agent: dict[str, Any] = {
            "name": u.name, "type": u.agent_type, "position": _wire(x, y, 0.0),
            "tasks": sorted(u.tasks), "speeds": {k: round(v, 3) for k, v in u.speeds.items()}}
        if u.endurance is not None:
            agent["endurance"] = float(u.endurance)
        agents.append(agent)
    search = {"name": "search-area", "common_params": {"execunit": "*"},
              "params": {"area": [_wire(x, y, 40.0) for x, y in poly], "speed": "standard",
                         "target-size": 2.0}}
    kind = "endurance" if endurance_case else "free"
    return {
        "name": f"team-{name}-u{len(units)}-s{seed}",
        "description": (f"Team search (seed {seed}, {kind}): {name}, concave, searched by "
                        f"{len(units)} units 0.5-2.5 km away (delegation.bench.team_search)."),
        "agents": agents,
        "mission": search,
    }


def team_bound(tree: TstNode, units: Sequence[UnitState]) -> float | None:
    """The largest DESIGN 3.11 lower bound (s) among the tree's shareable searches, every unit
    free at the start (no plan ends before it); None without one."""
    from delegation.allocation.problem import build_problem, flatten_tree
    from delegation.allocation.share_plan import search_bound, shareable
    from delegation.costs import cost_tables
    from delegation.tst import with_defaults, with_uuids

    prepared = with_defaults(with_uuids(tree))
    nodes = [node for _, node in flatten_tree(prepared)[1]]
    if not any(shareable(n) for n in nodes):
        return None
    tables = cost_tables(list(units), nodes)
    problem = build_problem(prepared, list(units), tables)
    bounds = [search_bound(problem, tables, None, t) for t, task in enumerate(problem.tasks)
              if shareable(task.node)]
    finite = [b for b in bounds if math.isfinite(b)]
    return max(finite) if finite else None
