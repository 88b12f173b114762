"""Signals to executing trees end to end (issue 20): the real engine on a real broker with
simulated units, or with a scripted unit that loses messages. The signal sent, the statuses seen
in order, and the units' start-tasks and signal-tasks counted."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from typing import Any

import pytest

from delegation.engine import EngineOptions, TstEngine
from delegation.fleet import make_unit
from delegation.local import LocalSystem
from delegation.messages import HeartBeat, encode
from delegation.runtime.settings import BrokerSettings
from test_engine_mqtt import FRAME, START, TASKS, ctl, move, start_tst

pytestmark = pytest.mark.mqtt

TIMEOUT = 30.0
ENDED = ("succeeded", "failed", "aborted")


@pytest.fixture
def system(mqtt_settings: BrokerSettings, prefix: str) -> Iterator[TstEngine]:
    """The engine and two simulated units (dji0, dji1) flying 400 m/s (10 m/s x 40)."""
    units = [
        make_unit("dji0", "air", START, TASKS, speeds={"fast": 10.0}),
        make_unit("dji1", "air", FRAME.geopoint(50, 0, 40), TASKS, speeds={"fast": 10.0}),
    ]
    local = LocalSystem(units, settings=mqtt_settings, prefix=prefix, speedup=40.0,
                        service=False, ready_timeout=10.0)
    local.start()
    assert local.engine is not None
    yield local.engine
    local.stop()


class Watch:
    """The engine's answers and feedback and the units' commands, read from a collector."""

    def __init__(self, collector: Any, engine: TstEngine, prefix: str) -> None:
        self.engine = engine
        self.commands = f"{prefix}/unit/+/+/+/exec/command"
        self.c = collector(f"{engine.base}/tst/#", self.commands)

    def send(self, command: dict[str, Any]) -> dict[str, Any]:
        self.c.publish(f"{self.engine.base}/tst/command", command)
        return self.c.wait_json(f"{self.engine.base}/tst/response",
                                lambda d: d["response-to"] == command["com-uuid"])

    def signal(self, command: str, signal: str, **target: str) -> None:
        msg = {"com-uuid": str(uuid.uuid4()), "command": command, "sender": "test",
               "signal": signal, **target}
        assert self.send(msg)["response"] == "ok"

    def status(self, node: str, status: str, timeout: float = TIMEOUT) -> dict[str, Any]:
        return self.c.wait_json(f"{self.engine.base}/tst/feedback",
                                lambda d: d["node-uuid"] == node and d["status"] == status,
                                timeout=timeout, what=f"{node} {status}")

    def history(self) -> dict[str, list[str]]:
        out: dict[str, list[str]] = {}
        for d in self.c.json_on(f"{self.engine.base}/tst/feedback"):
            out.setdefault(d["node-uuid"], []).append(d["status"])
        return out

    def order(self) -> list[tuple[str, str]]:
        return [(d["node-uuid"], d["status"])
                for d in self.c.json_on(f"{self.engine.base}/tst/feedback")]

    def to_unit(self, unit: str, command: str) -> list[dict[str, Any]]:
        topic = self.commands.replace("+/+/+", f"+/+/{unit}")
        return [d for d in self.c.json_on(topic) if d["command"] == command]


# --------------------------------------------------------------------------- item 1


def seq_abc() -> dict[str, Any]:
    return ctl("seq", "R", move("a", "/dji0", 0, 40_000), move("b", "/dji1", 50, 400),
               move("c", "/dji0", 0, 0))


def test_enough_to_a_queued_task_skips_it_and_keeps_the_order(system, collector, prefix) -> None:
    w = Watch(collector, system, prefix)
    assert w.send(start_tst(seq_abc()))["response"] == "started"
    w.status("a", "running")
    w.signal("signal-tst-node", "$enough", **{"node-uuid": "b"})
    w.status("b", "revoked")
    w.signal("signal-tst-node", "$enough", **{"node-uuid": "a"})  # a ends; c is next, not b
    assert w.c.wait_json(f"{system.base}/tst/feedback",
                         lambda d: d["root-flag"] and d["status"] in ENDED,
                         timeout=TIMEOUT)["status"] == "succeeded"
    history, order = w.history(), w.order()
    assert history["b"] == ["revoked"]
    assert history["c"] == ["active", "running", "succeeded"]
    assert order.index(("a", "succeeded")) < order.index(("c", "active"))
    assert len(w.to_unit("dji0", "start-task")) == 2 and w.to_unit("dji1", "start-task") == []
    assert [d["signal"] for d in w.to_unit("dji0", "signal-task")] == ["$enough"]
    assert w.to_unit("dji1", "signal-task") == []


def test_pause_of_a_queued_task_holds_it_when_its_turn_comes(system, collector, prefix) -> None:
    w = Watch(collector, system, prefix)
    assert w.send(start_tst(seq_abc()))["response"] == "started"
    w.status("a", "running")
    w.signal("signal-tst-node", "$pause", **{"node-uuid": "b"})
    w.signal("signal-tst-node", "$enough", **{"node-uuid": "a"})
    w.status("b", "paused")
    assert w.to_unit("dji1", "start-task") == []  # its turn came, paused: not started
    w.signal("signal-tst-node", "$continue", **{"node-uuid": "b"})
    w.status("R", "succeeded")
    history = w.history()
    assert history["b"] == ["paused", "active", "running", "succeeded"]
    assert len(w.to_unit("dji1", "start-task")) == 1 and len(w.to_unit("dji0", "start-task")) == 2


# --------------------------------------------------------------------------- item 5


@pytest.mark.parametrize(("command", "target"), [
    ("signal-tst-node", {"node-uuid": "a"}),
    ("signal-unit", {"unit": "/dji0"}),
])
def test_aborting_one_branch_lets_the_other_run_on(
    system, collector, prefix, command: str, target: dict[str, str]
) -> None:
    w = Watch(collector, system, prefix)
    left = ctl("seq", "L", move("a", "/dji0", 0, 40_000), move("a2", "/dji0", 0, 0))
    tree = ctl("conc", "R", left, move("b", "/dji1", 50, 1500))
    assert w.send(start_tst(tree))["response"] == "started"
    w.status("a", "running")
    w.status("b", "running")
    w.signal(command, "$abort", **target)
    final = w.c.wait_json(f"{system.base}/tst/feedback",
                          lambda d: d["root-flag"] and d["status"] in ENDED, timeout=TIMEOUT)
    assert final["status"] == "aborted" and "children[0]" in final["fail-reason"]
    history, order = w.history(), w.order()
    assert history["a"][-1] == "aborted" and history["a2"] == ["revoked"]
    assert history["L"][-1] == "aborted"
    assert history["b"] == ["active", "running", "succeeded"]  # never aborted
    assert order.index(("b", "succeeded")) < order.index(("R", "aborted"))
    assert [d["signal"] for d in w.to_unit("dji0", "signal-task")] == ["$abort"]
    assert w.to_unit("dji1", "signal-task") == []
    assert len(w.to_unit("dji0", "start-task")) == 1 == len(w.to_unit("dji1", "start-task"))


# --------------------------------------------------------------------------- item 3


@pytest.fixture
def lossy(mqtt_settings: BrokerSettings, prefix: str, collector) -> Iterator[tuple[Watch, str]]:
    """The engine re-sending every 0.3 s, 3 tries, and a unit ``ghost`` the test plays by hand
    (one heartbeat, then only the answers the test publishes)."""
    options = EngineOptions(resend_after=0.3, max_attempts=3, abort_timeout=5.0)
    engine = TstEngine(mqtt_settings, prefix=prefix, options=options)
    engine.start()
    try:
        w = Watch(collector, engine, prefix)
        base = f"{prefix}/unit/air/simulation/ghost"
        beat = HeartBeat(agent_type="air", agent_uuid="ghost-1", levels=["direct execution"],
                         name="ghost", rate=1.0, stamp=1.0)
        w.c.publish(f"{base}/heartbeat", encode(beat))
        assert engine.wait_for_units(["ghost"], 10.0)
        yield w, base
    finally:
        engine.stop()


def copies(w: Watch, command: str, n: int) -> list[dict[str, Any]]:
    """Wait for ``n`` copies of the ghost's ``command``; all of them so far."""
    w.c.wait_for(lambda _m: len(w.to_unit("ghost", command)) >= n, timeout=TIMEOUT,
                 what=f"{n} x {command}")
    return w.to_unit("ghost", command)


