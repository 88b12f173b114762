"""The TST node model: parse from JSON, serialise back exactly, walk, complete uuids.

A node keeps the caller's top-level keys in their order, the spelling of ``common_params`` they
used, and every field we do not understand (``meta``, extra params), so that a parsed tree
serialises back to the same JSON. Trees are values: transformations build new trees.
"""

from __future__ import annotations

import uuid as uuid_module
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Any, TypeVar

from delegation.errors import InputError, InputProblem, json_kind

#: Control nodes: they order their children and run on the engine.
CONTROL_NODES: frozenset[str] = frozenset({"seq", "conc"})

#: The canonical spelling of the common parameters key (seed section 11).
COMMON_KEY = "common_params"
COMMON_KEYS: tuple[str, ...] = ("common_params", "common-params")

MAX_DEPTH = 64
MAX_NODES = 10_000

R = TypeVar("R")


@dataclass(frozen=True, slots=True)
class TstNode:
    """One node of a Task Specification Tree.

    ``extra`` holds unknown top-level fields verbatim; ``key_order`` the caller's key order (empty
    for nodes we made, which serialise in the seed's sorted order).
    """

    name: str
    children: tuple[TstNode, ...] = ()
    common_params: dict[str, Any] = field(default_factory=dict)
    params: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    common_key: str = COMMON_KEY
    key_order: tuple[str, ...] = ()

    @property
    def is_control(self) -> bool:
        """True for ``seq``/``conc``."""
        return self.name in CONTROL_NODES

    @property
    def node_uuid(self) -> str | None:
        value = self.common_params.get("node-uuid")
        return value if isinstance(value, str) and value else None

    @property
    def execunit(self) -> Any:
        return self.common_params.get("execunit")

    def with_common_values(self, updates: dict[str, Any]) -> TstNode:
        """A copy with ``common_params`` keys (hyphenated, e.g. ``node-uuid``) updated."""
        common = dict(self.common_params)
        common.update(updates)
        return replace(self, common_params=common)

    def with_params(self, params: dict[str, Any]) -> TstNode:
        return replace(self, params=params)

    def with_children(self, children: tuple[TstNode, ...] | list[TstNode]) -> TstNode:
        return replace(self, children=tuple(children))

    def to_dict(self) -> dict[str, Any]:
        """Serialise (iteratively, so deep trees cannot exhaust the stack)."""
        return to_dict(self)


# --------------------------------------------------------------------------- execunit


class ExecUnitKind(Enum):
    """How an ``execunit`` value constrains allocation (docs/protocol.md §7)."""

    FIXED = "fixed"
    """``/dji0``: this unit, kept as given."""
    ALIAS = "alias"
    """``A``, ``team-1``: the service chooses; every node with the same alias gets the same unit."""
    FREE = "free"
    """``""``, ``*`` or missing: the service chooses for this node alone."""


def classify_execunit(value: Any) -> tuple[ExecUnitKind, str]:
    """Classify an ``execunit``: (kind, unit name without ``/`` or the alias, or "")."""
    if value is None:
        return ExecUnitKind.FREE, ""
    if not isinstance(value, str):
        raise TypeError(f"execunit must be a string, not {type(value).__name__}")
    text = value.strip()
    if text in ("", "*"):
        return ExecUnitKind.FREE, ""
    if text.startswith("/"):
        name = text.strip("/")
        if not name:
            return ExecUnitKind.FREE, ""
        return ExecUnitKind.FIXED, name
    return ExecUnitKind.ALIAS, text


# --------------------------------------------------------------------------- walking


def walk(root: TstNode, root_path: str = "root") -> Iterator[tuple[str, TstNode]]:
    """Every node with its path (``root/children[2]``), parents before children, in tree order."""
    stack: list[tuple[str, TstNode]] = [(root_path, root)]
    while stack:
        path, node = stack.pop()
        yield path, node
        for i in range(len(node.children) - 1, -1, -1):
            stack.append((f"{path}/children[{i}]", node.children[i]))


def stored_nodes(tree: dict[str, Any]) -> Iterator[tuple[dict[str, Any], dict[str, Any]]]:
    """Every node of a tree as JSON with its common parameters (``{}`` without), parents before
    children, in tree order: for trees the service built itself and keeps as JSON (the tree sent,
    the tree the engine runs), read per message or per plan without building `TstNode`s."""
    stack: list[Any] = [tree]
    while stack:
        raw = stack.pop()
        if not isinstance(raw, dict):
            continue
        yield raw, next((raw[k] for k in COMMON_KEYS if isinstance(raw.get(k), dict)), {})
        children = raw.get("children")
        if isinstance(children, list):
            stack.extend(reversed(children))


