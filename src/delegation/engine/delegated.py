"""Subtrees the engine hands to another TST executor (a delegator; docs/protocol.md §15.3),
pure.

A node of a tree to execute whose ``execunit`` names a unit on the ``tst execution`` level (by
its heartbeat ``levels``; not this engine) is not executed here: it is folded into one task node
(`DELEGATED_TASK`) on that unit, whose params carry the subtree, so the executor schedules it
like any task (its turn, re-sends with the same com-uuid, signals, timeouts). Where the executor
would send that task's ``start-task`` on the unit's ``exec/command``, a ``start-tst`` of the
subtree goes to the unit's ``tst/command`` (its root without the ``execunit`` naming the unit:
the delegator chooses its own units inside); a signal to the task becomes a ``signal-tst-tree``
of the subtree's root. The delegator's ``tst/response`` answers both; its ``tst/feedback`` for the
subtree's root moves the folded task, and its feedback for the nodes inside is relayed on this
engine's ``tst/feedback`` unchanged (node uuids are kept end to end).
"""

from __future__ import annotations

import json
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any

from delegation.engine.executor import SendSignal, SendStartTask
from delegation.messages import SignalTstTree, StartTst, TstFeedback, TstResponse, WireModel
from delegation.tst.node import (
    TstNode,
    classify_execunit,
    map_tree,
    stored_nodes,
    to_dict,
    walk,
)

__all__ = ["DELEGATED_TASK", "Delegated", "fold_delegated", "levels_of"]

#: The folded task's name (never a catalogue task: nobody else sends it).
DELEGATED_TASK = "delegated-subtree"


def levels_of(payload: bytes) -> list[str] | None:
    """The ``levels`` of a heartbeat payload (normalised spelling), or None when unreadable."""
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError):
        return None
    levels = data.get("levels") if isinstance(data, dict) else None
    if not isinstance(levels, list):
        return None
    return [" ".join(v.replace("_", " ").replace("-", " ").lower().split())
            for v in levels if isinstance(v, str)]


def fold_delegated(root: TstNode, executors: Collection[str]) -> TstNode:
    """The tree with every topmost node below the root that names one of ``executors`` (units
    on the ``tst execution`` level) as its ``execunit`` folded into a `DELEGATED_TASK` on that
    unit (the nodes inside, named for it too, go with it)."""
    if not executors:
        return root
    folded: set[int] = set()
    outer: list[str] = []  # paths of the nodes folded so far (walk is pre-order)
    for path, node in walk(root):
        if node is root or any(path.startswith(p + "/") for p in outer):
            continue
        if isinstance(node.execunit, str) and classify_execunit(node.execunit)[1] in executors:
            folded.add(id(node))
            outer.append(path)
    if not folded:
        return root

    def fold(original: TstNode, children: tuple[TstNode, ...]) -> TstNode:
        if id(original) not in folded:
            return original.with_children(children)
        unit = original.execunit
        subtree = to_dict(map_tree(original, lambda n, kids: _unnamed(n.with_children(kids),
                                                                      unit)))
        return TstNode(DELEGATED_TASK, (), dict(original.common_params), {"tst": subtree})

    return map_tree(root, fold)


def _unnamed(node: TstNode, execunit: str) -> TstNode:
    """The node without ``execunit`` when it names the delegator (it chooses its own units)."""
    if node.execunit != execunit:
        return node
    common = {k: v for k, v in node.common_params.items() if k != "execunit"}
    return TstNode(node.name, node.children, common, node.params, node.extra, node.common_key,
                   node.key_order)


@dataclass(slots=True)
class _Sent:
    """One subtree out to a delegator: its root's uuid, the folded task's current task-uuid."""

    unit: str
    root_uuid: str
    task_uuid: str
    inner: frozenset[str]


