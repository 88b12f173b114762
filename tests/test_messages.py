"""Messages: decode by topic, encode canonically, lenient readers (docs/protocol.md §9), clear
errors."""

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


def test_com_uuids_stay_fresh_past_the_pool_and_in_a_forked_child() -> None:
    """The random bytes come from the OS a pool at a time: many uuids, all distinct version-4
    ones, and a forked child never hands out the parent's next ones."""
    import os
    import uuid

    many = [new_com_uuid() for _ in range(1000)]
    assert len(set(many)) == 1000
    assert all(uuid.UUID(u).version == 4 and uuid.UUID(u).variant == uuid.RFC_4122 for u in many)
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: its next uuid, to the parent
        os.write(write, new_com_uuid().encode())
        os._exit(0)
    os.close(write)
    try:
        child = os.read(read, 64).decode()
    finally:
        os.close(read)
        os.waitpid(pid, 0)
    assert len(child) == 36 and child != new_com_uuid()


# --------------------------------------------------------------------------- the example agent
# Messages exactly as the public WARA-PS L2 Python example agent builds them (json.dumps of dicts
# in its key order), docs/protocol.md §9.

AGENT_UUID = "5d0f1d0e-6f4a-4c58-9d7e-2f6c3a1b9e11"
TASKS_AVAILABLE = [
    {"name": n, "signals": ["$abort", "$enough", "$pause", "$continue"]}
    for n in ("go-home", "move-to", "move-path", "search-area")
]


def test_example_agent_heartbeat_with_extra_field() -> None:
    msg = decode(
        f"{BASE}/heartbeat",
        _bytes(
            {
                "name": "pa_x1y2",
                "agent-type": "air",
                "agent-description": "L2_agent_example",
                "agent-uuid": AGENT_UUID,
                "levels": ["sensor", "direct execution"],
                "rate": 3,
                "stamp": 1700000000.25,
                "type": "HeartBeat",
            }
        ),
    )
    assert isinstance(msg, HeartBeat)
    assert (msg.name, msg.agent_type, msg.agent_uuid, msg.rate) == (
        "pa_x1y2",
        "air",
        AGENT_UUID,
        3.0,
    )
    assert msg.levels == ["sensor", "direct execution"]
    assert "agent-description" not in json.loads(encode(msg))


@pytest.mark.parametrize(
    "levels",
    [
        ["sensor", "direct_execution"],
        ["sensor", "direct execution"],
        ["Sensor", "Direct-Execution"],
    ],
)
def test_both_levels_spellings_read_as_one(levels: list[str]) -> None:
    msg = decode(
        f"{BASE}/heartbeat",
        _bytes(
            {
                "agent-type": "air",
                "agent-uuid": "u",
                "levels": levels,
                "name": "dji0",
                "rate": 1.0,
                "stamp": 1.0,
                "type": "HeartBeat",
            }
        ),
    )
    assert isinstance(msg, HeartBeat)
    assert msg.levels == ["sensor", "direct execution"]
    assert json.loads(encode(msg))["levels"] == ["sensor", "direct execution"]


def test_example_agent_sensor_info() -> None:
    msg = decode(
        f"{BASE}/sensor_info",
        _bytes(
            {
                "name": "pa_x1y2",
                "rate": 3,
                "sensor-data-provided": ["position", "speed", "course", "heading"],
                "stamp": 1700000000.5,
                "type": "SensorInfo",
            }
        ),
    )
    assert isinstance(msg, SensorInfo)
    assert msg.sensor_data_provided == ["position", "speed", "course", "heading"]


def test_example_agent_direct_execution_info_without_tasks_executing() -> None:
    msg = decode(
        f"{BASE}/direct_execution_info",
        _bytes(
            {
                "type": "DirectExecutionInfo",
                "name": "pa_x1y2",
                "rate": 3,
                "stamp": 1700000000.5,
                "tasks-available": TASKS_AVAILABLE,
            }
        ),
    )
    assert isinstance(msg, DirectExecutionInfo)
    assert [t.name for t in msg.tasks_available] == [
        "go-home",
        "move-to",
        "move-path",
        "search-area",
    ]
    assert msg.tasks_available[0].signals == ["$abort", "$enough", "$pause", "$continue"]
    assert msg.tasks_executing == []
    assert "tasks-executing" not in json.loads(encode(msg))


