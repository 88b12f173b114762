"""Planning jobs: from a command's tree to a job, from a finished job to a mission (pure).

The tree and the options are validated here, once on the service's path, so bad input is
answered at once; the planner receives the `ValidatedTree` and does not check it again. A
finished plan is answered (``ok``, ``failed`` naming the nodes nobody can take), recorded as a
mission, and with ``start`` sent to the engine. A start plan that used a unit which got busy in a
mission started meanwhile is planned again around it (at most ``MAX_REPLANS`` times). A preview's
plan is kept (`previews`), and a start naming it starts that plan while it still holds.
"""

from __future__ import annotations

import logging
from collections import OrderedDict, deque
from dataclasses import dataclass, field, replace
from typing import Any, Literal

from delegation.allocation import Plan
from delegation.errors import InputError, InputProblem
from delegation.fleet import UnitState
from delegation.learning import input_warnings
from delegation.messages import DelegationResponse, MissionStatus, StartTst
from delegation.runtime.commands import CommandKey
from delegation.runtime.core import Effects
from delegation.service.commands import CommandDesk
from delegation.service.config import ServiceConfig
from delegation.service.engine_link import EngineLink
from delegation.service.faces import Face
from delegation.service.fleet_view import FleetView
from delegation.service.jobs import (
    Job,
    PlanOptions,
    infeasible_reason,
    plan_options,
)
from delegation.service.lifecycle import Lifecycle
from delegation.service.missions import LifecycleEvent, Mission, MissionBook, node_infos
from delegation.service.offers import OfferDesk
from delegation.service.operator_view import OperatorView
from delegation.service.previews import Preview, Previews, stale_reason
from delegation.tst.node import to_dict, without_node_uuids
from delegation.tst.validate import ValidatedTree, validate_tree

log = logging.getLogger(__name__)

#: How often a start plan is made again because a unit it uses got busy meanwhile.
MAX_REPLANS = 3


@dataclass(frozen=True, slots=True)
class Timing:
    """When a mission's command arrived and when its instantiated tree left for the engine, and
    how much of that the planner itself took."""

    root_uuid: str
    received: float
    sent: float
    planning: float


@dataclass(eq=False)
class MissionPart:
    """What each part of the core that acts on missions works with (shared, one of each)."""

    config: ServiceConfig
    book: MissionBook
    desk: CommandDesk
    view: FleetView
    engine: EngineLink
    lifecycle: Lifecycle


