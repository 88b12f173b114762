"""Signals to executing trees at the engine's core (issue 20, docs/protocol.md §12): order kept
when a node that has not started is signalled, ``$enough`` never reports what did not run as
succeeded, aborting one node does not abort the whole tree, signal-tasks and start-tasks re-sent
with the same com-uuid until answered or given up, and trees as deep and wide as the limits allow.

Table-driven: each case is a tree, a script (signals from the operator, task ends from the
units) and what must follow. `Fleet` plays well-behaved units at the executor's level: every
start-task is accepted, every signal-task answered ``ok`` and acted on (``$abort`` -> aborted,
``$enough`` -> finished, ``$pause`` -> paused, ``$continue`` -> running)."""

from __future__ import annotations

import itertools
import json
import re
from dataclasses import dataclass, field
from typing import Any

import pytest

from delegation.engine import EngineOptions, NodeChanged, SendSignal, SendStartTask, TreeExecutor
from delegation.engine.executor import Action
from delegation.errors import InputError
from delegation.fleet import make_unit
from delegation.geo import GeoPoint
from delegation.messages import ExecResponse, encode
from delegation.messages import NodeStatus as S
from delegation.sim import SimUnitCore
from delegation.tst.node import MAX_DEPTH, MAX_NODES, TstNode, make_node, parse_tree
from test_engine_core import DJI0, ctl, engine, on, send, start_tst, task

START = GeoPoint(latitude=57.7605, longitude=16.6815, altitude=40.0)
UNIT_FEEDBACK = {"$abort": "aborted", "$enough": "finished", "$pause": "paused",
                 "$continue": "running"}


@dataclass
class Fleet:
    """A `TreeExecutor` driven by units that answer everything at once (unless told not to)."""

    executor: TreeExecutor
    now: float = 0.0
    answer_starts: bool = True
    answer_signals: bool = True
    history: dict[str, list[S]] = field(default_factory=dict)
    started: list[str] = field(default_factory=list)
    signalled: list[tuple[str, str]] = field(default_factory=list)
    task_of: dict[str, str] = field(default_factory=dict)  # node uuid -> task-uuid
    node_of: dict[str, str] = field(default_factory=dict)  # task-uuid -> node uuid
    reasons: dict[str, str] = field(default_factory=dict)
    out: list[Action] = field(default_factory=list)

    @classmethod
    def of(cls, tree: dict[str, Any] | TstNode, *units: str, answer_starts: bool = True,
           answer_signals: bool = True, **options: Any) -> Fleet:
        counter = itertools.count()
        ex = TreeExecutor(EngineOptions(**options), new_uuid=lambda: f"u{next(counter)}")
        for u in units or ("dji0", "dji1", "dji2", "dji3"):
            ex.unit_seen(u, 0.0)
        fleet = cls(ex, answer_starts=answer_starts, answer_signals=answer_signals)
        root = tree if isinstance(tree, TstNode) else parse_tree(tree)
        _, actions = ex.start_tree(root, 0.0)
        fleet.take(actions)
        return fleet

    def take(self, actions: list[Action]) -> None:
        """Record what the executor did; answer it as a unit would (depth first, in order)."""
        pending = list(actions)
        while pending:
            a = pending.pop(0)
            self.out.append(a)
            if isinstance(a, NodeChanged):
                self.history.setdefault(a.node_uuid, []).append(a.status)
                self.reasons[a.node_uuid] = a.fail_reason
            elif isinstance(a, SendStartTask):
                self.check_order(a.node_uuid)
                self.started.append(a.node_uuid)
                self.task_of[a.node_uuid] = a.task_uuid
                self.node_of[a.task_uuid] = a.node_uuid
                if self.answer_starts:
                    pending += self.executor.on_response(
                        a.com_uuid, "running", self.now, task_uuid=a.task_uuid)
            elif isinstance(a, SendSignal):
                self.signalled.append((self.node_of[a.task_uuid], a.signal))
                if self.answer_signals:
                    pending += self.executor.on_response(getattr(a, "com_uuid", ""), "ok", self.now)
                    if a.signal in UNIT_FEEDBACK:  # task-specific signals change no status
                        pending += self.executor.on_feedback(
                            a.task_uuid, UNIT_FEEDBACK[a.signal], self.now)

    def check_order(self, uid: str) -> None:
        """A task starts only when every earlier child of each ``seq`` above it has ended."""
        tree = self.executor.trees[self.executor._node_tree[uid]]
        node = tree.nodes[uid]
        parent = tree.parent(node)
        while parent is not None:
            if parent.is_seq:
                for sibling in parent.children[: parent.children.index(node.uuid)]:
                    assert tree.nodes[sibling].terminal, f"{uid} started before {sibling} ended"
            node, parent = parent, tree.parent(parent)

    def step(self, what: str, uid: str, arg: str = "") -> None:
        self.now += 1.0
        ex = self.executor
        if what == "node":
            self.take(ex.signal_node(uid, arg, self.now))
        elif what == "tree":
            self.take(ex.signal_tree(uid, arg, self.now))
        elif what == "unit":
            self.take(ex.signal_unit(uid, arg, self.now))
        elif what == "started":  # a check in the script: the tasks started so far
            assert self.started == uid.split(","), f"at step {self.now:g}"
        else:  # the unit reports the task ended: finished, failed, aborted
            self.take(ex.on_feedback(self.task_of[uid], what, self.now))

    def last(self, uid: str) -> S | None:
        return self.history.get(uid, [None])[-1]


