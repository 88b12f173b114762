"""The engine without a broker: its tree state machine (`TreeExecutor`) action by action, and its
core (`EngineCore`) message by message, with ``now`` passed in."""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Any

import pytest

from delegation.engine import (
    Action,
    EngineCore,
    EngineOptions,
    NodeChanged,
    SendSignal,
    SendStartTask,
    TreeExecutor,
    check_instantiated,
)
from delegation.errors import InputError
from delegation.fleet import make_unit
from delegation.geo import GeoPoint
from delegation.messages import ExecFeedback, ExecResponse, HeartBeat, encode
from delegation.messages import NodeStatus as S
from delegation.runtime.core import Core, Effects, Identity
from delegation.sim.core import SimUnitCore
from delegation.tst.node import parse_tree

WP = {"latitude": 57.76, "longitude": 16.68, "altitude": 40.0}


def task(uid: str, unit: str = "/dji0", name: str = "move-to") -> dict[str, Any]:
    return {
        "name": name,
        "common_params": {"execunit": unit, "node-uuid": uid},
        "params": {"waypoint": WP, "speed": "standard"},
    }


def ctl(kind: str, uid: str, *children: dict[str, Any]) -> dict[str, Any]:
    return {
        "name": kind,
        "common_params": {"execunit": "/op0", "node-uuid": uid},
        "children": list(children),
        "params": {},
    }


def core(*units: str) -> TreeExecutor:
    counter = itertools.count()
    options = EngineOptions(resend_after=2.0, max_attempts=3)
    c = TreeExecutor(options, new_uuid=lambda: f"u{next(counter)}")
    for u in units:
        c.unit_seen(u, 0.0)
    return c


def starts(actions: list[Action]) -> list[SendStartTask]:
    return [a for a in actions if isinstance(a, SendStartTask)]


def changes(actions: list[Action]) -> list[tuple[str, S]]:
    return [(a.node_uuid, a.status) for a in actions if isinstance(a, NodeChanged)]


def signals(actions: list[Action]) -> list[tuple[str, str, str]]:
    """The signal-tasks among ``actions``: (unit, task-uuid, signal), com-uuids left out."""
    return [(a.unit, a.task_uuid, a.signal) for a in actions if isinstance(a, SendSignal)]


def accept(c: TreeExecutor, start: SendStartTask, now: float = 0.0) -> list[Action]:
    return c.on_response(start.com_uuid, "running", now, task_uuid=start.task_uuid)


def test_seq_runs_children_in_order_to_succeeded() -> None:
    c = core("dji0", "dji1")
    root, actions = c.start_tree(parse_tree(ctl("seq", "R", task("a"), task("b", "/dji1"))), 0.0)
    assert root == "R"
    assert changes(actions) == [("R", S.RUNNING), ("a", S.ACTIVE)]
    (sa,) = starts(actions)
    assert (sa.unit, sa.name, sa.node_uuid, sa.params["speed"]) == (
        "dji0",
        "move-to",
        "a",
        "standard",
    )
    assert changes(accept(c, sa)) == [("a", S.RUNNING)]
    actions = c.on_feedback(sa.task_uuid, "finished", 1.0)
    assert changes(actions) == [("a", S.SUCCEEDED), ("b", S.ACTIVE)]
    (sb,) = starts(actions)
    assert sb.unit == "dji1"
    accept(c, sb)
    done = c.on_feedback(sb.task_uuid, "finished", 2.0)
    assert changes(done) == [("b", S.SUCCEEDED), ("R", S.SUCCEEDED)]
    assert [a.root_flag for a in done if isinstance(a, NodeChanged)] == [False, True]
    assert c.executing() == []


def test_conc_starts_all_and_waits_for_all() -> None:
    c = core("dji0", "dji1")
    _, actions = c.start_tree(parse_tree(ctl("conc", "R", task("a"), task("b", "/dji1"))), 0.0)
    sa, sb = starts(actions)
    accept(c, sa)
    accept(c, sb)
    assert changes(c.on_feedback(sb.task_uuid, "finished", 1.0)) == [("b", S.SUCCEEDED)]
    assert changes(c.on_feedback(sa.task_uuid, "enough", 2.0)) == [
        ("a", S.SUCCEEDED),
        ("R", S.SUCCEEDED),
    ]


