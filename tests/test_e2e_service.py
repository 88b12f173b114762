"""End to end on a real broker: partial tree -> service -> reference engine -> simulated units.

Everything is real: the broker (mosquitto and amqtt), the simulated units, the reference TST
engine and the delegation service; the test only talks MQTT to the service and watches topics.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from delegation.engine import TstEngine
from delegation.fleet import UnitState, make_unit
from delegation.geo import LocalFrame
from delegation.local import LocalSystem
from delegation.runtime.settings import BrokerSettings
from delegation.service import DelegationService, ServiceConfig
from delegation.sim import SimFleet
from delegation.tst.node import parse_tree, walk

pytestmark = [pytest.mark.mqtt, pytest.mark.slow]

FRAME = LocalFrame(57.7605, 16.6815)
AIR_TASKS = ["move-to", "move-path", "search-area", "look-at-position"]


def pt(x: float, y: float) -> dict[str, Any]:
    return FRAME.geopoint(x, y, 30.0).to_wire()


def move_to(x: float, y: float, **common: Any) -> dict[str, Any]:
    return {"name": "move-to", "common_params": dict(common), "params": {"waypoint": pt(x, y)}}


@dataclass
class Runtime:
    service: DelegationService
    engine: TstEngine
    fleet: SimFleet
    watch: Any  # conftest.Collector on the service's, the engine's and the units' topics
    base: str
    engine_base: str
    prefix: str

    def send(self, command: dict[str, Any], api: str = "tst", com: str | None = None,
             timeout: float = 20.0) -> dict[str, Any]:
        """Send a command to the service and return its answer (the first one)."""
        com = com or str(uuid.uuid4())
        body = {"com-uuid": com, "sender": "test", **command}
        self.watch.publish(f"{self.base}/{api}/command", json.dumps(body).encode())
        return self.answer(com, api, timeout)

    def answer(self, com: str, api: str = "tst", timeout: float = 20.0) -> dict[str, Any]:
        return self.watch.wait_json(f"{self.base}/{api}/response",
                                    lambda d: d.get("response-to") == com, timeout=timeout,
                                    what=f"answer to {com}")

    def node_status(self, node_uuid: str, status: str, timeout: float = 30.0) -> dict[str, Any]:
        """Wait for the service to relay ``status`` for a node on its own tst/feedback."""
        return self.watch.wait_json(
            f"{self.base}/tst/feedback",
            lambda d: d.get("node-uuid") == node_uuid and d.get("status") == status,
            timeout=timeout, what=f"{status} for {node_uuid}")

    def lifecycle(self, root: str) -> list[str]:
        return [d["status"] for d in self.watch.json_on(f"{self.base}/delegation/feedback")
                if d.get("root-uuid") == root]

    def engine_trees(self) -> list[dict[str, Any]]:
        return [d for d in self.watch.json_on(f"{self.engine_base}/tst/command")
                if d.get("command") == "start-tst"]


def start_runtime(settings: BrokerSettings, prefix: str, units: list[UnitState],
                  collector: Callable[..., Any], speedup: float,
                  example_agent: bool = False) -> Iterator[Runtime]:
    config = ServiceConfig(prefix=prefix)
    watch = collector(f"{config.base_topic}/#", f"{prefix}/unit/+/+/op0/tst/command",
                      f"{prefix}/unit/+/+/+/exec/#")
    with LocalSystem(units, settings=settings, config=config, speedup=speedup,
                     rates={u.name: 5.0 for u in units}, example_agent=example_agent) as system:
        assert system.service is not None and system.engine is not None
        assert system.fleet is not None
        yield Runtime(system.service, system.engine, system.fleet, watch, config.base_topic,
                      system.engine.base, prefix)


def fleet_units() -> list[UnitState]:
    return [
        make_unit("dji0", "air", FRAME.geopoint(0, 0, 30), AIR_TASKS,
                  speeds={"slow": 4.0, "standard": 8.0, "fast": 14.0}),
        make_unit("dji1", "air", FRAME.geopoint(150, 0, 30), AIR_TASKS,
                  speeds={"slow": 4.0, "standard": 8.0, "fast": 14.0}),
        make_unit("usv0", "surface", FRAME.geopoint(0, -150, 0), ["move-to", "move-path"]),
    ]


@pytest.fixture
def runtime(mqtt_settings: BrokerSettings, prefix: str,
            collector: Callable[..., Any]) -> Iterator[Runtime]:
    yield from start_runtime(mqtt_settings, prefix, fleet_units(), collector, speedup=100.0)


def partial_tree() -> dict[str, Any]:
    return {
        "name": "conc",
        "common_params": {"node-uuid": str(uuid.uuid4())},
        "children": [
            {"name": "seq", "children": [move_to(100, 120, execunit="A"),
                                         move_to(160, 160, execunit="A")]},
            move_to(-120, 80),
            {"name": "move-path", "common_params": {"execunit": "*"},
             "params": {"waypoints": [pt(-50, -160), pt(50, -200), pt(120, -170)]}},
        ],
    }


def assert_fully_instantiated(tst: dict[str, Any]) -> None:
    for path, node in walk(parse_tree(tst)):
        assert isinstance(node.execunit, str) and node.execunit.startswith("/"), path
        assert node.node_uuid, path
        if node.name == "move-to":
            assert node.params.get("speed") == "standard", path  # defaults filled in


def test_start_tst_partial_tree_runs_to_success(runtime: Runtime) -> None:
    tree = partial_tree()
    root = tree["common_params"]["node-uuid"]
    answer = runtime.send({"command": "start-tst", "receiver": "delegator0", "tst": tree})
    assert answer["response"] == "started" and answer["root-uuid"] == root, answer
    sent = runtime.engine_trees()
    assert len(sent) == 1
    assert_fully_instantiated(sent[0]["tst"])
    task_uuids = [n.node_uuid for _, n in walk(parse_tree(sent[0]["tst"])) if not n.is_control]
    aliased = [n for _, n in walk(parse_tree(sent[0]["tst"])) if n.name == "move-to"][:2]
    assert aliased[0].execunit == aliased[1].execunit  # the alias A got one unit

    final = runtime.node_status(root, "succeeded", timeout=60)
    assert final["root-flag"] is True
    for uid in task_uuids:
        runtime.node_status(str(uid), "succeeded", timeout=5)
    runtime.watch.wait_json(f"{runtime.base}/delegation/feedback",
                            lambda d: d.get("root-uuid") == root and d["status"] == "succeeded")
    assert runtime.lifecycle(root) == ["planned", "started", "running", "succeeded"]
    mission = runtime.send({"command": "query-mission", "root-uuid": root}, api="delegation")
    assert mission["mission"]["status"] == "succeeded"
    assert {n["status"] for n in mission["mission"]["nodes"]} == {"succeeded"}


def test_delegate_with_start_runs_to_success(runtime: Runtime) -> None:
    tree = partial_tree()
    root = tree["common_params"]["node-uuid"]
    answer = runtime.send({"command": "delegate", "tst": tree, "strategy": "optimal",
                           "time-limit": 1.0, "start": True}, api="delegation")
    assert answer["response"] == "started", answer
    plan = answer["plan"]
    assert plan["strategy"] == "optimal" and plan["feasible"]
    assert_fully_instantiated(plan["tst"])
    assert runtime.engine_trees()[0]["tst"] == plan["tst"]
    runtime.node_status(root, "succeeded", timeout=60)
    listed = runtime.send({"command": "list-missions"}, api="delegation")["missions"]
    assert [(m["root-uuid"], m["status"]) for m in listed] == [(root, "succeeded")]


def test_resent_command_runs_once_with_identical_answers(runtime: Runtime) -> None:
    tree = partial_tree()
    root = tree["common_params"]["node-uuid"]
    com = str(uuid.uuid4())
    body = json.dumps({"com-uuid": com, "command": "start-tst", "sender": "test",
                       "tst": tree}).encode()
    topic = f"{runtime.base}/tst/command"
    runtime.watch.publish(topic, body)
    runtime.watch.publish(topic, body)  # while the first is being planned
    first = runtime.answer(com)
    runtime.watch.publish(topic, body)  # after it was answered
    runtime.watch.wait_for(
        lambda m: m.topic == f"{runtime.base}/tst/response"
        and json.loads(m.payload).get("response-to") == com
        and sum(1 for d in runtime.watch.json_on(f"{runtime.base}/tst/response")
                if d.get("response-to") == com) >= 2,
        what="the second answer")
    answers = [d for d in runtime.watch.json_on(f"{runtime.base}/tst/response")
               if d.get("response-to") == com]
    assert first["response"] == "started"
    assert all(a == first for a in answers), answers  # the same answer, com-uuid included
    runtime.node_status(root, "succeeded", timeout=60)
    assert len(runtime.engine_trees()) == 1  # one execution
    starts = [d for d in runtime.watch.json_on(f"{runtime.prefix}/unit/+/+/+/exec/command")
              if d.get("command") == "start-task"]
    assert len({d["task-uuid"] for d in starts}) == 4


@pytest.fixture
def slow_runtime(mqtt_settings: BrokerSettings, prefix: str,
                 collector: Callable[..., Any]) -> Iterator[Runtime]:
    yield from start_runtime(mqtt_settings, prefix, fleet_units(), collector, speedup=4.0)


def test_abort_pause_continue_and_cancel(slow_runtime: Runtime) -> None:
    rt = slow_runtime
    # A long flight for one unit: paused, continued, then aborted through the TST face.
    long = {"name": "seq", "common_params": {"node-uuid": str(uuid.uuid4())},
            "children": [move_to(1500, 1500, **{"node-uuid": str(uuid.uuid4())})]}
    root = long["common_params"]["node-uuid"]
    task = long["children"][0]["common_params"]["node-uuid"]
    assert rt.send({"command": "start-tst", "tst": long})["response"] == "started"
    rt.node_status(task, "running")
    assert rt.send({"command": "signal-tst-node", "node-uuid": task,
                    "signal": "$pause"})["response"] == "ok"
    rt.node_status(task, "paused")
    assert rt.send({"command": "signal-tst-node", "node-uuid": task,
                    "signal": "$continue"})["response"] == "ok"
    rt.watch.wait_json(f"{rt.base}/tst/feedback",
                       lambda d: d.get("node-uuid") == task and d["status"] == "running"
                       and any(p.get("status") == "paused"
                               for p in rt.watch.json_on(f"{rt.base}/tst/feedback")),
                       what="running again after $continue")
    assert rt.send({"command": "signal-tst-tree", "node-uuid": root,
                    "signal": "$abort"})["response"] == "ok"
    rt.node_status(root, "aborted")
    rt.watch.wait_json(f"{rt.prefix}/unit/+/+/+/exec/feedback",
                       lambda d: d.get("status") == "aborted", what="a unit's task aborted")
    rt.watch.wait_json(f"{rt.base}/delegation/feedback",
                       lambda d: d.get("root-uuid") == root and d["status"] == "aborted")

    # The same through the Delegation API: cancel-mission is ok once the engine confirmed.
    other = {"name": "conc", "common_params": {"node-uuid": str(uuid.uuid4())},
             "children": [move_to(-1500, 1500), move_to(1500, -1500)]}
    root2 = other["common_params"]["node-uuid"]
    assert rt.send({"command": "delegate", "tst": other, "start": True},
                   api="delegation")["response"] == "started"
    rt.watch.wait_json(f"{rt.base}/delegation/feedback",
                       lambda d: d.get("root-uuid") == root2 and d["status"] == "running")
    assert rt.send({"command": "cancel-mission", "root-uuid": root2},
                   api="delegation")["response"] == "ok"
    rt.node_status(root2, "aborted")
    again = rt.send({"command": "cancel-mission", "root-uuid": root2}, api="delegation")
    assert again["response"] == "failed" and "already ended" in again["fail-reason"]


@pytest.fixture
def example_runtime(mqtt_settings: BrokerSettings, prefix: str,
                    collector: Callable[..., Any]) -> Iterator[Runtime]:
    # The public example agent: air, default speeds 1.5/3/6, move-to/move-path/search-area/go-home.
    units = [make_unit("agent0", "air", FRAME.geopoint(0, 0, 30),
                       ["go-home", "move-to", "move-path", "search-area"]),
             make_unit("agent1", "air", FRAME.geopoint(60, 0, 30),
                       ["go-home", "move-to", "move-path", "search-area"])]
    yield from start_runtime(mqtt_settings, prefix, units, collector, speedup=50.0,
                             example_agent=True)


def test_units_like_the_public_example_agent(example_runtime: Runtime) -> None:
    rt = example_runtime
    agents = rt.send({"command": "list-agents"}, api="delegation")["agents"]
    assert sorted(a["name"] for a in agents) == ["agent0", "agent1"]
    assert all(set(a["tasks-available"]) == {"go-home", "move-to", "move-path", "search-area"}
               for a in agents)
    tree = {"name": "conc", "common_params": {"node-uuid": str(uuid.uuid4())},
            "children": [move_to(80, 90),  # no speed given: the service must fill it in
                         {"name": "move-path",
                          "params": {"waypoints": [pt(-40, 20), pt(-80, 60)]}}]}
    root = tree["common_params"]["node-uuid"]
    assert rt.send({"command": "start-tst", "tst": tree})["response"] == "started"
    rt.node_status(root, "succeeded", timeout=60)
    starts = [d for d in rt.watch.json_on(f"{rt.prefix}/unit/+/+/+/exec/command")
              if d.get("command") == "start-task"]
    assert len(starts) == 2 and all(d["task"]["params"].get("speed") for d in starts)
