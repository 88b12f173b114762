"""The TST engine's execution logic as a pure state machine: no MQTT, no clock, no threads.

`EngineCore` executes fully instantiated trees (seed section 14): ``seq`` runs its children one
after the other, ``conc`` all at once; a task node becomes a ``start-task`` to its unit. It is fed
what arrives (unit responses and feedback, signals, heartbeats) together with ``now`` and returns
`Action` values (commands to send, node status changes to report); `delegation.engine` puts it on
MQTT.

Rules (DESIGN 3.4 and the seed):

* A start-task is re-sent with the same com-uuid (and task-uuid) every ``resend_after`` s until
  the unit answers, at most ``max_attempts`` times; then the node fails.
* A unit runs one vehicle task at a time: a vehicle task whose unit is busy with another of this
  engine's tasks waits (status ``waiting``) in a FIFO per unit. A unit that refuses with "A task is
  already running" (busy with someone else's task) is asked again every ``busy_retry`` s with a
  fresh task-uuid, for at most ``busy_timeout`` s.
* A task whose unit has not been seen (no heartbeat) waits up to ``unit_timeout`` s, then fails.
* Unit feedback ``finished``/``enough`` -> ``succeeded``; ``failed`` -> ``failed``; ``aborted``
  -> ``aborted``; ``paused``/``running`` as they are.
* A child that fails fails its ``seq``/``conc``; the rest is stopped (running tasks get ``$abort``,
  tasks not started are ``revoked``). A child that is aborted aborts its parent the same way.
* ``$abort``/``$pause``/``$continue``/``$enough`` on a node reach every running task under it;
  ``$abort`` revokes what has not started; ``$pause`` also holds back what would start next;
  ``$enough`` on a control node lets running tasks end and starts nothing more (it succeeds).
"""

from __future__ import annotations

import logging
import uuid as uuid_module
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from delegation.errors import InputError, Problem
from delegation.messages import NodeStatus
from delegation.tst.catalogue import is_vehicle_task
from delegation.tst.node import ExecUnitKind, TstNode, classify_execunit, walk, where, with_uuids

log = logging.getLogger(__name__)

#: Unit feedback statuses and the node status each one means.
FEEDBACK_STATUS: dict[str, NodeStatus] = {
    "running": NodeStatus.RUNNING,
    "starting": NodeStatus.RUNNING,
    "paused": NodeStatus.PAUSED,
    "finished": NodeStatus.SUCCEEDED,
    "enough": NodeStatus.SUCCEEDED,
    "success": NodeStatus.SUCCEEDED,
    "succeeded": NodeStatus.SUCCEEDED,
    "failed": NodeStatus.FAILED,
    "aborted": NodeStatus.ABORTED,
}
TERMINAL: frozenset[NodeStatus] = frozenset(
    {NodeStatus.SUCCEEDED, NodeStatus.FAILED, NodeStatus.ABORTED, NodeStatus.REVOKED}
)
#: The example agent's answer when a unit is busy.
BUSY_REASON = "A task is already running"
SIGNALS: tuple[str, ...] = ("$abort", "$pause", "$continue", "$enough")


# --------------------------------------------------------------------------- actions


@dataclass(frozen=True, slots=True)
class SendStartTask:
    """Send ``start-task`` to ``unit`` (a re-send carries the same com-uuid and task-uuid)."""

    unit: str
    com_uuid: str
    task_uuid: str
    name: str
    params: dict[str, Any]
    node_uuid: str


@dataclass(frozen=True, slots=True)
class SendSignal:
    """Send ``signal-task`` to ``unit`` for ``task_uuid``."""

    unit: str
    task_uuid: str
    signal: str


@dataclass(frozen=True, slots=True)
class NodeChanged:
    """A node's status changed: publish ``tst/feedback``."""

    root_uuid: str
    node_uuid: str
    status: NodeStatus
    root_flag: bool
    fail_reason: str = ""


Action = SendStartTask | SendSignal | NodeChanged


# --------------------------------------------------------------------------- state


