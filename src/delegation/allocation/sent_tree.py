"""Which tree the plan sends, and its times (docs/protocol.md §8; truthful plans).

The strategies plan on the precedence graph (``schedule.evaluate``). Two trees can carry it: the
series-parallel tree (``series_parallel``) and the old rule's (``instantiate``: conc children that
share a unit wrapped whole in a seq), which some allocations cannot use. Each candidate that
contains every precedence of the plan is simulated on its own structure, and the one with the
smaller makespan is sent (the old rule on a tie: it keeps more of the caller's tree); the plan's
times are that simulation's.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from delegation.allocation.instantiate import Placement, instantiate
from delegation.allocation.problem import Problem, Structure, flatten_tree, precedence
from delegation.allocation.schedule import IssueKind, Schedule, evaluate, restructured
from delegation.allocation.series_parallel import build_tree, schedule_decomposition
from delegation.tst import TstNode, leaves

#: The names of the two instantiation rules, as the plan's notes give them.
SERIES_PARALLEL = "series-parallel"
WRAP = "wrap"


@dataclass
class SentTree:
    """The tree to send, its simulated schedule, the rule that built it, and a note."""

    tree: TstNode
    schedule: Schedule
    rule: str
    note: str


def _remapped(tree: TstNode, index: Mapping[str, int]) -> Structure:
    """The structure of ``tree`` with its leaves numbered as ``index`` (uuid -> task) says."""
    structure, tree_leaves = flatten_tree(tree)
    tasks = [index[node.node_uuid or ""] for _, node in tree_leaves]
    task_of_node = tuple(-1 if k < 0 else tasks[k] for k in structure.task_of_node)
    node_of_task = [0] * len(index)
    for n, t in enumerate(task_of_node):
        if t >= 0:
            node_of_task[t] = n
    return dataclasses.replace(structure, task_of_node=task_of_node,
                               node_of_task=tuple(node_of_task))


def simulate_tree(
    problem: Problem, tree: TstNode, assign: np.ndarray, orders: Sequence[Sequence[int]]
) -> Schedule:
    """The schedule of running ``tree`` (the same leaves as ``problem``'s, any control nodes)
    with this allocation."""
    index = {task.uuid: t for t, task in enumerate(problem.tasks)}
    return _simulate(problem, _remapped(tree, index), assign, orders)


def _simulate(
    problem: Problem, structure: Structure, assign: np.ndarray, orders: Sequence[Sequence[int]]
) -> Schedule:
    return evaluate(restructured(problem, structure), assign, orders)


def missing_precedences(
    source: TstNode, sent: TstNode, routes: Mapping[str, Sequence[str]]
) -> list[str]:
    """Precedences of the plan (``source``'s seq order, each unit's ``routes`` of leaf uuids)
    that the ``sent`` tree's order does not contain."""
    uuids = [leaf.node_uuid or "" for leaf in leaves(source)]
    index = {u: i for i, u in enumerate(uuids)}
    if sorted(uuids) != sorted(leaf.node_uuid or "" for leaf in leaves(sent)):
        return ["the sent tree does not have the caller's tasks"]
    need = precedence(_remapped(source, index), len(uuids))
    for route in routes.values():
        for a, b in itertools.pairwise(route):
            need[index[a], index[b]] = True
    return _missing(need, _remapped(sent, index), uuids)


def _missing(need: np.ndarray, sent: Structure, uuids: Sequence[str]) -> list[str]:
    """The precedences ``need[a, b]`` that the order of the tree with structure ``sent`` lacks."""
    missing = np.argwhere(need & ~precedence(sent, len(uuids)))
    return [f"the sent tree does not run {uuids[a]} before {uuids[b]}" for a, b in missing[:5]]


def _same_leaves(tree: TstNode, index: Mapping[str, int]) -> bool:
    """Whether ``tree``'s leaves are exactly the tasks ``index`` numbers."""
    got = [leaf.node_uuid or "" for leaf in leaves(tree)]
    return len(got) == len(index) and set(got) == set(index)


def choose_tree(
    problem: Problem,
    schedule: Schedule,
    prepared: TstNode,
    placements: Mapping[str, Placement],
    engine_unit: str = "op0",
    new_uuid: Callable[[], str] | None = None,
) -> SentTree:
    """The tree to send for ``schedule`` (planned on the precedence graph) and its times.

    ``prepared`` is the tree ``problem`` was built from (its leaves are the problem's tasks, in
    order): the plan's precedences are ``problem.before`` and the units' orders.
    """
    old = instantiate(prepared, placements, engine_unit, new_uuid)
    if any(i.kind in (IssueKind.ORDER, IssueKind.DEADLOCK) for i in schedule.issues):
        return SentTree(old, schedule, WRAP, "instantiation: the old wrap rule (the schedule "
                        "cannot run: " + "; ".join(map(str, schedule.issues[:2])) + ")")
    uuids = [t.uuid for t in problem.tasks]
    index = {u: t for t, u in enumerate(uuids)}
    need = problem.before.copy()
    for route in schedule.orders:
        for a, b in itertools.pairwise(route):
            need[a, b] = True
    filled = {leaf.node_uuid or "": leaf for leaf in leaves(old)}
    _, order = schedule_decomposition(problem, schedule)
    sp = build_tree(order, prepared, filled, uuids, engine_unit, new_uuid)
    sp_structure = _remapped(sp, index)  # (build_tree keeps the leaves: KeyError otherwise)
    missing = _missing(need, sp_structure, uuids)
    if missing:
        raise RuntimeError("series-parallel instantiation lost precedences: "
                           + "; ".join(missing))
    best = SentTree(sp, _simulate(problem, sp_structure, schedule.assign, schedule.orders),
                    SERIES_PARALLEL, "")
    old_note = "the old wrap rule cannot carry this allocation"
    old_structure = _remapped(old, index) if _same_leaves(old, index) else None
    if old_structure is not None and not _missing(need, old_structure, uuids):
        wrap = SentTree(old, _simulate(problem, old_structure, schedule.assign, schedule.orders),
                        WRAP, "")
        old_note = f"the old wrap rule's tree: {wrap.schedule.makespan:.1f} s"
        if wrap.schedule.makespan <= best.schedule.makespan * (1 + 1e-9):
            sp_note = f"the series-parallel tree: {best.schedule.makespan:.1f} s"
            best = wrap
            old_note = sp_note
    best.note = (f"instantiation: the {best.rule} tree, makespan "
                 f"{best.schedule.makespan:.1f} s ({old_note}; the precedence graph: "
                 f"{schedule.makespan:.1f} s)")
    return best
