"""The auction's fast paths give exactly what the plain computations give (issue 9 item 6).

Each shortcut is checked against the computation it replaces, on generated trees of every shape:
the bid bound prunes only bids that cannot win (the same plan as simulating the whole shortlist),
the stacked tables rebid as the unit-by-unit ones do, the first tables of all units at once equal
``recompute`` unit by unit (in the general auction and the flat one), suffix minima equal
``np.argmin`` over the allowed positions, the LCA table equals the ancestry comparison, the
closed-ring test equals ``np.allclose``, and the small insertion tables priced in plain Python
equal numpy's to the bit.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest

import delegation.allocation.auction.flat as flat
import delegation.allocation.auction.stacked as stacked
import delegation.allocation.routes as routes
from allocation_helpers import SHAPES, problem_for, random_instance
from delegation.allocation import problem as problem_module
from delegation.allocation.auction import auction
from delegation.allocation.auction.general import _GeneralAuction, _suffix_minima
from delegation.allocation.problem import Problem
from delegation.allocation.schedule import Schedule
from delegation.allocation.strategies import Objective
from delegation.lanes import _close

CASES = [(seed, shape, objective) for seed in range(3) for shape in SHAPES
         for objective in ("makespan", "total")]


def _instance(seed: int, shape: str, homes: bool | None = None) -> Problem:
    tree, units = random_instance(seed, shape, n_tasks=14, n_units=4, homes=homes)
    return problem_for(tree, units)


def _same(a: Schedule, b: Schedule) -> None:
    assert a.assign.tolist() == b.assign.tolist()
    assert a.orders == b.orders
    assert a.makespan == b.makespan and a.total_time == b.total_time


@pytest.mark.parametrize(("seed", "shape", "objective"), CASES)
def test_the_bound_prunes_only_bids_that_cannot_win(
    seed: int, shape: str, objective: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    fast = auction(_instance(seed, shape), objective)
    # Bounds of zero prune nothing: every shortlisted bid is simulated.
    monkeypatch.setattr(_GeneralAuction, "_bounds",
                        lambda self, bids, cols: np.zeros(len(bids)))
    _same(fast, auction(_instance(seed, shape), objective))


def _same_with(monkeypatch: pytest.MonkeyPatch, setting: tuple[object, str, int], seed: int,
               shape: str, objective: str) -> tuple[Any, Any]:
    """The auction's plan, then its plan again with ``setting`` (module, name, value) in force:
    the two must be the same."""
    fast = auction(_instance(seed, shape), objective)
    monkeypatch.setattr(*setting)
    slow = auction(_instance(seed, shape), objective)
    _same(fast, slow)
    return fast, slow


@pytest.mark.parametrize(("seed", "shape", "objective"), CASES)
def test_stacked_tables_rebid_as_unit_by_unit(
    seed: int, shape: str, objective: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    _same_with(monkeypatch, (stacked, "STACK_LIMIT", 0), seed, shape, objective)


@pytest.mark.parametrize("homes", [False, True])
@pytest.mark.parametrize("shape", SHAPES)
def test_first_tables_at_once_equal_recompute_unit_by_unit(shape: str, homes: bool) -> None:
    at_once = _GeneralAuction(_instance(1, shape, homes), Objective.MAKESPAN)
    assert at_once._first_tables()
    one_by_one = _GeneralAuction(_instance(1, shape, homes), Objective.MAKESPAN)
    for u in range(one_by_one.n_units):
        one_by_one.recompute(u)
    for u in range(at_once.n_units):
        np.testing.assert_array_equal(at_once.costs[u], one_by_one.costs[u])
    np.testing.assert_array_equal(at_once.delta, one_by_one.delta)
    np.testing.assert_array_equal(at_once.pos, one_by_one.pos)


@pytest.mark.parametrize("homes", [False, True])
@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("objective", ["makespan", "total"])
def test_flat_first_bids_at_once_equal_recompute_unit_by_unit(
    seed: int, objective: str, homes: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert _instance(seed, "conc", homes).plain  # (what the flat auction plans)
    fast = auction(_instance(seed, "conc", homes), objective)
    monkeypatch.setattr(flat, "first_insertion_costs", lambda problem: None)
    slow = auction(_instance(seed, "conc", homes), objective)
    _same(fast, slow)
    np.testing.assert_array_equal(fast.start, slow.start)


def test_suffix_minima_are_argmin_over_the_positions_left() -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):
        rows, cols = int(rng.integers(1, 6)), int(rng.integers(1, 8))
        table = rng.choice([1.0, 2.0, 3.0, np.inf], size=(rows, cols))  # ties and no position
        low, arg = _suffix_minima(table)
        for p in range(rows):
            masked = np.where(np.arange(rows)[:, None] >= p, table, np.inf)
            np.testing.assert_array_equal(low[p], masked.min(axis=0))
            finite = np.isfinite(low[p])
            np.testing.assert_array_equal(arg[p][finite], np.argmin(masked, axis=0)[finite])


@pytest.mark.parametrize("shape", SHAPES)
def test_lca_table_equals_the_ancestry_comparison(
    shape: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    problem = _instance(2, shape)
    a, b = np.meshgrid(np.arange(problem.n_tasks), np.arange(problem.n_tasks), indexing="ij")
    table = problem.lca_depth(a, b)
    monkeypatch.setattr(problem_module, "LCA_TABLE_TASKS", 0)
    np.testing.assert_array_equal(table, _instance(2, shape).lca_depth(a, b))


def test_closed_ring_test_equals_allclose() -> None:
    values = [0.0, 1.0, 1.0 + 1e-6, 1.0 + 1e-4, -1.0, math.inf, -math.inf, math.nan, 1e8,
              1e8 + 1e3, 1e8 + 1e4]
    for a in itertools.product(values, repeat=2):
        for b in itertools.product(values, repeat=2):
            assert _close(list(a), list(b)) == bool(np.allclose(a, b)), (a, b)


@pytest.mark.parametrize("homes", [False, True])
@pytest.mark.parametrize("shape", SHAPES)
def test_small_insertion_tables_in_python_equal_numpy_to_the_bit(
    shape: str, homes: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    problem = _instance(3, shape, homes)
    rng = np.random.default_rng(3)
    cases = []
    for _ in range(40):
        u = int(rng.integers(problem.n_units))
        tasks = rng.permutation(problem.n_tasks)
        k = int(rng.integers(0, 6))
        cases.append((u, tasks[:k].tolist(), np.sort(tasks[k:])))
    small = [(routes.insertion_costs(problem, u, r, c),
              routes.whole_insertion_costs(problem, u, r, c)) for u, r, c in cases]
    monkeypatch.setattr(routes, "SMALL_TABLE", 0)
    for (u, r, c), (costs, whole) in zip(cases, small, strict=True):
        assert costs.shape == (len(r) + 1, c.size)
        np.testing.assert_array_equal(costs, routes.insertion_costs(problem, u, r, c))
        np.testing.assert_array_equal(whole, np.where(
            routes.keeps_subtrees_whole(problem, r, c), costs, np.inf))


@pytest.mark.parametrize(("seed", "shape", "objective"), CASES)
def test_auction_with_small_tables_in_python_plans_as_with_numpy(
    seed: int, shape: str, objective: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    fast, slow = _same_with(monkeypatch, (routes, "SMALL_TABLE", 0), seed, shape, objective)
    np.testing.assert_array_equal(fast.start, slow.start)


@pytest.mark.parametrize("homes", [False, True])
@pytest.mark.parametrize("shape", SHAPES)
def test_route_points_from_the_problems_lists_equal_points_for(shape: str, homes: bool) -> None:
    problem = _instance(4, shape, homes)
    rng = np.random.default_rng(4)
    for _ in range(30):
        u = int(rng.integers(problem.n_units))
        route = rng.permutation(problem.n_tasks)[: int(rng.integers(0, 6))].tolist()
        start, end, travels = problem.points_for(u, np.asarray(route, dtype=int))
        prev = [problem.unit_xy[u]]
        for k in range(len(route)):
            prev.append(end[k] if travels[k] else prev[k])
        here, speed = np.zeros(2), math.inf
        if problem.has_home[u]:
            here, speed = problem.home_xy[u], float(problem.home_speed[u])
        nxt, speeds = [here] * (len(route) + 1), [speed] * (len(route) + 1)
        for k in range(len(route) - 1, -1, -1):
            if travels[k]:
                here, speed = start[k], float(problem.speed[u, route[k]])
            nxt[k], speeds[k] = here, speed
        got = routes.route_points(problem, u, route)
        np.testing.assert_array_equal(got[0], np.array(prev).reshape(-1, 2))
        np.testing.assert_array_equal(got[1], np.array(nxt).reshape(-1, 2))
        np.testing.assert_array_equal(got[2], np.array(speeds))