@dataclass(slots=True)
class Delegated:
    """The subtrees out to other executors, and the units on the ``tst execution`` level."""

    engine: str
    executors: set[str] = field(default_factory=set)
    #: A delegator not heard for this long is handed nothing: the node runs here, as the
    #: service's re-delegation planned it (its units are lost after >= 5 s).
    fresh_for: float = 4.0
    _heard: dict[str, float] = field(default_factory=dict)
    _sent: dict[str, _Sent] = field(default_factory=dict)  # subtree root uuid -> sent
    _inner: dict[str, str] = field(default_factory=dict)  # node inside -> subtree root uuid

    @property
    def outstanding(self) -> bool:
        """True while a subtree is out (only then is a delegator's message worth reading)."""
        return bool(self._sent)

    def heard(self, unit: str, payload: bytes, now: float) -> None:
        """A heartbeat: is ``unit`` a TST executor (a delegator) we may hand subtrees to?"""
        levels = levels_of(payload)
        if levels is None or unit == self.engine:
            return
        if "tst execution" in levels:
            self.executors.add(unit)
            self._heard[unit] = now
        else:
            self.executors.discard(unit)

    def fold(self, root: TstNode, now: float) -> TstNode:
        """`fold_delegated` with the executors heard within ``fresh_for``."""
        fresh = {u for u in self.executors
                 if u != self.engine and now - self._heard.get(u, -1e18) < self.fresh_for}
        return fold_delegated(root, fresh)

    def handles(self, action: Any) -> bool:
        """True for a start or signal of a folded task (it goes to the unit's ``tst/command``)."""
        if isinstance(action, SendStartTask):
            return action.name == DELEGATED_TASK
        return isinstance(action, SendSignal) and any(
            s.task_uuid == action.task_uuid for s in self._sent.values())

    def command(self, action: SendStartTask | SendSignal, sender: str) -> WireModel:
        """The ``start-tst`` (same com-uuid on every re-send) or ``signal-tst-tree``."""
        if isinstance(action, SendStartTask):
            tree = action.params.get("tst", {})
            inner = frozenset(n for n in _uuids(tree) if n != action.node_uuid)
            self._sent[action.node_uuid] = _Sent(action.unit, action.node_uuid, action.task_uuid,
                                                 inner)
            self._inner.update(dict.fromkeys(inner, action.node_uuid))
            return StartTst(com_uuid=action.com_uuid, sender=sender, receiver=action.unit,
                            tst=tree)
        root = next(s.root_uuid for s in self._sent.values() if s.task_uuid == action.task_uuid)
        signal = action.signal if isinstance(action.signal, str) else action.signal.value
        return SignalTstTree(com_uuid=action.com_uuid, sender=sender, node_uuid=root,
                             signal=signal)

    def response(self, message: TstResponse) -> tuple[str, str, str]:
        """(response-to, response, fail-reason) as the executor reads a unit's answer: a
        delegator's ``started`` is a task ``running``."""
        response = "running" if message.response == "started" else message.response
        return message.response_to, response, message.fail_reason

    def feedback(self, unit: str, fb: TstFeedback) -> tuple[str, str] | TstFeedback | None:
        """A delegator's feedback: (task-uuid, status) for a subtree's root (the executor's
        ``on_feedback``), the feedback to relay for a node inside, or None (not ours)."""
        sent = self._sent.get(fb.node_uuid)
        if sent is not None and sent.unit == unit:
            return sent.task_uuid, fb.status
        root = self._inner.get(fb.node_uuid)
        if root is not None and self._sent[root].unit == unit:
            return TstFeedback(node_uuid=fb.node_uuid, status=fb.status,
                               fail_reason=fb.fail_reason)
        return None

    def forget(self, root_uuid: str) -> None:
        """A subtree ended: its nodes' feedback is no longer expected."""
        sent = self._sent.pop(root_uuid, None)
        for uid in sent.inner if sent else ():
            self._inner.pop(uid, None)


def _uuids(tree: dict[str, Any]) -> list[str]:
    """Every node-uuid in a tree as JSON (one the engine folded itself: `stored_nodes` reads it
    without parsing)."""
    return [c["node-uuid"] for _, c in stored_nodes(tree) if isinstance(c.get("node-uuid"), str)]
