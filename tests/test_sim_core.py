"""The simulated units' cores, message by message, without a broker: bytes and ``now`` in,
messages out."""

from __future__ import annotations

import json
import uuid
from typing import Any

import pytest

from delegation.fleet import make_unit
from delegation.geo import GeoPoint, LocalFrame
from delegation.messages import decode
from delegation.runtime.core import Core, Effects, Outgoing
from delegation.sim import SIM_SIGNALS, ExampleAgentCore, SimUnitCore
from delegation.topics import QOS_COMMAND, QOS_PERIODIC

PREFIX = "t"
START = GeoPoint(latitude=57.7605, longitude=16.6815, altitude=40.0)
FRAME = LocalFrame(START.latitude, START.longitude)
TASKS = ["move-to", "move-path", "search-area", "look-at-position", "go-home"]


def at(east: float, north: float) -> dict[str, Any]:
    return FRAME.geopoint(east, north, 40.0).to_wire()


def sim(name: str = "dji0", **kw: Any) -> SimUnitCore:
    unit = make_unit(name, "air", START, TASKS, speeds={"standard": 5.0, "fast": 10.0})
    return SimUnitCore(unit, prefix=PREFIX, **kw)


def example(name: str = "pa_x", **kw: Any) -> ExampleAgentCore:
    unit = make_unit(name, "air", START, TASKS, speeds={"standard": 5.0, "fast": 10.0})
    return ExampleAgentCore(unit, prefix=PREFIX, **kw)


def start_task(name: str, params: dict[str, Any], unit: str = "dji0", **kw: Any) -> dict[str, Any]:
    return {
        "com-uuid": kw.get("com_uuid", str(uuid.uuid4())),
        "command": "start-task",
        "execution-unit": f"/{unit}",
        "sender": "test",
        "task": {"name": name, "params": params},
        "task-uuid": kw.get("task_uuid", str(uuid.uuid4())),
    }


def signal(task_uuid: str, sig: str) -> dict[str, Any]:
    return {"com-uuid": str(uuid.uuid4()), "command": "signal-task", "signal": sig,
            "task-uuid": task_uuid}


def send(core: SimUnitCore | ExampleAgentCore, msg: dict[str, Any] | bytes,
         now: float = 0.0) -> Effects:
    payload = msg if isinstance(msg, bytes) else json.dumps(msg).encode()
    return core.on_message(core.identity.topic("exec/command"), payload, now)


def on(messages: Effects | list[Outgoing], core: Any, rest: str) -> list[Any]:
    """The decoded JSON published on one of the unit's topics, in order."""
    outs = messages.publish if isinstance(messages, Effects) else messages
    return [json.loads(o.payload) for o in outs if o.topic == core.identity.topic(rest)]


def only(messages: Effects | list[Outgoing], core: Any, rest: str) -> Any:
    found = on(messages, core, rest)
    assert len(found) == 1, f"{rest}: {found}"
    return found[0]


def run(core: SimUnitCore | ExampleAgentCore, start: float, seconds: float,
        step: float = 0.5) -> Effects:
    effects = Effects()
    now = start
    while now < start + seconds:
        now += step
        effects.extend(core.on_tick(now))
    return effects


# --------------------------------------------------------------------------- the seed's protocol


def test_is_a_core_with_its_identity() -> None:
    core = sim(rate=4.0)
    assert isinstance(core, Core)
    assert core.base == f"{PREFIX}/unit/air/simulation/dji0"
    assert core.subscriptions() == [f"{core.base}/exec/command"]
    assert core.status_period == pytest.approx(0.25)
    assert sim().status_period == 1.0
    with pytest.raises(ValueError, match="speedup"):
        sim(speedup=0.0)