@pytest.mark.parametrize(
    "entry",
    [
        {"task-name": "move-to", "task-uuid": "t-1"},
        {"name": "move-to", "uuid": "t-1"},
        {"name": "move-to", "uuid": "t-1", "started": 12.0},
    ],
)
def test_both_tasks_executing_shapes(entry: dict[str, object]) -> None:
    msg = decode(
        f"{BASE}/direct_execution_info",
        _bytes(
            {
                "name": "dji0",
                "rate": 1.0,
                "stamp": 2.0,
                "tasks-available": TASKS_AVAILABLE,
                "tasks-executing": [entry],
            }
        ),
    )
    assert isinstance(msg, DirectExecutionInfo)
    assert [(t.task_name, t.task_uuid) for t in msg.tasks_executing] == [("move-to", "t-1")]
    assert json.loads(encode(msg))["tasks-executing"] == [
        {"task-name": "move-to", "task-uuid": "t-1"}
    ]


@pytest.mark.parametrize("marker", [{"type": "GeoPoint"}, {"rostype": "GeoPoint"}, {}])
def test_position_with_either_marker(marker: dict[str, str]) -> None:
    payload = {"latitude": 57.76, "longitude": 16.68, "altitude": 29.8, **marker}
    msg = decode(f"{BASE}/sensor/position", _bytes(payload))
    assert isinstance(msg, SensorReading)
    assert msg.value == GeoPoint(latitude=57.76, longitude=16.68, altitude=29.8)
    assert json.loads(encode(msg)) == {
        "altitude": 29.8,
        "latitude": 57.76,
        "longitude": 16.68,
        "rostype": "GeoPoint",
    }


@pytest.mark.parametrize(
    ("payload", "expected"),
    [
        (b"3.0", 3.0),
        (b"3", 3.0),
        (b"-12.5", -12.5),
        (b'{"value": 3.0}', 3.0),
        (b'{"data": 4.5}', 4.5),
        (b'{"speed": 6}', 6.0),
        (b'"2.5"', 2.5),
    ],
)
def test_numeric_sensor_bare_or_object(payload: bytes, expected: float) -> None:
    assert parse_sensor("speed", payload) == expected
    for name in ("heading", "course"):
        assert parse_sensor(name, payload) == expected
    reading = decode(f"{BASE}/sensor/speed", payload)
    assert isinstance(reading, SensorReading)
    assert (reading.sensor, reading.value) == ("speed", expected)
    assert encode(reading) == json.dumps(expected).encode()


def test_other_sensors_are_plain_json() -> None:
    assert parse_sensor("camera_url", b'"rtsp://x/y"') == "rtsp://x/y"
    assert parse_sensor("battery_state", b'{"percentage": 0.8}') == {"percentage": 0.8}


@pytest.mark.parametrize(
    "payload",
    [
        b"fast",
        b'{"a": 1, "b": 2}',
        b"true",
        b"[1]",
        b"null",
        b"1e999",
        b'"inf"',
        b'"nan"',
        str(10**400).encode(),
        b'{"value": %d}' % 10**400,
    ],
)
def test_numeric_sensor_rejects_non_numbers(payload: bytes) -> None:
    with pytest.raises(MessageError) as info:
        parse_sensor("speed", payload)
    assert "sensor/speed" in str(info.value)


def test_position_out_of_range_names_the_field() -> None:
    with pytest.raises(MessageError) as info:
        parse_sensor("position", b'{"latitude": 91.0, "longitude": 16.0}')
    assert info.value.problems[0].where == "sensor/position"
    assert info.value.problems[0].field == "latitude"


