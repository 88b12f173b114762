"""Sequential single-item auction.

Each round every capable unit bids, for every unassigned task, the marginal cost of inserting it at
the best place in its own route (for the chosen objective: makespan with ties broken by total time,
or total time); the lowest bid wins, ties go to the lower unit, then the lower task index.

When every task is activated at mission start (a ``conc`` of tasks, the common case and the one that
must scale to 200 units x 1000 tasks), a unit's bids depend only on its own route: bids live in a
(units x tasks) array and after each round only the winner's row is recomputed, with numpy over all
candidate positions at once. When the tree orders tasks across units (``seq``), a task's marginal
makespan depends on the other units' timing, so bids are evaluated with the schedule simulator on
the two best positions (by added route time) of each (unit, task) pair, every round.
"""

from __future__ import annotations

import logging

import numpy as np

from delegation.allocation.problem import Problem
from delegation.allocation.routes import _home_leg, insertion_costs, valid_positions
from delegation.allocation.schedule import EPS, Schedule, evaluate

log = logging.getLogger(__name__)


def assign_passive(problem: Problem, assign: np.ndarray) -> None:
    """Give every unassigned non-vehicle task (``look-at-*``) a unit, in place.

    They neither travel nor occupy the unit, so any allowed unit will do: the alias's unit where
    one is bound, else the first allowed unit holding the fewest such tasks.
    """
    vehicle = problem.vehicle
    alias_of = problem.alias_of()
    load = np.zeros(problem.n_units, dtype=int)
    for t in range(problem.n_tasks):
        if vehicle[t] or assign[t] >= 0:
            continue
        allowed = problem.allowed[:, t].copy()
        g = alias_of[t]
        if g >= 0:
            bound = {int(assign[m]) for m in problem.alias_groups[g] if assign[m] >= 0}
            if bound:
                mask = np.zeros_like(allowed)
                mask[next(iter(bound))] = True
                allowed &= mask
        if not allowed.any():
            continue
        choices = np.nonzero(allowed)[0]
        u = int(choices[np.argmin(load[choices])])
        assign[t] = u
        load[u] += 1


def unassigned_reason(problem: Problem, t: int) -> str:
    """Why task ``t`` is left out of a plan."""
    if problem.reasons[t]:
        return str(problem.reasons[t])
    return "no capable unit has enough endurance left to add it to its route"


def auction(problem: Problem, objective: str = "makespan") -> Schedule:
    """Plan with the sequential auction; see the module docstring."""
    if problem.flat:
        assign, orders = _flat_auction(problem, objective)
    else:
        assign, orders = _general_auction(problem, objective)
    assign_passive(problem, assign)
    return evaluate(problem, assign, orders)


def _flat_auction(problem: Problem, objective: str) -> tuple[np.ndarray, list[list[int]]]:
    n_units, n_tasks = problem.n_units, problem.n_tasks
    assign = np.full(n_tasks, -1, dtype=int)
    routes: list[list[int]] = [[] for _ in range(n_units)]
    vehicle = problem.vehicle
    open_tasks = vehicle & problem.allowed.any(axis=0)
    if n_units == 0 or not open_tasks.any():
        return assign, routes
    base = np.array([_home_leg(problem, u) for u in range(n_units)])
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

    for u in range(n_units):
        recompute(u)
    makespan = 0.0
    for _ in range(int(open_tasks.sum())):
        current = np.where([bool(r) for r in routes], used, base)[:, None]
        if objective == "total":
            primary = delta
            secondary = current + delta
        else:
            primary = np.maximum(current + delta, makespan)
            secondary = delta
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
        g = alias_of[t]
        if g >= 0:
            members = problem.alias_groups[g]
            others = np.ones(n_units, dtype=bool)
            others[u] = False
            allowed[np.ix_(others, members)] = False
            delta[np.ix_(others, members)] = np.inf
        recompute(u)
    return assign, routes


def _general_auction(problem: Problem, objective: str) -> tuple[np.ndarray, list[list[int]]]:
    n_units, n_tasks = problem.n_units, problem.n_tasks
    assign = np.full(n_tasks, -1, dtype=int)
    routes: list[list[int]] = [[] for _ in range(n_units)]
    vehicle = problem.vehicle
    allowed = problem.allowed & vehicle[None, :]
    alias_of = problem.alias_of()
    remaining = [t for t in range(n_tasks) if allowed[:, t].any()]
    while remaining:
        best_key: tuple[float, ...] | None = None
        best_move: tuple[int, int, int] | None = None
        for u in range(n_units):
            cand = np.array([t for t in remaining if allowed[u, t]], dtype=int)
            if cand.size == 0:
                continue
            costs = insertion_costs(problem, u, routes[u], cand)
            for j, t in enumerate(cand.tolist()):
                lo, hi = valid_positions(problem, routes[u], t)
                if lo > hi:
                    continue
                column = costs[lo : hi + 1, j]
                for p in (lo + np.argsort(column, kind="stable")[:2]).tolist():
                    trial_routes = [list(r) for r in routes]
                    trial_routes[u].insert(p, t)
                    assign[t] = u
                    trial = evaluate(problem, assign, trial_routes)
                    assign[t] = -1
                    if not trial.valid:
                        continue
                    key = (*trial.key(objective), float(u), float(t))
                    if best_key is None or key < best_key:
                        best_key, best_move = key, (u, t, p)
        if best_move is None:
            break
        u, t, p = best_move
        routes[u].insert(p, t)
        assign[t] = u
        remaining.remove(t)
        g = alias_of[t]
        if g >= 0:
            for m in problem.alias_groups[g]:
                keep = allowed[u, m]
                allowed[:, m] = False
                allowed[u, m] = keep
    return assign, routes
