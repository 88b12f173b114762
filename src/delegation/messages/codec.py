"""From topic bytes to a model and back: ``decode`` picks the model from the topic (and, for
commands, from the ``command`` field); ``encode`` writes the seed's canonical JSON.

``decode`` raises ``MessageError`` (an ``InputError``) for anything it cannot accept, and nothing
else, whatever the bytes.
"""

from __future__ import annotations

import json
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from delegation.errors import InputProblem, MessageError, json_kind
from delegation.geo import GeoPoint
from delegation.messages import delegation_api, direct, info, tst_exec
from delegation.messages.base import WireModel
from delegation.messages.errors import json_value, validation_problems
from delegation.messages.sensors import SensorReading, sensor_value

M = TypeVar("M", bound=BaseModel)


def _by_command(*models: type[WireModel]) -> dict[str, type[WireModel]]:
    """``{command: model}``, the name read from each model's ``command`` field."""
    return {str(m.model_fields["command"].default): m for m in models}


#: Commands by API: ``{command: model}``.
EXEC_COMMANDS = _by_command(
    direct.Ping, direct.StartTask, direct.SignalTask, direct.QueryStatus, direct.SignalExecutor
)
TST_COMMANDS = _by_command(
    direct.Ping, tst_exec.StartTst, tst_exec.SignalTstNode, tst_exec.SignalTstTree,
    tst_exec.SignalUnit, tst_exec.RebindTstNodes, tst_exec.QueryTst,
)
DELEGATION_COMMANDS = _by_command(
    delegation_api.DelegationPing,
    delegation_api.Delegate,
    delegation_api.GetBids,
    delegation_api.QueryMission,
    delegation_api.ListMissions,
    delegation_api.ListAgents,
    delegation_api.CancelMission,
)
COMMANDS: dict[str, dict[str, type[WireModel]]] = {
    "exec": EXEC_COMMANDS,
    "tst": TST_COMMANDS,
    "delegation": DELEGATION_COMMANDS,
}
#: Responses and feedback by API.
RESPONSES: dict[str, type[WireModel]] = {
    "exec": direct.ExecResponse,
    "tst": tst_exec.TstResponse,
    "delegation": delegation_api.DelegationResponse,
}
FEEDBACK: dict[str, type[WireModel]] = {
    "exec": direct.ExecFeedback,
    "tst": tst_exec.TstFeedback,
    "delegation": delegation_api.DelegationFeedback,
}
#: Info messages by the last topic level.
INFO: dict[str, type[WireModel]] = {
    "heartbeat": info.HeartBeat,
    "sensor_info": info.SensorInfo,
    "direct_execution_info": info.DirectExecutionInfo,
    "tst_execution_info": info.TstExecutionInfo,
    "delegation_info": info.DelegationInfo,
}
#: Info messages by their ``type`` field (for files without a topic).
INFO_TYPES: dict[str, type[WireModel]] = {m.model_fields["type"].default: m for m in INFO.values()}


def validate_model(model: type[M], data: Any, where: str) -> M:
    """``model.model_validate(data)``, with errors as a ``MessageError`` naming the fields."""
    if not isinstance(data, dict):
        raise MessageError(InputProblem(where, "", f"must be a JSON object, not {json_kind(data)}"))
    # Writers may leave com-uuid to its default (a fresh one); on the wire it is required, or the
    # answer could not name what it answers.
    problems: list[InputProblem] = []
    if "com_uuid" in model.model_fields and "com-uuid" not in data and "com_uuid" not in data:
        problems.append(InputProblem(where, "com-uuid", "missing"))

    # Raised outside the ``except`` blocks: pydantic's ValidationError takes no part in garbage
    # collection, so a frame that held it while a new exception was raised (its traceback) was
    # never freed, and with it the payload (measured: 100 pings with 1 MB com-uuids kept 201 MB).
    message: M | None = None
    try:
        message = model.model_validate(data)
    except ValidationError as exc:
        problems += validation_problems(exc, where)
    except RecursionError:  # pragma: no cover - JSON this deep is refused by json_value first
        problems.append(InputProblem(where, "", "nested too deeply"))
    if problems or message is None:
        raise MessageError(problems)
    return message