def seq_abc() -> dict[str, Any]:
    return ctl("seq", "R", task("a", "/dji0"), task("b", "/dji1"), task("c", "/dji2"))


def nested() -> dict[str, Any]:
    inner = ctl("seq", "S", task("x", "/dji1"), task("y", "/dji2"))
    return ctl("seq", "R", task("a", "/dji0"), inner, task("c", "/dji3"))


# --------------------------------------------------------------------------- item 1: seq order

#: (name, tree, script, starts in order, histories of some nodes, the root's last status)
ORDER_CASES: list[tuple[str, Any, list[tuple[str, ...]], list[str], dict[str, list[S]], S]] = [
    (
        "enough to a queued task skips it",
        seq_abc,
        [("node", "b", "$enough"), ("finished", "a"), ("finished", "c")],
        ["a", "c"],
        {"b": [S.REVOKED], "c": [S.ACTIVE, S.RUNNING, S.SUCCEEDED]},
        S.SUCCEEDED,
    ),
    (
        "pause then continue of a queued task does not start it out of order",
        seq_abc,
        [("node", "b", "$pause"), ("node", "b", "$continue"), ("started", "a"),
         ("finished", "a"), ("finished", "b"), ("finished", "c")],
        ["a", "b", "c"],
        {"b": [S.ACTIVE, S.RUNNING, S.SUCCEEDED]},
        S.SUCCEEDED,
    ),
    (
        "pause of a queued task is applied when its turn comes",
        seq_abc,
        [("node", "b", "$pause"), ("finished", "a"), ("started", "a"),
         ("node", "b", "$continue"), ("finished", "b"), ("finished", "c")],
        ["a", "b", "c"],
        {"b": [S.PAUSED, S.ACTIVE, S.RUNNING, S.SUCCEEDED]},
        S.SUCCEEDED,
    ),
    (
        "enough to a queued nested seq revokes it and never starts its children",
        nested,
        [("node", "S", "$enough"), ("finished", "a"), ("finished", "c")],
        ["a", "c"],
        {"S": [S.REVOKED], "x": [S.REVOKED], "y": [S.REVOKED]},
        S.SUCCEEDED,
    ),
    (
        "enough to a queued nested seq, by signal-tst-tree",
        nested,
        [("tree", "S", "$enough"), ("finished", "a"), ("finished", "c")],
        ["a", "c"],
        {"S": [S.REVOKED], "x": [S.REVOKED], "y": [S.REVOKED]},
        S.SUCCEEDED,
    ),
    (
        "abort of a queued task: the running one ends first, then the seq is aborted",
        seq_abc,
        [("node", "b", "$abort"), ("finished", "a")],
        ["a"],
        {"a": [S.ACTIVE, S.RUNNING, S.SUCCEEDED], "b": [S.ABORTED], "c": [S.REVOKED]},
        S.ABORTED,
    ),
    (
        "pause of a queued nested seq holds its children when its turn comes",
        nested,
        [("node", "S", "$pause"), ("finished", "a"), ("started", "a"), ("node", "S", "$continue"),
         ("finished", "x"), ("finished", "y"), ("finished", "c")],
        ["a", "x", "y", "c"],
        {"S": [S.PAUSED, S.RUNNING, S.SUCCEEDED], "x": [S.PAUSED, S.ACTIVE, S.RUNNING,
                                                       S.SUCCEEDED]},
        S.SUCCEEDED,
    ),
]