def test_status_from_models() -> None:
    core = sim(rate=5.0)
    status = core.status(10.0, 1000.0)
    assert {o.qos for o in status} == {QOS_PERIODIC}
    hb = only(status, core, "heartbeat")
    assert hb["levels"] == ["sensor", "direct execution"]
    assert (hb["rate"], hb["stamp"], hb["agent-uuid"]) == (5.0, 1000.0, core.agent_uuid)
    info = only(status, core, "sensor_info")
    assert info["sensor-data-provided"] == ["position", "speed", "course", "heading",
                                            "battery_state"]
    for sensor in info["sensor-data-provided"]:
        only(status, core, f"sensor/{sensor}")
    dei = only(status, core, "direct_execution_info")
    assert dei["tasks-executing"] == []  # said explicitly, unlike the model's default
    assert {t["name"] for t in dei["tasks-available"]} == set(TASKS)
    assert all(t["signals"] == list(SIM_SIGNALS) for t in dei["tasks-available"])
    pos = only(status, core, "sensor/position")
    assert pos["rostype"] == "GeoPoint" and pos["latitude"] == pytest.approx(START.latitude)
    assert only(status, core, "sensor/speed") == {"value": 0.0}
    assert only(status, core, "sensor/battery_state") == {"percentage": 1.0, "charging": False}
    for out in status:  # every message reads back as what the seed says
        decode(out.topic, out.payload)


def test_start_task_answers_feeds_back_and_says_tasks_executing_at_once() -> None:
    core = sim(speedup=10.0)
    core.status(0.0, 1000.0)  # the unit learns wall time from its periodic status
    core.on_tick(0.0)
    cmd = start_task("move-to", {"waypoint": at(0, 200), "speed": "standard"})  # 40 s at 5 m/s
    effects = send(core, cmd, now=2.0)
    [resp] = [o for o in effects.publish if o.topic.endswith("exec/response")]
    assert resp.qos == QOS_COMMAND
    answer = json.loads(resp.payload)
    assert (answer["response"], answer["fail-reason"], answer["task-uuid"]) == (
        "running", "", cmd["task-uuid"])
    assert answer["response-to"] == cmd["com-uuid"] and answer["agent-uuid"] == core.agent_uuid
    assert [f["status"] for f in on(effects, core, "exec/feedback")] == ["running"]
    dei = only(effects, core, "direct_execution_info")
    assert dei["tasks-executing"] == [{"task-name": "move-to", "task-uuid": cmd["task-uuid"]}]
    assert only(effects, core, "heartbeat")["stamp"] == 1002.0
    assert core.commands_handled == 1 and core.vehicle.busy

    assert on(core.on_tick(3.0), core, "exec/feedback") == []  # 10 s simulated: still flying
    done = run(core, 3.0, 3.5)  # 35 s more simulated
    assert [(f["task-uuid"], f["status"]) for f in on(done, core, "exec/feedback")] == [
        (cmd["task-uuid"], "finished")]
    assert only(done, core, "direct_execution_info")["tasks-executing"] == []
    assert core.vehicle.odometer == pytest.approx(200.0, abs=0.5)


def test_resent_com_uuid_gets_the_same_bytes_and_runs_once() -> None:
    core = sim()
    cmd = start_task("move-to", {"waypoint": at(0, 5000), "speed": "standard"})
    first = send(core, cmd, now=1.0)
    again = send(core, cmd, now=2.0)
    [resp] = [o for o in first.publish if o.topic.endswith("exec/response")]
    assert again.publish == [resp]  # the answer alone, byte for byte: no feedback, no status
    assert json.loads(resp.payload)["response"] == "running"  # not "already running"
    assert core.commands_handled == 1 and len(core.vehicle.tasks) == 1
    entry = core.commands.get(("exec", cmd["com-uuid"]))
    assert entry is not None and entry.resends == 1


