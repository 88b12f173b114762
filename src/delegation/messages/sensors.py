"""Sensor values (seed section 6): ``sensor/position`` is a GeoPoint, ``speed``/``heading``/
``course`` are numbers. Real units send the numbers bare (``3.0``) or wrapped in an object
(``{"value": 3.0}``, ROS bridges ``{"data": 3.0}``); both are read.
"""

from __future__ import annotations

import math
from typing import Any

from pydantic import ConfigDict, ValidationError

from delegation.errors import InputProblem, MessageError
from delegation.geo import GeoPoint
from delegation.messages.base import WireModel
from delegation.messages.errors import json_value, validation_problems

#: Sensors whose value is one number.
NUMERIC_SENSORS: frozenset[str] = frozenset({"speed", "heading", "course", "altitude"})
#: Keys under which an object-shaped numeric sensor carries its number.
_NUMBER_KEYS: tuple[str, ...] = ("value", "data")

SensorValue = GeoPoint | float | dict[str, Any] | list[Any] | str | bool | None


class SensorReading(WireModel):
    """One value from ``.../sensor/<sensor>``, as ``decode`` returns it."""

    model_config = ConfigDict(arbitrary_types_allowed=True)

    sensor: str
    value: Any

    def to_wire(self) -> Any:
        """The value as the unit publishes it (position as a GeoPoint object, numbers bare)."""
        if isinstance(self.value, GeoPoint):
            return self.value.to_wire()
        return self.value


def _number(value: Any) -> float | None:
    """A finite float from a JSON number or numeric string, else None."""
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        return None
    try:
        number = float(value)
    except (OverflowError, ValueError):  # huge integers overflow; strings may not be numbers
        return None
    return number if math.isfinite(number) else None


def sensor_value(sensor_name: str, data: Any) -> SensorValue:
    """Interpret decoded JSON ``data`` from ``sensor/<sensor_name>``; raise ``MessageError``."""
    where = f"sensor/{sensor_name}"
    if sensor_name == "position":
        problems = []
        try:
            return GeoPoint.model_validate(data)
        except ValidationError as exc:
            problems = validation_problems(exc, where)
        raise MessageError(problems)  # outside ``except``: see ``validate_model``
    if sensor_name in NUMERIC_SENSORS:
        number = _number(data)
        if number is None and isinstance(data, dict):
            candidates = [data[k] for k in (*_NUMBER_KEYS, sensor_name) if k in data]
            if not candidates and len(data) == 1:
                candidates = list(data.values())
            number = _number(candidates[0]) if candidates else None
        if number is None:
            raise MessageError(
                InputProblem(
                    where, "", f"expected a number or an object holding one, got {data!r:.80}")
            )
        return number
    value: SensorValue = data  # any other sensor: its JSON value as it came
    return value


def parse_sensor(sensor_name: str, payload: bytes) -> SensorValue:
    """A sensor's payload: position -> GeoPoint; speed/heading/course -> float; others as JSON."""
    return sensor_value(sensor_name, json_value(payload, f"sensor/{sensor_name}"))
