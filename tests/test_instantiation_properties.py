"""Series-parallel instantiation (docs/protocol.md §8), as properties over random allocations.

Whatever the tree's shape and whatever runnable allocation a strategy might return, the tree sent
contains every precedence of the plan (the caller's seq order and each unit's order), never lets
the engine start two vehicle tasks of one unit at once, and its simulated times are the plan's
(``check_invariants`` runs the sent tree as the engine would).
"""

from __future__ import annotations

import random

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from allocation_helpers import SHAPES, prepared_for, problem_for, random_instance
from delegation.allocation import check_invariants, make_plan, plan_mission
from delegation.allocation.invariants import _unsafe_pairs
from delegation.allocation.schedule import evaluate
from delegation.allocation.sent_tree import SERIES_PARALLEL, missing_precedences
from delegation.bench.generate import generate_scenario
from delegation.scenario import scenario_from_dict


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 10_000),
    shape=st.sampled_from(SHAPES),
    n_tasks=st.integers(2, 9),
    n_units=st.integers(1, 4),
    order_seed=st.integers(0, 10_000),
)
def test_the_sent_tree_holds_every_precedence_and_one_task_per_unit(
    seed: int, shape: str, n_tasks: int, n_units: int, order_seed: int
) -> None:
    tree, units = random_instance(seed, shape, n_tasks=n_tasks, n_units=n_units)
    problem = problem_for(tree, units)
    rng = random.Random(order_seed)
    assign = np.array([rng.choice(np.nonzero(problem.allowed[:, t])[0].tolist())
                       if problem.allowed[:, t].any() else -1 for t in range(problem.n_tasks)])
    orders: list[list[int]] = [[] for _ in range(problem.n_units)]
    for t in rng.sample(range(problem.n_tasks), problem.n_tasks):
        if assign[t] >= 0 and problem.tasks[t].vehicle:
            orders[int(assign[t])].append(t)
    schedule = evaluate(problem, assign, orders)
    if not schedule.valid:
        return  # a cycle between the units' orders and the tree: no strategy returns one
    plan = make_plan(problem, schedule, prepared_for(tree), strategy="auction",
                     objective="makespan", solve_time=0.0)
    routes = {name: [a.node_uuid for a in items] for name, items in plan.routes.items()}
    assert plan.source is not None
    assert missing_precedences(plan.source, plan.tst, routes) == []
    assert _unsafe_pairs(plan.tst, {a.node_uuid: a for a in plan.assignments}) == []
    assert check_invariants(plan, tree, units) == []
    assert plan.precedence_makespan == pytest.approx(schedule.makespan)
    assert plan.makespan >= schedule.makespan * (1 - 1e-9)


@pytest.mark.parametrize("seed", [0, 1])
def test_generated_mixed_trees_get_a_series_parallel_tree_that_beats_the_old_rule(
    seed: int,
) -> None:
    data = generate_scenario(units=10, tasks=30, seed=seed, structure="mixed")
    scenario = scenario_from_dict(data)
    tree, units = scenario.tree(), scenario.units()
    plan = plan_mission(tree, units, strategy="auction")
    assert check_invariants(plan, tree, units) == []
    assert any(note.startswith(f"instantiation: the {SERIES_PARALLEL} tree")
               for note in plan.notes)
    assert plan.instantiation_loss is not None and plan.instantiation_loss >= 0.0
    assert plan.lower_bound is not None and 0 < plan.lower_bound <= plan.precedence_makespan
    body = plan.to_json()
    assert body["precedence-makespan"] == plan.precedence_makespan
    assert body["instantiation-loss"] == plan.instantiation_loss
    assert body["fallback"] is None
