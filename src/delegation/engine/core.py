"""The reference TST engine (``op0``) on MQTT: the seed's TST Execution API (section 14).

A thin unit around `delegation.engine.executor.TreeExecutor`: it reads ``tst/command``
(``start-tst`` for fully instantiated trees, ``signal-tst-node``, ``signal-tst-tree``,
``signal-unit``, ``ping``), every unit's heartbeat (to learn base topics) and
``exec/response``/``exec/feedback``;
it publishes ``tst/response``, ``tst/feedback`` for every node status change, ``start-task`` and
``signal-task`` to the units, and its own ``heartbeat`` (levels ``["tst execution"]``) and
``tst_execution_info``. A command re-sent with the same com-uuid gets the same answer again.
"""

from __future__ import annotations

import logging
import threading
import time
import uuid
from collections.abc import Callable, Iterable
from typing import Any

from delegation.engine.executor import (
    Action,
    EngineOptions,
    NodeChanged,
    SendSignal,
    SendStartTask,
    TreeExecutor,
)
from delegation.errors import InputError
from delegation.messages import (
    ExecFeedback,
    ExecResponse,
    HeartBeat,
    MessageError,
    Ping,
    SignalTask,
    SignalTstNode,
    SignalTstTree,
    SignalUnit,
    StartTask,
    StartTst,
    TaskSpecMsg,
    TstExecutionInfo,
    TstFeedback,
    TstResponse,
    decode,
    encode,
)
from delegation.messages.answers import AnswerCache, com_uuid_of
from delegation.runtime.mqtt import Message
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.unit import MqttUnit
from delegation.topics import (
    DEFAULT_PREFIX,
    QOS_COMMAND,
    QOS_PERIODIC,
    parse_unit_topic,
    unit_base_topic,
    unit_filter,
)
from delegation.tst.node import parse_tree

log = logging.getLogger(__name__)


