"""A simulated unit on MQTT: the Heartbeat, Sensor and Direct Execution APIs around a `SimVehicle`.

It publishes ``heartbeat``, ``sensor_info``, ``direct_execution_info`` and the sensors
``position``, ``speed``, ``heading``, ``course``, ``battery_state`` at its rate, answers ``ping``,
``start-task``, ``signal-task`` and ``query-status`` on ``exec/command``, and reports task status
on ``exec/feedback``. A command re-sent with the same ``com-uuid`` is answered again with the same
answer and never executed twice (seed 12).

``example_agent=True`` behaves like the public WARA-PS example agent (DESIGN 4) instead, for tests
that must drive that peer: bare-number sensors, ``"type": "GeoPoint"``, level ``direct_execution``,
no ``tasks-executing``, one task at a time of any kind, no ``ping``/``query-status``, no com-uuid
history, feedback ``enough`` for ``$enough``, and silence (no response at all) for a task without
``speed``, as the example agent crashes on it.
"""

from __future__ import annotations

import json
import logging
import time
import uuid
from collections.abc import Callable
from typing import Any

from delegation.fleet import UnitState
from delegation.messages import (
    DirectExecutionInfo,
    ExecFeedback,
    ExecResponse,
    HeartBeat,
    MessageError,
    Ping,
    QueryStatus,
    SensorInfo,
    SignalTask,
    StartTask,
    TaskAvailable,
    TaskExecuting,
    decode,
    encode,
)
from delegation.messages.answers import AnswerCache, com_uuid_of
from delegation.runtime.mqtt import Message
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.unit import MqttUnit
from delegation.sim.vehicle import SimVehicle, TaskEvent
from delegation.topics import DEFAULT_PREFIX, QOS_COMMAND, QOS_PERIODIC, unit_base_topic

log = logging.getLogger(__name__)

#: Signals every simulated task understands.
SIM_SIGNALS: tuple[str, ...] = ("$abort", "$enough", "$pause", "$continue")
#: Tasks the example agent needs ``speed`` for (it reads ``params["speed"]`` unguarded).
_EXAMPLE_SPEED_TASKS = frozenset({"move-to", "go-home", "move-path", "search-area"})
#: Simulation step on the unit's thread (wall seconds).
TICK_S = 0.05


