"""Catching up from the units themselves (pure; DESIGN 3.13, docs/protocol.md §11).

`CatchUp` asks the engine how a tree stands (``query-tst``, ours). An engine without that
extension (the public op0) does not answer it, and then a mission whose tasks ended while the
service was away would never be brought up to date: nothing the engine publishes later says so.
The seed gives another means: every unit answers ``query-status`` for a task it was given (seed
12.1: ``running``, ``failed``, ``success``, ``unknown``). To ask, the service needs each task's
``task-uuid``, which only the engine and the unit know; so the service watches the units'
``exec/command`` for the ``start-task`` its engine sends (name and params identify the task node
on that unit) and keeps the pair with the mission (`Mission.node_tasks`, stored, so that it
survives a ``kill -9``).

When the engine leaves a ``query-tst`` unanswered (or refuses it), each unit that ran a task of
the mission that had not ended is asked; the answers are taken as the task feedback they would
have been, and the tree's outcome is derived as the engine derives it (§12.3, `decide`): every
task succeeded -> succeeded; a failed (or, ``unknown``, lost) task -> failed naming it. What the
units cannot tell (a task started while the service was away, whose ``task-uuid`` it never saw; a
unit that does not answer) leaves the outcome open: the mission then goes on with the engine's
feedback, and is asked about again while the engine stays silent (``catch_up_attempts``).
"""

from __future__ import annotations

import logging
from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field
from typing import Any

from delegation.errors import MessageError
from delegation.messages import (
    TERMINAL_NODE_STATUSES,
    ExecResponse,
    QueryStatus,
    StartTask,
    TaskSpecMsg,
    TstFeedback,
    decode,
)
from delegation.runtime.core import Effects, Outgoing
from delegation.service.missions import Mission, MissionBook
from delegation.service.planning import MissionPart
from delegation.tst.node import CONTROL_NODES, TstNode, parse_tree, stored_nodes, walk

log = logging.getLogger(__name__)

#: A unit's answer to ``query-status`` as its task node's status: the seed's words (12.1), and
#: the feedback words older units answer with; None: the task is still on (running or paused).
ANSWER_STATUS: dict[str, str | None] = {
    "success": "succeeded",
    "finished": "succeeded",
    "enough": "succeeded",
    "failed": "failed",
    "aborted": "aborted",
    "unknown": "failed",  # the unit lost the task (rebooted, or never got it): not done
    "running": None,
    "paused": None,
    "starting": None,
}

#: Task statuses after which a task has nothing more to say.
_DONE_OK = frozenset({"succeeded", "revoked"})

#: A tree's task nodes by (unit, task name): [(node uuid, params)] in tree order (`tasks_by_unit`).
TaskIndex = dict[tuple[str, str], list[tuple[str, dict[str, Any]]]]


def decide(tree: TstNode, tasks: Mapping[str, tuple[str, str]]
           ) -> dict[str, tuple[str, str]]:
    """The control nodes of ``tree`` whose end the tasks' final statuses (``tasks``: task node
    uuid -> (status, fail-reason); a task not in it has not ended, or nobody knows) decide, as
    the engine would end them (docs/protocol.md §12.3): a ``seq`` fails (or is aborted) at its
    first child that did, succeeds when every child succeeded or was revoked; a ``conc`` fails
    when a child failed, else ends once every child ended (aborted when one was). Uuid ->
    (status, fail-reason), children before parents; an undecided node is absent."""
    ended: dict[str, tuple[str, str]] = dict(tasks)
    nodes = list(walk(tree))
    paths = {id(node): path for path, node in nodes}
    for _, node in reversed(nodes):  # children before parents
        if not node.is_control:
            continue
        children = [(paths[id(c)], c, ended.get(c.node_uuid or "")) for c in node.children]
        verdict = _seq(children) if node.name != "conc" else _conc(children)
        if verdict is not None:
            ended[node.node_uuid or ""] = verdict
    return {uid: v for uid, v in ended.items() if uid not in tasks}


def _why(path: str, node: TstNode, status: str, reason: str) -> str:
    return f"{path} ({node.name}) {status}: {reason or status}"


def _seq(children: list[tuple[str, TstNode, tuple[str, str] | None]]
         ) -> tuple[str, str] | None:
    for path, child, end in children:
        if end is None:
            return None
        if end[0] not in _DONE_OK:
            return end[0], _why(path, child, *end)
    return "succeeded", ""


