"""The engine catching up after a broker outage (docs/protocol.md §11): ``query-status`` to the
units on reconnect and when a unit's heartbeat comes back after a gap; the answers applied as
feedback."""

from __future__ import annotations

import json

import pytest

from delegation.engine import EngineCore
from delegation.messages import ExecFeedback, ExecResponse, HeartBeat, encode
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


def signal_node(c: EngineCore, uid: str, signal: str, now: float) -> Effects:
    return send(c, {"com-uuid": f"s-{signal}", "command": "signal-tst-node", "node-uuid": uid,
                    "sender": "test", "signal": signal}, now)


# (a signal the task got before the outage, the unit's answer to query-status, what follows)
ANSWERS: list[tuple[str | None, str, list[tuple[str, str]]]] = [
    # the seed's words: running, failed, success, unknown
    (None, "running", []),
    (None, "success", [("a", "succeeded"), ("R", "succeeded")]),
    (None, "failed", [("a", "failed"), ("R", "failed")]),
    (None, "unknown", [("a", "failed"), ("R", "failed")]),
    # a paused task is still on the unit: "running" does not make it running again
    ("$pause", "running", []),
    # the seed has no word for aborted: "failed" after our $abort is the abort done
    ("$abort", "failed", [("a", "aborted"), ("R", "aborted")]),
    # older units' feedback words still mean what they say
    (None, "finished", [("a", "succeeded"), ("R", "succeeded")]),
    ("$pause", "paused", []),
]


@pytest.mark.parametrize(("signal", "word", "then"), ANSWERS,
                         ids=[f"{s or 'none'}-{w}" for s, w, _ in ANSWERS])
def test_query_status_answers_in_the_seeds_words(signal: str | None, word: str,
                                                 then: list[tuple[str, str]]) -> None:
    c = engine("dji0")
    task_uuid = running_task(c)
    if signal is not None:
        effects = signal_node(c, "a", signal, 2.0)
        (sig,) = commands(effects)
        c.on_message(f"{DJI0}/exec/response", encode(ExecResponse(
            response="ok", response_to=str(sig["com-uuid"]), task_uuid=task_uuid)), 2.1)
        if signal == "$pause":  # the unit's feedback: the node is paused
            c.on_message(f"{DJI0}/exec/feedback", encode(ExecFeedback(
                agent_uuid="dji0", status="paused", task_uuid=task_uuid)), 2.2)
    (query,) = commands(c.on_reconnect(20.0))
    assert statuses(answer(c, query, word, 20.1)) == then
    expected = {"$pause": "paused", None: "running", "$abort": "running"}[signal]
    assert c.trees["R"].nodes["a"].status.value == (then[0][1] if then else expected)


def beat(c: EngineCore, agent_uuid: str, now: float) -> Effects:
    hb = HeartBeat(agent_type="air", agent_uuid=agent_uuid, levels=["direct execution"],
                   name="dji0", rate=1.0, stamp=now)
    return c.on_message(f"{DJI0}/heartbeat", encode(hb), now)


# (what the node is doing when dji0's heartbeat comes, that heartbeat's agent-uuid, what follows)
REBOOTS: list[tuple[str, str, list[tuple[str, str]]]] = [
    ("running", "dji0-after-reboot", [("a", "failed"), ("R", "failed")]),
    ("paused", "dji0-after-reboot", [("a", "failed"), ("R", "failed")]),
    ("running", "dji0", []),  # the same agent-uuid: the same life
    # not answered yet: the start-task is re-sent as before, and the rebooted unit may take it
    ("unanswered", "dji0-after-reboot", []),
    ("succeeded", "dji0-after-reboot", []),  # nothing of ours on it any more
]


@pytest.mark.parametrize(("doing", "agent_uuid", "then"), REBOOTS,
                         ids=[f"{d}-{'new' if u != 'dji0' else 'same'}" for d, u, _ in REBOOTS])
def test_a_new_agent_uuid_is_a_rebooted_unit(doing: str, agent_uuid: str,
                                             then: list[tuple[str, str]]) -> None:
    """Seed 12.1: "the changing agent-uuid when rebooting is used to detect that the agent has
    lost its history of commands": the tasks it accepted are gone, at its first new heartbeat
    (however short the reboot, whether or not it answers query-status)."""
    c = engine("dji0")  # its heartbeat's agent-uuid: "dji0"
    if doing == "unanswered":
        send(c, start_tst(ctl("seq", "R", task("a"))))
    else:
        task_uuid = running_task(c)
        if doing in ("paused", "succeeded"):
            status = "paused" if doing == "paused" else "finished"
            c.on_message(f"{DJI0}/exec/feedback", encode(ExecFeedback(
                agent_uuid="dji0", status=status, task_uuid=task_uuid)), 1.8)
    effects = beat(c, agent_uuid, 2.0)  # one second after the last: no gap, no query-status
    assert statuses(effects) == then
    assert [m["command"] for m in commands(effects)] == []
    if then:
        reason = next(json.loads(o.payload)["fail-reason"] for o in effects.publish
                      if o.topic == FEEDBACK)
        assert reason == ("/dji0 rebooted (a new agent-uuid in its heartbeat): "
                          "the task it ran is gone")
    assert statuses(beat(c, agent_uuid, 3.0)) == []  # told once
