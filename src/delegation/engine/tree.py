"""An executing tree's state: what every node shares, what a ``seq``/``conc`` adds
(`ControlNode`), what a task adds (`TaskNode` and its current `TaskAttempt`).

Pure data plus its construction from a parsed tree; `delegation.engine.executor` decides what
happens to it.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from delegation.errors import InputProblem
from delegation.messages import TERMINAL_NODE_STATUSES, NodeStatus, Signal
from delegation.tst.catalogue import is_vehicle_task
from delegation.tst.node import ExecUnitKind, TstNode, classify_execunit, walk, where

__all__ = [
    "ControlNode",
    "ExecNode",
    "TaskAttempt",
    "TaskNode",
    "Tree",
    "build_tree",
    "check_instantiated",
]


@dataclass(slots=True, kw_only=True)
class ExecNode:
    """What every node of an executing tree has: where it is and its status."""

    uuid: str
    name: str
    path: str
    parent: str | None
    children: list[str]
    params: dict[str, Any]
    status: NodeStatus = NodeStatus.NOT_ACTIVE
    fail_reason: str = ""
    turn: bool = False
    """Its parent has activated it (its turn came); a node ended before its turn is skipped or
    noted by its parent when the turn would have come (docs/protocol.md §12)."""
    held: bool = False
    """``$pause`` remembered: start nothing (more) here until ``$continue``."""

    @property
    def terminal(self) -> bool:
        return self.status in TERMINAL_NODE_STATUSES


@dataclass(slots=True, kw_only=True)
class ControlNode(ExecNode):
    """A ``seq`` or ``conc``: which child is next, how many ended, and how it will end."""

    cursor: int = 0
    """``seq``: the child whose turn it is (``len(children)`` once past the last)."""
    opened: bool = False
    """``conc``: its children were activated."""
    ended: int = 0
    """How many children reached a final status."""
    stopping: NodeStatus | None = None
    """Failing or aborting: the status it ends with once its children have ended."""
    outcome: NodeStatus | None = None
    """``conc``: a child was aborted; the others go on and it ends with this status."""
    why: str = ""
    """The fail-reason it will end with (``stopping`` or ``outcome``)."""

    @property
    def is_seq(self) -> bool:
        return self.name != "conc"


@dataclass(slots=True)
class TaskAttempt:
    """The start-task currently out for a task: re-sent with the same ids until answered."""

    task_uuid: str = ""
    com_uuid: str = ""
    sends: int = 0
    """How often it was sent; 0 while nothing is out (not started, or refused by a busy unit)."""
    sent_at: float = 0.0
    answered: bool = False


@dataclass(slots=True, kw_only=True)
class TaskNode(ExecNode):
    """A task on one unit: its current attempt and what the unit may still report about."""

    unit: str
    """The unit's name (no slash)."""
    vehicle: bool
    """Moves the vehicle: the unit runs one such task at a time."""
    attempt: TaskAttempt = field(default_factory=TaskAttempt)
    waiting_since: float = 0.0
    retry_at: float | None = None
    """A busy unit refused: ask again (with fresh ids) at this time."""
    abort_sent: bool = False
    """``$abort`` went out to the unit."""
    abort_answered_at: float | None = None
    """The unit answered our ``$abort``: its ``aborted`` feedback is awaited from then."""
    pending: list[Signal | str] = field(default_factory=list)
    """Signals that arrived before the unit answered the start-task, in order."""
    signals: set[str] = field(default_factory=set)
    """Com-uuids of this node's signal-tasks still out (unanswered)."""
    known_uuids: set[str] = field(default_factory=set)
    """Every task-uuid sent for this node (the unit may run an earlier one after all)."""
    known_coms: set[str] = field(default_factory=set)
    refused: set[str] = field(default_factory=set)
    """Task-uuids a busy unit refused."""
    moves: int = 0
    """How often it was moved to another unit (its start-task ids differ per move)."""
    hold_until: float | None = None
    """Failed (reported), its branch not told until then: waiting for a rebind (§12.7)."""
    held_end: tuple[NodeStatus, str] = (NodeStatus.FAILED, "")
    """The status and fail-reason reported while held (its end when the hold runs out)."""

    @property
    def sent(self) -> bool:
        """A start-task is out (it may be re-sent, or answered)."""
        return self.attempt.sends > 0

    @property
    def started(self) -> bool:
        """A task the unit may be executing (start-task sent and not ended)."""
        return self.sent and not self.terminal


