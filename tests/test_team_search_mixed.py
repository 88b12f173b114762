"""A shared search inside a tree with other tasks (DESIGN 3.11, issue 21): the parts are sized for
what each unit does before the search in the plan that flies them (``share_plan.before_search``,
``seen_in``, ``planner._reseated``), so that they end together and the search within 1.4 x its
bound.

The mixed case is ``benchmarks/team_search.py --only mixed``'s worst before the fix (the coast
scaled to 2 km2, six drones 0.5-2.5 km away): the parts were sized for the other tasks as the
unshared plan allocated them; planned with the parts, the auction gave a move-path to the unit
with the second largest part, which started it 2,000 s after the others (1.46 x the bound).
(Since each sweep starts at its end nearest the unit, that case is 1.09 x without the fix, and
coast3-0.2km2's shows the fault.) Pure logic: no clock, no network.
"""

from __future__ import annotations

import random

import numpy as np
import pytest

from delegation.allocation import check_invariants, plan_mission
from delegation.allocation import planner as planner_module
from delegation.allocation.problem import build_problem, flatten_tree
from delegation.allocation.schedule import evaluate
from delegation.allocation.share_plan import before_search
from delegation.bench.team_search import concave_polygons, fleet, geo_at, search_node, unit_at
from delegation.costs import cost_tables
from delegation.tst import TstNode, make_node, with_defaults, with_uuids


def move(x: float, y: float) -> TstNode:
    return make_node("move-to", execunit="*", params={"waypoint": geo_at(x, y),
                                                       "speed": "standard"})


def mixed_case(name: str, seed: int) -> tuple[TstNode, list]:  # type: ignore[type-arg]
    """The tree and fleet ``benchmarks/team_search.py``'s ``mixed`` plans for ``name``/``seed``:
    seq(move-to, conc(search, move-path, move-to), move-to)."""
    polygons = concave_polygons()
    k = list(polygons).index(name)
    poly = polygons[name]
    rng = random.Random(100 + 10 * k + seed)
    units = fleet(10 * k + seed, poly)
    reach = float(np.hypot(*(poly - poly.mean(axis=0)).T).max()) + 1000.0
    first = move(rng.uniform(-reach, reach), rng.uniform(-reach, reach))
    path = make_node("move-path", execunit="*", params={
        "waypoints": [geo_at(rng.uniform(-reach, reach), rng.uniform(-reach, reach))
                      for _ in range(3)], "speed": "standard"})
    tree = make_node("seq", children=[
        first,
        make_node("conc", children=[search_node(poly), path,
                                    move(rng.uniform(-reach, reach), -reach)]),
        move(rng.uniform(-reach, reach), reach)])
    return with_uuids(tree), units


def test_what_precedes_a_search_is_what_each_unit_does_before_its_own_part() -> None:
    # seq(m0, conc(search, a, b)): dji0 flies m0, dji1 the search then a, dji2 b.
    units = [unit_at(f"dji{i}", "air", 1500.0 * i, -2000.0) for i in range(3)]
    search = search_node(concave_polygons()["L-0.2km2"])
    tree = with_defaults(with_uuids(make_node("seq", children=[
        move(0.0, -1500.0),
        make_node("conc", children=[search, move(2000.0, 0.0), move(-2000.0, 0.0)])])))
    tables = cost_tables(units, [node for _, node in flatten_tree(tree)[1]])
    problem = build_problem(tree, units, tables)
    m0, s, a, b = range(4)
    schedule = evaluate(problem, [0, 1, 1, 2], [[m0], [s, a], [b]])
    seen = before_search(problem, tables, schedule, [s])
    assert seen.act == pytest.approx(float(schedule.end[m0]))
    # dji0: the move-to the tree puts first, and where it ends; dji1: nothing (``a`` comes after
    # its search); dji2: ``b``, which need not wait for the search but is the plan's for dji2.
    assert seen.units[0].free == pytest.approx(float(schedule.end[m0]))
    assert seen.units[0].here == pytest.approx(tuple(tables.end_for(0, m0)))
    assert 1 not in seen.units
    busy = seen.units[2]
    assert busy.free == pytest.approx(float(schedule.end[b]))
    assert busy.used == pytest.approx(float(schedule.travel_time[b] + schedule.work_time[b]))
    assert busy.here == pytest.approx(tuple(tables.end_for(2, b)))


def search_spread(plan) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """(the search's end over its bound, the spread of its parts' ends over its duration)."""
    search = plan.shared[0]
    ends = [p.end for p in search.parts]
    began = min(p.start for p in search.parts)
    return search.end / search.bound, (max(ends) - min(ends)) / (search.end - began)


def test_sized_from_the_unshared_plan_alone_one_part_starts_late(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # (What the next test repairs: the parts are never sized again.) Since each sweep starts at
    # its end nearest the unit, coast1-2km2/1 no longer shows it (1.09 x the bound either way);
    # coast3-0.2km2/0 does (1.15 x, its parts' ends spread over half the search).
    monkeypatch.setattr(planner_module, "RESEAT_GAIN", float("inf"))
    tree, units = mixed_case("coast3-0.2km2", 0)
    plan = plan_mission(tree, units, strategy="auction")
    ratio, spread = search_spread(plan)
    assert ratio > 1.12 and spread > 0.4


@pytest.mark.parametrize(("name", "seed"), [("coast1-2km2", 1), ("coast3-0.2km2", 0)])
def test_the_parts_are_sized_for_what_the_plan_flying_them_has_each_unit_do_first(
        name: str, seed: int) -> None:
    tree, units = mixed_case(name, seed)
    plan = plan_mission(tree, units, strategy="auction")
    assert plan.feasible and check_invariants(plan, tree, units) == []
    assert len(plan.shared) == 1 and len(plan.shared[0].parts) >= 3
    ratio, spread = search_spread(plan)
    assert ratio <= 1.1  # (issue 21's target for a search among other tasks: 1.4)
    assert spread <= 0.2  # the parts end together (give or take their real sweeps)
