"""The fully instantiated tree (DESIGN 3.4), built as a new tree from the plan.

Every leaf gets its unit, control nodes the engine's unit unless fixed; uuids, unknown fields and
the caller's key order are kept. A unit runs one vehicle task at a time, so where the plan gives one
unit several children of a ``conc``, those children are wrapped in a new ``seq`` in planned order.
"""

from __future__ import annotations

import uuid as uuid_module
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from delegation.tst import ExecUnitKind, TstNode, classify_execunit, leaves, make_node, map_tree


@dataclass(frozen=True, slots=True)
class Placement:
    """Where the plan put one task."""

    unit: str
    start: float
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

    def units_of(node: TstNode) -> tuple[set[str], float]:
        found: set[str] = set()
        first = float("inf")
        for leaf in leaves(node):
            p = placements.get(leaf.node_uuid or "")
            if p is not None and p.vehicle:
                found.add(p.unit)
                first = min(first, p.start)
        return found, first

    def fill(node: TstNode, children: tuple[TstNode, ...]) -> TstNode:
        node = node.with_children(children)
        if not node.is_control:
            p = placements.get(node.node_uuid or "")
            return node.with_common_values({"execunit": "/" + p.unit}) if p else node
        try:
            kind, _ = classify_execunit(node.execunit)
        except TypeError:
            kind = ExecUnitKind.FREE
        if kind is not ExecUnitKind.FIXED:
            node = node.with_common_values({"execunit": engine})
        if node.name == "conc" and len(children) > 1:
            node = node.with_children(_serialise_shared(list(children), units_of, engine, make))
        return node

    return map_tree(tree, fill)


def _serialise_shared(
    children: list[TstNode],
    units_of: Callable[[TstNode], tuple[set[str], float]],
    engine: str,
    make: Callable[[], str],
) -> list[TstNode]:
    """Wrap the children of a conc that share a unit in a seq, ordered by planned start."""
    info = [units_of(c) for c in children]
    parent = list(range(len(children)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    owner: dict[str, int] = {}
    for i, (units, _) in enumerate(info):
        for unit in sorted(units):
            if unit in owner:
                parent[find(i)] = find(owner[unit])
            else:
                owner[unit] = i
    groups: dict[int, list[int]] = {}
    for i in range(len(children)):
        groups.setdefault(find(i), []).append(i)
    out: list[TstNode] = []
    for i in range(len(children)):
        members = groups[find(i)]
        if len(members) == 1:
            out.append(children[i])
        elif i == members[0]:
            ordered = sorted(members, key=lambda k: (info[k][1], k))
            out.append(
                make_node("seq", [children[k] for k in ordered], execunit=engine, node_uuid=make())
            )
    return out
