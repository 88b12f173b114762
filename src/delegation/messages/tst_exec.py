"""TST Execution API (seed section 14): start and signal trees, responses, node feedback.

``start-tst`` keeps its ``tst`` as raw JSON so that unknown fields survive forwarding; parse it with
``delegation.tst.parse_and_validate``.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any, Literal

from pydantic import Field

from delegation.messages.base import Answer, Command, WireModel, new_com_uuid


class NodeStatus(StrEnum):
    """TST node statuses (seed 14.5)."""

    NOT_ACTIVE = "not-active"
    ACTIVE = "active"
    WAITING = "waiting"
    RUNNING = "running"
    PAUSED = "paused"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    ABORTED = "aborted"
    REVOKED = "revoked"


#: The end of a task node's fail-reason (after ``/unit``) when the unit aborted the task without
#: being asked to (its own operator, its own safety rules): the delegation service re-delegates
#: it (docs/protocol.md §11, §12.3).
UNIT_ABORTED = "aborted the task itself (not asked to)"

#: Statuses after which a node never changes again.
TERMINAL_NODE_STATUSES: frozenset[NodeStatus] = frozenset(
    {NodeStatus.SUCCEEDED, NodeStatus.FAILED, NodeStatus.ABORTED, NodeStatus.REVOKED}
)


class StartTst(Command):
    """``start-tst`` (seed 11): execute a tree (fully instantiated for an engine, partially for a
    delegator)."""

    command: Literal["start-tst"] = "start-tst"
    receiver: str | None = None
    tst: dict[str, Any]
    #: Our extension (docs/protocol.md §12.5): the tree is the unfinished part of one an earlier
    #: instance of the engine executed; its tasks may be running or done on their units already,
    #: so each is asked ``query-status`` once its re-sent start-task is answered. Other engines
    #: ignore the field.
    resume: bool | None = None
    #: Our extension (docs/protocol.md §12.7): a task of this tree that fails (or that its unit
    #: aborts unasked) is reported ``failed``/``aborted`` but held, its branch not stopped, for
    #: this many seconds, waiting for a ``rebind-tst-nodes`` of it; then its branch fails as
    #: usual. An engine that holds says so in its ``started`` answer. Others ignore the field.
    hold_failed: float | None = Field(default=None, ge=0.0)


class _NodeSignal(Command):
    """A signal to the node ``node-uuid`` (the seed's 14.3.1 and 14.3.2 carry the same fields and
    differ in how far the signal reaches: the subclasses)."""

    command: str
    node_uuid: str
    signal: str


class SignalTstNode(_NodeSignal):
    """``signal-tst-node`` (seed 14.3.1): a signal to one node."""

    command: Literal["signal-tst-node"] = "signal-tst-node"


class SignalTstTree(_NodeSignal):
    """``signal-tst-tree`` (seed 14.3.2): a signal to every node of the tree under ``node-uuid``."""

    command: Literal["signal-tst-tree"] = "signal-tst-tree"


class SignalUnit(Command):
    """``signal-unit`` (seed 14.3.3): a signal to every running node on ``unit`` (``/dji21``)."""

    command: Literal["signal-unit"] = "signal-unit"
    signal: str
    unit: str


class RebindTstNodes(Command):
    """``rebind-tst-nodes`` (ours, not the seed's; docs/protocol.md §12.6): task nodes of an
    executing tree run on other units from now on (``execunits``: node uuid -> ``/unit``), the
    rest of the tree untouched. How the delegation service moves a lost unit's tasks."""

    command: Literal["rebind-tst-nodes"] = "rebind-tst-nodes"
    execunits: dict[str, str]
    #: Task node uuid -> a fully instantiated tree run in its place (its root has that uuid):
    #: a lost unit's unswept remainder of a shared search, shared again among live units.
    subtrees: dict[str, dict[str, Any]] | None = None


class QueryTst(Command):
    """``query-tst``: our extension of the TST API (docs/protocol.md §12.5): the status of every
    node of the tree whose root is ``node-uuid``, answered ``ok`` with ``nodes``, or ``unknown``
    when the engine does not know the tree (never started there, or forgotten: restarted)."""

    command: Literal["query-tst"] = "query-tst"
    node_uuid: str


class TstResponse(Answer):
    """The answer on ``tst/response`` (seed 14.4): ``ok``, ``started`` (with ``root-uuid``),
    ``failed`` (with ``fail-reason``), ``pong``.

    The seed writes ``fail-reason`` on ``started``/``failed`` and leaves it out of ``ok``/``pong``.
    """

    root_uuid: str | None = None
    #: The answer to ``query-tst``: every node of the tree, parents before children, each
    #: ``{"node-uuid", "status", "fail-reason"}``.
    nodes: list[dict[str, Any]] | None = None
    #: The ``started`` answer of an engine that holds failed tasks (``StartTst.hold_failed``).
    hold_failed: float | None = None

    def omit_when_empty(self) -> frozenset[str]:
        if self.response in ("ok", "pong"):
            return frozenset({"fail-reason"})
        return frozenset()


class TstFeedback(WireModel):
    """Node status updates on ``tst/feedback`` (seed 14.5)."""

    com_uuid: str = Field(default_factory=new_com_uuid)
    fail_reason: str = ""
    node_uuid: str
    root_flag: bool = False
    status: str