def parse_command(data: Any, api: str | None = None) -> WireModel:
    """A command from decoded JSON, by its ``command`` field; ``api`` (exec, tst, delegation)
    restricts the commands accepted; without it every API's commands are (``ping`` -> ``Ping``)."""
    where = f"{api}/command" if api else "command"
    if not isinstance(data, dict):
        raise MessageError(InputProblem(where, "", f"must be a JSON object, not {json_kind(data)}"))
    name = data.get("command")
    if not isinstance(name, str):
        message = "missing" if name is None else f"must be a string, not {json_kind(name)}"
        raise MessageError(InputProblem(where, "command", message))
    tables = [COMMANDS[api]] if api else list(COMMANDS.values())
    for table in tables:
        if name in table:
            if data.get("com-uuid") == "":  # a command's answer must name what it answers
                raise MessageError(InputProblem(name, "com-uuid", "must not be empty"))
            return validate_model(table[name], data, name)
    known = sorted({c for t in tables for c in t})
    raise MessageError(
        InputProblem(
            where, "command", f"unknown command {name!r}; expected one of {', '.join(known)}")
    )


def parse_message(data: Any) -> WireModel:
    """A message from decoded JSON without a topic (files, ``delegation validate``): a command
    by its ``command`` field, an info message by its ``type``, a response by ``response``, a
    feedback by ``status``. Trees are not messages: see ``delegation.tst``."""
    if isinstance(data, dict):
        if "command" in data:
            return parse_command(data)
        kind = data.get("type")
        if isinstance(kind, str) and kind in INFO_TYPES:
            return validate_model(INFO_TYPES[kind], data, kind)
        if "response" in data:
            model: type[WireModel] = tst_exec.TstResponse
            if "agent-uuid" in data or "task-uuid" in data:
                model = direct.ExecResponse
            elif any(k in data for k in ("plan", "bids", "mission", "missions", "agents")):
                model = delegation_api.DelegationResponse
            return validate_model(model, data, "response")
        if "status" in data:
            if "task-uuid" in data:
                return validate_model(direct.ExecFeedback, data, "feedback")
            if "node-uuid" in data:
                return validate_model(tst_exec.TstFeedback, data, "feedback")
            return validate_model(delegation_api.DelegationFeedback, data, "feedback")
    raise MessageError(InputProblem(
        "message", "", "not a command, info, response or feedback message"))


def decode(topic: str, payload: bytes | str) -> WireModel:
    """The model for ``payload`` arriving on ``topic`` (by its last levels), or ``MessageError``.

    ``.../heartbeat`` -> ``HeartBeat``, ``.../exec/command`` -> the command's model,
    ``.../tst/feedback`` -> ``TstFeedback``, ``.../sensor/speed`` -> ``SensorReading`` ...
    """
    levels = topic.rstrip("/").split("/") if isinstance(topic, str) else []
    last = levels[-1] if levels else ""
    parent = levels[-2] if len(levels) > 1 else ""
    if parent == "sensor" and last:
        value = sensor_value(last, json_value(payload, f"sensor/{last}"))
        return SensorReading(sensor=last, value=value)
    if last in INFO:
        return validate_model(INFO[last], json_value(payload, last), last)
    if parent in COMMANDS:
        where = f"{parent}/{last}"
        if last == "command":
            return parse_command(json_value(payload, where), parent)
        if last == "response":
            return validate_model(RESPONSES[parent], json_value(payload, where), where)
        if last == "feedback":
            return validate_model(FEEDBACK[parent], json_value(payload, where), where)
    raise MessageError(InputProblem("topic", "", f"no WARA-PS message is published on {topic!r}"))


def encode(model: WireModel | GeoPoint) -> bytes:
    """Canonical JSON bytes: hyphenated keys, keys sorted like the seed, no ``None`` fields.

    Raises ``MessageError`` for what JSON cannot hold (NaN in a raw field, nesting too deep).
    """
    try:
        data = model.to_wire()
        text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError, RecursionError) as exc:
        raise MessageError(InputProblem(
            type(model).__name__, "", f"cannot be encoded: {exc}")) from None
    return text.encode("utf-8")
