"""The reference TST engine with simulated units on a real broker."""

from __future__ import annotations

import uuid
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from delegation.engine import TstEngine
from delegation.fleet import make_unit
from delegation.geo import GeoPoint, LocalFrame
from delegation.local import LocalSystem
from delegation.runtime.settings import BrokerSettings
from delegation.sim import SimFleet

pytestmark = pytest.mark.mqtt

START = GeoPoint(latitude=57.7605, longitude=16.6815, altitude=40.0)
FRAME = LocalFrame(START.latitude, START.longitude)
TASKS = ["move-to", "move-path", "search-area", "look-at-position", "go-home"]
TIMEOUT = 30.0


def at(east: float, north: float) -> dict[str, Any]:
    return FRAME.geopoint(east, north, 40.0).to_wire()


def move(uid: str, unit: str, east: float, north: float) -> dict[str, Any]:
    return {
        "name": "move-to",
        "common_params": {"execunit": unit, "node-uuid": uid},
        "params": {"waypoint": at(east, north), "speed": "fast"},
    }


def ctl(kind: str, uid: str, *children: dict[str, Any]) -> dict[str, Any]:
    return {
        "name": kind,
        "common_params": {"execunit": "/op0", "node-uuid": uid},
        "children": list(children),
        "params": {},
    }


@pytest.fixture
def system(
    mqtt_settings: BrokerSettings, prefix: str
) -> Iterator[Callable[..., tuple[TstEngine, SimFleet]]]:
    started: list[Any] = []

    def make(example_agent: bool = False, speedup: float = 40.0) -> tuple[TstEngine, SimFleet]:
        units = [
            make_unit("dji0", "air", START, TASKS, speeds={"fast": 10.0}),
            make_unit("dji1", "air", FRAME.geopoint(50, 0, 40), TASKS, speeds={"fast": 10.0}),
        ]
        system = LocalSystem(units, settings=mqtt_settings, prefix=prefix, speedup=speedup,
                             example_agent=example_agent, service=False, ready_timeout=10.0)
        system.start()
        started.append(system)
        assert system.engine is not None and system.fleet is not None
        return system.engine, system.fleet

    yield make
    for thing in reversed(started):
        thing.stop()


def start_tst(tree: dict[str, Any]) -> dict[str, Any]:
    return {
        "com-uuid": str(uuid.uuid4()),
        "command": "start-tst",
        "receiver": "op0",
        "sender": "test",
        "tst": tree,
    }


def test_heartbeat_info_and_ping(system, collector, prefix: str) -> None:
    c = collector(f"{prefix}/unit/+/+/op0/#")
    engine, _ = system()
    hb = c.wait_json(f"{engine.base}/heartbeat")
    assert hb["levels"] == ["tst execution"] and hb["name"] == "op0"
    assert c.wait_json(f"{engine.base}/tst_execution_info")["trees-executing"] == []
    ping = {"com-uuid": str(uuid.uuid4()), "command": "ping", "sender": "test"}
    c.publish(f"{engine.base}/tst/command", ping)
    pong = c.wait_json(
        f"{engine.base}/tst/response", lambda d: d["response-to"] == ping["com-uuid"]
    )
    assert pong["response"] == "pong"


def test_tree_runs_to_succeeded(system, collector, prefix: str) -> None:
    engine, fleet = system()
    c = collector(f"{engine.base}/tst/#", f"{prefix}/unit/+/+/+/exec/command")
    tree = ctl(
        "seq",
        "root",
        ctl("conc", "both", move("a", "/dji0", 0, 100), move("b", "/dji1", 50, 100)),
        move("c", "/dji0", 0, 0),
    )
    cmd = start_tst(tree)
    c.publish(f"{engine.base}/tst/command", cmd)
    resp = c.wait_json(f"{engine.base}/tst/response", lambda d: d["response-to"] == cmd["com-uuid"])
    assert (resp["response"], resp["root-uuid"], resp["fail-reason"]) == ("started", "root", "")
    fb = f"{engine.base}/tst/feedback"
    final = c.wait_json(
        fb, lambda d: d["root-flag"] and d["status"] == "succeeded", timeout=TIMEOUT
    )
    assert final["node-uuid"] == "root" and final["fail-reason"] == ""
    statuses: dict[str, list[str]] = {}
    for d in c.json_on(fb):
        statuses.setdefault(d["node-uuid"], []).append(d["status"])
        assert d["root-flag"] is (d["node-uuid"] == "root")
    for node in ("a", "b", "c"):
        assert statuses[node] == ["active", "running", "succeeded"], node
    assert statuses["both"] == ["running", "succeeded"]
    # c started only after a (same unit, later in the seq); every task was started once.
    commands = c.json_on(f"{prefix}/unit/+/+/+/exec/command")
    started = [d["task"]["name"] for d in commands if d["command"] == "start-task"]
    assert started == ["move-to"] * 3
    assert fleet["dji0"].vehicle.odometer == pytest.approx(200.0, abs=1.0)


