"""The planner's queue is bounded (issue 22): past ``planner_queue`` jobs waiting or being
planned, a command that plans is turned away ``failed`` with the reason, not kept (neither in
the command log nor in the store), and the same command re-sent once the planner caught up is
planned normally."""

from __future__ import annotations

import json
import os
import threading
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

import cli_forks
from delegation.runtime.core import Effects, JobDone
from delegation.runtime.settings import BrokerSettings
from delegation.service import DelegationService, Job, ServiceConfig, ServiceCore, run_job
from delegation.service.store import SqliteStore
from test_service_core import BASE, PREFIX, feed_engine, feed_unit, on, partial_tree

BUSY = "planner: busy: 2 plans are waiting or being made (at most 2)"


def _delegate(com: str, root: str) -> bytes:
    tree = {**partial_tree(), "common_params": {"node-uuid": root}}
    for i, child in enumerate(tree["children"]):
        child["common_params"] = {**child["common_params"], "node-uuid": f"{root}-{i}"}
    return json.dumps({"com-uuid": com, "command": "delegate", "sender": "test",
                       "tst": tree}).encode()


def _send(core: ServiceCore, payload: bytes, now: float = 101.0) -> Effects:
    return core.on_message(f"{BASE}/delegation/command", payload, now)


def test_past_the_bound_a_plan_is_turned_away_and_a_later_resend_is_planned() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX, planner_queue=2))
    feed_unit(core, "dji0", 57.7605, 16.6815, ["move-to"], 100.0)
    feed_engine(core, 100.0)
    jobs = [job for i in range(2) for job in _send(core, _delegate(f"d-{i}", f"r{i}")).jobs]
    assert len(jobs) == 2 and core.planner_jobs == 2

    third = _delegate("d-2", "r2")
    for _ in range(2):  # sent again while still busy: turned away again, never "reused"
        refused = _send(core, third)
        [answer] = on(refused, "delegation/response")
        assert refused.jobs == [] and answer["response"] == "failed"
        assert answer["response-to"] == "d-2" and answer["fail-reason"].startswith(BUSY)
        assert core.commands.get(("delegation", "d-2")) is None  # not kept
    assert on(_send(core, json.dumps({"com-uuid": "p", "command": "ping"}).encode()),
              "delegation/response")[0]["response"] == "pong"  # the rest is served

    done = core.on_job_done(JobDone(jobs[0], run_job(jobs[0])), 102.0)
    assert on(done, "delegation/response")[0]["response"] == "ok" and core.planner_jobs == 1
    [job] = _send(core, third, 103.0).jobs  # the same bytes: a new command now
    assert core.planner_jobs == 2
    answer = on(core.on_job_done(JobDone(job, run_job(job)), 104.0), "delegation/response")
    assert answer[0]["response-to"] == "d-2" and answer[0]["response"] == "ok"
    assert core.planner_jobs == 1


@pytest.mark.mqtt
def test_a_busy_planner_on_a_broker_turns_a_command_away_unstored(
    mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any], tmp_path: Path
) -> None:
    release = threading.Event()
    planning = threading.Event()

    def held_planner(job: Job) -> Any:
        planning.set()
        release.wait(30)
        return run_job(job)

    store = SqliteStore(tmp_path / "state.sqlite")
    service = DelegationService(mqtt_settings, ServiceConfig(prefix=prefix, planner_queue=1,
                                                             listen_first=0.0),
                                planner=held_planner, store=store)
    base = service.config.base_topic
    c = collector(f"{base}/delegation/response")
    tree = {"name": "move-to", "common_params": {"node-uuid": str(uuid.uuid4())},
            "params": {"waypoint": {"latitude": 57.76, "longitude": 16.68, "altitude": 20.0}}}

    def send(com: str, command: str) -> None:
        c.publish(f"{base}/delegation/command", json.dumps(
            {"com-uuid": com, "command": command, "sender": "t", "tst": tree}).encode())

    def answers(com: str) -> list[dict[str, Any]]:
        return [d for d in c.json_on(f"{base}/delegation/response")
                if d.get("response-to") == com]

    service.start()
    try:
        first, second = str(uuid.uuid4()), str(uuid.uuid4())
        send(first, "get-bids")
        assert planning.wait(10)
        send(second, "get-bids")
        busy = c.wait_json(f"{base}/delegation/response",
                           lambda d: d.get("response-to") == second, what="the busy answer")
        assert busy["response"] == "failed"
        assert busy["fail-reason"].startswith("planner: busy: 1 plans are waiting or being made "
                                              "(at most 1)")
        assert store.load_command(("delegation", second)) is None
        release.set()
        assert c.wait_json(f"{base}/delegation/response",
                           lambda d: d.get("response-to") == first)["response"] == "ok"
        assert service.wait_until(lambda core: core.planner_jobs == 0, 10)
        send(second, "get-bids")  # re-sent once the planner caught up: planned
        c.wait_for(lambda _m: len(answers(second)) == 2, what="the re-send's answer")
        assert answers(second)[1]["response"] == "ok"
        stored = store.load_command(("delegation", second))
        assert stored is not None and stored.state.value == "done"
    finally:
        release.set()
        service.stop()
        store.close()


@pytest.mark.parametrize("value, says", [("0", "must be at least 1, not 0"),
                                          ("many", "'many' is not a whole number")])
def test_serve_names_a_wrong_planner_queue(value: str, says: str) -> None:
    # forked with the CLI imported (`cli_forks`): still a process of its own
    done = cli_forks.run(["serve", "--planner-queue", value], dict(os.environ), timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert f"argument --planner-queue: {says}" in done.stderr