def test_example_agent_start_task_responses() -> None:
    for response, reason in [
        ("running", ""),
        ("failed", "A task is already running"),
        ("failed", "Task is not supported"),
    ]:
        raw = {
            "agent-uuid": AGENT_UUID,
            "com-uuid": "c-2",
            "fail-reason": reason,
            "response": response,
            "response-to": "c-1",
            "task-uuid": "t-1",
        }
        msg = decode(f"{BASE}/exec/response", _bytes(raw))
        assert isinstance(msg, ExecResponse)
        assert (msg.response, msg.fail_reason, msg.task_uuid) == (response, reason, "t-1")
        assert json.loads(encode(msg)) == raw


def test_example_agent_signal_response_without_agent_uuid() -> None:
    raw = {"com-uuid": "c-3", "response": "ok", "response-to": "c-1", "task-uuid": "t-1"}
    msg = decode(f"{BASE}/exec/response", _bytes(raw))
    assert isinstance(msg, ExecResponse)
    assert (msg.response, msg.agent_uuid, msg.fail_reason) == ("ok", "", "")


@pytest.mark.parametrize("status", ["running", "finished", "failed", "aborted", "enough", "paused"])
def test_example_agent_feedback(status: str) -> None:
    raw = {"agent-uuid": AGENT_UUID, "com-uuid": "c-4", "status": status, "task-uuid": "t-1"}
    msg = decode(f"{BASE}/exec/feedback", _bytes(raw))
    assert isinstance(msg, ExecFeedback)
    assert msg.status == status
    assert encode(msg) == json.dumps(raw, sort_keys=True, separators=(",", ":")).encode()


def test_common_params_either_spelling_in_start_tst() -> None:
    for key in ("common_params", "common-params"):
        tree = {
            "name": "move-to",
            key: {"execunit": "/dji0", "node-uuid": "n1"},
            "params": {"waypoint": {"latitude": 57.0, "longitude": 16.0}},
        }
        msg = decode(
            "op0/tst/command",
            _bytes({"com-uuid": "c", "command": "start-tst", "sender": "me", "tst": tree}),
        )
        assert isinstance(msg, StartTst)
        assert msg.tst == tree  # kept verbatim, spelling and all
        assert json.loads(encode(msg))["tst"] == tree


# --------------------------------------------------------------------------- writers


def test_writers_use_hyphenated_sorted_keys_and_skip_none() -> None:
    cmd = StartTask(
        com_uuid="c1",
        execution_unit="dji0",
        sender="delegator0",
        task=TaskSpecMsg(name="move-to", params={"speed": "fast"}),
        task_uuid="t1",
    )
    assert encode(cmd) == (
        b'{"com-uuid":"c1","command":"start-task","execution-unit":"dji0","sender":"delegator0",'
        b'"task":{"name":"move-to","params":{"speed":"fast"}},"task-uuid":"t1"}'
    )
    assert "task-uuid" not in json.loads(encode(cmd.model_copy(update={"task_uuid": None})))


def test_fail_reason_follows_the_seed() -> None:
    assert "fail-reason" not in json.loads(encode(ExecResponse(response="pong", response_to="a")))
    assert (
        json.loads(encode(ExecResponse(response="running", response_to="a")))["fail-reason"] == ""
    )
    assert "fail-reason" not in json.loads(encode(TstResponse(response="ok", response_to="a")))
    started = json.loads(encode(TstResponse(response="started", response_to="a", root_uuid="r")))
    assert (started["fail-reason"], started["root-uuid"]) == ("", "r")
    ok = json.loads(encode(DelegationResponse(response="ok", response_to="a")))
    assert ok["fail-reason"] == ""  # docs/protocol.md §5: every delegation response carries it
    assert "plan" not in ok


def test_tst_feedback_round_trip() -> None:
    fb = TstFeedback(com_uuid="c", node_uuid="n", root_flag=True, status="succeeded")
    assert decode("op0/tst/feedback", encode(fb)) == fb
    assert json.loads(encode(fb)) == {
        "com-uuid": "c",
        "fail-reason": "",
        "node-uuid": "n",
        "root-flag": True,
        "status": "succeeded",
    }


