"""The operator's own tree during execution (DESIGN 3.4 revised): pure state.

The tree sent to the engine may regroup the caller's control nodes (series-parallel
instantiation), so the engine's feedback on control nodes is about a tree the operator never
wrote. The service relays the leaves' feedback unchanged and derives every control node of the
operator's tree from its children, as the engine computes a control node: failed when a child
failed, aborted when a child was aborted (or revoked), succeeded when all succeeded, running once
any child has started. Nodes that exist only in the sent tree are not shown. A control node the
sent tree kept (same uuid and tasks) that the engine reports ended first is shown as the engine
says (an aborted tree's root, whose tasks may never report).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from delegation.tst.node import TstNode, walk

_FINAL = frozenset({"succeeded", "failed", "aborted", "revoked"})
_STARTED = frozenset({"active", "waiting", "running", "paused", "succeeded", "failed",
                      "aborted", "revoked"})


@dataclass
class OperatorView:
    """The operator's tree by uuid: parents, children, leaves, and the control statuses shown."""

    root: str
    parent: dict[str, str] = field(default_factory=dict)
    children: dict[str, list[str]] = field(default_factory=dict)  # control nodes only
    leaves: set[str] = field(default_factory=set)
    shown: dict[str, str] = field(default_factory=dict)  # control uuid -> last status published

    @classmethod
    def of(cls, tree: TstNode) -> OperatorView:
        """The view of a tree with a uuid on every node (the plan's ``source``)."""
        view = cls(root=tree.node_uuid or "")
        for _, node in walk(tree):
            uid = node.node_uuid or ""
            if not node.is_control:
                view.leaves.add(uid)
                continue
            kids = [c.node_uuid or "" for c in node.children]
            view.children[uid] = kids
            for kid in kids:
                view.parent[kid] = uid
        return view

    def __contains__(self, node_uuid: object) -> bool:
        return node_uuid in self.leaves or node_uuid in self.children

    def derive(self, node_uuid: str, statuses: Mapping[str, str]) -> str:
        """A control node's status from its children's (leaves: as the engine said)."""
        if node_uuid in self.leaves:
            return statuses.get(node_uuid, "not-active")
        kids = [self.derive(k, statuses) if k in self.children else statuses.get(k, "not-active")
                for k in self.children.get(node_uuid, [])]
        if "failed" in kids:
            return "failed"
        if "aborted" in kids or "revoked" in kids:
            return "aborted"
        if kids and all(k == "succeeded" for k in kids):
            return "succeeded"
        if any(k in _STARTED for k in kids):
            return "running"
        return "not-active"

    def final_from_engine(self, node_uuid: str, status: str) -> bool:
        """A control node the sent tree kept (same uuid, same tasks) ended as the engine says:
        True when that is news to show (e.g. an aborted tree whose leaves never reported)."""
        if node_uuid not in self.children or status not in _FINAL:
            return False
        if self.shown.get(node_uuid) in _FINAL:
            return False
        self.shown[node_uuid] = status
        return True

    def changes(self, leaf_uuid: str, statuses: Mapping[str, str]) -> list[tuple[str, str]]:
        """After ``leaf_uuid``'s status changed: the operator's control nodes above it whose
        derived status changed (innermost first), recorded as shown."""
        out: list[tuple[str, str]] = []
        node = self.parent.get(leaf_uuid)
        while node is not None:
            status = self.derive(node, statuses)
            if (status != "not-active" and self.shown.get(node) != status
                    and self.shown.get(node) not in _FINAL):
                self.shown[node] = status
                out.append((node, status))
            node = self.parent.get(node)
        return out
