"""The plan (DESIGN 3.5): who does what when, the totals, the instantiated tree."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from delegation.tst import TstNode


@dataclass(frozen=True, slots=True)
class Assignment:
    """One task given to one unit: when it starts (travel begins) and ends, what it costs."""

    node_uuid: str
    name: str
    execunit: str  # "/dji0"
    start: float
    end: float
    travel_time: float
    work_time: float
    distance: float  # travel + work, m

    def to_json(self) -> dict[str, Any]:
        return {
            "node-uuid": self.node_uuid,
            "name": self.name,
            "execunit": self.execunit,
            "start": self.start,
            "end": self.end,
            "travel-time": self.travel_time,
            "work-time": self.work_time,
            "distance": self.distance,
        }


@dataclass(frozen=True, slots=True)
class Unassigned:
    """A task no unit can take, and why."""

    node_uuid: str
    name: str
    reason: str

    def to_json(self) -> dict[str, Any]:
        return {"node-uuid": self.node_uuid, "name": self.name, "reason": self.reason}


@dataclass
class Plan:
    """A plan: DESIGN 3.5. ``routes`` (per unit, in execution order) is for maps, not JSON."""

    strategy: str
    objective: str
    feasible: bool
    makespan: float
    total_time: float
    total_distance: float
    solve_time: float
    bound: float | None
    gap: float | None
    assignments: list[Assignment]
    unassigned: list[Unassigned]
    tst: TstNode
    routes: dict[str, list[Assignment]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)  # what the strategy did (also logged)
    #: The caller's tree with uuids and defaults, before units were filled in (not in JSON).
    source: TstNode | None = None

    def to_json(self) -> dict[str, Any]:
        """Exactly DESIGN 3.5, hyphenated keys; ``bound``/``gap`` null unless proven."""
        return {
            "strategy": self.strategy,
            "objective": self.objective,
            "feasible": self.feasible,
            "makespan": self.makespan,
            "total-time": self.total_time,
            "total-distance": self.total_distance,
            "solve-time": self.solve_time,
            "bound": self.bound,
            "gap": self.gap,
            "assignments": [a.to_json() for a in self.assignments],
            "unassigned": [u.to_json() for u in self.unassigned],
            "tst": self.tst.to_dict(),
        }
