"""The auction's closing local search (``auction.improve``, issue 25).

It may only make a plan better: on generated trees of every shape and both objectives the plan
``plan_mission`` returns with it is never worse than without it (the sent tree's makespan, the
total time), every task keeps a unit, alias groups stay on one unit and every unit's tasks under
each node stay one run. On the issue-25 case (partner A's own tasks of two-site scenario 0 of
``benchmarks/federation.py``) the auction alone put the long ``move-path`` after a short task on
the same unit: 441 s where one service seeing both fleets planned A's units to 314 s.
"""

from __future__ import annotations

import importlib
from typing import Any

import numpy as np
import pytest

from allocation_helpers import SHAPES, problem_for, random_instance
from delegation.allocation import plan_mission
from delegation.allocation.auction import auction
from delegation.allocation.auction.flat import flat_auction
from delegation.allocation.auction.general import general_auction
from delegation.allocation.auction.improve import improve
from delegation.allocation.routes import keeps_subtrees_whole
from delegation.allocation.schedule import evaluate
from delegation.allocation.strategies import Objective
from delegation.fleet import make_unit
from delegation.geo import LocalFrame

AUCTION = importlib.import_module("delegation.allocation.auction")
CASES = [(seed, shape, objective) for seed in range(4) for shape in SHAPES
         for objective in ("makespan", "total")]


def _without_search(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(AUCTION, "improve", lambda problem, objective, schedule: schedule)


@pytest.mark.parametrize(("seed", "shape", "objective"), CASES)
def test_search_keeps_the_plan_whole_and_never_worse_than_the_auction(
    seed: int, shape: str, objective: str
) -> None:
    tree, units = random_instance(seed, shape, n_tasks=10, n_units=4)
    problem = problem_for(tree, units)
    goal = Objective(objective)
    assign, orders = (flat_auction if problem.plain else general_auction)(problem, goal)
    AUCTION.assign_passive(problem, assign)
    raw = evaluate(problem, assign, orders)
    better = improve(problem, goal, raw)
    assert better.valid or better is raw
    assert (better.assign >= 0).tolist() == (raw.assign >= 0).tolist()
    for group in problem.alias_groups:
        assert len({int(better.assign[t]) for t in group}) == 1
    for route in better.orders:
        for k, t in enumerate(route):
            rest = route[:k] + route[k + 1:]
            assert keeps_subtrees_whole(problem, rest, np.array([t]))[k, 0], (route, t)
    if problem.plain:  # the graph is the tree: the search's own measure is the plan's
        assert better.key(goal) <= raw.key(goal)


@pytest.mark.parametrize(("seed", "shape", "objective"), CASES)
def test_plan_with_the_search_is_never_worse(
    seed: int, shape: str, objective: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    tree, units = random_instance(seed, shape, n_tasks=10, n_units=4)
    with_search = plan_mission(tree, units, strategy="auction", objective=objective)
    _without_search(monkeypatch)
    alone = plan_mission(tree, units, strategy="auction", objective=objective)
    assert with_search.feasible == alone.feasible
    assert len(with_search.unassigned) == len(alone.unassigned)
    first, other = ("makespan", "total_time") if objective == "makespan" \
        else ("total_time", "makespan")
    a, b = getattr(with_search, first), getattr(alone, first)
    assert a < b * (1 - 1e-9) or (a <= b * (1 + 1e-9)
                                  and getattr(with_search, other) <= getattr(alone, other) + 1e-6)


FRAME = LocalFrame(57.7605, 16.6815)
SPEEDS = {"slow": 4.0, "standard": 8.0, "fast": 14.0}


def _pt(x: float, y: float) -> dict[str, Any]:
    return FRAME.geopoint(x, y, 30.0).to_wire()


def _move(x: float, y: float) -> dict[str, Any]:
    return {"name": "move-to", "params": {"waypoint": _pt(x, y)}}


def _issue25_case() -> tuple[dict[str, Any], list[Any]]:
    """Partner A's part of federation.py's scenario 0 (seed 1), to the metre."""
    tree = {"name": "conc", "children": [
        {"name": "seq", "children": [_move(-751, -759), _move(66, 703)]},
        {"name": "seq", "children": [_move(703, 85), _move(-247, 283)]},
        {"name": "move-path", "params": {"waypoints": [_pt(-640, 207), _pt(358, -326),
                                                       _pt(389, 633)]}},
        _move(390, -153),
    ]}
    units = [make_unit(name, "air", FRAME.geopoint(x, y, 30.0),
                       ["move-to", "move-path", "search-area"], speeds=SPEEDS)
             for name, x, y in (("a0", -219, 208), ("a1", 158, -147), ("a2", -3, -30))]
    return tree, units


def test_issue25_subset_is_no_longer_planned_much_worse(monkeypatch: pytest.MonkeyPatch) -> None:
    tree, units = _issue25_case()
    with_search = plan_mission(tree, units, strategy="auction")
    _without_search(monkeypatch)
    alone = plan_mission(tree, units, strategy="auction")
    # The auction alone: 441 s (the move-path after a short task); one service seeing both
    # fleets planned these tasks on these units to 314 s: within 15 % of that now.
    assert alone.makespan > 400
    assert with_search.makespan <= 314 * 1.15


def test_single_unit_and_invalid_schedules_are_returned_as_they_are() -> None:
    tree, units = random_instance(0, "conc", n_tasks=5, n_units=1)
    problem = problem_for(tree, units)
    one = auction(problem, Objective.MAKESPAN)
    assert improve(problem, Objective.MAKESPAN, one) is one
