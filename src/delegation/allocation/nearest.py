"""The baseline: the rule of the public WARA-PS drone-operator example.

Each task, in tree order, goes to the closest capable unit (from where the units are now) that has
no task yet in this plan; once every capable unit has one, to the closest capable unit. A unit runs
its tasks in tree order. Units whose endurance would not cover the task are skipped.
"""

from __future__ import annotations

import numpy as np

from delegation.allocation.auction import assign_passive
from delegation.allocation.problem import Problem
from delegation.allocation.routes import home_legs, insertion_costs
from delegation.allocation.schedule import EPS, Schedule, evaluate
from delegation.allocation.strategies import Objective


def nearest(problem: Problem, objective: Objective | str = Objective.MAKESPAN) -> Schedule:
    """Plan with the nearest-unit rule (the rule ignores ``objective``, which must be one)."""
    Objective(objective)  # ValueError for an unknown one
    n_units, n_tasks = problem.n_units, problem.n_tasks
    assign = np.full(n_tasks, -1, dtype=int)
    routes: list[list[int]] = [[] for _ in range(n_units)]
    used = home_legs(problem)
    vehicle = problem.vehicle
    alias_of = problem.alias_of()
    bound: dict[int, int] = {}
    travels = problem.travels
    for t in range(n_tasks):
        if not vehicle[t]:
            continue
        allowed = problem.allowed[:, t].copy()
        g = alias_of[t]
        if g in bound:
            only = np.zeros(n_units, dtype=bool)
            only[bound[g]] = True
            allowed &= only
        if not allowed.any():
            continue
        if travels[t]:
            dist = np.hypot(*(problem.unit_xy - problem.start_at(np.arange(n_units), t)).T)
        else:
            dist = np.zeros(n_units)
        busy = np.array([bool(r) for r in routes])
        chosen = -1
        for pool in (allowed & ~busy, allowed):
            for u in np.nonzero(pool)[0][np.argsort(dist[pool], kind="stable")].tolist():
                add = float(insertion_costs(problem, u, routes[u], np.array([t]))[-1, 0])
                if used[u] + add <= problem.endurance[u] * (1 + EPS) + EPS:
                    chosen = u
                    used[u] += add
                    break
            if chosen >= 0:
                break
        if chosen < 0:
            continue
        routes[chosen].append(t)
        assign[t] = chosen
        if g >= 0:
            bound[g] = chosen
    assign_passive(problem, assign)
    return evaluate(problem, assign, routes)
