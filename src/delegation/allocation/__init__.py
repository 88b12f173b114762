"""Allocation: the problem from the tree, the strategies (nearest, auction, optimal), the plan.

Pure code: no network, no clock (except measuring solve time), no sleeps.

The vocabulary (``Objective``, ``OBJECTIVES``, ``STRATEGIES``) is imported at once and is light;
the rest (numpy and the strategies) when first used, so that command-line parsers can offer the
names cheaply.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from delegation.allocation.strategies import (
    OBJECTIVES,
    STRATEGIES,
    Objective,
    StrategyFn,
    StrategyResult,
)

if TYPE_CHECKING:
    from delegation.allocation.bids import compute_bids
    from delegation.allocation.invariants import check_invariants
    from delegation.allocation.plan import Assignment, Plan, Unassigned
    from delegation.allocation.planner import make_plan, plan_mission
    from delegation.allocation.problem import Problem, build_problem
    from delegation.allocation.schedule import IssueKind, Schedule, ScheduleIssue, evaluate

_LAZY = {
    "compute_bids": "bids",
    "check_invariants": "invariants",
    "Assignment": "plan",
    "Plan": "plan",
    "Unassigned": "plan",
    "make_plan": "planner",
    "plan_mission": "planner",
    "Problem": "problem",
    "build_problem": "problem",
    "IssueKind": "schedule",
    "Schedule": "schedule",
    "ScheduleIssue": "schedule",
    "evaluate": "schedule",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


__all__ = [
    "OBJECTIVES",
    "STRATEGIES",
    "Assignment",
    "IssueKind",
    "Objective",
    "Plan",
    "Problem",
    "Schedule",
    "ScheduleIssue",
    "StrategyFn",
    "StrategyResult",
    "Unassigned",
    "build_problem",
    "check_invariants",
    "compute_bids",
    "evaluate",
    "make_plan",
    "plan_mission",
]
