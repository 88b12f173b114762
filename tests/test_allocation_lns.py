"""The large neighbourhood search behind ``optimal`` on trees that are neither plain nor tiny."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from delegation.allocation import check_invariants, plan_mission
from delegation.allocation.auction import auction as auction_schedule
from delegation.allocation.optimal.lns import better_key, tree_key
from delegation.allocation.optimal.parallel import (
    HELPER_SCRIPT,
    HelperLns,
    LnsAnswer,
    use_second_core,
)
from delegation.allocation.problem import build_problem
from delegation.allocation.schedule import evaluate
from delegation.allocation.strategies import Objective
from delegation.bench.generate import generate_scenario
from delegation.fleet import UnitState
from delegation.runtime.second_core import launch
from delegation.scenario import scenario_from_dict
from delegation.tst import TstNode, with_defaults, with_uuids


@pytest.mark.slow  # searches for its time limit
def test_optimal_searches_mixed_trees_within_its_time_limit_and_beats_the_auction() -> None:
    scenario = scenario_from_dict(generate_scenario(units=10, tasks=30, seed=0,
                                                    structure="mixed"))
    tree, units = scenario.tree(), scenario.units()
    auction = plan_mission(tree, units, strategy="auction")
    # The limit is wall-clock: on a loaded machine (8 test workers, other suites: load average
    # 15-22) the search got a fraction of a core and once ended at 2005 s against the auction's
    # 1998 s. A search that was given most of its limit in CPU must beat the auction; a starved
    # one is given once more with 6 s.
    for limit in (2.0, 6.0):
        cpu = time.thread_time()
        plan = plan_mission(tree, units, strategy="optimal", time_limit=limit)
        cpu = time.thread_time() - cpu
        if plan.makespan < auction.makespan or cpu >= 0.6 * limit:
            break
    # The search stops at 90 % of the limit; the slack is for a loaded machine (this bounds a
    # runaway search, it does not time the planner: benchmarks do that).
    assert plan.solve_time <= limit * 1.5
    assert check_invariants(plan, tree, units) == []
    assert any(note.startswith("large neighbourhood search:") for note in plan.notes)
    assert plan.makespan < auction.makespan, f"{cpu:.2f} s of CPU"  # measured: 1828 -> ~1300 s
    assert plan.fallback is None and plan.strategy_label == "optimal"


@pytest.fixture
def second_core() -> Iterator[None]:
    use_second_core(launch)
    yield
    use_second_core(None)


def _mixed(units: int, tasks: int) -> tuple[TstNode, list[UnitState]]:
    scenario = scenario_from_dict(generate_scenario(units=units, tasks=tasks, seed=0,
                                                    structure="mixed"))
    return scenario.tree(), scenario.units()


@pytest.mark.slow  # searches for its time limit
def test_the_search_runs_on_both_cores_within_its_time_limit(second_core: None) -> None:
    """With a second core, a helper process searches with another seed; the better is kept."""
    tree, units = _mixed(10, 30)
    auction = plan_mission(tree, units, strategy="auction")
    plan = plan_mission(tree, units, strategy="optimal", time_limit=3.0)
    assert plan.solve_time <= 3.0 * 1.5  # a runaway bound, with slack for a loaded machine
    assert check_invariants(plan, tree, units) == []
    notes = " ".join(plan.notes)
    assert "large neighbourhood search on the second core (another seed): " in notes
    assert plan.makespan < auction.makespan


@pytest.mark.slow  # searches for its time limit
def test_the_helper_search_answers_a_valid_schedule_no_worse_than_its_start(
    second_core: None,
) -> None:
    tree, units = _mixed(10, 30)
    problem = build_problem(with_defaults(with_uuids(tree)), units)
    start = auction_schedule(problem, Objective.MAKESPAN)
    # 4 s: the helper must get past its own start (imports) and search. Its deadline is
    # wall-clock: on a machine loaded past that (load average 22, 8 test workers and other
    # suites) it can start after it and answer its start, no search done; then again with 8 s
    # and 16 s (8 s was not enough once at load average 20). A helper that never searches fails
    # every try.
    for seconds in (4.0, 8.0, 16.0):
        helper = HelperLns.start(problem, Objective.MAKESPAN, start, seconds, seed=3)
        assert helper is not None
        answer = helper.result(30)
        assert isinstance(answer, LnsAnswer), answer
        if answer.iterations > 0:
            break
    found = evaluate(problem, answer.assign, answer.orders)
    assert found.valid and answer.iterations > 0
    before = tree_key(problem, Objective.MAKESPAN, start)
    assert not better_key(before, tree_key(problem, Objective.MAKESPAN, found))


def test_without_a_second_core_the_search_runs_alone() -> None:
    tree, units = _mixed(10, 30)
    plan = plan_mission(tree, units, strategy="optimal", time_limit=1.0)
    assert "second core" not in " ".join(plan.notes)


def test_a_failing_search_helper_is_reported_not_raised(second_core: None) -> None:
    answer = launch(HELPER_SCRIPT, b"not a pickle").result(30)
    assert isinstance(answer, str) and answer.startswith("helper failed")
