"""Allocation: the problem from the tree, the strategies (nearest, auction, optimal), the plan.

Pure code: no network, no clock (except measuring solve time), no sleeps.
"""

from delegation.allocation.invariants import check_invariants
from delegation.allocation.plan import Assignment, Plan, Unassigned
from delegation.allocation.planner import OBJECTIVES, STRATEGIES, make_plan, plan_mission
from delegation.allocation.problem import Problem, build_problem
from delegation.allocation.schedule import Schedule, evaluate

__all__ = [
    "OBJECTIVES",
    "STRATEGIES",
    "Assignment",
    "Plan",
    "Problem",
    "Schedule",
    "Unassigned",
    "build_problem",
    "check_invariants",

    "evaluate",
    "make_plan",
    "plan_mission",
]
