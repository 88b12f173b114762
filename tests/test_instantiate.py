"""The fully instantiated tree (docs/protocol.md §8): units filled in, uuids and unknown fields
kept, catalogue defaults filled, conc children on one unit wrapped in a seq in planned order."""

from __future__ import annotations

import random
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from allocation_helpers import geo, move_to, prepared_for, problem_for, random_instance, unit
from delegation.allocation import check_invariants, make_plan, plan_mission
from delegation.allocation.instantiate import Placement, instantiate
from delegation.allocation.schedule import evaluate
from delegation.scenario import load_scenario
from delegation.tst import leaves, map_tree, parse_tree, walk


def counter() -> Any:
    n = iter(range(1000))
    return lambda: f"new-{next(n)}"


def test_units_uuids_unknown_fields_and_defaults() -> None:
    units = [unit("dji0", 0, 0), unit("dji1", 1000, 0)]
    raw = {
        "name": "seq",
        "meta": {"author": "op"},
        "common_params": {"node-uuid": "root-1"},
        "children": [
            {"name": "move-to", "common_params": {"execunit": "*", "node-uuid": "a-1"},
             "params": {"waypoint": geo(10, 0), "extra-param": 42}, "meta": "keep me"},
            {"name": "move-to", "common_params": {"execunit": "/dji0"},
             "params": {"waypoint": geo(990, 0)}},
        ],
    }
    tree = parse_tree(raw)
    plan = plan_mission(tree, units, strategy="auction", new_uuid=counter())
    out = plan.to_json()["tst"]
    assert out["meta"] == {"author": "op"}
    assert out["common_params"] == {"node-uuid": "root-1", "execunit": "/op0"}
    first, second = out["children"]
    assert first["common_params"] == {"execunit": "/dji0", "node-uuid": "a-1"}
    assert first["meta"] == "keep me"
    assert first["params"]["extra-param"] == 42
    assert first["params"]["speed"] == "standard"  # the catalogue default, filled in
    assert second["common_params"]["execunit"] == "/dji0"  # fixed: kept
    assert second["common_params"]["node-uuid"] == "new-0"  # missing: made
    assert list(first) == ["name", "common_params", "params", "meta"]  # the caller's key order
    assert check_invariants(plan, tree, units) == []


def test_fixed_control_nodes_keep_their_unit_and_engine_unit_is_configurable() -> None:
    units = [unit("dji0", 0, 0)]
    tree = parse_tree({"name": "conc", "common_params": {"execunit": "/other-engine"},
                       "children": [{"name": "seq", "children": [move_to(5, 5)]}]})
    plan = plan_mission(tree, units, engine_unit="op7")
    out = plan.tst.to_dict()
    assert out["common_params"]["execunit"] == "/other-engine"
    assert out["children"][0]["common_params"]["execunit"] == "/op7"


def test_conc_children_on_one_unit_are_wrapped_in_a_seq_in_planned_order() -> None:
    # One unit, three move-tos under a conc: the plan visits the nearest first.
    units = [unit("dji0", 0, 0)]
    tree = parse_tree({"name": "conc", "common_params": {"node-uuid": "c"}, "children": [
        {**move_to(300, 0), "common_params": {"node-uuid": "far"}},
        {**move_to(100, 0), "common_params": {"node-uuid": "near"}},
        {**move_to(200, 0), "common_params": {"node-uuid": "mid"}},
    ]})
    plan = plan_mission(tree, units, strategy="auction", new_uuid=counter())
    root = plan.tst
    assert root.name == "conc" and len(root.children) == 1
    wrapper = root.children[0]
    assert wrapper.name == "seq"
    assert wrapper.common_params == {"execunit": "/op0", "node-uuid": "new-0"}
    assert [c.node_uuid for c in wrapper.children] == ["near", "mid", "far"]
    assert check_invariants(plan, tree, units) == []


def test_wrapping_keeps_other_children_in_place() -> None:
    tree = parse_tree({"name": "conc", "children": [
        {**move_to(0, 0), "common_params": {"node-uuid": "x1"}},
        {**move_to(0, 0), "common_params": {"node-uuid": "y"}},
        {**move_to(0, 0), "common_params": {"node-uuid": "x2"}},
        {"name": "look-at-position", "common_params": {"node-uuid": "look"},
         "params": {"geopoint": geo(0, 0)}},
    ]})
    placements = {
        "x1": Placement("a", 1, True),
        "y": Placement("b", 0, True),
        "x2": Placement("a", 0, True),
        "look": Placement("a", 0, False),  # not a vehicle task: may run alongside
    }
    out = instantiate(tree, placements, "op0", counter())
    kids = out.children
    assert [k.name for k in kids] == ["seq", "move-to", "look-at-position"]
    assert [c.node_uuid for c in kids[0].children] == ["x2", "x1"]
    assert kids[1].node_uuid == "y"
    assert kids[2].execunit == "/a"


def test_subtrees_sharing_a_unit_are_serialised() -> None:
    # conc(seq(a1, b1), a2): a1 and a2 both on unit a -> the two children go into one seq.
    tree = parse_tree({"name": "conc", "children": [
        {"name": "seq", "common_params": {"node-uuid": "s"}, "children": [
            {**move_to(0, 0), "common_params": {"node-uuid": "a1"}},
            {**move_to(0, 0), "common_params": {"node-uuid": "b1"}}]},
        {**move_to(0, 0), "common_params": {"node-uuid": "a2"}},
    ]})
    placements = {"a1": Placement("a", 0, True), "b1": Placement("b", 0, True),
                  "a2": Placement("a", 1, True)}
    out = instantiate(tree, placements, "op0", counter())
    assert [c.node_uuid for c in out.children[0].children] == ["s", "a2"]


