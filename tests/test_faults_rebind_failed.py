"""A task its unit ends on its own moves alone, with real processes (issue 22 item 3,
docs/protocol.md §11 and §12.7): two units busy in one mission; u1's pilot aborts u1's task (a
``signal-task $abort`` straight to u1, not through the engine: the unit ended it unasked). The
engine holds that task (the service started the tree with ``hold-failed``), the service moves it
to another unit by ``rebind-tst-nodes`` under the same uuid, and u0's running task is never
signalled nor started again (counted on the wire). The mission succeeds, every task finished
once.

Same set-up as `test_faults` (private mosquitto, one ``delegation sim`` process per unit, the
reference engine and the service in this process)."""

from __future__ import annotations

import json
import uuid

from conftest import Collector
from delegation.engine import TstEngine
from delegation.runtime.broker import PrivateMosquitto
from test_faults import (
    GOAL,
    SPEEDUP,
    Processes,
    conc,
    delegate,
    final_status,
    finished_per_goal,
    mosquitto,
    move_to,
    prefix,
    procs,
    pytestmark,
    ready,
    start_service,
    wait_running,
)

__all__ = ["mosquitto", "prefix", "procs", "pytestmark"]


def test_a_task_its_unit_aborts_moves_alone_and_the_other_units_task_is_untouched(
        mosquitto: PrivateMosquitto, procs: Processes, prefix: str) -> None:
    settings = mosquitto.settings()
    procs.sim("u0", speedup=SPEEDUP / 4)  # still flying when the repair is done
    for name in ("u1", "u2"):
        procs.sim(name)
    with TstEngine(settings, prefix=prefix), start_service(settings, prefix) as service:
        ready(service, ["u0", "u1", "u2"])
        col = Collector(settings, [f"{prefix}/unit/+/+/+/exec/#",
                                   f"{prefix}/unit/+/+/op0/tst/command",
                                   f"{prefix}/unit/+/+/delegator0/delegation/#"]).start()
        try:
            root = delegate(col, service, conc(move_to(GOAL["u0"], "/u0"),
                                               move_to(GOAL["u1"], "/u1")))
            wait_running(col, {"u0", "u1"})
            [start] = [d for d in col.json_on("+/unit/+/+/u1/exec/command")
                       if d.get("command") == "start-task"][:1]
            col.publish(f"{prefix}/unit/air/simulation/u1/exec/command",
                        {"com-uuid": str(uuid.uuid4()), "command": "signal-task",
                         "sender": "pilot", "signal": "$abort", "task-uuid": start["task-uuid"]})
            moved = col.wait_json("+/unit/+/+/+/delegation/feedback",
                                  lambda d: d.get("status") == "re-delegated", timeout=20.0)
            assert "aborted on /u1" in moved["fail-reason"], moved
            [task] = moved["tasks"]
            # Moved within the running tree: the same node, no replacement tree.
            assert task["node-uuid"] == task["replaces"] and task["unit"] in ("/u0", "/u2")
            assert finished_per_goal(col) == {}, "u0 was still flying its own task"
            end = final_status(col, root, timeout=120.0)
            assert end["status"] == "succeeded", end
            sent = [json.loads(m.payload) for m in list(col.messages)
                    if m.topic.endswith("/u0/exec/command")]
            assert not [d for d in sent if d.get("command") == "signal-task"], sent
            starts = {d["com-uuid"] for d in sent if d.get("command") == "start-task"}
            assert len(starts) == (2 if task["unit"] == "/u0" else 1), sent
            done = finished_per_goal(col)
            assert done[GOAL["u0"]] == ["u0"], done
            assert done[GOAL["u1"]] == [task["unit"].strip("/")], done
            commands = [d.get("command") for d in col.json_on("+/unit/+/+/op0/tst/command")]
            assert commands == ["start-tst", "rebind-tst-nodes"], commands
        finally:
            col.stop()
