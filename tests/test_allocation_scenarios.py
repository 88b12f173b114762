"""Every bundled scenario, every strategy, both objectives: the plan passes check_invariants."""

from __future__ import annotations

from pathlib import Path

import pytest

from delegation.allocation import STRATEGIES, check_invariants, plan_mission
from delegation.scenario import load_scenario
from delegation.tst import leaves

SCENARIOS = sorted(
    p for p in (Path(__file__).resolve().parents[1] / "scenarios").iterdir()
    if p.suffix in (".yaml", ".yml", ".json")
)


def test_there_are_scenarios() -> None:
    assert len(SCENARIOS) >= 5


@pytest.mark.parametrize("path", SCENARIOS, ids=[p.name for p in SCENARIOS])
@pytest.mark.parametrize("strategy", STRATEGIES)
def test_plans_keep_the_invariants(path: Path, strategy: str) -> None:
    scenario = load_scenario(path)
    tree, units = scenario.tree(), scenario.units()
    for objective in ("makespan", "total"):
        plan = plan_mission(tree, units, strategy=strategy, objective=objective, time_limit=0.4)
        assert check_invariants(plan, tree, units) == []
        assert plan.strategy == strategy and plan.objective == objective
        # Every task (a shared search: each of its parts) is either assigned or unassigned with
        # a reason.
        planned = plan.planned if plan.planned is not None else tree
        assert len(plan.assignments) + len(plan.unassigned) == len(leaves(planned))


@pytest.mark.parametrize("path", SCENARIOS, ids=[p.name for p in SCENARIOS])
def test_optimal_is_never_worse_than_auction(path: Path) -> None:
    scenario = load_scenario(path)
    tree, units = scenario.tree(), scenario.units()
    plans = {s: plan_mission(tree, units, strategy=s, time_limit=0.4) for s in STRATEGIES}
    assert len(plans["optimal"].unassigned) <= len(plans["auction"].unassigned)
    if len(plans["optimal"].unassigned) == len(plans["auction"].unassigned):
        assert plans["optimal"].makespan <= plans["auction"].makespan * (1 + 1e-9)