@dataclass
class ExecNode:
    """One node of an executing tree."""

    uuid: str
    name: str
    path: str
    parent: str | None
    children: list[str]
    unit: str | None  # task nodes: the unit name (no slash)
    params: dict[str, Any]
    is_control: bool
    vehicle: bool
    status: NodeStatus = NodeStatus.NOT_ACTIVE
    fail_reason: str = ""
    # control nodes
    next_child: int = 0
    held: bool = False  # $pause: start nothing more until $continue
    enough: bool = False  # $enough: start nothing more, succeed when running children end
    stopping: NodeStatus | None = None  # failing/aborting: the status once children have ended
    # task nodes
    task_uuid: str = ""
    com_uuid: str = ""
    attempts: int = 0
    sent_at: float = 0.0
    answered: bool = False
    waiting_since: float = 0.0
    retry_at: float | None = None
    known_uuids: set[str] = field(default_factory=set)
    known_coms: set[str] = field(default_factory=set)
    refused: set[str] = field(default_factory=set)  # task-uuids a busy unit refused
    abort_sent_at: float | None = None
    pending_signal: str | None = None  # a signal that arrived before the unit answered

    @property
    def terminal(self) -> bool:
        return self.status in TERMINAL

    @property
    def started(self) -> bool:
        """A task the unit may be executing (start-task sent and not ended)."""
        return not self.is_control and self.attempts > 0 and not self.terminal


@dataclass
class Tree:
    root_uuid: str
    nodes: dict[str, ExecNode]
    started_at: float

    @property
    def root(self) -> ExecNode:
        return self.nodes[self.root_uuid]

    @property
    def done(self) -> bool:
        return self.root.terminal


def check_instantiated(root: TstNode) -> list[Problem]:
    """Why a (parsed) tree is not fully instantiated: every task node needs ``/unit``."""
    problems: list[Problem] = []
    for path, node in walk(root):
        try:
            kind, _ = classify_execunit(node.execunit)
        except TypeError as exc:
            problems.append(Problem(where(path, node), f"{node.common_key}.execunit", str(exc)))
            continue
        if node.is_control:
            if node.execunit not in (None, "") and kind is not ExecUnitKind.FIXED:
                problems.append(
                    Problem(
                        where(path, node),
                        f"{node.common_key}.execunit",
                        f"{node.execunit!r} is not a unit (a fully instantiated tree names "
                        "units as /name)",
                    )
                )
            continue
        if kind is not ExecUnitKind.FIXED:
            shown = "missing" if node.execunit is None else repr(node.execunit)
            problems.append(
                Problem(
                    where(path, node),
                    f"{node.common_key}.execunit",
                    f"{shown} is not a unit: the engine runs fully instantiated trees only "
                    "(every task names its unit as /name)",
                )
            )
    return problems


# --------------------------------------------------------------------------- the core


