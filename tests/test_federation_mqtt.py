"""Two delegation services, each with its own simulated fleet and engine, on one real broker
(docs/protocol.md §15): a mission whose best plan uses both fleets runs to success with the
operator's view whole; a delegator that never answers offers delays planning by the bid window
at most.

On one broker (`one_broker`): the subject is the services' federation, the same code on either
broker; the MQTT client on each broker is what test_mqtt.py checks."""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from typing import Any

import pytest

from conftest import one_broker
from delegation.fleet import make_unit
from delegation.local import LocalSystem
from delegation.runtime.settings import BrokerSettings
from delegation.service import ServiceConfig
from test_e2e_service import AIR_TASKS, FRAME, move_to

pytestmark = [pytest.mark.mqtt, pytest.mark.slow, one_broker()]

SPEEDS = {"slow": 4.0, "standard": 8.0, "fast": 14.0}
#: Site B is 2 km east of site A: a unit of one site needs 250 s to reach the other.
SITE_B = 2000.0


def site(name: str, engine: str, unit: str, x: float, prefix: str, **config: Any
         ) -> tuple[ServiceConfig, Any]:
    cfg = ServiceConfig(prefix=prefix, name=name, engine=engine, fleet=frozenset({unit}),
                        **config)
    return cfg, make_unit(unit, "air", FRAME.geopoint(x, 0, 30), AIR_TASKS, speeds=SPEEDS)


def start_site(stack: ExitStack, settings: BrokerSettings, cfg: ServiceConfig,
               unit: Any) -> LocalSystem:
    system = LocalSystem([unit], settings=settings, config=cfg, speedup=100.0,
                         rates={unit.name: 5.0})
    stack.enter_context(system)
    return system


def ask(watch: Any, base: str, command: dict[str, Any], timeout: float = 20.0
        ) -> dict[str, Any]:
    com = str(uuid.uuid4())
    watch.publish(f"{base}/delegation/command", {"com-uuid": com, "sender": "test", **command})
    return watch.wait_json(f"{base}/delegation/response", lambda d: d.get("response-to") == com,
                           timeout=timeout, what=f"answer to {command['command']}")


def wait_delegator(watch: Any, base: str, name: str, timeout: float = 15.0) -> None:
    """Until the service at ``base`` lists ``name`` as a delegator with the tasks its fleet can
    do (its info arrives at 1 Hz; the first before it has heard its units)."""
    deadline = time.monotonic() + timeout
    while True:
        agents = ask(watch, base, {"command": "list-agents"})["agents"]
        if any(a["name"] == name and a.get("delegates-tasks") for a in agents):
            return
        old = {id(m) for m in watch.messages}
        watch.wait_for(lambda m, old=old: id(m) not in old
                       and m.topic.endswith(f"/{name}/delegation_info"),
                       timeout=max(0.1, deadline - time.monotonic()),
                       what=f"{name} listed as a delegator")


def watch_prefix(base: str) -> str:
    return base.split("/unit/")[0]


@pytest.fixture
def two_sites(mqtt_settings: BrokerSettings, prefix: str,
              collector: Callable[..., Any]) -> Iterator[tuple[Any, ServiceConfig]]:
    a_cfg, a0 = site("delegator-a", "op-a", "a0", 0.0, prefix)
    b_cfg, b0 = site("delegator-b", "op-b", "b0", SITE_B, prefix,
                     partners=frozenset({"delegator-a", "op-a"}))
    watch = collector(f"{prefix}/unit/+/+/delegator-a/#", f"{prefix}/unit/+/+/delegator-b/#",
                      f"{prefix}/unit/+/+/+/delegation_info")
    with ExitStack() as stack:
        start_site(stack, mqtt_settings, b_cfg, b0)
        start_site(stack, mqtt_settings, a_cfg, a0)
        wait_delegator(watch, a_cfg.base_topic, "delegator-b")
        yield watch, a_cfg