def where(path: str, node: TstNode | None = None) -> str:
    """A node's name for messages: its path, plus name and uuid where known."""
    if node is None:
        return path
    label = f"{path} ({node.name}"
    if node.node_uuid:
        label += f" {node.node_uuid}"
    return label + ")"


def leaves(root: TstNode) -> list[TstNode]:
    """Task (non-control) nodes in tree order."""
    return [n for _, n in walk(root) if not n.is_control]


def map_tree(root: TstNode, fn: Callable[[TstNode, tuple[R, ...]], R]) -> R:
    """Rebuild the tree bottom-up: ``fn(node, new_children)`` returns the new node (or, for a
    fold such as ``to_dict``, whatever stands for the node, given what stands for its children).

    Iterative post-order, so it is safe on the deepest trees the parser admits. Nodes are values,
    so one node object may stand in several places; each place gets its own ``fn`` call.
    """
    # Results of finished subtrees, in tree order: a node's children are the last ones.
    results: list[R] = []
    stack: list[tuple[TstNode, bool]] = [(root, False)]
    while stack:
        node, expanded = stack.pop()
        if expanded:
            first = len(results) - len(node.children)
            new_children = tuple(results[first:])
            del results[first:]
            results.append(fn(node, new_children))
        else:
            stack.append((node, True))
            for child in reversed(node.children):
                stack.append((child, False))
    return results[0]


def with_uuids(root: TstNode, new_uuid: Callable[[], str] | None = None) -> TstNode:
    """The same tree with a ``node-uuid`` on every node; the caller's uuids are kept."""
    make = new_uuid or (lambda: str(uuid_module.uuid4()))

    def fill(node: TstNode, children: tuple[TstNode, ...]) -> TstNode:
        if node.node_uuid is not None and same_nodes(children, node.children):
            return node  # (nothing to change: a value needs no copy; the planner's hot path)
        node = replace(node, children=children)
        if node.node_uuid is None:
            node = node.with_common_values({"node-uuid": make()})
        return node

    return map_tree(root, fill)


def same_nodes(a: tuple[TstNode, ...], b: tuple[TstNode, ...]) -> bool:
    """Whether ``a`` and ``b`` hold the very same node objects (a rebuilt subtree that changed
    nothing is the old one: ``map_tree`` callers keep it instead of copying)."""
    return len(a) == len(b) and all(x is y for x, y in zip(a, b, strict=True))


# --------------------------------------------------------------------------- parse / serialise


def parse_tree(data: Any) -> TstNode:
    """Parse a TST from decoded JSON, checking structure only (see ``validate`` for params).

    Raises ``InputError`` naming node path and field for: a node that is not an object, a missing
    or non-string ``name``, ``children`` that is not a list, ``params``/``common_params`` that are
    not objects, a task node with children, duplicate node-uuids, a tree deeper than
    ``MAX_DEPTH`` or larger than ``MAX_NODES``.
    """
    problems: list[InputProblem] = []
    count = 0
    # Iterative pre-order over raw dicts; nodes are assembled afterwards bottom-up.
    order: list[tuple[str, Any, int, str | None]] = []  # (path, raw, depth, parent path)
    stack: list[tuple[str, Any, int, str | None]] = [("root", data, 1, None)]
    while stack:
        path, raw, depth, parent = stack.pop()
        count += 1
        if count > MAX_NODES:
            raise InputError(InputProblem("root", "", f"tree has more than {MAX_NODES} nodes"))
        if depth > MAX_DEPTH:
            raise InputError(
                InputProblem(path, "children", f"tree is nested deeper than {MAX_DEPTH} levels")
            )
        order.append((path, raw, depth, parent))
        if not isinstance(raw, dict):
            kind = json_kind(raw)
            problems.append(InputProblem(path, "", f"a node must be a JSON object, not {kind}"))
            continue
        children = raw.get("children", [])
        if children is None:
            children = []
        if not isinstance(children, list):
            problems.append(InputProblem(
                path, "children", f"must be a list, not {json_kind(children)}"))
            continue
        for i in range(len(children) - 1, -1, -1):
            stack.append((f"{path}/children[{i}]", children[i], depth + 1, path))

    if problems:
        raise InputError(problems)

    built: dict[str, TstNode] = {}
    made: list[tuple[str, TstNode]] = []
    for path, raw, _depth, _parent in reversed(order):
        node, node_problems = _build_node(path, raw, built)
        problems.extend(node_problems)
        if node is None:
            continue
        built[path] = node
        made.append((path, node))
    # Uuids in tree order, so that the later of two nodes is the one called a duplicate.
    seen_uuids: dict[str, str] = {}
    for path, node in reversed(made):
        uid = node.common_params.get("node-uuid")
        if uid is not None and not isinstance(uid, str):
            problems.append(
                InputProblem(where(path, node), "common_params.node-uuid", "must be a string")
            )
        elif isinstance(uid, str) and uid:
            if uid in seen_uuids:
                problems.append(
                    InputProblem(
                        where(path, node),
                        "common_params.node-uuid",
                        f"duplicate node-uuid {uid!r} (also used by {seen_uuids[uid]})",
                    )
                )
            else:
                seen_uuids[uid] = path
    if problems:
        # Report in tree order, not build order.
        problems.sort(key=lambda p: _path_key(p.where))
        raise InputError(problems)
    return built["root"]


