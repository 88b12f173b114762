"""The auction for plain trees (``Problem.plain``): a unit's bids depend only on its own route.

Bids live in a (units x tasks) array; after each round only the winner's row is recomputed, with
numpy over all candidate positions at once (the case that must scale to 200 units x 1000 tasks).
"""

from __future__ import annotations

import numpy as np

from delegation.allocation.problem import Problem
from delegation.allocation.routes import first_insertion_costs, home_legs, insertion_costs
from delegation.allocation.schedule import EPS
from delegation.allocation.strategies import Objective


def flat_auction(
    problem: Problem, objective: Objective
) -> tuple[np.ndarray, list[list[int]]]:
    """Assignment and per-unit routes of the vehicle tasks."""
    n_units, n_tasks = problem.n_units, problem.n_tasks
    assign = np.full(n_tasks, -1, dtype=int)
    routes: list[list[int]] = [[] for _ in range(n_units)]
    vehicle = problem.vehicle
    open_tasks = vehicle & problem.allowed.any(axis=0)
    if n_units == 0 or not open_tasks.any():
        return assign, routes
    base = home_legs(problem)
    used = np.zeros(n_units)  # travel + work incl. way home; 0 while idle (flat: also finish time)
    delta = np.full((n_units, n_tasks), np.inf)
    pos = np.zeros((n_units, n_tasks), dtype=int)
    alias_of = problem.alias_of()
    allowed = problem.allowed & open_tasks[None, :]

    def recompute(u: int) -> None:
        delta[u] = np.inf
        cand = np.nonzero(allowed[u])[0]
        if cand.size == 0:
            return
        costs = insertion_costs(problem, u, routes[u], cand)
        best = np.argmin(costs, axis=0)
        add = costs[best, np.arange(cand.size)]
        now = used[u] if routes[u] else base[u]
        ok = now + add <= problem.endurance[u] * (1 + EPS) + EPS
        delta[u, cand] = np.where(ok, add, np.inf)
        pos[u, cand] = best

    first = first_insertion_costs(problem)
    if first is None:
        for u in range(n_units):
            recompute(u)
    else:  # every route is empty: ``recompute`` of every unit at once (position 0)
        ok = base[:, None] + first <= problem.endurance[:, None] * (1 + EPS) + EPS
        delta[...] = np.where(allowed & ok, first, np.inf)
    makespan = 0.0
    for _ in range(int(open_tasks.sum())):
        current = np.where([bool(r) for r in routes], used, base)[:, None]
        match objective:
            case Objective.MAKESPAN:
                primary = np.maximum(current + delta, makespan)
                secondary = delta
            case Objective.TOTAL:
                primary = delta
                secondary = current + delta
        best = primary.min()
        if not np.isfinite(best):
            break
        flat_index = int(np.argmin(np.where(primary <= best, secondary, np.inf)))
        u, t = divmod(flat_index, n_tasks)
        routes[u].insert(int(pos[u, t]), t)
        used[u] = (used[u] if len(routes[u]) > 1 else base[u]) + delta[u, t]
        makespan = max(makespan, used[u])
        assign[t] = u
        allowed[:, t] = False
        delta[:, t] = np.inf
        bind_alias(problem, alias_of, allowed, delta, u, t)
        recompute(u)
    return assign, routes


def bind_alias(
    problem: Problem, alias_of: np.ndarray, allowed: np.ndarray, delta: np.ndarray, u: int, t: int
) -> None:
    """Task ``t`` went to unit ``u``: the rest of its alias group may go to ``u`` only."""
    g = alias_of[t]
    if g < 0:
        return
    members = problem.alias_groups[g]
    others = np.ones(problem.n_units, dtype=bool)
    others[u] = False
    allowed[np.ix_(others, members)] = False
    delta[np.ix_(others, members)] = np.inf