def _conc(children: list[tuple[str, TstNode, tuple[str, str] | None]]
          ) -> tuple[str, str] | None:
    failed = [(p, c, e) for p, c, e in children if e is not None and e[0] == "failed"]
    if failed:
        path, child, end = failed[0]
        return "failed", _why(path, child, *end)
    if any(end is None for _, _, end in children):
        return None
    aborted = [(p, c, e) for p, c, e in children if e is not None and e[0] not in _DONE_OK]
    if aborted:
        path, child, end = aborted[0]
        return end[0], _why(path, child, *end)
    return "succeeded", ""


def tasks_by_unit(tst: dict[str, Any]) -> TaskIndex:
    """(unit, task name) -> [(node uuid, params)] of every task node of a tree, in tree order:
    what a ``start-task`` on that unit is matched against. The tree is one the service built
    and sent (valid): it is walked as JSON, not parsed again."""
    out: TaskIndex = {}
    for raw, common in stored_nodes(tst):
        name, uid = raw.get("name"), common.get("node-uuid")
        if name not in CONTROL_NODES and isinstance(name, str) and isinstance(uid, str) and uid:
            unit = str(common.get("execunit") or "").strip("/")
            out.setdefault((unit, name), []).append((uid, dict(raw.get("params") or {})))
    return out


def frozen(value: Any) -> Hashable:
    """A hashable stand-in for a JSON value, equal to another's exactly when the values are
    equal (``==``): objects as their sorted items, arrays as tuples (each marked, so that
    ``{}`` and ``[]`` differ); numbers, strings, booleans and null as they are (their hashes
    agree with ``==``)."""
    if isinstance(value, dict):
        return ("{", tuple(sorted((k, frozen(v)) for k, v in value.items())))
    if isinstance(value, list):
        return ("[", tuple(frozen(v) for v in value))
    return value  # type: ignore[no-any-return]


#: What a ``start-task`` is looked up by: (unit, task name, `frozen` params).
TaskKey = tuple[str, str, Hashable]


def task_of(mission: Mission, index: Mapping[tuple[str, str], list[tuple[str, dict[str, Any]]]],
            unit: str, cmd: StartTask) -> str | None:
    """The task node of ``mission`` (its tree indexed by `tasks_by_unit`) that ``cmd``, a
    ``start-task`` seen on ``unit``, starts: the same name and params on that unit. Of identical
    tasks on one unit, the one that already has this task-uuid (a re-send), else the first that
    has none, else (the engine tried one again with new ids) the first that has not ended."""
    candidates = [uid for uid, params in index.get((unit, cmd.task.name), ())
                  if params == cmd.task.params and uid in mission.current_nodes]
    for uid in candidates:
        if mission.node_tasks.get(uid, ("", ""))[1] == cmd.task_uuid:
            return uid
    for uid in candidates:
        if uid not in mission.node_tasks:
            return uid
    for uid in candidates:
        if mission.node_status.get(uid) not in TERMINAL_NODE_STATUSES:
            return uid
    return None


@dataclass(frozen=True, slots=True)
class _Asked:
    """One ``query-status`` out, waiting for its unit's answer."""

    root: str
    node: str
    unit: str
    deadline: float


@dataclass(slots=True)
class _Round:
    """One mission's units being asked: the queries out, and the answers so far."""

    waiting: set[str] = field(default_factory=set)
    #: Task node uuid -> (status, fail-reason) from its unit's answer (final statuses only).
    ended: dict[str, tuple[str, str]] = field(default_factory=dict)
    #: Tasks their unit says are still on.
    running: set[str] = field(default_factory=set)


@dataclass(frozen=True, slots=True)
class UnitsSay:
    """What a mission's units said, as the engine's feedback would have said it: tasks' and
    decided control nodes' statuses, children before parents, the root last (it ends the
    mission); ``abort``: the tree ended badly while a unit still runs a task of it."""

    root: str
    feedback: tuple[TstFeedback, ...]
    abort: bool = False