def test_same_unit_in_conc_waits_until_free() -> None:
    c = core("dji0")
    _, actions = c.start_tree(parse_tree(ctl("conc", "R", task("a"), task("b"))), 0.0)
    assert changes(actions) == [("R", S.RUNNING), ("a", S.ACTIVE), ("b", S.WAITING)]
    (sa,) = starts(actions)
    accept(c, sa)
    actions = c.on_feedback(sa.task_uuid, "finished", 5.0)
    assert changes(actions) == [("a", S.SUCCEEDED), ("b", S.ACTIVE)]
    (sb,) = starts(actions)
    assert sb.node_uuid == "b"


def test_camera_tasks_do_not_wait_for_the_unit() -> None:
    c = core("dji0")
    look = task("l", name="look-at-position")
    _, actions = c.start_tree(parse_tree(ctl("conc", "R", task("a"), look)), 0.0)
    assert [s.node_uuid for s in starts(actions)] == ["a", "l"]


def test_failed_child_fails_the_seq_and_aborts_the_rest() -> None:
    c = core("dji0", "dji1")
    tree = ctl("seq", "R", ctl("conc", "C", task("a"), task("b", "/dji1")), task("z"))
    _, actions = c.start_tree(parse_tree(tree), 0.0)
    sa, sb = starts(actions)
    accept(c, sa)
    accept(c, sb)
    actions = c.on_feedback(sa.task_uuid, "failed", 1.0)
    assert changes(actions) == [("a", S.FAILED)]
    assert signals(actions) == [("dji1", sb.task_uuid, "$abort")]
    actions = c.on_feedback(sb.task_uuid, "aborted", 2.0)
    assert changes(actions) == [
        ("b", S.ABORTED),
        ("C", S.FAILED),
        ("z", S.REVOKED),
        ("R", S.FAILED),
    ]
    root_change = next(a for a in actions if isinstance(a, NodeChanged) and a.root_flag)
    assert "children[0]" in root_change.fail_reason and "failed" in root_change.fail_reason


def test_refused_task_fails_with_the_units_reason() -> None:
    c = core("dji0")
    _, actions = c.start_tree(parse_tree(ctl("seq", "R", task("a"))), 0.0)
    (sa,) = starts(actions)
    actions = c.on_response(sa.com_uuid, "failed", 0.5, fail_reason="Task is not supported")
    assert changes(actions) == [("a", S.FAILED), ("R", S.FAILED)]
    reasons = [a.fail_reason for a in actions if isinstance(a, NodeChanged)]
    assert "Task is not supported" in reasons[0] and "Task is not supported" in reasons[1]


def test_abort_tree_reaches_running_tasks_and_revokes_the_rest() -> None:
    c = core("dji0")
    _, actions = c.start_tree(parse_tree(ctl("seq", "R", task("a"), task("b"))), 0.0)
    (sa,) = starts(actions)
    accept(c, sa)
    actions = c.signal_tree("R", "$abort", 1.0)
    assert len(actions) == 2
    assert ("dji0", sa.task_uuid, "$abort") in signals(actions)
    assert ("b", S.REVOKED) in changes(actions)
    assert changes(c.on_feedback(sa.task_uuid, "aborted", 2.0)) == [
        ("a", S.ABORTED),
        ("R", S.ABORTED),
    ]


def test_abort_without_confirmation_times_out() -> None:
    c = core("dji0")
    _, actions = c.start_tree(parse_tree(ctl("seq", "R", task("a"))), 0.0)
    (sa,) = starts(actions)
    accept(c, sa)
    (abort,) = [x for x in c.signal_node("a", "$abort", 1.0) if isinstance(x, SendSignal)]
    assert c.on_response(abort.com_uuid, "ok", 1.5) == []  # accepted, never confirmed
    assert c.tick(5.0) == []
    assert changes(c.tick(16.5)) == [("a", S.ABORTED), ("R", S.ABORTED)]


def test_pause_holds_the_next_child_and_continue_releases_it() -> None:
    c = core("dji0")
    _, actions = c.start_tree(parse_tree(ctl("seq", "R", task("a"), task("b"))), 0.0)
    (sa,) = starts(actions)
    accept(c, sa)
    actions = c.signal_tree("R", "$pause", 1.0)
    assert ("R", S.PAUSED) in changes(actions)
    assert ("dji0", sa.task_uuid, "$pause") in signals(actions)
    assert changes(c.on_feedback(sa.task_uuid, "paused", 1.1)) == [("a", S.PAUSED)]
    # The running task ends anyway (a unit may ignore $pause); b must not start while paused.
    actions = c.on_feedback(sa.task_uuid, "finished", 2.0)
    assert starts(actions) == [] and ("b", S.PAUSED) in changes(actions)
    actions = c.signal_tree("R", "$continue", 3.0)
    assert ("R", S.RUNNING) in changes(actions)
    assert [s.node_uuid for s in starts(actions)] == ["b"]


