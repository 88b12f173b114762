"""The operator's own tree during execution (docs/protocol.md §8): pure state.

The tree sent to the engine may regroup the caller's control nodes (series-parallel
instantiation). The service relays unchanged the engine's feedback on the leaves and on the
control nodes the sent tree kept (same uuid, same tasks: the engine computes them; the root is
always kept). A control node of the operator's tree that the sent tree does not have is derived
from its children, as the engine computes a control node (docs/protocol.md §12.3): once every
child has ended, failed when a child failed, else aborted when a child was aborted, revoked when
every child was revoked (skipped), else succeeded (a ``revoked`` child is skipped work, not a
failure); before that, running once any child has started. Nodes that exist only in the sent tree
are not shown.

A search the plan shared among units (DESIGN 3.11) is sent as a ``conc`` of per-unit parts with
the search's uuid; where the sent tree kept that ``conc``, the engine's feedback on it is relayed
as the search's; where it regrouped it away, the search's status is derived from its parts' like
a control node's (running when one runs, succeeded when all did). The parts themselves are not
shown.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from delegation.tst.node import TstNode, walk

_FINAL = frozenset({"succeeded", "failed", "aborted", "revoked"})
_STARTED = frozenset({"active", "waiting", "running", "paused", "succeeded", "failed",
                      "aborted"})


@dataclass
class OperatorView:
    """The operator's tree by uuid: parents, children, leaves, and the control statuses shown."""

    root: str
    parent: dict[str, str] = field(default_factory=dict)
    children: dict[str, list[str]] = field(default_factory=dict)  # control nodes only
    leaves: set[str] = field(default_factory=set)
    kept: set[str] = field(default_factory=set)  # control nodes the sent tree has too
    shown: dict[str, str] = field(default_factory=dict)  # derived uuid -> last status published
    #: Parts of shared searches whose ``conc`` the sent tree does not have (tracked, not shown).
    parts: set[str] = field(default_factory=set)

    @classmethod
    def of(cls, tree: TstNode, sent: TstNode | None = None,
           shared: Mapping[str, Sequence[str]] | None = None) -> OperatorView:
        """The view of a tree with a uuid on every node (the plan's ``source``); ``sent``: the
        tree sent (its control nodes with the operator's uuids are relayed, not derived);
        ``shared``: each shared search's uuid -> its parts' uuids (``Plan.part_map``)."""
        view = cls(root=tree.node_uuid or "")
        if sent is not None:
            view.kept = {n.node_uuid or "" for _, n in walk(sent) if n.is_control}
        for _, node in walk(tree):
            uid = node.node_uuid or ""
            if not node.is_control and uid in (shared or {}) and uid not in view.kept:
                view.children[uid] = list((shared or {})[uid])
                for part in view.children[uid]:
                    view.parent[part] = uid
                    view.parts.add(part)
                continue
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

    def relayed(self, node_uuid: str) -> bool:
        """The engine's feedback on this node is shown unchanged (a leaf or a kept node)."""
        return node_uuid in self.leaves or (node_uuid in self.children
                                            and node_uuid in self.kept)

    def tracked(self, node_uuid: str) -> bool:
        """The engine's feedback on this node moves the view: relayed, or a shared search's
        part (shown only through the search's derived status)."""
        return self.relayed(node_uuid) or node_uuid in self.parts

    def derive(self, node_uuid: str, statuses: Mapping[str, str]) -> str:
        """A control node's status from its children's (leaves: as the engine said)."""
        if self.relayed(node_uuid) or node_uuid in self.parts:
            return statuses.get(node_uuid, "not-active")
        kids = [self.derive(k, statuses) for k in self.children.get(node_uuid, [])]
        if kids and all(k in _FINAL for k in kids):
            if "failed" in kids:
                return "failed"
            if "aborted" in kids:
                return "aborted"
            return "revoked" if all(k == "revoked" for k in kids) else "succeeded"
        if any(k in _STARTED for k in kids):
            return "running"
        return "not-active"

    def reset(self) -> None:
        """The tree was replaced (a re-delegation): what was shown may change again."""
        self.shown.clear()

    def changes(self, node_uuid: str, statuses: Mapping[str, str]) -> list[tuple[str, str]]:
        """After relayed ``node_uuid``'s status changed: the derived control nodes above it whose
        status changed (innermost first), recorded as shown."""
        out: list[tuple[str, str]] = []
        node = self.parent.get(node_uuid)
        while node is not None:
            if self.relayed(node):
                node = self.parent.get(node)
                continue
            status = self.derive(node, statuses)
            if (status != "not-active" and self.shown.get(node) != status
                    and self.shown.get(node) not in _FINAL):
                self.shown[node] = status
                out.append((node, status))
            node = self.parent.get(node)
        return out