def test_a_mission_whose_best_plan_uses_both_fleets_succeeds(
        two_sites: tuple[Any, ServiceConfig]) -> None:
    watch, a = two_sites
    root = str(uuid.uuid4())
    near_a, near_b = move_to(100, 0), move_to(SITE_B + 100, 0)
    near_a["common_params"]["node-uuid"], near_b["common_params"]["node-uuid"] = "near-a", \
        f"near-b-{root[:8]}"
    tree = {"name": "conc", "common_params": {"node-uuid": root}, "children": [near_a, near_b]}
    answer = ask(watch, a.base_topic, {"command": "delegate", "tst": tree, "start": True},
                 timeout=30.0)
    assert answer["response"] == "started", answer
    plan = answer["plan"]
    units = {x["node-uuid"]: x["execunit"] for x in plan["assignments"]}
    assert units == {"near-a": "/a0", near_b["common_params"]["node-uuid"]: "/delegator-b"}
    assert any(n.startswith("offer taken") for n in plan["notes"]), plan["notes"]
    assert plan["makespan"] < 100.0  # a0 alone would fly 2 km to site B (> 250 s)
    # The operator's view stays whole: every node's feedback on delegator-a's tst/feedback.
    feedback = f"{a.base_topic}/tst/feedback"
    for uid in ("near-a", near_b["common_params"]["node-uuid"], root):
        watch.wait_json(feedback, lambda d, u=uid: d.get("node-uuid") == u
                        and d.get("status") == "succeeded", timeout=60.0, what=f"{uid} ok")
    # delegator-b ran the subtree with its own unit: its own tst/feedback says so.
    b_feedback = [d for d in watch.json_on(f"{watch_prefix(a.base_topic)}/unit/+/+/delegator-b/"
                                            "tst/feedback")
                  if d.get("node-uuid") == near_b["common_params"]["node-uuid"]]
    assert any(d["status"] == "succeeded" for d in b_feedback)
    mission = ask(watch, a.base_topic, {"command": "query-mission", "root-uuid": root})
    assert mission["mission"]["status"] == "succeeded"


def test_a_delegator_that_never_answers_delays_planning_by_the_window_at_most(
        mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any]) -> None:
    a_cfg, a0 = site("delegator-a", "op-a", "a0", 0.0, prefix, bid_window=0.5)
    watch = collector(f"{prefix}/unit/+/+/delegator-a/#", f"{prefix}/unit/+/+/mute/#")
    mute = f"{prefix}/unit/ground/simulation/mute"

    def mute_says_hello() -> None:
        watch.publish(f"{mute}/heartbeat", {
            "agent-type": "ground", "agent-uuid": "mute", "levels": ["tst execution",
                                                                     "delegation"],
            "name": "mute", "rate": 1.0, "stamp": time.time(), "type": "HeartBeat"})
        watch.publish(f"{mute}/delegation_info", {
            "name": "mute", "rate": 1.0, "stamp": time.time(), "tasks-available": ["move-to"],
            "units-managed": [], "type": "DelegationInfo"})

    with ExitStack() as stack:
        start_site(stack, mqtt_settings, a_cfg, a0)
        mute_says_hello()
        deadline = time.monotonic() + 10.0
        while not any(a.get("delegator") for a in ask(watch, a_cfg.base_topic,
                                                      {"command": "list-agents"})["agents"]):
            assert time.monotonic() < deadline, "mute never listed as a delegator"
            mute_says_hello()
        tree = {"name": "conc", "common_params": {"node-uuid": str(uuid.uuid4())},
                "children": [move_to(100, 0), move_to(0, 100)]}
        began = time.monotonic()
        answer = ask(watch, a_cfg.base_topic, {"command": "delegate", "tst": tree})
        took = time.monotonic() - began
    assert answer["response"] == "ok", answer
    asked = watch.json_on(f"{mute}/delegation/command/delegator-a")
    assert len(asked) == 2 and all(x["preview"] is True for x in asked)
    notes = answer["plan"]["notes"]
    assert sum("mute did not answer within 0.5 s" in n for n in notes) == 2, notes
    assert {x["execunit"] for x in answer["plan"]["assignments"]} == {"/a0"}
    assert 0.5 <= took < 0.5 + 2.0, took  # the window, plus planning on a loaded machine


