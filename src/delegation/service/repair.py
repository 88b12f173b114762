"""Repair: a unit lost, rebooted or failing a task, or the engine gone (pure; docs/protocol.md
§11).

A unit lost (heartbeat stopped, or a new agent-uuid) or answering ``failed`` has its unfinished
tasks re-delegated: what remains of the mission is planned without it (a job), and the operator is
told which task moved where (`delegation.service.redelegation` computes the remaining tree).
A lost unit's tasks move within the running tree (``rebind-tst-nodes``): the other units' tasks
go on untouched. A lost unit's search that ran is first reduced to what its reported positions had
not swept (`delegation.service.sweep_progress`); the planner may share that remainder among the
live units, and its pieces then run in the task's place (``rebind-tst-nodes`` ``subtrees``).
A failed task of a tree our engine holds (``hold-failed``, §12.7: its branch not stopped) moves
alone the same way. A failed task of any other tree (its branch already stopped by the engine),
or a rebind the engine refuses, replaces the tree: the old one is aborted and the remaining one
started. A task re-delegated ``max_retries`` times, or one nobody can take, fails the mission
naming it. An engine lost or restarted does not fail its missions: they are caught up with
(`delegation.service.catch_up`), which gives a restarted engine the unfinished part of each tree
again; a lost engine is waited for, at most ``engine_return_timeout``, then its missions fail
saying so.
"""

from __future__ import annotations

import logging
import uuid
from dataclasses import dataclass, field, replace
from typing import Any

from delegation.allocation import Plan
from delegation.allocation.sharing import SHAREABLE
from delegation.errors import InputError
from delegation.fleet import FleetEvent, FleetEventKind
from delegation.messages import (
    TERMINAL_NODE_STATUSES,
    DelegationFeedback,
    MissionStatus,
    RebindTstNodes,
    SignalTstTree,
    StartTst,
)
from delegation.runtime.core import Effects
from delegation.service.catch_up import CatchUp
from delegation.service.engine_link import INTERNAL as INTERNAL  # re-exported: tests, older callers
from delegation.service.federated import handover, take_back, without_units
from delegation.service.jobs import Job, JobFailed, JobResult, PlanDone, internal_error
from delegation.service.missions import Mission, node_infos
from delegation.service.planning import MissionPart, Planning
from delegation.service.redelegation import (
    Remaining,
    first_origin,
    moved_tasks,
    remaining_tree,
    unfinished_on,
    unit_of,
)
from delegation.service.sweep_progress import unswept
from delegation.tst.node import TstNode, map_tree, parse_tree, to_dict, walk, where
from delegation.tst.validate import validate_tree

log = logging.getLogger(__name__)

#: The status of a task our engine holds for a rebind (docs/protocol.md §12.7; one its unit
#: aborted unasked is held too, known by its feedback's fail-reason only).
_HELD = frozenset({"failed"})



@dataclass(frozen=True, slots=True)
class Replan:
    """A re-delegation being planned: what remains, why, and the tree it replaces."""

    remaining: Remaining
    why: str
    old_root: str
    units: frozenset[str]
    #: The planning job's id (a newer replan of the mission supersedes this one).
    job: int = 0
    #: Move the freed tasks within the running tree (`rebind-tst-nodes`) rather than replace it.
    rebind: bool = False
    #: A lost delegator's part, offered to the other delegators: what goes whole to one of them
    #: moves within the running tree (`federated.handover`), else the tree is replaced.
    handover: bool = False
    #: Freed searches reduced to what their lost unit had not swept: new uuid -> share swept.
    credited: dict[str, float] = field(default_factory=dict)
    #: Failed tasks the engine holds for this rebind (their uuids in the running tree).
    held: frozenset[str] = frozenset()


@dataclass(frozen=True, slots=True)
class Rebinding:
    """A ``rebind-tst-nodes`` sent and not answered yet: what it moves, and why."""

    execunits: dict[str, str]
    why: str
    units: frozenset[str]
    tasks: list[dict[str, Any]]
    #: What the mission's tree records, when more than ``execunits`` (a handed-over subtree's
    #: nodes: the engine holds it as one node, our tree has them all).
    book: dict[str, str] = field(default_factory=dict)
    #: Task uuid -> the subtree run in its place (a lost unit's unswept remainder, shared).
    subtrees: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: Failed tasks the engine held, moved by it: their recorded failure is forgotten.
    held: frozenset[str] = frozenset()
    #: New nodes of ``subtrees`` -> the nodes they stand for (a lost delegator's part planned
    #: for our own units: its tasks have new uuids, the operator hears them under the old).
    origin: dict[str, str] = field(default_factory=dict)