@pytest.mark.parametrize(
    ("tree", "script", "starts", "histories", "final"),
    [case[1:] for case in ORDER_CASES],
    ids=[case[0] for case in ORDER_CASES],
)
def test_a_signal_to_a_node_that_has_not_started_keeps_the_seq_order(
    tree, script, starts, histories, final
) -> None:
    run = Fleet.of(tree())
    for step in script:
        run.step(*step)
    assert run.started == starts
    for uid, history in histories.items():
        assert run.history.get(uid) == history, uid
    assert run.last("R") is final
    assert run.executor.executing() == []


# --------------------------------------------------------------------------- item 4: $enough


def conc_of_seqs() -> dict[str, Any]:
    left = ctl("seq", "L", task("a", "/dji0"), task("a2", "/dji0"))
    return ctl("conc", "R", left, task("d", "/dji1"))


#: (name, tree, script, nodes signalled $enough, nodes revoked, the root's last status)
ENOUGH_CASES: list[tuple[str, Any, list[tuple[str, ...]], list[str], set[str], S]] = [
    ("tree enough on a seq: the running task is told, the queued are revoked",
     seq_abc, [("tree", "R", "$enough")], ["a"], {"b", "c"}, S.SUCCEEDED),
    ("node enough on a seq: the running task runs to its end, the queued are revoked",
     seq_abc, [("node", "R", "$enough"), ("finished", "a")], [], {"b", "c"}, S.SUCCEEDED),
    ("tree enough on a conc of a seq and a task",
     conc_of_seqs, [("tree", "R", "$enough")], ["a", "d"], {"a2"}, S.SUCCEEDED),
    ("tree enough on a conc: a task waiting for its busy unit is revoked",
     lambda: ctl("conc", "R", task("a", "/dji0"), task("b", "/dji0")),
     [("tree", "R", "$enough")], ["a"], {"b"}, S.SUCCEEDED),
    ("node enough on a conc: a task waiting for its busy unit is revoked",
     lambda: ctl("conc", "R", task("a", "/dji0"), task("b", "/dji0")),
     [("node", "R", "$enough"), ("finished", "a")], [], {"b"}, S.SUCCEEDED),
    ("enough on an inner seq: the conc goes on and succeeds",
     conc_of_seqs, [("tree", "L", "$enough"), ("finished", "d")], ["a"], {"a2"}, S.SUCCEEDED),
]


@pytest.mark.parametrize(
    ("tree", "script", "told", "revoked", "final"),
    [case[1:] for case in ENOUGH_CASES],
    ids=[case[0] for case in ENOUGH_CASES],
)
def test_enough_on_a_control_node_never_reports_queued_tasks_succeeded(
    tree, script, told, revoked, final
) -> None:
    run = Fleet.of(tree())
    for step in script:
        run.step(*step)
    assert [uid for uid, sig in run.signalled if sig == "$enough"] == told
    assert {uid for uid, h in run.history.items() if h[-1] is S.REVOKED} == revoked
    for uid in revoked:
        assert S.SUCCEEDED not in run.history[uid] and uid not in run.started
    assert run.last("R") is final
    assert run.executor.executing() == []