def test_cancelling_the_top_mission_aborts_the_delegated_subtree(
        two_sites: tuple[Any, ServiceConfig]) -> None:
    watch, a = two_sites
    root, far = str(uuid.uuid4()), f"far-{uuid.uuid4().hex[:8]}"
    near_a, far_b = move_to(100, 0), move_to(SITE_B + 4000, 0)  # b0 needs 500 s (5 s here)
    near_a["common_params"]["node-uuid"], far_b["common_params"]["node-uuid"] = \
        f"a-{far}", far
    tree = {"name": "conc", "common_params": {"node-uuid": root}, "children": [near_a, far_b]}
    answer = ask(watch, a.base_topic, {"command": "delegate", "tst": tree, "start": True},
                 timeout=30.0)
    assert answer["response"] == "started", answer
    assert {x["execunit"] for x in answer["plan"]["assignments"]
            if x["node-uuid"] == far} == {"/delegator-b"}
    feedback = f"{a.base_topic}/tst/feedback"
    watch.wait_json(feedback, lambda d: d.get("node-uuid") == far and d["status"] == "running",
                    timeout=30.0, what="the delegated subtree running")
    cancelled = ask(watch, a.base_topic, {"command": "cancel-mission", "root-uuid": root},
                    timeout=40.0)
    assert cancelled["response"] == "ok", cancelled
    watch.wait_json(feedback, lambda d: d.get("node-uuid") == far and d["status"] == "aborted",
                    timeout=20.0, what="the delegated subtree aborted")
    # delegator-b's own mission (the subtree, its root is ours) ended aborted there.
    b_events = f"{watch_prefix(a.base_topic)}/unit/+/+/delegator-b/delegation/feedback"
    watch.wait_json(b_events, lambda d: d.get("root-uuid") == far and d["status"] == "aborted",
                    timeout=20.0, what="delegator-b's mission aborted")


def test_a_delegator_killed_mid_mission_is_re_delegated_and_the_mission_succeeds(
        mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any]) -> None:
    a_cfg, a0 = site("delegator-a", "op-a", "a0", 0.0, prefix)
    b_cfg, b0 = site("delegator-b", "op-b", "b0", SITE_B, prefix,
                     partners=frozenset({"delegator-a", "op-a"}))
    watch = collector(f"{prefix}/unit/+/+/delegator-a/#", f"{prefix}/unit/+/+/delegator-b/#",
                      f"{prefix}/unit/+/+/+/delegation_info", f"{prefix}/unit/+/+/op-a/tst/command")
    root, far = str(uuid.uuid4()), f"far-{uuid.uuid4().hex[:8]}"
    # b0: 300 s (3 s here: still flying when delegator-b is stopped); a0 then 540 s (5.4 s)
    near_a, far_b = move_to(100, 0), move_to(SITE_B + 2400, 0)
    near_a["common_params"]["node-uuid"], far_b["common_params"]["node-uuid"] = \
        f"a-{far}", far
    tree = {"name": "conc", "common_params": {"node-uuid": root}, "children": [near_a, far_b]}
    with ExitStack() as stack:
        b_system = start_site(stack, mqtt_settings, b_cfg, b0)
        start_site(stack, mqtt_settings, a_cfg, a0)
        wait_delegator(watch, a_cfg.base_topic, "delegator-b")
        answer = ask(watch, a_cfg.base_topic, {"command": "delegate", "tst": tree,
                                               "start": True}, timeout=30.0)
        assert answer["response"] == "started", answer
        feedback = f"{a_cfg.base_topic}/tst/feedback"
        watch.wait_json(feedback, lambda d: d.get("node-uuid") == far
                        and d["status"] == "running", timeout=30.0, what="far running at b")
        assert b_system.service is not None
        b_system.service.stop()  # delegator-b dies (its engine and b0 fly on, unheard of)
        events = f"{a_cfg.base_topic}/delegation/feedback"
        moved = watch.wait_json(events, lambda d: d.get("root-uuid") == root
                                and d["status"] == "re-delegated", timeout=30.0,
                                what="the re-delegation")
        assert "/delegator-b lost" in moved["fail-reason"]
        assert [(t["replaces"], t["unit"]) for t in moved["tasks"]] == [(far, "/a0")]
        watch.wait_json(events, lambda d: d.get("root-uuid") == root
                        and d["status"] == "succeeded", timeout=60.0, what="the mission's end")
        # Our a0 took the lost part in its place in the running tree: no tree was replaced
        # (a0's own task was neither aborted nor started again).
        sent = [d["command"] for d in watch.json_on(f"{prefix}/unit/+/+/op-a/tst/command")]
        assert sent.count("start-tst") == 1 and "signal-tst-tree" not in sent, sent
        assert "rebind-tst-nodes" in sent


