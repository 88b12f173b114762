"""The TST engine's execution logic as a pure state machine: no MQTT, no clock, no threads.

`TreeExecutor` executes fully instantiated trees (seed section 14): ``seq`` runs its children one
after the other, ``conc`` all at once; a task node becomes a ``start-task`` to its unit. It is fed
what arrives (unit responses and feedback, signals, heartbeats) together with ``now`` and returns
`Action` values (commands to send, node status changes to report);
`delegation.engine.core.EngineCore` turns them into messages.

Rules (docs/protocol.md §8, §12 and the seed):

* A start-task's ids are derived from the tree's ``run`` (the start-tst's com-uuid), the node and
  the attempt (docs/protocol.md §12.4), so an engine restarted and given the tree again re-sends
  the start-tasks a unit already got; a ``resume`` tree asks ``query-status`` once each is
  answered (§12.5).
* A start-task is re-sent with the same com-uuid (and task-uuid) every ``resend_after`` s until
  the unit answers, at most ``max_attempts`` times; then the node fails and the unit is sent
  ``$abort`` (it may have got the task and be running it).
* A unit runs one vehicle task at a time: a vehicle task whose unit is busy with another of this
  engine's tasks waits (status ``waiting``) in a FIFO per unit. A unit that refuses with "A task is
  already running" (busy with someone else's task) is asked again every ``busy_retry`` s with a
  fresh task-uuid, for at most ``busy_timeout`` s.
* A task whose unit has not been seen (no heartbeat) waits up to ``unit_timeout`` s, then fails.
* Unit feedback ``finished``/``enough`` -> ``succeeded``; ``failed`` -> ``failed``; ``aborted``
  -> ``aborted``; ``paused``/``running`` as they are.
* A child that fails fails its ``seq``/``conc``; the rest is stopped (running tasks get
  ``$abort``, what has not started is ``revoked``). A child that is aborted ends its ``seq``
  (the rest is revoked, never run out of order) while a ``conc`` lets its other branches run on
  and ends ``aborted`` when they have ended (docs/protocol.md §12.3).
* After a broker outage (the engine reconnected, or a unit's heartbeat came back after a gap) the
  engine asks the unit ``query-status`` for each task it runs for us and applies the answer as
  feedback: a ``finished`` lost during the outage still ends the task; ``unknown`` (the unit lost
  the task) fails it.
* Signals (docs/protocol.md §12): ``signal-tst-node`` is for the node alone, ``signal-tst-tree``
  for every node under it too. A node signalled before its turn keeps it: ``$enough`` skips it
  (``revoked``), ``$pause`` holds it when its turn comes, ``$continue`` lets it go without
  starting it early, ``$abort`` ends it ``aborted`` and its parent learns it when the turn comes.
  ``$enough`` on a control node starts nothing more under it (what has not started is
  ``revoked``, never ``succeeded``).
* A ``signal-task`` is re-sent with the same com-uuid until the unit answers, at most
  ``max_attempts`` times, then given up (said in the node's fail-reason; an unanswered ``$abort``
  ends the node ``aborted`` saying the unit may still run it). A given-up start-task is followed
  by ``$abort``. Signals that arrive before the unit answered the start-task wait, all of them,
  in order.
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
from delegation.messages import (
    SIGNALS,
    TERMINAL_NODE_STATUSES,
    UNIT_ABORTED,
    NodeStatus,
    Signal,
)
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
#: The uuid5 namespace of reproducible start-task ids (`TreeExecutor._start_ids`).
RUN_NAMESPACE = uuid_module.UUID("5d0c5a52-8a3e-4f55-9d3b-3f0f2f6b9a11")


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
    """Send ``signal-task`` to ``unit`` for ``task_uuid`` (a re-send carries the same com-uuid)."""

    unit: str
    task_uuid: str
    signal: Signal | str
    """A built-in `Signal` or a task-specific name (seed 12.2.2), sent as it is."""
    com_uuid: str


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

#: Pending work of the state machine: (operation, tree, node uuid, child uuid or "").
_Op = tuple[str, Tree, str, str]
#: The fail-reason of a node skipped by ``$enough`` before it started.
SKIPPED = "not started: $enough"


@dataclass(slots=True)
class _SignalOut:
    """A ``signal-task`` out and not answered: re-sent with the same com-uuid until it is."""

    unit: str
    task_uuid: str
    signal: Signal | str
    node_uuid: str
    sends: int
    sent_at: float


class TreeExecutor:
    """Executes trees; every method takes ``now`` and returns the actions to carry out.

    The walks are iterative (a worklist, `_drain`), so a tree's depth and width are bounded by
    the tree limits only, never by Python's recursion limit.
    """

    def __init__(
        self, options: EngineOptions | None = None, *, new_uuid: Callable[[], str] | None = None
    ) -> None:
        self.options = options or EngineOptions()
        self.new_uuid = new_uuid or (lambda: str(uuid_module.uuid4()))
        self.trees: dict[str, Tree] = {}
        self._node_tree: dict[str, str] = {}  # node uuid -> root uuid
        self._task_node: dict[str, str] = {}  # every task-uuid sent -> node uuid
        self._com_node: dict[str, str] = {}  # every start-task com-uuid -> node uuid
        self._signals: dict[str, _SignalOut] = {}  # signal-task com-uuid -> what is out
        self._occupant: dict[str, str] = {}  # unit -> node uuid of the vehicle task it runs
        self._queue: dict[str, deque[str]] = {}  # unit -> node uuids waiting for it
        self._queries: dict[str, str] = {}  # query-status com-uuid -> task-uuid asked about
        self._todo: list[_Op] = []  # the worklist, last in first out (depth first)
        self.units_seen: set[str] = set()

    # ---- starting

    def start_tree(
        self, root: TstNode, now: float, run: str = "", resume: bool = False,
        hold_failed: float = 0.0,
    ) -> tuple[str, list[Action]]:
        """Start executing a parsed tree; raises `InputError` naming the nodes it cannot run.

        ``run`` (the start-tst's com-uuid) makes the start-task ids reproducible (`Tree.run`);
        ``resume`` asks each task's unit for its status once its start-task is answered;
        ``hold_failed`` holds a failed task that long for a rebind (`Tree.hold_failed`)."""
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
        tree = build_tree(root, now, run, resume)
        tree.hold_failed = max(0.0, hold_failed)
        self._prune()
        self.trees[tree.root_uuid] = tree
        for uid in tree.nodes:
            self._node_tree[uid] = tree.root_uuid
        actions: list[Action] = []
        self._activate(tree, tree.root, now, actions)
        self._drain(now, actions)
        return tree.root_uuid, actions

    # ---- the worklist

    def _drain(self, now: float, actions: list[Action]) -> None:
        """Do the pending work: activations, children that ended, control nodes to move on."""
        todo = self._todo
        while todo:
            op, tree, uid, child = todo.pop()
            node = tree.nodes[uid]
            if op == "activate":
                self._activate(tree, node, now, actions)
                continue
            assert isinstance(node, ControlNode)
            if op == "child" and not node.terminal:
                self._note(tree, node, tree.nodes[child], now, actions)
            self._advance(tree, node, now, actions)

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
        was_terminal = node.terminal
        node.status = status
        node.fail_reason = reason
        parent = tree.parent(node)
        if parent is not None and node.terminal and not was_terminal:
            parent.ended += 1
        actions.append(
            NodeChanged(tree.root_uuid, node.uuid, status, node.uuid == tree.root_uuid, reason)
        )

    def _activate(self, tree: Tree, node: ExecNode, now: float, actions: list[Action]) -> None:
        """The node's turn came: a task starts (or waits), a control node runs its children."""
        if node.terminal or node.turn:
            return
        node.turn = True
        if isinstance(node, TaskNode):
            node.waiting_since = now
            self._try_start(tree, node, now, actions)
            return
        self._set(tree, node, NodeStatus.PAUSED if node.held else NodeStatus.RUNNING, actions)
        self._todo.append(("advance", tree, node.uuid, ""))

    def _finish(
        self,
        tree: Tree,
        node: ExecNode,
        status: NodeStatus,
        now: float,
        actions: list[Action],
        reason: str = "",
        *,
        release: bool = False,
    ) -> None:
        """A node reached a final status: tell its parent if it was waiting for it (a failed
        task of a holding tree is held first, `_hold`; ``release`` ends the hold)."""
        if node.terminal:
            return
        if isinstance(node, TaskNode) and not release and (
                node.hold_until is not None or self._hold(tree, node, status, reason, now,
                                                          actions)):
            return  # held: reported, its branch not told; a later end changes nothing
        if isinstance(node, TaskNode):
            node.hold_until = None
        self._set(tree, node, status, actions, reason)
        if isinstance(node, TaskNode):
            self._release_unit(node, now, actions)
            queue = self._queue.get(node.unit)
            if queue and node.uuid in queue:
                queue.remove(node.uuid)
            node.pending.clear()
            for com in node.signals:
                self._signals.pop(com, None)
            node.signals.clear()
        if node.turn and node.parent is not None:
            self._todo.append(("child", tree, node.parent, node.uuid))

    def _hold(self, tree: Tree, node: TaskNode, status: NodeStatus, reason: str, now: float,
              actions: list[Action]) -> bool:
        """A task of a holding tree failed (or its unit aborted it unasked): report it, free its
        unit, and keep its branch going until a rebind moves it or `Tree.hold_failed` runs out
        (docs/protocol.md §12.7). False when the tree does not hold, or this end is not held."""
        unasked = status is NodeStatus.ABORTED and reason.endswith(UNIT_ABORTED)
        if tree.hold_failed <= 0.0 or not node.turn or not (
                status is NodeStatus.FAILED or unasked):
            return False
        node.hold_until = now + tree.hold_failed
        node.held_end = (status, reason)
        self._release_unit(node, now, actions)
        node.pending.clear()
        for com in node.signals:
            self._signals.pop(com, None)
        node.signals.clear()
        actions.append(NodeChanged(tree.root_uuid, node.uuid, status, node.uuid == tree.root_uuid,
                                   reason))
        log.info("task %s (%s) %s: held %g s for a rebind", node.uuid, node.path, status.value,
                 tree.hold_failed)
        return True

    def _note(
        self, tree: Tree, parent: ControlNode, child: ExecNode, now: float, actions: list[Action]
    ) -> None:
        """What a child's end means for its parent (docs/protocol.md §12.3): a failed child
        fails the parent and stops the rest; an aborted child ends a ``seq`` (the rest is not
        run out of order) while a ``conc`` lets its other branches run on and ends ``aborted``;
        a child succeeded or revoked (skipped) changes nothing."""
        status = child.status
        if status not in (NodeStatus.FAILED, NodeStatus.ABORTED) or parent.stopping is not None:
            return
        why = f"{child.path} ({child.name}) {status.value}"
        if child.fail_reason:
            why += f": {child.fail_reason}"
        if status is NodeStatus.FAILED or parent.is_seq:
            parent.stopping = status
            parent.why = why
            self._stop(tree, parent, now, actions)
        elif parent.outcome is None:
            parent.outcome = status
            parent.why = why

    def _advance(self, tree: Tree, node: ControlNode, now: float, actions: list[Action]) -> None:
        """Start the children whose turn it is; end the node once every child has ended."""
        if node.terminal or not node.turn:
            return
        if node.stopping is None:
            if node.is_seq:
                self._advance_seq(tree, node, now, actions)
            elif not node.opened:
                self._open_conc(tree, node, now, actions)
        if node.ended < len(node.children):
            return
        status = node.stopping or node.outcome or NodeStatus.SUCCEEDED
        reason = node.why if status is not NodeStatus.SUCCEEDED else ""
        self._finish(tree, node, status, now, actions, reason)

    def _advance_seq(
        self, tree: Tree, node: ControlNode, now: float, actions: list[Action]
    ) -> None:
        """Move the cursor past the children that ended (noting those that ended before their
        turn) and activate the first that has not had its turn."""
        while node.cursor < len(node.children):
            child = tree.nodes[node.children[node.cursor]]
            if child.terminal:
                node.cursor += 1
                if not child.turn:
                    self._note(tree, node, child, now, actions)
                    if node.stopping is not None:
                        return
                continue
            if not child.turn:
                self._activate(tree, child, now, actions)
            return

    def _open_conc(self, tree: Tree, node: ControlNode, now: float, actions: list[Action]) -> None:
        """A ``conc``'s turn: every child that has not ended starts (depth first, in order)."""
        node.opened = True
        children = tree.children(node)
        for child in children:
            if child.terminal and not child.turn:
                self._note(tree, node, child, now, actions)
        if node.stopping is not None:
            return
        for child in reversed(children):
            if not child.terminal:
                self._todo.append(("activate", tree, child.uuid, ""))

    # ---- starting tasks and sharing units

    def _held(self, tree: Tree, node: ExecNode) -> bool:
        """``$pause`` on the node or a node above it holds it back."""
        return node.held or any(a.held for a in tree.ancestors(node))

    def _try_start(self, tree: Tree, node: TaskNode, now: float, actions: list[Action]) -> None:
        """Send the task's start-task now, or make it wait for its unit (or for ``$continue``)."""
        if node.terminal or not node.turn or node.sent:
            return
        unit = node.unit
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
        task_uuid, com_uuid = self._start_ids(tree, node)
        node.attempt = TaskAttempt(task_uuid, com_uuid, sends=1, sent_at=now)
        node.known_uuids.add(task_uuid)
        node.known_coms.add(node.attempt.com_uuid)
        self._task_node[task_uuid] = node.uuid
        self._com_node[node.attempt.com_uuid] = node.uuid
        self._set(tree, node, NodeStatus.ACTIVE, actions)
        actions.append(self._start_action(node))

    def _start_ids(self, tree: Tree, node: TaskNode) -> tuple[str, str]:
        """The task-uuid and com-uuid of the node's next start-task: derived from the tree's
        ``run``, the node and the attempt's number where the tree has a run (an engine restarted
        and given the tree again re-sends the very start-task a unit already got: answered
        again, not run again, seed 12), else fresh."""
        if not tree.run:
            return self.new_uuid(), self.new_uuid()
        attempt = f"{tree.run}/{node.uuid}/{len(node.known_uuids) + 1}"
        if node.moves:  # not the ids its earlier unit got (§12.6: a new task-uuid)
            attempt += f"/moved{node.moves}"
        return (str(uuid_module.uuid5(RUN_NAMESPACE, f"{attempt}/task")),
                str(uuid_module.uuid5(RUN_NAMESPACE, f"{attempt}/start")))

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

    def _stop(self, tree: Tree, node: ControlNode, now: float, actions: list[Action]) -> None:
        """``node`` fails or aborts: what has not started under it is revoked, running tasks
        get ``$abort``, control nodes under it end once their children have."""
        for n in tree.subtree(node)[1:]:
            if n.terminal:
                continue
            if isinstance(n, TaskNode):
                if n.sent:
                    self._signal_task(tree, n, Signal.ABORT, now, actions)
                else:
                    self._finish(tree, n, NodeStatus.REVOKED, now, actions)
            elif not n.turn:
                self._set(tree, n, NodeStatus.REVOKED, actions)
            else:
                assert isinstance(n, ControlNode)
                n.stopping = n.stopping or NodeStatus.ABORTED
                self._todo.append(("advance", tree, n.uuid, ""))

    def _signal_task(
        self, tree: Tree, node: TaskNode, signal: Signal | str, now: float,
        actions: list[Action],
    ) -> None:
        """Deliver a signal to one task node, whatever state it is in (docs/protocol.md §12.1);
        a task-specific one only to a task the unit may be running (`_task_signal_targets`)."""
        if node.terminal:
            return
        if node.hold_until is not None:  # failed already: only an abort changes it (ends it)
            if signal is Signal.ABORT:
                end, why = node.held_end
                self._finish(tree, node, end, now, actions, why, release=True)
            return
        if not isinstance(signal, Signal) and not node.sent:
            log.info("task %s: task-specific signal %r dropped: nothing runs", node.uuid, signal)
            return
        if not node.sent:
            # Not sent to the unit (not its turn yet, or waiting): the engine decides alone.
            if signal is Signal.ABORT:
                why = "aborted before it started"
                self._finish(tree, node, NodeStatus.ABORTED, now, actions, why)
            elif signal is Signal.ENOUGH:
                self._finish(tree, node, NodeStatus.REVOKED, now, actions, SKIPPED)
            elif signal is Signal.PAUSE:
                node.held = True
                if node.turn:
                    self._set(tree, node, NodeStatus.PAUSED, actions)
            elif signal is Signal.CONTINUE:
                node.held = False
                if node.turn and node.status is NodeStatus.PAUSED:
                    self._try_start(tree, node, now, actions)
            return
        node.held = signal is Signal.PAUSE or (node.held and signal is not Signal.CONTINUE)
        if not node.attempt.answered:
            node.pending.append(signal)  # delivered in order once the unit accepts the task
            return
        self._send_signal(node, signal, now, actions)

    def _send_signal(
        self, node: TaskNode, signal: Signal | str, now: float, actions: list[Action]
    ) -> None:
        """A ``signal-task`` with a fresh com-uuid, re-sent by `tick` until answered."""
        com = self.new_uuid()
        task_uuid = node.attempt.task_uuid
        self._signals[com] = _SignalOut(node.unit, task_uuid, signal, node.uuid, 1, now)
        node.signals.add(com)
        if signal is Signal.ABORT:
            node.abort_sent = True
        actions.append(SendSignal(node.unit, task_uuid, signal, com))

    def _deliver_pending(self, node: TaskNode, now: float, actions: list[Action]) -> None:
        """The unit has accepted the task: send the signals that arrived before it did."""
        pending, node.pending = node.pending, []
        for signal in pending:
            self._send_signal(node, signal, now, actions)

    def _abort_control(
        self, tree: Tree, node: ControlNode, now: float, actions: list[Action]
    ) -> None:
        """``$abort`` to a control node: it ends ``aborted`` once what runs under it stopped."""
        if not node.turn:
            for n in tree.subtree(node)[1:]:
                if not n.terminal:
                    self._set(tree, n, NodeStatus.REVOKED, actions)
            self._finish(tree, node, NodeStatus.ABORTED, now, actions, "aborted before it started")
            return
        if node.stopping is None:
            node.stopping = NodeStatus.ABORTED
            node.why = "aborted"
            self._stop(tree, node, now, actions)
        self._todo.append(("advance", tree, node.uuid, ""))

    def _enough_control(
        self, tree: Tree, node: ControlNode, whole: bool, now: float, actions: list[Action]
    ) -> None:
        """``$enough`` to a control node: nothing more starts under it (what has not started is
        revoked, not reported succeeded); with ``whole`` running tasks get ``$enough`` too."""
        for n in tree.subtree(node)[1:]:
            if n.terminal:
                continue
            if isinstance(n, TaskNode):
                if not n.sent:
                    self._finish(tree, n, NodeStatus.REVOKED, now, actions, SKIPPED)
                elif whole:
                    self._signal_task(tree, n, Signal.ENOUGH, now, actions)
            elif not n.turn:
                self._set(tree, n, NodeStatus.REVOKED, actions, SKIPPED)
            else:
                self._todo.append(("advance", tree, n.uuid, ""))
        if node.turn:
            self._todo.append(("advance", tree, node.uuid, ""))
        else:
            self._finish(tree, node, NodeStatus.REVOKED, now, actions, SKIPPED)

    def _hold_control(
        self,
        tree: Tree,
        node: ControlNode,
        signal: Signal,
        whole: bool,
        now: float,
        actions: list[Action],
    ) -> None:
        """``$pause``/``$continue`` to a control node: on the node alone it holds back (lets go)
        what would start under it; with ``whole`` every node under it gets the signal too."""
        pause = signal is Signal.PAUSE
        for n in tree.subtree(node) if whole else [node]:
            if n.terminal:
                continue
            n.held = pause
            if isinstance(n, TaskNode):
                if n.sent:
                    self._signal_task(tree, n, signal, now, actions)
                elif pause and n.turn:
                    self._set(tree, n, NodeStatus.PAUSED, actions)
            elif n.turn and n.status is not NodeStatus.NOT_ACTIVE:
                self._set(tree, n, NodeStatus.PAUSED if pause else NodeStatus.RUNNING, actions)
        if pause:
            return
        for n in tree.subtree(node):  # what the hold kept back starts (if nothing else holds it)
            if isinstance(n, TaskNode) and n.turn and not n.sent and n.status is NodeStatus.PAUSED:
                self._try_start(tree, n, now, actions)

    def _signal(self, node_uuid: str, signal: str, now: float, whole: bool) -> list[Action]:
        tree = self._tree_of(node_uuid)
        sig = self._check_signal(signal)
        node = tree.nodes[node_uuid]
        actions: list[Action] = []
        if node.terminal:
            return actions
        if not isinstance(sig, Signal):
            for task in self._task_signal_targets(tree, node, sig, whole):
                self._signal_task(tree, task, sig, now, actions)
            return actions
        if isinstance(node, TaskNode):
            self._signal_task(tree, node, sig, now, actions)
        else:
            assert isinstance(node, ControlNode)
            if sig is Signal.ABORT:
                self._abort_control(tree, node, now, actions)
            elif sig is Signal.ENOUGH:
                self._enough_control(tree, node, whole, now, actions)
            else:
                self._hold_control(tree, node, sig, whole, now, actions)
        self._drain(now, actions)
        return actions

    @staticmethod
    def _task_signal_targets(
        tree: Tree, node: ExecNode, name: str, whole: bool
    ) -> list[TaskNode]:
        """The task nodes a task-specific signal goes to (docs/protocol.md §12.1): the node
        itself, or with ``whole`` every task under it, whose start-task is out and that has not
        ended; `InputError` when there is none (the engine cannot act on one itself)."""
        if isinstance(node, TaskNode):
            if node.started:
                return [node]
            raise InputError(InputProblem(
                "node-uuid", "node-uuid", f"task-specific signal {name!r}: {node.name} "
                f"{node.uuid} has not started (only a running task can take it)"))
        targets = [n for n in tree.subtree(node) if isinstance(n, TaskNode) and n.started]
        if not whole:
            raise InputError(InputProblem(
                "node-uuid", "node-uuid", f"task-specific signal {name!r}: {node.name} "
                f"{node.uuid} is a control node (signal-tst-tree sends it to its running tasks)"))
        if not targets:
            raise InputError(InputProblem(
                "node-uuid", "node-uuid", f"task-specific signal {name!r}: no running task "
                f"under {node.name} {node.uuid}"))
        return targets

    def signal_node(self, node_uuid: str, signal: str, now: float) -> list[Action]:
        """``signal-tst-node``: the signal to this node alone (docs/protocol.md §12.2); raises
        `InputError` for an unknown node or signal."""
        return self._signal(node_uuid, signal, now, whole=False)

    def signal_tree(self, node_uuid: str, signal: str, now: float) -> list[Action]:
        """``signal-tst-tree``: the signal to the node and every node under it."""
        return self._signal(node_uuid, signal, now, whole=True)

    def signal_unit(self, unit: str, signal: str, now: float) -> list[Action]:
        """``signal-unit``: the signal to every running task node on ``unit``."""
        sig = self._check_signal(signal)
        name = unit.strip("/")
        actions: list[Action] = []
        for tree in list(self.trees.values()):
            for node in tree.tasks():
                if node.unit == name and node.started:
                    self._signal_task(tree, node, sig, now, actions)
        self._drain(now, actions)
        return actions

    def _tree_of(self, node_uuid: str) -> Tree:
        root = self._node_tree.get(node_uuid)
        if root is None or root not in self.trees:
            raise InputError(InputProblem(
                "node-uuid", "node-uuid", f"no executing node {node_uuid!r}"))
        return self.trees[root]

    @staticmethod
    def _check_signal(signal: str) -> Signal | str:
        """A built-in signal (``$...``: one of `SIGNALS`), or a task-specific name (seed 12.2.2:
        "Signal names starting with $ is system signals. Other names are specific for the
        task"), passed on to the task's unit as it is."""
        if signal.startswith("$"):
            try:
                return Signal(signal)
            except ValueError:
                raise InputError(InputProblem(
                    "signal", "signal", f"{signal!r} is not one of {', '.join(SIGNALS)} (names "
                    "without $ are task-specific)")) from None
        if not signal or len(signal) > 128 or not signal.isprintable() or signal.strip() != signal:
            raise InputError(InputProblem(
                "signal", "signal", f"{signal[:40]!r} is no signal name (1-128 printable "
                "characters, no leading or trailing space)"))
        return signal

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
        self._drain(now, actions)
        return actions

    def unit_rebooted(self, unit: str, now: float) -> list[Action]:
        """``unit``'s heartbeat carries a new ``agent-uuid``: it rebooted and lost its history
        (seed 12.1), so every task it accepted from us and that has not ended is gone: failed,
        naming the reboot (the service re-delegates them). A start-task not answered yet goes on
        being re-sent: the rebooted unit may take it now."""
        unit = unit.strip("/")
        actions: list[Action] = []
        why = f"/{unit} rebooted (a new agent-uuid in its heartbeat): the task it ran is gone"
        for tree in list(self.trees.values()):
            for node in tree.tasks():
                if node.unit == unit and node.started and node.attempt.answered:
                    self._finish(tree, node, NodeStatus.FAILED, now, actions, why)
        self._drain(now, actions)
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
        """A unit's ``exec/response`` to one of our start-tasks, signal-tasks or queries (others
        are ignored)."""
        asked = self._queries.pop(response_to, None)
        if asked is not None:
            return self._status_answer(asked, response, now)
        out = self._signals.pop(response_to, None)
        if out is not None:
            return self._signal_answer(response_to, out, response, fail_reason, now)
        found = self._task(self._com_node.get(response_to))
        if found is None or found[1].attempt.com_uuid != response_to:
            return []
        tree, node = found
        actions: list[Action] = []
        if node.terminal or node.attempt.answered or node.hold_until is not None:
            return actions
        node.attempt.answered = True
        if response in ("running", "started", "ok", "finished"):
            if node.status in (NodeStatus.ACTIVE, NodeStatus.WAITING):
                self._set(tree, node, NodeStatus.RUNNING, actions)
            if response == "finished":
                self._finish(tree, node, NodeStatus.SUCCEEDED, now, actions)
            else:
                self._deliver_pending(node, now, actions)
                if tree.resume and len(node.known_uuids) == 1:
                    # Maybe the answer to a start-task an earlier engine sent: the task may have
                    # ended since, its feedback heard by nobody. The unit knows.
                    actions.append(self._ask(node))
            self._drain(now, actions)
            return actions
        reason = fail_reason or f"{response}"
        if reason == BUSY_REASON and now - node.waiting_since < self.options.busy_timeout:
            # Busy with a task that is not ours: ask again later, with a fresh task-uuid.
            # The node keeps the unit, so this engine's own tasks for it stay queued behind.
            node.retry_at = now + self.options.busy_retry
            node.attempt.sends = 0
            node.refused.add(node.attempt.task_uuid)
            self._set(tree, node, NodeStatus.WAITING, actions)
            pending, node.pending = node.pending, []
            for signal in pending:  # nothing runs on the unit: the engine decides alone
                self._signal_task(tree, node, signal, now, actions)
        else:
            refused = f"/{node.unit} refused {node.name}: {reason}"
            self._finish(tree, node, NodeStatus.FAILED, now, actions, refused)
        self._drain(now, actions)
        return actions

    def _signal_answer(
        self, com: str, out: _SignalOut, response: str, fail_reason: str, now: float
    ) -> list[Action]:
        """A unit answered one of our signal-tasks: no more re-sends; a refusal is said in the
        node's fail-reason; an answered ``$abort`` waits for its ``aborted`` feedback."""
        found = self._task(out.node_uuid)
        if found is None or found[1].terminal:
            return []
        tree, node = found
        node.signals.discard(com)
        actions: list[Action] = []
        if out.signal is Signal.ABORT and node.abort_answered_at is None:
            node.abort_answered_at = now
        if response not in ("ok", "running", "paused", "finished", "aborted", "enough"):
            why = f"/{node.unit} refused {out.signal}: {fail_reason or response}"
            log.info("task %s: %s", out.task_uuid, why)
            self._set(tree, node, node.status, actions, why)
        return actions

    def on_feedback(self, task_uuid: str, status: str, now: float) -> list[Action]:
        """A unit's ``exec/feedback`` for one of our tasks (others are ignored)."""
        found = self._task(self._task_node.get(task_uuid))
        if found is None:
            return []
        tree, node = found
        actions: list[Action] = []
        if node.terminal or node.hold_until is not None:
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
            if mapped is NodeStatus.ABORTED and not node.abort_sent \
                    and Signal.ABORT not in node.pending:
                reason = f"/{node.unit} {UNIT_ABORTED}"  # nobody here asked it to
            self._finish(tree, node, mapped, now, actions, reason)
        else:
            self._set(tree, node, mapped, actions)
            self._deliver_pending(node, now, actions)
        self._drain(now, actions)
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
                if node.terminal or not node.sent or not node.attempt.answered \
                        or node.hold_until is not None:
                    continue
                if unit is not None and node.unit != unit:
                    continue
                actions.append(self._ask(node))
        if len(self._queries) > 10_000:  # unanswered queries (example agents never answer)
            for com in list(self._queries)[: len(self._queries) - 10_000]:
                del self._queries[com]
        return actions

    def _ask(self, node: TaskNode) -> SendQuery:
        """``query-status`` for the node's current task, its answer awaited."""
        com = self.new_uuid()
        self._queries[com] = node.attempt.task_uuid
        return SendQuery(node.unit, com, node.attempt.task_uuid)

    def tree_status(self, root_uuid: str) -> list[dict[str, str]] | None:
        """``query-tst``: every node of the tree ``root_uuid`` (parents first) with its status
        and fail-reason; None when no such tree is known (never started here, or forgotten)."""
        tree = self.trees.get(root_uuid)
        if tree is None:
            return None
        return [_shown(n) for n in tree.nodes.values()]

    def _status_answer(self, task_uuid: str, response: str, now: float) -> list[Action]:
        """A unit's answer to ``query-status`` in the seed's words (running, failed, success,
        unknown; older units answer with feedback words), applied as feedback: ``running`` says
        the task is still on, so a paused node stays paused; ``failed`` after our ``$abort`` is
        the abort done (the seed has no word for aborted)."""
        found = self._task(self._task_node.get(task_uuid))
        if response == "running":
            return []  # still on the unit, as the node says (running or paused)
        if response == "failed" and found is not None and found[1].abort_sent:
            response = "aborted"
        if response != "unknown":
            return self.on_feedback(task_uuid, response, now)
        if found is None or found[1].terminal or found[1].attempt.task_uuid != task_uuid:
            return []
        tree, node = found
        actions: list[Action] = []
        why = f"/{node.unit} no longer knows task {task_uuid} (query-status after an outage)"
        self._finish(tree, node, NodeStatus.FAILED, now, actions, why)
        self._drain(now, actions)
        return actions

    # ---- re-binding tasks to other units (the service's repairs, docs/protocol.md §12.6)

    def rebind(self, execunits: dict[str, str], now: float,
               subtrees: dict[str, TstNode] | None = None) -> list[Action]:
        """``rebind-tst-nodes``: each task node (uuid -> ``/unit``) runs on another unit from now
        on, in the same tree: one not started yet starts there when its turn comes; one waiting
        or running on its old unit is started again on the new one (the old unit, which may
        still fly it, is sent ``$abort`` for its old task-uuid, whose messages are ignored from
        then). ``subtrees`` (uuid -> a fully instantiated tree whose root has that uuid or none)
        replace task nodes the same way: the old task is stopped on its unit and the subtree
        runs in its place (a lost unit's unswept remainder of a search shared among live
        units). The rest of the tree is not touched. All or nothing: raises `InputError` naming
        every node that cannot be re-bound (unknown, not a task, already ended, not a unit, a
        subtree not instantiated or reusing a known node uuid)."""
        subtrees = subtrees or {}
        problems: list[InputProblem] = []
        found: list[tuple[Tree, TaskNode, str]] = []
        for uid, execunit in execunits.items():
            at = self._rebindable(uid, f"execunits.{uid}", problems)
            unit = self._unit_named(at[1], uid, execunit, problems) if at else ""
            if at and unit:
                found.append((at[0], at[1], unit))
        grafts: list[tuple[Tree, TaskNode, TstNode]] = []
        for uid, raw in subtrees.items():
            if uid in execunits:
                problems.append(InputProblem("subtrees", f"subtrees.{uid}", "also in execunits"))
                continue
            at = self._rebindable(uid, f"subtrees.{uid}", problems)
            sub = self._graftable(at[1], uid, raw, problems) if at else None
            if at and sub is not None:
                grafts.append((at[0], at[1], sub))
        if problems:
            raise InputError(problems)
        actions: list[Action] = []
        freed: list[str] = []
        for tree, node, unit in found:
            if unit != node.unit:
                freed += self._rebind_task(tree, node, unit, now, actions)
        for tree, node, sub in grafts:
            freed += self._graft(tree, node, sub, now, actions)
        for old in freed:  # its next queued task (if any) may start on it now
            self._wake(old, now, actions)
        self._drain(now, actions)
        return actions

    def _rebindable(self, uid: str, field_name: str, problems: list[InputProblem]
                    ) -> tuple[Tree, TaskNode] | None:
        """The executing task node ``uid`` that has not ended, else None (the problem noted)."""
        tree = self.trees.get(self._node_tree.get(uid, ""))
        node = tree.nodes.get(uid) if tree is not None else None
        if tree is None or node is None:
            problems.append(InputProblem("execunits", field_name, "no executing node"))
        elif not isinstance(node, TaskNode):
            problems.append(InputProblem(node.path, field_name, "not a task node"))
        elif node.terminal:
            problems.append(InputProblem(node.path, field_name,
                                         f"already ended ({node.status.value})"))
        else:
            return tree, node
        return None

    @staticmethod
    def _unit_named(node: TaskNode, uid: str, execunit: object,
                    problems: list[InputProblem]) -> str:
        """The unit name of ``/name``, else "" (the problem noted)."""
        unit = execunit.strip("/") if isinstance(execunit, str) else ""
        if not isinstance(execunit, str) or not execunit.startswith("/") or not unit \
                or "/" in unit:
            problems.append(InputProblem(node.path, f"execunits.{uid}",
                                         f"{execunit!r} is not a unit (/name)"))
            return ""
        return unit

    def _graftable(self, node: TaskNode, uid: str, sub: TstNode,
                   problems: list[InputProblem]) -> TstNode | None:
        """``sub`` with ``uid`` as its root's uuid, its other nodes given uuids, if it can run
        in the task's place: instantiated, its root ``uid`` (or none), no uuid already known."""
        field_name = f"subtrees.{uid}"
        if sub.node_uuid not in (None, uid):
            problems.append(InputProblem(node.path, field_name,
                                         f"its root's node-uuid is {sub.node_uuid}, not {uid}"))
            return None
        sub = with_uuids(sub.with_common_values({"node-uuid": uid}), self.new_uuid)
        mine = [InputProblem(node.path + q.where.removeprefix("root"),
                             f"{field_name}.{q.field}", q.message)
                for q in check_instantiated(sub)]
        for path, n in walk(sub):
            if n.node_uuid != uid and n.node_uuid in self._node_tree:
                mine.append(InputProblem(f"{node.path}{path[len('root'):]}", field_name,
                                         f"node-uuid {n.node_uuid} is already executing"))
        problems += mine
        return None if mine else sub

    def _graft(self, tree: Tree, node: TaskNode, sub: TstNode, now: float,
               actions: list[Action]) -> list[str]:
        """Run ``sub`` (root uuid = the node's) in the task node's place; the task is stopped on
        its unit as by a move. The old unit's name if the node occupied it."""
        released = self._detach(node, now, actions)
        part = build_tree(sub, now, tree.run, tree.resume)
        for uid, new in part.nodes.items():
            new.path = node.path + new.path[len("root"):]
            if uid == node.uuid:
                new.parent, new.turn, new.held = node.parent, False, node.held
            tree.nodes[uid] = new
            self._node_tree[uid] = tree.root_uuid
        log.info("task %s (%s) on /%s replaced by a %s of %d node(s)", node.uuid, node.path,
                 node.unit, sub.name, len(part.nodes))
        if node.turn:
            self._activate(tree, tree.nodes[node.uuid], now, actions)
        return [node.unit] if released else []

    def _detach(self, node: TaskNode, now: float, actions: list[Action]) -> bool:
        """Take the node off its unit: ``$abort`` for what it was sent (its answer or giving up
        changes nothing), its ids forgotten. True if it occupied the unit."""
        old = node.unit
        queue = self._queue.get(old)
        if queue and node.uuid in queue:
            queue.remove(node.uuid)
        if node.sent and node.hold_until is None:
            # Detached from the node (no node uuid): its answer or its giving up changes nothing.
            com = self.new_uuid()
            self._signals[com] = _SignalOut(old, node.attempt.task_uuid, Signal.ABORT, "", 1, now)
            actions.append(SendSignal(old, node.attempt.task_uuid, Signal.ABORT, com))
        for com in node.signals:
            self._signals.pop(com, None)
        for task_uuid in node.known_uuids:
            self._task_node.pop(task_uuid, None)
        for com in node.known_coms:
            self._com_node.pop(com, None)
        for kept in (node.signals, node.known_uuids, node.known_coms, node.refused):
            kept.clear()
        node.pending.clear()
        node.attempt = TaskAttempt()
        node.retry_at = None
        node.abort_sent = False
        node.abort_answered_at = None
        node.hold_until = None
        node.moves += 1
        released = node.vehicle and self._occupant.get(old) == node.uuid
        if released:
            del self._occupant[old]
        return released

    def _rebind_task(
        self, tree: Tree, node: TaskNode, unit: str, now: float, actions: list[Action]
    ) -> list[str]:
        """Move one task node to ``unit``; the old unit's name if the node occupied it."""
        old = node.unit
        released = self._detach(node, now, actions)
        node.unit = unit
        log.info("task %s (%s) re-bound from /%s to /%s", node.uuid, node.path, old, unit)
        if node.turn:
            node.waiting_since = now
            self._try_start(tree, node, now, actions)
        return [old] if released else []

    # ---- time

    def tick(self, now: float) -> list[Action]:
        """Re-send unanswered start-tasks and signal-tasks, retry busy units, time out units
        never seen."""
        actions: list[Action] = []
        self._tick_signals(now, actions)
        for tree in list(self.trees.values()):
            if tree.done:
                continue
            for node in tree.tasks():
                if not node.terminal:
                    self._tick_task(tree, node, now, actions)
        self._drain(now, actions)
        return actions

    def _tick_signals(self, now: float, actions: list[Action]) -> None:
        """Re-send each unanswered signal-task (same com-uuid) every ``resend_after`` s; after
        ``max_attempts`` sends give up, saying so in the node's fail-reason."""
        opts = self.options
        for com, out in list(self._signals.items()):
            if now - out.sent_at < opts.resend_after:
                continue
            if out.sends < opts.max_attempts:
                out.sends += 1
                out.sent_at = now
                actions.append(SendSignal(out.unit, out.task_uuid, out.signal, com))
                continue
            del self._signals[com]
            why = f"/{out.unit} did not answer {out.signal} ({out.sends} attempts)"
            log.warning("task %s: %s", out.task_uuid, why)
            found = self._task(out.node_uuid)
            if found is None or found[1].terminal:
                continue
            tree, node = found
            node.signals.discard(com)
            if out.signal is Signal.ABORT:
                why += "; it may still be running the task"
                self._finish(tree, node, NodeStatus.ABORTED, now, actions, why)
            else:
                self._set(tree, node, node.status, actions, why)

    def _tick_task(self, tree: Tree, node: TaskNode, now: float, actions: list[Action]) -> None:
        if node.hold_until is not None:
            if now >= node.hold_until:  # no rebind came: its branch learns the end now
                end, why = node.held_end
                log.info("task %s (%s): no rebind within %g s", node.uuid, node.path,
                         tree.hold_failed)
                self._finish(tree, node, end, now, actions, why, release=True)
            return
        opts = self.options
        attempt = node.attempt
        answered = node.abort_answered_at
        if answered is not None and now - answered >= opts.abort_timeout:
            why = f"/{node.unit} did not confirm $abort within {opts.abort_timeout:g} s"
            self._finish(tree, node, NodeStatus.ABORTED, now, actions, why)
        elif node.sent and not attempt.answered:
            if now - attempt.sent_at < opts.resend_after:
                return
            if attempt.sends >= opts.max_attempts:
                # The unit may have got it and be running it: tell it to stop.
                why = (f"/{node.unit} did not answer start-task ({attempt.sends} attempts); "
                       "$abort sent")
                self._finish(tree, node, NodeStatus.FAILED, now, actions, why)
                self._send_signal(node, Signal.ABORT, now, actions)
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


def _shown(node: ExecNode) -> dict[str, str]:
    """A node as ``query-tst`` shows it: a held task (§12.7) with the end it was reported."""
    if isinstance(node, TaskNode) and node.hold_until is not None:
        return {"node-uuid": node.uuid, "status": node.held_end[0].value,
                "fail-reason": node.held_end[1]}
    return {"node-uuid": node.uuid, "status": node.status.value, "fail-reason": node.fail_reason}
