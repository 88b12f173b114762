"""The fully instantiated tree (docs/protocol.md §8), built as a new tree from the plan.

Every leaf gets its unit, control nodes the engine's unit unless fixed; uuids, unknown fields and
the caller's key order are kept. A unit runs one vehicle task at a time, so where the plan gives one
unit several children of a ``conc``, those children (with every child sharing a unit with them) are
wrapped in a new ``seq``, in the order ``serialise.order_children`` derives from the units' orders:
the order the schedule evaluator simulated, so the plan's times are the tree's.
"""

from __future__ import annotations

import uuid as uuid_module
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from delegation.allocation.serialise import order_children
from delegation.tst import ExecUnitKind, TstNode, classify_execunit, leaves, make_node, map_tree


@dataclass(frozen=True, slots=True)
class Placement:
    """Where the plan put one task: its unit, and its position in that unit's order."""

    unit: str
    rank: int  # 0 for the unit's first vehicle task; unused for other tasks
    vehicle: bool


def instantiate(
    tree: TstNode,
    placements: Mapping[str, Placement],
    engine_unit: str = "op0",
    new_uuid: Callable[[], str] | None = None,
) -> TstNode:
    """The instantiated tree. ``tree`` has uuids on every node; ``placements`` maps leaf uuids.

    Leaves without a placement (unassigned) keep their ``execunit`` as given.
    """
    make = new_uuid or (lambda: str(uuid_module.uuid4()))
    engine = "/" + engine_unit.strip("/")

    def visits(node: TstNode) -> list[tuple[str, int]]:
        """(unit, rank) of the vehicle tasks under ``node``."""
        found = []
        for leaf in leaves(node):
            p = placements.get(leaf.node_uuid or "")
            if p is not None and p.vehicle:
                found.append((p.unit, p.rank))
        return found

    def fill(node: TstNode, children: tuple[TstNode, ...]) -> TstNode:
        if not node.is_control:
            if node.children:  # (a task with children is invalid; kept as given)
                node = node.with_children(children)
            p = placements.get(node.node_uuid or "")
            return node.with_common_values({"execunit": "/" + p.unit}) if p else node
        node = node.with_children(children)
        try:
            kind, _ = classify_execunit(node.execunit)
        except TypeError:
            kind = ExecUnitKind.FREE
        if kind is not ExecUnitKind.FIXED:
            node = node.with_common_values({"execunit": engine})
        if node.name == "conc" and len(children) > 1:
            node = node.with_children(_serialise_shared(list(children), visits, engine, make))
        return node

    return map_tree(tree, fill)


def _serialise_shared(
    children: list[TstNode],
    visits: Callable[[TstNode], list[tuple[str, int]]],
    engine: str,
    make: Callable[[], str],
) -> list[TstNode]:
    """Wrap the children of a conc that share a unit in a seq, in the units' order."""
    per_unit: dict[str, list[tuple[int, int]]] = {}
    for i, child in enumerate(children):
        for unit, rank in visits(child):
            per_unit.setdefault(unit, []).append((rank, i))
    runs = [(unit, [i for _, i in sorted(items)]) for unit, items in sorted(per_unit.items())]
    groups, _ = order_children(runs)
    first = {min(group): group for group in groups}  # the wrapper takes its first child's place
    inside = {i for group in groups for i in group}
    out: list[TstNode] = []
    for i, child in enumerate(children):
        if i in first:
            group = first[i]
            out.append(
                make_node("seq", [children[k] for k in group], execunit=engine, node_uuid=make())
            )
        elif i not in inside:
            out.append(child)
    return out
