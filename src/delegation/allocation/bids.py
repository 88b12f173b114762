"""Bids without a plan: per task and unit, the estimated travel, work and distance, or why not."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from delegation.costs import cost_tables
from delegation.tst.node import TstNode, leaves
from delegation.tst.validate import with_defaults

if TYPE_CHECKING:
    from delegation.fleet import UnitState


def compute_bids(tree: TstNode, units: Sequence[UnitState]) -> list[dict[str, Any]]:
    """Every task node x unit: estimated travel, work and distance, or why the unit cannot bid."""
    tasks = leaves(with_defaults(tree))
    if not tasks or not units:
        return []
    tables = cost_tables(units, tasks)
    to_start = tables.dist_unit_to_start()
    bids: list[dict[str, Any]] = []
    for t, task in enumerate(tables.tasks):
        for u, unit in enumerate(tables.units):
            base = {"node-uuid": task.node_uuid, "name": task.name, "unit": f"/{unit.name}"}
            if not tables.capable[u, t]:
                bids.append({**base, "reason": tables.reason(u, t) or "cannot take this task"})
                continue
            travel = float(to_start[u, t])  # 0 for tasks done in place
            bids.append({
                **base,
                "travel-time": round(travel / float(tables.speed[u, t]), 3),
                "work-time": round(float(tables.work_time[u, t]), 3),
                "distance": round(travel + float(tables.work_distance[u, t]), 3),
                "open-ended": bool(tables.open_ended[t]),
            })
    return bids
