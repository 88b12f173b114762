"""The TST engine's execution logic as a pure state machine: no MQTT, no clock, no threads.

`TreeExecutor` executes fully instantiated trees (seed section 14): ``seq`` runs its children one
after the other, ``conc`` all at once; a task node becomes a ``start-task`` to its unit. It is fed
what arrives (unit responses and feedback, signals, heartbeats) together with ``now`` and returns
`Action` values (commands to send, node status changes to report);
`delegation.engine.core.EngineCore` turns them into messages.

Rules (docs/protocol.md §8 and the seed):

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
* After a broker outage (the engine reconnected, or a unit's heartbeat came back after a gap) the
  engine asks the unit ``query-status`` for each task it runs for us and applies the answer as
  feedback: a ``finished`` lost during the outage still ends the task; ``unknown`` (the unit lost
  the task) fails it.
* ``$abort``/``$pause``/``$continue``/``$enough`` on a node reach every running task under it;
  ``$abort`` revokes what has not started; ``$pause`` also holds back what would start next;
  ``$enough`` on a control node lets running tasks end and starts nothing more (it succeeds).
"""

from __future__ import annotations

import logging
import uuid as uuid_module
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from delegation.engine.tree import (
    ControlNode,
    ExecNode,
    TaskAttempt,
    TaskNode,
    Tree,
    build_tree,
    check_instantiated,
)
from delegation.errors import InputError, InputProblem
from delegation.messages import SIGNALS, TERMINAL_NODE_STATUSES, NodeStatus, Signal
from delegation.tst.node import TstNode, walk, where, with_uuids

log = logging.getLogger(__name__)

__all__ = [
    "BUSY_REASON",
    "FEEDBACK_STATUS",
    "Action",
    "EngineOptions",
    "NodeChanged",
    "SendQuery",
    "SendSignal",
    "SendStartTask",
    "TreeExecutor",
]

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
#: The example agent's answer when a unit is busy.
BUSY_REASON = "A task is already running"


@dataclass(frozen=True, slots=True)
class EngineOptions:
    """The engine's timing and retention rules (seconds unless said otherwise)."""

    resend_after: float = 2.0
    """Re-send an unanswered start-task (same com-uuid) after this long."""
    max_attempts: int = 5
    """Sends of one start-task before the node fails."""
    unit_timeout: float = 15.0
    """How long a task waits for its unit's first heartbeat."""
    busy_retry: float = 2.0
    """Ask a unit busy with someone else's task again after this long."""
    busy_timeout: float = 120.0
    """Give up on a busy unit after this long."""
    abort_timeout: float = 15.0
    """A task sent ``$abort`` counts as aborted after this long without confirmation."""
    keep_done: int = 200
    """Finished trees kept (queryable, their uuids taken) before the oldest is forgotten."""


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
    signal: Signal


@dataclass(frozen=True, slots=True)
class NodeChanged:
    """A node's status changed: publish ``tst/feedback``."""

    root_uuid: str
    node_uuid: str
    status: NodeStatus
    root_flag: bool
    fail_reason: str = ""


@dataclass(frozen=True, slots=True)
class SendQuery:
    """Send ``query-status`` to ``unit`` for ``task_uuid`` (catching up after an outage)."""

    unit: str
    com_uuid: str
    task_uuid: str


Action = SendStartTask | SendSignal | SendQuery | NodeChanged


# --------------------------------------------------------------------------- the state machine


