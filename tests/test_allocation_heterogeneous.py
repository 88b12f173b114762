"""Every strategy and objective on a fleet whose units offer different tasks.

A plain ``conc`` of more than ``CP_MAX_FLAT_TASKS`` move-tos goes to the routing solver, which must
keep each task to the units that offer it (OR-Tools 9.15's binding rejects every argument to
``SetAllowedVehiclesForIndex``: the planner crashed with a ``TypeError`` there); a mixed tree goes
to CP-SAT.
"""

from __future__ import annotations

import random
from typing import Any

import pytest

from allocation_helpers import geo, move_to, unit
from delegation.allocation import OBJECTIVES, STRATEGIES, check_invariants, plan_mission
from delegation.allocation.optimal import CP_MAX_FLAT_TASKS
from delegation.fleet import UnitState
from delegation.tst import TstNode, parse_tree


def _look_at(x: float, y: float) -> dict[str, Any]:
    return {"name": "look-at-position", "common_params": {"execunit": "*"},
            "params": {"geopoint": geo(x, y)}}


def _fleet() -> list[UnitState]:
    """Two full units, one that only moves, one that only looks, one that only follows paths."""
    return [
        unit("full0", 0, 0),
        unit("full1", 1500, -800, speed=8.0),
        unit("mover", -1200, 900, speed=4.0, tasks=("move-to",)),
        unit("looker", 300, 300, tasks=("look-at-position",)),
        unit("pather", 0, 1000, tasks=("move-path",)),
    ]


def _points(seed: int, n: int) -> list[tuple[float, float]]:
    rng = random.Random(seed)
    return [(rng.uniform(-2000, 2000), rng.uniform(-2000, 2000)) for _ in range(n)]


def _plain_conc() -> TstNode:
    leaves = [move_to(x, y) for x, y in _points(1, CP_MAX_FLAT_TASKS + 4)]
    leaves.append(_look_at(100, 100))
    return parse_tree({"name": "conc", "children": leaves})


def _mixed() -> TstNode:
    pts = _points(2, 7)
    leaves = [move_to(x, y) for x, y in pts]
    return parse_tree({"name": "seq", "children": [
        leaves[0],
        {"name": "conc", "children": [
            {"name": "seq", "children": [leaves[1], leaves[2], _look_at(*pts[2])]},
            {"name": "seq", "children": leaves[3:5]},
            *leaves[5:],
        ]},
    ]})


TREES = {"plain conc": _plain_conc, "mixed": _mixed}


@pytest.mark.parametrize("shape", list(TREES))
@pytest.mark.parametrize("objective", list(OBJECTIVES))
@pytest.mark.parametrize("strategy", list(STRATEGIES))
def test_every_strategy_plans_a_heterogeneous_fleet(
    strategy: str, objective: str, shape: str
) -> None:
    tree, units = TREES[shape](), _fleet()
    plan = plan_mission(tree, units, strategy=strategy, objective=objective, time_limit=0.5)
    assert plan.feasible
    if strategy == "optimal":
        solver = "routing" if shape == "plain conc" else "CP-SAT"
        assert any(solver in note for note in plan.notes), plan.notes
    assert check_invariants(plan, tree, units) == []
    offered = {u.name: u.tasks for u in units}
    for a in plan.assignments:
        assert a.name in offered[a.execunit.strip("/")]
    used = {a.execunit for a in plan.assignments}
    assert "/pather" not in used  # the tree has no move-path
    looks = [a for a in plan.assignments if a.name == "look-at-position"]
    assert looks and all(a.execunit != "/mover" for a in looks)