def test_abort_tree(system, collector, prefix: str) -> None:
    engine, fleet = system(speedup=1.0)
    c = collector(f"{engine.base}/tst/#")
    tree = ctl("seq", "root", move("far", "/dji0", 0, 5000), move("next", "/dji0", 0, 0))
    cmd = start_tst(tree)
    c.publish(f"{engine.base}/tst/command", cmd)
    fb = f"{engine.base}/tst/feedback"
    c.wait_json(fb, lambda d: d["node-uuid"] == "far" and d["status"] == "running", timeout=TIMEOUT)
    abort = {
        "com-uuid": str(uuid.uuid4()),
        "command": "signal-tst-tree",
        "node-uuid": "root",
        "sender": "test",
        "signal": "$abort",
    }
    c.publish(f"{engine.base}/tst/command", abort)
    ok = c.wait_json(f"{engine.base}/tst/response", lambda d: d["response-to"] == abort["com-uuid"])
    assert ok["response"] == "ok"
    final = c.wait_json(
        fb,
        lambda d: d["root-flag"] and d["status"] in ("aborted", "failed", "succeeded"),
        timeout=TIMEOUT,
    )
    assert final["status"] == "aborted"
    last = {d["node-uuid"]: d["status"] for d in c.json_on(fb)}
    assert last == {"root": "aborted", "far": "aborted", "next": "revoked"}
    assert not fleet["dji0"].vehicle.busy


def test_not_instantiated_tree_fails_with_the_node(system, collector, prefix: str) -> None:
    engine, _ = system()
    c = collector(f"{engine.base}/tst/#")
    tree = ctl("seq", "root", move("ok", "/dji0", 0, 10), move("free", "*", 0, 20))
    cmd = start_tst(tree)
    c.publish(f"{engine.base}/tst/command", cmd)
    resp = c.wait_json(f"{engine.base}/tst/response", lambda d: d["response-to"] == cmd["com-uuid"])
    assert resp["response"] == "failed"
    assert "root/children[1]" in resp["fail-reason"] and "free" in resp["fail-reason"]
    assert engine.inspect(lambda core: core.trees) == {}


def test_resent_start_tst_is_answered_again_and_runs_once(system, collector, prefix: str) -> None:
    engine, _ = system()
    c = collector(f"{engine.base}/tst/#", f"{prefix}/unit/+/+/+/exec/command")
    cmd = start_tst(ctl("seq", "root", move("a", "/dji0", 0, 50)))
    c.publish(f"{engine.base}/tst/command", cmd)
    c.publish(f"{engine.base}/tst/command", cmd)
    topic = f"{engine.base}/tst/response"
    c.wait_for(
        lambda m: sum(d["response-to"] == cmd["com-uuid"] for d in c.json_on(topic)) == 2,
        what="two answers",
    )
    answers = [d for d in c.json_on(topic) if d["response-to"] == cmd["com-uuid"]]
    assert answers[0] == answers[1] and answers[0]["response"] == "started"
    c.wait_json(
        f"{engine.base}/tst/feedback",
        lambda d: d["root-flag"] and d["status"] == "succeeded",
        timeout=TIMEOUT,
    )
    starts = [
        d for d in c.json_on(f"{prefix}/unit/+/+/+/exec/command") if d["command"] == "start-task"
    ]
    assert len(starts) == 1


def test_drives_an_example_agent_to_the_end(system, collector, prefix: str) -> None:
    engine, _ = system(example_agent=True)
    c = collector(f"{engine.base}/tst/#")
    tree = ctl(
        "conc",
        "root",
        ctl("seq", "s0", move("a", "/dji0", 0, 100), move("a2", "/dji0", 0, 0)),
        move("b", "/dji1", 50, 100),
    )
    cmd = start_tst(tree)
    c.publish(f"{engine.base}/tst/command", cmd)
    final = c.wait_json(
        f"{engine.base}/tst/feedback",
        lambda d: d["root-flag"] and d["status"] in ("succeeded", "failed", "aborted"),
        timeout=TIMEOUT,
    )
    assert final["status"] == "succeeded"
    last = {d["node-uuid"]: d["status"] for d in c.json_on(f"{engine.base}/tst/feedback")}
    assert set(last.values()) == {"succeeded"} and len(last) == 5
