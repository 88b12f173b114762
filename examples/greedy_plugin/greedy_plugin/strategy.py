"""``least_loaded``: each task, in tree order, goes to the allowed unit that is busy the least.

A deliberately simple strategy that shows the whole contract (docs/strategies.md): read the
``Problem``'s arrays, choose ``assign`` and per-unit ``orders``, let ``evaluate`` simulate the tree
(it reports deadlocks and endurance in ``issues``), and return a ``StrategyResult``. It respects
capability and aliases (``allowed``, ``alias_of``); it ignores endurance and the objective, so
its plans may be invalid where a unit's battery is short (the plan then says infeasible).
"""

from __future__ import annotations

import numpy as np

from delegation.allocation import Objective, Problem, StrategyResult, evaluate


def least_loaded(problem: Problem, objective: Objective, time_limit: float, /) -> StrategyResult:
    """Plan ``problem``; ``objective`` and ``time_limit`` are accepted and not used."""
    n_units = problem.n_units
    assign = np.full(problem.n_tasks, -1, dtype=int)
    orders: list[list[int]] = [[] for _ in range(n_units)]
    busy = np.zeros(n_units)  # seconds of travel + work so far
    where = problem.unit_xy.astype(float).copy()  # each unit's position after its last task
    alias_of = problem.alias_of()
    bound: dict[int, int] = {}
    for t in range(problem.n_tasks):
        allowed = problem.allowed[:, t].copy()
        group = alias_of[t]
        if group in bound:
            allowed[:] = False
            allowed[bound[group]] = True
        if not allowed.any():
            continue  # stays unassigned; the planner explains why
        if problem.vehicle[t]:
            travel = np.zeros(n_units)
            if problem.travels[t]:
                travel = np.hypot(*(where - problem.start_xy[t]).T) / problem.speed[:, t]
            cost = busy + travel + problem.work_time[:, t]
            u = int(np.flatnonzero(allowed)[np.argmin(cost[allowed])])
            busy[u] = cost[u]
            if problem.travels[t]:
                where[u] = problem.end_xy[t]
            orders[u].append(t)
        else:  # look-at tasks: no travel, the unit is not occupied
            u = int(np.flatnonzero(allowed)[0])
        assign[t] = u
        if group >= 0:
            bound[group] = u
    notes = ["least-loaded (example plugin)"]
    return StrategyResult(evaluate(problem, assign, orders), notes=notes)
