"""A failed task held for a rebind (issue 22 item 3, docs/protocol.md §12.7): in a tree started
with ``hold-failed``, a task that fails (or that its unit aborts unasked) is reported at once but
its branch is not stopped: a ``rebind-tst-nodes`` of it within the bound runs it on another unit
and nothing else is touched; without one, the branch fails as without the option. Pure: the
executor driven by `Fleet` (units that answer at once)."""

from __future__ import annotations

import itertools
from typing import Any

from delegation.engine.executor import EngineOptions, SendSignal, SendStartTask, TreeExecutor
from delegation.messages import UNIT_ABORTED
from delegation.messages import NodeStatus as S
from delegation.tst.node import parse_tree
from test_engine_core import ctl, engine, on, send, start_tst, task
from test_engine_signals import Fleet

HOLD = 10.0


def holding(tree: dict[str, Any], hold: float = HOLD) -> Fleet:
    counter = itertools.count()
    ex = TreeExecutor(EngineOptions(), new_uuid=lambda: f"u{next(counter)}")
    for u in ("dji0", "dji1", "dji2"):
        ex.unit_seen(u, 0.0)
    fleet = Fleet(ex)
    _, actions = ex.start_tree(parse_tree(tree), 0.0, hold_failed=hold)
    fleet.take(actions)
    return fleet


def conc_ab() -> dict[str, Any]:
    return ctl("conc", "R", task("a", "/dji0"), task("b", "/dji1"))


def starts(fleet: Fleet, since: int = 0) -> list[tuple[str, str]]:
    return [(a.node_uuid, a.unit) for a in fleet.out[since:] if isinstance(a, SendStartTask)]


def signals(fleet: Fleet, since: int = 0) -> list[tuple[str, str]]:
    return [(a.unit, str(a.signal)) for a in fleet.out[since:] if isinstance(a, SendSignal)]


def test_a_failed_task_is_reported_held_and_moved_by_a_rebind_nothing_else_touched() -> None:
    fleet = holding(conc_ab())
    fleet.step("failed", "b")
    assert fleet.last("b") is S.FAILED  # reported at once
    assert fleet.last("R") is S.RUNNING  # its branch goes on
    assert fleet.executor.tree_status("R")[2] == {  # type: ignore[index]
        "node-uuid": "b", "status": "failed", "fail-reason": "/dji1 reported failed"}
    before = len(fleet.out)
    fleet.now += 1.0
    fleet.take(fleet.executor.rebind({"b": "/dji2"}, fleet.now))
    assert starts(fleet, before) == [("b", "dji2")]
    assert signals(fleet, before) == []  # the old unit ended the task itself: no $abort
    assert fleet.last("b") is S.RUNNING
    fleet.step("finished", "b")
    fleet.step("finished", "a")
    assert fleet.last("R") is S.SUCCEEDED
    assert not [n for n, _ in fleet.signalled if n == "a"]  # the healthy task never signalled
    # The hold's time passing later changes nothing.
    fleet.take(fleet.executor.tick(HOLD + 50.0))
    assert fleet.last("R") is S.SUCCEEDED


def test_without_a_rebind_within_the_bound_the_branch_fails_as_without_the_option() -> None:
    fleet = holding(conc_ab())
    fleet.step("failed", "b")  # at t = 1
    fleet.take(fleet.executor.tick(1.0 + HOLD - 0.1))
    assert fleet.last("R") is S.RUNNING and not [n for n, _ in fleet.signalled if n == "a"]
    fleet.now = 1.0 + HOLD
    fleet.take(fleet.executor.tick(fleet.now))
    assert ("a", "$abort") in fleet.signalled  # the conc fails: its running task is stopped
    assert fleet.last("R") is S.FAILED
    assert "/dji1 reported failed" in fleet.reasons["R"]


def test_a_held_task_in_a_seq_holds_what_follows_until_it_is_moved() -> None:
    fleet = holding(ctl("seq", "R", task("a", "/dji0"), task("b", "/dji1")))
    fleet.step("failed", "a")
    assert starts(fleet) == [("a", "dji0")]  # b waits: a has not succeeded
    fleet.now += 1.0
    fleet.take(fleet.executor.rebind({"a": "/dji2"}, fleet.now))
    fleet.step("finished", "a")
    assert starts(fleet)[-1] == ("b", "dji1")
    fleet.step("finished", "b")
    assert fleet.last("R") is S.SUCCEEDED


def test_a_task_its_unit_aborts_unasked_is_held_too() -> None:
    fleet = holding(conc_ab())
    fleet.step("aborted", "b")
    assert fleet.last("b") is S.ABORTED and fleet.reasons["b"] == f"/dji1 {UNIT_ABORTED}"
    assert fleet.last("R") is S.RUNNING
    fleet.take(fleet.executor.rebind({"b": "/dji0"}, 2.0))  # waits for a on dji0
    assert fleet.last("b") is S.WAITING


def test_late_messages_about_the_held_task_change_nothing_and_an_abort_ends_it() -> None:
    fleet = holding(conc_ab())
    fleet.step("failed", "b")
    old = fleet.task_of["b"]
    assert fleet.executor.on_feedback(old, "finished", 3.0) == []
    assert [a.unit for a in fleet.executor.query()] == ["dji0"]  # nothing asked of dji1
    fleet.take(fleet.executor.signal_tree("R", "$abort", 4.0))  # the operator ends it all
    fleet.step("aborted", "a")
    assert fleet.last("R") in (S.FAILED, S.ABORTED)


def test_a_tree_without_the_option_fails_its_branch_at_once() -> None:
    fleet = holding(conc_ab(), hold=0.0)
    fleet.step("failed", "b")
    assert ("a", "$abort") in fleet.signalled


def test_the_engine_says_it_holds_in_its_started_answer() -> None:
    c = engine("dji0", "dji1")
    out = send(c, {**start_tst(conc_ab()), "hold-failed": 20})
    [answer] = on(out, f"{c.base}/tst/response")
    assert answer["response"] == "started" and answer["hold-failed"] == 20
    plain = send(c, start_tst(ctl("conc", "Q", task("q", "/dji0")), com_uuid="c9"))
    [answer] = on(plain, f"{c.base}/tst/response")
    assert "hold-failed" not in answer