@pytest.mark.parametrize(
    "model",
    [
        Ping(com_uuid="c", sender="s"),
        QueryStatus(com_uuid="c", sender="s", task_uuid="t"),
        SignalTask(com_uuid="c", sender="s", signal="$abort", task_uuid="t"),
        SignalTstNode(com_uuid="c", node_uuid="n", sender="s", signal="$enough"),
        SignalTstTree(com_uuid="c", node_uuid="n", sender="s", signal="$pause"),
        SignalUnit(com_uuid="c", sender="s", signal="$abort", unit="/dji0"),
        StartTst(com_uuid="c", receiver="delegator0", sender="s", tst={"name": "seq"}),
        Delegate(
            com_uuid="c",
            sender="s",
            tst={"name": "seq"},
            strategy="auction",
            objective="makespan",
            time_limit=2.5,
            start=True,
        ),
        GetBids(com_uuid="c", sender="s", tst={"name": "move-to"}),
        QueryMission(com_uuid="c", root_uuid="r", sender="s"),
        ListMissions(com_uuid="c", sender="s"),
        ListAgents(com_uuid="c", sender="s"),
        CancelMission(com_uuid="c", root_uuid="r", sender="s"),
        DelegationPing(com_uuid="c", sender="s"),
        DelegationResponse(
            com_uuid="c",
            response="ok",
            response_to="r",
            plan={"feasible": True},
            agents=[{"name": "dji0"}],
        ),
        DelegationFeedback(com_uuid="c", root_uuid="r", status="planned"),
        ExecFeedback(agent_uuid="a", com_uuid="c", status="running", task_uuid="t"),
        TstResponse(com_uuid="c", fail_reason="no unit", response="failed", response_to="r"),
    ],
    ids=lambda m: type(m).__name__,
)
def test_every_model_round_trips_through_its_topic(model: object) -> None:
    from delegation.messages import WireModel

    assert isinstance(model, WireModel)
    api = {
        Ping: "exec",
        QueryStatus: "exec",
        SignalTask: "exec",
        ExecFeedback: "exec",
        SignalTstNode: "tst",
        SignalTstTree: "tst",
        SignalUnit: "tst",
        StartTst: "tst",
        TstResponse: "tst",
    }.get(type(model), "delegation")
    kind = (
        "response"
        if "Response" in type(model).__name__
        else "feedback"
        if "Feedback" in type(model).__name__
        else "command"
    )
    again = decode(f"x/{api}/{kind}", encode(model))
    assert again == model
    assert encode(again) == encode(model)


def test_delegate_defaults() -> None:
    msg = decode(
        "delegator0/delegation/command",
        _bytes({"com-uuid": "c", "command": "delegate", "sender": "s", "tst": {"name": "seq"}}),
    )
    assert isinstance(msg, Delegate)
    assert (msg.strategy, msg.objective, msg.time_limit, msg.start) == (None, None, None, False)


def test_commands_are_chosen_per_api() -> None:
    assert isinstance(decode("a/exec/command", _bytes({"command": "ping", "com-uuid": "c"})), Ping)
    assert isinstance(
        decode("a/delegation/command", _bytes({"command": "ping", "com-uuid": "c"})), DelegationPing
    )
    assert isinstance(parse_command({"command": "list-agents", "com-uuid": "c"}), ListAgents)


# --------------------------------------------------------------------------- errors


def _problems(topic: str, payload: bytes) -> list[str]:
    with pytest.raises(MessageError) as info:
        decode(topic, payload)
    return [str(p) for p in info.value.problems]


def test_invalid_json_is_named() -> None:
    (problem,) = _problems(f"{BASE}/exec/command", b'{"command": "ping",')
    assert problem.startswith("exec/command: invalid JSON")
    assert "line 1" in problem


