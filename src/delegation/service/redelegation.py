"""Re-delegation (docs/protocol.md §11): what a running mission still has to do when one of its
units is lost or fails a task, as a tree to plan again. Pure: trees and statuses in, trees and
rows out.

Semantics (docs/protocol.md §11): the remaining tree keeps the original structure (``seq``
order, ``conc`` grouping) with every task that has not succeeded; a task that succeeded is never
run again, a control node left without tasks is dropped. Tasks of the lost (or failing) unit
become free (``execunit`` ``""``) and are planned again with the live units from where they are;
every other task stays on its unit (so the plan puts the freed ones after them). The plan is then
applied by `delegation.service.repair`: for a lost unit, each freed task moves to its planned
unit within the running tree (``rebind-tst-nodes``: healthy units' tasks are not touched); for a
failed task (whose branch the engine already stopped), or an engine that cannot move tasks, the
old tree is aborted and the remaining one started in its place.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from delegation.tst.node import ExecUnitKind, TstNode, classify_execunit, walk, where

#: Node statuses after which a task is done for good (not run again).
DONE = frozenset({"succeeded"})


@dataclass(frozen=True, slots=True)
class Remaining:
    """The part of a mission still to do: a partial tree and where each of its tasks came from."""

    tree: TstNode
    #: New node uuid -> the node uuid it replaces (tasks and control nodes).
    origin: dict[str, str]
    #: New uuids of the tasks freed for planning (they were on a lost or failing unit).
    freed: frozenset[str]


def unit_of(node: TstNode) -> str:
    """The unit name of an instantiated task (``/u0`` -> ``u0``), or ``""``."""
    try:
        kind, name = classify_execunit(node.execunit)
    except TypeError:
        return ""
    return name if kind is ExecUnitKind.FIXED else ""


def unfinished_on(tree: TstNode, node_status: Mapping[str, str], unit: str) -> list[str]:
    """Uuids of the tasks of ``tree`` on ``unit`` that have not succeeded, in tree order."""
    return [
        node.node_uuid
        for _, node in walk(tree)
        if not node.is_control and node.node_uuid and unit_of(node) == unit
        and node_status.get(node.node_uuid) not in DONE
    ]


def remaining_tree(
    tree: TstNode,
    node_status: Mapping[str, str],
    free_units: Iterable[str],
    new_uuid: Callable[[], str],
    only: Collection[str] | None = None,
) -> Remaining | None:
    """The tasks of ``tree`` that have not succeeded, in its structure, with new node uuids; the
    tasks of ``free_units`` without a unit. With ``only``, just the tasks it names are freed and
    the free units' other tasks are left out (a failed task moved alone, docs/protocol.md §12.7:
    they stay on their unit in the running tree, and the plan only says where the freed go).
    None when nothing is left to do."""
    free = set(free_units)
    origin: dict[str, str] = {}
    freed: set[str] = set()

    def freeing(node: TstNode) -> bool:
        return unit_of(node) in free and (only is None or (node.node_uuid or "") in only)

    def copy(node: TstNode) -> TstNode | None:
        old = node.node_uuid or ""
        if node.is_control:
            children = [c for c in (copy(child) for child in node.children) if c is not None]
            if not children:
                return None
            new = node.with_children(children)
        else:
            if node_status.get(old) in DONE:
                return None
            if only is not None and unit_of(node) in free and old not in only:
                return None
            new = node
            if freeing(node):
                new = node.with_common_values({"execunit": ""})
        uid = new_uuid()
        origin[uid] = old
        if not node.is_control and freeing(node):
            freed.add(uid)
        return new.with_common_values({"node-uuid": uid})

    root = copy(tree)
    if root is None:
        return None
    return Remaining(root, origin, frozenset(freed))


def moved_tasks(instantiated: TstNode, remaining: Remaining) -> list[dict[str, Any]]:
    """The ``tasks`` of a ``re-delegated`` feedback: every freed task and its new unit."""
    rows: list[dict[str, Any]] = []
    for path, node in walk(instantiated):
        uid = node.node_uuid or ""
        if uid in remaining.freed:
            rows.append({"node-uuid": uid, "replaces": remaining.origin.get(uid, ""),
                         "name": node.name, "path": where(path, node),
                         "unit": f"/{unit_of(node)}" if unit_of(node) else ""})
    return rows


def first_origin(origin: Mapping[str, str], uid: str) -> str:
    """The uuid of the node of the first tree that ``uid`` (after any number of re-delegations)
    stands for: the retry budget counts per original task."""
    seen: set[str] = set()
    while uid in origin and uid not in seen:
        seen.add(uid)
        uid = origin[uid]
    return uid


def current_node(origin: Mapping[str, str], current: Iterable[str], uid: str) -> str | None:
    """The node of the current tree that stands for ``uid`` (a node of any earlier tree, e.g. the
    operator's): ``uid`` itself while its tree runs, else the node whose origin chain leads to
    it; None when no node of the current tree does (it ended before, or was regrouped away)."""
    nodes = set(current)
    if uid in nodes:
        return uid
    for node in sorted(nodes):
        seen: set[str] = set()
        step = node
        while step in origin and step not in seen:
            seen.add(step)
            step = origin[step]
            if step == uid:
                return node
    return None


def statuses_by_first(node_status: Mapping[str, str], origin: Mapping[str, str],
                      current: Iterable[str]) -> dict[str, str]:
    """Node statuses under the uuids of the first tree (the operator's): what the first tree's
    nodes said, then what the nodes standing for them in later trees say (a task that succeeded
    in any tree; every node of the current tree, which replaces what its predecessors said)."""
    out = dict(node_status)
    for uid, status in node_status.items():
        if uid in origin and status in DONE:
            out[first_origin(origin, uid)] = status
    for uid in current:
        if uid in origin:
            out[first_origin(origin, uid)] = node_status.get(uid, "not-active")
    return out