# --------------------------------------------------------------------------- item 5: one abort


def two_branches() -> dict[str, Any]:
    left = ctl("seq", "L", task("a", "/dji0"), task("a2", "/dji0"))
    return ctl("conc", "R", left, task("b", "/dji1"))


#: (name, tree, script, nodes sent $abort, last statuses, the root's last status)
ABORT_CASES: list[tuple[str, Any, list[tuple[str, ...]], list[str], dict[str, S], S]] = [
    ("signal-tst-node $abort on one task: its seq aborts, the other branch runs on",
     two_branches, [("node", "a", "$abort"), ("finished", "b")], ["a"],
     {"a": S.ABORTED, "a2": S.REVOKED, "L": S.ABORTED, "b": S.SUCCEEDED}, S.ABORTED),
    ("signal-unit $abort: only that unit's task",
     two_branches, [("unit", "/dji0", "$abort"), ("finished", "b")], ["a"],
     {"a": S.ABORTED, "a2": S.REVOKED, "L": S.ABORTED, "b": S.SUCCEEDED}, S.ABORTED),
    ("the unit aborts its own task",
     two_branches, [("aborted", "a"), ("finished", "b")], [],
     {"a": S.ABORTED, "a2": S.REVOKED, "L": S.ABORTED, "b": S.SUCCEEDED}, S.ABORTED),
    ("signal-tst-node $abort on an inner seq",
     two_branches, [("node", "L", "$abort"), ("finished", "b")], ["a"],
     {"a": S.ABORTED, "a2": S.REVOKED, "L": S.ABORTED, "b": S.SUCCEEDED}, S.ABORTED),
    ("signal-tst-tree $abort on the root aborts everything",
     two_branches, [("tree", "R", "$abort")], ["a", "b"],
     {"a": S.ABORTED, "a2": S.REVOKED, "L": S.ABORTED, "b": S.ABORTED}, S.ABORTED),
    ("a failed task still fails its conc and stops the other branch",
     two_branches, [("failed", "a")], ["b"],
     {"a": S.FAILED, "a2": S.REVOKED, "L": S.FAILED, "b": S.ABORTED}, S.FAILED),
]


@pytest.mark.parametrize(
    ("tree", "script", "aborted", "last", "final"),
    [case[1:] for case in ABORT_CASES],
    ids=[case[0] for case in ABORT_CASES],
)
def test_aborting_one_node_does_not_abort_the_whole_tree(
    tree, script, aborted, last, final
) -> None:
    run = Fleet.of(tree())
    for step in script:
        run.step(*step)
    assert [uid for uid, sig in run.signalled if sig == "$abort"] == aborted
    assert {uid: run.last(uid) for uid in last} == last
    assert run.last("R") is final
    if final is S.ABORTED and "tree" not in script[0][0]:
        assert "children[0]" in run.reasons["R"]  # the branch that was aborted
    assert run.executor.executing() == []


#: signal-tst-node differs from signal-tst-tree on a control node.
NODE_VS_TREE: list[tuple[str, str, list[tuple[str, str]], S]] = [
    ("node", "$pause", [], S.PAUSED),
    ("tree", "$pause", [("a", "$pause"), ("b", "$pause")], S.PAUSED),
    ("node", "$enough", [], S.RUNNING),
    ("tree", "$enough", [("a", "$enough"), ("b", "$enough")], S.SUCCEEDED),
]


@pytest.mark.parametrize(("face", "signal", "told", "root"), NODE_VS_TREE)
def test_signal_tst_node_is_the_node_alone_and_signal_tst_tree_every_node(
    face, signal, told, root
) -> None:
    run = Fleet.of(two_branches())
    run.step(face, "R", signal)
    assert run.signalled == told
    assert run.last("R") is root


# --------------------------------------------------------------------------- item 3: re-sends


