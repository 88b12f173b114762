"""What the page shows of a search shared among units (DESIGN 3.11), pure.

The operator's tree keeps their one search node; its parts (one per unit, in the tree sent) are
never tree nodes on the page. They hang off that node as ``parts`` (docs/ui.md NODE), each with its
unit and planned interval, so the timeline draws each in its unit's lane and the node's own
interval spans them. The service relays no feedback for parts (3.4), so a part's status and
actual interval come from the feedback of the engine that runs the mission (the plan's root
``execunit``): the page listens to that engine's ``tst/feedback`` for the parts alone. (A unit's
``direct_execution_info`` names the engine's task-uuid, not the node: no use here.)

When a unit with a part is lost, what it had not swept is planned again among the live units and
runs in its part's place (docs/protocol.md §11, §12.6 ``subtrees``: a ``conc`` under the part's
uuid holding the pieces). The page then shows the pieces, not the lost part (``reshared``): their
units, areas on the map, and status from the engine's feedback as for any part.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from delegation.errors import DelegationError
from delegation.tst.node import TstNode, parse_tree, walk
from delegation.web.geometry import shared_parts, shared_searches


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) \
        else None


def engine_of(plan: Mapping[str, Any] | None) -> str | None:
    """The engine that runs a plan's tree: its root's ``execunit`` (None when it has none)."""
    tst = (plan or {}).get("tst")
    params = tst.get("common_params") if isinstance(tst, dict) else None
    unit = params.get("execunit") if isinstance(params, dict) else None
    return unit.strip("/") or None if isinstance(unit, str) else None


def part_uuids(plan: Mapping[str, Any] | None) -> dict[str, str]:
    """Part uuid -> the operator's search uuid, for a plan JSON (empty without one)."""
    return {uid: found[0] for uid, found in shared_parts(plan or {}).items()}


def search_parts(
    plan: Mapping[str, Any] | None,
    actual: Callable[[str], tuple[str | None, float | None, float | None]],
) -> dict[str, list[dict[str, Any]]]:
    """The operator's search uuid -> its parts as the page shows them: ``uuid``, ``unit``,
    ``part`` ("1/3"), ``area`` (m²), ``sweep-length`` (m), ``plan-start``, ``plan-end`` (s from
    the mission's start), and ``status``, ``actual-start``, ``actual-end`` from ``actual``."""
    out: dict[str, list[dict[str, Any]]] = {}
    if not plan:
        return out
    times = {a["node-uuid"]: a for a in plan.get("assignments") or []
             if isinstance(a, dict) and isinstance(a.get("node-uuid"), str)}
    for search, parts in shared_searches(plan):
        shown = []
        for i, part in enumerate(parts):
            uid = part["node-uuid"]
            planned = times.get(uid, part)
            status, start, end = actual(uid)
            shown.append({
                "uuid": uid, "name": str(part.get("name") or "search-area"),
                "unit": str(planned.get("execunit") or part.get("execunit") or "").strip("/"),
                "part": f"{i + 1}/{len(parts)}", "area": _number(part.get("area")),
                "sweep-length": _number(part.get("sweep-length")),
                "plan-start": _number(planned.get("start")),
                "plan-end": _number(planned.get("end")),
                "status": status, "actual-start": start, "actual-end": end,
            })
        out[search] = shown
    return out


def span(parts: list[dict[str, Any]]) -> tuple[float | None, float | None]:
    """The planned interval of a search from its parts' (None unless every part has one)."""
    starts = [p["plan-start"] for p in parts]
    ends = [p["plan-end"] for p in parts]
    if not parts or None in starts or None in ends:
        return None, None
    return min(starts), max(ends)


def reshared(plan: Mapping[str, Any] | None, current: Any) -> Mapping[str, Any] | None:
    """``plan`` as the page shows it once parts of its shared searches were re-shared or moved:
    in ``current`` (``query-mission``'s ``current-tst``, the tree the engine executes now) a
    part's uuid that names a ``conc`` holds the pieces run in its place, and a part that names a
    task may have another unit. Each re-shared part is replaced in ``shared-searches`` by its
    pieces (``replaces`` naming it; unit and name from the tree; no planned area or times: the
    re-delegation's plan is not the mission's) and leaves ``assignments``; a moved part takes
    its new unit in both; ``tst`` is ``current`` (the pieces' areas, for the map). ``plan``
    itself when no part changed, or when ``current`` is another tree (a replaced tree has other
    uuids: its tasks are shown on the nodes they replace)."""
    tst = (plan or {}).get("tst")
    if not plan or not isinstance(current, dict) or not isinstance(tst, dict):
        return plan
    try:
        tree = parse_tree(current)
    except DelegationError:
        return plan
    first = tst.get("common_params")
    if not isinstance(first, dict) or tree.node_uuid != first.get("node-uuid"):
        return plan
    nodes = {node.node_uuid: node for _, node in walk(tree) if node.node_uuid}
    gone: set[str] = set()
    moved: dict[str, str] = {}

    def now(part: Mapping[str, Any], depth: int = 0) -> list[Mapping[str, Any]]:
        uid = part["node-uuid"]
        node = nodes.get(uid)
        if node is None or depth > 8:
            return [part]
        if node.name == "conc":
            gone.add(uid)
            out: list[Mapping[str, Any]] = []
            for child in node.children:
                if child.node_uuid:
                    out += now(_piece(child, uid), depth + 1)
            return out
        unit = node.execunit if isinstance(node.execunit, str) else ""
        if unit and unit != part.get("execunit"):
            moved[uid] = unit
            return [{**part, "execunit": unit}]
        return [part]

    searches = []
    for search in plan.get("shared-searches") or []:
        parts = search.get("parts") if isinstance(search, dict) else None
        if not isinstance(parts, list):
            searches.append(search)
            continue
        shown = [q for p in parts if isinstance(p, dict) and isinstance(p.get("node-uuid"), str)
                 for q in now(p)]
        searches.append({**search, "parts": shown})
    if not gone and not moved:
        return plan
    assignments = [
        {**a, "execunit": moved[a["node-uuid"]]} if a.get("node-uuid") in moved else a
        for a in plan.get("assignments") or []
        if isinstance(a, dict) and a.get("node-uuid") not in gone]
    return {**plan, "tst": current, "shared-searches": searches, "assignments": assignments}


def _piece(node: TstNode, replaces: str) -> dict[str, Any]:
    """A piece of a re-shared part, in the form of a plan's part (docs/plan.md §1)."""
    unit = node.execunit if isinstance(node.execunit, str) else ""
    return {"node-uuid": node.node_uuid, "name": node.name, "execunit": unit, "area": None,
            "sweep-length": None, "start": None, "end": None, "replaces": replaces}
