"""The service's use of the engine (pure): what the engine's feedback and answers mean for the
missions and the callers, and cancels.

Feedback moves the mission book on, is relayed to the operator (in the tree the operator sent:
control nodes the sent tree regrouped are derived from their children), times the learner's
tasks, and a task failing on its unit is re-delegated within its retry budget before the
engine's root ``failed`` could end the mission. An answer to a command sent for a caller moves
the mission on and then answers the caller; an accepted ``$abort`` of a ``cancel-mission`` waits
for the engine's confirmation (`delegation.service.cancels`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

from delegation.errors import InputError, InputProblem
from delegation.messages import (
    TERMINAL_NODE_STATUSES,
    UNIT_ABORTED,
    CancelMission,
    DelegationResponse,
    MissionStatus,
    QueryTst,
    SignalTstNode,
    SignalTstTree,
    SignalUnit,
    TstFeedback,
    TstResponse,
)
from delegation.runtime.commands import CommandKey
from delegation.runtime.core import Effects
from delegation.service.catch_up import CatchUp
from delegation.service.engine_link import INTERNAL, EngineAnswer
from delegation.service.missions import Mission
from delegation.service.planning import MissionPart
from delegation.service.redelegation import current_node, first_origin
from delegation.service.repair import Repair
from delegation.service.unit_catch_up import UnitCatchUp, UnitsSay

log = logging.getLogger(__name__)


@dataclass(slots=True)
class _Fanout:
    """One caller's signal sent as several (a regrouped control node): answers still awaited
    and the failures among those in."""

    waiting: int
    failures: list[str] = field(default_factory=list)


@dataclass(eq=False)
class EngineUse(MissionPart):
    """The engine's feedback and answers, applied; ``cancel-mission`` sent to it."""

    repair: Repair
    catch_up: CatchUp
    #: Asking the units when the engine cannot say how a tree stands.
    units: UnitCatchUp
    #: Callers' signals sent as several, by the caller's command key.
    fanout: dict[CommandKey, _Fanout] = field(default_factory=dict)

    def signal(self, cmd: SignalTstNode | SignalTstTree | SignalUnit, key: CommandKey,
               now: float) -> Effects:
        """A signal on the TST face, forwarded to the engine if the caller may touch every
        mission it affects (answered when the engine answers)."""
        if isinstance(cmd, SignalUnit):
            unit = cmd.unit.strip("/")
            for mission in self.book:
                if not mission.ended and any(n.execunit.strip("/") == unit
                                             for n in mission.nodes.values()):
                    self.desk.authorise(cmd.command, mission, key)
            model = SignalUnit(unit=cmd.unit, signal=cmd.signal, sender=self.config.name)
            return Effects(publish=[self.engine.send("signal", key, "tst", model, now)])
        found = self.book.of_node(cmd.node_uuid)
        if found is None:
            raise InputError(InputProblem(
                cmd.command, "node-uuid",
                f"{cmd.node_uuid!r} is not a node of any mission of {self.config.name}"))
        self.desk.authorise(cmd.command, found, key)
        if found.redelegating:
            raise InputError(InputProblem(
                cmd.command, "node-uuid", f"mission {found.root_uuid} is being re-delegated: "
                "its new tree is not sent yet, signal again in a moment"))
        view = found.operator
        target = (None if view is not None and cmd.node_uuid in view.children
                  and not view.relayed(cmd.node_uuid)  # regrouped away: not in the tree sent
                  else current_node(found.origin, found.current_nodes, cmd.node_uuid))
        targets = [target] if target is not None else self._regrouped(found, cmd)
        if not targets:
            return self.desk.respond("tst", key, TstResponse(response="ok", response_to=key[1]))
        if len(targets) > 1:
            self.fanout[key] = _Fanout(len(targets))
        kind: type[SignalTstNode | SignalTstTree] = type(cmd) if target is not None \
            else SignalTstNode
        return Effects(publish=[
            self.engine.send("signal", key, "tst", kind(node_uuid=uid, signal=cmd.signal,
                                                        sender=self.config.name),
                             now, found.root_uuid)
            for uid in targets])

    def _regrouped(self, mission: Mission, cmd: SignalTstNode | SignalTstTree) -> list[str]:
        """A signal to an operator's control node that the tree running does not have (the
        sent tree regrouped it away; docs/protocol.md §4): the tasks under it it reaches, as
        nodes of the running tree. ``signal-tst-tree`` and ``$abort``: every task that has not
        ended; ``signal-tst-node`` ``$pause``/``$continue``/``$enough`` (the node alone: what has
        not started under it): the tasks that have not started."""
        operator = mission.operator
        uid = cmd.node_uuid
        if operator is None or uid not in operator.children:
            raise InputError(InputProblem(
                cmd.command, "node-uuid", f"{uid!r} ended before mission {mission.root_uuid} "
                "was re-delegated: it is not part of the tree running now"))
        leaves: list[str] = []
        stack = [uid]
        while stack:
            node = stack.pop()
            if node in operator.leaves:
                leaves.append(node)
            stack.extend(reversed(operator.children.get(node, [])))
        alone = isinstance(cmd, SignalTstNode) and cmd.signal != "$abort"
        out = []
        for leaf in leaves:
            now_uid = current_node(mission.origin, mission.current_nodes, leaf)
            if now_uid is None or mission.node_status.get(now_uid) in TERMINAL_NODE_STATUSES:
                continue
            if alone and now_uid in mission.node_started:
                continue
            out.append(now_uid)
        return out

    def receive(self, topic: str, payload: bytes, now: float) -> Effects:
        """One message from the engine: feedback (from where its tree was sent only), or the
        answer to a command sent to it."""
        got = self.engine.receive(topic, payload)
        if isinstance(got, TstFeedback):
            mission = self.book.of_node(got.node_uuid)
            bound = self.view.fleet.base_topic(self.config.engine)
            if mission is not None and not self.engine.sent_from(mission.root_uuid, topic, bound):
                log.warning("ignoring feedback on %s for %s: mission %s was sent to %s",
                            topic, got.node_uuid, mission.root_uuid,
                            self.engine.sent_to.get(mission.root_uuid, "no engine"))
                return Effects()
            return self.feedback(got, now)
        if isinstance(got, EngineAnswer):
            return self.answer(got, now)
        return Effects()

    def feedback(self, fb: TstFeedback, now: float, redelegate: bool = True) -> Effects:
        """Node statuses: the mission book moves on, the operator hears it (in the tree it
        sent), the learner times the task; a task failing on its unit is re-delegated (unless
        ``redelegate`` is False: its tree ended with it, as its units said, `UnitCatchUp`)."""
        # A task failing on its unit is re-delegated (within its retry budget) before the
        # engine's root ``failed`` that follows could end the mission.
        retry = self._failed_task(fb) if redelegate else None
        held = self.book.of_node(fb.node_uuid)
        lapsed = (self.repair.hold_ran_out(held, fb.node_uuid, fb.status, now)
                  if held is not None and fb.status == "failed" else None)
        mission, events = self.book.observe_feedback(
            fb.node_uuid, fb.status, fb.root_flag, fb.fail_reason, self.lifecycle.epoch(now)
        )
        if mission is None:
            return Effects()  # a tree someone else gave the engine
        self.view.task_feedback(fb, now)
        effects = self.relay(mission, fb)
        effects.extend(self.lifecycle.publish(events))
        if retry is not None:
            # Held by the engine (hold-failed): the task alone moves; else the engine already
            # ended the failed (or aborted) branch and the tree is replaced.
            effects.extend(self.repair.failed(mission, fb.node_uuid, retry[0], retry[1], now))
        if lapsed is not None:
            effects.extend(lapsed)
        return effects

    def relay(self, mission: Mission, fb: TstFeedback) -> Effects:
        """The operator hears a node's status in the tree they sent (docs/protocol.md §4, §11):
        under the uuid of the first tree's node it stands for (after a re-delegation replaced
        the tree), leaves and kept control nodes unchanged, regrouped control nodes derived.
        Nothing of a tree that was replaced (its abort is not news), and only tasks' own
        statuses while its replacement is planned (the failure that started it spreads up)."""
        effects = Effects()
        uid = fb.node_uuid
        if uid not in mission.current_nodes or (mission.redelegating and uid in mission.nodes
                                                 and not mission.nodes[uid].is_task):
            return effects
        first = first_origin(mission.origin, uid)
        operator = mission.operator
        relayed = operator is None or operator.relayed(first)
        if operator is not None and not relayed and not operator.tracked(first):
            return effects  # a node only the sent tree has
        if relayed:  # leaves and kept nodes: as the engine said (a shared search's part: not)
            effects.send(self.desk.topics.tst_feedback, TstFeedback(
                node_uuid=first, root_flag=first == mission.root_uuid, status=fb.status,
                fail_reason=fb.fail_reason))
        if operator is not None:
            # The operator's control nodes the sent tree regrouped away, and shared searches
            # whose parts' conc it regrouped away: derived from their children (docs/protocol.md
            # §8, DESIGN 3.11).
            for node, status in operator.changes(first, mission.operator_statuses()):
                effects.send(self.desk.topics.tst_feedback, TstFeedback(
                    node_uuid=node, root_flag=node == operator.root, status=status,
                    fail_reason=fb.fail_reason if status in ("failed", "aborted") else ""))
        return effects

    def _failed_task(self, fb: TstFeedback) -> tuple[str, str] | None:
        """(unit, why) when ``fb`` is a task of a running mission's current tree failing on its
        unit, or aborted by its unit unasked (docs/protocol.md §11), with retry budget left,
        else None. An ``$abort`` the operator (or the engine, stopping a failed branch) sent
        ends the task as asked: not re-delegated."""
        if fb.status != "failed" and not (fb.status == "aborted"
                                          and fb.fail_reason.endswith(UNIT_ABORTED)):
            return None
        mission = self.book.of_node(fb.node_uuid)
        if mission is None or mission.ended or mission.redelegating:
            return None
        info = mission.nodes.get(fb.node_uuid)
        if info is None or not info.is_task or fb.node_uuid not in mission.current_nodes:
            return None
        if mission.retries.get(first_origin(mission.origin, fb.node_uuid), 0) \
                >= self.config.max_retries:
            return None  # the budget is spent: the failure ends the mission as usual
        unit = info.execunit.strip("/")
        why = f"{info.path} ({info.name}) {fb.status} on /{unit}: {fb.fail_reason or fb.status}"
        return unit, why

    def answer(self, got: EngineAnswer, now: float) -> Effects:
        """The mission moves on (if it does), then the caller gets its answer."""
        req = got.request
        if req.kind == "query":
            return self._caught_up(req.root_uuid, got, now)
        if got.confirm:
            return self._confirm(got, now)
        effects = Effects()
        if got.mission_status is not None:
            effects.extend(self.lifecycle.set_status(req.root_uuid, got.mission_status, now,
                                                     got.fail_reason))
        if req.kind == "rebind":
            answer = got.answer
            return effects.extend(self.repair.rebind_answered(
                req.root_uuid, getattr(answer, "response", "") == "ok",
                getattr(answer, "fail_reason", "") or "no answer", now))
        if req.kind == "start" and got.holds:
            self.repair.holding.add(req.tree or req.root_uuid)  # §12.7: failed tasks held
        if got.response is not None:  # a confirmed start: what the tree did meanwhile
            effects.extend(self._caught_up(req.root_uuid, got, now))
        if got.abort:
            effects.extend(self.repair.abort_tree(req.tree, now))
        if got.answer is None:
            return effects
        if req.key[0] == INTERNAL:
            return effects  # the service's own command (re-delegation): nobody to answer
        fan = self.fanout.get(req.key)
        if fan is not None:  # one of several signals for one command: answered once, at the end
            fan.waiting -= 1
            if getattr(got.answer, "response", "") == "failed":
                fan.failures.append(getattr(got.answer, "fail_reason", "") or "failed")
            if fan.waiting > 0:
                return effects
            del self.fanout[req.key]
            if fan.failures:
                return effects.extend(self.desk.fail(req.face, req.key, req.key[1],
                                                     "; ".join(fan.failures)))
            return effects.extend(self.desk.respond(req.face, req.key, TstResponse(
                response="ok", response_to=req.key[1])))
        mission = self.book.find(req.root_uuid) if req.kind == "cancel" else None
        if mission is not None and not mission.ended \
                and getattr(got.answer, "response", "") == "ok":
            # Answered when the engine confirms (the root ends), or `pending` at the deadline.
            self.lifecycle.wait_cancel(req.root_uuid, req.key, now)
            return effects
        return effects.extend(self.desk.respond(req.face, req.key, got.answer))

    def _caught_up(self, root: str, got: EngineAnswer, now: float) -> Effects:
        """The engine's answer to ``query-tst`` (`CatchUp.answered`): missed feedback applied as
        if it had just arrived, or the tree sent again; no answer: asked again."""
        if got.response is None:
            self.catch_up.unanswered(root)
            return self._ask_units(root, now)
        missed, effects = self.catch_up.answered(root, got.response, now)
        if missed:
            log.info("mission %s: caught up on %d node status(es) missed", root, len(missed))
        for fb in missed:
            effects.extend(self.feedback(fb, now))
        if got.response.response not in ("ok", "unknown"):  # an engine without query-tst
            effects.extend(self._ask_units(root, now))
        return effects

    def _ask_units(self, root: str, now: float) -> Effects:
        """The engine cannot say how the mission's tree stands: its units are asked
        (`UnitCatchUp`)."""
        effects, said = self.units.ask(root, now)
        return effects.extend(self._units_said(said, now))

    def from_unit(self, unit: str, rest: str, topic: str, payload: bytes, now: float
                  ) -> Effects:
        """A unit's ``exec/command`` (a ``start-task`` of our engine: its task-uuid is kept) or
        ``exec/response`` (maybe the answer to our ``query-status``)."""
        if rest == "exec/command":
            self.units.start_seen(unit, topic, payload)
            return Effects()
        return self._units_said(self.units.answer_seen(unit, topic, payload), now)

    def units_expired(self, now: float) -> Effects:
        """Units that did not answer ``query-status`` in time: what the others said counts."""
        effects = Effects()
        for said in self.units.expire(now):
            effects.extend(self._units_said(said, now))
        return effects

    def _units_said(self, said: UnitsSay | None, now: float) -> Effects:
        """The units' answers applied as the feedback they would have been (a failed task ends
        its tree as the engine ended it: not re-delegated); a tree that ended badly while a
        unit still runs a task of it is ``$abort``ed on the engine."""
        mission = self.book.find(said.root) if said is not None else None
        if said is None or mission is None or mission.ended:
            return Effects()
        tree = mission.current_root
        effects = Effects()
        for fb in said.feedback:
            effects.extend(self.feedback(fb, now, redelegate=False))
        if said.abort:
            effects.extend(self.repair.abort_tree(tree, now))
        return effects

    def _confirm(self, got: EngineAnswer, now: float) -> Effects:
        """A ``start-tst`` went unanswered: ask the engine whether it runs the tree before the
        mission is judged (``confirm``); with no engine to ask, it fails as before."""
        req = got.request
        query = QueryTst(node_uuid=req.tree, sender=self.config.name)
        try:
            out = self.engine.send("confirm", req.key, req.face, query, now, req.root_uuid,
                                   req.plan, tree=req.tree)
        except InputError as exc:
            why = (f"engine {self.config.engine} did not answer within "
                   f"{self.config.engine_timeout:g} s ({exc.fail_reason})")
            effects = self.lifecycle.set_status(req.root_uuid, MissionStatus.FAILED, now, why)
            if req.key[0] == INTERNAL:
                return effects
            return effects.extend(self.desk.fail(req.face, req.key, req.caller_com_uuid, why))
        log.info("mission %s: no answer to start-tst from %s: asking whether it runs tree %s",
                 req.root_uuid, self.config.engine, req.tree)
        return Effects(publish=[out])

    def cancel(self, cmd: CancelMission, key: CommandKey, now: float) -> Effects:
        """``cancel-mission``: aborted at once when no engine runs its tree, else the engine
        is asked to ``$abort`` it (answered when it confirms, or ``pending``)."""
        mission = self.desk.authorise(cmd.command, self.book.get(cmd.root_uuid), key)
        if mission.ended:
            raise InputError(InputProblem("cancel-mission", "root-uuid",
                                          f"mission {cmd.root_uuid} already ended "
                                          f"({mission.status.value})"))
        if mission.status is MissionStatus.PLANNED and not self.engine.starting(mission.root_uuid):
            out = self.desk.respond("delegation", key,
                                    DelegationResponse(response="ok", response_to=key[1]))
            return out.extend(self.lifecycle.set_status(
                mission.root_uuid, MissionStatus.ABORTED, now, "cancelled before it started"))
        problem = self.engine.problem(now)
        if problem or mission.redelegating:
            # Nothing to wait for: no engine runs the tree (or its replacement is not sent yet).
            why = f"cancelled ({problem})" if problem else "cancelled while re-delegating"
            out = self.desk.respond("delegation", key,
                                    DelegationResponse(response="ok", response_to=key[1]))
            out.extend(self.repair.forget(mission.root_uuid, now))  # its old tree may run
            return out.extend(self.lifecycle.set_status(
                mission.root_uuid, MissionStatus.ABORTED, now, why))
        model = SignalTstTree(node_uuid=mission.current_root, signal="$abort",
                              sender=self.config.name)
        return Effects(publish=[self.engine.send("cancel", key, "delegation", model, now,
                                                 mission.root_uuid)])
