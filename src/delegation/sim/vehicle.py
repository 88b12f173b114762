"""A simulated vehicle without MQTT and without a clock: tasks, motion, battery.

`SimVehicle` is driven by `step(dt)` with simulated seconds, so its kinematics are tested
directly; `delegation.sim.core.SimUnitCore` feeds it ``dt`` (the time passed times a speed-up
factor) and turns its events into WARA-PS messages.

Work follows the cost model (`delegation.costs`), so simulated missions take as long as the planner
says: a task flies the points of `costs.task_path` (a move-to's waypoint, a move-path's waypoints,
the boustrophedon sweep of a search with the unit's own sweep width, flown from the end that costs
least from where the unit is when the task starts) at the unit's speed for the
task's ``speed`` class, in straight lines in a local ENU frame, then stays for the task's fixed time
(``duration`` of observe-position, take-off, land) or, for open-ended tasks, until ``$enough``.
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from delegation.errors import InputError
from delegation.fleet import UnitState
from delegation.geo import GeoPoint, LocalFrame
from delegation.tst.catalogue import CATALOGUE, is_vehicle_task
from delegation.tst.node import TstNode
from delegation.tst.validate import param_problems

log = logging.getLogger(__name__)

#: Fail reasons, spelled like the public example agent's.
ALREADY_RUNNING = "A task is already running"
NOT_SUPPORTED = "Task is not supported"
INVALID_TASK_UUID = "Invalid task-uuid"
BATTERY_EMPTY = "battery depleted"

#: How many finished tasks a vehicle remembers for query-status.
HISTORY = 1000


class TaskState(StrEnum):
    """What a task on the vehicle is doing; the values are the feedback statuses sent."""

    RUNNING = "running"
    """Moving along its path or holding (observing, looking)."""
    PAUSED = "paused"
    """Stopped by ``$pause`` until ``$continue``."""
    FINISHED = "finished"
    """Reached the end of its work, or ended by ``$enough``."""
    ENOUGH = "enough"
    """Ended by ``$enough`` (the public example agent's spelling; ours says ``finished``)."""
    FAILED = "failed"
    """Could not go on (battery)."""
    ABORTED = "aborted"
    """Ended by ``$abort``."""


ENDED = frozenset({TaskState.FINISHED, TaskState.ENOUGH, TaskState.FAILED, TaskState.ABORTED})

#: A task's state in the seed's words for ``query-status`` (seed 12.1: "running, failed, success,
#: unknown"): a paused task is still on (running); ``$abort`` ended it unsuccessfully (failed).
QUERY_WORDS: dict[str, str] = {
    TaskState.RUNNING: "running",
    TaskState.PAUSED: "running",
    TaskState.FINISHED: "success",
    TaskState.ENOUGH: "success",
    TaskState.FAILED: "failed",
    TaskState.ABORTED: "failed",
}


#: A navigate loop shorter than this (m) is flown as a hold: its waypoints are one point.
LOOP_MIN_M = 1.0


def _loop_length(loop: tuple[tuple[float, float, float], ...]) -> float:
    """Metres once round a closed loop of (east, north, altitude) points."""
    if len(loop) < 2:
        return 0.0
    return sum(math.hypot(b[0] - a[0], b[1] - a[1])
               for a, b in zip(loop, loop[1:] + loop[:1], strict=True))


@dataclass(frozen=True, slots=True)
class VehiclePolicy:
    """How a vehicle's task handling departs from ours (the example agent's is in
    `delegation.sim.example_agent`)."""

    one_task_at_a_time: bool = False
    """Refuse any task while any task runs (ours refuse only a second vehicle task: a camera task
    runs alongside a flight)."""
    enough_status: TaskState = TaskState.FINISHED
    """The state a task ends in on ``$enough``."""


@dataclass
class SimTask:
    """One task on the vehicle: where it still has to go, and how long it then stays."""

    uuid: str
    name: str
    vehicle: bool
    legs: list[tuple[float, float, float]]  # remaining (east, north, altitude) points
    speed: float
    hold: float  # seconds to stay after the last leg; math.inf: until $enough
    loop: tuple[tuple[float, float, float], ...] = ()  # flown again and again (navigate loop-flag)
    state: TaskState = TaskState.RUNNING
    fail_reason: str = ""
    travelled: float = 0.0
    elapsed: float = 0.0


@dataclass(frozen=True, slots=True)
class TaskEvent:
    """A status change the vehicle reports (the MQTT unit turns it into exec/feedback)."""

    task_uuid: str
    status: str
    fail_reason: str = ""


@dataclass
class SimVehicle:
    """A unit's body and its running tasks. Pure: time only advances through `step`."""

    unit: UnitState
    policy: VehiclePolicy = field(default_factory=VehiclePolicy)
    frame: LocalFrame = field(init=False)
    east: float = field(init=False, default=0.0)
    north: float = field(init=False, default=0.0)
    altitude: float = field(init=False, default=0.0)
    speed: float = field(init=False, default=0.0)
    heading: float = field(init=False, default=0.0)
    course: float = field(init=False, default=0.0)
    battery: float = field(init=False, default=1.0)
    sim_time: float = field(init=False, default=0.0)
    odometer: float = field(init=False, default=0.0)
    tasks: dict[str, SimTask] = field(init=False, default_factory=dict)
    history: OrderedDict[str, str] = field(init=False, default_factory=OrderedDict)

    def __post_init__(self) -> None:
        p = self.unit.position
        self.frame = LocalFrame(p.latitude, p.longitude)
        self.altitude = p.altitude
        self.battery = 1.0 if self.unit.battery is None else float(self.unit.battery)
        self.home = self.unit.home or p

    # ---- what the sensors show

    @property
    def position(self) -> GeoPoint:
        return self.frame.geopoint(self.east, self.north, self.altitude)

    @property
    def endurance(self) -> float:
        """Seconds at full battery, as the planner counts them (``UnitState.remaining_endurance``,
        docs/plan.md §2.5): the unit's own; without one there is no limit, and the battery never
        drains. (It drained as if the unit had 3,600 s, so a search the planner rightly found
        feasible failed with "battery depleted": one model for both, issue 21.)"""
        endurance = self.unit.endurance
        return float(endurance) if endurance is not None and endurance > 0.0 else math.inf

    @property
    def busy(self) -> bool:
        """True while a vehicle task (one that moves the platform) is on."""
        return any(t.vehicle for t in self.tasks.values())

    def executing(self) -> list[tuple[str, str]]:
        """(task-name, task-uuid) of every task on, for ``tasks-executing``."""
        return [(t.name, t.uuid) for t in self.tasks.values()]

    def status_of(self, task_uuid: str) -> str:
        """For query-status: a task's state in the seed's words (`QUERY_WORDS`), or ``unknown``
        for a task this vehicle never ran or has forgotten."""
        task = self.tasks.get(task_uuid)
        if task is not None:
            return QUERY_WORDS[task.state]
        state = self.history.get(task_uuid)
        return "unknown" if state is None else QUERY_WORDS[state]

    # ---- commands

    def start_task(self, name: str, params: dict[str, Any], task_uuid: str) -> str | None:
        """Start a task; the fail reason when it is refused, else None."""
        if name not in self.unit.tasks:
            return NOT_SUPPORTED
        vehicle = is_vehicle_task(name)
        if self.policy.one_task_at_a_time and self.tasks:
            return ALREADY_RUNNING
        if vehicle and self.busy:
            return ALREADY_RUNNING
        if task_uuid in self.tasks or task_uuid in self.history:
            return f"task-uuid {task_uuid} was already used"
        if vehicle and self.battery <= 0.0:
            return BATTERY_EMPTY
        try:
            task = self._plan(name, params, task_uuid, vehicle)
        except (InputError, KeyError, TypeError, ValueError) as exc:
            return f"bad parameters for {name}: {exc}"
        self.tasks[task_uuid] = task
        return None

    def _plan(self, name: str, params: dict[str, Any], task_uuid: str, vehicle: bool) -> SimTask:
        # Imported here: the cost model pulls in shapely/numpy work only a simulator needs.
        from delegation.costs import task_geometry, task_path, unit_speed

        spec = CATALOGUE.get(name)
        if spec is not None:
            problems = param_problems(spec, params)
            if problems:
                raise ValueError("; ".join(f"{f}: {m}" for f, m in problems))
        node = TstNode(name=name, params=dict(params))
        geometry = task_geometry(node)
        speed = unit_speed(self.unit, params.get("speed"))
        # A sweep starts at the end that costs least from where the unit is now, as the
        # planner's schedule chose it from where the unit's previous task left it.
        points = ([self.home] if name == "go-home"
                  else task_path(node, self.unit, self.frame, here=self.position))
        # Altitude is cosmetic (the cost model ignores it): searches fly at least at the sweep
        # altitude, take-off climbs and land descends where the unit is (or at ``p``).
        floor = self.unit.effective_sweep_altitude if geometry.kind == "areas" else -math.inf
        legs = []
        for p in points:
            east, north = self.frame.point_xy(p)
            legs.append((east, north, max(p.altitude, floor)))
        here = legs[-1] if legs else (self.east, self.north, self.altitude)
        if name == "take-off":
            climb = params.get("height-above-takeoff")
            target = (
                self.altitude + float(climb)
                if isinstance(climb, int | float) and not isinstance(climb, bool)
                else max(self.altitude, self.unit.effective_sweep_altitude)
            )
            legs.append((here[0], here[1], target))
        elif name == "land":
            legs.append((here[0], here[1], points[-1].altitude if points else 0.0))
        hold = math.inf if geometry.open_ended else float(geometry.fixed_time)
        # navigate's loop-flag: round the waypoints until $enough (a loop of no length: a hold)
        loop = tuple(legs) if name == "navigate" and params.get("loop-flag") is True else ()
        if _loop_length(loop) <= LOOP_MIN_M:
            loop = ()
        return SimTask(task_uuid, name, vehicle, legs, speed, hold, loop)

    def signal(self, task_uuid: str, signal: str) -> tuple[str | None, TaskEvent | None]:
        """Apply ``$abort``/``$enough``/``$pause``/``$continue``: (fail reason or None, event)."""
        task = self.tasks.get(task_uuid)
        if task is None:
            return INVALID_TASK_UUID, None
        if signal == "$abort":
            return None, self._end(task, TaskState.ABORTED)
        if signal == "$enough":
            return None, self._end(task, self.policy.enough_status)
        if signal == "$pause":
            task.state = TaskState.PAUSED
            self.speed = 0.0
            return None, TaskEvent(task.uuid, TaskState.PAUSED.value)
        if signal == "$continue":
            task.state = TaskState.RUNNING
            return None, TaskEvent(task.uuid, TaskState.RUNNING.value)
        return f"signal {signal!r} is not supported", None

    def _end(self, task: SimTask, state: TaskState, reason: str = "") -> TaskEvent:
        task.state = state
        task.fail_reason = reason
        self.tasks.pop(task.uuid, None)
        self.history[task.uuid] = state.value
        while len(self.history) > HISTORY:
            self.history.popitem(last=False)
        if not self.busy:
            self.speed = 0.0
        return TaskEvent(task.uuid, state.value, reason)

    # ---- time

    def step(self, dt: float) -> list[TaskEvent]:
        """Advance ``dt`` simulated seconds; the status changes that happened."""
        if dt <= 0.0:
            return []
        self.sim_time += dt
        events: list[TaskEvent] = []
        moving = False
        for task in list(self.tasks.values()):
            if task.state is not TaskState.RUNNING:
                continue
            remaining = dt
            if task.vehicle and task.legs:
                remaining = self._move(task, remaining)
                moving = True
            while task.loop and not task.legs and remaining > 0.0:
                task.legs = list(task.loop)  # round again, from the first waypoint
                remaining = self._move(task, remaining)
                moving = True
            if not task.legs and remaining > 0.0:
                task.elapsed += remaining
                if task.vehicle:
                    self.speed = 0.0
                if task.elapsed >= task.hold:
                    events.append(self._end(task, TaskState.FINISHED))
        if any(t.vehicle for t in self.tasks.values()) or moving:
            self.battery = max(0.0, self.battery - dt / self.endurance)
            if self.battery <= 0.0:
                for task in [t for t in self.tasks.values() if t.vehicle]:
                    events.append(self._end(task, TaskState.FAILED, BATTERY_EMPTY))
        return events

    def _move(self, task: SimTask, dt: float) -> float:
        """Fly along the task's legs for up to ``dt`` s; the seconds left once they are done."""
        budget = task.speed * dt
        while task.legs and budget > 0.0:
            east, north, alt = task.legs[0]
            de, dn = east - self.east, north - self.north
            dist = math.hypot(de, dn)
            if dist > 1e-9:
                self.heading = self.course = math.degrees(math.atan2(de, dn)) % 360.0
            if dist <= budget:
                self.east, self.north, self.altitude = east, north, alt
                budget -= dist
                task.travelled += dist
                self.odometer += dist
                task.legs.pop(0)
            else:
                f = budget / dist
                self.east += de * f
                self.north += dn * f
                self.altitude += (alt - self.altitude) * f
                task.travelled += budget
                self.odometer += budget
                budget = 0.0
        self.speed = task.speed if task.legs else 0.0
        return budget / task.speed if task.speed > 0 else 0.0
