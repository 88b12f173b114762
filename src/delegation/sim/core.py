"""A simulated unit's core: the Heartbeat, Sensor and Direct Execution APIs around a `SimVehicle`.

Pure (no paho, no threads, no clock): `delegation.sim.unit.SimUnit` runs it on a broker. It
answers ``ping``, ``start-task``, ``signal-task`` and ``query-status`` on ``exec/command``, reports
task status on ``exec/feedback``, and its `status` is ``heartbeat``, ``sensor_info``,
``direct_execution_info`` and the sensors ``position``, ``speed``, ``course``, ``heading``,
``battery_state``. A command re-sent with the same ``com-uuid`` is answered again with the same
bytes and never executed twice (seed 12).

`SimCore` is what every simulated unit shares (identity, vehicle, time); `SimUnitCore` speaks the
seed's protocol; `delegation.sim.example_agent.ExampleAgentCore` speaks the public example
agent's.
"""

from __future__ import annotations

import logging
import uuid
from abc import ABC, abstractmethod
from collections.abc import Sequence
from functools import cached_property
from typing import ClassVar

from delegation.fleet import UnitState
from delegation.messages import (
    DirectExecutionInfo,
    ExecFeedback,
    ExecResponse,
    MessageError,
    Ping,
    QueryStatus,
    SensorInfo,
    Signal,
    SignalTask,
    StartTask,
    TaskAvailable,
    TaskExecuting,
    decode,
)
from delegation.runtime.commands import CommandLog, com_uuid_of
from delegation.runtime.core import Effects, Identified, Identity, Outgoing, heartbeat
from delegation.sim.vehicle import ENDED, SimVehicle, TaskEvent, VehiclePolicy
from delegation.topics import DEFAULT_PREFIX, QOS_COMMAND, QOS_PERIODIC

log = logging.getLogger(__name__)

#: Signals every simulated task understands (in the order ``tasks-available`` lists them).
SIM_SIGNALS: tuple[str, ...] = tuple(
    s.value for s in (Signal.ABORT, Signal.ENOUGH, Signal.PAUSE, Signal.CONTINUE)
)
#: The face commands arrive on (the `CommandLog` key's first half).
FACE = "exec"
#: The sensors `SimUnitCore` publishes, in ``sensor-data-provided`` order.
SENSORS: tuple[str, ...] = ("position", "speed", "course", "heading", "battery_state")


class _AlwaysListsExecuting(DirectExecutionInfo):
    """``direct_execution_info`` with ``tasks-executing`` even when empty: ours say "idle"
    explicitly (the model leaves the key out, as the seed's examples do)."""

    def omit_when_empty(self) -> frozenset[str]:
        return frozenset()


class SimCore(Identified, ABC):
    """What every simulated unit's core shares: who it is, its vehicle, and simulated time.

    ``speedup`` multiplies time (a 600 m flight at 6 m/s with ``speedup=50`` takes 2 s of ``now``).
    Subclasses say how commands are read and answered and what `status` publishes.
    """

    #: Messages per second when the caller gives no rate.
    DEFAULT_RATE: ClassVar[float] = 1.0
    #: How the vehicle handles tasks.
    POLICY: ClassVar[VehiclePolicy] = VehiclePolicy()

    def __init__(
        self,
        unit: UnitState,
        *,
        prefix: str = DEFAULT_PREFIX,
        role: str = "simulation",
        rate: float | None = None,
        speedup: float = 1.0,
        agent_uuid: str | None = None,
    ) -> None:
        if speedup <= 0:
            raise ValueError(f"speedup must be positive, not {speedup}")
        self.unit = unit
        self.speedup = float(speedup)
        self.identity = Identity(
            name=unit.name,
            agent_type=unit.agent_type,
            agent_uuid=agent_uuid or str(uuid.uuid4()),
            role=role,
            prefix=prefix,
            rate=float(rate if rate is not None else self.DEFAULT_RATE),
        )
        self.vehicle = SimVehicle(unit, self.POLICY)
        self.commands_handled = 0
        self._last_tick: float | None = None
        # Wall minus monotonic seconds, learnt from `status`: stamps status sent between periods.
        self._wall_offset = 0.0

    def subscriptions(self) -> list[str]:
        return [self.identity.topic("exec/command")]

    # ---- time

    def on_tick(self, now: float) -> Effects:
        """Step the vehicle by the time passed since the last tick (times ``speedup``)."""
        last = self._last_tick if self._last_tick is not None else now
        self._last_tick = now
        effects = Effects()
        for event in self.vehicle.step((now - last) * self.speedup):
            effects.extend(self._feedback(event, now))
        return effects

    def status(self, now: float, stamp: float) -> list[Outgoing]:
        self._wall_offset = stamp - now
        return self._status(stamp)

    def _status_now(self, now: float) -> list[Outgoing]:
        """Status out of period (a task started or ended), stamped like the periodic one."""
        return self._status(now + self._wall_offset)

    def _feedback(self, event: TaskEvent, now: float) -> Effects:
        """``exec/feedback`` for a status change; a task that ended changes ``tasks-executing``,
        so status goes out at once too."""
        effects = Effects().send(
            self.identity.topic("exec/feedback"),
            ExecFeedback(
                agent_uuid=self.agent_uuid, status=event.status, task_uuid=event.task_uuid
            ),
        )
        if event.status in ENDED:
            effects.publish.extend(self._status_now(now))
        return effects

    @abstractmethod
    def on_message(self, topic: str, payload: bytes, now: float) -> Effects:
        """One command on ``exec/command``."""

    @abstractmethod
    def _status(self, stamp: float) -> list[Outgoing]:
        """Heartbeat, info and sensor messages stamped ``stamp`` (wall seconds)."""

    def _infos(
        self, stamp: float, sensors: Sequence[str], info: DirectExecutionInfo
    ) -> tuple[SensorInfo, DirectExecutionInfo]:
        """The sensor info naming ``sensors``, and ``info`` offering the unit's tasks with the
        signals the simulation understands."""
        sensor_info = SensorInfo(
            name=self.name, rate=self.rate, sensor_data_provided=list(sensors), stamp=stamp
        )
        info.tasks_available = [
            TaskAvailable(name=t, signals=list(SIM_SIGNALS)) for t in sorted(self.unit.tasks)
        ]
        return sensor_info, info


