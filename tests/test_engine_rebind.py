"""``rebind-tst-nodes`` at the engine's core (issue 22 item 3, docs/protocol.md §12.6): task nodes
of an executing tree move to other units, and nothing else of the tree is touched: a healthy
unit's running task gets no signal and no second start-task.

Table-driven at the executor's level with `Fleet` (units that accept and act on everything), and
once through `EngineCore` (the command on ``tst/command``, its answer, the topics written to)."""

from __future__ import annotations

from typing import Any

import pytest

from delegation.engine.executor import SendSignal, SendStartTask
from delegation.errors import InputError
from delegation.messages import NodeStatus as S
from test_engine_core import DJI0, ctl, engine, on, send, start_tst, task
from test_engine_signals import Fleet


def conc_ab() -> dict[str, Any]:
    return ctl("conc", "R", task("a", "/dji0"), task("b", "/dji1"))


def seq_ab() -> dict[str, Any]:
    return ctl("seq", "R", task("a", "/dji0"), task("b", "/dji1"))


def conc_seq() -> dict[str, Any]:
    return ctl("conc", "R", task("a", "/dji0"),
               ctl("seq", "S", task("b", "/dji1"), task("c", "/dji1")))


#: (name, tree, rebinding, then the units report, start-tasks per node on which units, the
#: nodes that must never be signalled, the root's last status)
CASES: list[tuple[str, Any, dict[str, str], list[tuple[str, str]], dict[str, list[str]],
                  list[str], S]] = [
    (
        "a running task moves to an idle unit; its sibling runs on untouched",
        conc_ab, {"b": "/dji2"}, [("finished", "a"), ("finished", "b")],
        {"a": ["dji0"], "b": ["dji1", "dji2"]}, ["a"], S.SUCCEEDED,
    ),
    (
        "a running task moves to a busy unit: it waits for the unit's own task to end",
        conc_ab, {"b": "/dji0"}, [("finished", "a"), ("finished", "b")],
        {"a": ["dji0"], "b": ["dji1", "dji0"]}, ["a"], S.SUCCEEDED,
    ),
    (
        "a task whose turn has not come starts on its new unit when it comes",
        seq_ab, {"b": "/dji2"}, [("finished", "a"), ("finished", "b")],
        {"a": ["dji0"], "b": ["dji2"]}, ["a"], S.SUCCEEDED,
    ),
    (
        "a lost unit's running and queued tasks move together, in their order",
        conc_seq, {"b": "/dji2", "c": "/dji2"},
        [("finished", "a"), ("finished", "b"), ("finished", "c")],
        {"a": ["dji0"], "b": ["dji1", "dji2"], "c": ["dji2"]}, ["a"], S.SUCCEEDED,
    ),
]


@pytest.mark.parametrize(("tree", "rebind", "script", "units", "untouched", "final"),
                         [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_rebinding_moves_only_the_named_tasks(tree, rebind, script, units, untouched,
                                              final) -> None:
    fleet = Fleet.of(tree(), "dji0", "dji1", "dji2")
    started_on: dict[str, list[str]] = {}
    fleet.now += 1.0
    before = len(fleet.out)
    fleet.take(fleet.executor.rebind(rebind, fleet.now))
    for what, uid in script:
        fleet.step(what, uid)
    for a in fleet.out:
        if isinstance(a, SendStartTask):
            started_on.setdefault(a.node_uuid, []).append(a.unit)
    assert started_on == units
    moved_away = [a for a in fleet.out[before:] if isinstance(a, SendSignal)]
    # The old unit is told $abort for the task it may still fly; nobody else is signalled.
    assert {(a.unit, a.signal) for a in moved_away} <= {("dji1", "$abort")}
    assert not [n for n, _ in fleet.signalled if n in untouched]
    assert fleet.last("R") is final
    assert fleet.history["a"] == [S.ACTIVE, S.RUNNING, S.SUCCEEDED]


def test_the_old_units_late_messages_about_a_moved_task_are_ignored() -> None:
    fleet = Fleet.of(conc_ab(), "dji0", "dji1", "dji2")
    old = fleet.task_of["b"]
    fleet.now = 1.0
    fleet.take(fleet.executor.rebind({"b": "/dji2"}, fleet.now))
    new = fleet.task_of["b"]
    assert new != old
    # The old unit comes back and says it finished (or failed) the old task: not this node's.
    assert fleet.executor.on_feedback(old, "finished", 2.0) == []
    assert fleet.executor.on_feedback(old, "failed", 2.0) == []
    assert fleet.last("b") is S.RUNNING
    fleet.step("finished", "b")
    fleet.step("finished", "a")
    assert fleet.last("b") is S.SUCCEEDED and fleet.last("R") is S.SUCCEEDED


def test_an_unanswered_abort_to_the_old_unit_changes_nothing_when_given_up() -> None:
    fleet = Fleet.of(conc_ab(), "dji0", "dji1", "dji2", max_attempts=2, resend_after=1.0)
    fleet.answer_signals = False
    fleet.take(fleet.executor.rebind({"b": "/dji2"}, 1.0))
    for t in (3.0, 5.0, 7.0):
        fleet.take(fleet.executor.tick(t))
    assert fleet.last("b") is S.RUNNING and fleet.reasons["b"] == ""
    assert [s for n, s in fleet.signalled if n == "b"] == ["$abort", "$abort"]


PROBLEMS = [
    ({"zz": "/dji2"}, "no executing node"),
    ({"S": "/dji2"}, "not a task node"),
    ({"a": "dji2"}, "is not a unit"),
    ({"a": "/"}, "is not a unit"),
    ({"b": "/dji2", "a": "/dji0/x"}, "is not a unit"),
]


@pytest.mark.parametrize(("rebind", "why"), PROBLEMS)
def test_a_rebinding_that_cannot_be_done_is_refused_whole(rebind, why) -> None:
    fleet = Fleet.of(conc_seq(), "dji0", "dji1", "dji2")
    before = dict(fleet.history)
    with pytest.raises(InputError, match=why):
        fleet.executor.rebind(rebind, 1.0)
    assert fleet.history == before
    assert fleet.executor.trees["R"].nodes["b"].unit == "dji1"  # type: ignore[attr-defined]


def test_a_task_that_ended_cannot_be_rebound() -> None:
    fleet = Fleet.of(conc_ab(), "dji0", "dji1", "dji2")
    fleet.step("finished", "a")
    with pytest.raises(InputError, match=r"already ended \(succeeded\)"):
        fleet.executor.rebind({"a": "/dji2"}, 3.0)


def test_rebind_tst_nodes_on_the_engines_tst_command() -> None:
    c = engine("dji0", "dji1", "dji2")
    send(c, start_tst(ctl("conc", "R", task("a", "/dji0"), task("b", "/dji1"))))
    out = send(c, {"com-uuid": "c2", "command": "rebind-tst-nodes", "sender": "test",
                   "execunits": {"b": "/dji2"}}, now=2.0)
    assert on(out, f"{c.base}/tst/response")[0]["response"] == "ok"
    to_dji2 = on(out, "test/unit/air/real/dji2/exec/command")
    assert [m["command"] for m in to_dji2] == ["start-task"]
    assert to_dji2[0]["execution-unit"].endswith("dji2")
    assert on(out, f"{DJI0}/exec/command") == []  # the healthy unit hears nothing
    refused = send(c, {"com-uuid": "c3", "command": "rebind-tst-nodes", "sender": "test",
                       "execunits": {"R": "/dji2"}}, now=3.0)
    answer = on(refused, f"{c.base}/tst/response")[0]
    assert answer["response"] == "failed" and "not a task node" in answer["fail-reason"]