class SimUnit(MqttUnit):
    """One simulated unit, its own loop thread driving a `SimVehicle`.

    ``speedup`` multiplies simulated time (a 600 m flight at 6 m/s with ``speedup=50`` takes 2 s);
    ``clock`` (monotonic seconds) and ``wall`` (epoch seconds for ``stamp``) are injectable.
    """

    def __init__(
        self,
        settings: BrokerSettings,
        unit: UnitState,
        *,
        prefix: str = DEFAULT_PREFIX,
        role: str = "simulation",
        rate: float | None = None,
        speedup: float = 1.0,
        example_agent: bool = False,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        super().__init__(settings, unit.name, tick_interval=TICK_S, clock=clock)
        if speedup <= 0:
            raise ValueError(f"speedup must be positive, not {speedup}")
        self.unit = unit
        self.example_agent = example_agent
        self.rate = float(rate if rate is not None else (3.0 if example_agent else 1.0))
        self.speedup = float(speedup)
        self.wall = wall
        self.base = unit_base_topic(unit.name, unit.agent_type, role, prefix)
        self.vehicle = SimVehicle(unit, example_agent=example_agent)
        self.agent_uuid = str(uuid.uuid4())
        self._answers = AnswerCache()
        self._last_tick: float | None = None
        self._next_publish = 0.0
        self.commands_handled = 0

    # ---- MqttUnit hooks

    def subscriptions(self) -> list[str]:
        return [f"{self.base}/exec/command"]

    def on_start(self) -> None:
        self._last_tick = self.clock()
        self._publish_status()
        self._next_publish = self.clock() + 1.0 / self.rate

    def tick(self, now: float) -> None:
        last = self._last_tick if self._last_tick is not None else now
        self._last_tick = now
        for event in self.vehicle.step((now - last) * self.speedup):
            self._feedback(event)
        if now >= self._next_publish:
            self._publish_status()
            self._next_publish = max(self._next_publish + 1.0 / self.rate, now)

    def handle(self, message: Message) -> None:
        if self.example_agent:
            self._handle_like_example(message)
            return
        com_uuid = com_uuid_of(message.payload)
        previous = self._answers.get(com_uuid)
        if previous is not None:
            log.debug("%s: re-sent command %s answered again", self.name, com_uuid)
            self.publish(f"{self.base}/exec/response", previous, qos=QOS_COMMAND)
            return
        try:
            command = decode(message.topic, message.payload)
        except MessageError as exc:
            log.warning("%s: bad command: %s", self.name, exc)
            if com_uuid is not None:
                self._respond(com_uuid, "failed", fail_reason=str(exc))
            return
        self.commands_handled += 1
        if isinstance(command, Ping):
            self._respond(command.com_uuid, "pong")
        elif isinstance(command, StartTask):
            self._start_task(command)
        elif isinstance(command, SignalTask):
            reason, event = self.vehicle.signal(command.task_uuid, command.signal)
            self._respond(
                command.com_uuid,
                "failed" if reason else "ok",
                fail_reason=reason or "",
                task_uuid=command.task_uuid,
            )
            if event is not None:
                self._feedback(event)
        elif isinstance(command, QueryStatus):
            self._respond(
                command.com_uuid,
                self.vehicle.status_of(command.task_uuid),
                task_uuid=command.task_uuid,
            )
        else:
            name = getattr(command, "command", type(command).__name__)
            self._respond(command.com_uuid, "failed", fail_reason=f"{name} is not supported")  # type: ignore[attr-defined]

    # ---- commands

    def _start_task(self, command: StartTask) -> None:
        target = command.execution_unit.strip("/")
        if target and target != self.name:
            self._respond(
                command.com_uuid,
                "failed",
                fail_reason=f"execution-unit {command.execution_unit} is not {self.name}",
                task_uuid=command.task_uuid,
            )
            return
        task_uuid = command.task_uuid or str(uuid.uuid4())
        reason = self.vehicle.start_task(command.task.name, command.task.params, task_uuid)
        if reason is None:
            self._respond(command.com_uuid, "running", task_uuid=task_uuid)
            self._feedback(TaskEvent(task_uuid, "running"))
            self._publish_status()  # tasks-executing changed: say so now, not at the next period
        else:
            log.info("%s: refused %s: %s", self.name, command.task.name, reason)
            self._respond(command.com_uuid, "failed", fail_reason=reason, task_uuid=task_uuid)

    def _respond(
        self, com_uuid: str, response: str, fail_reason: str = "", task_uuid: str | None = None
    ) -> None:
        answer = ExecResponse(
            agent_uuid=self.agent_uuid,
            fail_reason=fail_reason,
            response=response,
            response_to=com_uuid,
            task_uuid=task_uuid,
        )
        data = encode(answer)
        self._answers.put(com_uuid, data)
        self.publish(f"{self.base}/exec/response", data, qos=QOS_COMMAND)

    def _feedback(self, event: TaskEvent) -> None:
        msg = ExecFeedback(
            agent_uuid=self.agent_uuid, status=event.status, task_uuid=event.task_uuid
        )
        self.publish(f"{self.base}/exec/feedback", encode(msg), qos=QOS_COMMAND)
        if event.status not in ("running", "paused"):
            self._publish_status()

    # ---- periodic messages

    def _publish_status(self) -> None:
        stamp = self.wall()
        v = self.vehicle
        levels = ["sensor", "direct_execution" if self.example_agent else "direct execution"]
        heartbeat = HeartBeat(
            agent_type=self.unit.agent_type,
            agent_uuid=self.agent_uuid,
            levels=levels,
            name=self.name,
            rate=self.rate,
            stamp=stamp,
        ).to_wire()
        heartbeat["levels"] = levels  # the model normalises spelling; publish ours as chosen
        if self.example_agent:
            heartbeat["agent-description"] = "L2_agent_example"
        self.publish(f"{self.base}/heartbeat", heartbeat)
        sensors = ["position", "speed", "course", "heading"]
        if not self.example_agent:
            sensors.append("battery_state")
        sensor_info = SensorInfo(
            name=self.name, rate=self.rate, sensor_data_provided=sensors, stamp=stamp
        )
        self.publish(f"{self.base}/sensor_info", encode(sensor_info), qos=QOS_PERIODIC)
        info = DirectExecutionInfo(
            name=self.name,
            rate=self.rate,
            stamp=stamp,
            tasks_available=[
                TaskAvailable(name=t, signals=list(SIM_SIGNALS)) for t in sorted(self.unit.tasks)
            ],
            tasks_executing=[TaskExecuting(task_name=n, task_uuid=u) for n, u in v.executing()],
        ).to_wire()
        if self.example_agent:
            info.pop("tasks-executing", None)
        else:
            info["tasks-executing"] = info.get("tasks-executing", [])
        self.publish(f"{self.base}/direct_execution_info", info)
        pos = v.position
        if self.example_agent:
            position: dict[str, Any] = {
                "latitude": pos.latitude,
                "longitude": pos.longitude,
                "altitude": pos.altitude,
                "type": "GeoPoint",
            }
            self.publish(f"{self.base}/sensor/position", position)
            for sensor, value in (("speed", v.speed), ("course", v.course), ("heading", v.heading)):
                self.publish(f"{self.base}/sensor/{sensor}", json.dumps(value), qos=QOS_PERIODIC)
        else:
            self.publish(f"{self.base}/sensor/position", pos.to_wire())
            for sensor, value in (("speed", v.speed), ("course", v.course), ("heading", v.heading)):
                self.publish(f"{self.base}/sensor/{sensor}", {"value": value})
            self.publish(
                f"{self.base}/sensor/battery_state",
                {"percentage": round(v.battery, 6), "charging": False},
            )

    # ---- the example agent's protocol, quirks included

    def _handle_like_example(self, message: Message) -> None:
        try:
            msg = json.loads(message.payload)
            command = msg["command"]
        except (ValueError, KeyError, TypeError):
            log.warning("%s (example agent): unreadable command ignored", self.name)
            return
        if command == "start-task":
            try:
                task_uuid, task, com_uuid = msg["task-uuid"], msg["task"], msg["com-uuid"]
                name, params = task["name"], task.get("params", {})
                if (
                    name in _EXAMPLE_SPEED_TASKS
                    and name in self.unit.tasks
                    and not self.vehicle.tasks
                ):
                    params["speed"]
            except (KeyError, TypeError):
                log.warning(
                    "%s (example agent): start-task without speed/uuid: no answer", self.name
                )
                return
            reason = self.vehicle.start_task(name, params, task_uuid)
            response = {
                "agent-uuid": self.agent_uuid,
                "com-uuid": str(uuid.uuid4()),
                "fail-reason": reason or "",
                "response": "failed" if reason else "running",
                "response-to": com_uuid,
                "task-uuid": task_uuid,
            }
            self.publish(f"{self.base}/exec/response", response)
            self._example_feedback(task_uuid, "failed" if reason else "running")
        elif command == "signal-task":
            signal, task_uuid, com_uuid = (
                msg.get("signal"),
                msg.get("task-uuid"),
                msg.get("com-uuid"),
            )
            running = next(iter(self.vehicle.tasks), "")
            if running and running == task_uuid:
                _, event = self.vehicle.signal(task_uuid, str(signal))
                reply = {
                    "com-uuid": str(uuid.uuid4()),
                    "response": "ok",
                    "response-to": com_uuid,
                    "task-uuid": running,
                }
                self.publish(f"{self.base}/exec/response", reply)
                self._example_feedback(running, event.status if event else "")
            else:
                reply = {
                    "com-uuid": str(uuid.uuid4()),
                    "fail-reason": "Invalid task-uuid",
                    "response": "failed",
                    "response-to": com_uuid,
                    "task-uuid": running,
                }
                self.publish(f"{self.base}/exec/response", reply)
                self._example_feedback(running, "failed")

    def _example_feedback(self, task_uuid: str, status: str) -> None:
        self.publish(
            f"{self.base}/exec/feedback",
            {
                "agent-uuid": self.agent_uuid,
                "com-uuid": str(uuid.uuid4()),
                "status": status,
                "task-uuid": task_uuid,
            },
        )
