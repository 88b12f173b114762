"""A PNG map of a plan: units, tasks, planned routes and flown tracks (matplotlib, Agg).

Drawn in a mission-local East-North frame (metres) so distances look right. Used by ``delegation
demo`` after a run and reusable by the benchmark for any plan. Rendering only: it never plans.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from delegation.costs import TaskGeometry, task_geometry, task_path
from delegation.fleet import UnitState
from delegation.geo import GeoPoint, LocalFrame
from delegation.tst.node import TstNode, parse_tree, walk
from delegation.tst.validate import read_geopoint


class PlanLike(Protocol):
    def to_json(self) -> dict[str, Any]: ...


def _plan_json(plan: PlanLike | Mapping[str, Any]) -> dict[str, Any]:
    if isinstance(plan, Mapping):
        return dict(plan)
    return plan.to_json()


@dataclass(frozen=True, slots=True)
class _Shape:
    """What the map draws for a task: the cost model's geometry, plus the target of a task done
    in place (the position a look-at-position camera points at)."""

    name: str
    geometry: TaskGeometry
    target: GeoPoint | None

    @property
    def points(self) -> list[GeoPoint]:
        pts = list(self.geometry.points) + [p for area in self.geometry.areas for p in area]
        return pts + ([self.target] if self.target is not None else [])

    @property
    def label_at(self) -> GeoPoint | None:
        pts = self.points
        if not pts:
            return None
        if self.geometry.kind == "areas" and self.geometry.circle is None:
            return GeoPoint(latitude=float(np.mean([q.latitude for q in pts])),
                            longitude=float(np.mean([q.longitude for q in pts])))
        return pts[0]


def _shape(node: TstNode) -> _Shape:
    target = None
    if node.params.get("geopoint") is not None:
        with suppress(ValueError, TypeError):
            target = read_geopoint(node.params["geopoint"])
    return _Shape(node.name, task_geometry(node), target)


def _route_points(node: TstNode, unit: UnitState, here: GeoPoint) -> list[GeoPoint]:
    """Where the unit goes for a task: the cost model's own path (sweeps for searches, flown the
    way that suits ``here``, where its previous task left it, as the unit flies it), in the
    frame the simulator uses (around the unit's start) so that near-symmetric areas are swept
    along the same axis on the map as in flight; nothing for tasks done in place (look-at-*)."""
    frame = LocalFrame(unit.position.latitude, unit.position.longitude)
    return task_path(node, unit, frame, here=here)


def planned_route(assigned: Sequence[Mapping[str, Any]], unit: UnitState,
                  nodes: Mapping[str, TstNode]) -> list[GeoPoint]:
    """The unit's planned route: its position, each assigned task's path in the plan's order
    (each search flown the way that suits where the task before left the unit, as the planner's
    schedule and the simulated unit fly it), then home."""
    route = [unit.position]
    here = unit.position
    for a in sorted(assigned, key=lambda a: (a.get("start", 0.0), a.get("end", 0.0))):
        node = nodes.get(str(a.get("node-uuid")))
        if node is not None:
            points = _route_points(node, unit, here)
            route += points
            here = points[-1] if points else here
    if unit.home is not None:
        route.append(unit.home)
    return route


#: Map coordinates (east, north in metres) of a position.
_XY = Callable[[GeoPoint], tuple[float, float]]


def render_map(
    plan: PlanLike | Mapping[str, Any],
    units: Sequence[UnitState],
    tracks: Mapping[str, Sequence[GeoPoint]] | None = None,
    path: str | Path = "map.png",
    title: str | None = None,
) -> Path:
    """Write a PNG map of ``plan`` to ``path`` and return the path.

    ``plan`` is a ``Plan`` or its docs/plan.md §1 JSON; ``tracks`` maps unit names to flown
    positions.
    """
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    data = _plan_json(plan)
    tree = parse_tree(data["tst"]) if isinstance(data.get("tst"), dict) else None
    nodes: dict[str, TstNode] = {}
    if tree is not None:
        nodes = {n.node_uuid: n for _, n in walk(tree) if not n.is_control and n.node_uuid}
    shapes = [_shape(n) for n in nodes.values()]
    tracks = tracks or {}

    all_pts: list[GeoPoint] = [u.position for u in units]
    all_pts += [u.home for u in units if u.home is not None]
    for shape in shapes:
        all_pts += shape.points
    for pts in tracks.values():
        all_pts += list(pts)
    xy: _XY = LocalFrame.around(all_pts).point_xy

    # A bare Figure on the Agg canvas: no pyplot global state, safe off the main thread.
    fig = Figure(figsize=(9, 8), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    cmap = matplotlib.colormaps["tab10"]
    colour = {u.name: cmap(i % 10) for i, u in enumerate(units)}

    _draw_tasks(ax, shapes, xy)
    _draw_routes(ax, data, units, nodes, colour, xy)
    _draw_units(ax, units, tracks, colour, xy)

    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    makespan = float(data.get("makespan") or 0.0)
    heading = title or f"{data.get('strategy', '')} plan, makespan {makespan:.0f} s"
    legend = "  (dashed: planned, solid: flown)" if tracks else "  (planned routes)"
    ax.set_title(heading + legend, fontsize=10)
    ax.grid(True, alpha=0.3)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out, format="png")
    return out


def _draw_tasks(ax: Any, shapes: Sequence[_Shape], xy: _XY) -> None:
    """Tasks: areas and circles shaded, paths dotted, points and look-at targets crossed."""
    from matplotlib.patches import Circle, Polygon

    for shape in shapes:
        g = shape.geometry
        if g.circle is not None:
            cx, cy = xy(g.circle[0])
            ax.add_patch(Circle((cx, cy), g.circle[1], alpha=0.15, color="grey"))
            ax.plot([cx], [cy], "+", color="grey")
        elif g.kind == "areas":
            for area in g.areas:
                poly = np.array([xy(p) for p in area])
                ax.add_patch(Polygon(poly, closed=True, alpha=0.15, color="grey"))
                ax.plot(*np.vstack([poly, poly[:1]]).T, color="grey", lw=0.8)
        elif g.kind == "path" and g.points:
            line = np.array([xy(p) for p in g.points])
            ax.plot(line[:, 0], line[:, 1], color="grey", lw=1.2, ls=":")
        elif shape.points:
            px, py = xy(shape.points[0])
            ax.plot([px], [py], "x", color="black", ms=7)
        if shape.label_at is not None:
            ax.annotate(shape.name, xy(shape.label_at), fontsize=7, color="dimgrey",
                        xytext=(4, -10), textcoords="offset points")


def _draw_routes(
    ax: Any,
    data: Mapping[str, Any],
    units: Sequence[UnitState],
    nodes: Mapping[str, TstNode],
    colour: Mapping[str, Any],
    xy: _XY,
) -> None:
    """Planned routes, dashed: unit position -> each assigned task in order -> home."""
    routes: dict[str, list[dict[str, Any]]] = {}
    for a in data.get("assignments", []):
        routes.setdefault(str(a.get("execunit", "")).strip("/"), []).append(a)
    by_name = {u.name: u for u in units}
    for unit_name, assigned in routes.items():
        unit = by_name.get(unit_name)
        if unit is None:
            continue
        route = [xy(p) for p in planned_route(assigned, unit, nodes)]
        line = np.array(route)
        ax.plot(line[:, 0], line[:, 1], ls="--", lw=1.2, color=colour[unit_name], alpha=0.9,
                zorder=3)


def _draw_units(
    ax: Any,
    units: Sequence[UnitState],
    tracks: Mapping[str, Sequence[GeoPoint]],
    colour: Mapping[str, Any],
    xy: _XY,
) -> None:
    """Flown tracks (solid), units at their start positions, and their homes."""
    for unit_name, pts in tracks.items():
        if len(pts) >= 2:
            line = np.array([xy(p) for p in pts])
            ax.plot(line[:, 0], line[:, 1], lw=2.5, color=colour.get(unit_name, "black"),
                    alpha=0.45, zorder=2)
    for u in units:
        ux, uy = xy(u.position)
        ax.plot([ux], [uy], "o", color=colour[u.name], ms=8, mec="black", zorder=4)
        ax.annotate(u.name, (ux, uy), fontsize=8, xytext=(5, 5), textcoords="offset points")
        if u.home is not None:
            hx, hy = xy(u.home)
            ax.plot([hx], [hy], "s", color=colour[u.name], ms=6, mec="black", alpha=0.7)
