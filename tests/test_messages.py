"""Messages: decode by topic, encode canonically, lenient readers (DESIGN 4), clear errors."""

from __future__ import annotations

import json

import pytest

from delegation.errors import InputError
from delegation.geo import GeoPoint
from delegation.messages import (
    CancelMission,
    Delegate,
    DelegationFeedback,
    DelegationPing,
    DelegationResponse,
    DirectExecutionInfo,
    ExecFeedback,
    ExecResponse,
    GetBids,
    HeartBeat,
    ListAgents,
    ListMissions,
    MessageError,
    Ping,
    QueryMission,
    QueryStatus,
    SensorInfo,
    SensorReading,
    SignalTask,
    SignalTstNode,
    SignalTstTree,
    SignalUnit,
    StartTask,
    StartTst,
    TaskSpecMsg,
    TstFeedback,
    TstResponse,
    decode,
    encode,
    new_com_uuid,
    parse_command,
    parse_sensor,
)

BASE = "waraps/unit/air/simulation/dji0"


def _bytes(data: object) -> bytes:
    return json.dumps(data).encode()


def test_message_error_is_an_input_error() -> None:
    assert issubclass(MessageError, InputError)


def test_new_com_uuid_is_fresh() -> None:
    a, b = new_com_uuid(), new_com_uuid()
    assert a != b and len(a) == 36