def quiet(tree: dict[str, Any], **options: Any) -> Fleet:
    """Units that accept the start-tasks but answer no signal-task."""
    return Fleet.of(tree, answer_signals=False, resend_after=2.0, max_attempts=3, **options)


def signal_sends(run: Fleet) -> list[tuple[str, str]]:
    return [(a.signal, a.com_uuid) for a in run.out if isinstance(a, SendSignal)]


@pytest.mark.parametrize(("signal", "status"), [("$pause", S.RUNNING), ("$abort", S.ABORTED)])
def test_an_unanswered_signal_is_resent_with_the_same_com_uuid_then_given_up(
    signal: str, status: S
) -> None:
    run = quiet(ctl("seq", "R", task("a")))
    run.take(run.executor.signal_node("a", signal, 1.0))
    run.take(run.executor.tick(2.0))
    run.take(run.executor.tick(3.0))
    run.take(run.executor.tick(5.0))
    sends = signal_sends(run)
    assert [s for s, _ in sends] == [signal] * 3 and len({c for _, c in sends}) == 1
    run.take(run.executor.tick(7.0))
    assert len(signal_sends(run)) == 3  # given up: no fourth send
    assert run.last("a") is status
    assert f"did not answer {signal} (3 attempts)" in run.reasons["a"]


def test_an_answered_signal_is_not_resent() -> None:
    run = quiet(ctl("seq", "R", task("a")))
    (sig,) = [a for a in run.executor.signal_node("a", "$pause", 1.0) if isinstance(a, SendSignal)]
    assert run.executor.on_response(sig.com_uuid, "ok", 1.5) == []
    assert run.executor.tick(9.0) == []


def test_an_abort_answered_but_never_confirmed_ends_aborted_after_the_timeout() -> None:
    run = quiet(ctl("seq", "R", task("a")), abort_timeout=15.0)
    (sig,) = [a for a in run.executor.signal_node("a", "$abort", 1.0) if isinstance(a, SendSignal)]
    run.executor.on_response(sig.com_uuid, "ok", 1.5)
    assert run.executor.tick(16.0) == []
    run.take(run.executor.tick(16.5))
    assert run.last("a") is S.ABORTED and "did not confirm $abort" in run.reasons["a"]


def test_a_given_up_start_task_is_followed_by_abort_to_the_unit() -> None:
    run = Fleet.of(ctl("seq", "R", task("a")), answer_starts=False, answer_signals=False,
                   resend_after=2.0, max_attempts=2)
    ex = run.executor
    task_uuid = run.task_of["a"]
    run.take(ex.tick(2.0))  # the second send
    run.take(ex.tick(4.0))  # given up
    assert run.last("a") is S.FAILED and "did not answer start-task" in run.reasons["a"]
    assert "$abort sent" in run.reasons["a"]
    (abort,) = [a for a in run.out if isinstance(a, SendSignal)]
    assert (abort.unit, abort.task_uuid, abort.signal) == ("dji0", task_uuid, "$abort")
    run.take(ex.tick(6.0))
    resent = [a for a in run.out if isinstance(a, SendSignal)]
    assert resent == [abort, abort]  # re-sent, same com-uuid, until answered
    assert ex.on_response(abort.com_uuid, "ok", 6.5) == []
    assert ex.tick(9.0) == []


def test_signals_waiting_for_the_start_task_answer_are_all_delivered_in_order() -> None:
    counter = itertools.count()
    ex = TreeExecutor(EngineOptions(), new_uuid=lambda: f"u{next(counter)}")
    ex.unit_seen("dji0", 0.0)
    _, actions = ex.start_tree(parse_tree(ctl("seq", "R", task("a"))), 0.0)
    (start,) = [a for a in actions if isinstance(a, SendStartTask)]
    assert ex.signal_node("a", "$abort", 0.5) == []
    assert ex.signal_node("a", "$pause", 0.6) == []
    actions = ex.on_response(start.com_uuid, "running", 1.0, task_uuid=start.task_uuid)
    sent = [(a.task_uuid, a.signal) for a in actions if isinstance(a, SendSignal)]
    assert sent == [(start.task_uuid, "$abort"), (start.task_uuid, "$pause")]