def test_a_lost_partners_part_goes_to_another_partner_whose_own_part_runs_on(
        mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any]) -> None:
    """Three partners: a0 16 km west, b0 and c0 600 m apart; a task near b0 goes to delegator-b, a
    long one near c0 to delegator-c. delegator-b dies mid-task: its task is offered to delegator-c
    (c0, once free, is nearer than a0) and moves there within the running tree, same uuid;
    delegator-c's own part is neither aborted nor started again, and the mission succeeds."""
    trusting = {"partners": frozenset({"delegator-a", "op-a"})}
    a_cfg, a0 = site("delegator-a", "op-a", "a0", -14000.0, prefix)
    b_cfg, b0 = site("delegator-b", "op-b", "b0", SITE_B, prefix, **trusting)
    c_cfg, c0 = site("delegator-c", "op-c", "c0", SITE_B + 600.0, prefix, **trusting)
    watch = collector(*(f"{prefix}/unit/+/+/{n}/#" for n in ("delegator-a", "delegator-b",
                                                              "delegator-c")),
                      f"{prefix}/unit/+/+/+/delegation_info")
    root, b_part, c_part = (f"{x}-{uuid.uuid4().hex[:8]}" for x in ("root", "b", "c"))
    near_a = move_to(-13900, 0)
    near_a["common_params"]["node-uuid"] = f"a-{root}"
    # b0: 7 km (9 s here); c0: 8 km (10 s here), ending 1.2 km from b's task (1.5 s more).
    at_b = move_to(SITE_B, 7000, **{"node-uuid": b_part})
    at_c = move_to(SITE_B + 600.0, 8000, **{"node-uuid": c_part})
    tree = {"name": "conc", "common_params": {"node-uuid": root},
            "children": [near_a, at_b, at_c]}
    with ExitStack() as stack:
        b_system = start_site(stack, mqtt_settings, b_cfg, b0)
        start_site(stack, mqtt_settings, c_cfg, c0)
        start_site(stack, mqtt_settings, a_cfg, a0)
        wait_delegator(watch, a_cfg.base_topic, "delegator-b")
        wait_delegator(watch, a_cfg.base_topic, "delegator-c")
        answer = ask(watch, a_cfg.base_topic, {"command": "delegate", "tst": tree,
                                               "start": True}, timeout=30.0)
        assert answer["response"] == "started", answer
        units = {x["node-uuid"]: x["execunit"] for x in answer["plan"]["assignments"]}
        assert units == {f"a-{root}": "/a0", b_part: "/delegator-b", c_part: "/delegator-c"}
        feedback = f"{a_cfg.base_topic}/tst/feedback"
        watch.wait_json(feedback, lambda d: d.get("node-uuid") == b_part
                        and d["status"] == "running", timeout=30.0, what="b's part running")
        assert b_system.service is not None
        b_system.service.stop()  # delegator-b dies (its engine and b0 fly on, unheard of)
        events = f"{a_cfg.base_topic}/delegation/feedback"
        moved = watch.wait_json(events, lambda d: d.get("root-uuid") == root
                                and d["status"] == "re-delegated", timeout=30.0,
                                what="the re-delegation")
        assert "/delegator-b lost" in moved["fail-reason"]
        assert [(t["node-uuid"], t["replaces"], t["unit"]) for t in moved["tasks"]] == [
            (b_part, b_part, "/delegator-c")]
        for uid in (c_part, b_part, root):
            watch.wait_json(feedback, lambda d, u=uid: d.get("node-uuid") == u
                            and d.get("status") == "succeeded", timeout=60.0, what=f"{uid} ok")
        watch.wait_json(events, lambda d: d.get("root-uuid") == root
                        and d["status"] == "succeeded", timeout=20.0, what="the mission's end")
    to_c = [d for d in watch.json_on(f"{watch_prefix(a_cfg.base_topic)}/unit/+/+/delegator-c/"
                                     "tst/command")]
    started = [d["tst"]["common_params"]["node-uuid"] for d in to_c
               if d.get("command") == "start-tst"]
    assert sorted(started) == sorted([c_part, b_part])  # each once: c's part never again
    assert not [d for d in to_c if d.get("command") == "signal-tst-tree"]
