"""The example plugin plans a generated scenario into a sound plan.

Run: PYTHONPATH=examples/greedy_plugin pytest examples/greedy_plugin
"""

from delegation.allocation import check_invariants, plan_mission
from delegation.allocation.strategies import STRATEGIES, resolve_strategy
from delegation.bench.generate import generate_scenario
from delegation.scenario import scenario_from_dict


def test_least_loaded_gives_a_sound_plan() -> None:
    name = resolve_strategy("greedy_plugin.strategy:least_loaded")
    try:
        scenario = scenario_from_dict(generate_scenario(units=4, tasks=15, seed=2))
        tree, units = scenario.tree(), scenario.units()
        plan = plan_mission(tree, units, strategy=name, objective="makespan")
        assert plan.strategy == name
        assert len(plan.assignments) + len(plan.unassigned) == 15
        assert list(check_invariants(plan, tree, units)) == []
        assert "least-loaded (example plugin)" in plan.notes
    finally:
        STRATEGIES.unregister(name)