def test_lost_start_task_and_abort_are_resent_with_the_same_com_uuid(lossy) -> None:
    w, base = lossy
    assert w.send(start_tst(ctl("seq", "R", move("a", "/ghost", 0, 100))))["response"] == "started"
    starts = copies(w, "start-task", 2)  # the first copy is "lost": the ghost answers the second
    assert all(s == starts[0] for s in starts)
    w.c.publish(f"{base}/exec/response", {"com-uuid": "g1", "response": "running",
                                          "response-to": starts[0]["com-uuid"],
                                          "task-uuid": starts[0]["task-uuid"]})
    w.status("a", "running")
    w.signal("signal-tst-node", "$abort", **{"node-uuid": "a"})
    aborts = copies(w, "signal-task", 2)
    assert all(s == aborts[0] for s in aborts)
    assert (aborts[0]["signal"], aborts[0]["task-uuid"]) == ("$abort", starts[0]["task-uuid"])
    w.c.publish(f"{base}/exec/response", {"com-uuid": "g2", "response": "ok",
                                          "response-to": aborts[0]["com-uuid"]})
    w.c.publish(f"{base}/exec/feedback", {"com-uuid": "g3", "status": "aborted",
                                          "task-uuid": starts[0]["task-uuid"]})
    w.status("R", "aborted")
    assert w.history()["a"] == ["active", "running", "aborted"]


def test_a_start_task_never_answered_fails_the_node_then_aborts_on_the_unit(lossy) -> None:
    w, base = lossy
    assert w.send(start_tst(ctl("seq", "R", move("a", "/ghost", 0, 100))))["response"] == "started"
    failed = w.status("a", "failed")
    assert "did not answer start-task (3 attempts)" in failed["fail-reason"]
    starts = w.to_unit("ghost", "start-task")
    assert len(starts) == 3 and all(s == starts[0] for s in starts)
    aborts = copies(w, "signal-task", 2)  # re-sent until answered
    assert all(s == aborts[0] for s in aborts)
    assert (aborts[0]["signal"], aborts[0]["task-uuid"]) == ("$abort", starts[0]["task-uuid"])
    w.c.publish(f"{base}/exec/response", {"com-uuid": "g1", "response": "ok",
                                          "response-to": aborts[0]["com-uuid"]})
    assert w.status("R", "failed")["root-flag"] is True