@dataclass
class Tree:
    """One executing tree, its nodes by uuid (parents before children)."""

    root_uuid: str
    nodes: dict[str, ExecNode]
    started_at: float
    run: str = ""
    """What makes this execution's start-task ids (the start-tst's com-uuid): the same tree sent
    again with the same com-uuid to a restarted engine re-sends the same start-tasks, which a
    unit answers again instead of running them again (seed 12). ``""``: random ids."""
    resume: bool = False
    """The unfinished part of a tree an earlier engine ran: each task is asked ``query-status``
    once its start-task is answered (it may have ended while no engine listened)."""
    hold_failed: float = 0.0
    """Seconds a failed task is held for a rebind before its branch is told (§12.7); 0: never."""

    @property
    def root(self) -> ExecNode:
        return self.nodes[self.root_uuid]

    @property
    def done(self) -> bool:
        return self.root.terminal

    def parent(self, node: ExecNode) -> ControlNode | None:
        """The node's parent (always a control node), or None for the root."""
        if node.parent is None:
            return None
        parent = self.nodes[node.parent]
        assert isinstance(parent, ControlNode), "only control nodes have children"
        return parent

    def children(self, node: ExecNode) -> list[ExecNode]:
        return [self.nodes[uid] for uid in node.children]

    def tasks(self) -> Iterator[TaskNode]:
        """The task nodes, in tree order."""
        return (n for n in list(self.nodes.values()) if isinstance(n, TaskNode))

    def subtree(self, node: ExecNode) -> list[ExecNode]:
        """``node`` and every node under it, depth first in tree order."""
        out, stack = [], [node.uuid]
        while stack:
            uid = stack.pop()
            out.append(self.nodes[uid])
            stack.extend(reversed(self.nodes[uid].children))
        return out

    def ancestors(self, node: ExecNode) -> Iterator[ControlNode]:
        parent = self.parent(node)
        while parent is not None:
            yield parent
            parent = self.parent(parent)


def check_instantiated(root: TstNode) -> list[InputProblem]:
    """Why a (parsed) tree is not fully instantiated: every task node needs ``/unit``."""
    problems: list[InputProblem] = []
    for path, node in walk(root):
        try:
            kind, _ = classify_execunit(node.execunit)
        except TypeError as exc:
            problems.append(InputProblem(
                where(path, node), f"{node.common_key}.execunit", str(exc)))
            continue
        if node.is_control:
            if node.execunit not in (None, "") and kind is not ExecUnitKind.FIXED:
                problems.append(
                    InputProblem(
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
                InputProblem(
                    where(path, node),
                    f"{node.common_key}.execunit",
                    f"{shown} is not a unit: the engine runs fully instantiated trees only "
                    "(every task names its unit as /name)",
                )
            )
    return problems


def build_tree(root: TstNode, now: float, run: str = "", resume: bool = False) -> Tree:
    """The executing state of a checked tree (every node has a uuid, every task a unit)."""
    nodes: dict[str, ExecNode] = {}
    parents: dict[int, str] = {}
    for path, node in walk(root):
        uid = node.node_uuid or ""
        shared: dict[str, Any] = {
            "uuid": uid,
            "name": node.name,
            "path": path,
            "parent": parents.get(id(node)),
            "children": [c.node_uuid or "" for c in node.children],
            "params": dict(node.params),
        }
        if node.is_control:
            nodes[uid] = ControlNode(**shared)
        else:
            _, unit = classify_execunit(node.execunit)
            nodes[uid] = TaskNode(**shared, unit=unit, vehicle=is_vehicle_task(node.name))
        for child in node.children:
            parents[id(child)] = uid
    return Tree(root.node_uuid or "", nodes, now, run, resume)
