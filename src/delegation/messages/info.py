"""Heartbeat and per-level info messages (seed section 5), read as real units send them.

Real units are looser than the seed (docs/protocol.md §9): levels spelled ``direct_execution``,
``tasks-executing`` entries as ``{name, uuid}`` or missing altogether. Readers accept those; writers
emit the seed's spelling.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import Field, field_validator, model_validator

from delegation.messages.base import WireModel

#: The levels of seed 5.1, in their canonical spelling.
LEVELS: tuple[str, ...] = ("sensor", "direct execution", "tst execution", "delegation")


def normalise_level(level: str) -> str:
    """``direct_execution`` / ``Direct-Execution`` -> ``direct execution``."""
    return " ".join(level.replace("_", " ").replace("-", " ").lower().split())


class HeartBeat(WireModel):
    """Seed 5.1: a unit exists; ``levels`` say which APIs it registers on."""

    agent_type: str
    agent_uuid: str
    levels: list[str] = Field(default_factory=list)
    name: str
    rate: float
    stamp: float
    type: Literal["HeartBeat"] = "HeartBeat"

    @field_validator("levels", mode="before")
    @classmethod
    def _levels(cls, value: Any) -> Any:
        if isinstance(value, list):
            return [normalise_level(v) if isinstance(v, str) else v for v in value]
        return value

    @field_validator("type", mode="before")
    @classmethod
    def _type(cls, value: Any) -> Any:
        return "HeartBeat" if value is None else value


class SensorInfo(WireModel):
    """Seed 5.2: the sensors a unit publishes under ``sensor/``; a heartbeat for that level."""

    name: str
    rate: float
    sensor_data_provided: list[str] = Field(default_factory=list)
    stamp: float | None = None
    type: Literal["SensorInfo"] = "SensorInfo"


class TaskAvailable(WireModel):
    """One entry of ``tasks-available``: a task and the signals it understands."""

    name: str
    signals: list[str] = Field(default_factory=list)

    @model_validator(mode="before")
    @classmethod
    def _bare_name(cls, value: Any) -> Any:
        return {"name": value} if isinstance(value, str) else value


class TaskExecuting(WireModel):
    """One entry of ``tasks-executing``: ``{task-name, task-uuid}`` (or ``{name, uuid}``)."""

    task_name: str
    task_uuid: str

    @model_validator(mode="before")
    @classmethod
    def _short_keys(cls, value: Any) -> Any:
        if isinstance(value, dict):
            value = dict(value)
            if "task-name" not in value and "task_name" not in value and "name" in value:
                value["task-name"] = value["name"]
            if "task-uuid" not in value and "task_uuid" not in value and "uuid" in value:
                value["task-uuid"] = value["uuid"]
        return value


class LevelInfo(WireModel):
    """What every level's info message carries: the unit, how often it is sent, and when."""

    name: str
    rate: float
    stamp: float


class DirectExecutionInfo(LevelInfo):
    """Seed 5.3: the tasks a unit offers and runs; a heartbeat for the direct execution level."""

    tasks_available: list[TaskAvailable] = Field(default_factory=list)
    tasks_executing: list[TaskExecuting] = Field(default_factory=list)
    type: Literal["DirectExecutionInfo"] = "DirectExecutionInfo"

    _omit_empty: ClassVar[frozenset[str]] = frozenset({"tasks-executing"})

    @field_validator("tasks_executing", "tasks_available", mode="before")
    @classmethod
    def _null_list(cls, value: Any) -> Any:
        return [] if value is None else value


class TstExecutionInfo(LevelInfo):
    """Info for the TST execution level (the seed names the level, not the message): the root
    uuids of the trees this engine is executing."""

    trees_executing: list[str] = Field(default_factory=list)
    type: Literal["TstExecutionInfo"] = "TstExecutionInfo"


class DelegationInfo(LevelInfo):
    """Info for the delegation level (ours, docs/protocol.md §2, §15): what the service offers.

    ``tasks-available`` (the tasks its live fleet can do, the union) and ``units-managed`` (the
    units it plans for) make it a *delegator* to other services (docs/protocol.md §15): they ask
    it for offers on subtrees whose tasks it lists, and leave the units it manages to it. A
    sender that lists no tasks is a delegator nobody offers anything to.
    """

    strategies: list[str] = Field(default_factory=list)
    objectives: list[str] = Field(default_factory=list)
    missions_active: int = 0
    tasks_available: list[str] = Field(default_factory=list)
    units_managed: list[str] = Field(default_factory=list)
    type: Literal["DelegationInfo"] = "DelegationInfo"

    @field_validator("tasks_available", mode="before")
    @classmethod
    def _task_names(cls, value: Any) -> Any:
        """Accept the ``direct_execution_info`` spelling too (``[{name: ...}]``)."""
        if isinstance(value, list):
            return [v.get("name") if isinstance(v, dict) else v for v in value]
        return value