def test_ping_and_query_status() -> None:
    core = sim()
    ping = {"com-uuid": "p1", "command": "ping", "sender": "test"}
    pong = only(send(core, ping), core, "exec/response")
    assert pong == {"agent-uuid": core.agent_uuid, "com-uuid": pong["com-uuid"],
                    "response": "pong", "response-to": "p1"}  # no fail-reason on pong
    cmd = start_task("move-to", {"waypoint": at(0, 5000), "speed": "standard"})
    send(core, cmd)
    for task_uuid, state in ((cmd["task-uuid"], "running"), ("nope", "unknown")):
        query = {"com-uuid": str(uuid.uuid4()), "command": "query-status", "task-uuid": task_uuid}
        answer = only(send(core, query), core, "exec/response")
        assert (answer["response"], answer["task-uuid"]) == (state, task_uuid)


def test_signals_pause_continue_abort_and_a_wrong_task() -> None:
    core = sim(speedup=5.0)
    cmd = start_task("move-to", {"waypoint": at(0, 5000), "speed": "standard"})
    t = cmd["task-uuid"]
    send(core, cmd)
    for sig, status in (("$pause", "paused"), ("$continue", "running"), ("$abort", "aborted")):
        effects = send(core, signal(t, sig))
        assert only(effects, core, "exec/response")["response"] == "ok"
        assert [f["status"] for f in on(effects, core, "exec/feedback")] == [status]
    # The task ended: tasks-executing says so at once.
    assert only(effects, core, "direct_execution_info")["tasks-executing"] == []
    assert not core.vehicle.busy
    wrong = only(send(core, signal("no-such-task", "$abort")), core, "exec/response")
    assert (wrong["response"], wrong["fail-reason"]) == ("failed", "Invalid task-uuid")


def test_enough_finishes_an_open_ended_task() -> None:
    core = sim()
    cmd = start_task("look-at-position", {"geopoint": at(10, 10)})
    send(core, cmd)
    effects = send(core, signal(cmd["task-uuid"], "$enough"))
    assert [f["status"] for f in on(effects, core, "exec/feedback")] == ["finished"]


def test_refusals() -> None:
    core = sim()
    first = start_task("move-to", {"waypoint": at(0, 5000), "speed": "standard"})
    second = start_task("move-to", {"waypoint": at(0, 10), "speed": "standard"})
    unknown = start_task("navigate", {"waypoints": [at(0, 1)]})
    elsewhere = start_task("move-to", {"waypoint": at(0, 10)}, unit="other")
    send(core, first)
    for cmd, reason in ((second, "A task is already running"), (unknown, "Task is not supported"),
                        (elsewhere, "execution-unit /other is not dji0")):
        effects = send(core, cmd)
        answer = only(effects, core, "exec/response")
        assert (answer["response"], answer["fail-reason"]) == ("failed", reason)
        assert on(effects, core, "exec/feedback") == []
    # A camera task runs alongside a flight.
    look = only(send(core, start_task("look-at-position", {"geopoint": at(0, 5)})), core,
                "exec/response")
    assert look["response"] == "running"


def test_bad_and_unsupported_commands() -> None:
    core = sim()
    bad = {"com-uuid": "b1", "command": "start-task", "sender": "test"}  # no task
    effects = send(core, bad)
    answer = only(effects, core, "exec/response")
    assert answer["response"] == "failed" and answer["fail-reason"]
    assert send(core, bad).publish == effects.publish  # answered again, same bytes
    assert send(core, b"{not json").publish == []
    assert send(core, {"command": "start-task"}).publish == []  # no com-uuid: no one to answer
    odd = {"com-uuid": "s1", "command": "signal-executor", "signal": "$abort"}
    answer = only(send(core, odd), core, "exec/response")
    assert (answer["response"], answer["fail-reason"]) == (
        "failed", "signal-executor is not supported")
    assert core.commands_handled == 1


def test_ticks_step_the_vehicle_by_elapsed_time_times_speedup() -> None:
    core = sim(speedup=2.0)
    send(core, start_task("move-to", {"waypoint": at(0, 5000), "speed": "standard"}))
    core.on_tick(100.0)  # the first tick only starts the clock
    assert core.vehicle.odometer == 0.0
    core.on_tick(101.0)
    assert core.vehicle.odometer == pytest.approx(10.0)  # 2 s simulated at 5 m/s


