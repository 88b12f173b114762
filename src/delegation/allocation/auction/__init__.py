"""Sequential single-item auction.

Each round every capable unit bids, for every unassigned task, the marginal cost of inserting it at
the best place in its own route (for the chosen objective: makespan with ties broken by total time,
or total time); the lowest bid wins, ties go to the lower unit, then the lower task index.

When every task is activated at mission start and no conc child holds more than one task (a
``conc`` of tasks, the common case and the one that must scale to 200 units x 1000 tasks;
``Problem.plain``), a unit's bids depend only on its own route: bids live in a (units x tasks)
array and after each round only the winner's row is recomputed, with numpy over all candidate
positions at once. Otherwise (``seq`` orders tasks across units, or conc children are subtrees that
run one after another where they share a unit), bids are the same route insertions restricted to
positions that keep the tree's order and every subtree's tasks in one run per unit, but a task's
marginal makespan depends on the other units' timing: the auctioneer ranks the bids by an estimate
and simulates the best few exactly (see ``general``).

Modules: ``flat`` (plain trees), ``general`` (the rest, a ``_GeneralAuction``); this one chooses.
"""

from __future__ import annotations

import logging

import numpy as np

from delegation.allocation.auction.flat import flat_auction
from delegation.allocation.auction.general import POSITION_TRIES, SHARE_FACTOR, general_auction
from delegation.allocation.auction.improve import improve
from delegation.allocation.problem import Problem
from delegation.allocation.schedule import Schedule, evaluate
from delegation.allocation.strategies import Objective

log = logging.getLogger(__name__)

__all__ = [
    "POSITION_TRIES",
    "SHARE_FACTOR",
    "assign_passive",
    "auction",
    "unassigned_reason",
]


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


def auction(problem: Problem, objective: Objective | str = Objective.MAKESPAN) -> Schedule:
    """Plan with the sequential auction; see the module docstring. ``ValueError`` for an unknown
    objective.

    The awards are followed by a bounded local search (``improve``): moves of tasks off the unit
    that ends last, kept only when strictly better on the objective.
    """
    goal = Objective(objective)
    if problem.plain:
        assign, orders = flat_auction(problem, goal)
    else:
        assign, orders = general_auction(problem, goal)
    assign_passive(problem, assign)
    return improve(problem, goal, evaluate(problem, assign, orders))
