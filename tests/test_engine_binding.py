"""The engine binds each unit to the base topic of its first heartbeat (issue 11, docs/security.md):
an impostor's heartbeat and answers from another topic are logged and ignored."""

from __future__ import annotations

import json
import logging

import pytest

from delegation.messages import ExecFeedback, ExecResponse, HeartBeat, encode
from test_engine_core import DJI0, ctl, engine, on, send, start_tst, task

FAKE = "test/unit/air/evil/dji0"


def test_start_tasks_go_to_the_first_seen_topic_only(caplog: pytest.LogCaptureFixture) -> None:
    c = engine("dji0")
    hb = HeartBeat(
        agent_type="air",
        agent_uuid="x",
        levels=["direct execution"],
        name="dji0",
        rate=20.0,
        stamp=1,
    )
    with caplog.at_level(logging.WARNING):
        for now in (0.1, 0.2, 0.3):
            assert c.on_message(f"{FAKE}/heartbeat", encode(hb), now).publish == []
    assert c.bases["dji0"] == DJI0
    assert sum("ignoring test/unit/air/evil/dji0" in r.message for r in caplog.records) == 1
    started = send(c, start_tst(ctl("seq", "R", task("a"))))
    assert on(started, f"{FAKE}/exec/command") == []
    (start_task,) = on(started, f"{DJI0}/exec/command")
    # The impostor answers for the real unit: ignored; the tree is still waiting for dji0.
    forged = ExecResponse(
        response="running",
        response_to=start_task["com-uuid"],
        agent_uuid="x",
        task_uuid=start_task["task-uuid"],
    )
    assert c.on_message(f"{FAKE}/exec/response", encode(forged), 1.1).publish == []
    done = ExecFeedback(agent_uuid="x", task_uuid=start_task["task-uuid"], status="finished")
    assert c.on_message(f"{FAKE}/exec/feedback", encode(done), 1.2).publish == []
    real = c.on_message(f"{DJI0}/exec/response", encode(forged), 1.3)
    statuses = [
        json.loads(o.payload)["status"] for o in real.publish if o.topic.endswith("tst/feedback")
    ]
    assert "running" in statuses
