"""Direct Execution API (seed section 12): commands to a unit, its responses and task feedback."""

from __future__ import annotations

from enum import StrEnum
from typing import Any, Literal

from pydantic import Field

from delegation.messages.base import Answer, Command, WireModel, new_com_uuid


class TaskStatus(StrEnum):
    """Task feedback statuses (seed 12.4, plus ``enough`` sent by the public example agent).

    Feedback may also carry task-specific strings, so models keep ``status`` a plain ``str``.
    """

    STARTING = "starting"
    RUNNING = "running"
    PAUSED = "paused"
    FINISHED = "finished"
    FAILED = "failed"
    ABORTED = "aborted"
    ENOUGH = "enough"


class Signal(StrEnum):
    """The built-in signals (seed 12.2.2) to a task, a tree node or a unit; other names are task
    specific."""

    ENOUGH = "$enough"
    """Stop as soon as it makes sense, and count it as success (open-ended tasks)."""
    PAUSE = "$pause"
    """Hold still; nothing new starts until ``$continue``."""
    CONTINUE = "$continue"
    """Go on after a ``$pause``."""
    ABORT = "$abort"
    """Stop now: running tasks end ``aborted``, what has not started is revoked."""


#: The built-in signals' names, in `Signal`'s order.
SIGNALS: tuple[str, ...] = tuple(s.value for s in Signal)


class Ping(Command):
    """``ping``: answered with ``pong`` (seed 12.2.1; also accepted on tst and delegation)."""

    command: Literal["ping"] = "ping"


class TaskSpecMsg(WireModel):
    """The ``task`` of a ``start-task``: a task name and its raw params (kept verbatim)."""

    name: str
    params: dict[str, Any] = Field(default_factory=dict)


class StartTask(Command):
    """``start-task`` (seed 10): run one task on ``execution-unit``."""

    command: Literal["start-task"] = "start-task"
    execution_unit: str
    task: TaskSpecMsg
    task_uuid: str | None = None


class SignalTask(Command):
    """``signal-task`` (seed 12.2.2): ``$abort``, ``$enough``, ``$pause``, ``$continue`` or a
    task-specific signal."""

    command: Literal["signal-task"] = "signal-task"
    signal: str
    task_uuid: str


class SignalExecutor(Command):
    """``signal-executor`` (seed 12.2.2's second example): a signal to the executor itself."""

    command: Literal["signal-executor"] = "signal-executor"
    signal: str
    uuid: str | None = None


class QueryStatus(Command):
    """``query-status`` (seed 12.1): the status of a task (running, failed, success, unknown)."""

    command: Literal["query-status"] = "query-status"
    task_uuid: str


class ExecResponse(Answer):
    """A unit's answer on ``exec/response`` (seed 12.3): ``pong``, ``running``, ``failed``, ...

    ``fail-reason`` is always written except on ``pong``, which the seed shows without it.
    """

    agent_uuid: str = ""
    task_uuid: str | None = None

    def omit_when_empty(self) -> frozenset[str]:
        return frozenset({"fail-reason"}) if self.response == "pong" else frozenset()


class ExecFeedback(WireModel):
    """Task status updates on ``exec/feedback`` (seed 12.4)."""

    agent_uuid: str = ""
    com_uuid: str = Field(default_factory=new_com_uuid)
    status: str
    task_uuid: str