@dataclass(eq=False)
class Repair(MissionPart):
    """Re-delegation of a lost or failing unit's tasks; a lost engine waited for (its missions
    failed when it does not come back), a returning or restarted one caught up with."""

    planning: Planning
    catch_up: CatchUp
    #: Missions whose re-delegation is being planned, by root uuid.
    replans: dict[str, Replan] = field(default_factory=dict)
    #: Missions whose ``rebind-tst-nodes`` waits for the engine's answer, by root uuid.
    rebinds: dict[str, Rebinding] = field(default_factory=dict)
    #: Since when the engine is lost (its missions wait for it), or None.
    engine_away: float | None = None
    #: Roots of the trees our engine said it holds failed tasks of (``hold-failed``, §12.7).
    holding: set[str] = field(default_factory=set)

    def forget(self, root_uuid: str, now: float) -> Effects:
        """The mission ends while re-delegating (cancelled): abort its old tree, still running
        on a live engine, and drop the replan."""
        self.rebinds.pop(root_uuid, None)
        replan = self.replans.pop(root_uuid, None)
        if replan is None or replan.rebind:  # a rebind's tree is the mission's: cancel aborts it
            return Effects()
        return self.abort_tree(replan.old_root, now)

    def engine_gone(self, event: FleetEvent, now: float) -> Effects:
        """The engine's heartbeat stopped, or it came back with a new agent-uuid. Its missions
        are not failed for that: a restarted engine is asked about each tree, does not know it,
        and is given its unfinished part again (`CatchUp`); a lost one is waited for, at most
        ``engine_return_timeout`` (`engine_wait`)."""
        engine = self.config.engine
        if event.kind is FleetEventKind.LOST:
            if self.engine_away is None:
                self.engine_away = now
            log.warning("engine %s lost (no heartbeat): its missions wait for it at most %g s",
                        engine, self.config.engine_return_timeout)
            return Effects()
        log.warning("engine %s restarted (new agent-uuid): its missions' trees are sent again "
                    "where it does not know them", engine)
        self.engine_away = None
        self.catch_up.want_open()
        return Effects()

    def engine_wait(self, now: float) -> Effects:
        """While the engine is lost: back (heard again), its missions are brought up to date;
        not back within ``engine_return_timeout``, they end ``failed`` saying so."""
        away = self.engine_away
        if away is None:
            return Effects()
        if self.engine.base(now) is not None:
            self.engine_away = None
            log.info("engine %s is back: catching up on its missions", self.config.engine)
            self.catch_up.want_open()
            return Effects()
        if now - away < self.config.engine_return_timeout:
            return Effects()
        self.engine_away = None
        why = (f"engine {self.config.engine} lost (no heartbeat) and not back within "
               f"{self.config.engine_return_timeout:g} s: the trees it executed are gone")
        effects = Effects()
        for m in self.book:
            if m.ended or m.status is MissionStatus.PLANNED:
                continue
            self.replans.pop(m.root_uuid, None)
            effects.extend(self.lifecycle.set_status(m.root_uuid, MissionStatus.FAILED, now, why))
        return effects

    def unit_lost(self, event: FleetEvent, now: float) -> Effects:
        """A unit lost or rebooted: re-delegate its unfinished tasks in every running mission."""
        why = (f"/{event.name} lost (no heartbeat)" if event.kind is FleetEventKind.LOST
               else f"/{event.name} rebooted (new agent-uuid): its tasks are gone")
        effects = Effects()
        # A delegator runs whole subtrees (not task nodes that could move): its part is planned
        # again in a replacement tree (docs/protocol.md §15.4).
        delegator = event.name in {d.name for d in self.view.fleet.delegators(
            now, alive_only=False)}
        for m in self.book:
            if m.ended or m.redelegating or m.status not in (MissionStatus.STARTED,
                                                             MissionStatus.RUNNING):
                continue
            if m.root_uuid in self.replans or m.root_uuid in self.rebinds:
                continue  # one repair at a time: the next looks for lost units again
            if unfinished_on(parse_tree(m.current_tst), m.node_status, event.name):
                effects.extend(self.redelegate(m, event.name, why, now,
                                               rebind=False if delegator else None,
                                               offers=delegator))
        return effects

    def failed(self, mission: Mission, node_uuid: str, unit: str, why: str, now: float
               ) -> Effects:
        """A task failed on its unit (or was aborted by it unasked). In a tree the engine holds
        it for (``holding``) it alone moves, by rebind, its branch going on; otherwise the
        engine already stopped its branch and the tree is replaced."""
        if mission.current_root not in self.holding:
            return self.redelegate(mission, unit, why, now, rebind=False)
        # Every held task of that unit (a rebooted unit fails them all, one feedback each: each
        # replan supersedes the last, so the last covers them all).
        held = {uid for uid in unfinished_on(parse_tree(mission.current_tst), mission.node_status,
                                             unit)
                if mission.node_status.get(uid) in _HELD} | {node_uuid}
        return self.redelegate(mission, unit, why, now, rebind=True, only=held)

    def hold_ran_out(self, mission: Mission, node_uuid: str, status: str, now: float
                     ) -> Effects | None:
        """A control node of the running tree ``failed`` while a held task's move is planned
        or sent: the engine's hold (``hold-failed``, §12.7) ran out before the move was ready
        (a planner busy with a long plan), and the task's branch failed as without it. The
        mission does not end with the old tree: the repair goes on as its replacement (the
        mission is ``redelegating`` from now, and the remaining tree is planned and started as
        for a tree the engine does not hold). None when this is not that."""
        root = mission.root_uuid
        info = mission.nodes.get(node_uuid)
        if status != "failed" or info is None or info.is_task or mission.ended \
                or mission.redelegating or node_uuid not in mission.current_nodes:
            return None
        replan, sent = self.replans.get(root), self.rebinds.get(root)
        moving: Replan | Rebinding | None = (
            replan if replan is not None and replan.rebind and replan.held
            else sent if sent is not None and sent.held else None)
        if moving is None:
            return None
        log.warning("mission %s: the engine's hold of %s ran out before its move was ready (%s "
                    "failed): the tree is replaced instead", root,
                    ", ".join(sorted(moving.held)), info.path)
        # Planned again whole (the move planned only the held task; the unit's other tasks,
        # left on it then, stopped with the branch too): the earlier job's result is dropped.
        self.replans.pop(root, None)
        self.rebinds.pop(root, None)
        return self.redelegate(mission, next(iter(sorted(moving.units))), moving.why, now,
                               rebind=False)
        return None

    def redelegate(self, mission: Mission, unit: str, why: str, now: float,
                   *, rebind: bool | None = None, offers: bool = False,
                   only: set[str] | None = None) -> Effects:
        """Plan what ``mission`` still has to do without ``unit`` (a job). With ``rebind``
        (``repair: rebind``, the default for a lost unit) the tree runs on meanwhile and the
        freed tasks then move within it; else the mission waits for a replacement tree
        (``redelegating``: no root status ends it meanwhile). With ``offers`` (a lost delegator)
        the other delegators are asked for offers first (docs/protocol.md §15.4). ``only``: the
        tasks to free (a failed task the engine holds), ``unit``'s others stay on it."""
        if rebind is None:
            rebind = self.config.repair == "rebind"
        tree = parse_tree(mission.current_tst)
        # Every unit of the tree that is gone too (e.g. lost while this was being planned).
        lost = {unit} | {n.execunit.strip("/") for _, n in walk(tree) if not n.is_control
                         and isinstance(n.execunit, str) and n.execunit.startswith("/")
                         and not self.view.fleet.is_alive(n.execunit, now)}
        remaining = remaining_tree(tree, mission.node_status, lost, lambda: str(uuid.uuid4()),
                                   only=only)
        if remaining is None:
            return Effects()
        if offers:  # the lost delegator's seq/conc are free for anyone too
            remaining = replace(remaining, tree=without_units(remaining.tree, lost))
        paths = {n.node_uuid: where(p, n) for p, n in walk(parse_tree(mission.current_tst))}
        for uid in remaining.freed:
            old = remaining.origin[uid]
            if mission.retries.get(first_origin(mission.origin, old), 0) >= self.config.max_retries:
                reason = (f"{why}; {paths.get(old, old)} was re-delegated "
                          f"{self.config.max_retries} times already (retry budget)")
                return self.abort_and_fail(mission, mission.current_root, reason, now)
        try:  # made of a valid tree, but checked like any tree the planner gets
            checked = validate_tree(remaining.tree, self.config.limits)
        except InputError as exc:
            return self.abort_and_fail(mission, mission.current_root, f"{why}; {exc.fail_reason}",
                                       now)
        credited: dict[str, float] = {}
        if rebind and self.config.repair_sweep == "remainder":
            reduced, credited = self.subtract_swept(mission, remaining, now)
            try:
                checked, remaining = validate_tree(reduced.tree, self.config.limits), reduced
            except InputError as exc:  # said, and the parts planned whole as without it
                log.warning("mission %s: the unswept remainder is not a valid tree (%s): the "
                            "lost parts are planned again whole", mission.root_uuid,
                            exc.fail_reason)
                credited = {}
        old_root = mission.current_root
        if not rebind:
            mission.current_root = ""  # re-delegating
        self.rebinds.pop(mission.root_uuid, None)  # a replacement supersedes a rebind in flight
        units, notes = self.view.plannable(now, exclude=lost, mission=mission.root_uuid)
        job_id = self.planning.next_id()
        # Failed tasks the engine holds for a rebind: moved although their status is final.
        held = frozenset(only or ()) | frozenset(
            uid for u in lost for uid in unfinished_on(tree, mission.node_status, u)
            if mission.node_status.get(uid) in _HELD) \
            if rebind and mission.current_root in self.holding else frozenset()
        self.replans[mission.root_uuid] = Replan(remaining, why, old_root, frozenset(lost),
                                                 job_id, rebind, handover=offers,
                                                 credited=credited, held=held)
        options = self.planning.options(mission.plan.get("strategy"),
                                        mission.plan.get("objective"), None)
        job = Job(id=job_id, kind="plan",
                  key=(INTERNAL, f"{mission.root_uuid}#{mission.redelegations + 1}"),
                  face="delegation", tree=checked, units=units, options=options,
                  engine=self.config.engine, start=True, source="redelegate", received=now,
                  notes=notes, redelegate=mission.root_uuid,
                  delegators=frozenset(d.name for d in self.view.fleet.delegators(
                      now, alive_only=False)))
        log.info("mission %s: re-delegating %d task(s): %s", mission.root_uuid,
                 len(remaining.freed), why)
        opened = self.planning.offers.open(job, "", now, redelegation=True) \
            if offers and self.planning.offers is not None else None
        return opened if opened is not None else Effects(jobs=[job])

    def subtract_swept(self, mission: Mission, remaining: Remaining, now: float
                       ) -> tuple[Remaining, dict[str, float]]:
        """``remaining`` with each freed search that ran reduced to what its unit had not swept
        (`sweep_progress`: the positions it reported since the task ran), and the share of each
        credited as swept (new uuid -> share)."""
        states = {u.name: u for u in self.view.fleet.snapshot(now)}
        to_mono = now - self.lifecycle.epoch(now)  # node_started is in epoch seconds
        reduced: dict[str, TstNode] = {}
        credited: dict[str, float] = {}
        for _, node in walk(remaining.tree):
            uid = node.node_uuid or ""
            old = remaining.origin.get(uid, "")
            started = mission.node_started.get(old)
            info = mission.nodes.get(old)
            if uid not in remaining.freed or node.name not in SHAREABLE or started is None \
                    or info is None:
                continue
            unit = states.get(info.execunit.strip("/"))
            if unit is None:
                continue
            track = self.view.fleet.track(unit.name, started + to_mono)
            left, done = unswept(node, unit, track)
            if done > 0.0:
                reduced[uid], credited[uid] = left, done
                log.info("mission %s: %s had swept %.0f %% of %s (%d positions): the rest is "
                         "shared again", mission.root_uuid, info.execunit, 100.0 * done,
                         info.path, len(track))

        def swap(node: TstNode, children: tuple[TstNode, ...]) -> TstNode:
            if node.is_control:
                return replace(node, children=children)
            return reduced.get(node.node_uuid or "", node)

        if not reduced:
            return remaining, {}
        return Remaining(map_tree(remaining.tree, swap), remaining.origin,
                         remaining.freed), credited

    def redelegated(self, job: Job, result: JobResult, now: float) -> Effects:
        """A re-delegation was planned: abort the old tree, start the new one, tell the operator;
        or fail the mission naming the unit and the tasks nobody can take."""
        replan = self.replans.get(job.redelegate)
        if replan is None or replan.job != job.id:
            return Effects()  # cancelled, or superseded by a newer replan
        del self.replans[job.redelegate]
        mission = self.book.find(job.redelegate)
        if mission is None or mission.ended:
            return Effects()  # ended meanwhile
        if isinstance(result, JobFailed):
            return self.abort_and_fail(mission, replan.old_root, f"{replan.why}; {result.reason}",
                                        now)
        if not isinstance(result, PlanDone):
            return self.abort_and_fail(mission, replan.old_root,
                                        internal_error(result).reason, now)
        plan = result.plan
        origin = replan.remaining.origin
        if not plan.feasible:
            paths = {n.node_uuid: where(p, n) for p, n in walk(parse_tree(mission.current_tst))}
            parts = [f"{paths.get(origin.get(u.node_uuid, ''), u.name)}: {u.reason}"
                     for u in plan.unassigned]
            reason = f"{replan.why}; nobody can take " + "; ".join(parts)
            return self.abort_and_fail(mission, replan.old_root, reason, now)
        if replan.rebind:
            return self.rebind(mission, replan, plan, now)
        if replan.handover:
            handed = self.hand_over(mission, replan, plan, now)
            if handed is None:
                handed = self.take_back(mission, replan, plan, now)
            if handed is not None:
                return handed
        if any(mission.node_status.get(origin.get(uid, "")) == "succeeded"
               for uid in origin):
            # A task finished while this was planned: plan again without it (never run twice).
            mission.current_root = replan.old_root
            return self.redelegate(mission, next(iter(replan.units)), replan.why, now,
                                   rebind=False)
        problem = self.engine.problem(now)
        if problem:
            return self.abort_and_fail(mission, replan.old_root, f"{replan.why}; {problem}", now)
        plan_json = {**plan.to_json(), "notes": list(plan.notes)}
        new_root = plan.tst.node_uuid or ""
        self.book.replace_tree(mission, plan_json["tst"], new_root, node_infos(plan.tst), origin)
        moved = moved_tasks(plan.tst, replan.remaining)
        for uid in replan.remaining.freed:
            first = first_origin(mission.origin, uid)
            mission.retries[first] = mission.retries.get(first, 0) + 1
        effects = self.abort_tree(replan.old_root, now)
        start = StartTst(receiver=self.config.engine, sender=self.config.name, tst=plan_json["tst"],
                         hold_failed=self.config.hold_failed or None)
        effects.publish.append(self.engine.send("start", (INTERNAL, f"{new_root}#start"),
                                                "delegation", start, now, mission.root_uuid,
                                                plan_json))
        effects.send(self.desk.topics.delegation_feedback, DelegationFeedback(
            root_uuid=mission.root_uuid, status=MissionStatus.RE_DELEGATED.value,
            fail_reason=replan.why, tasks=moved))
        log.info("mission %s re-delegated: %s", mission.root_uuid,
                 ", ".join(f"{t['path']} -> {t['unit']}" for t in moved))
        for note in plan.notes:
            log.info("mission %s (re-delegation): %s", mission.root_uuid, note)
        return effects

    def rebind(self, mission: Mission, replan: Replan, plan: Plan, now: float) -> Effects:
        """Send ``rebind-tst-nodes`` for the freed tasks that have not ended, each to the unit
        the plan gave it; a freed search the plan shared, or reduced to its unswept remainder,
        is replaced by its parts (``subtrees``). The rest of the running tree is not touched."""
        execunits, subtrees, tasks = self.moves(mission, replan, plan)
        if not execunits and not subtrees:
            return Effects()
        problem = self.engine.problem(now)
        if problem:
            return self.abort_and_fail(mission, mission.current_root,
                                       f"{replan.why}; {problem}", now)
        self.rebinds[mission.root_uuid] = Rebinding(execunits, replan.why, replan.units, tasks,
                                                    subtrees=subtrees, held=replan.held)
        model = RebindTstNodes(execunits=execunits, subtrees=subtrees or None,
                               sender=self.config.name)
        key = (INTERNAL, f"{mission.root_uuid}#rebind{mission.redelegations + 1}")
        for note in plan.notes:
            log.info("mission %s (re-delegation): %s", mission.root_uuid, note)
        return Effects(publish=[self.engine.send("rebind", key, "delegation", model, now,
                                                 mission.root_uuid)])

    def hand_over(self, mission: Mission, replan: Replan, plan: Plan, now: float
                  ) -> Effects | None:
        """A lost delegator's subtrees that the plan gives whole to other delegators move there
        within the running tree (one ``rebind-tst-nodes`` of each subtree's root): the rest of
        the tree, other partners' parts too, runs on untouched, uuids kept. None when the plan
        does otherwise (the caller replaces the tree)."""
        moves = handover(parse_tree(mission.current_tst), plan.tst, replan.remaining.origin,
                         replan.remaining.freed, replan.units,
                         {d.name for d in self.view.fleet.delegators(now)}, mission.node_status)
        if moves is None or mission.node_status.get(replan.old_root) in TERMINAL_NODE_STATUSES:
            return None
        problem = self.engine.problem(now)
        if problem:
            return None
        mission.current_root = replan.old_root  # the tree runs on
        self.rebinds[mission.root_uuid] = Rebinding(moves.engine, replan.why, replan.units,
                                                    moves.tasks, book=moves.book)
        key = (INTERNAL, f"{mission.root_uuid}#rebind{mission.redelegations + 1}")
        for note in plan.notes:
            log.info("mission %s (re-delegation): %s", mission.root_uuid, note)
        model = RebindTstNodes(execunits=moves.engine, sender=self.config.name)
        return Effects(publish=[self.engine.send("rebind", key, "delegation", model, now,
                                                 mission.root_uuid)])

    def take_back(self, mission: Mission, replan: Replan, plan: Plan, now: float
                  ) -> Effects | None:
        """A lost delegator's part that the plan gives to our own units runs in its place
        within the running tree (``rebind-tst-nodes`` ``subtrees`` of each subtree's root, which
        the engine holds as one node; `federated.take_back`): the rest of the tree, other
        partners' parts too, runs on untouched, uuids kept. None when the plan does otherwise
        (the caller replaces the tree)."""
        if mission.node_status.get(replan.old_root) in TERMINAL_NODE_STATUSES \
                or self.engine.problem(now):
            return None
        delegators = {d.name for d in self.view.fleet.delegators(now, alive_only=False)}
        taken = take_back(parse_tree(mission.current_tst), plan.tst, replan.remaining.origin,
                          replan.remaining.freed, replan.units, delegators, mission.node_status)
        if taken is None:
            return None
        mission.current_root = replan.old_root  # the tree runs on
        self.rebinds[mission.root_uuid] = Rebinding({}, replan.why, replan.units, taken.tasks,
                                                    subtrees=taken.subtrees,
                                                    origin=taken.origin)
        key = (INTERNAL, f"{mission.root_uuid}#rebind{mission.redelegations + 1}")
        for note in plan.notes:
            log.info("mission %s (re-delegation): %s", mission.root_uuid, note)
        model = RebindTstNodes(execunits={}, subtrees=taken.subtrees, sender=self.config.name)
        return Effects(publish=[self.engine.send("rebind", key, "delegation", model, now,
                                                 mission.root_uuid)])

    def moves(self, mission: Mission, replan: Replan, plan: Plan
              ) -> tuple[dict[str, str], dict[str, dict[str, Any]], list[dict[str, Any]]]:
        """What the rebind moves: (task uuid -> its new unit, task uuid -> the subtree of parts
        run in its place, the ``re-delegated`` rows) for the freed tasks that have not ended."""
        origin = replan.remaining.origin
        planned = {n.node_uuid: n for _, n in walk(plan.tst) if n.node_uuid}
        parts = plan.part_map()
        execunits: dict[str, str] = {}
        subtrees: dict[str, dict[str, Any]] = {}
        tasks: list[dict[str, Any]] = []
        for uid in sorted(replan.remaining.freed):
            old = origin[uid]
            if mission.node_status.get(old) in TERMINAL_NODE_STATUSES and old not in replan.held:
                continue
            info = mission.nodes[old]
            row: dict[str, Any] = {"node-uuid": old, "replaces": old, "name": info.name,
                                   "path": info.path}
            if uid in replan.credited:
                row["swept"] = round(replan.credited[uid], 3)
            pieces = [planned[p] for p in parts.get(uid, []) if p in planned]
            node = planned.get(uid)
            if pieces or uid in replan.credited:
                pieces = pieces or ([node] if node is not None and not node.is_control else [])
                if not pieces:
                    continue
                sub = TstNode(name="conc", children=tuple(pieces),
                              common_params={"node-uuid": old})
                subtrees[old] = to_dict(sub)
                tasks += [{**row, "node-uuid": p.node_uuid or "", "name": p.name,
                           "path": f"{info.path}/children[{i}]", "unit": p.execunit}
                          for i, p in enumerate(pieces)]
            elif node is not None and unit_of(node):
                execunits[old] = f"/{unit_of(node)}"
                tasks.append({**row, "unit": execunits[old]})
        return execunits, subtrees, tasks

    def rebind_answered(self, root_uuid: str, ok: bool, reason: str, now: float) -> Effects:
        """The engine's answer to ``rebind-tst-nodes``: the tasks moved (the book follows, the
        operator is told ``re-delegated``); refused or unanswered (an engine without it), the
        tree is replaced instead."""
        sent = self.rebinds.pop(root_uuid, None)
        mission = self.book.find(root_uuid)
        if sent is None or mission is None or mission.ended or mission.redelegating:
            return Effects()
        if not ok:
            log.warning("mission %s: the engine did not re-bind (%s): replacing the tree",
                        root_uuid, reason)
            why = f"{sent.why} (the engine did not move the tasks: {reason})"
            return self.redelegate(mission, next(iter(sorted(sent.units))), why, now,
                                   rebind=False)
        for uid in sent.held:  # runs again: its failure, held, was not its end
            mission.node_status.pop(uid, None)
            mission.node_ended.pop(uid, None)
        self.book.rebind(mission, sent.book or sent.execunits)
        if sent.subtrees:
            self.book.graft(mission, sent.subtrees)
            mission.origin.update(sent.origin)
        # The retry budget counts once per task first delegated (a handed-over subtree: each of
        # its tasks; a search moved as parts: the search).
        moved = set(sent.execunits) | set(sent.subtrees) | (
            {t["node-uuid"] for t in sent.tasks} if sent.book else set())
        for first in {first_origin(mission.origin, uid) for uid in moved}:
            mission.retries[first] = mission.retries.get(first, 0) + 1
        effects = Effects()
        effects.send(self.desk.topics.delegation_feedback, DelegationFeedback(
            root_uuid=root_uuid, status=MissionStatus.RE_DELEGATED.value, fail_reason=sent.why,
            tasks=sent.tasks))
        log.info("mission %s re-delegated in place: %s", root_uuid,
                 ", ".join(f"{t['path']} -> {t['unit']}" for t in sent.tasks))
        return effects.extend(self.still_lost(mission, now))

    def still_lost(self, mission: Mission, now: float) -> Effects:
        """After a repair: a unit of the mission lost meanwhile has its tasks moved too."""
        tree = parse_tree(mission.current_tst)
        for _, node in walk(tree):
            unit = unit_of(node) if not node.is_control else ""
            if unit and not self.view.fleet.is_alive(f"/{unit}", now) \
                    and unfinished_on(tree, mission.node_status, unit):
                return self.redelegate(mission, unit, f"/{unit} lost (no heartbeat)", now)
        return Effects()

    def abort_tree(self, root: str, now: float) -> Effects:
        """``$abort`` a tree the service gave the engine (no caller waits for the answer)."""
        if not root or self.engine.problem(now):
            return Effects()
        model = SignalTstTree(node_uuid=root, signal="$abort", sender=self.config.name)
        abort = self.engine.send("signal", (INTERNAL, f"{root}#abort"), "delegation", model, now)
        return Effects(publish=[abort])

    def abort_and_fail(self, mission: Mission, root: str, reason: str, now: float) -> Effects:
        """``$abort`` the tree ``root`` and end the mission ``failed`` with ``reason``."""
        effects = self.abort_tree(root, now)
        return effects.extend(self.lifecycle.set_status(mission.root_uuid, MissionStatus.FAILED,
                                                        now, reason))
