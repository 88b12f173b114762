"""Simulated units over a real broker: the Heartbeat, Sensor and Direct Execution APIs."""

from __future__ import annotations

import json
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from delegation.fleet import make_unit
from delegation.geo import GeoPoint, LocalFrame
from delegation.messages import decode
from delegation.runtime.settings import BrokerSettings
from delegation.sim import SimFleet, SimUnit, agent_rates

pytestmark = pytest.mark.mqtt

START = GeoPoint(latitude=57.7605, longitude=16.6815, altitude=40.0)
FRAME = LocalFrame(START.latitude, START.longitude)
TASKS = ["move-to", "move-path", "search-area", "look-at-position", "go-home"]


def at(east: float, north: float) -> dict[str, Any]:
    return FRAME.geopoint(east, north, 40.0).to_wire()


@pytest.fixture
def sim(mqtt_settings: BrokerSettings, prefix: str) -> Iterator[Callable[..., SimUnit]]:
    made: list[SimUnit] = []

    def make(name: str = "dji0", **kw: Any) -> SimUnit:
        unit = make_unit(name, "air", START, TASKS, speeds={"standard": 5.0})
        s = SimUnit(mqtt_settings, unit, prefix=prefix, **kw)
        s.start()
        made.append(s)
        return s

    yield make
    for s in made:
        s.stop()


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
    return {
        "com-uuid": str(uuid.uuid4()),
        "command": "signal-task",
        "sender": "test",
        "signal": sig,
        "task-uuid": task_uuid,
    }


def test_publishes_heartbeat_info_and_sensors(sim, collector, prefix: str) -> None:
    c = collector(f"{prefix}/#")
    s = sim(rate=5.0)
    base = f"{prefix}/unit/air/simulation/dji0"
    assert s.base == base
    hb = decode(f"{base}/heartbeat", json.dumps(c.wait_json(f"{base}/heartbeat")).encode())
    assert hb.levels == ["sensor", "direct execution"]  # type: ignore[attr-defined]
    dei = c.wait_json(f"{base}/direct_execution_info")
    assert {t["name"] for t in dei["tasks-available"]} == set(TASKS)
    assert dei["tasks-executing"] == []
    info = c.wait_json(f"{base}/sensor_info")
    for sensor in info["sensor-data-provided"]:
        c.wait_json(f"{base}/sensor/{sensor}", what=f"sensor {sensor}")
    pos = c.wait_json(f"{base}/sensor/position")
    assert pos["rostype"] == "GeoPoint" and pos["latitude"] == pytest.approx(START.latitude)
    assert c.wait_json(f"{base}/sensor/battery_state")["percentage"] == 1.0


def test_ping_and_task_to_the_end(sim, collector, prefix: str) -> None:
    s = sim(speedup=40.0)
    c = collector(f"{s.base}/exec/#", f"{s.base}/direct_execution_info")
    ping = {"com-uuid": str(uuid.uuid4()), "command": "ping", "sender": "test"}
    c.publish(f"{s.base}/exec/command", ping)
    pong = c.wait_json(f"{s.base}/exec/response", lambda d: d["response-to"] == ping["com-uuid"])
    assert pong["response"] == "pong" and pong["agent-uuid"] == s.agent_uuid

    cmd = start_task("move-to", {"waypoint": at(0, 200), "speed": "standard"})  # 40 s simulated
    c.publish(f"{s.base}/exec/command", cmd)
    resp = c.wait_json(f"{s.base}/exec/response", lambda d: d["response-to"] == cmd["com-uuid"])
    assert (resp["response"], resp["fail-reason"], resp["task-uuid"]) == (
        "running",
        "",
        cmd["task-uuid"],
    )
    c.wait_json(
        f"{s.base}/direct_execution_info",
        lambda d: d["tasks-executing"] == [{"task-name": "move-to", "task-uuid": cmd["task-uuid"]}],
    )
    c.wait_json(
        f"{s.base}/exec/feedback",
        lambda d: d["task-uuid"] == cmd["task-uuid"] and d["status"] == "finished",
        timeout=20,
    )
    statuses = [
        d["status"]
        for d in c.json_on(f"{s.base}/exec/feedback")
        if d["task-uuid"] == cmd["task-uuid"]
    ]
    assert statuses == ["running", "finished"]

    query = {
        "com-uuid": str(uuid.uuid4()),
        "command": "query-status",
        "sender": "test",
        "task-uuid": cmd["task-uuid"],
    }
    c.publish(f"{s.base}/exec/command", query)
    answer = c.wait_json(f"{s.base}/exec/response", lambda d: d["response-to"] == query["com-uuid"])
    assert answer["response"] == "success"  # the seed's word for query-status (12.1)


def test_second_task_refused_and_unknown_task(sim, collector, prefix: str) -> None:
    s = sim()
    c = collector(f"{s.base}/exec/#")
    first = start_task("move-to", {"waypoint": at(0, 5000), "speed": "standard"})
    second = start_task("move-to", {"waypoint": at(0, 10), "speed": "standard"})
    unknown = start_task("navigate", {"waypoints": [at(0, 1)]})
    for cmd in (first, second, unknown):
        c.publish(f"{s.base}/exec/command", cmd)
    topic = f"{s.base}/exec/response"
    assert (
        c.wait_json(topic, lambda d: d["response-to"] == first["com-uuid"])["response"] == "running"
    )
    r2 = c.wait_json(topic, lambda d: d["response-to"] == second["com-uuid"])
    assert (r2["response"], r2["fail-reason"]) == ("failed", "A task is already running")
    r3 = c.wait_json(topic, lambda d: d["response-to"] == unknown["com-uuid"])
    assert (r3["response"], r3["fail-reason"]) == ("failed", "Task is not supported")