class TstEngine(MqttUnit):
    """The TST engine unit. ``core_options`` are passed to `EngineCore` (timeouts, retries)."""

    def __init__(
        self,
        settings: BrokerSettings,
        name: str = "op0",
        *,
        prefix: str = DEFAULT_PREFIX,
        agent_type: str = "ground",
        role: str = "simulation",
        rate: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        tick_interval: float = 0.1,
        **core_options: Any,
    ) -> None:
        super().__init__(settings, name, tick_interval=tick_interval, clock=clock)
        self.prefix = prefix
        self.agent_type = agent_type
        self.rate = rate
        self.wall = wall
        self.base = unit_base_topic(name, agent_type, role, prefix)
        self.core = TreeExecutor(EngineOptions(**core_options))
        self.bases: dict[str, str] = {}
        self.agent_uuid = ""
        self._answers = AnswerCache()
        self._next_info = 0.0
        self._seen = threading.Condition()

    def wait_for_units(self, names: Iterable[str], timeout: float) -> bool:
        """Block until the engine has heard a heartbeat of every unit in ``names``."""
        wanted = {n.strip("/") for n in names}
        with self._seen:
            return self._seen.wait_for(lambda: wanted <= set(self.bases), timeout)

    # ---- MqttUnit hooks

    def subscriptions(self) -> list[str]:
        return [
            f"{self.base}/tst/command",
            unit_filter(self.prefix, "heartbeat"),
            unit_filter(self.prefix, "exec/response"),
            unit_filter(self.prefix, "exec/feedback"),
        ]

    def on_start(self) -> None:
        self.agent_uuid = str(uuid.uuid4())
        self._publish_info()
        self._next_info = self.clock() + 1.0 / self.rate

    def tick(self, now: float) -> None:
        self._carry_out(self.core.tick(now))
        if now >= self._next_info:
            self._publish_info()
            self._next_info = max(self._next_info + 1.0 / self.rate, now)

    def handle(self, message: Message) -> None:
        now = self.clock()
        parsed = parse_unit_topic(message.topic)
        if parsed is None:
            return
        if parsed.rest == "heartbeat":
            if self.bases.get(parsed.name) != parsed.base:
                with self._seen:
                    self.bases[parsed.name] = parsed.base
                    self._seen.notify_all()
            self._carry_out(self.core.unit_seen(parsed.name, now))
        elif parsed.rest == "tst/command" and parsed.base == self.base:
            self._command(message, now)
        elif parsed.rest in ("exec/response", "exec/feedback"):
            self._from_unit(message, now)

    # ---- tst/command

    def _command(self, message: Message, now: float) -> None:
        com_uuid = com_uuid_of(message.payload)
        previous = self._answers.get(com_uuid)
        if previous is not None:
            log.debug("%s: re-sent command %s answered again", self.name, com_uuid)
            self.publish(f"{self.base}/tst/response", previous, qos=QOS_COMMAND)
            return
        try:
            command = decode(message.topic, message.payload)
        except MessageError as exc:
            log.warning("%s: bad command: %s", self.name, exc)
            if com_uuid is not None:
                self._respond(com_uuid, "failed", fail_reason=exc.fail_reason)
            return
        actions: list[Action] = []
        try:
            if isinstance(command, Ping):
                self._respond(command.com_uuid, "pong")
                return
            if isinstance(command, StartTst):
                root_uuid, actions = self.core.start_tree(parse_tree(command.tst), now)
                log.info("%s: executing tree %s", self.name, root_uuid)
                self._respond(command.com_uuid, "started", root_uuid=root_uuid)
            elif isinstance(command, SignalTstNode):
                actions = self.core.signal_node(command.node_uuid, command.signal, now)
                self._respond(command.com_uuid, "ok")
            elif isinstance(command, SignalTstTree):
                actions = self.core.signal_tree(command.node_uuid, command.signal, now)
                self._respond(command.com_uuid, "ok")
            elif isinstance(command, SignalUnit):
                actions = self.core.signal_unit(command.unit, command.signal, now)
                self._respond(command.com_uuid, "ok")
            else:
                name = getattr(command, "command", type(command).__name__)
                self._respond(
                    getattr(command, "com_uuid", com_uuid or ""),
                    "failed",
                    fail_reason=f"{name} is not supported by the TST engine",
                )
        except InputError as exc:
            self._respond(getattr(command, "com_uuid", ""), "failed", fail_reason=exc.fail_reason)
            return
        self._carry_out(actions)

    def _respond(
        self, com_uuid: str, response: str, fail_reason: str = "", root_uuid: str | None = None
    ) -> None:
        answer = TstResponse(
            fail_reason=fail_reason, response=response, response_to=com_uuid, root_uuid=root_uuid
        )
        data = encode(answer)
        self._answers.put(com_uuid, data)
        self.publish(f"{self.base}/tst/response", data, qos=QOS_COMMAND)

    # ---- from the units

    def _from_unit(self, message: Message, now: float) -> None:
        """A unit's ``exec/response`` or ``exec/feedback``, handed to the core."""
        try:
            msg = decode(message.topic, message.payload)
        except MessageError as exc:
            log.debug("%s: unreadable message on %s: %s", self.name, message.topic, exc)
            return
        if isinstance(msg, ExecResponse):
            self._carry_out(
                self.core.on_response(
                    msg.response_to,
                    msg.response,
                    now,
                    fail_reason=msg.fail_reason,
                    task_uuid=msg.task_uuid,
                )
            )
        elif isinstance(msg, ExecFeedback):
            self._carry_out(self.core.on_feedback(msg.task_uuid, msg.status, now))

    # ---- actions

    def _carry_out(self, actions: list[Action]) -> None:
        for action in actions:
            if isinstance(action, NodeChanged):
                feedback = TstFeedback(
                    fail_reason=action.fail_reason,
                    node_uuid=action.node_uuid,
                    root_flag=action.root_flag,
                    status=action.status.value,
                )
                self.publish(f"{self.base}/tst/feedback", encode(feedback), qos=QOS_COMMAND)
                if action.root_flag and action.status.value in ("succeeded", "failed", "aborted"):
                    log.info("%s: tree %s %s", self.name, action.root_uuid, action.status.value)
            elif isinstance(action, SendStartTask):
                base = self.bases.get(action.unit)
                if base is None:  # the core starts tasks only on units it has seen
                    log.error("%s: no base topic for /%s", self.name, action.unit)
                    continue
                start = StartTask(
                    com_uuid=action.com_uuid,
                    execution_unit=f"/{action.unit}",
                    sender=self.name,
                    task=TaskSpecMsg(name=action.name, params=action.params),
                    task_uuid=action.task_uuid,
                )
                self.publish(f"{base}/exec/command", encode(start), qos=QOS_COMMAND)
            elif isinstance(action, SendSignal):
                base = self.bases.get(action.unit)
                if base is None:
                    continue
                signal = SignalTask(
                    signal=action.signal, sender=self.name, task_uuid=action.task_uuid
                )
                self.publish(f"{base}/exec/command", encode(signal), qos=QOS_COMMAND)

    def _publish_info(self) -> None:
        stamp = self.wall()
        heartbeat = HeartBeat(
            agent_type=self.agent_type,
            agent_uuid=self.agent_uuid,
            levels=["tst execution"],
            name=self.name,
            rate=self.rate,
            stamp=stamp,
        )
        self.publish(f"{self.base}/heartbeat", encode(heartbeat), qos=QOS_PERIODIC)
        info = TstExecutionInfo(
            name=self.name, rate=self.rate, stamp=stamp, trees_executing=self.core.executing()
        )
        self.publish(f"{self.base}/tst_execution_info", encode(info), qos=QOS_PERIODIC)