@dataclass(eq=False)
class UnitCatchUp(MissionPart):
    """The ``start-task``s seen, the ``query-status``es out, and what the answers decide."""

    #: Query com-uuid -> what it asked.
    asked: dict[str, _Asked] = field(default_factory=dict)
    #: Root uuid -> the round of queries of that mission under way.
    rounds: dict[str, _Round] = field(default_factory=dict)
    #: Root uuid -> (the tree indexed, `tasks_by_unit` of it, its tasks' `TaskKey`s): made
    #: again when the tree changes.
    _index: dict[str, tuple[dict[str, Any], TaskIndex, frozenset[TaskKey]]] = field(
        default_factory=dict)
    #: (unit, task name, params) -> the open missions whose running tree has such a task, so
    #: that a ``start-task`` is matched against those alone (usually one).
    _by_task: dict[TaskKey, dict[str, None]] = field(default_factory=dict)
    #: The book and its `MissionBook.revision` when the index was last brought in step.
    _synced: tuple[MissionBook | None, int] = (None, -1)

    def _tasks(self, mission: Mission) -> TaskIndex:
        """The mission's running tree indexed (made again, and `_by_task` with it, when the
        tree was replaced)."""
        cached = self._index.get(mission.root_uuid)
        if cached is not None and cached[0] is mission.current_tst:
            return cached[1]
        self._drop(mission.root_uuid)
        index = tasks_by_unit(mission.current_tst)
        keys = frozenset((unit, name, frozen(params))
                         for (unit, name), tasks in index.items() for _, params in tasks)
        self._index[mission.root_uuid] = (mission.current_tst, index, keys)
        for key in keys:
            self._by_task.setdefault(key, {})[mission.root_uuid] = None
        return index

    def _drop(self, root: str) -> None:
        """Forget a mission's index (it ended, left memory, or its tree is indexed again)."""
        cached = self._index.pop(root, None)
        for key in cached[2] if cached is not None else ():
            roots = self._by_task.get(key)
            if roots is not None:
                roots.pop(root, None)
                if not roots:
                    del self._by_task[key]

    def _sync(self) -> None:
        """Index the missions changed since the last call (added, a tree replaced, ended); those
        that left memory are dropped when met (`_candidates`)."""
        book = self.book
        last_book, last = self._synced
        if last_book is not book:
            self._index.clear()
            self._by_task.clear()
            last = -1
        elif last == book.revision:
            return
        self._synced = (book, book.revision)
        for root in book.changed_since(last):
            mission = book.in_memory(root)
            if mission is None or mission.ended:
                self._drop(root)
            else:
                self._tasks(mission)

    def _candidates(self, unit: str, task: TaskSpecMsg) -> list[Mission]:
        """The open missions in memory whose running tree has ``task`` (its name and params)
        on ``unit``, in the book's order."""
        self._sync()
        out = []
        for root in list(self._by_task.get((unit, task.name, frozen(task.params)), ())):
            mission = self.book.in_memory(root)
            if mission is None or mission.ended:
                self._drop(root)
            else:
                out.append(mission)
        out.sort(key=lambda m: self.book.order.get(m.root_uuid, 0))  # the book's order
        return out

    def start_seen(self, unit: str, topic: str, payload: bytes) -> None:
        """A message on ``unit``'s ``exec/command``: a ``start-task`` from our engine for a task
        of an open mission is remembered with the mission (stored)."""
        if b"start-task" not in payload:  # signals, queries, pings: not read
            return
        try:
            cmd = decode(topic, payload)
        except MessageError:
            return
        if not isinstance(cmd, StartTask) or not cmd.task_uuid \
                or cmd.sender.strip("/") != self.config.engine:
            return
        for mission in self._candidates(unit, cmd.task):
            if mission.redelegating:
                continue
            uid = task_of(mission, self._tasks(mission), unit, cmd)
            if uid is None:
                continue
            if mission.node_tasks.get(uid) != (unit, cmd.task_uuid):
                mission.node_tasks[uid] = (unit, cmd.task_uuid)
                self.book.touch(mission.root_uuid)
            return

    def ask(self, root: str, now: float) -> tuple[Effects, UnitsSay | None]:
        """``query-status`` to the unit of each task of the mission that had not ended (one
        round at a time); what the book alone already decides when there is nobody to ask."""
        mission = self.book.find(root)
        if mission is None or mission.ended or mission.redelegating or root in self.rounds:
            return Effects(), None
        effects = Effects()
        round_ = _Round()
        for uid in sorted(mission.current_nodes):
            info = mission.nodes.get(uid)
            if info is None or not info.is_task \
                    or mission.node_status.get(uid) in TERMINAL_NODE_STATUSES:
                continue
            unit, task_uuid = mission.node_tasks.get(uid, ("", ""))
            base = self.view.fleet.base_topic(unit) if unit else None
            if base is None:
                continue  # never seen started (or its unit never heard): nobody to ask
            query = QueryStatus(task_uuid=task_uuid, sender=self.config.name)
            self.asked[query.com_uuid] = _Asked(root, uid, unit, now + self.config.catch_up_timeout)
            round_.waiting.add(query.com_uuid)
            effects.publish.append(Outgoing.of(f"{base}/exec/command", query))
        if not round_.waiting:
            return effects, self._judge(mission, round_)
        self.rounds[root] = round_
        log.info("mission %s: engine %s cannot say how tree %s stands: %d unit task(s) asked "
                 "query-status", root, self.config.engine, mission.current_root,
                 len(round_.waiting))
        return effects, None

    def answer_seen(self, unit: str, topic: str, payload: bytes) -> UnitsSay | None:
        """A message on ``unit``'s ``exec/response``: the answer to one of our queries (from the
        unit asked only) counts; the round's verdict once every query is answered or expired."""
        if not self.asked:  # every answer to everyone else's commands: not read
            return None
        try:
            msg = decode(topic, payload)
        except MessageError:
            return None
        if not isinstance(msg, ExecResponse):
            return None
        asked = self.asked.get(msg.response_to)
        if asked is None or asked.unit != unit:
            return None
        del self.asked[msg.response_to]
        round_ = self.rounds.get(asked.root)
        if round_ is None:
            return None
        round_.waiting.discard(msg.response_to)
        word = msg.response.strip().lower()
        status = ANSWER_STATUS.get(word)
        if status is not None:
            why = {"unknown": f"/{unit} no longer knows the task (its answer to query-status)",
                   "failed": msg.fail_reason or f"/{unit} said failed to query-status"}.get(
                       word, msg.fail_reason)
            round_.ended[asked.node] = (status, why)
        elif word in ANSWER_STATUS:
            round_.running.add(asked.node)
        else:
            log.warning("mission %s: /%s answered query-status %r: not a status", asked.root,
                        unit, msg.response)
        return self._done(asked.root, round_)

    def expire(self, now: float) -> list[UnitsSay]:
        """Queries their unit did not answer in time (the public example agent never does):
        their tasks stay undecided; rounds that are complete then give their verdict."""
        late = [com for com, asked in self.asked.items() if now >= asked.deadline]
        roots: set[str] = set()
        for com in late:
            asked = self.asked.pop(com)
            round_ = self.rounds.get(asked.root)
            if round_ is not None:
                round_.waiting.discard(com)
                roots.add(asked.root)
                log.info("mission %s: /%s did not answer query-status within %g s", asked.root,
                         asked.unit, self.config.catch_up_timeout)
        out = []
        for root in sorted(roots):
            said = self._done(root, self.rounds[root])
            if said is not None:
                out.append(said)
        return out

    def _done(self, root: str, round_: _Round) -> UnitsSay | None:
        if round_.waiting:
            return None
        del self.rounds[root]
        mission = self.book.find(root)
        if mission is None or mission.ended or mission.redelegating:
            return None
        return self._judge(mission, round_)

    def _judge(self, mission: Mission, round_: _Round) -> UnitsSay | None:
        """The feedback the units' answers amount to: every task's new final status, and, when
        the tasks decide it, the tree's end (`decide`); None when they tell nothing new."""
        tasks: dict[str, tuple[str, str]] = {}
        for uid in mission.current_nodes:
            info = mission.nodes.get(uid)
            status = mission.node_status.get(uid)
            if info is not None and info.is_task and status in TERMINAL_NODE_STATUSES:
                tasks[uid] = (status, "")
        news = {uid: end for uid, end in round_.ended.items() if uid not in tasks}
        tasks.update(news)
        decided = decide(parse_tree(mission.current_tst), tasks)
        root = mission.current_root
        feedback = [TstFeedback(node_uuid=uid, status=s, fail_reason=why, root_flag=False)
                    for uid, (s, why) in news.items()]
        feedback += [TstFeedback(node_uuid=uid, status=s, fail_reason=why, root_flag=uid == root)
                     for uid, (s, why) in decided.items()
                     if mission.node_status.get(uid) != s and uid != root]
        end = decided.get(root)
        if end is not None:
            feedback.append(TstFeedback(node_uuid=root, status=end[0], fail_reason=end[1],
                                        root_flag=True))
            log.info("mission %s: its units' answers end tree %s %s", mission.root_uuid, root,
                     end[0])
        elif news or round_.running:
            log.info("mission %s: its units' answers leave tree %s open (%d task(s) ended, %d "
                     "still on): the engine's feedback goes on", mission.root_uuid, root,
                     len(news), len(round_.running))
        if not feedback:
            return None
        abort = end is not None and end[0] != "succeeded" and bool(round_.running)
        return UnitsSay(mission.root_uuid, tuple(feedback), abort)