class EngineCore:
    """Executes trees; every method takes ``now`` and returns the actions to carry out."""

    def __init__(
        self,
        *,
        new_uuid: Callable[[], str] | None = None,
        resend_after: float = 2.0,
        max_attempts: int = 5,
        unit_timeout: float = 15.0,
        busy_retry: float = 2.0,
        busy_timeout: float = 120.0,
        abort_timeout: float = 15.0,
        keep_done: int = 200,
    ) -> None:
        self.new_uuid = new_uuid or (lambda: str(uuid_module.uuid4()))
        self.resend_after = resend_after
        self.max_attempts = max_attempts
        self.unit_timeout = unit_timeout
        self.busy_retry = busy_retry
        self.busy_timeout = busy_timeout
        self.abort_timeout = abort_timeout
        self.keep_done = keep_done
        self.trees: dict[str, Tree] = {}
        self._node_tree: dict[str, str] = {}  # node uuid -> root uuid
        self._task_node: dict[str, str] = {}  # every task-uuid sent -> node uuid
        self._com_node: dict[str, str] = {}  # every start-task com-uuid -> node uuid
        self._occupant: dict[str, str] = {}  # unit -> node uuid of the vehicle task it runs
        self._queue: dict[str, deque[str]] = {}  # unit -> node uuids waiting for it
        self.units_seen: set[str] = set()

    # ---- starting

    def start_tree(self, root: TstNode, now: float) -> tuple[str, list[Action]]:
        """Start executing a parsed tree; raises `InputError` naming the nodes it cannot run."""
        root = with_uuids(root, self.new_uuid)
        problems = check_instantiated(root)
        for path, node in walk(root):
            uid = node.node_uuid or ""
            old = self.trees.get(self._node_tree.get(uid, ""))
            if old is not None and old.done:
                self.forget(old.root_uuid)
            if uid in self._node_tree:
                problems.append(
                    Problem(
                        where(path, node),
                        "common_params.node-uuid",
                        f"node-uuid {uid} belongs to a tree that is already executing",
                    )
                )
        if problems:
            raise InputError(problems)
        tree = self._build(root, now)
        self._prune()
        self.trees[tree.root_uuid] = tree
        for uid in tree.nodes:
            self._node_tree[uid] = tree.root_uuid
        actions: list[Action] = []
        self._activate(tree, tree.root, now, actions)
        return tree.root_uuid, actions

    def _build(self, root: TstNode, now: float) -> Tree:
        nodes: dict[str, ExecNode] = {}
        parents: dict[int, str] = {}
        for path, node in walk(root):
            uid = node.node_uuid or ""
            unit = None
            if not node.is_control:
                _, unit = classify_execunit(node.execunit)
            nodes[uid] = ExecNode(
                uuid=uid,
                name=node.name,
                path=path,
                parent=parents.get(id(node)),
                children=[c.node_uuid or "" for c in node.children],
                unit=unit,
                params=dict(node.params),
                is_control=node.is_control,
                vehicle=(not node.is_control) and is_vehicle_task(node.name),
            )
            for child in node.children:
                parents[id(child)] = uid
        return Tree(root.node_uuid or "", nodes, now)

    # ---- the state machine

    def _set(
        self,
        tree: Tree,
        node: ExecNode,
        status: NodeStatus,
        actions: list[Action],
        reason: str = "",
    ) -> None:
        if node.status == status and node.fail_reason == reason:
            return
        node.status = status
        node.fail_reason = reason
        actions.append(
            NodeChanged(tree.root_uuid, node.uuid, status, node.uuid == tree.root_uuid, reason)
        )

    def _activate(self, tree: Tree, node: ExecNode, now: float, actions: list[Action]) -> None:
        if node.is_control:
            self._set(tree, node, NodeStatus.RUNNING, actions)
            if not node.children:
                self._finish(tree, node, NodeStatus.SUCCEEDED, now, actions)
            elif node.name == "conc":
                node.next_child = len(node.children)
                for uid in node.children:
                    if node.status in TERMINAL or node.stopping is not None:
                        break
                    self._activate(tree, tree.nodes[uid], now, actions)
            else:
                node.next_child = 1
                self._activate(tree, tree.nodes[node.children[0]], now, actions)
            return
        node.waiting_since = now
        self._try_start(tree, node, now, actions)

    def _try_start(self, tree: Tree, node: ExecNode, now: float, actions: list[Action]) -> None:
        """Send the task's start-task now, or make it wait for its unit."""
        unit = node.unit or ""
        if self._held(tree, node):
            self._set(tree, node, NodeStatus.PAUSED, actions)
            return
        blocked = unit not in self.units_seen or (
            node.vehicle and self._occupant.get(unit) not in (None, node.uuid)
        )
        if blocked or (node.retry_at is not None and now < node.retry_at):
            if node.vehicle and unit in self.units_seen and node.retry_at is None:
                queue = self._queue.setdefault(unit, deque())
                if node.uuid not in queue:
                    queue.append(node.uuid)
            self._set(tree, node, NodeStatus.WAITING, actions)
            return
        if node.vehicle:
            self._occupant[unit] = node.uuid
            waiting = self._queue.get(unit)
            if waiting and node.uuid in waiting:
                waiting.remove(node.uuid)
        node.retry_at = None
        node.task_uuid = self.new_uuid()
        node.com_uuid = self.new_uuid()
        node.known_uuids.add(node.task_uuid)
        self._task_node[node.task_uuid] = node.uuid
        self._com_node[node.com_uuid] = node.uuid
        node.known_coms.add(node.com_uuid)
        node.attempts = 1
        node.answered = False
        node.sent_at = now
        self._set(tree, node, NodeStatus.ACTIVE, actions)
        actions.append(self._start_action(node))

    def _start_action(self, node: ExecNode) -> SendStartTask:
        return SendStartTask(
            node.unit or "", node.com_uuid, node.task_uuid, node.name, node.params, node.uuid
        )

    def _held(self, tree: Tree, node: ExecNode) -> bool:
        return any(tree.nodes[a].held for a in self._ancestors(tree, node))

    def _ancestors(self, tree: Tree, node: ExecNode) -> Iterator[str]:
        parent = node.parent
        while parent is not None:
            yield parent
            parent = tree.nodes[parent].parent

    def _release_unit(self, node: ExecNode, now: float, actions: list[Action]) -> None:
        """A vehicle task ended: give its unit to the next task waiting for it."""
        unit = node.unit or ""
        if not node.vehicle or self._occupant.get(unit) != node.uuid:
            return
        del self._occupant[unit]
        self._wake(unit, now, actions)

    def _wake(self, unit: str, now: float, actions: list[Action]) -> None:
        queue = self._queue.get(unit)
        while queue and unit not in self._occupant:
            uid = queue.popleft()
            root = self._node_tree.get(uid)
            tree = self.trees.get(root or "")
            if tree is None:
                continue
            waiting = tree.nodes[uid]
            if waiting.status is NodeStatus.WAITING:
                self._try_start(tree, waiting, now, actions)

    def _finish(
        self,
        tree: Tree,
        node: ExecNode,
        status: NodeStatus,
        now: float,
        actions: list[Action],
        reason: str = "",
    ) -> None:
        """A node reached a final status: tell its parent."""
        if node.terminal:
            return
        self._set(tree, node, status, actions, reason)
        if not node.is_control:
            self._release_unit(node, now, actions)
            queue = self._queue.get(node.unit or "")
            if queue and node.uuid in queue:
                queue.remove(node.uuid)
        if node.parent is not None:
            self._child_ended(tree, tree.nodes[node.parent], node, now, actions)

    def _child_ended(
        self, tree: Tree, parent: ExecNode, child: ExecNode, now: float, actions: list[Action]
    ) -> None:
        if parent.terminal:
            return
        if child.status in (NodeStatus.FAILED, NodeStatus.ABORTED) and parent.stopping is None:
            why = f"{child.path} ({child.name}) {child.status.value}"
            if child.fail_reason:
                why += f": {child.fail_reason}"
            parent.stopping = child.status
            parent.fail_reason = why
            self._stop_children(tree, parent, "$abort", now, actions)
        if parent.stopping is not None or parent.enough:
            if all(tree.nodes[c].terminal for c in parent.children):
                status = parent.stopping or NodeStatus.SUCCEEDED
                self._finish(tree, parent, status, now, actions, parent.fail_reason)
            return
        if parent.name == "conc":
            if all(tree.nodes[c].terminal for c in parent.children):
                self._finish(tree, parent, NodeStatus.SUCCEEDED, now, actions)
            return
        # seq: the next child, or done.
        if parent.next_child < len(parent.children):
            nxt = tree.nodes[parent.children[parent.next_child]]
            parent.next_child += 1
            self._activate(tree, nxt, now, actions)
        elif all(tree.nodes[c].terminal for c in parent.children):
            self._finish(tree, parent, NodeStatus.SUCCEEDED, now, actions)

    def _stop_children(
        self, tree: Tree, parent: ExecNode, signal: str, now: float, actions: list[Action]
    ) -> None:
        """Stop everything under ``parent``: signal running tasks, revoke what has not started."""
        for uid in list(parent.children):
            child = tree.nodes[uid]
            if child.terminal:
                continue
            if child.is_control:
                if child.status is NodeStatus.NOT_ACTIVE:
                    self._revoke_subtree(tree, child, actions)
                else:
                    child.stopping = child.stopping or NodeStatus.ABORTED
                    self._stop_children(tree, child, signal, now, actions)
                    if all(tree.nodes[c].terminal for c in child.children):
                        self._finish(tree, child, child.stopping, now, actions, child.fail_reason)
            elif child.status is NodeStatus.NOT_ACTIVE:
                self._revoke_subtree(tree, child, actions)
            else:
                self._signal_task(tree, child, signal, now, actions)
        if parent.name == "seq":
            parent.next_child = len(parent.children)

    def _revoke_subtree(self, tree: Tree, node: ExecNode, actions: list[Action]) -> None:
        for uid in self._subtree(tree, node):
            n = tree.nodes[uid]
            if not n.terminal:
                self._set(tree, n, NodeStatus.REVOKED, actions)

    def _subtree(self, tree: Tree, node: ExecNode) -> list[str]:
        out, stack = [], [node.uuid]
        while stack:
            uid = stack.pop()
            out.append(uid)
            stack.extend(reversed(tree.nodes[uid].children))
        return out

    def _signal_task(
        self, tree: Tree, node: ExecNode, signal: str, now: float, actions: list[Action]
    ) -> None:
        """Deliver a signal to one task node, whatever state it is in."""
        if node.terminal:
            return
        if node.attempts == 0:
            # Not sent to the unit (yet): the engine decides alone.
            if signal == "$abort":
                self._finish(
                    tree, node, NodeStatus.ABORTED, now, actions, "aborted before it started"
                )
            elif signal == "$enough":
                self._finish(tree, node, NodeStatus.SUCCEEDED, now, actions)
            elif signal == "$pause":
                self._set(tree, node, NodeStatus.PAUSED, actions)
            elif signal == "$continue" and node.status is NodeStatus.PAUSED:
                self._try_start(tree, node, now, actions)
            return
        if signal == "$abort" and node.abort_sent_at is None:
            node.abort_sent_at = now
        if not node.answered:
            node.pending_signal = signal  # deliver once the unit has accepted the task
            return
        actions.append(SendSignal(node.unit or "", node.task_uuid, signal))

    @staticmethod
    def _deliver_pending_signal(node: ExecNode, actions: list[Action]) -> None:
        """The unit has accepted the task: send the signal that arrived before it did."""
        if node.pending_signal is not None:
            signal, node.pending_signal = node.pending_signal, None
            actions.append(SendSignal(node.unit or "", node.task_uuid, signal))

    # ---- inputs from units

    def unit_seen(self, unit: str, now: float) -> list[Action]:
        """A heartbeat from ``unit``: tasks waiting for it to appear can start."""
        unit = unit.strip("/")
        if unit in self.units_seen:
            return []
        self.units_seen.add(unit)
        actions: list[Action] = []
        for tree in list(self.trees.values()):
            for node in list(tree.nodes.values()):
                if node.unit == unit and node.status is NodeStatus.WAITING and node.attempts == 0:
                    self._try_start(tree, node, now, actions)
        return actions

    def _node_for_task(self, task_uuid: str | None) -> tuple[Tree, ExecNode] | None:
        uid = self._task_node.get(task_uuid or "")
        tree = self.trees.get(self._node_tree.get(uid or "", ""))
        if tree is None or uid is None:
            return None
        return tree, tree.nodes[uid]

    def _node_for_com(self, com_uuid: str) -> tuple[Tree, ExecNode] | None:
        uid = self._com_node.get(com_uuid)
        tree = self.trees.get(self._node_tree.get(uid or "", ""))
        if tree is None or uid is None:
            return None
        node = tree.nodes[uid]
        return (tree, node) if node.com_uuid == com_uuid else None

    def on_response(
        self,
        response_to: str,
        response: str,
        now: float,
        *,
        fail_reason: str = "",
        task_uuid: str | None = None,
    ) -> list[Action]:
        """A unit's ``exec/response`` to one of our start-tasks (others are ignored)."""
        found = self._node_for_com(response_to)
        if found is None:
            return []
        tree, node = found
        actions: list[Action] = []
        if node.terminal or node.answered:
            return actions
        node.answered = True
        if response in ("running", "started", "ok", "finished"):
            if node.status in (NodeStatus.ACTIVE, NodeStatus.WAITING):
                self._set(tree, node, NodeStatus.RUNNING, actions)
            if response == "finished":
                self._finish(tree, node, NodeStatus.SUCCEEDED, now, actions)
            else:
                self._deliver_pending_signal(node, actions)
            return actions
        reason = fail_reason or f"{response}"
        if reason == BUSY_REASON and now - node.waiting_since < self.busy_timeout:
            # Busy with a task that is not ours: ask again later, with a fresh task-uuid.
            # The node keeps the unit, so this engine's own tasks for it stay queued behind.
            node.retry_at = now + self.busy_retry
            node.attempts = 0
            node.refused.add(node.task_uuid)
            self._set(tree, node, NodeStatus.WAITING, actions)
            return actions
        self._finish(
            tree,
            node,
            NodeStatus.FAILED,
            now,
            actions,
            f"/{node.unit} refused {node.name}: {reason}",
        )
        return actions

    def on_feedback(self, task_uuid: str, status: str, now: float) -> list[Action]:
        """A unit's ``exec/feedback`` for one of our tasks (others are ignored)."""
        found = self._node_for_task(task_uuid)
        if found is None:
            return []
        tree, node = found
        actions: list[Action] = []
        if node.terminal:
            return actions
        if status == "failed" and task_uuid in node.refused:
            return actions  # the example agent's feedback next to a refusal we already handled
        if task_uuid != node.task_uuid:
            # An earlier attempt of this node is what the unit runs after all: adopt it.
            node.task_uuid = task_uuid
            node.retry_at = None
            if node.vehicle:
                self._occupant[node.unit or ""] = node.uuid
        mapped = FEEDBACK_STATUS.get(status)
        if mapped is None:
            log.debug("task %s reports %r (task specific): kept as running", task_uuid, status)
            return actions
        if mapped is NodeStatus.FAILED and not node.answered:
            # The example agent sends feedback "failed" next to a refusal; the response decides.
            return actions
        node.answered = True
        if mapped in TERMINAL:
            reason = f"/{node.unit} reported {status}" if mapped is not NodeStatus.SUCCEEDED else ""
            self._finish(tree, node, mapped, now, actions, reason)
        else:
            self._set(tree, node, mapped, actions)
            self._deliver_pending_signal(node, actions)
        return actions

    # ---- signals

    def _signal_node(
        self, tree: Tree, node: ExecNode, signal: str, now: float, actions: list[Action]
    ) -> None:
        if node.terminal:
            return
        if not node.is_control:
            self._signal_task(tree, node, signal, now, actions)
            return
        if signal == "$abort":
            node.stopping = node.stopping or NodeStatus.ABORTED
            node.fail_reason = node.fail_reason or "aborted"
            self._stop_children(tree, node, "$abort", now, actions)
            if all(tree.nodes[c].terminal for c in node.children):
                self._finish(tree, node, node.stopping, now, actions, node.fail_reason)
            return
        if signal == "$pause":
            node.held = True
            self._set(tree, node, NodeStatus.PAUSED, actions)
        elif signal == "$continue":
            node.held = False
            if node.status is NodeStatus.PAUSED:
                self._set(tree, node, NodeStatus.RUNNING, actions)
        elif signal == "$enough":
            node.enough = True
            if node.name == "seq":
                node.next_child = len(node.children)
            for uid in self._subtree(tree, node)[1:]:
                n = tree.nodes[uid]
                if n.status is NodeStatus.NOT_ACTIVE:
                    self._set(tree, n, NodeStatus.REVOKED, actions)
        for uid in node.children:
            child = tree.nodes[uid]
            if child.status is not NodeStatus.NOT_ACTIVE:
                self._signal_node(tree, child, signal, now, actions)
        if signal == "$enough" and all(tree.nodes[c].terminal for c in node.children):
            self._finish(tree, node, NodeStatus.SUCCEEDED, now, actions)

    def signal_node(self, node_uuid: str, signal: str, now: float) -> list[Action]:
        """``signal-tst-node``: raises `InputError` for an unknown node or signal."""
        tree = self._tree_of(node_uuid)
        self._check_signal(signal)
        actions: list[Action] = []
        self._signal_node(tree, tree.nodes[node_uuid], signal, now, actions)
        return actions

    def signal_tree(self, node_uuid: str, signal: str, now: float) -> list[Action]:
        """``signal-tst-tree``: the signal to the node and every node under it."""
        return self.signal_node(node_uuid, signal, now)

    def signal_unit(self, unit: str, signal: str, now: float) -> list[Action]:
        """``signal-unit``: the signal to every running task node on ``unit``."""
        self._check_signal(signal)
        name = unit.strip("/")
        actions: list[Action] = []
        for tree in list(self.trees.values()):
            for node in list(tree.nodes.values()):
                if node.unit == name and node.started:
                    self._signal_task(tree, node, signal, now, actions)
        return actions

    def _tree_of(self, node_uuid: str) -> Tree:
        root = self._node_tree.get(node_uuid)
        if root is None or root not in self.trees:
            raise InputError(Problem("node-uuid", "node-uuid", f"no executing node {node_uuid!r}"))
        return self.trees[root]

    @staticmethod
    def _check_signal(signal: str) -> None:
        if signal not in SIGNALS:
            raise InputError(
                Problem("signal", "signal", f"{signal!r} is not one of {', '.join(SIGNALS)}")
            )

    # ---- time

    def tick(self, now: float) -> list[Action]:
        """Re-send unanswered start-tasks, retry busy units, time out units never seen."""
        actions: list[Action] = []
        for tree in list(self.trees.values()):
            if tree.done:
                continue
            for node in list(tree.nodes.values()):
                if node.is_control or node.terminal:
                    continue
                if (
                    node.abort_sent_at is not None
                    and now - node.abort_sent_at >= self.abort_timeout
                ):
                    self._finish(
                        tree,
                        node,
                        NodeStatus.ABORTED,
                        now,
                        actions,
                        f"/{node.unit} did not confirm $abort within {self.abort_timeout:g} s",
                    )
                    continue
                if node.attempts > 0 and not node.answered and node.status is NodeStatus.ACTIVE:
                    if now - node.sent_at < self.resend_after:
                        continue
                    if node.attempts >= self.max_attempts:
                        self._finish(
                            tree,
                            node,
                            NodeStatus.FAILED,
                            now,
                            actions,
                            f"/{node.unit} did not answer start-task ({node.attempts} attempts)",
                        )
                        continue
                    node.attempts += 1
                    node.sent_at = now
                    actions.append(self._start_action(node))
                elif node.status is NodeStatus.WAITING and node.attempts == 0:
                    if node.retry_at is not None:
                        if now >= node.retry_at:
                            self._try_start(tree, node, now, actions)
                    elif (node.unit or "") not in self.units_seen and (
                        now - node.waiting_since >= self.unit_timeout
                    ):
                        self._finish(
                            tree,
                            node,
                            NodeStatus.FAILED,
                            now,
                            actions,
                            f"unit /{node.unit} is unknown: no heartbeat within "
                            f"{self.unit_timeout:g} s",
                        )
        return actions

    # ---- queries

    def executing(self) -> list[str]:
        """Root uuids of the trees still executing."""
        return [r for r, t in self.trees.items() if not t.done]

    def status(self, node_uuid: str) -> NodeStatus | None:
        root = self._node_tree.get(node_uuid)
        tree = self.trees.get(root or "")
        return tree.nodes[node_uuid].status if tree else None

    def _prune(self) -> None:
        """Forget the oldest finished trees beyond ``keep_done`` (they stay queryable till then)."""
        done = [r for r, t in self.trees.items() if t.done]  # insertion order: oldest first
        for root_uuid in done[: max(0, len(done) - self.keep_done)]:
            self.forget(root_uuid)

    def forget(self, root_uuid: str) -> None:
        """Drop a finished tree (its node uuids may be used again)."""
        tree = self.trees.get(root_uuid)
        if tree is None or not tree.done:
            return
        del self.trees[root_uuid]
        for uid, node in tree.nodes.items():
            self._node_tree.pop(uid, None)
            for t in node.known_uuids:
                self._task_node.pop(t, None)
            for c in node.known_coms:
                self._com_node.pop(c, None)
