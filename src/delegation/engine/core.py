"""The reference TST engine's core: the seed's TST Execution API (section 14), pure.

`EngineCore` reads ``tst/command`` (``start-tst`` for fully instantiated trees,
``signal-tst-node``, ``signal-tst-tree``, ``signal-unit``, ``ping``, and our ``query-tst``:
docs/protocol.md §12.5), every unit's heartbeat (to
learn base topics) and ``exec/response``/``exec/feedback``; it returns ``tst/response``,
``tst/feedback`` for every node status change, and ``start-task``/``signal-task`` to the units'
``exec/command``. Its status is a ``heartbeat`` (levels ``["tst execution"]``) and a
``tst_execution_info``. A command re-sent with the same com-uuid gets the same answer again and is
never run twice (`CommandLog`). The tree logic itself is `TreeExecutor`'s; `TstEngine` puts this
core on a broker.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable

from delegation.engine.delegated import Delegated
from delegation.engine.executor import (
    Action,
    EngineOptions,
    NodeChanged,
    SendQuery,
    SendSignal,
    SendStartTask,
    TreeExecutor,
)
from delegation.engine.tree import Tree
from delegation.errors import InputError, InputProblem
from delegation.messages import (
    ExecFeedback,
    ExecResponse,
    MessageError,
    NodeStatus,
    Ping,
    QueryStatus,
    QueryTst,
    RebindTstNodes,
    SignalTask,
    SignalTstNode,
    SignalTstTree,
    SignalUnit,
    StartTask,
    StartTst,
    TaskSpecMsg,
    TstExecutionInfo,
    TstFeedback,
    TstResponse,
    WireModel,
    decode,
)
from delegation.messages.errors import json_value
from delegation.runtime.commands import CommandKey, CommandLog, com_uuid_of
from delegation.runtime.core import Effects, Identified, Identity, Outgoing, heartbeat
from delegation.topics import QOS_COMMAND, QOS_PERIODIC, parse_unit_topic, unit_filter
from delegation.tst.node import ExecUnitKind, TstNode, classify_execunit, parse_tree, walk, where

log = logging.getLogger(__name__)

__all__ = ["LEVELS", "EngineCore"]

#: The engine's heartbeat levels.
LEVELS: tuple[str, ...] = ("tst execution",)
#: A tree's final statuses worth a log line (a root is never revoked).
ENDED = frozenset({NodeStatus.SUCCEEDED, NodeStatus.FAILED, NodeStatus.ABORTED})
#: The face commands arrive on (the `CommandLog` key's first part).
FACE = "tst"


class EngineCore(Identified):
    """The TST engine's every decision: commands, unit messages and time in, `Effects` out."""

    def __init__(
        self,
        identity: Identity,
        options: EngineOptions | None = None,
        *,
        new_uuid: Callable[[], str] | None = None,
        answers_query_tst: bool = True,
    ) -> None:
        self.identity = identity
        self.answers_query_tst = answers_query_tst
        """False (tests only): ``query-tst`` gets no answer at all, as from an engine without
        our extension that stays silent (the public op0 as issue 22 describes it), so that the
        service's catch-up from the units themselves is exercised with a real engine."""
        self.executor = TreeExecutor(options, new_uuid=new_uuid)
        #: Subtrees handed to other TST executors (delegators), docs/protocol.md §15.3.
        self.delegated = Delegated(identity.name)
        self.commands = CommandLog()
        self.bases: dict[str, str] = {}
        """Unit name -> base topic, from the unit's heartbeat (where its exec/command goes).

        Bound at the first heartbeat (docs/security.md): the same name from another base topic is an
        impostor's, logged once per topic and ignored, as are its exec answers."""
        self._impostors: set[tuple[str, str]] = set()
        self._command_topic = identity.topic("tst/command")
        self.heard: dict[str, float] = {}
        self.agent_uuids: dict[str, str] = {}
        """Unit name -> the agent-uuid of its last heartbeat (a new one: it rebooted)."""
        """Unit name -> when its last heartbeat arrived (``now``)."""
        self._reconnected_at: float | None = None
        self.catch_up_gap = 3.0
        """A unit heard again after this long a silence is asked ``query-status``."""

    # ---- the Core protocol (``name``, ``status_period``: `Identified`)

    def subscriptions(self) -> list[str]:
        prefix = self.identity.prefix
        return [
            self._command_topic,
            unit_filter(prefix, "heartbeat"),
            unit_filter(prefix, "exec/response"),
            unit_filter(prefix, "exec/feedback"),
            unit_filter(prefix, "tst/response"),
            unit_filter(prefix, "tst/feedback"),
        ]

    def on_message(self, topic: str, payload: bytes, now: float) -> Effects:
        if topic == self._command_topic:
            return self._command(topic, payload, now)
        parsed = parse_unit_topic(topic)
        if parsed is None:
            return Effects()
        if parsed.rest in ("tst/response", "tst/feedback"):
            return self._from_executor(parsed.name, parsed.base, parsed.rest, payload, now)
        if parsed.rest not in ("heartbeat", "exec/response", "exec/feedback"):
            return Effects()
        bound = (
            self.bases.setdefault(parsed.name, parsed.base)
            if parsed.rest == "heartbeat"
            else self.bases.get(parsed.name)
        )
        if bound != parsed.base:
            self._impostor(parsed.name, parsed.base, bound)
            return Effects()
        if parsed.rest == "heartbeat":
            self.delegated.heard(parsed.name, payload, now)
            actions = self.executor.unit_seen(parsed.name, now)
            if self._rebooted(parsed.name, topic, payload):
                actions += self.executor.unit_rebooted(parsed.name, now)
            elif self._missed(parsed.name, now):
                log.info("%s: /%s is back: asking for its tasks' status", self.name, parsed.name)
                actions += self.executor.query(parsed.name)
            self.heard[parsed.name] = now
            return self._carry_out(actions)
        return self._from_unit(topic, payload, now)

    def _impostor(self, name: str, base: str, bound: str | None) -> None:
        """A message for ``name`` from a base topic it is not bound to: logged once, ignored."""
        if (name, base) in self._impostors:
            return
        if len(self._impostors) < 1024:
            self._impostors.add((name, base))
        if bound is None:
            log.warning("%s: ignoring %s: no heartbeat of %s yet", self.name, base, name)
        else:
            log.warning("%s: ignoring %s: %s is bound to %s", self.name, base, name, bound)

    def _rebooted(self, unit: str, topic: str, payload: bytes) -> bool:
        """True when ``unit``'s heartbeat carries another ``agent-uuid`` than before: the seed's
        sign that it rebooted and lost its history of commands (12.1)."""
        try:  # the agent-uuid alone: 14 us a heartbeat, where a full decode takes ~90 us
            beat = json_value(payload, topic)
        except MessageError as exc:
            log.debug("%s: unreadable heartbeat of /%s: %s", self.name, unit, exc)
            return False
        agent_uuid = beat.get("agent-uuid") if isinstance(beat, dict) else None
        if not isinstance(agent_uuid, str) or not agent_uuid or len(agent_uuid) > 128:
            return False
        before = self.agent_uuids.get(unit)
        self.agent_uuids[unit] = agent_uuid
        if before is None or before == agent_uuid:
            return False
        log.warning("%s: /%s rebooted (agent-uuid %s, was %s): its tasks are gone",
                    self.name, unit, agent_uuid, before)
        return True

    def _missed(self, unit: str, now: float) -> bool:
        """True when messages from ``unit`` may have been lost: its heartbeat comes back after a
        gap, or for the first time since this engine reconnected to the broker."""
        last = self.heard.get(unit)
        if last is None:
            return False
        if self._reconnected_at is not None and last < self._reconnected_at:
            return True
        return now - last > self.catch_up_gap

    def on_reconnect(self, now: float) -> Effects:
        """Back on the broker after an outage: ask every unit about the tasks it runs for us (and
        again each unit when its heartbeat is first heard, in case it was not back yet)."""
        self._reconnected_at = now
        return self._carry_out(self.executor.query())

    def on_tick(self, now: float) -> Effects:
        """Re-sends, busy retries and timeouts (see `TreeExecutor.tick`)."""
        return self._carry_out(self.executor.tick(now))

    def status(self, now: float, stamp: float) -> list[Outgoing]:
        info = TstExecutionInfo(
            name=self.identity.name,
            rate=self.identity.rate,
            stamp=stamp,
            trees_executing=self.executor.executing(),
        )
        return [
            heartbeat(self.identity, LEVELS, stamp),
            Outgoing.of(self.identity.topic("tst_execution_info"), info, QOS_PERIODIC),
        ]

    # ---- views (tests, `TstEngine.wait_for_units`)

    @property
    def trees(self) -> dict[str, Tree]:
        """The trees executing or recently finished, by root uuid."""
        return self.executor.trees

    def knows(self, names: Iterable[str]) -> bool:
        """Whether a heartbeat of every unit in ``names`` has arrived (their tasks can start)."""
        return {n.strip("/") for n in names} <= set(self.bases)

    # ---- tst/command

    def _command(self, topic: str, payload: bytes, now: float) -> Effects:
        com_uuid = com_uuid_of(payload)
        key: CommandKey | None = (FACE, com_uuid) if com_uuid else None
        if key is not None:
            again = self.commands.answer_again(key)
            if again is not None:
                return Effects.of(again)
            self.commands.begin(key, now)
        try:
            command = decode(topic, payload)
        except MessageError as exc:
            log.warning("%s: bad command: %s", self.name, exc)
            if key is None:
                return Effects()
            return self._answer(key, key[1], "failed", fail_reason=exc.fail_reason)
        try:
            return self._dispatch(command, key, now)
        except InputError as exc:
            answer_to = getattr(command, "com_uuid", "")
            return self._answer(key, answer_to, "failed", fail_reason=exc.fail_reason)

    def _dispatch(self, command: WireModel, key: CommandKey | None, now: float) -> Effects:
        """Run one decoded command: its answer first, then what it set going."""
        if isinstance(command, Ping):
            return self._answer(key, command.com_uuid, "pong")
        if isinstance(command, QueryTst):
            if not self.answers_query_tst:
                log.debug("%s: query-tst %s left unanswered (answers_query_tst off)", self.name,
                          command.com_uuid)
                return Effects()
            nodes = self.executor.tree_status(command.node_uuid)
            if nodes is None:
                why = f"no tree {command.node_uuid} is known to {self.name}"
                return self._answer(key, command.com_uuid, "unknown", fail_reason=why)
            return self._answer(key, command.com_uuid, "ok", root_uuid=command.node_uuid,
                                nodes=nodes)
        if isinstance(command, StartTst):
            tree = parse_tree(command.tst)
            self._refuse_own_tasks(tree)
            hold = float(command.hold_failed or 0.0)
            root_uuid, actions = self.executor.start_tree(self.delegated.fold(tree, now), now,
                                                          run=command.com_uuid,
                                                          resume=bool(command.resume),
                                                          hold_failed=hold)
            log.info("%s: executing tree %s", self.name, root_uuid)
            answer = self._answer(key, command.com_uuid, "started", root_uuid=root_uuid,
                                  hold_failed=hold or None)
            return answer.extend(self._carry_out(actions))
        if isinstance(command, SignalTstNode):
            actions = self.executor.signal_node(command.node_uuid, command.signal, now)
        elif isinstance(command, SignalTstTree):
            actions = self.executor.signal_tree(command.node_uuid, command.signal, now)
        elif isinstance(command, SignalUnit):
            actions = self.executor.signal_unit(command.unit, command.signal, now)
        elif isinstance(command, RebindTstNodes):
            subtrees = {uid: parse_tree(raw) for uid, raw in (command.subtrees or {}).items()}
            actions = self.executor.rebind(command.execunits, now, subtrees)
        else:  # a tst command this engine does not implement (decode knows every tst command)
            name = getattr(command, "command", type(command).__name__)
            reason = f"{name} is not supported by the TST engine"
            return self._answer(key, getattr(command, "com_uuid", ""), "failed", reason)
        return self._answer(key, command.com_uuid, "ok").extend(self._carry_out(actions))

    def _refuse_own_tasks(self, root: TstNode) -> None:
        """``InputError`` naming every task node whose execunit is this engine: the engine
        executes trees, not tasks, and a start-task to itself would go unanswered until it
        failed (the seed's single-task start-tst examples name ``/op0``, the engine's name)."""
        problems = [
            InputProblem(where(path, node), f"{node.common_key}.execunit",
                         f"/{self.name} is this TST engine, which runs no tasks: name the unit "
                         f"that is to run {node.name} (e.g. /dji0)")
            for path, node in walk(root)
            if not node.is_control
            and _fixed_unit(node.execunit) == self.name
        ]
        if problems:
            raise InputError(problems)

    def _answer(
        self,
        key: CommandKey | None,
        com_uuid: str,
        response: str,
        fail_reason: str = "",
        root_uuid: str | None = None,
        nodes: list[dict[str, str]] | None = None,
        hold_failed: float | None = None,
    ) -> Effects:
        """The ``tst/response``, remembered for re-sends of the command."""
        answer = TstResponse(fail_reason=fail_reason, response=response, response_to=com_uuid,
                             root_uuid=root_uuid, nodes=list(nodes) if nodes else None,
                             hold_failed=hold_failed)
        out = Outgoing.of(self.identity.topic("tst/response"), answer, QOS_COMMAND)
        if key is not None:
            self.commands.finish(key, [out])
        return Effects.of([out])

    # ---- from the units

    def _from_unit(self, topic: str, payload: bytes, now: float) -> Effects:
        """A unit's ``exec/response`` or ``exec/feedback``, handed to the executor."""
        try:
            msg = decode(topic, payload)
        except MessageError as exc:
            log.debug("%s: unreadable message on %s: %s", self.name, topic, exc)
            return Effects()
        if isinstance(msg, ExecResponse):
            actions = self.executor.on_response(
                msg.response_to,
                msg.response,
                now,
                fail_reason=msg.fail_reason,
                task_uuid=msg.task_uuid,
            )
        elif isinstance(msg, ExecFeedback):
            actions = self.executor.on_feedback(msg.task_uuid, msg.status, now)
        else:
            return Effects()
        return self._carry_out(actions)

    # ---- actions to messages

    def _carry_out(self, actions: list[Action]) -> Effects:
        effects = Effects()
        for action in actions:
            if isinstance(action, NodeChanged):
                effects.send(self.identity.topic("tst/feedback"), self._feedback(action))
                continue
            base = self.bases.get(action.unit)
            if base is None:  # the executor starts tasks only on units it has seen
                log.error("%s: no base topic for /%s", self.name, action.unit)
                continue
            if self.delegated.handles(action):  # a subtree to a delegator: its tst/command
                assert not isinstance(action, SendQuery)
                effects.send(f"{base}/tst/command", self.delegated.command(action, self.name))
            elif not (isinstance(action, SendQuery) and action.unit in self.delegated.executors):
                effects.send(f"{base}/exec/command", self._to_unit(action))
        return effects

    def _from_executor(self, unit: str, base: str, rest: str, payload: bytes,
                       now: float) -> Effects:
        """A delegator's ``tst/response`` or ``tst/feedback`` about a subtree we handed it."""
        if not self.delegated.outstanding or unit == self.name or \
                unit not in self.delegated.executors or self.bases.get(unit) != base:
            return Effects()  # (every service's relayed feedback arrives here too: not read)
        try:
            msg = decode(f"{base}/{rest}", payload)
        except MessageError as exc:
            log.debug("%s: unreadable message from /%s: %s", self.name, unit, exc)
            return Effects()
        if isinstance(msg, TstResponse):
            com, response, reason = self.delegated.response(msg)
            return self._carry_out(self.executor.on_response(com, response, now,
                                                             fail_reason=reason))
        if not isinstance(msg, TstFeedback):
            return Effects()
        got = self.delegated.feedback(unit, msg)
        if isinstance(got, TstFeedback):  # a node inside the subtree: relayed unchanged
            return Effects().send(self.identity.topic("tst/feedback"), got)
        if got is None:
            return Effects()
        if msg.status in ("succeeded", "failed", "aborted"):
            self.delegated.forget(msg.node_uuid)
        return self._carry_out(self.executor.on_feedback(*got, now))

    def _to_unit(
        self, action: SendStartTask | SendSignal | SendQuery
    ) -> StartTask | SignalTask | QueryStatus:
        if isinstance(action, SendQuery):
            return QueryStatus(com_uuid=action.com_uuid, sender=self.name,
                               task_uuid=action.task_uuid)
        if isinstance(action, SendStartTask):
            return StartTask(
                com_uuid=action.com_uuid,
                execution_unit=action.unit,  # "dji0", as every seed example (no slash)
                sender=self.name,
                task=TaskSpecMsg(name=action.name, params=action.params),
                task_uuid=action.task_uuid,
            )
        return SignalTask(com_uuid=action.com_uuid, signal=str(action.signal), sender=self.name,
                          task_uuid=action.task_uuid)

    def _feedback(self, change: NodeChanged) -> TstFeedback:
        if change.root_flag and change.status in ENDED:
            log.info("%s: tree %s %s", self.name, change.root_uuid, change.status.value)
        return TstFeedback(
            fail_reason=change.fail_reason,
            node_uuid=change.node_uuid,
            root_flag=change.root_flag,
            status=change.status.value,
        )


def _fixed_unit(execunit: object) -> str | None:
    """The unit a node's execunit names (``/dji0`` -> ``dji0``), None for an alias or free."""
    try:
        kind, name = classify_execunit(execunit)
    except TypeError:
        return None
    return name if kind is ExecUnitKind.FIXED else None