def test_a_refused_signal_is_said_in_the_nodes_fail_reason() -> None:
    run = quiet(ctl("seq", "R", task("a")))
    (sig,) = [a for a in run.executor.signal_node("a", "$pause", 1.0) if isinstance(a, SendSignal)]
    run.take(run.executor.on_response(sig.com_uuid, "failed", 1.5, fail_reason="cannot pause"))
    assert run.last("a") is S.RUNNING and run.reasons["a"] == "/dji0 refused $pause: cannot pause"
    assert run.executor.tick(9.0) == []  # answered: not re-sent


def test_signals_waiting_for_a_unit_that_turns_out_busy_are_applied_by_the_engine() -> None:
    counter = itertools.count()
    ex = TreeExecutor(EngineOptions(), new_uuid=lambda: f"u{next(counter)}")
    ex.unit_seen("dji0", 0.0)
    _, actions = ex.start_tree(parse_tree(ctl("seq", "R", task("a"), task("b", "/dji1"))), 0.0)
    (start,) = [a for a in actions if isinstance(a, SendStartTask)]
    assert ex.signal_node("a", "$pause", 0.5) == []  # waits for the answer
    actions = ex.on_response(start.com_uuid, "failed", 1.0, fail_reason="A task is already running")
    assert [(a.node_uuid, a.status) for a in actions if isinstance(a, NodeChanged)] == [
        ("a", S.WAITING), ("a", S.PAUSED)]
    assert ex.tick(10.0) == []  # held: not asked again until $continue
    (again,) = [a for a in ex.signal_node("a", "$continue", 11.0) if isinstance(a, SendStartTask)]
    assert again.task_uuid != start.task_uuid


def test_the_core_sends_signal_tasks_with_their_com_uuid_and_resends_the_same_bytes() -> None:
    c = engine("dji0")
    (start,) = on(send(c, start_tst(ctl("seq", "R", task("a")))), f"{DJI0}/exec/command")
    accepted = ExecResponse(response="running", response_to=start["com-uuid"])
    c.on_message(f"{DJI0}/exec/response", encode(accepted), 1.5)
    signal = {"com-uuid": "s1", "command": "signal-tst-node", "node-uuid": "a", "sender": "t",
              "signal": "$pause"}
    first = [o for o in send(c, signal, 2.0).publish if o.topic == f"{DJI0}/exec/command"]
    again = [o for o in c.on_tick(4.5).publish if o.topic == f"{DJI0}/exec/command"]
    assert len(first) == 1 and again == first
    sent = json.loads(first[0].payload)
    assert (sent["command"], sent["signal"], sent["task-uuid"]) == (
        "signal-task", "$pause", start["task-uuid"])
    ok = ExecResponse(response="ok", response_to=sent["com-uuid"])
    c.on_message(f"{DJI0}/exec/response", encode(ok), 5.0)
    assert on(c.on_tick(9.0), f"{DJI0}/exec/command") == []


def test_a_unit_answers_a_resent_signal_task_again_and_never_runs_it_twice() -> None:
    unit = make_unit("dji0", "air", START, ["move-to"], speeds={"standard": 5.0})
    sim = SimUnitCore(unit, prefix="t")
    command = sim.identity.topic("exec/command")

    def send_unit(msg: dict[str, Any], now: float) -> list[Any]:
        return sim.on_message(command, json.dumps(msg).encode(), now).publish

    start = {"com-uuid": "s", "command": "start-task", "execution-unit": "dji0",
             "task": {"name": "move-to", "params": task("a")["params"]}, "task-uuid": "t1"}
    first = [o for o in send_unit(start, 0.0) if o.topic.endswith("exec/response")]
    assert send_unit(start, 0.5) == first  # the same answer, the task started once
    pause = {"com-uuid": "p", "command": "signal-task", "signal": "$pause", "task-uuid": "t1"}
    answer = [o for o in send_unit(pause, 1.0) if o.topic.endswith("exec/response")]
    send_unit({"com-uuid": "c", "command": "signal-task", "signal": "$continue",
               "task-uuid": "t1"}, 2.0)
    assert send_unit(pause, 3.0) == answer  # a late copy of $pause: answered, not applied again
    assert sim.vehicle.status_of("t1") == "running" and sim.commands_handled == 3


