"""What the page shows of a search shared among units (DESIGN 3.11), pure.

The operator's tree keeps their one search node; its parts (one per unit, in the tree sent) are
never tree nodes on the page. They hang off that node as ``parts`` (docs/ui.md NODE), each with its
unit and planned interval, so the timeline draws each in its unit's lane and the node's own
interval spans them. The service relays no feedback for parts (3.4), so a part's status and
actual interval come from the feedback of the engine that runs the mission (the plan's root
``execunit``): the page listens to that engine's ``tst/feedback`` for the parts alone. (A unit's
``direct_execution_info`` names the engine's task-uuid, not the node: no use here.)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from delegation.web.geometry import shared_parts


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
    for search in plan.get("shared-searches") or []:
        if not isinstance(search, dict) or not isinstance(search.get("node-uuid"), str):
            continue
        parts = [p for p in search.get("parts") or [] if isinstance(p, dict)
                 and isinstance(p.get("node-uuid"), str)]
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
        out[search["node-uuid"]] = shown
    return out


def span(parts: list[dict[str, Any]]) -> tuple[float | None, float | None]:
    """The planned interval of a search from its parts' (None unless every part has one)."""
    starts = [p["plan-start"] for p in parts]
    ends = [p["plan-end"] for p in parts]
    if not parts or None in starts or None in ends:
        return None, None
    return min(starts), max(ends)