def test_abort_pause_continue(sim, collector, prefix: str) -> None:
    s = sim(speedup=5.0)
    c = collector(f"{s.base}/exec/#")
    cmd = start_task("move-to", {"waypoint": at(0, 5000), "speed": "standard"})
    t = cmd["task-uuid"]
    c.publish(f"{s.base}/exec/command", cmd)
    fb = f"{s.base}/exec/feedback"
    c.wait_json(fb, lambda d: d["task-uuid"] == t and d["status"] == "running")
    for sig, status in (("$pause", "paused"), ("$continue", "running"), ("$abort", "aborted")):
        msg = signal(t, sig)
        c.publish(f"{s.base}/exec/command", msg)
        r = c.wait_json(
            f"{s.base}/exec/response", lambda d, m=msg: d["response-to"] == m["com-uuid"]
        )
        assert r["response"] == "ok"
        c.wait_json(fb, lambda d, st=status: d["task-uuid"] == t and d["status"] == st, what=status)
    assert [d["status"] for d in c.json_on(fb) if d["task-uuid"] == t] == [
        "running",
        "paused",
        "running",
        "aborted",
    ]
    assert not s.vehicle.busy
    bad = signal("no-such-task", "$abort")
    c.publish(f"{s.base}/exec/command", bad)
    r = c.wait_json(f"{s.base}/exec/response", lambda d: d["response-to"] == bad["com-uuid"])
    assert (r["response"], r["fail-reason"]) == ("failed", "Invalid task-uuid")


def test_resent_com_uuid_is_answered_again_not_run_twice(sim, collector, prefix: str) -> None:
    s = sim()
    c = collector(f"{s.base}/exec/#")
    cmd = start_task("move-to", {"waypoint": at(0, 5000), "speed": "standard"})
    c.publish(f"{s.base}/exec/command", cmd)
    topic = f"{s.base}/exec/response"
    first = c.wait_json(topic, lambda d: d["response-to"] == cmd["com-uuid"])
    c.publish(f"{s.base}/exec/command", cmd)  # the link lost the answer: send the same again
    c.wait_for(
        lambda m: (
            m.topic == topic
            and sum(d["response-to"] == cmd["com-uuid"] for d in c.json_on(topic)) == 2
        ),
        what="the second answer",
    )
    answers = [d for d in c.json_on(topic) if d["response-to"] == cmd["com-uuid"]]
    assert answers[0] == answers[1] == first
    assert first["response"] == "running"  # not "A task is already running"
    assert s.commands_handled == 1
    running = [d for d in c.json_on(f"{s.base}/exec/feedback") if d["status"] == "running"]
    assert len(running) == 1


def test_example_agent_shapes(sim, collector, prefix: str) -> None:
    c = collector(f"{prefix}/#")
    s = sim("pa_x", example_agent=True, speedup=40.0)
    base = s.base
    hb = c.wait_json(f"{base}/heartbeat")
    assert hb["levels"] == ["sensor", "direct_execution"] and hb["rate"] == 3.0
    assert "tasks-executing" not in c.wait_json(f"{base}/direct_execution_info")
    assert c.wait_json(f"{base}/sensor/position")["type"] == "GeoPoint"
    speed = c.wait_for(lambda m: m.topic == f"{base}/sensor/speed", what="speed")
    assert isinstance(json.loads(speed.payload), float)  # a bare number
    ping = {"com-uuid": str(uuid.uuid4()), "command": "ping", "sender": "test"}
    no_speed = start_task("move-to", {"waypoint": at(0, 10)}, unit="pa_x")
    ok = start_task("move-to", {"waypoint": at(0, 100), "speed": "fast"}, unit="pa_x")
    for cmd in (ping, no_speed, ok):
        c.publish(f"{base}/exec/command", cmd)
    resp = c.wait_json(f"{base}/exec/response", lambda d: d["response-to"] == ok["com-uuid"])
    assert resp["response"] == "running"
    c.wait_json(
        f"{base}/exec/feedback",
        lambda d: d["task-uuid"] == ok["task-uuid"] and d["status"] == "finished",
        timeout=20,
    )
    # Like the example agent: no pong, and silence for a move-to without speed.
    answered = {d["response-to"] for d in c.json_on(f"{base}/exec/response")}
    assert ping["com-uuid"] not in answered and no_speed["com-uuid"] not in answered


def test_fleet_runs_one_unit_per_agent(mqtt_settings, collector, prefix: str) -> None:
    from delegation.scenario import scenario_from_dict

    scenario = scenario_from_dict(
        {
            "name": "two",
            "description": "two units",
            "agents": [
                {"name": "a0", "type": "air", "position": START.to_wire(), "tasks": ["move-to"]},
                {
                    "name": "b0",
                    "type": "surface",
                    "position": START.to_wire(),
                    "tasks": ["move-to"],
                    "rate": 4.0,
                },
            ],
            "mission": {"name": "move-to", "params": {"waypoint": START.to_wire()}},
        }
    )
    c = collector(f"{prefix}/unit/+/+/+/heartbeat")
    with SimFleet(mqtt_settings, scenario.units(), rates=agent_rates(scenario),
                  prefix=prefix) as fleet:
        assert len(fleet) == 2 and fleet["/b0"].rate == 4.0
        c.wait_json(f"{prefix}/unit/air/simulation/a0/heartbeat")
        c.wait_json(f"{prefix}/unit/surface/simulation/b0/heartbeat")
    assert not any(u.running for u in fleet)
