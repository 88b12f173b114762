"""What the map draws for a plan: each task's geometry and each unit's planned route (pure).

A task is a ``point`` (move-to, observe-position, land, look-at-position), a ``path`` (move-path,
navigate, take-off's path) or an ``area`` (search-area, each polygon of search-areas, and the
circle of search-around-position as a 24-gon). A part of a search shared among units (the plan's
``shared-searches``, DESIGN 3.11) is a task of its own, in its unit's colour, that names the
operator's search (``part-of``) and says which part it is (``part``: "2/3"). A unit's planned
route is where it was when the plan was made, then the points of its vehicle tasks in the plan's
order (an area's vertices; the sweep itself is the unit's business). Look-at tasks move only
the camera: drawn, not routed.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from typing import Any

from delegation.errors import DelegationError
from delegation.tst.catalogue import is_vehicle_task
from delegation.tst.node import parse_tree, walk

_M_PER_DEG = 111_320.0
_CIRCLE_SIDES = 24

Point = list[float]


def _point(value: Any) -> Point | None:
    if not isinstance(value, dict):
        return None
    lat, lon = value.get("latitude"), value.get("longitude")
    if isinstance(lat, bool) or isinstance(lon, bool):
        return None
    if isinstance(lat, int | float) and isinstance(lon, int | float):
        return [float(lat), float(lon)]
    return None


def _points(value: Any) -> list[Point]:
    if not isinstance(value, list):
        return []
    return [p for p in (_point(v) for v in value) if p is not None]


def _circle(centre: Point, radius: float) -> list[Point]:
    lat, lon = centre
    dlat = radius / _M_PER_DEG
    dlon = radius / (_M_PER_DEG * max(0.01, math.cos(math.radians(lat))))
    return [[lat + dlat * math.sin(a), lon + dlon * math.cos(a)]
            for a in (2 * math.pi * k / _CIRCLE_SIDES for k in range(_CIRCLE_SIDES))]


def task_shapes(name: str, params: Mapping[str, Any]) -> list[tuple[str, list[Point]]]:
    """(kind, coordinates) for one task's parameters; empty when it has no geometry."""
    if name == "search-area":
        area = _points(params.get("area"))
        return [("area", area)] if area else []
    if name == "search-areas":
        areas = params.get("areas")
        return [("area", pts) for pts in (_points(a) for a in areas or [])
                if pts] if isinstance(areas, list) else []
    if name == "search-around-position":
        centre = _point(params.get("geopoint"))
        radius = params.get("radius", 50.0)
        r = float(radius) if isinstance(radius, int | float) and radius > 0 else 50.0
        return [("area", _circle(centre, r))] if centre else []
    for key in ("waypoints", "path"):
        pts = _points(params.get(key))
        if pts:
            return [("path", pts)]
    for key in ("waypoint", "geopoint", "p"):
        p = _point(params.get(key))
        if p is not None:
            return [("point", [p])]
    return []


def shared_searches(plan: Mapping[str, Any]) -> Iterator[tuple[str, list[dict[str, Any]]]]:
    """Each of a plan's ``shared-searches`` with a uuid: (the operator's search uuid, its parts
    that have a uuid, in the plan's order, which numbers them from 1)."""
    for search in plan.get("shared-searches") or []:
        if not isinstance(search, dict) or not isinstance(search.get("node-uuid"), str):
            continue
        yield search["node-uuid"], [p for p in search.get("parts") or [] if isinstance(p, dict)
                                    and isinstance(p.get("node-uuid"), str)]


def shared_parts(plan: Mapping[str, Any]) -> dict[str, tuple[str, int, int]]:
    """Each shared search's part uuid -> (the operator's search uuid, its number from 1, of how
    many), from the plan's ``shared-searches``."""
    return {part["node-uuid"]: (search, i + 1, len(parts))
            for search, parts in shared_searches(plan) for i, part in enumerate(parts)}


def plan_geometry(
    plan: Mapping[str, Any], starts: Mapping[str, Point]
) -> tuple[dict[str, list[Point]], list[dict[str, Any]]]:
    """(routes, tasks) of a plan JSON (docs/plan.md §1) whose units started at ``starts``."""
    tst = plan.get("tst")
    if not isinstance(tst, dict):
        return {}, []
    try:
        root = parse_tree(tst)
    except DelegationError:
        return {}, []
    assigned: dict[str, str] = {}
    order: list[tuple[float, str, str]] = []
    for a in plan.get("assignments") or []:
        if isinstance(a, dict) and isinstance(a.get("node-uuid"), str):
            unit = str(a.get("execunit", "")).strip("/")
            assigned[a["node-uuid"]] = unit
            start = a.get("start")
            order.append((float(start) if isinstance(start, int | float) else 0.0,
                          a["node-uuid"], unit))
    shapes: dict[str, list[tuple[str, list[Point]]]] = {}
    tasks: list[dict[str, Any]] = []
    parts = shared_parts(plan)
    for _, node in walk(root):
        uid = node.node_uuid
        if node.is_control or uid is None:
            continue
        found = task_shapes(node.name, node.params)
        shapes[uid] = found
        owner: str | None = assigned.get(uid) or (
            str(node.execunit).strip("/") if isinstance(node.execunit, str) else None)
        part = parts.get(uid)
        for kind, coords in found:
            task = {"uuid": uid, "name": node.name, "unit": owner, "kind": kind,
                    "coordinates": coords}
            if part is not None:
                task["part-of"], task["part"] = part[0], f"{part[1]}/{part[2]}"
            tasks.append(task)
    names = {node.node_uuid: node.name for _, node in walk(root) if node.node_uuid}
    routes: dict[str, list[Point]] = {}
    for _, uid, unit in sorted(order):
        if not unit:
            continue
        route = routes.get(unit)
        if route is None:
            route = routes[unit] = [list(starts[unit])] if unit in starts else []
        if not is_vehicle_task(names.get(uid, "")):
            continue
        for _, coords in shapes.get(uid, []):
            route.extend(list(p) for p in coords)
    return routes, tasks