def test_signal_unit_reaches_only_that_units_running_tasks() -> None:
    c = core("dji0", "dji1")
    _, actions = c.start_tree(parse_tree(ctl("conc", "R", task("a"), task("b", "/dji1"))), 0.0)
    sa, sb = starts(actions)
    accept(c, sa)
    accept(c, sb)
    assert signals(c.signal_unit("/dji1", "$pause", 1.0)) == [("dji1", sb.task_uuid, "$pause")]
    with pytest.raises(InputError, match="signal"):
        c.signal_unit("/dji1", "$explode", 1.0)
    with pytest.raises(InputError, match="no executing node"):
        c.signal_node("nope", "$abort", 1.0)


def test_unanswered_start_task_is_resent_with_the_same_com_uuid_then_fails() -> None:
    c = core("dji0")
    _, actions = c.start_tree(parse_tree(ctl("seq", "R", task("a"))), 0.0)
    (first,) = starts(actions)
    assert c.tick(1.0) == []
    (again,) = starts(c.tick(2.0))
    assert again == first  # same com-uuid, same task-uuid
    (third,) = starts(c.tick(4.0))
    assert third == first
    actions = c.tick(6.0)
    assert changes(actions) == [("a", S.FAILED), ("R", S.FAILED)]
    assert "did not answer" in next(a for a in actions if isinstance(a, NodeChanged)).fail_reason


def test_busy_unit_is_asked_again_with_a_new_task_uuid() -> None:
    c = core("dji0")
    _, actions = c.start_tree(parse_tree(ctl("seq", "R", task("a"))), 0.0)
    (first,) = starts(actions)
    actions = c.on_response(first.com_uuid, "failed", 0.1, fail_reason="A task is already running")
    assert changes(actions) == [("a", S.WAITING)]
    # The example agent also sends feedback "failed" for the refused task-uuid: ignored.
    assert c.on_feedback(first.task_uuid, "failed", 0.2) == []
    assert c.tick(1.0) == []
    (second,) = starts(c.tick(2.2))
    assert second.task_uuid != first.task_uuid and second.com_uuid != first.com_uuid
    accept(c, second, 2.3)
    assert changes(c.on_feedback(second.task_uuid, "finished", 9.0)) == [
        ("a", S.SUCCEEDED),
        ("R", S.SUCCEEDED),
    ]


def test_unknown_unit_waits_then_fails() -> None:
    c = core()
    _, actions = c.start_tree(parse_tree(ctl("seq", "R", task("a"), task("b"))), 0.0)
    assert changes(actions) == [("R", S.RUNNING), ("a", S.WAITING)]
    (sa,) = starts(c.unit_seen("dji0", 3.0))
    assert sa.node_uuid == "a"
    c2 = core()
    c2.start_tree(parse_tree(ctl("seq", "R", task("a"))), 0.0)
    actions = c2.tick(15.0)
    assert changes(actions) == [("a", S.FAILED), ("R", S.FAILED)]


def test_not_instantiated_trees_are_refused_naming_the_node() -> None:
    tree = parse_tree(ctl("seq", "R", task("a"), task("b", "*"), task("c", "A")))
    problems = check_instantiated(tree)
    assert [p.where for p in problems] == [
        "root/children[1] (move-to b)",
        "root/children[2] (move-to c)",
    ]
    c = core("dji0")
    with pytest.raises(InputError, match=r"children\[1\]"):
        c.start_tree(tree, 0.0)
    missing = {"name": "move-to", "params": {"waypoint": WP}}
    with pytest.raises(InputError, match="missing"):
        c.start_tree(parse_tree(missing), 0.0)
    assert c.trees == {}


def test_node_uuids_of_an_executing_tree_cannot_be_reused() -> None:
    c = core("dji0")
    c.start_tree(parse_tree(ctl("seq", "R", task("a"))), 0.0)
    with pytest.raises(InputError, match="already executing"):
        c.start_tree(parse_tree(ctl("seq", "R", task("a"))), 1.0)


def test_missing_node_uuids_are_made() -> None:
    c = core("dji0")
    tree = {"name": "move-to", "common_params": {"execunit": "/dji0"}, "params": {"waypoint": WP}}
    root, actions = c.start_tree(parse_tree(tree), 0.0)
    assert root and changes(actions) == [(root, S.ACTIVE)]


