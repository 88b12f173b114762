"""A PNG map of a plan: units, tasks, planned routes and flown tracks (matplotlib, Agg).

Drawn in a mission-local East-North frame (metres) so distances look right. Used by ``delegation
demo`` after a run and reusable by the benchmark for any plan. Rendering only: it never plans.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from delegation.geo import GeoPoint, LocalFrame
from delegation.tst.node import TstNode, parse_tree, walk
from delegation.tst.validate import read_geopoint


class UnitLike(Protocol):
    """What the map needs of a unit (``fleet.UnitState`` has it)."""

    @property
    def name(self) -> str: ...
    @property
    def position(self) -> GeoPoint: ...
    @property
    def home(self) -> GeoPoint | None: ...


class PlanLike(Protocol):
    def to_json(self) -> dict[str, Any]: ...


def _plan_json(plan: PlanLike | Mapping[str, Any]) -> dict[str, Any]:
    if isinstance(plan, Mapping):
        return dict(plan)
    return plan.to_json()


def _points(value: Any) -> list[GeoPoint]:
    try:
        return [read_geopoint(v) for v in value]
    except Exception:  # a param we cannot draw is left out of the map, not fatal
        return []


def _point(value: Any) -> GeoPoint | None:
    try:
        return read_geopoint(value)
    except Exception:
        return None


def task_geometry(node: TstNode) -> dict[str, Any]:
    """Where a task node is on the map: ``kind`` plus points (and ``radius`` for circles)."""
    p = node.params
    if node.name == "move-to":
        pt = _point(p.get("waypoint"))
        return {"kind": "point", "points": [pt] if pt else []}
    if node.name == "move-path":
        return {"kind": "path", "points": _points(p.get("waypoints") or [])}
    if node.name == "search-area":
        return {"kind": "area", "points": _points(p.get("area") or [])}
    if node.name == "search-areas":
        areas = p.get("areas") or []
        return {"kind": "areas", "areas": [_points(a) for a in areas if isinstance(a, list)]}
    if node.name == "search-around-position":
        pt = _point(p.get("geopoint"))
        radius = p.get("radius")
        return {
            "kind": "circle",
            "points": [pt] if pt else [],
            "radius": float(radius) if isinstance(radius, int | float) else 0.0,
        }
    for key in ("geopoint", "waypoint", "position"):
        if key in p:
            pt = _point(p.get(key))
            return {"kind": "point", "points": [pt] if pt else []}
    return {"kind": "none", "points": []}


def _anchor(geom: dict[str, Any], first: bool) -> GeoPoint | None:
    """The point a route goes to (first) or leaves from (last) for a task."""
    if geom["kind"] == "areas":
        pts = [p for a in geom["areas"] for p in a]
    else:
        pts = geom.get("points", [])
    if not pts:
        return None
    if geom["kind"] in ("area", "areas"):
        return GeoPoint(
            latitude=float(np.mean([q.latitude for q in pts])),
            longitude=float(np.mean([q.longitude for q in pts])),
        )
    return pts[0] if first else pts[-1]


def _route_points(node: TstNode | None, unit: UnitLike) -> list[GeoPoint]:
    """Where the unit goes for a task: the cost model's own path (sweeps for searches); nothing
    for tasks done in place (look-at-*)."""
    if node is None:
        return []
    try:
        from delegation.costs import task_path

        # The frame the simulator uses (around the unit's start), so that near-symmetric areas
        # are swept along the same axis on the map as in flight.
        frame = LocalFrame(unit.position.latitude, unit.position.longitude)
        return task_path(node, unit, frame)  # type: ignore[arg-type]
    except Exception:  # a unit without what the cost model needs: draw the task's anchor
        g = task_geometry(node)
        return [p for p in (_anchor(g, True), _anchor(g, False)) if p is not None]


def render_map(
    plan: PlanLike | Mapping[str, Any],
    units: Sequence[UnitLike],
    tracks: Mapping[str, Sequence[GeoPoint]] | None = None,
    path: str | Path = "map.png",
    title: str | None = None,
) -> Path:
    """Write a PNG map of ``plan`` to ``path`` and return the path.

    ``plan`` is a ``Plan`` or its DESIGN 3.5 JSON; ``tracks`` maps unit names to flown positions.
    """
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, Polygon

    data = _plan_json(plan)
    tree = parse_tree(data["tst"]) if isinstance(data.get("tst"), dict) else None
    geoms: dict[str, tuple[str, dict[str, Any]]] = {}
    nodes: dict[str, TstNode] = {}
    if tree is not None:
        for _, node in walk(tree):
            if not node.is_control and node.node_uuid:
                geoms[node.node_uuid] = (node.name, task_geometry(node))
                nodes[node.node_uuid] = node
    tracks = tracks or {}

    all_pts: list[GeoPoint] = [u.position for u in units]
    all_pts += [u.home for u in units if u.home is not None]
    for _, g in geoms.values():
        all_pts += [p for a in g.get("areas", []) for p in a] + list(g.get("points", []))
    for pts in tracks.values():
        all_pts += list(pts)
    frame = LocalFrame.around(all_pts)

    def xy(p: GeoPoint) -> tuple[float, float]:
        return frame.point_xy(p)

    # A bare Figure on the Agg canvas: no pyplot global state, safe off the main thread.
    fig = Figure(figsize=(9, 8), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    cmap = matplotlib.colormaps["tab10"]
    colour = {u.name: cmap(i % 10) for i, u in enumerate(units)}

    # Tasks.
    for name, g in geoms.values():
        kind = g["kind"]
        if kind in ("area", "areas"):
            for area in g.get("areas", [g.get("points", [])]):
                if len(area) >= 3:
                    poly = np.array([xy(p) for p in area])
                    ax.add_patch(Polygon(poly, closed=True, alpha=0.15, color="grey"))
                    ax.plot(*np.vstack([poly, poly[:1]]).T, color="grey", lw=0.8)
        elif kind == "circle" and g["points"]:
            cx, cy = xy(g["points"][0])
            ax.add_patch(Circle((cx, cy), g.get("radius", 0.0), alpha=0.15, color="grey"))
            ax.plot([cx], [cy], "+", color="grey")
        elif kind == "path" and g["points"]:
            line = np.array([xy(p) for p in g["points"]])
            ax.plot(line[:, 0], line[:, 1], color="grey", lw=1.2, ls=":")
        elif g.get("points"):
            px, py = xy(g["points"][0])
            ax.plot([px], [py], "x", color="black", ms=7)
        anchor = _anchor(g, first=True)
        if anchor is not None:
            ax.annotate(name, xy(anchor), fontsize=7, color="dimgrey",
                        xytext=(4, -10), textcoords="offset points")

    # Planned routes: unit position -> each assigned task in order -> home.
    routes: dict[str, list[dict[str, Any]]] = {}
    for a in data.get("assignments", []):
        routes.setdefault(str(a.get("execunit", "")).strip("/"), []).append(a)
    by_name = {u.name: u for u in units}
    for unit_name, assigned in routes.items():
        unit = by_name.get(unit_name)
        if unit is None:
            continue
        route = [xy(unit.position)]
        for a in sorted(assigned, key=lambda a: (a.get("start", 0.0), a.get("end", 0.0))):
            route += [xy(p) for p in _route_points(nodes.get(str(a.get("node-uuid"))), unit)]
        if unit.home is not None:
            route.append(xy(unit.home))
        line = np.array(route)
        ax.plot(line[:, 0], line[:, 1], ls="--", lw=1.2, color=colour[unit_name], alpha=0.9,
                zorder=3)

    # Flown tracks.
    for unit_name, pts in tracks.items():
        if len(pts) >= 2:
            line = np.array([xy(p) for p in pts])
            ax.plot(line[:, 0], line[:, 1], lw=2.5, color=colour.get(unit_name, "black"),
                    alpha=0.45, zorder=2)

    # Units (start positions) and homes.
    for u in units:
        ux, uy = xy(u.position)
        ax.plot([ux], [uy], "o", color=colour[u.name], ms=8, mec="black", zorder=4)
        ax.annotate(u.name, (ux, uy), fontsize=8, xytext=(5, 5), textcoords="offset points")
        if u.home is not None:
            hx, hy = xy(u.home)
            ax.plot([hx], [hy], "s", color=colour[u.name], ms=6, mec="black", alpha=0.7)

    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    makespan = float(data.get("makespan") or 0.0)
    heading = title or f"{data.get('strategy', '')} plan, makespan {makespan:.0f} s"
    ax.set_title(heading + "  (dashed: planned, solid: flown)", fontsize=10)
    ax.grid(True, alpha=0.3)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out, format="png")
    return out
