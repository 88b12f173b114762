"""The engine catching up after a broker outage (docs/protocol.md §11): ``query-status`` to the
units on reconnect and when a unit's heartbeat comes back after a gap; the answers applied as
feedback."""

from __future__ import annotations

import json

from delegation.engine import EngineCore
from delegation.messages import ExecResponse, encode
from delegation.runtime.core import Effects
from test_engine_core import DJI0, FEEDBACK, ctl, engine, heartbeat_of, send, start_tst, task

EXEC = f"{DJI0}/exec/command"


def commands(effects: Effects) -> list[dict[str, object]]:
    return [json.loads(o.payload) for o in effects.publish if o.topic == EXEC]


def running_task(c: EngineCore) -> str:
    """Start a one-task tree on dji0 and let dji0 accept it; its task-uuid."""
    (start,) = commands(send(c, start_tst(ctl("seq", "R", task("a")))))
    answer = ExecResponse(response="running", response_to=str(start["com-uuid"]),
                          task_uuid=str(start["task-uuid"]))
    c.on_message(f"{DJI0}/exec/response", encode(answer), 1.5)
    return str(start["task-uuid"])


def answer(c: EngineCore, query: dict[str, object], state: str, now: float) -> Effects:
    resp = ExecResponse(response=state, response_to=str(query["com-uuid"]),
                        task_uuid=str(query["task-uuid"]))
    return c.on_message(f"{DJI0}/exec/response", encode(resp), now)


def statuses(effects: Effects) -> list[tuple[str, str]]:
    return [(f["node-uuid"], f["status"]) for f in
            (json.loads(o.payload) for o in effects.publish if o.topic == FEEDBACK)]


def test_on_reconnect_the_engine_asks_and_a_lost_finished_ends_the_task() -> None:
    c = engine("dji0")
    task_uuid = running_task(c)
    (query,) = commands(c.on_reconnect(20.0))
    assert (query["command"], query["task-uuid"]) == ("query-status", task_uuid)
    done = answer(c, query, "finished", 20.1)
    assert statuses(done) == [("a", "succeeded"), ("R", "succeeded")]
    assert answer(c, query, "finished", 20.2) == Effects()  # answered once


def test_a_unit_heard_again_after_a_gap_or_after_our_reconnect_is_asked() -> None:
    c = engine("dji0")
    running_task(c)
    heartbeat_of(c, "dji0", 2.0)
    assert commands(heartbeat_of(c, "dji0", 3.0)) == []  # no gap
    (query,) = commands(heartbeat_of(c, "dji0", 10.0))  # 7 s of silence
    assert query["command"] == "query-status"
    assert statuses(answer(c, query, "running", 10.1)) == []  # still running: nothing changes
    c.on_reconnect(11.0)
    (again,) = commands(heartbeat_of(c, "dji0", 11.5))  # first heartbeat since our reconnect
    assert again["command"] == "query-status"


def test_a_task_the_unit_no_longer_knows_fails_with_the_reason() -> None:
    c = engine("dji0")
    running_task(c)
    (query,) = commands(c.on_reconnect(20.0))
    failed = answer(c, query, "unknown", 20.1)
    assert statuses(failed) == [("a", "failed"), ("R", "failed")]
    reason = next(json.loads(o.payload)["fail-reason"] for o in failed.publish
                  if o.topic == FEEDBACK)
    assert "no longer knows task" in reason