class SimUnitCore(SimCore):
    """A simulated unit speaking the seed's Direct Execution API, with com-uuid idempotency."""

    @cached_property
    def commands(self) -> CommandLog:
        """The commands seen, by (face, com-uuid): a re-sent one gets the same answer again."""
        return CommandLog()

    # ---- commands

    def on_message(self, topic: str, payload: bytes, now: float) -> Effects:
        com_uuid = com_uuid_of(payload)
        again = self.commands.answer_again((FACE, com_uuid)) if com_uuid is not None else None
        if again is not None:
            return Effects.of(again)
        try:
            command = decode(topic, payload)
        except MessageError as exc:
            log.warning("%s: bad command: %s", self.name, exc)
            if com_uuid is None:
                return Effects()
            return self._answered(com_uuid, now, self._response(com_uuid, "failed", str(exc)))
        self.commands_handled += 1
        if isinstance(command, Ping):
            return self._answered(command.com_uuid, now, self._response(command.com_uuid, "pong"))
        if isinstance(command, StartTask):
            return self._start_task(command, now)
        if isinstance(command, SignalTask):
            return self._signal_task(command, now)
        if isinstance(command, QueryStatus):
            state = self.vehicle.status_of(command.task_uuid)
            answer = self._response(command.com_uuid, state, task_uuid=command.task_uuid)
            return self._answered(command.com_uuid, now, answer)
        name = getattr(command, "command", type(command).__name__)
        com = str(getattr(command, "com_uuid", com_uuid or ""))
        return self._answered(com, now, self._response(com, "failed", f"{name} is not supported"))

    def _start_task(self, command: StartTask, now: float) -> Effects:
        target = command.execution_unit.strip("/")
        if target and target != self.name:
            wrong = f"execution-unit {command.execution_unit} is not {self.name}"
            answer = self._response(command.com_uuid, "failed", wrong, command.task_uuid)
            return self._answered(command.com_uuid, now, answer)
        task_uuid = command.task_uuid or str(uuid.uuid4())
        reason = self.vehicle.start_task(command.task.name, command.task.params, task_uuid)
        if reason is not None:
            log.info("%s: refused %s: %s", self.name, command.task.name, reason)
            answer = self._response(command.com_uuid, "failed", reason, task_uuid)
            return self._answered(command.com_uuid, now, answer)
        effects = self._answered(
            command.com_uuid, now, self._response(command.com_uuid, "running", "", task_uuid)
        )
        effects.extend(self._feedback(TaskEvent(task_uuid, "running"), now))
        # tasks-executing changed: say so now, not at the next period.
        effects.publish.extend(self._status_now(now))
        return effects

    def _signal_task(self, command: SignalTask, now: float) -> Effects:
        reason, event = self.vehicle.signal(command.task_uuid, command.signal)
        answer = self._response(
            command.com_uuid, "failed" if reason else "ok", reason or "", command.task_uuid
        )
        effects = self._answered(command.com_uuid, now, answer)
        if event is not None:
            effects.extend(self._feedback(event, now))
        return effects

    def _response(
        self, com_uuid: str, response: str, fail_reason: str = "", task_uuid: str | None = None
    ) -> Outgoing:
        answer = ExecResponse(
            agent_uuid=self.agent_uuid,
            fail_reason=fail_reason,
            response=response,
            response_to=com_uuid,
            task_uuid=task_uuid,
        )
        return Outgoing.of(self.identity.topic("exec/response"), answer, QOS_COMMAND)

    def _answered(self, com_uuid: str, now: float, answer: Outgoing) -> Effects:
        """Remember ``answer`` for ``com_uuid`` (a re-send gets these bytes again); send it."""
        key = (FACE, com_uuid)
        if self.commands.get(key) is None:
            self.commands.begin(key, now)
        self.commands.finish(key, [answer])
        return Effects.of([answer])

    # ---- status

    def _status(self, stamp: float) -> list[Outgoing]:
        ident, v = self.identity, self.vehicle
        running = [TaskExecuting(task_name=n, task_uuid=u) for n, u in v.executing()]
        sensors, info = self._infos(stamp, SENSORS, _AlwaysListsExecuting(
            name=self.name, rate=self.rate, stamp=stamp, tasks_executing=running))
        out = [
            heartbeat(ident, ["sensor", "direct execution"], stamp),
            Outgoing.of(ident.topic("sensor_info"), sensors, QOS_PERIODIC),
            Outgoing.of(ident.topic("direct_execution_info"), info, QOS_PERIODIC),
            Outgoing.of(ident.topic("sensor/position"), v.position.to_wire(), QOS_PERIODIC),
        ]
        for sensor, value in (("speed", v.speed), ("course", v.course), ("heading", v.heading)):
            out.append(Outgoing.of(ident.topic(f"sensor/{sensor}"), {"value": value}, QOS_PERIODIC))
        battery = {"percentage": round(v.battery, 6), "charging": False}
        out.append(Outgoing.of(ident.topic("sensor/battery_state"), battery, QOS_PERIODIC))
        return out
