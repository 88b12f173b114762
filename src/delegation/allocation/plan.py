"""The plan (docs/plan.md §1): who does what when, the totals, the instantiated tree."""

from __future__ import annotations

import math
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


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


@dataclass(frozen=True, slots=True)
class SharedPart:
    """One unit's part of a shared search (DESIGN 3.11): its task, unit, area, sweep and times
    (NaN when the part is unassigned)."""

    node_uuid: str
    name: str  # search-area, or search-areas for a part in several pieces
    unit: str
    area_m2: float
    sweep_m: float
    start: float
    end: float

    def to_json(self) -> dict[str, Any]:
        return {"node-uuid": self.node_uuid, "name": self.name, "execunit": "/" + self.unit,
                "area": self.area_m2, "sweep-length": _finite(self.sweep_m),
                "start": _finite(self.start), "end": _finite(self.end)}


@dataclass(frozen=True, slots=True)
class SharedSearch:
    """A search of the caller's shared among units: its parts, its lower bound (DESIGN 3.11:
    every unit sweeping from when it could be there, no turns) and the gap to it."""

    node_uuid: str
    name: str
    area_m2: float
    bound: float
    parts: tuple[SharedPart, ...]

    @property
    def end(self) -> float:
        """When its last part ends (NaN if a part is unassigned)."""
        ends = [p.end for p in self.parts]
        return max(ends) if ends and all(math.isfinite(e) for e in ends) else math.nan

    @property
    def gap(self) -> float | None:
        """``(end - bound) / end``; None while a part is unassigned."""
        end = self.end
        if not math.isfinite(end) or end <= 0.0:
            return None
        return max(0.0, (end - self.bound) / end)

    def to_json(self) -> dict[str, Any]:
        return {"node-uuid": self.node_uuid, "name": self.name, "area": self.area_m2,
                "end": _finite(self.end), "bound": _finite(self.bound), "gap": self.gap,
                "parts": [p.to_json() for p in self.parts]}


@dataclass
class Plan:
    """A plan: docs/plan.md §1. ``routes`` (per unit, in execution order) is for maps, not JSON."""

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
    #: The makespan of the plan's precedence graph (the tree's order + each unit's order), which
    #: the strategies plan for; ``makespan`` is the sent tree's (docs/protocol.md §8).
    precedence_makespan: float | None = None
    #: The strategy whose plan this is when the strategy fell back to it (``optimal`` keeping
    #: the auction's plan), else None.
    fallback: str | None = None
    #: A lower bound on the makespan of any plan for this problem (``bounds``; not in JSON).
    lower_bound: float | None = None
    #: The searches shared among units (DESIGN 3.11), JSON ``shared-searches``.
    shared: list[SharedSearch] = field(default_factory=list)
    #: The tree the plan was made on when searches were shared: ``source`` with each shared
    #: search replaced by the ``conc`` of its parts (None: ``source`` itself). Not in JSON.
    planned: TstNode | None = None

    @property
    def instantiation_loss(self) -> float | None:
        """What the tree sent adds to the precedence graph's makespan (s, never negative)."""
        if self.precedence_makespan is None:
            return None
        return max(0.0, self.makespan - self.precedence_makespan)

    def part_map(self) -> dict[str, list[str]]:
        """Each shared search's uuid -> its parts' uuids."""
        return {s.node_uuid: [p.node_uuid for p in s.parts] for s in self.shared}

    def part_of(self) -> dict[str, str]:
        """A shared search's part uuid -> the caller's search uuid (DESIGN 3.11)."""
        return {part.node_uuid: search.node_uuid
                for search in self.shared for part in search.parts}

    def caller_counts(self) -> tuple[int, int]:
        """(assigned, unassigned) counted in the caller's tasks: a shared search is one task,
        unassigned when any of its parts is."""
        part_of = self.part_of()
        missing = {part_of.get(u.node_uuid, u.node_uuid) for u in self.unassigned}
        done = {part_of.get(a.node_uuid, a.node_uuid) for a in self.assignments} - missing
        return len(done), len(missing)

    @property
    def strategy_label(self) -> str:
        """``optimal (= auction)`` when the strategy fell back to another's plan."""
        return f"{self.strategy} (= {self.fallback})" if self.fallback else self.strategy

    def to_json(self) -> dict[str, Any]:
        """Exactly docs/plan.md §1, hyphenated keys; ``bound``/``gap`` null unless proven."""
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
            "precedence-makespan": self.precedence_makespan,
            "instantiation-loss": self.instantiation_loss,
            "fallback": self.fallback,
            "assignments": [a.to_json() for a in self.assignments],
            "unassigned": [u.to_json() for u in self.unassigned],
            "shared-searches": [s.to_json() for s in self.shared],
            "tst": self.tst.to_dict(),
        }
