"""The engine's part in restarts without loss (issue 22 items 1-2, docs/protocol.md §12.5):
``query-tst`` answers a tree's node statuses; start-task ids are derived from the start-tst's
com-uuid, the node and the attempt, so a restarted engine given the same tree again re-sends the
very start-tasks its units got (answered again, not run again); a resumed tree asks each unit
``query-status`` once its start-task is answered."""

from __future__ import annotations

import json

from delegation.fleet import make_unit
from delegation.geo import GeoPoint
from delegation.messages import ExecFeedback, ExecResponse, encode
from delegation.runtime.mqtt import MqttClient
from delegation.runtime.settings import BrokerSettings
from delegation.sim.core import SimUnitCore
from test_engine_core import DJI0, FEEDBACK, RESPONSE, ctl, engine, on, send, start_tst, task


def _query(root: str, com: str = "q1") -> dict[str, str]:
    return {"com-uuid": com, "command": "query-tst", "node-uuid": root, "sender": "test"}


def test_query_tst_answers_every_node_status_parents_first() -> None:
    c = engine("dji0")
    (start,) = on(send(c, start_tst(ctl("seq", "R", task("a"), task("b")))), f"{DJI0}/exec/command")
    c.on_message(f"{DJI0}/exec/response",
                 encode(ExecResponse(response="running", response_to=start["com-uuid"])), 2.0)
    (answer,) = on(send(c, _query("R"), 3.0), RESPONSE)
    assert answer["response"] == "ok" and answer["root-uuid"] == "R"
    assert [(n["node-uuid"], n["status"]) for n in answer["nodes"]] == [
        ("R", "running"), ("a", "running"), ("b", "not-active")]
    (unknown,) = on(send(c, _query("nope", "q2"), 3.0), RESPONSE)
    assert unknown["response"] == "unknown" and "no tree nope" in unknown["fail-reason"]


def test_start_task_ids_are_derived_from_the_start_tst_com_uuid_node_and_attempt() -> None:
    first, restarted, other = engine("dji0"), engine("dji0"), engine("dji0")
    tree = ctl("seq", "R", task("a"))
    (one,) = on(send(first, start_tst(tree, "same")), f"{DJI0}/exec/command")
    (two,) = on(send(restarted, start_tst(tree, "same")), f"{DJI0}/exec/command")
    (three,) = on(send(other, start_tst(tree, "another")), f"{DJI0}/exec/command")
    assert (one["com-uuid"], one["task-uuid"]) == (two["com-uuid"], two["task-uuid"])
    assert one["com-uuid"] != three["com-uuid"] and one["task-uuid"] != three["task-uuid"]
    assert one["com-uuid"] != one["task-uuid"]


def test_a_busy_retry_gets_new_ids() -> None:
    c = engine("dji0")
    (start,) = on(send(c, start_tst(ctl("seq", "R", task("a")))), f"{DJI0}/exec/command")
    busy = ExecResponse(response="failed", response_to=start["com-uuid"],
                        fail_reason="A task is already running")
    c.on_message(f"{DJI0}/exec/response", encode(busy), 2.0)
    (again,) = on(c.on_tick(4.5), f"{DJI0}/exec/command")
    assert again["task-uuid"] != start["task-uuid"] and again["com-uuid"] != start["com-uuid"]


def _resumed_on_a_unit(unit: SimUnitCore, status_after: str) -> None:
    """A unit got a task's start-task from an engine that then died; a new engine is given the
    tree again (same start-tst com-uuid, ``resume``): the unit answers the re-sent start-task
    again without running it twice, and its ``query-status`` answer decides the node."""
    tree = ctl("seq", "R", task("a"))
    command = f"{DJI0}/exec/command"
    dead = engine("dji0")
    (start,) = on(send(dead, start_tst(tree, "s1")), command)
    first = unit.on_message(command, encode_dict(start), 1.0)
    if status_after == "finished":
        unit.on_tick(1.0)
        unit.on_tick(1000.0)  # flown: the finished feedback went to nobody
    c = engine("dji0")
    resumed = dict(start_tst(tree, "s1"), resume=True)
    (again,) = on(send(c, resumed), command)
    assert again == start  # the very same start-task
    second = unit.on_message(command, encode_dict(again), 1001.0)
    assert second.publish == first.publish[:1]  # answered again, byte for byte; not run again
    effects = c.on_message(f"{DJI0}/exec/response", second.publish[0].payload, 1001.1)
    (query,) = on(effects, command)
    assert query["command"] == "query-status" and query["task-uuid"] == start["task-uuid"]
    answer = unit.on_message(command, encode_dict(query), 1001.2)
    effects = c.on_message(f"{DJI0}/exec/response", answer.publish[0].payload, 1001.3)
    statuses = [(d["node-uuid"], d["status"]) for d in on(effects, FEEDBACK)]
    if status_after == "finished":
        assert statuses == [("a", "succeeded"), ("R", "succeeded")]
    else:
        assert statuses == []  # still running: adopted, its feedback will come
        assert c.executor.status("a").value == "running"


def encode_dict(d: dict[str, object]) -> bytes:
    return json.dumps(d).encode()


def _unit() -> SimUnitCore:
    return SimUnitCore(make_unit("dji0", "air", GeoPoint(latitude=57.76, longitude=16.679,
                                                         altitude=40.0), ["move-to"]),
                       prefix="test", role="real")


def test_a_resumed_task_still_running_is_adopted() -> None:
    _resumed_on_a_unit(_unit(), "running")


def test_a_resumed_task_that_finished_meanwhile_succeeds() -> None:
    _resumed_on_a_unit(_unit(), "finished")


def test_a_fresh_tree_asks_no_query_status() -> None:
    c = engine("dji0")
    (start,) = on(send(c, start_tst(ctl("seq", "R", task("a")))), f"{DJI0}/exec/command")
    effects = c.on_message(f"{DJI0}/exec/response",
                           encode(ExecResponse(response="running", response_to=start["com-uuid"])),
                           2.0)
    assert on(effects, f"{DJI0}/exec/command") == []
    done = c.on_message(f"{DJI0}/exec/feedback",
                        encode(ExecFeedback(status="finished", task_uuid=start["task-uuid"])), 3.0)
    assert on(done, FEEDBACK)[-1]["status"] == "succeeded"


def test_a_connection_never_up_is_not_reported_lost() -> None:
    """On amqtt the refused MQTT 5 attempt before the 3.1.1 fallback closes a connection that
    was never up: reported as a loss, it left a unit offline for good (a restarted service on
    amqtt judged nobody and caught up on nothing)."""
    seen: list[tuple[bool, int]] = []
    client = MqttClient(BrokerSettings(host="127.0.0.1", port=1), "probe", sink=lambda _m: None,
                        on_connection=lambda up, n: seen.append((up, n)))
    client._on_disconnect(None, None, None, 0, None)  # paho's callback, the attempt refused
    assert seen == []
    client.connected.set()  # up, then lost: that is a loss
    client._on_disconnect(None, None, None, 0, None)
    assert seen == [(False, 0)] and not client.connected.is_set()


def test_an_engine_told_not_to_answer_query_tst_stays_silent_and_runs_trees_as_usual() -> None:
    """The test-only ``answers_query_tst=False`` imitates an engine without the extension that
    does not answer it (the public op0): the service's catch-up from its units is tested so."""
    c = engine("dji0")
    c.answers_query_tst = False
    (start,) = on(send(c, start_tst(ctl("seq", "R", task("a")))), f"{DJI0}/exec/command")
    assert start["command"] == "start-task"
    assert send(c, _query("R"), 3.0).publish == []
