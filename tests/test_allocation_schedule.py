"""The schedule simulator against hand-computed numbers (hand-made cost tables, no cost model).

Everything else (strategies, the brute force in the exactness tests) relies on this evaluator, so
these cases pin its timing semantics (docs/plan.md §3) with numbers worked out by hand.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest

from delegation.allocation.problem import Problem, flatten_tree, problem_from_arrays
from delegation.allocation.schedule import IssueKind, evaluate
from delegation.tst import parse_tree


@dataclass
class Tables:
    """A hand-made stand-in for ``delegation.costs.CostTables``."""

    unit_xy: np.ndarray
    start_xy: np.ndarray
    home_xy: np.ndarray | None = None
    end_xy: np.ndarray | None = None
    speed: np.ndarray | None = None
    work_time: np.ndarray | None = None
    work_distance: np.ndarray | None = None
    travels: np.ndarray | None = None
    capable: np.ndarray | None = None
    endurance: np.ndarray | None = None
    why: dict[tuple[int, int], str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n_u, n_t = len(self.unit_xy), len(self.start_xy)
        self.unit_xy = np.asarray(self.unit_xy, dtype=float)
        self.start_xy = np.asarray(self.start_xy, dtype=float)
        if self.home_xy is None:
            self.home_xy = np.full((n_u, 2), np.nan)
        if self.end_xy is None:
            self.end_xy = self.start_xy.copy()
        if self.speed is None:
            self.speed = np.full((n_u, n_t), 10.0)
        if self.work_time is None:
            self.work_time = np.zeros((n_u, n_t))
        if self.work_distance is None:
            self.work_distance = np.zeros((n_u, n_t))
        if self.travels is None:
            self.travels = np.ones(n_t, dtype=bool)
        if self.capable is None:
            self.capable = np.ones((n_u, n_t), dtype=bool)
        if self.endurance is None:
            self.endurance = np.full(n_u, np.inf)

    def reason(self, u: int, t: int) -> str | None:
        return self.why.get((u, t), "cannot")


def task(name: str = "move-to") -> dict[str, object]:
    return {"name": name, "params": {}}


def make(tree: dict[str, object], tables: Tables, n_units: int | None = None) -> Problem:
    structure, leaves = flatten_tree(parse_tree(tree))
    n = len(tables.unit_xy) if n_units is None else n_units
    return problem_from_arrays(
        structure, leaves, [f"u{i}" for i in range(n)], tables=tables,
        home_speed=np.full(n, 10.0),
    )


def test_one_unit_two_tasks_in_a_conc() -> None:
    # u0 at the origin, 10 m/s; tasks at (100, 0) and (100, 100).
    p = make({"name": "conc", "children": [task(), task()]},
             Tables(unit_xy=[[0, 0]], start_xy=[[100, 0], [100, 100]]))
    s = evaluate(p, [0, 0], [[0, 1]])
    assert s.valid
    assert s.start.tolist() == [0.0, 10.0]  # the second waits for the unit
    assert s.end.tolist() == [10.0, 20.0]
    assert s.travel_time.tolist() == [10.0, 10.0]
    assert s.distance.tolist() == [100.0, 100.0]
    assert s.makespan == 20.0 and s.total_time == 20.0 and s.total_distance == 200.0


def test_the_way_home_counts() -> None:
    p = make({"name": "conc", "children": [task(), task()]},
             Tables(unit_xy=[[0, 0]], start_xy=[[100, 0], [100, 100]], home_xy=[[0, 0]]))
    s = evaluate(p, [0, 0], [[0, 1]])
    back = math.hypot(100, 100) / 10.0
    assert s.makespan == pytest.approx(20.0 + back)
    assert s.total_time == pytest.approx(20.0 + back)
    assert s.total_distance == pytest.approx(200.0 + math.hypot(100, 100))
    assert s.unit_used[0] == pytest.approx(20.0 + back)


def test_seq_across_units_waits_for_the_predecessor() -> None:
    # seq(a, b): a on u0 (10 s away), b on u1 (50 m away at 10 m/s): b travels from t=10.
    p = make({"name": "seq", "children": [task(), task()]},
             Tables(unit_xy=[[0, 0], [0, 50]], start_xy=[[100, 0], [0, 100]]))
    s = evaluate(p, [0, 1], [[0], [1]])
    assert s.start.tolist() == [0.0, 10.0]
    assert s.end.tolist() == [10.0, 15.0]
    assert s.makespan == 15.0 and s.total_time == 15.0


def test_conc_children_start_together_and_travel_from_where_the_unit_is() -> None:
    # conc(seq(a, b), c): a and c on u0, b on u1. u0 does c first (at 0), then a: a travels
    # from c's end at t=5; b waits for a.
    tree = {"name": "conc", "children": [{"name": "seq", "children": [task(), task()]}, task()]}
    p = make(tree, Tables(unit_xy=[[0, 0], [0, 0]], start_xy=[[50, 50], [0, 30], [50, 0]]))
    s = evaluate(p, [0, 1, 0], [[2, 0], [1]])
    assert s.start[2] == 0.0 and s.end[2] == 5.0
    assert s.start[0] == 5.0 and s.end[0] == 10.0  # (50,0) -> (50,50): 50 m
    assert s.start[1] == 10.0 and s.end[1] == 13.0  # u1 waits for a, then 30 m
    assert s.makespan == 13.0


def test_work_time_and_distance() -> None:
    p = make({"name": "conc", "children": [task("search-area")]},
             Tables(unit_xy=[[0, 0]], start_xy=[[30, 40]], end_xy=[[60, 80]],
                    work_time=[[7.0]], work_distance=[[70.0]]))
    s = evaluate(p, [0], [[0]])
    assert (s.travel_time[0], s.work_time[0], s.end[0]) == (5.0, 7.0, 12.0)
    assert s.distance[0] == 120.0  # 50 travel + 70 work


def test_in_place_and_non_vehicle_tasks() -> None:
    # take-off (in place, 20 s) then a move-to; a look-at (non-vehicle) runs alongside.
    tree = {"name": "conc", "children": [
        {"name": "seq", "children": [task("take-off"), task()]}, task("look-at-position")]}
    tables = Tables(unit_xy=[[0, 0]], start_xy=[[np.nan, np.nan], [0, 100], [np.nan, np.nan]],
                    travels=np.array([False, True, False]), work_time=[[20.0, 0.0, 0.0]])
    p = make(tree, tables)
    s = evaluate(p, [0, 0, 0], [[0, 1]])
    assert s.valid
    assert (s.start[0], s.end[0]) == (0.0, 20.0)
    assert (s.start[1], s.end[1]) == (20.0, 30.0)
    assert (s.start[2], s.end[2], s.travel_time[2]) == (0.0, 0.0, 0.0)
    assert s.makespan == 30.0


def test_deadlock_between_units_is_reported() -> None:
    # conc(seq(a1, a2), seq(b1, b2)); u0: a2 then b1, u1: b2 then a1 -> each waits for the other.
    tree = {"name": "conc", "children": [
        {"name": "seq", "children": [task(), task()]},
        {"name": "seq", "children": [task(), task()]}]}
    p = make(tree, Tables(unit_xy=[[0, 0], [0, 0]], start_xy=[[10, 0]] * 4))
    s = evaluate(p, [1, 0, 0, 1], [[1, 2], [3, 0]])
    assert not s.valid
    deadlocks = [i for i in s.issues if i.kind is IssueKind.DEADLOCK]
    assert len(deadlocks) == 1 and "deadlock" in str(deadlocks[0])


def test_battery_is_checked() -> None:
    p = make({"name": "conc", "children": [task(), task()]},
             Tables(unit_xy=[[0, 0]], start_xy=[[100, 0], [100, 100]], endurance=[15.0]))
    s = evaluate(p, [0, 0], [[0, 1]])
    assert not s.valid
    assert s.issues[0].kind is IssueKind.ENDURANCE
    assert "endurance" in s.issues[0].text
    assert evaluate(p, [0, -1], [[0]]).valid  # one task alone fits


def test_unassigned_tasks_take_no_time() -> None:
    p = make({"name": "seq", "children": [task(), task()]},
             Tables(unit_xy=[[0, 0]], start_xy=[[100, 0], [200, 0]]))
    s = evaluate(p, [-1, 0], [[1]])
    assert np.isnan(s.start[0])
    assert (s.start[1], s.end[1]) == (0.0, 20.0)
    assert s.n_unassigned == 1


def test_wrong_orders_are_reported() -> None:
    p = make({"name": "conc", "children": [task(), task()]},
             Tables(unit_xy=[[0, 0], [1, 1]], start_xy=[[100, 0], [200, 0]]))
    missing = evaluate(p, [0, 0], [[0]])  # task 1 assigned but in no order
    wrong = evaluate(p, [0, 1], [[0, 1], []])  # task 1 listed on the wrong unit
    for s in (missing, wrong):
        assert not s.valid
        assert {i.kind for i in s.issues} == {IssueKind.ORDER}


# --------------------------------------------------------------------------- whole subtrees
# The old instantiation rule (``wrapped=True``), kept as a fallback the planner compares with.


def test_conc_children_sharing_a_unit_run_one_after_another_as_whole_subtrees() -> None:
    # conc(seq(a, b), c): a and c on u0, b on u1 (all 10 m/s, units at the origin).
    # a at (100, 0), b at (0, 300), c at (0, 50). u0 does c first, then a: the instantiated
    # tree wraps [c, seq(a, b)] in a seq, so a (and b after it) start only once c has ended;
    # b does not run alongside c.
    tree = {"name": "conc", "children": [{"name": "seq", "children": [task(), task()]}, task()]}
    p = make(tree, Tables(unit_xy=[[0, 0], [0, 0]], start_xy=[[100, 0], [0, 300], [0, 50]]))
    s = evaluate(p, [0, 1, 0], [[2, 0], [1]], wrapped=True)
    assert s.valid
    assert (s.start[2], s.end[2]) == (0.0, 5.0)  # c: 50 m
    assert s.start[0] == 5.0 and s.end[0] == pytest.approx(5.0 + math.hypot(100, 50) / 10)
    assert s.start[1] == s.end[0] and s.end[1] == pytest.approx(s.end[0] + 30.0)  # b: 300 m
    assert s.serialised is not None and s.serialised.wraps == [(0, [4, 1])]  # c, then the seq
    # The other way round on u0 (a, then c): c waits for the whole seq, b included.
    s = evaluate(p, [0, 1, 0], [[0, 2], [1]], wrapped=True)
    assert s.valid
    assert (s.start[0], s.end[0]) == (0.0, 10.0)
    assert (s.start[1], s.end[1]) == (10.0, 40.0)
    assert s.start[2] == 40.0  # not 10.0: the seq (with b on u1) ends at 40
    assert s.end[2] == pytest.approx(40.0 + math.hypot(100, 50) / 10)
    # On the precedence graph (the default, what strategies plan for) c waits for a alone.
    s = evaluate(p, [0, 1, 0], [[0, 2], [1]])
    assert s.valid and s.start[2] == 10.0 and s.start[1] == 10.0


def test_the_wrap_order_comes_from_the_units_orders_first_in_tree_on_ties() -> None:
    # conc(A = seq(a1, a2), B = seq(b1, b2), C = c). u0: a1 then c (A before C); u1: b1 then
    # a2 (B before A); u2: b2. The wrap runs B, A, C: B waits for nothing, A for B, C for A.
    tree = {"name": "conc", "children": [
        {"name": "seq", "children": [task(), task()]},
        {"name": "seq", "children": [task(), task()]},
        task()]}
    p = make(tree, Tables(unit_xy=[[0, 0], [0, 0], [0, 0]],
                          start_xy=[[10, 0], [20, 0], [0, 10], [0, 20], [30, 0]]))
    s = evaluate(p, [0, 1, 1, 2, 0], [[0, 4], [2, 1], [3]], wrapped=True)
    assert s.valid
    a, b, c = 1, 4, 7  # tree nodes of the three children
    assert s.serialised is not None and s.serialised.wraps == [(0, [b, a, c])]
    # b2 is on u2, which shares nothing: it is in the component only through seq B.
    assert s.start[2] == 0.0 and s.start[3] == s.end[2]  # B: b1 then b2
    assert s.start[0] == pytest.approx(s.end[3])  # A starts when B (b2 included) has ended
    assert s.start[4] == pytest.approx(s.end[1])  # C after A


def test_children_free_to_go_together_run_in_tree_order() -> None:
    # conc(A = seq(a1, a2), B = b, C = seq(c1, c2)). u0: a1 then c1 (A before C); u1: b then c2
    # (B before C). A and B are both free to go first: the one first in the tree (A) goes
    # first, then B (although it shares no unit with A), then C. Not by time: b is shorter.
    tree = {"name": "conc", "children": [
        {"name": "seq", "children": [task(), task()]},
        task(),
        {"name": "seq", "children": [task(), task()]}]}
    p = make(tree, Tables(unit_xy=[[0, 0], [0, 0], [0, 0]],
                          start_xy=[[100, 0], [200, 0], [0, 10], [0, 20], [0, 30]]))
    s = evaluate(p, [0, 2, 1, 0, 1], [[0, 3], [2, 4], [1]], wrapped=True)
    assert s.valid
    assert s.serialised is not None and s.serialised.wraps == [(0, [1, 4, 5])]
    assert (s.start[0], s.end[0], s.end[1]) == (0.0, 10.0, 30.0)  # a1; a2 (u2, 200 m)
    assert s.start[2] == 30.0 and s.end[2] == 31.0  # b after the whole of A
    assert s.start[3] == 31.0 and s.end[3] == pytest.approx(31.0 + math.hypot(100, 20) / 10)
    assert s.start[4] == pytest.approx(s.end[3]) and s.end[4] == pytest.approx(s.end[3] + 2.0)


def test_allocations_that_cannot_run_as_whole_subtrees_are_invalid() -> None:
    tree = {"name": "conc", "children": [
        {"name": "seq", "children": [task(), task()]},
        {"name": "seq", "children": [task(), task()]}]}
    p = make(tree, Tables(unit_xy=[[0, 0], [0, 0]], start_xy=[[10, 0]] * 4))
    # u0: a1 then b1 (A before B); u1: b2 then a2 (B before A): the units disagree.
    s = evaluate(p, [0, 1, 0, 1], [[0, 2], [3, 1]], wrapped=True)
    assert not s.valid
    assert any(i.kind is IssueKind.SERIALISATION and "disagree" in i.text for i in s.issues)
    # The precedence graph has no cycle there: it can run (a series-parallel tree carries it).
    assert evaluate(p, [0, 1, 0, 1], [[0, 2], [3, 1]]).valid
    # u0: a1, b1, a2: it would leave A and come back to it.
    s = evaluate(p, [0, 0, 0, 1], [[0, 2, 1], [3]], wrapped=True)
    assert not s.valid
    assert any(i.kind is IssueKind.SERIALISATION and "come back" in i.text for i in s.issues)
