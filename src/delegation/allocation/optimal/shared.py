"""What the routing and the CP-SAT models share: tick resolution, task points, evaluation."""

from __future__ import annotations

import numpy as np

from delegation.allocation.auction import assign_passive
from delegation.allocation.problem import Problem
from delegation.allocation.schedule import Schedule, evaluate

#: Ticks per horizon: integer resolution of solver times.
TICKS = 1_000_000


def finish(problem: Problem, orders: list[list[int]]) -> Schedule:
    """Evaluate vehicle routes, with non-vehicle tasks re-given to units afterwards."""
    assign = np.full(problem.n_tasks, -1, dtype=int)
    for u, order in enumerate(orders):
        assign[order] = u
    assign_passive(problem, assign)
    return evaluate(problem, assign, orders)


def points(
    problem: Problem, u: int, tasks: list[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start/end points of ``tasks`` for unit ``u``; in-place tasks sit at the unit's position."""
    start, end, travels = problem.points_for(u, np.asarray(tasks, dtype=int))
    start[~travels] = problem.unit_xy[u]
    end[~travels] = problem.unit_xy[u]
    return start, end, travels


def exact_model(problem: Problem, tasks: list[int]) -> bool:
    """Arc costs are exact only when every vehicle task ends at a known point."""
    idx = np.asarray(tasks, dtype=int)
    home = problem.home_task()[idx]
    if home.any() and not problem.has_home.all():
        return False
    return bool(problem.travels[idx].all())