def test_enough_on_a_control_node_ends_it_successfully() -> None:
    c = core("dji0", "dji1")
    look = task("l", "/dji1", name="look-at-position")
    _, actions = c.start_tree(parse_tree(ctl("seq", "R", look, task("z"))), 0.0)
    (sl,) = starts(actions)
    accept(c, sl)
    actions = c.signal_tree("R", "$enough", 5.0)
    assert ("dji1", sl.task_uuid, "$enough") in signals(actions)
    assert ("z", S.REVOKED) in changes(actions)
    assert changes(c.on_feedback(sl.task_uuid, "finished", 6.0)) == [
        ("l", S.SUCCEEDED),
        ("R", S.SUCCEEDED),
    ]


def test_finished_trees_are_forgotten_beyond_keep_done() -> None:
    counter = itertools.count()
    c = TreeExecutor(EngineOptions(keep_done=2), new_uuid=lambda: f"u{next(counter)}")
    c.unit_seen("dji0", 0.0)
    for i in range(5):
        _, actions = c.start_tree(parse_tree(ctl("seq", f"R{i}", task(f"a{i}"))), float(i))
        (s,) = starts(actions)
        accept(c, s)
        c.on_feedback(s.task_uuid, "finished", float(i))
    c.start_tree(parse_tree(ctl("seq", "R5", task("a5"))), 6.0)
    assert list(c.trees) == ["R3", "R4", "R5"]
    assert c.status("a0") is None and c.status("a4") is S.SUCCEEDED
    # A finished tree's uuids may be used again (a4 then waits: dji0 is busy with a5).
    _, actions = c.start_tree(parse_tree(ctl("seq", "R4", task("a4"))), 7.0)
    assert changes(actions) == [("R4", S.RUNNING), ("a4", S.WAITING)]


# --------------------------------------------------------------------------- the core: messages

IDENTITY = Identity("op0", "ground", "engine-uuid", prefix="test")
COMMAND = f"{IDENTITY.base}/tst/command"
RESPONSE = f"{IDENTITY.base}/tst/response"
FEEDBACK = f"{IDENTITY.base}/tst/feedback"
DJI0 = "test/unit/air/real/dji0"  # a role other than the engine's: the heartbeat tells


def engine(*units: str) -> EngineCore:
    counter = itertools.count()
    options = EngineOptions(resend_after=2.0, max_attempts=3)
    c = EngineCore(IDENTITY, options, new_uuid=lambda: f"u{next(counter)}")
    for name in units:
        heartbeat_of(c, name)
    return c


def heartbeat_of(c: EngineCore, name: str, now: float = 0.0) -> Effects:
    hb = HeartBeat(
        agent_type="air", agent_uuid=name, levels=["direct execution"], name=name, rate=1.0, stamp=1
    )
    return c.on_message(f"test/unit/air/real/{name}/heartbeat", encode(hb), now)


def send(c: EngineCore, command: dict[str, Any] | bytes, now: float = 1.0) -> Effects:
    payload = command if isinstance(command, bytes) else json.dumps(command).encode()
    return c.on_message(COMMAND, payload, now)


def on(effects: Effects, topic: str) -> list[dict[str, Any]]:
    return [json.loads(out.payload) for out in effects.publish if out.topic == topic]


def start_tst(tree: dict[str, Any], com_uuid: str = "c1") -> dict[str, Any]:
    return {"com-uuid": com_uuid, "command": "start-tst", "sender": "test", "tst": tree}


def test_the_core_speaks_the_core_protocol() -> None:
    c = engine()
    assert isinstance(c, Core)
    assert c.name == "op0" and c.status_period == 1.0
    assert COMMAND in c.subscriptions() and "test/unit/+/+/+/exec/feedback" in c.subscriptions()


def test_status_is_a_heartbeat_and_the_trees_executing() -> None:
    c = engine("dji0")
    send(c, start_tst(ctl("seq", "R", task("a"))))
    hb, info = c.status(5.0, 1234.5)
    assert hb.topic == f"{IDENTITY.base}/heartbeat" and hb.qos == 0
    beat = json.loads(hb.payload)
    assert (beat["levels"], beat["name"], beat["agent-uuid"]) == (
        ["tst execution"],
        "op0",
        "engine-uuid",
    )
    assert info.topic == f"{IDENTITY.base}/tst_execution_info"
    data = json.loads(info.payload)
    assert (data["trees-executing"], data["stamp"], data["type"]) == (
        ["R"],
        1234.5,
        "TstExecutionInfo",
    )