def test_unassigned_leaves_keep_their_execunit() -> None:
    units = [unit("dji0", 0, 0, tasks=("move-to",))]
    tree = parse_tree({"name": "seq", "children": [
        move_to(10, 0),
        {"name": "look-at-position", "common_params": {"execunit": "A"},
         "params": {"geopoint": geo(0, 0)}}]})
    plan = plan_mission(tree, units)
    assert not plan.feasible
    look = next(n for n in leaves(plan.tst) if n.name == "look-at-position")
    assert look.execunit == "A"
    assert all(n.node_uuid for _, n in walk(plan.tst))


DEMO = Path(__file__).resolve().parents[1] / "scenarios" / "demo.yaml"


def _demo_plan(strategy: str, without: str = "") -> tuple[Any, Any, Any]:
    scenario = load_scenario(DEMO)
    tree, units = scenario.tree(), [u for u in scenario.units() if u.name != without]
    return plan_mission(tree, units, strategy=strategy, time_limit=1.0), tree, units


def test_plan_times_are_those_of_the_instantiated_tree() -> None:
    # The demo without dji1, with nearest: dji0 takes the move-to of seq(move-to, search-area),
    # another move-to and the move-path; usv0 the search-area and a move-to. The old rule ran the
    # whole seq (usv0's search included) before the move-path; the series-parallel tree runs the
    # move-path right after dji0's move-tos, beside usv0's search, and the plan's times are that
    # tree's. (With dji1, the search's shorter sweep (lanes along the short side) gives it to dji1.)
    plan, tree, units = _demo_plan("nearest", without="dji1")
    by_name = {a.name: a for a in plan.assignments}
    search, path = by_name["search-area"], by_name["move-path"]
    assert path.execunit == "/dji0" and search.execunit == "/usv0"
    before = max((a for a in plan.assignments if a.execunit == "/dji0" and a.end <= path.start),
                 key=lambda a: a.end)
    assert before.name == "move-to"
    assert path.start == pytest.approx(before.end)
    assert path.start < search.end
    assert plan.precedence_makespan == pytest.approx(plan.makespan)
    assert any("series-parallel tree" in note for note in plan.notes)
    assert check_invariants(plan, tree, units) == []


def test_invariants_run_the_tree_and_catch_times_it_does_not_have() -> None:
    plan, tree, units = _demo_plan("nearest")
    # The bug this guards: the move-path timed as if it did not wait for dji0's move-to before
    # it in the tree, the plan otherwise consistent.
    moved = next(a for a in plan.assignments if a.name == "move-path")
    first = next(a for a in plan.assignments if a.name == "move-to" and a.execunit == "/dji0")
    begin = first.start
    early = replace(moved, start=begin, end=begin + moved.travel_time + moved.work_time)
    plan.assignments[plan.assignments.index(moved)] = early
    problems = check_invariants(plan, tree, units)
    assert any("the instantiated tree runs it at" in p and moved.node_uuid in p
               for p in problems)


def test_invariants_catch_a_tree_that_contradicts_the_routes() -> None:
    plan, tree, units = _demo_plan("nearest")
    assert plan.source is not None
    given = {node.node_uuid for _, node in walk(plan.source)}
    wrapper = next(node for _, node in walk(plan.tst) if node.node_uuid not in given)
    assert wrapper.name == "seq" and len(wrapper.children) >= 2
    # The wrapped subtrees in the opposite order: dji0's route cannot run in that tree.
    plan.tst = map_tree(plan.tst, lambda node, kids: node.with_children(
        kids[::-1] if node.node_uuid == wrapper.node_uuid else kids))
    problems = check_invariants(plan, tree, units)
    assert any("the sent tree does not run" in p for p in problems)  # a lost precedence


def test_every_runnable_allocation_runs_as_planned() -> None:
    # Random assignments and orders (not a strategy's): whenever the evaluator accepts one, the
    # instantiated tree runs it at exactly the evaluated times.
    checked = 0
    for seed, shape in [(0, "subtrees"), (1, "nested"), (2, "seq-of-concs"), (3, "conc-of-seqs")]:
        tree, units = random_instance(seed, shape, n_tasks=6, n_units=3)
        problem = problem_for(tree, units)
        rng = random.Random(seed)
        for _ in range(60):
            assign = np.array([rng.choice(np.nonzero(problem.allowed[:, t])[0].tolist())
                               for t in range(problem.n_tasks)])
            orders: list[list[int]] = [[] for _ in range(problem.n_units)]
            for t in rng.sample(range(problem.n_tasks), problem.n_tasks):
                orders[int(assign[t])].append(t)
            schedule = evaluate(problem, assign, orders)
            if not schedule.valid:
                continue
            plan = make_plan(problem, schedule, prepared_for(tree), strategy="auction",
                             objective="makespan", solve_time=0.0)
            assert check_invariants(plan, tree, units) == []
            checked += 1
    assert checked >= 40, checked