class TreeExecutor:
    """Executes trees; every method takes ``now`` and returns the actions to carry out."""

    def __init__(
        self, options: EngineOptions | None = None, *, new_uuid: Callable[[], str] | None = None
    ) -> None:
        self.options = options or EngineOptions()
        self.new_uuid = new_uuid or (lambda: str(uuid_module.uuid4()))
        self.trees: dict[str, Tree] = {}
        self._node_tree: dict[str, str] = {}  # node uuid -> root uuid
        self._task_node: dict[str, str] = {}  # every task-uuid sent -> node uuid
        self._com_node: dict[str, str] = {}  # every start-task com-uuid -> node uuid
        self._occupant: dict[str, str] = {}  # unit -> node uuid of the vehicle task it runs
        self._queue: dict[str, deque[str]] = {}  # unit -> node uuids waiting for it
        self._queries: dict[str, str] = {}  # query-status com-uuid -> task-uuid asked about
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
                    InputProblem(
                        where(path, node),
                        "common_params.node-uuid",
                        f"node-uuid {uid} belongs to a tree that is already executing",
                    )
                )
        if problems:
            raise InputError(problems)
        tree = build_tree(root, now)
        self._prune()
        self.trees[tree.root_uuid] = tree
        for uid in tree.nodes:
            self._node_tree[uid] = tree.root_uuid
        actions: list[Action] = []
        self._activate(tree, tree.root, now, actions)
        return tree.root_uuid, actions

    # ---- status changes

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
        if isinstance(node, TaskNode):
            node.waiting_since = now
            self._try_start(tree, node, now, actions)
            return
        assert isinstance(node, ControlNode)
        self._set(tree, node, NodeStatus.RUNNING, actions)
        if not node.children:
            self._finish(tree, node, NodeStatus.SUCCEEDED, now, actions)
        elif node.is_seq:
            node.next_child = 1
            self._activate(tree, tree.nodes[node.children[0]], now, actions)
        else:
            node.next_child = len(node.children)
            for child in tree.children(node):
                if node.terminal or node.stopping is not None:
                    break
                self._activate(tree, child, now, actions)

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
        if isinstance(node, TaskNode):
            self._release_unit(node, now, actions)
            queue = self._queue.get(node.unit)
            if queue and node.uuid in queue:
                queue.remove(node.uuid)
        parent = tree.parent(node)
        if parent is not None:
            self._child_ended(tree, parent, node, now, actions)

    def _finish_if_children_ended(
        self, tree: Tree, node: ControlNode, now: float, actions: list[Action]
    ) -> None:
        """A control node whose children have all ended ends too: as it is stopping (failed,
        aborted), else succeeded."""
        if tree.children_ended(node):
            status = node.stopping or NodeStatus.SUCCEEDED
            self._finish(tree, node, status, now, actions, node.fail_reason)

    def _child_ended(
        self, tree: Tree, parent: ControlNode, child: ExecNode, now: float, actions: list[Action]
    ) -> None:
        if parent.terminal:
            return
        if child.status in (NodeStatus.FAILED, NodeStatus.ABORTED) and parent.stopping is None:
            why = f"{child.path} ({child.name}) {child.status.value}"
            if child.fail_reason:
                why += f": {child.fail_reason}"
            parent.stopping = child.status
            parent.fail_reason = why
            self._stop_children(tree, parent, Signal.ABORT, now, actions)
        going_on = parent.stopping is None and not parent.enough and parent.is_seq
        if going_on and parent.next_child < len(parent.children):
            nxt = tree.nodes[parent.children[parent.next_child]]
            parent.next_child += 1
            self._activate(tree, nxt, now, actions)
            return
        self._finish_if_children_ended(tree, parent, now, actions)

    # ---- starting tasks and sharing units

    def _try_start(self, tree: Tree, node: TaskNode, now: float, actions: list[Action]) -> None:
        """Send the task's start-task now, or make it wait for its unit."""
        unit = node.unit
        if any(a.held for a in tree.ancestors(node)):
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
        task_uuid = self.new_uuid()
        node.attempt = TaskAttempt(task_uuid, self.new_uuid(), sends=1, sent_at=now)
        node.known_uuids.add(task_uuid)
        node.known_coms.add(node.attempt.com_uuid)
        self._task_node[task_uuid] = node.uuid
        self._com_node[node.attempt.com_uuid] = node.uuid
        self._set(tree, node, NodeStatus.ACTIVE, actions)
        actions.append(self._start_action(node))

    @staticmethod
    def _start_action(node: TaskNode) -> SendStartTask:
        a = node.attempt
        return SendStartTask(node.unit, a.com_uuid, a.task_uuid, node.name, node.params, node.uuid)

    def _release_unit(self, node: TaskNode, now: float, actions: list[Action]) -> None:
        """A vehicle task ended: give its unit to the next task waiting for it."""
        if not node.vehicle or self._occupant.get(node.unit) != node.uuid:
            return
        del self._occupant[node.unit]
        self._wake(node.unit, now, actions)

    def _wake(self, unit: str, now: float, actions: list[Action]) -> None:
        queue = self._queue.get(unit)
        while queue and unit not in self._occupant:
            uid = queue.popleft()
            tree = self.trees.get(self._node_tree.get(uid, ""))
            if tree is None:
                continue
            waiting = tree.nodes[uid]
            if isinstance(waiting, TaskNode) and waiting.status is NodeStatus.WAITING:
                self._try_start(tree, waiting, now, actions)

    # ---- stopping and signals

    def _stop_children(
        self, tree: Tree, parent: ControlNode, signal: Signal, now: float, actions: list[Action]
    ) -> None:
        """Stop everything under ``parent``: signal running tasks, revoke what has not started."""
        for child in tree.children(parent):
            if child.terminal:
                continue
            if child.status is NodeStatus.NOT_ACTIVE:
                self._revoke_subtree(tree, child, actions)
            elif isinstance(child, ControlNode):
                child.stopping = child.stopping or NodeStatus.ABORTED
                self._stop_children(tree, child, signal, now, actions)
                self._finish_if_children_ended(tree, child, now, actions)
            elif isinstance(child, TaskNode):
                self._signal_task(tree, child, signal, now, actions)
        if parent.is_seq:
            parent.next_child = len(parent.children)

    def _revoke_subtree(self, tree: Tree, node: ExecNode, actions: list[Action]) -> None:
        for n in tree.subtree(node):
            if not n.terminal:
                self._set(tree, n, NodeStatus.REVOKED, actions)

    def _signal_task(
        self, tree: Tree, node: TaskNode, signal: Signal, now: float, actions: list[Action]
    ) -> None:
        """Deliver a signal to one task node, whatever state it is in."""
        if node.terminal:
            return
        if not node.sent:
            # Not sent to the unit (yet): the engine decides alone.
            if signal is Signal.ABORT:
                self._finish(
                    tree, node, NodeStatus.ABORTED, now, actions, "aborted before it started"
                )
            elif signal is Signal.ENOUGH:
                self._finish(tree, node, NodeStatus.SUCCEEDED, now, actions)
            elif signal is Signal.PAUSE:
                self._set(tree, node, NodeStatus.PAUSED, actions)
            elif signal is Signal.CONTINUE and node.status is NodeStatus.PAUSED:
                self._try_start(tree, node, now, actions)
            return
        if signal is Signal.ABORT and node.abort_sent_at is None:
            node.abort_sent_at = now
        if not node.attempt.answered:
            node.pending_signal = signal  # deliver once the unit has accepted the task
            return
        actions.append(SendSignal(node.unit, node.attempt.task_uuid, signal))

    @staticmethod
    def _deliver_pending_signal(node: TaskNode, actions: list[Action]) -> None:
        """The unit has accepted the task: send the signal that arrived before it did."""
        if node.pending_signal is not None:
            signal, node.pending_signal = node.pending_signal, None
            actions.append(SendSignal(node.unit, node.attempt.task_uuid, signal))

    def _signal_node(
        self, tree: Tree, node: ExecNode, signal: Signal, now: float, actions: list[Action]
    ) -> None:
        if node.terminal:
            return
        if isinstance(node, TaskNode):
            self._signal_task(tree, node, signal, now, actions)
            return
        assert isinstance(node, ControlNode)
        if signal is Signal.ABORT:
            node.stopping = node.stopping or NodeStatus.ABORTED
            node.fail_reason = node.fail_reason or "aborted"
            self._stop_children(tree, node, Signal.ABORT, now, actions)
            self._finish_if_children_ended(tree, node, now, actions)
            return
        if signal is Signal.PAUSE:
            node.held = True
            self._set(tree, node, NodeStatus.PAUSED, actions)
        elif signal is Signal.CONTINUE:
            node.held = False
            if node.status is NodeStatus.PAUSED:
                self._set(tree, node, NodeStatus.RUNNING, actions)
        elif signal is Signal.ENOUGH:
            node.enough = True
            if node.is_seq:
                node.next_child = len(node.children)
            for n in tree.subtree(node)[1:]:
                if n.status is NodeStatus.NOT_ACTIVE:
                    self._set(tree, n, NodeStatus.REVOKED, actions)
        for child in tree.children(node):
            if child.status is not NodeStatus.NOT_ACTIVE:
                self._signal_node(tree, child, signal, now, actions)
        if signal is Signal.ENOUGH:
            self._finish_if_children_ended(tree, node, now, actions)

    def signal_node(self, node_uuid: str, signal: str, now: float) -> list[Action]:
        """``signal-tst-node``: raises `InputError` for an unknown node or signal."""
        tree = self._tree_of(node_uuid)
        sig = self._check_signal(signal)
        actions: list[Action] = []
        self._signal_node(tree, tree.nodes[node_uuid], sig, now, actions)
        return actions

    def signal_tree(self, node_uuid: str, signal: str, now: float) -> list[Action]:
        """``signal-tst-tree``: the signal to the node and every node under it."""
        return self.signal_node(node_uuid, signal, now)

    def signal_unit(self, unit: str, signal: str, now: float) -> list[Action]:
        """``signal-unit``: the signal to every running task node on ``unit``."""
        sig = self._check_signal(signal)
        name = unit.strip("/")
        actions: list[Action] = []
        for tree in list(self.trees.values()):
            for node in tree.tasks():
                if node.unit == name and node.started:
                    self._signal_task(tree, node, sig, now, actions)
        return actions

    def _tree_of(self, node_uuid: str) -> Tree:
        root = self._node_tree.get(node_uuid)
        if root is None or root not in self.trees:
            raise InputError(InputProblem(
                "node-uuid", "node-uuid", f"no executing node {node_uuid!r}"))
        return self.trees[root]

    @staticmethod
    def _check_signal(signal: str) -> Signal:
        try:
            return Signal(signal)
        except ValueError:
            raise InputError(
                InputProblem("signal", "signal", f"{signal!r} is not one of {', '.join(SIGNALS)}")
            ) from None

    # ---- inputs from units

    def unit_seen(self, unit: str, now: float) -> list[Action]:
        """A heartbeat from ``unit``: tasks waiting for it to appear can start."""
        unit = unit.strip("/")
        if unit in self.units_seen:
            return []
        self.units_seen.add(unit)
        actions: list[Action] = []
        for tree in list(self.trees.values()):
            for node in tree.tasks():
                if node.unit == unit and node.status is NodeStatus.WAITING and not node.sent:
                    self._try_start(tree, node, now, actions)
        return actions

    def _task(self, uid: str | None) -> tuple[Tree, TaskNode] | None:
        tree = self.trees.get(self._node_tree.get(uid or "", ""))
        node = tree.nodes.get(uid or "") if tree is not None else None
        if tree is None or not isinstance(node, TaskNode):
            return None
        return tree, node

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
        asked = self._queries.pop(response_to, None)
        if asked is not None:
            return self._status_answer(asked, response, now)
        found = self._task(self._com_node.get(response_to))
        if found is None or found[1].attempt.com_uuid != response_to:
            return []
        tree, node = found
        actions: list[Action] = []
        if node.terminal or node.attempt.answered:
            return actions
        node.attempt.answered = True
        if response in ("running", "started", "ok", "finished"):
            if node.status in (NodeStatus.ACTIVE, NodeStatus.WAITING):
                self._set(tree, node, NodeStatus.RUNNING, actions)
            if response == "finished":
                self._finish(tree, node, NodeStatus.SUCCEEDED, now, actions)
            else:
                self._deliver_pending_signal(node, actions)
            return actions
        reason = fail_reason or f"{response}"
        if reason == BUSY_REASON and now - node.waiting_since < self.options.busy_timeout:
            # Busy with a task that is not ours: ask again later, with a fresh task-uuid.
            # The node keeps the unit, so this engine's own tasks for it stay queued behind.
            node.retry_at = now + self.options.busy_retry
            node.attempt.sends = 0
            node.refused.add(node.attempt.task_uuid)
            self._set(tree, node, NodeStatus.WAITING, actions)
            return actions
        refused = f"/{node.unit} refused {node.name}: {reason}"
        self._finish(tree, node, NodeStatus.FAILED, now, actions, refused)
        return actions

    def on_feedback(self, task_uuid: str, status: str, now: float) -> list[Action]:
        """A unit's ``exec/feedback`` for one of our tasks (others are ignored)."""
        found = self._task(self._task_node.get(task_uuid))
        if found is None:
            return []
        tree, node = found
        actions: list[Action] = []
        if node.terminal:
            return actions
        if status == "failed" and task_uuid in node.refused:
            return actions  # the example agent's feedback next to a refusal we already handled
        if task_uuid != node.attempt.task_uuid:
            # An earlier attempt of this node is what the unit runs after all: adopt it.
            node.attempt.task_uuid = task_uuid
            node.retry_at = None
            if node.vehicle:
                self._occupant[node.unit] = node.uuid
        mapped = FEEDBACK_STATUS.get(status)
        if mapped is None:
            log.debug("task %s reports %r (task specific): kept as running", task_uuid, status)
            return actions
        if mapped is NodeStatus.FAILED and not node.attempt.answered:
            # The example agent sends feedback "failed" next to a refusal; the response decides.
            return actions
        node.attempt.answered = True
        if mapped in TERMINAL_NODE_STATUSES:
            reason = f"/{node.unit} reported {status}" if mapped is not NodeStatus.SUCCEEDED else ""
            self._finish(tree, node, mapped, now, actions, reason)
        else:
            self._set(tree, node, mapped, actions)
            self._deliver_pending_signal(node, actions)
        return actions

    # ---- catching up after an outage

    def query(self, unit: str | None = None) -> list[Action]:
        """``query-status`` for every task a unit (``unit``, or every unit) accepted from us and
        that has not ended: its feedback may have been lost while the broker was away."""
        actions: list[Action] = []
        for tree in list(self.trees.values()):
            if tree.done:
                continue
            for node in tree.tasks():
                if node.terminal or not node.sent or not node.attempt.answered:
                    continue
                if unit is not None and node.unit != unit:
                    continue
                com = self.new_uuid()
                self._queries[com] = node.attempt.task_uuid
                actions.append(SendQuery(node.unit, com, node.attempt.task_uuid))
        if len(self._queries) > 10_000:  # unanswered queries (example agents never answer)
            for com in list(self._queries)[: len(self._queries) - 10_000]:
                del self._queries[com]
        return actions

    def _status_answer(self, task_uuid: str, response: str, now: float) -> list[Action]:
        """A unit's answer to ``query-status``: its task's state, applied as feedback."""
        if response != "unknown":
            return self.on_feedback(task_uuid, response, now)
        found = self._task(self._task_node.get(task_uuid))
        if found is None or found[1].terminal or found[1].attempt.task_uuid != task_uuid:
            return []
        tree, node = found
        actions: list[Action] = []
        why = f"/{node.unit} no longer knows task {task_uuid} (query-status after an outage)"
        self._finish(tree, node, NodeStatus.FAILED, now, actions, why)
        return actions

    # ---- time

    def tick(self, now: float) -> list[Action]:
        """Re-send unanswered start-tasks, retry busy units, time out units never seen."""
        actions: list[Action] = []
        for tree in list(self.trees.values()):
            if tree.done:
                continue
            for node in tree.tasks():
                if not node.terminal:
                    self._tick_task(tree, node, now, actions)
        return actions

    def _tick_task(self, tree: Tree, node: TaskNode, now: float, actions: list[Action]) -> None:
        opts = self.options
        attempt = node.attempt
        if node.abort_sent_at is not None and now - node.abort_sent_at >= opts.abort_timeout:
            why = f"/{node.unit} did not confirm $abort within {opts.abort_timeout:g} s"
            self._finish(tree, node, NodeStatus.ABORTED, now, actions, why)
        elif node.sent and not attempt.answered and node.status is NodeStatus.ACTIVE:
            if now - attempt.sent_at < opts.resend_after:
                return
            if attempt.sends >= opts.max_attempts:
                why = f"/{node.unit} did not answer start-task ({attempt.sends} attempts)"
                self._finish(tree, node, NodeStatus.FAILED, now, actions, why)
                return
            attempt.sends += 1
            attempt.sent_at = now
            actions.append(self._start_action(node))
        elif node.status is NodeStatus.WAITING and not node.sent:
            if node.retry_at is not None:
                if now >= node.retry_at:
                    self._try_start(tree, node, now, actions)
            elif node.unit not in self.units_seen and now - node.waiting_since >= opts.unit_timeout:
                why = f"unit /{node.unit} is unknown: no heartbeat within {opts.unit_timeout:g} s"
                self._finish(tree, node, NodeStatus.FAILED, now, actions, why)

    # ---- queries and memory

    def executing(self) -> list[str]:
        """Root uuids of the trees still executing."""
        return [r for r, t in self.trees.items() if not t.done]

    def status(self, node_uuid: str) -> NodeStatus | None:
        tree = self.trees.get(self._node_tree.get(node_uuid, ""))
        return tree.nodes[node_uuid].status if tree else None

    def _prune(self) -> None:
        """Forget the oldest finished trees beyond ``keep_done`` (they stay queryable till then)."""
        done = [r for r, t in self.trees.items() if t.done]  # insertion order: oldest first
        for root_uuid in done[: max(0, len(done) - self.options.keep_done)]:
            self.forget(root_uuid)

    def forget(self, root_uuid: str) -> None:
        """Drop a finished tree (its node uuids may be used again)."""
        tree = self.trees.get(root_uuid)
        if tree is None or not tree.done:
            return
        del self.trees[root_uuid]
        for uid in tree.nodes:
            self._node_tree.pop(uid, None)
        for node in tree.tasks():
            for t in node.known_uuids:
                self._task_node.pop(t, None)
            for c in node.known_coms:
                self._com_node.pop(c, None)