def test_ping_is_answered_with_pong() -> None:
    c = engine()
    (pong,) = on(send(c, {"com-uuid": "p1", "command": "ping", "sender": "test"}), RESPONSE)
    assert (pong["response"], pong["response-to"]) == ("pong", "p1")


def test_bad_json_with_a_com_uuid_is_answered_failed_naming_the_problem() -> None:
    c = engine()
    bad = {"com-uuid": "b1", "command": "signal-tst-node", "sender": "test", "signal": "$abort"}
    (answer,) = on(send(c, bad), RESPONSE)
    assert (answer["response"], answer["response-to"]) == ("failed", "b1")
    assert "node-uuid" in answer["fail-reason"]
    assert send(c, b"{not json") == Effects()  # no com-uuid: nobody to answer


def test_unsupported_command_is_answered_failed() -> None:
    c = engine()
    (answer,) = on(send(c, {"com-uuid": "d1", "command": "delegate", "sender": "t"}), RESPONSE)
    assert (answer["response"], answer["response-to"]) == ("failed", "d1")
    assert "delegate" in answer["fail-reason"] and "start-tst" in answer["fail-reason"]


def test_resent_start_tst_gets_the_same_bytes_and_starts_the_tree_once() -> None:
    c = engine("dji0")
    cmd = start_tst(ctl("seq", "R", task("a")))
    first = send(c, cmd)
    again = send(c, cmd, now=3.0)
    (started,) = on(first, RESPONSE)
    assert (started["response"], started["root-uuid"]) == ("started", "R")
    assert again.publish == [o for o in first.publish if o.topic == RESPONSE]  # no start-task
    assert again.publish[0].payload == first.publish[0].payload
    assert len(on(first, f"{DJI0}/exec/command")) == 1  # the start-task, sent once
    assert list(c.trees) == ["R"] and c.commands.get(("tst", "c1")) is not None


def test_start_tst_of_a_tree_not_fully_instantiated_fails_naming_the_node() -> None:
    c = engine("dji0")
    effects = send(c, start_tst(ctl("seq", "R", task("a"), task("free", "*"))))
    (answer,) = on(effects, RESPONSE)
    assert answer["response"] == "failed"
    assert "root/children[1]" in answer["fail-reason"] and "free" in answer["fail-reason"]
    assert c.trees == {} and on(effects, FEEDBACK) == []


def test_start_task_goes_to_the_base_topic_learnt_from_the_heartbeat() -> None:
    c = engine()
    effects = send(c, start_tst(ctl("seq", "R", task("a"))))
    assert [d["status"] for d in on(effects, FEEDBACK)] == ["running", "waiting"]
    assert not c.knows(["dji0"])
    effects = heartbeat_of(c, "dji0", 2.0)
    assert c.knows(["/dji0"]) and c.bases["dji0"] == DJI0
    (start,) = on(effects, f"{DJI0}/exec/command")
    assert (start["command"], start["execution-unit"], start["sender"]) == (
        "start-task",
        "dji0",  # as every seed example (10.1.x), without the execunit's slash
        "op0",
    )
    assert start["task"]["name"] == "move-to" and start["task"]["params"]["speed"] == "standard"
    assert [(d["node-uuid"], d["status"]) for d in on(effects, FEEDBACK)] == [("a", "active")]


def test_unit_response_and_feedback_become_tst_feedback() -> None:
    c = engine("dji0")
    (start,) = on(send(c, start_tst(ctl("seq", "R", task("a")))), f"{DJI0}/exec/command")
    accepted = ExecResponse(
        response="running", response_to=start["com-uuid"], task_uuid=start["task-uuid"]
    )
    effects = c.on_message(f"{DJI0}/exec/response", encode(accepted), 2.0)
    assert [(d["node-uuid"], d["status"]) for d in on(effects, FEEDBACK)] == [("a", "running")]
    done = ExecFeedback(status="finished", task_uuid=start["task-uuid"])
    effects = c.on_message(f"{DJI0}/exec/feedback", encode(done), 3.0)
    assert [(d["node-uuid"], d["status"], d["root-flag"]) for d in on(effects, FEEDBACK)] == [
        ("a", "succeeded", False),
        ("R", "succeeded", True),
    ]
    assert json.loads(c.status(4.0, 0.0)[1].payload)["trees-executing"] == []


