"""Small generated allocation instances and a brute-force optimum, shared by the allocation tests.

The brute force enumerates every assignment of vehicle tasks to allowed units (aliases: one unit per
alias) and every order on every unit, evaluates each with the schedule simulator (itself tested
against hand-computed numbers in test_allocation_schedule.py, including conc children that share
a unit running one after another as whole subtrees) and keeps the best. Allocations the
instantiated tree cannot run (deadlocks, units disagreeing on the order of subtrees) are invalid
and skipped.
"""

from __future__ import annotations

import itertools
import random
from typing import Any

import numpy as np

from delegation.allocation.problem import Problem, build_problem
from delegation.allocation.schedule import Schedule, evaluate
from delegation.fleet import UnitState, make_unit
from delegation.geo import LocalFrame
from delegation.tst import TstNode, parse_tree, with_defaults, with_uuids

FRAME = LocalFrame(57.76, 16.68)


def geo(x: float, y: float) -> dict[str, Any]:
    return FRAME.geopoint(x, y).to_wire()


def move_to(x: float, y: float, execunit: str = "*", speed: str = "standard") -> dict[str, Any]:
    return {
        "name": "move-to",
        "common_params": {"execunit": execunit},
        "params": {"speed": speed, "waypoint": geo(x, y)},
    }


def unit(name: str, x: float, y: float, speed: float = 5.0, home: bool = False,
         tasks: tuple[str, ...] = ("move-to", "move-path", "look-at-position"),
         **kw: Any) -> UnitState:
    return make_unit(
        name, "air", FRAME.geopoint(x, y), tasks,
        {"slow": speed / 2, "standard": speed, "fast": speed * 2},
        home=FRAME.geopoint(x, y) if home else None, **kw,
    )


SHAPES = ("conc", "seq-of-concs", "conc-of-seqs", "seq", "aliases", "mixed", "subtrees",
          "nested")


def random_instance(seed: int, shape: str, n_tasks: int = 6, n_units: int = 3,
                    homes: bool | None = None) -> tuple[TstNode, list[UnitState]]:
    """A tree of ``n_tasks`` move-tos of the given shape and ``n_units`` units, from ``seed``."""
    rng = random.Random(seed)
    pts = [(rng.uniform(-2000, 2000), rng.uniform(-2000, 2000)) for _ in range(n_tasks)]
    speeds = ["standard", "fast", "slow"]
    leaves = [move_to(x, y, speed=speeds[rng.randrange(3)] if rng.random() < 0.3 else "standard")
              for x, y in pts]
    if homes is None:
        homes = rng.random() < 0.5
    units = [
        unit(f"u{k}", rng.uniform(-2000, 2000), rng.uniform(-2000, 2000),
             speed=rng.choice([4.0, 5.0, 8.0]), home=homes and k != 1)
        for k in range(n_units)
    ]
    if shape == "conc":
        tree = {"name": "conc", "children": leaves}
    elif shape == "seq":
        tree = {"name": "seq", "children": leaves}
    elif shape == "seq-of-concs":
        h = n_tasks // 2
        tree = {"name": "seq", "children": [{"name": "conc", "children": leaves[:h]},
                                            {"name": "conc", "children": leaves[h:]}]}
    elif shape == "conc-of-seqs":
        h = n_tasks // 2
        tree = {"name": "conc", "children": [{"name": "seq", "children": leaves[:h]},
                                             {"name": "seq", "children": leaves[h:]}]}
    elif shape == "aliases":
        for i, leaf in enumerate(leaves):
            leaf["common_params"]["execunit"] = ["A", "B", "*"][i % 3]
        tree = {"name": "conc", "children": [{"name": "seq", "children": leaves[:3]},
                                             {"name": "conc", "children": leaves[3:]}]}
    elif shape == "mixed":
        leaves[0]["common_params"]["execunit"] = "/u0"
        leaves[1]["common_params"]["execunit"] = "A"
        leaves[4 % n_tasks]["common_params"]["execunit"] = "A"
        tree = {"name": "seq", "children": [
            leaves[0],
            {"name": "conc", "children": [{"name": "seq", "children": leaves[1:3]}, *leaves[3:]]},
        ]}
    elif shape == "subtrees":
        # Four conc children, two of them seqs: units shared between subtrees and single tasks
        # make components of three or four children, some with no unit in common.
        h = max(2, n_tasks // 3)
        tree = {"name": "conc", "children": [
            {"name": "seq", "children": leaves[:h]},
            {"name": "seq", "children": leaves[h : 2 * h]},
            *leaves[2 * h :],
        ]}
    elif shape == "nested":
        # A seq ending in a conc, next to a seq and a single task: wrappers at two levels.
        tree = {"name": "conc", "children": [
            {"name": "seq", "children": [leaves[0], {"name": "conc", "children": leaves[1:3]}]},
            {"name": "seq", "children": leaves[3:5]},
            *leaves[5:],
        ]}
    else:
        raise ValueError(shape)
    return parse_tree(tree), units


def prepared_for(tree: TstNode) -> TstNode:
    """The tree with uuids (``n0``, ``n1`` ...) and catalogue defaults, as planning prepares it."""
    n = iter(range(10_000))
    return with_defaults(with_uuids(tree, lambda: f"n{next(n)}"))


def problem_for(tree: TstNode, units: list[UnitState]) -> Problem:
    return build_problem(prepared_for(tree), units)


def brute_force(problem: Problem, objective: str) -> Schedule:
    """The best schedule over all assignments and all orders (small instances only)."""
    return brute_force_all(problem)[objective]


def brute_force_all(problem: Problem) -> dict[str, Schedule]:
    """The best schedule per objective, from one enumeration of all assignments and orders."""
    vehicle = [t for t in range(problem.n_tasks) if problem.tasks[t].vehicle
               and problem.allowed[:, t].any()]
    alias_of = problem.alias_of()
    choices = [np.nonzero(problem.allowed[:, t])[0].tolist() for t in vehicle]
    best: dict[str, Schedule] = {}
    for combo in itertools.product(*choices):
        bound: dict[int, int] = {}
        ok = True
        for t, u in zip(vehicle, combo, strict=True):
            g = alias_of[t]
            if g >= 0 and bound.setdefault(g, u) != u:
                ok = False
                break
        if not ok:
            continue
        per_unit: list[list[int]] = [[] for _ in range(problem.n_units)]
        for t, u in zip(vehicle, combo, strict=True):
            per_unit[u].append(t)
        assign = np.full(problem.n_tasks, -1, dtype=int)
        for t, u in zip(vehicle, combo, strict=True):
            assign[t] = u
        for orders in itertools.product(*[itertools.permutations(r) for r in per_unit]):
            s = evaluate(problem, assign, [list(o) for o in orders])
            if not s.valid:
                continue
            for objective in ("makespan", "total"):
                if objective not in best or s.key(objective) < best[objective].key(objective):
                    best[objective] = s
    assert len(best) == 2
    return best
