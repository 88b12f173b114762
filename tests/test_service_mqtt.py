"""The delegation service on a real broker (mosquitto and amqtt), with real simulated units.

These tests need no engine: commands that only plan or inspect, bad commands, and that planning
does not block the receive path. Execution end to end is in ``test_e2e_service.py``.
"""

from __future__ import annotations

import json
import threading
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from delegation.fleet import make_unit
from delegation.geo import GeoPoint, LocalFrame
from delegation.local import LocalSystem
from delegation.runtime.settings import BrokerSettings
from delegation.service import DelegationService, Job, ServiceConfig, run_job

pytestmark = pytest.mark.mqtt

ORIGIN = GeoPoint(latitude=57.7605, longitude=16.6815)
FRAME = LocalFrame(ORIGIN.latitude, ORIGIN.longitude)


def pt(x: float, y: float) -> dict[str, Any]:
    return FRAME.geopoint(x, y, 30.0).to_wire()


@pytest.fixture
def stack(mqtt_settings: BrokerSettings, prefix: str) -> Iterator[DelegationService]:
    units = [
        make_unit("dji0", "air", FRAME.geopoint(0, 0, 30), ["move-to", "move-path", "search-area"]),
        make_unit("dji1", "air", FRAME.geopoint(200, 0, 30), ["move-to", "move-path"]),
        make_unit("usv0", "surface", FRAME.geopoint(0, -200, 0), ["move-to"]),
    ]
    with LocalSystem(units, settings=mqtt_settings, prefix=prefix, engine=False,
                     rates={u.name: 5.0 for u in units}) as system:
        assert system.service is not None
        yield system.service


Send = Callable[..., dict[str, Any]]


@pytest.fixture
def send(stack: DelegationService, collector: Callable[..., Any]) -> Send:
    base = stack.config.base_topic
    c = collector(f"{base}/+/response", f"{base}/+/feedback")

    def _send(command: dict[str, Any] | bytes, api: str = "delegation", com: str | None = None,
              timeout: float = 15.0) -> dict[str, Any]:
        topic = f"{base}/{api}/response"
        if isinstance(command, bytes):
            # Unreadable: the answer cannot name a com-uuid, so wait for one more such answer.
            before = sum(1 for d in c.json_on(topic) if d.get("response-to") == "")
            c.publish(f"{base}/{api}/command", command)
            c.wait_for(lambda _m: sum(1 for d in c.json_on(topic)
                                      if d.get("response-to") == "") > before,
                       timeout=timeout, what="an answer to an unreadable command")
            return [d for d in c.json_on(topic) if d.get("response-to") == ""][-1]
        com = com or str(uuid.uuid4())
        payload = json.dumps({"com-uuid": com, "sender": "test", **command}).encode()
        c.publish(f"{base}/{api}/command", payload)
        return c.wait_json(topic, lambda d: d.get("response-to") == com,
                           timeout=timeout, what=f"answer to {com}")

    _send.collector = c  # type: ignore[attr-defined]
    return _send


def tree(n: int = 3) -> dict[str, Any]:
    return {"name": "conc", "common_params": {"node-uuid": str(uuid.uuid4())},
            "children": [{"name": "move-to", "common_params": {"execunit": "*"},
                          "params": {"waypoint": pt(100.0 * i, 150.0 + 30 * i)}}
                         for i in range(n)]}


def test_ping_agents_bids_and_plan(send: Send) -> None:
    assert send({"command": "ping"})["response"] == "pong"
    agents = send({"command": "list-agents"})["agents"]
    assert sorted(a["name"] for a in agents) == ["dji0", "dji1", "usv0"]
    assert all(a["alive"] and a["position"] for a in agents)
    bids = send({"command": "get-bids", "tst": tree(2)})["bids"]
    assert len(bids) == 6
    answer = send({"command": "delegate", "tst": tree(3), "strategy": "auction"})
    assert answer["response"] == "ok" and answer["fail-reason"] == ""
    plan = answer["plan"]
    assert plan["feasible"] and len(plan["assignments"]) == 3
    assert {a["execunit"] for a in plan["assignments"]} <= {"/dji0", "/dji1", "/usv0"}


def test_bad_commands_fail_and_the_service_keeps_serving(send: Send) -> None:
    cases: list[tuple[dict[str, Any] | bytes, str, str]] = [
        (b"{this is not json", "tst", "invalid JSON"),
        (b"[1, 2]", "delegation", "JSON object"),
        ({"command": "make-coffee"}, "delegation", "make-coffee"),
        ({"command": "start-tst", "tst": {"name": "move-to", "params": {}}}, "tst", "waypoint"),
        ({"command": "start-tst", "tst": {"name": "seq", "children": {"a": 1}}}, "tst",
         "children"),
        ({"command": "query-mission", "root-uuid": "no-such-mission"}, "delegation",
         "no-such-mission"),
        ({"command": "delegate", "tst": tree(1), "strategy": "psychic"}, "delegation", "psychic"),
    ]
    for command, api, expect in cases:
        data = send(command, api=api)
        assert data["response"] == "failed", (command, data)
        assert expect in data["fail-reason"], (command, data)
    assert send({"command": "ping"})["response"] == "pong"
    assert send({"command": "delegate", "tst": tree(2)})["response"] == "ok"


def test_start_tst_without_engine_fails_naming_it(send: Send) -> None:
    answer = send({"command": "start-tst", "tst": tree(2)}, api="tst")
    assert answer["response"] == "failed" and "'op0'" in answer["fail-reason"]


def test_planning_does_not_block_the_receive_path(
    mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any]
) -> None:
    release = threading.Event()
    planning = threading.Event()

    def held_planner(job: Job) -> Any:
        planning.set()
        release.wait(30)
        return run_job(job)

    service = DelegationService(mqtt_settings, ServiceConfig(prefix=prefix), planner=held_planner)
    base = service.config.base_topic
    c = collector(f"{base}/delegation/response")
    service.start()
    try:
        slow = str(uuid.uuid4())
        c.publish(f"{base}/delegation/command",
                  json.dumps({"com-uuid": slow, "command": "get-bids", "sender": "t",
                              "tst": tree(2)}).encode())
        assert planning.wait(10)
        ping = str(uuid.uuid4())
        c.publish(f"{base}/delegation/command",
                  json.dumps({"com-uuid": ping, "command": "ping", "sender": "t"}).encode())
        pong = c.wait_json(f"{base}/delegation/response", lambda d: d.get("response-to") == ping)
        assert pong["response"] == "pong"
        assert not any(d.get("response-to") == slow for d in c.json_on(f"{base}/+/response"))
        release.set()
        bids = c.wait_json(f"{base}/delegation/response", lambda d: d.get("response-to") == slow)
        assert bids["response"] == "ok" and bids["bids"] == []  # no units on this broker prefix
    finally:
        release.set()
        service.stop()