# --------------------------------------------------------------------------- task-specific signals


def conc_ab() -> dict[str, Any]:
    return ctl("conc", "R", task("a", "/dji0"), task("b", "/dji1"))


#: (name, tree, steps before, the signal (how, node, name), signalled, refused with)
TASK_SIGNALS: list[tuple[str, Any, list[tuple[str, ...]], tuple[str, str, str],
                         list[tuple[str, str]], str | None]] = [
    ("to a running task: sent to its unit as it is", seq_abc, [],
     ("node", "a", "zoom-in"), [("a", "zoom-in")], None),
    ("to a task not started: refused, nothing sent", seq_abc, [],
     ("node", "b", "zoom-in"), [], "'zoom-in': move-to b has not started"),
    ("to a control node alone: refused", conc_ab, [],
     ("node", "R", "zoom-in"), [], "is a control node (signal-tst-tree sends it"),
    ("signal-tst-tree: every running task under the node", conc_ab, [],
     ("tree", "R", "battery-is-charged"),
     [("a", "battery-is-charged"), ("b", "battery-is-charged")], None),
    ("signal-tst-tree: only the running ones", seq_abc, [],
     ("tree", "R", "zoom-in"), [("a", "zoom-in")], None),
    ("signal-tst-tree with nothing running under it: refused", nested, [],
     ("tree", "S", "zoom-in"), [], "'zoom-in': no running task under seq S"),
    ("to a tree that ended: nothing to do (answered ok)", seq_abc,
     [("finished", "a"), ("finished", "b"), ("finished", "c")],
     ("tree", "R", "zoom-in"), [], None),
    ("signal-unit: that unit's running tasks", conc_ab, [],
     ("unit", "dji1", "zoom-in"), [("b", "zoom-in")], None),
    ("an unknown $-signal is still refused", seq_abc, [],
     ("node", "a", "$zoom"), [], "'$zoom' is not one of $enough, $pause, $continue, $abort"),
    ("an empty name is refused", seq_abc, [], ("node", "a", ""), [], "is no signal name"),
    ("a padded name is refused", seq_abc, [], ("node", "a", " zoom"), [], "is no signal name"),
    ("a 200-character name is refused", seq_abc, [], ("node", "a", "z" * 200), [],
     "is no signal name"),
]


@pytest.mark.parametrize(("name", "tree", "before", "signal", "signalled", "refused"),
                         TASK_SIGNALS, ids=[c[0] for c in TASK_SIGNALS])
def test_task_specific_signals_on_the_tst_face(
        name: str, tree: Any, before: list[tuple[str, ...]], signal: tuple[str, str, str],
        signalled: list[tuple[str, str]], refused: str | None) -> None:
    """Seed 12.2.2: "Signal names starting with $ is system signals. Other names are specific
    for the task": forwarded to the running tasks they reach, never refused for their name."""
    run = Fleet.of(tree())
    for step in before:
        run.step(*step)
    statuses = {uid: run.last(uid) for uid in run.history}
    if refused is None:
        run.step(*signal)
    else:
        with pytest.raises(InputError, match=re.escape(refused)):
            run.step(*signal)
    assert [(u, str(s)) for u, s in run.signalled] == signalled
    assert {uid: run.last(uid) for uid in statuses} == statuses  # no status changed


