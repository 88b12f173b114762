"""A simulated unit that behaves like the public WARA-PS example agent (docs/protocol.md §10),
quirks included.

Tests that must drive that peer use it. Every way it departs from the seed is here:

- heartbeat level ``direct_execution`` and an ``agent-description``; rate 3 Hz by default;
- sensors ``position`` (with ``"type": "GeoPoint"``), ``speed``, ``course``, ``heading``, the
  numbers bare; no ``battery_state``; no ``tasks-executing`` in ``direct_execution_info``;
- no ``ping`` or ``query-status`` (silence), no com-uuid history (a re-send runs again);
- one task at a time of any kind; feedback ``enough`` for ``$enough``; ``Invalid task-uuid``
  (with a ``failed`` feedback) for a signal to a task that is not the running one;
- silence for a ``start-task`` of move-to, go-home, move-path or search-area without ``speed``
  (the example agent crashes reading ``params["speed"]``);
- its own response and feedback shapes (a fresh ``com-uuid`` in each, no ``agent-uuid`` on a
  signal's answer), published at QoS 0.
"""

from __future__ import annotations

import json
import logging
import uuid
from typing import Any, ClassVar

from delegation.messages import DirectExecutionInfo
from delegation.runtime.core import Effects, Outgoing, heartbeat
from delegation.sim.core import SimCore
from delegation.sim.vehicle import TaskState, VehiclePolicy
from delegation.topics import QOS_PERIODIC

log = logging.getLogger(__name__)

#: The example agent's task handling: one task of any kind, ``$enough`` ends it ``enough``.
EXAMPLE_AGENT_POLICY = VehiclePolicy(one_task_at_a_time=True, enough_status=TaskState.ENOUGH)
#: Tasks the example agent needs ``speed`` for (it reads ``params["speed"]`` unguarded).
SPEED_TASKS = frozenset({"move-to", "go-home", "move-path", "search-area"})
#: The sensors it publishes, in ``sensor-data-provided`` order.
SENSORS: tuple[str, ...] = ("position", "speed", "course", "heading")
#: Its heartbeat's levels, spelt as it spells them, and its description.
LEVELS: tuple[str, ...] = ("sensor", "direct_execution")
DESCRIPTION = "L2_agent_example"
#: Its answers and feedback go out at QoS 0 like everything it publishes.
QOS = QOS_PERIODIC


class ExampleAgentCore(SimCore):
    """The public example agent's protocol around a `SimVehicle` (see the module's list)."""

    DEFAULT_RATE: ClassVar[float] = 3.0
    POLICY: ClassVar[VehiclePolicy] = EXAMPLE_AGENT_POLICY

    def on_message(self, topic: str, payload: bytes, now: float) -> Effects:
        try:
            msg = json.loads(payload)
            command = msg["command"]
        except (ValueError, KeyError, TypeError):
            log.warning("%s (example agent): unreadable command ignored", self.name)
            return Effects()
        if command == "start-task":
            return self._start_task(msg)
        if command == "signal-task":
            return self._signal_task(msg)
        return Effects()  # ping, query-status, ...: the example agent does not answer

    def _start_task(self, msg: dict[str, Any]) -> Effects:
        task = msg.get("task")
        if not (
            isinstance(task, dict)
            and isinstance(task.get("name"), str)
            and isinstance(task.get("params", {}), dict)
            and "task-uuid" in msg
            and "com-uuid" in msg
        ):
            log.warning("%s (example agent): start-task without task/uuid: no answer", self.name)
            return Effects()
        name, params = task["name"], task.get("params", {})
        task_uuid, com_uuid = msg["task-uuid"], msg["com-uuid"]
        if self._crashes_without_speed(name, params):
            log.warning("%s (example agent): %s without speed: no answer", self.name, name)
            return Effects()
        reason = self.vehicle.start_task(name, params, task_uuid)
        response = {
            "agent-uuid": self.agent_uuid,
            "com-uuid": str(uuid.uuid4()),
            "fail-reason": reason or "",
            "response": "failed" if reason else "running",
            "response-to": com_uuid,
            "task-uuid": task_uuid,
        }
        effects = Effects().send(self.identity.topic("exec/response"), response, QOS)
        return effects.extend(self._example_feedback(task_uuid, "failed" if reason else "running"))

    def _crashes_without_speed(self, name: str, params: dict[str, Any]) -> bool:
        """The example agent reads ``params["speed"]`` for these tasks once it accepts one (a task
        it supports, while none runs): without it, it dies before answering."""
        return (
            name in SPEED_TASKS
            and name in self.unit.tasks
            and not self.vehicle.tasks
            and "speed" not in params
        )

    def _signal_task(self, msg: dict[str, Any]) -> Effects:
        signal, task_uuid, com_uuid = msg.get("signal"), msg.get("task-uuid"), msg.get("com-uuid")
        running = next(iter(self.vehicle.tasks), "")
        reply: dict[str, Any] = {
            "com-uuid": str(uuid.uuid4()),
            "response": "ok",
            "response-to": com_uuid,
            "task-uuid": running,
        }
        if running and running == task_uuid:
            _, event = self.vehicle.signal(running, str(signal))
            status = event.status if event else ""
        else:
            reply.update({"fail-reason": "Invalid task-uuid", "response": "failed"})
            status = "failed"
        effects = Effects().send(self.identity.topic("exec/response"), reply, QOS)
        return effects.extend(self._example_feedback(running, status))

    def _example_feedback(self, task_uuid: str, status: str) -> Effects:
        feedback = {
            "agent-uuid": self.agent_uuid,
            "com-uuid": str(uuid.uuid4()),
            "status": status,
            "task-uuid": task_uuid,
        }
        return Effects().send(self.identity.topic("exec/feedback"), feedback, QOS)

    def _status(self, stamp: float) -> list[Outgoing]:
        ident, v = self.identity, self.vehicle
        # No tasks_executing: the model leaves the empty list out, as the example agent does.
        sensors, info = self._infos(
            stamp, SENSORS, DirectExecutionInfo(name=self.name, rate=self.rate, stamp=stamp)
        )
        pos = v.position
        position = {
            "latitude": pos.latitude,
            "longitude": pos.longitude,
            "altitude": pos.altitude,
            "type": "GeoPoint",
        }
        out = [
            heartbeat(ident, LEVELS, stamp, {"agent-description": DESCRIPTION}),
            Outgoing.of(ident.topic("sensor_info"), sensors, QOS_PERIODIC),
            Outgoing.of(ident.topic("direct_execution_info"), info, QOS_PERIODIC),
            Outgoing.of(ident.topic("sensor/position"), position, QOS_PERIODIC),
        ]
        for sensor, value in (("speed", v.speed), ("course", v.course), ("heading", v.heading)):
            out.append(
                Outgoing(ident.topic(f"sensor/{sensor}"), json.dumps(value).encode(), QOS_PERIODIC)
            )
        return out