@pytest.mark.parametrize(
    "payload", [b"\xff\xfe", b"NaN", b'{"rate": Infinity}', b'{"rate": 1e999}', b"[" * 100000]
)
def test_undecodable_bytes_are_message_errors(payload: bytes) -> None:
    assert _problems(f"{BASE}/heartbeat", payload)


def test_unknown_command_lists_the_known_ones() -> None:
    (problem,) = _problems("op0/tst/command", _bytes({"command": "start-task", "com-uuid": "c"}))
    assert "command: unknown command 'start-task'" in problem
    assert "start-tst" in problem


def test_missing_and_wrong_fields_are_each_named() -> None:
    problems = _problems(
        "op0/tst/command", _bytes({"command": "signal-tst-node", "com-uuid": 5, "signal": "$abort"})
    )
    assert "signal-tst-node: com-uuid: Input should be a valid string, got 5" in problems
    assert "signal-tst-node: node-uuid: missing" in problems


def test_nested_field_path_is_named() -> None:
    problems = _problems(
        f"{BASE}/direct_execution_info",
        _bytes({"name": "d", "rate": 1, "stamp": 1, "tasks-available": [{"name": "a"}, {"x": 1}]}),
    )
    assert problems == ["direct_execution_info: tasks-available[1].name: missing"]


def test_start_tst_tree_must_be_an_object() -> None:
    problems = _problems("op0/tst/command", _bytes({"command": "start-tst", "tst": [1]}))
    assert any(p.startswith("start-tst: tst: Input should be a valid dictionary") for p in problems)


def test_unknown_topic() -> None:
    (problem,) = _problems("waraps/unit/air/simulation/dji0/something", b"{}")
    assert "no WARA-PS message" in problem


def test_a_non_object_message() -> None:
    (problem,) = _problems(f"{BASE}/heartbeat", b"[1, 2]")
    assert problem == "heartbeat: must be a JSON object, not a list"


def test_numbers_beyond_float_range_are_refused_everywhere() -> None:
    tree = b'{"name": "move-to", "params": {"waypoint": {"latitude": 1e400, "longitude": 0}}}'
    payload = b'{"com-uuid": "c", "command": "start-tst", "sender": "s", "tst": ' + tree + b"}"
    (problem,) = _problems("op0/tst/command", payload)
    assert "out of range" in problem
    huge_rate = b'{"agent-type": "a", "agent-uuid": "u", "name": "n", "rate": %d, "stamp": 1}'
    (problem,) = _problems(f"{BASE}/heartbeat", huge_rate % 10**400)
    assert problem.startswith("heartbeat: rate: Input should be a valid number")


def _nested_tree(depth: int) -> dict[str, object]:
    node: dict[str, object] = {
        "name": "move-to",
        "params": {"waypoint": {"latitude": 1.0, "longitude": 2.0}},
    }
    for _ in range(depth - 1):
        node = {"name": "seq", "children": [node]}
    return node


def test_the_deepest_tree_the_parser_admits_travels_in_a_message() -> None:
    from delegation.tst import MAX_DEPTH, parse_and_validate

    msg = StartTst(com_uuid="c", sender="s", tst=_nested_tree(MAX_DEPTH))
    again = decode("op0/tst/command", encode(msg))
    assert isinstance(again, StartTst)
    assert parse_and_validate(again.tst).name == "seq"


@pytest.mark.parametrize("depth", [120, 500, 5000])
def test_json_nested_too_deeply_is_refused_on_reading(depth: int) -> None:
    tst = '{"name": "seq", "children": [' * (depth - 1) + '{"name": "move-to"}' + "]}" * (depth - 1)
    payload = b'{"com-uuid": "c", "command": "start-tst", "tst": %s}' % tst.encode()
    (problem,) = _problems("op0/tst/command", payload)
    assert "nested" in problem and "deep" in problem


def test_encode_refuses_what_json_cannot_hold() -> None:
    with pytest.raises(MessageError):
        encode(StartTst(com_uuid="c", tst={"x": float("nan")}))
    with pytest.raises(MessageError):
        encode(StartTst(com_uuid="c", tst=_nested_tree(200)))