def test_a_task_specific_signal_waits_for_the_start_and_is_resent_until_answered() -> None:
    run = Fleet.of(seq_abc(), answer_starts=False, answer_signals=False, resend_after=2.0,
                   max_attempts=3)
    (start,) = [a for a in run.out if isinstance(a, SendStartTask)]
    run.step("node", "a", "zoom-in")  # the start-task is not answered yet: held back
    assert run.signalled == []
    run.take(run.executor.on_response(start.com_uuid, "running", run.now,
                                      task_uuid=start.task_uuid))
    assert run.signalled == [("a", "zoom-in")]
    (sent,) = [a for a in run.out if isinstance(a, SendSignal)]
    resent = [a for a in run.executor.tick(run.now + 2.5) if isinstance(a, SendSignal)]
    assert resent == [sent]  # the same com-uuid
    run.executor.tick(run.now + 5.0)
    gave_up = run.executor.tick(run.now + 7.5)
    assert [(a.node_uuid, a.status, a.fail_reason) for a in gave_up
            if isinstance(a, NodeChanged)] == [
        ("a", S.RUNNING, "/dji0 did not answer zoom-in (3 attempts)")]


def test_the_core_forwards_a_task_specific_signal_to_the_unit() -> None:
    c = engine("dji0")
    (start,) = on(send(c, start_tst(ctl("seq", "R", task("a")))), f"{DJI0}/exec/command")
    c.on_message(f"{DJI0}/exec/response",
                 encode(ExecResponse(response="running", response_to=start["com-uuid"])), 1.5)
    signal = {"com-uuid": "s1", "command": "signal-tst-node", "node-uuid": "a", "sender": "t",
              "signal": "battery-is-charged"}
    effects = send(c, signal, 2.0)
    (answer,) = on(effects, f"{c.base}/tst/response")
    assert answer["response"] == "ok", answer
    (sent,) = on(effects, f"{DJI0}/exec/command")
    assert (sent["command"], sent["signal"], sent["task-uuid"]) == (
        "signal-task", "battery-is-charged", start["task-uuid"])


# --------------------------------------------------------------------------- depth and width


def test_a_seq_as_wide_as_the_limits_allow_runs_without_recursion() -> None:
    children = [ctl("seq", f"s{i}") for i in range(MAX_NODES - 2)] + [task("a")]
    run = Fleet.of(ctl("seq", "R", *children))
    assert run.started == ["a"]
    run.step("finished", "a")
    assert run.last("R") is S.SUCCEEDED and run.last("s0") is S.SUCCEEDED


def test_a_wide_conc_of_tasks_ends_when_the_last_ends() -> None:
    n = 3000
    units = [f"u{i}" for i in range(n)]
    tree = ctl("conc", "R", *[task(f"t{i}", f"/u{i}") for i in range(n)])
    run = Fleet.of(tree, *units)
    assert len(run.started) == n
    run.step("tree", "R", "$abort")
    assert run.last("R") is S.ABORTED
    assert {run.last(f"t{i}") for i in range(n)} == {S.ABORTED}


@pytest.mark.parametrize("depth", [MAX_DEPTH, 3000])
def test_a_deep_tree_runs_and_aborts_without_recursion(depth: int) -> None:
    # Deeper than the wire limit (MAX_DEPTH) is built directly: the executor has no limit of
    # its own.
    def chain() -> TstNode:
        node = make_node("seq", [make_node("move-to", execunit="/dji0", node_uuid="leaf",
                                           params=task("x")["params"]),
                                 make_node("move-to", execunit="/dji1", node_uuid="leaf2",
                                           params=task("x")["params"])],
                         execunit="/op0", node_uuid=f"n{depth}")
        for level in range(depth - 1, 0, -1):
            node = make_node("seq", [node], execunit="/op0", node_uuid=f"n{level}")
        return make_node("seq", [node], execunit="/op0", node_uuid="R")

    run = Fleet.of(chain())
    assert run.started == ["leaf"]
    run.step("finished", "leaf")
    assert run.started == ["leaf", "leaf2"]
    run.step("tree", "R", "$abort")
    assert run.last("leaf2") is S.ABORTED and run.last("R") is S.ABORTED
    assert run.last(f"n{depth}") is S.ABORTED