# --------------------------------------------------------------------------- the example agent


def test_example_agent_status_shapes() -> None:
    core = example()
    assert core.rate == 3.0 and core.status_period == pytest.approx(1 / 3)
    send(core, start_task("move-to", {"waypoint": at(0, 500), "speed": "fast"}, unit="pa_x"))
    status = core.status(0.0, 1000.0)
    hb = only(status, core, "heartbeat")
    assert hb["levels"] == ["sensor", "direct_execution"]
    assert hb["agent-description"] == "L2_agent_example"
    dei = only(status, core, "direct_execution_info")
    assert "tasks-executing" not in dei  # even with a task running
    info = only(status, core, "sensor_info")
    assert info["sensor-data-provided"] == ["position", "speed", "course", "heading"]
    assert on(status, core, "sensor/battery_state") == []
    assert only(status, core, "sensor/position")["type"] == "GeoPoint"
    for sensor in ("speed", "course", "heading"):
        assert isinstance(only(status, core, f"sensor/{sensor}"), float)  # a bare number


def test_example_agent_is_silent_without_speed_and_for_ping_and_query() -> None:
    core = example()
    no_speed = start_task("move-to", {"waypoint": at(0, 10)}, unit="pa_x")
    assert send(core, no_speed).publish == []
    assert not core.vehicle.tasks
    for msg in ({"com-uuid": "p", "command": "ping"},
                {"com-uuid": "q", "command": "query-status", "task-uuid": "x"}, b"{oops"):
        assert send(core, msg).publish == []
    # A task that needs no speed is answered.
    look = send(core, start_task("look-at-position", {"geopoint": at(0, 5)}, unit="pa_x"))
    assert only(look, core, "exec/response")["response"] == "running"


def test_example_agent_task_signals_and_one_task_at_a_time() -> None:
    core = example(speedup=10.0)
    cmd = start_task("move-to", {"waypoint": at(0, 100), "speed": "fast"}, unit="pa_x")
    effects = send(core, cmd)
    answer = only(effects, core, "exec/response")
    assert (answer["response"], answer["fail-reason"], answer["agent-uuid"]) == (
        "running", "", core.agent_uuid)
    assert answer["com-uuid"] != cmd["com-uuid"]
    assert [f["status"] for f in on(effects, core, "exec/feedback")] == ["running"]
    assert on(effects, core, "direct_execution_info") == []  # no tasks-executing to update
    assert {o.qos for o in effects.publish} == {QOS_PERIODIC}
    # No com-uuid history: a re-send runs again, and any second task is refused.
    assert only(send(core, cmd), core, "exec/response")["fail-reason"] == (
        "A task is already running")
    look = start_task("look-at-position", {"geopoint": at(0, 5)}, unit="pa_x")
    assert only(send(core, look), core, "exec/response")["response"] == "failed"
    wrong = send(core, signal("other", "$pause"))
    reply = only(wrong, core, "exec/response")
    assert (reply["response"], reply["fail-reason"], reply["task-uuid"]) == (
        "failed", "Invalid task-uuid", cmd["task-uuid"])
    assert "agent-uuid" not in reply
    assert [f["status"] for f in on(wrong, core, "exec/feedback")] == ["failed"]
    enough = send(core, signal(cmd["task-uuid"], "$enough"))
    assert only(enough, core, "exec/response")["response"] == "ok"
    assert [f["status"] for f in on(enough, core, "exec/feedback")] == ["enough"]
    assert not core.vehicle.tasks


def test_example_agent_finishes_a_flight() -> None:
    core = example(speedup=10.0)
    cmd = start_task("move-to", {"waypoint": at(0, 100), "speed": "fast"}, unit="pa_x")
    send(core, cmd)
    core.on_tick(0.0)
    done = run(core, 0.0, 1.5)  # 100 m at 10 m/s: 10 s simulated
    assert [f["status"] for f in on(done, core, "exec/feedback")] == ["finished"]