def _path_key(text: str) -> list[int]:
    head = text.split(" ", 1)[0]
    return [int(part[:-1]) for part in head.split("[")[1:] if part[:-1].isdigit()]


def _build_node(
    path: str, raw: dict[str, Any], built: dict[str, TstNode]
) -> tuple[TstNode | None, list[InputProblem]]:
    problems: list[InputProblem] = []
    name = raw.get("name")
    if not isinstance(name, str) or not name:
        problems.append(
            InputProblem(path, "name", "missing" if name is None else "must be a non-empty string")
        )
        return None, problems
    present = [k for k in COMMON_KEYS if k in raw]
    common_key = present[0] if present else COMMON_KEY
    if len(present) > 1:
        problems.append(
            InputProblem(path, "common_params", "both common_params and common-params are given")
        )
    common = raw.get(common_key, {})
    if common is None:
        common = {}
    if not isinstance(common, dict):
        problems.append(InputProblem(
            path, common_key, f"must be an object, not {json_kind(common)}"))
        common = {}
    params = raw.get("params", {})
    if params is None:
        params = {}
    if not isinstance(params, dict):
        problems.append(InputProblem(path, "params", f"must be an object, not {json_kind(params)}"))
        params = {}
    raw_children = raw.get("children") or []
    children = tuple(
        built.pop(f"{path}/children[{i}]")
        for i in range(len(raw_children))
        if f"{path}/children[{i}]" in built
    )
    if len(children) != len(raw_children):
        # A child failed to build; its own problem is already reported.
        return None, problems
    known = {"name", "children", "params", *COMMON_KEYS}
    extra = {k: v for k, v in raw.items() if k not in known}
    node = TstNode(
        name=name,
        children=children,
        common_params=dict(common),
        params=dict(params),
        extra=extra,
        common_key=common_key,
        key_order=tuple(raw.keys()),
    )
    if name not in CONTROL_NODES and children:
        problems.append(
            InputProblem(where(path, node), "children", f"task node {name!r} cannot have children")
        )
    return (node if not problems else None), problems


def _node_dict(node: TstNode, children: list[dict[str, Any]]) -> dict[str, Any]:
    values: dict[str, Any] = {
        "name": node.name,
        "children": children,
        node.common_key: node.common_params,
        "params": node.params,
        **node.extra,
    }
    if node.key_order:
        # Keep the caller's keys in order; add a structural key only when it now has content.
        ordered = {k: values[k] for k in node.key_order if k in values}
        for k in sorted(values):
            if k not in ordered and values[k]:
                ordered[k] = values[k]
        return ordered
    return {k: values[k] for k in sorted(values)}


def to_dict(root: TstNode) -> dict[str, Any]:
    """Serialise a tree to plain JSON data (iteratively, see ``map_tree``)."""
    return map_tree(root, lambda node, kids: _node_dict(node, list(kids)))


def make_node(
    name: str,
    children: list[TstNode] | tuple[TstNode, ...] = (),
    *,
    execunit: str | None = None,
    node_uuid: str | None = None,
    params: dict[str, Any] | None = None,
) -> TstNode:
    """Build a node the way the seed writes one (for tests, scenarios and instantiation)."""
    common: dict[str, Any] = {}
    if execunit is not None:
        common["execunit"] = execunit
    if node_uuid is not None:
        common["node-uuid"] = node_uuid
    return TstNode(name=name, children=tuple(children), common_params=common, params=params or {})


def without_node_uuids(tree: dict[str, Any]) -> dict[str, Any]:
    """A copy of a tree's JSON without node uuids (everything else kept as it is), so the same
    mission can be planned or run again: a planned mission holds its uuids and the service refuses
    a second one with the same."""
    out = {k: v for k, v in tree.items() if k not in ("children", "common_params",
                                                       "common-params")}
    for key in ("common_params", "common-params"):
        if isinstance(tree.get(key), dict):
            out[key] = {k: v for k, v in tree[key].items() if k != "node-uuid"}
    if isinstance(tree.get("children"), list):
        out["children"] = [without_node_uuids(c) if isinstance(c, dict) else c
                           for c in tree["children"]]
    return out
