"""The allocation vocabulary: what a plan minimises (``Objective``) and the strategies by name.

``STRATEGIES`` maps a strategy's name to one function with one signature (``StrategyFn``); adding a
strategy is one entry here. The module is light (the strategies are imported when first run), so
command-line parsers can offer the names without loading numpy or OR-Tools.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from delegation.allocation.problem import Problem
    from delegation.allocation.schedule import Schedule


class Objective(StrEnum):
    """What a plan minimises; the other measure breaks ties."""

    MAKESPAN = "makespan"  # when the last task ends (units with a home: when back home)
    TOTAL = "total"  # travel + work of all units, ways home included


@dataclass
class StrategyResult:
    """A strategy's schedule, a proven lower bound on the objective (s) if any, and notes on
    what it did."""

    schedule: Schedule
    bound: float | None = None
    notes: list[str] = field(default_factory=list)
    #: The strategy whose plan this is, when this one fell back to it (else None).
    fallback: str | None = None


class StrategyFn(Protocol):
    """A strategy: plan ``problem`` for ``objective`` within ``time_limit`` seconds (a limit
    only the search strategies use). Never raises for infeasibility: tasks no unit can take
    stay unassigned (``assign`` -1)."""

    def __call__(
        self, problem: Problem, objective: Objective, time_limit: float, /
    ) -> StrategyResult: ...


def _nearest(problem: Problem, objective: Objective, time_limit: float, /) -> StrategyResult:
    from delegation.allocation.nearest import nearest

    return StrategyResult(nearest(problem, objective))


def _auction(problem: Problem, objective: Objective, time_limit: float, /) -> StrategyResult:
    from delegation.allocation.auction import auction

    return StrategyResult(auction(problem, objective))


def _optimal(problem: Problem, objective: Objective, time_limit: float, /) -> StrategyResult:
    from delegation.allocation.optimal import optimise

    result = optimise(problem, objective, time_limit)
    return StrategyResult(result.schedule, result.bound, result.notes,
                          "auction" if result.kept_auction else None)


#: The strategies by name, in the order they are offered (baseline first).
STRATEGIES: dict[str, StrategyFn] = {
    "nearest": _nearest,
    "auction": _auction,
    "optimal": _optimal,
}

#: The objectives, in the order they are offered (the default first).
OBJECTIVES: tuple[Objective, ...] = tuple(Objective)