@dataclass(eq=False)
class Planning(MissionPart):
    """Commands' trees to planning jobs, and finished plans to answers and missions."""

    #: Other delegators' offers, asked for before a plan (None: plan with the own fleet only).
    offers: OfferDesk | None = None
    timings: deque[Timing] = field(default_factory=lambda: deque(maxlen=10_000))
    _job_ids: int = field(default=0, init=False)
    #: Start plans made again around a unit that got busy meanwhile, by command.
    _replanned: dict[CommandKey, int] = field(default_factory=dict, init=False)
    #: Each caller's recent previews, so that a start naming one starts that plan.
    previews: Previews = field(default_factory=Previews, init=False)
    #: Starts naming a preview that are planned again: (preview id, why), said in the answer.
    _unpreviewed: OrderedDict[CommandKey, tuple[str, str]] = field(
        default_factory=OrderedDict, init=False)

    def next_id(self) -> int:
        """A new job id (jobs run in arrival order)."""
        self._job_ids += 1
        return self._job_ids

    def options(
        self, strategy: str | None, objective: str | None, time_limit: float | None,
        split: bool = True,
    ) -> PlanOptions:
        """The options asked for, this service's defaults elsewhere; ``InputError`` if bad."""
        c = self.config
        return plan_options(strategy, objective, time_limit,
                            defaults=PlanOptions(c.strategy, c.objective, c.time_limit),
                            max_time_limit=c.max_time_limit, split=split)

    def job(
        self,
        face: Face,
        key: CommandKey,
        raw_tree: dict[str, Any],
        now: float,
        options: PlanOptions,
        *,
        start: bool,
        source: str,
        kind: Literal["plan", "bids"] = "plan",
        preview_id: str | None = None,
        waits: bool = False,
    ) -> Effects:
        """Validate the tree (once, here: a bad one is answered at once) and hand it to the
        planner as a job; a start naming a preview starts the previewed plan if it holds.

        ``waits``: a start plan is being made, so a start plan that holds units (`holds_units`)
        waits for it and is given the units as they are then (`refreshed`): the fleet is not
        read now (a `Job.deferred` job), unless other delegators may be asked for offers (they
        are asked with the units as they are now)."""
        self._trusted(key, now)
        if preview_id is not None and (not start or source != "delegate"):
            raise InputError(InputProblem("command", "preview-id",
                                          "only a start (start: true, no preview) names one"))
        tree = validate_tree(raw_tree, self.config.limits).with_uuids()
        if kind == "plan":
            conflicts = self.book.conflicts(tree.root)
            if conflicts:
                raise InputError(conflicts)
            problem = self.engine.problem(now) if start else None
            if problem:
                raise InputError(InputProblem("engine", "", problem))
        view = self.view
        deferred = (waits and kind == "plan" and start and preview_id is None
                    and self.config.commitments != "share"
                    and not (self.offers is not None and self.offers.may_ask(now)))
        units: tuple[UnitState, ...] = ()
        notes: tuple[str, ...] = ()
        if not deferred:
            units, notes = view.plannable(now) if kind == "plan" else (view.units(now), ())
        if preview_id is not None:
            preview = self._previewed(key, preview_id, tree, units, now)
            if isinstance(preview, Preview):
                return self._start_preview(preview, key, now)
            options = preview or options
            notes = (f"preview {preview_id} not started, planned again: "
                     f"{self._unpreviewed[key][1]}", *notes)
        job_id = self.next_id()
        warnings = tuple(input_warnings(tree.root, units, view.fleet.names())) \
            if kind == "plan" and not deferred else ()
        for w in warnings:
            log.warning("mission %s: %s", tree.node_uuid, w)
        log.info("mission %s (%s) received on %s (%s%s): %s", tree.node_uuid, tree.name, face,
                 source, ", start" if start else "",
                 "waits for the start plan being made" if deferred
                 else f"{len(units)} units to plan for")
        job = Job(id=job_id, kind=kind, key=key, face=face, tree=tree,
                  units=units, options=options, engine=self.config.engine,
                  start=start, source=source, received=self.desk.received(key, now),
                  speed_sources=view.speed_sources(units), warnings=warnings, notes=notes,
                  limits=self.config.limits, deferred=deferred)
        if kind == "plan" and self.offers is not None:  # ask other delegators first
            held = self.offers.open(job, self.desk.caller(key), now)
            if held is not None:
                return held
        return Effects(jobs=[job])

    def holds_units(self, job: Job) -> bool:
        """Whether ``job`` is a start plan of the own fleet that commits units: such plans are
        made one at a time, each with the fleet as it is when it begins (`refreshed`), so that
        a burst's plans do not all use the same free units and get planned again."""
        return (job.kind == "plan" and job.start and not job.redelegate and not job.offers
                and self.config.commitments != "share")

    def refreshed(self, job: Job, now: float) -> Job:
        """``job`` with the units as they are ``now`` (the missions started since it arrived
        hold theirs), as `planned` would plan it again around a clash."""
        units, notes = self.view.plannable(now)
        unpreviewed = self._unpreviewed.get(job.key)
        if unpreviewed is not None:
            notes = (f"preview {unpreviewed[0]} not started, planned again: {unpreviewed[1]}",
                     *notes)
        warnings = tuple(input_warnings(job.tree.root, units, self.view.fleet.names()))
        if job.deferred:  # said on arrival for a job read then
            for w in warnings:
                log.warning("mission %s: %s", job.tree.node_uuid, w)
        return replace(job, units=units, notes=notes, warnings=warnings,
                       speed_sources=self.view.speed_sources(units), deferred=False)

    def _trusted(self, key: CommandKey, now: float) -> None:
        """``InputError`` when another delegator (or a TST engine: one of theirs handing us a
        subtree) asks us to plan and is neither a partner nor an operator of ours."""
        caller = self.desk.caller(key)
        fleet = self.view.fleet
        if not caller or caller in self.config.partners or caller in self.config.operators:
            return
        levels = fleet.levels(caller)
        if "delegation" in levels or "tst execution" in levels:
            raise InputError(InputProblem(
                "command", "sender", f"{caller} is another delegator (or its engine) that "
                f"{self.config.name} does not trust: start it with --partner {caller}"))

    def planned(self, job: Job, plan: Plan, now: float, seconds: float) -> Effects:
        """A plan was made for a command: plan again around a clash, refuse it when infeasible,
        else record the mission and answer it (with ``start``, once the engine accepts)."""
        plan_json = {**plan.to_json(), "notes": list(plan.notes)}
        clash = self._clash(plan, job) if job.start and plan.feasible else set()
        if clash and self._replanned.get(job.key, 0) < MAX_REPLANS:
            # A unit it uses got busy in a mission started meanwhile: plan again around it.
            self._replanned[job.key] = self._replanned.get(job.key, 0) + 1
            log.info("mission %s planned again: %s got busy meanwhile", plan.tst.node_uuid,
                     ", ".join(sorted(clash)))
            job_id = self.next_id()
            units, notes = self.view.plannable(now)
            return Effects(jobs=[replace(job, id=job_id, units=units, notes=notes)])
        self._replanned.pop(job.key, None)
        unpreviewed = self._unpreviewed.pop(job.key, None)
        if unpreviewed is not None:  # a start naming a preview that no longer held: say so
            plan_json["from-preview"] = {"id": unpreviewed[0], "started": False,
                                         "reason": unpreviewed[1]}
        log.info("mission %s planned: %s/%s, %s, makespan %.0f s, units %s", plan.tst.node_uuid,
                 plan.strategy, plan.objective, "feasible" if plan.feasible else "infeasible",
                 plan.makespan or 0.0,
                 ", ".join(sorted({a.execunit for a in plan.assignments})) or "none")
        if plan.notes:  # one record: a plan in a busy fleet has a note per unit
            log.info("mission %s: %s", plan.tst.node_uuid, "; ".join(plan.notes))
        if not plan.feasible:
            reason = infeasible_reason(plan, job.tree.root)
            log.info("mission %s refused: %s", plan.tst.node_uuid, reason)
            if job.face == "tst":
                return self.desk.fail("tst", job.key, job.com_uuid, reason)
            return self.desk.respond("delegation", job.key, DelegationResponse(
                response="failed", response_to=job.com_uuid, fail_reason=reason, plan=plan_json))
        if job.source == "preview":  # answered and kept for a start, never stored as a mission
            plan_json["preview-id"] = job.com_uuid
            self.previews.keep(Preview(job.com_uuid, self.desk.caller(job.key), job, plan,
                                       plan_json, now, without_node_uuids(to_dict(job.tree.root))))
            return self.desk.respond("delegation", job.key, DelegationResponse(
                response="ok", response_to=job.com_uuid, plan=plan_json))
        conflicts = self.book.conflicts(plan.tst)
        if conflicts:  # a twin command with the same tree was planned meanwhile
            return self.desk.fail(job.face, job.key, job.com_uuid,
                                  InputError(conflicts).fail_reason)
        return self._record(job, plan, plan_json, now, seconds)

    def _previewed(self, key: CommandKey, preview_id: str, tree: ValidatedTree,
                   units: tuple[UnitState, ...], now: float) -> Preview | PlanOptions | None:
        """The caller's preview when it still holds; else (remembering why, for the answer)
        the options it was planned with, or None when it is not known."""
        preview, why = self.previews.take(self.desk.caller(key), preview_id, now)
        if preview is not None:
            why = stale_reason(preview, to_dict(tree.root), units)
            if not why:
                return preview
        self._unpreviewed[key] = (preview_id, why)
        while len(self._unpreviewed) > 1000:
            self._unpreviewed.popitem(last=False)
        return preview.job.options if preview is not None else None

    def _start_preview(self, preview: Preview, key: CommandKey, now: float) -> Effects:
        """Start the previewed plan itself (its tree, uuids, assignment and times)."""
        conflicts = self.book.conflicts(preview.plan.tst)
        if conflicts:  # started already under another preview id
            raise InputError(conflicts)
        job = replace(preview.job, id=self.next_id(), key=key, start=True, source="delegate",
                      received=self.desk.received(key, now))
        plan_json = {k: v for k, v in preview.plan_json.items() if k != "preview-id"}
        plan_json["from-preview"] = {"id": preview.preview_id, "started": True}
        log.info("mission %s: the plan of preview %s started as previewed",
                 preview.plan.tst.node_uuid, preview.preview_id)
        return self._record(job, preview.plan, plan_json, now, 0.0)

    def _record(self, job: Job, plan: Plan, plan_json: dict[str, Any], now: float,
                seconds: float) -> Effects:
        """A feasible plan becomes a mission: answered ``ok``, or sent to the engine."""
        root_uuid = plan.tst.node_uuid or ""
        self.book.add(Mission(root_uuid=root_uuid, source=job.source,
                              created=self.lifecycle.epoch(now),
                              tst=plan_json["tst"], plan=plan_json,
                              nodes={**(node_infos(plan.source) if plan.source else {}),
                                     **node_infos(plan.tst)},
                              operator=(OperatorView.of(plan.source, plan.tst, plan.part_map())
                                        if plan.source else None),
                              received=to_dict(job.tree.root), command=job.key,
                              owner=self.desk.caller(job.key)))
        self.view.planned(plan.tst)
        effects = self.lifecycle.publish([LifecycleEvent(root_uuid, MissionStatus.PLANNED)])
        if not job.start:
            return effects.extend(self.desk.respond("delegation", job.key, DelegationResponse(
                response="ok", response_to=job.com_uuid, plan=plan_json)))
        problem = self.engine.problem(now)
        if problem:
            effects.extend(self.lifecycle.set_status(root_uuid, MissionStatus.FAILED, now, problem))
            return effects.extend(self.desk.fail(job.face, job.key, job.com_uuid, problem))
        start = StartTst(receiver=self.config.engine, sender=self.config.name, tst=plan_json["tst"],
                         hold_failed=self.config.hold_failed or None)
        effects.publish.append(self.engine.send("start", job.key, job.face, start, now, root_uuid,
                                                plan_json))
        log.info("mission %s sent to engine %s", root_uuid, self.config.engine)
        self.timings.append(Timing(root_uuid, job.received, now, seconds))
        return effects

    def _clash(self, plan: Plan, job: Job) -> set[str]:
        """Units a start plan uses that got busy in a mission started meanwhile (the plan did
        not know: it used them as free now)."""
        if self.config.commitments == "share":
            return set()
        known = {u.name for u in job.units if u.available_at > 0.0}
        used = {a.execunit.strip("/") for a in plan.assignments}
        return (used & set(self.view.committed())) - known