def test_signals_are_answered_ok_and_reach_the_unit() -> None:
    c = engine("dji0")
    (start,) = on(send(c, start_tst(ctl("seq", "R", task("a"), task("b")))), f"{DJI0}/exec/command")
    accepted = ExecResponse(response="running", response_to=start["com-uuid"])
    c.on_message(f"{DJI0}/exec/response", encode(accepted), 2.0)
    abort = {
        "com-uuid": "s1",
        "command": "signal-tst-tree",
        "node-uuid": "R",
        "sender": "t",
        "signal": "$abort",
    }
    effects = send(c, abort, 3.0)
    assert effects.publish[0].topic == RESPONSE  # the answer first, then what it set going
    assert on(effects, RESPONSE)[0]["response"] == "ok"
    (signal,) = on(effects, f"{DJI0}/exec/command")
    assert (signal["command"], signal["signal"], signal["task-uuid"]) == (
        "signal-task",
        "$abort",
        start["task-uuid"],
    )
    assert ("b", "revoked") in [(d["node-uuid"], d["status"]) for d in on(effects, FEEDBACK)]
    unknown = {
        "com-uuid": "s2",
        "command": "signal-unit",
        "unit": "/dji0",
        "sender": "t",
        "signal": "$explode",
    }
    (answer,) = on(send(c, unknown, 4.0), RESPONSE)
    assert answer["response"] == "failed" and "$explode" in answer["fail-reason"]


def test_unanswered_start_task_is_resent_on_tick() -> None:
    c = engine("dji0")
    (start,) = on(send(c, start_tst(ctl("seq", "R", task("a")))), f"{DJI0}/exec/command")
    assert on(c.on_tick(2.5), f"{DJI0}/exec/command") == []  # sent at 1.0
    assert on(c.on_tick(3.0), f"{DJI0}/exec/command") == [start]  # same com-uuid and task-uuid


@pytest.mark.parametrize(("spelt", "accepted"), [("dji0", True), ("/dji0", True),
                                                 ("usv0", False), ("/usv0", False)])
def test_start_task_names_the_unit_as_the_seed_examples_do(spelt: str, accepted: bool) -> None:
    """Seed 10.1.x: ``"execution-unit": "dji0"`` in every start-task (the tree's execunit is
    ``/dji0``); the simulated unit takes either spelling of its own name, and no other name."""
    c = engine("dji0")
    (start,) = on(send(c, start_tst(ctl("seq", "R", task("a", "/dji0")))), f"{DJI0}/exec/command")
    assert start["execution-unit"] == "dji0"
    sim = SimUnitCore(make_unit("dji0", "air", GeoPoint(**WP), ["move-to"]), prefix="test")
    start["execution-unit"] = spelt
    answer = sim.on_message(sim.identity.topic("exec/command"), json.dumps(start).encode(), 1.0)
    (response,) = [json.loads(o.payload) for o in answer.publish if o.topic.endswith("response")]
    assert response["response"] == ("running" if accepted else "failed"), response


SEED = Path(__file__).parent / "fixtures" / "seed"


@pytest.mark.parametrize("path", sorted(SEED.glob("11.1.*.json")), ids=lambda p: p.name)
def test_the_seeds_single_task_start_tst_to_the_engine_itself_is_refused_at_once(
        path: Path) -> None:
    """Seed 11.1.x: one task with execunit /op0 sent to op0, this engine: answered failed at once
    naming the node and why (was: start-task to itself, failed ~10 s later)."""
    c = engine("dji0")
    effects = send(c, path.read_bytes())
    (answer,) = on(effects, RESPONSE)
    assert answer["response"] == "failed"
    assert answer["fail-reason"].startswith("root (")
    assert "execunit: /op0 is this TST engine, which runs no tasks" in answer["fail-reason"]
    assert c.trees == {} and on(effects, FEEDBACK) == []
    assert [o for o in effects.publish if "exec/command" in o.topic] == []


@pytest.mark.parametrize(("units", "refused"), [
    (("/dji0", "/dji0"), []),
    (("/dji0", "/op0"), ["root/children[1]"]),
    (("/op0", "/op0"), ["root/children[0]", "root/children[1]"]),
])
def test_tasks_for_the_engine_are_named(units: tuple[str, str], refused: list[str]) -> None:
    c = engine("dji0")
    (answer,) = on(send(c, start_tst(ctl("seq", "R", task("a", units[0]), task("b", units[1])))),
                   RESPONSE)
    assert answer["response"] == ("failed" if refused else "started")
    assert [w for w in refused if w not in answer.get("fail-reason", "")] == []
