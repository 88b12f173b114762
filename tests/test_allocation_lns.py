"""The large neighbourhood search behind ``optimal`` on trees that are neither plain nor tiny."""

from __future__ import annotations

from delegation.allocation import check_invariants, plan_mission
from delegation.bench.generate import generate_scenario
from delegation.scenario import scenario_from_dict


def test_optimal_searches_mixed_trees_within_its_time_limit_and_beats_the_auction() -> None:
    scenario = scenario_from_dict(generate_scenario(units=10, tasks=30, seed=0,
                                                    structure="mixed"))
    tree, units = scenario.tree(), scenario.units()
    auction = plan_mission(tree, units, strategy="auction")
    plan = plan_mission(tree, units, strategy="optimal", time_limit=2.0)
    assert plan.solve_time <= 2.0 * 1.1  # the search stops at 90 % of the limit
    assert check_invariants(plan, tree, units) == []
    assert any(note.startswith("large neighbourhood search:") for note in plan.notes)
    assert plan.makespan < auction.makespan  # measured: 1828 s -> ~1300 s in 2 s
    assert plan.fallback is None and plan.strategy_label == "optimal"
