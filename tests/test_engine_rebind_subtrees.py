"""``rebind-tst-nodes`` with ``subtrees`` (issue 22 item 3, issue 21 item 4; docs/protocol.md
§12.6): a task node of an executing tree is replaced by a subtree under the same uuid (a lost
unit's unswept remainder of a shared search, shared again among live units). The old unit is told
``$abort``, the subtree runs in the task's place (now if its turn had come, else when it comes),
its end is the node's end, and nothing else of the tree is touched."""

from __future__ import annotations

from typing import Any

import pytest

from delegation.engine.executor import SendSignal, SendStartTask
from delegation.errors import InputError
from delegation.messages import NodeStatus as S
from delegation.tst.node import parse_tree
from test_engine_core import DJI0, ctl, engine, on, send, start_tst, task
from test_engine_signals import Fleet

OTHER_WP = {"latitude": 57.77, "longitude": 16.69, "altitude": 40.0}


def conc_ab() -> dict[str, Any]:
    return ctl("conc", "R", task("a", "/dji0"), task("b", "/dji1"))


def seq_ab() -> dict[str, Any]:
    return ctl("seq", "R", task("a", "/dji0"), task("b", "/dji1"))


def parts(*pairs: tuple[str, str]) -> dict[str, Any]:
    """A conc replacing ``b`` (no node-uuid on its root: the key gives it)."""
    node = ctl("conc", "b", *(task(uid, unit) for uid, unit in pairs))
    del node["common_params"]["node-uuid"]
    return node


def starts(fleet: Fleet, since: int = 0) -> list[tuple[str, str]]:
    return [(a.node_uuid, a.unit) for a in fleet.out[since:] if isinstance(a, SendStartTask)]


def test_a_running_task_replaced_by_parts_runs_them_and_ends_with_them() -> None:
    fleet = Fleet.of(conc_ab(), "dji0", "dji1", "dji2")
    fleet.now, before = 1.0, len(fleet.out)
    fleet.take(fleet.executor.rebind({}, fleet.now, {"b": parse_tree(
        parts(("b1", "/dji2"), ("b2", "/dji0")))}))
    # b1 starts at once on the idle dji2; b2 waits for dji0's own running task a.
    assert starts(fleet, before) == [("b1", "dji2")]
    assert fleet.last("b2") is S.WAITING
    aborts = [(a.unit, a.signal) for a in fleet.out[before:] if isinstance(a, SendSignal)]
    assert aborts == [("dji1", "$abort")]  # the old unit, for the task it may still fly
    assert not [n for n, _ in fleet.signalled if n == "a"]
    fleet.step("finished", "a")
    assert starts(fleet, before)[-1] == ("b2", "dji0")
    fleet.step("finished", "b1")
    assert fleet.last("b") is S.RUNNING and fleet.last("R") is S.RUNNING
    fleet.step("finished", "b2")
    assert fleet.last("b") is S.SUCCEEDED and fleet.last("R") is S.SUCCEEDED
    assert fleet.history["a"] == [S.ACTIVE, S.RUNNING, S.SUCCEEDED]
    assert fleet.executor.tree_status("R") is not None
    assert {n["node-uuid"] for n in fleet.executor.tree_status("R") or []} == {
        "R", "a", "b", "b1", "b2"}


def test_a_task_whose_turn_has_not_come_is_replaced_and_its_subtree_waits_for_the_turn() -> None:
    fleet = Fleet.of(seq_ab(), "dji0", "dji1", "dji2")
    fleet.now, before = 1.0, len(fleet.out)
    fleet.take(fleet.executor.rebind({}, fleet.now, {"b": parse_tree(
        parts(("b1", "/dji2"), ("b2", "/dji1")))}))
    assert starts(fleet, before) == [] and not [a for a in fleet.out[before:]
                                                if isinstance(a, SendSignal)]
    fleet.step("finished", "a")
    assert sorted(starts(fleet, before)) == [("b1", "dji2"), ("b2", "dji1")]
    fleet.step("finished", "b1")
    fleet.step("failed", "b2")
    assert fleet.last("b") is S.FAILED and fleet.last("R") is S.FAILED
    assert fleet.reasons["b"].startswith("root/children[1]/children[1] (move-to) failed")


def test_a_task_replaced_by_one_task_with_other_parameters_starts_them_on_its_new_unit() -> None:
    fleet = Fleet.of(conc_ab(), "dji0", "dji1", "dji2")
    new = task("b", "/dji2")
    new["params"]["waypoint"] = OTHER_WP
    fleet.now, before = 1.0, len(fleet.out)
    fleet.take(fleet.executor.rebind({}, fleet.now, {"b": parse_tree(new)}))
    [sent] = [a for a in fleet.out[before:] if isinstance(a, SendStartTask)]
    assert (sent.node_uuid, sent.unit, sent.params["waypoint"]) == ("b", "dji2", OTHER_WP)
    fleet.step("finished", "b")
    fleet.step("finished", "a")
    assert fleet.last("R") is S.SUCCEEDED


PROBLEMS = [
    ({"b": ctl("conc", "other", task("b1", "/dji2"))}, "its root's node-uuid is other"),
    ({"b": parts(("a", "/dji2"))}, "node-uuid a is already executing"),
    ({"b": parts(("b1", "dji2"))}, "is not a unit"),
    ({"S": parts(("b1", "/dji2"))}, "no executing node"),
    ({"R": parts(("b1", "/dji2"))}, "not a task node"),
]


@pytest.mark.parametrize(("subtrees", "why"), PROBLEMS)
def test_a_replacement_that_cannot_be_done_is_refused_whole(subtrees, why) -> None:
    fleet = Fleet.of(conc_ab(), "dji0", "dji1", "dji2")
    before = dict(fleet.history)
    with pytest.raises(InputError, match=why):
        fleet.executor.rebind({"a": "/dji2"},  1.0,
                              {k: parse_tree(v) for k, v in subtrees.items()})
    assert fleet.history == before
    assert fleet.executor.trees["R"].nodes["a"].unit == "dji0"  # type: ignore[attr-defined]
    assert "b1" not in fleet.executor.trees["R"].nodes


def test_a_node_both_moved_and_replaced_is_refused() -> None:
    fleet = Fleet.of(conc_ab(), "dji0", "dji1", "dji2")
    with pytest.raises(InputError, match="also in execunits"):
        fleet.executor.rebind({"b": "/dji2"}, 1.0, {"b": parse_tree(parts(("b1", "/dji2")))})


def test_subtrees_on_the_engines_tst_command() -> None:
    c = engine("dji0", "dji1", "dji2")
    send(c, start_tst(conc_ab()))
    out = send(c, {"com-uuid": "c2", "command": "rebind-tst-nodes", "sender": "test",
                   "execunits": {}, "subtrees": {"b": parts(("b1", "/dji2"))}}, now=2.0)
    assert on(out, f"{c.base}/tst/response")[0]["response"] == "ok"
    to_dji2 = on(out, "test/unit/air/real/dji2/exec/command")
    assert [m["command"] for m in to_dji2] == ["start-task"]
    assert on(out, f"{DJI0}/exec/command") == []  # the healthy unit hears nothing
    bad = send(c, {"com-uuid": "c3", "command": "rebind-tst-nodes", "sender": "test",
                   "execunits": {}, "subtrees": {"a": {"name": "conc", "children": 3}}}, now=3.0)
    answer = on(bad, f"{c.base}/tst/response")[0]
    assert answer["response"] == "failed" and "children" in answer["fail-reason"]
