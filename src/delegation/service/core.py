"""Every decision of the delegation service, fed with messages, ticks, finished jobs and ``now``.

Faces (docs/protocol.md §4-§6): the TST face on ``tst/command`` (a drop-in delegator:
``start-tst`` with a partial tree, signals forwarded to the engine) and the Delegation API on
``delegation/command``. Every command is answered once per com-uuid; a re-send gets the stored
answer again (while the first is still being planned, the one answer sent when ready serves both).

Payloads of ``delegation/response`` (besides ``com-uuid``, ``response-to``, ``response``,
``fail-reason``):

* ``delegate``: ``plan`` (docs/plan.md §1); ``response`` ``ok`` (planned only) or ``started`` (with
  ``start``, once the engine accepted the tree); an infeasible tree is ``failed`` with the plan.
* ``get-bids``: ``bids``, one per task node x unit: ``node-uuid``, ``name``, ``unit`` and either
  ``travel-time``/``work-time`` (s), ``distance`` (m), ``open-ended``, or ``reason``.
* ``query-mission``: ``mission``: ``root-uuid``, ``name``, ``source``, ``status``,
  ``fail-reason``, ``created``/``started``/``ended`` (epoch s), ``nodes`` (``node-uuid``, ``name``,
  ``execunit``, ``path``, ``status``, ``started``/``ended`` in s since the mission started),
  ``assignments``, ``unassigned``, ``makespan``, ``strategy``, ``notes`` (the plan's), ``tst``
  (the instantiated tree, so that a client can re-attach).
* ``list-missions``: ``missions``: the summary fields above, oldest first, a page of ``limit``
  from ``offset``; ``total`` and ``next`` (the next page's offset, null on the last).
* ``list-agents``: ``agents``: the fleet registry's rows (``name``, ``type``, ``position``,
  ``tasks-available``, ``last-seen``, ``busy``/``state``, ``battery``, ...) plus the ``speeds``
  the service plans with and their ``speeds-source`` (``learnt``/``profile``/``default``).
* ``cancel-mission``: ``ok`` once the abort is confirmed (the engine reported the tree's root
  ``aborted``); ``pending`` (with the reason) when the engine accepted the ``$abort`` but did not
  confirm it within ``cancel_timeout``; ``failed`` if the mission ended otherwise first. With no
  live engine the mission is ended ``aborted`` at once, saying so.

Faults (docs/protocol.md §11): a unit lost (heartbeat stopped, or a new agent-uuid) or
answering ``failed`` has its unfinished tasks re-delegated (`delegation.service.redelegation`); an
engine restarted is given the unfinished part of each tree again, a lost one is waited for
(``engine_return_timeout``); after its own restart or reconnect the service asks the engine about
every open mission before judging it (`delegation.service.catch_up`). ``now`` is monotonic (every
timeout); mission records are stamped in epoch seconds from the ``stamp`` of `status` (``now`` +
offset).

Planning is a job (`Effects.jobs`) the unit runs on its worker, in arrival order: a long
``optimal`` plan delays the next plan, never a ``ping``, a signal or feedback. The tree and the
options are validated once on the service's path, so bad input is answered at once.

The core dispatches; each decision lives in one part it composes: reading and answering commands
(`commands`), the fleet as planned with (`fleet_view`), planning jobs (`planning`), the engine's
feedback and answers and cancels (`engine_use`), re-delegation and lost engines (`repair`),
catching up after restarts and outages (`catch_up`), mission status publishing (`lifecycle`).
"""

from __future__ import annotations

import logging
import uuid
from collections import deque
from collections.abc import Iterable
from dataclasses import replace
from typing import Any

from delegation.errors import InputError, InputProblem
from delegation.fleet import FleetEventKind, FleetRegistry, UnitState
from delegation.learning import SpeedLearner
from delegation.messages import (
    CancelMission,
    Delegate,
    DelegationPing,
    DelegationResponse,
    GetBids,
    ListAgents,
    ListMissions,
    Ping,
    QueryMission,
    SignalTstNode,
    SignalTstTree,
    SignalUnit,
    StartTst,
    TstResponse,
    WireModel,
)
from delegation.runtime.commands import CommandKey, CommandLog
from delegation.runtime.core import Effects, Identified, JobDone, Outgoing
from delegation.service.access import client_of
from delegation.service.cancels import Cancels
from delegation.service.catch_up import CatchUp
from delegation.service.commands import CommandDesk, Topics
from delegation.service.config import ServiceConfig
from delegation.service.engine_link import EngineLink
from delegation.service.engine_use import EngineUse
from delegation.service.faces import Face
from delegation.service.fleet_view import FleetView
from delegation.service.jobs import BidsDone, Job, JobFailed, JobResult, PlanDone, internal_error
from delegation.service.lifecycle import LEVELS, Epoch, Lifecycle, status_messages
from delegation.service.missions import MissionBook
from delegation.service.offers import OfferDesk
from delegation.service.planning import Planning, Timing
from delegation.service.repair import Repair
from delegation.service.unit_catch_up import UnitCatchUp
from delegation.topics import parse_unit_topic

log = logging.getLogger(__name__)

__all__ = ["LEVELS", "ServiceCore", "Timing"]


class ServiceCore(Identified):
    """Every decision of the delegation service (a `JobCore`: planning runs as jobs); who it is
    on the broker (``name``, ``status_period``, ...) comes from its `Identity`, which its config
    makes (`ServiceConfig.identity`)."""

    def __init__(
        self,
        config: ServiceConfig | None = None,
        fleet: FleetRegistry | None = None,
        agent_uuid: str | None = None,
    ) -> None:
        c = self.config = config or ServiceConfig()
        self.fleet = fleet or FleetRegistry(profiles=c.profiles,
                                            min_timeout=c.min_heartbeat_timeout,
                                            max_timeout=c.max_heartbeat_timeout)
        self.engine = EngineLink(c, self.fleet)
        self.identity = c.identity(agent_uuid or str(uuid.uuid4()))
        self._offline_since: float | None = None
        #: When this core first heard anything (its listening began), and the planning commands
        #: that arrived before the engine and a round of heartbeats were heard (``listen_round``),
        #: held until they are or ``listen_first`` passed.
        self._listening_since: float | None = None
        self._held: list[tuple[Face, WireModel, CommandKey]] = []
        #: Jobs handed to the planner whose results have not come back (`ServiceConfig.
        #: planner_queue` bounds the ones commands add).
        self.planner_jobs = 0
        #: Start plans waiting for the one being made (`Planning.holds_units`): each is handed
        #: out when the one before it is done, with the units as they are then.
        self._start_queue: deque[Job] = deque()
        self._start_running = False
        #: ``now`` as epoch seconds (the offset learnt from `status`): mission records' stamps.
        self._epoch = Epoch()
        self.topics = Topics.under(c.base_topic)
        book = MissionBook()
        self.desk = CommandDesk(c, CommandLog(), self.topics)
        self.view = FleetView(c, self.fleet, book, self.engine, self._epoch)
        self.lifecycle = Lifecycle(book, self.desk, Cancels(c.engine, c.cancel_timeout),
                                   self._epoch)
        shared = (c, book, self.desk, self.view, self.engine, self.lifecycle)
        self.offers = OfferDesk(c, self.fleet)
        self.planning = Planning(*shared, offers=self.offers)
        self.catch_up = CatchUp(*shared)
        self.repair = Repair(*shared, planning=self.planning, catch_up=self.catch_up)
        self.unit_catch_up = UnitCatchUp(*shared)
        self.engine_use = EngineUse(*shared, repair=self.repair, catch_up=self.catch_up,
                                    units=self.unit_catch_up)

    @property
    def book(self) -> MissionBook:
        """Every mission (the unit swaps in one backed by its store)."""
        return self.view.book

    @book.setter
    def book(self, book: MissionBook) -> None:
        for part in (self.view, self.lifecycle, self.planning, self.catch_up, self.repair,
                     self.engine_use, self.unit_catch_up):
            part.book = book

    @property
    def commands(self) -> CommandLog:
        """Every command by (face, com-uuid) (the unit swaps in one backed by its store)."""
        return self.desk.commands

    @commands.setter
    def commands(self, log: CommandLog) -> None:
        self.desk.commands = log

    @property
    def timings(self) -> deque[Timing]:
        """When each mission's command arrived and its tree left for the engine."""
        return self.planning.timings

    @timings.setter
    def timings(self, timings: deque[Timing]) -> None:
        self.planning.timings = timings

    @property
    def learner(self) -> SpeedLearner:
        """Speeds learnt from the units' flights (`delegation.learning`)."""
        return self.view.learner

    @property
    def tst_response_topic(self) -> str:
        return self.topics.tst_response

    @property
    def delegation_response_topic(self) -> str:
        return self.topics.delegation_response

    # ------------------------------------------------------------------ fleet views

    def units(self, now: float) -> tuple[UnitState, ...]:
        """The units to plan for, with learnt speeds (`FleetView.units`)."""
        return self.view.units(now)

    def agents(self, now: float) -> list[dict[str, Any]]:
        """The live units for ``list-agents``."""
        return self.view.agents(now)

    def ready(self, units: Iterable[str], engine: bool, now: float) -> bool:
        """True once the named units (and the engine, with ``engine``) are live as seen here."""
        return self.view.ready(units, engine, now)

    def plannable(
        self, now: float, exclude: Iterable[str] = (), mission: str = ""
    ) -> tuple[tuple[UnitState, ...], tuple[str, ...]]:
        """The units to plan a mission with, and notes naming those left out
        (`FleetView.plannable`)."""
        return self.view.plannable(now, exclude, mission)

    # ------------------------------------------------------------------ inputs

    def subscriptions(self) -> list[str]:
        """The filters the service listens on (the command topics also per client)."""
        p = self.config.prefix
        return [
            self.topics.tst_command,
            self.topics.delegation_command,
            f"{self.topics.tst_command}/+",
            f"{self.topics.delegation_command}/+",
            f"{p}/unit/+/+/+/heartbeat",
            f"{p}/unit/+/+/+/direct_execution_info",
            f"{p}/unit/+/+/+/delegation_info",
            f"{p}/unit/+/+/+/sensor_info",
            f"{p}/unit/+/+/+/sensor/#",
            f"{p}/unit/+/+/+/exec/command",  # our engine's start-tasks (`UnitCatchUp`)
            f"{p}/unit/+/+/+/exec/response",
            *self.engine.subscriptions(),
            *self.offers.subscriptions(),
        ]

    def _listening(self, now: float) -> None:
        """The first message or tick: the missions the store gave this instance (it restarted)
        are caught up with before they are judged (`CatchUp`)."""
        if self._listening_since is None:
            self._listening_since = now
            self.catch_up.want_open()

    def on_message(self, topic: str, payload: bytes, now: float) -> Effects:
        """One message from the broker (a command on a shared or a per-client command topic)."""
        self._listening(now)
        effects = self._message(topic, payload, now)
        return self._counted(effects.extend(self._release_held(now)) if self._held else effects,
                             now)

    def _counted(self, effects: Effects, now: float) -> Effects:
        """Count the jobs ``effects`` hands to the planner (each comes back as one `JobDone`);
        start plans that hold units go one at a time (`Planning.holds_units`), the others wait
        in order (a `Job.deferred` one handed out at once reads the fleet now)."""
        self.planner_jobs += len(effects.jobs)
        if not any(self.planning.holds_units(j) for j in effects.jobs if isinstance(j, Job)):
            return effects
        jobs = []
        for job in effects.jobs:
            if not (isinstance(job, Job) and self.planning.holds_units(job)):
                jobs.append(job)
            elif self._start_running:
                self._start_queue.append(job)
            else:
                self._start_running = True
                jobs.append(self.planning.refreshed(job, now) if job.deferred else job)
        effects.jobs = jobs
        return effects

    def _next_start(self, done: JobDone, now: float) -> list[Job]:
        """The next waiting start plan, with the units as they are now, once ``done`` ended the
        one being made."""
        if not (isinstance(done.job, Job) and self.planning.holds_units(done.job)):
            return []
        self._start_running = bool(self._start_queue)
        return [self.planning.refreshed(self._start_queue.popleft(), now)] \
            if self._start_queue else []

    def _message(self, topic: str, payload: bytes, now: float) -> Effects:
        faces: tuple[tuple[Face, str], ...] = (("tst", self.topics.tst_command),
                                               ("delegation", self.topics.delegation_command))
        for face, command_topic in faces:
            if topic == command_topic:
                return self._command(face, payload, now)
            client = client_of(topic, command_topic)
            if client is not None:
                return self._command(face, payload, now, client)
        if len(payload) > self.config.max_payload:
            log.debug("ignoring %s: %d bytes", topic, len(payload))
            return Effects()
        parsed = parse_unit_topic(topic)
        if parsed is None or parsed.name == self.config.name:
            return Effects()
        if parsed.name == self.config.engine and parsed.rest in ("tst/response", "tst/feedback"):
            return self.engine_use.receive(topic, payload, now)
        if self.offers.is_answer(topic):
            return Effects(jobs=self.offers.receive(topic, payload, now))
        if parsed.rest in ("exec/command", "exec/response"):
            return self.engine_use.from_unit(parsed.name, parsed.rest, topic, payload, now)
        self.view.observe(topic, payload, now)
        return self._fleet_events(now)

    def on_tick(self, now: float) -> Effects:
        """Engine commands never answered, catching up, the lost engine waited for, cancels'
        deadlines, units lost."""
        self._listening(now)
        self.view.log_silent(now)
        effects = self._release_held(now) if self._held else Effects()
        effects.extend(self.engine_use.units_expired(now))  # before a silent engine asks again
        for got in self.engine.expire(now):
            effects.extend(self.engine_use.answer(got, now))
        if self._offline_since is None:
            effects.extend(self.repair.engine_wait(now))
            effects.extend(self.catch_up.queries(now))
        effects.extend(self.lifecycle.cancel_deadlines(now))
        effects.jobs.extend(self.offers.expire(now))
        if self._offline_since is None:  # nobody is lost while we cannot hear them
            self.fleet.check(now)
        return self._counted(effects.extend(self._fleet_events(now)), now)

    def on_disconnect(self, now: float) -> Effects:
        """Our own connection to the broker is lost: stop judging liveness until it is back."""
        self._offline_since = now
        return Effects()

    def on_reconnect(self, now: float) -> Effects:
        """Back on the broker: every unit and the engine get a full timeout from now to be heard
        again (they reconnect too); whoever is not is lost then. What the engine published
        meanwhile never arrives (clean sessions): every open mission is asked about."""
        self._offline_since = None
        self.fleet.grace(now, self.config.reconnect_grace)
        self.catch_up.want_open()
        return Effects()

    def status(self, now: float, stamp: float) -> list[Outgoing]:
        """Heartbeat, ``tst_execution_info`` and ``delegation_info`` (periodic, QoS 0)."""
        self._epoch.offset = stamp - now
        return status_messages(self.config, self.identity, self.book, stamp,
                               self.view.summary(now))

    def _fleet_events(self, now: float) -> Effects:
        """What the registry noticed: a lost or rebooted unit re-delegates, a lost or restarted
        engine ends its missions (consumed here: events would otherwise pile up)."""
        effects = Effects()
        for event in self.fleet.drain_events():
            log.info("unit %s %s", event.name, event.kind.value)
            if event.kind is FleetEventKind.APPEARED:
                continue
            if event.name == self.config.engine:
                effects.extend(self.repair.engine_gone(event, now))
            else:
                effects.extend(self._with_delegators(self.repair.unit_lost(event, now), now))
        return effects

    def _with_delegators(self, effects: Effects, now: float) -> Effects:
        """Re-delegation jobs learn which units are delegators (their subtrees stay with them,
        docs/protocol.md §15.4)."""
        names = frozenset(d.name for d in self.fleet.delegators(now, alive_only=False))
        if names:
            effects.jobs = [replace(j, delegators=names) if isinstance(j, Job) else j
                            for j in effects.jobs]
        return effects

    def _command(self, face: Face, payload: bytes, now: float, client: str | None = None
                 ) -> Effects:
        arrival = self.desk.arrive(face, payload, now, client)
        if arrival.effects is not None or arrival.command is None:
            return arrival.effects or Effects()
        key = arrival.key
        plans = isinstance(arrival.command, StartTst | Delegate | GetBids)
        if plans and self.planner_jobs >= self.config.planner_queue:
            return self.desk.turn_away(face, key, InputError(InputProblem(
                "planner", "", f"busy: {self.planner_jobs} plans are waiting or being made (at "
                f"most {self.config.planner_queue}); nothing was accepted: send the command "
                "again later")).fail_reason)
        if self._warming(now) and plans:
            log.info("command %s on %s held until the engine %s and a round of heartbeats "
                     "are heard (at most %.1f s)", key[1], face, self.config.engine,
                     self.config.listen_first)
            self._held.append((face, arrival.command, key))
            return Effects()
        return self._act(face, arrival.command, key, now)

    def _warming(self, now: float) -> bool:
        """True while the service has just begun listening (within ``listen_first``) and has not
        heard its engine yet, or not yet one round of its peers' heartbeats (``listen_round``)."""
        since = self._listening_since
        return (since is not None and now < since + self.config.listen_first
                and (self.engine.base(now) is None or now < since + self.config.listen_round))

    def _release_held(self, now: float) -> Effects:
        """Act on the held commands, in arrival order, once the engine is heard or the wait ends."""
        if self._warming(now):
            return Effects()
        held, self._held = self._held, []
        effects = Effects()
        for face, command, key in held:
            effects.extend(self._act(face, command, key, now))
        return effects

    def _act(self, face: Face, command: WireModel, key: CommandKey, now: float) -> Effects:
        try:
            if face == "tst":
                return self._tst_command(command, key, now)
            return self._delegation_command(command, key, now)
        except InputError as exc:
            return self.desk.fail(face, key, key[1], exc.fail_reason)

    def _tst_command(self, cmd: WireModel, key: CommandKey, now: float) -> Effects:
        if isinstance(cmd, StartTst):
            return self.planning.job("tst", key, cmd.tst, now,
                                     self.planning.options(None, None, None),
                                     start=True, source="tst", waits=self._start_running)
        if isinstance(cmd, SignalTstNode | SignalTstTree | SignalUnit):
            return self.engine_use.signal(cmd, key, now)
        if isinstance(cmd, Ping):
            return self.desk.respond("tst", key, TstResponse(response="pong", response_to=key[1]))
        name = getattr(cmd, "command", "?")
        raise InputError(InputProblem("tst/command", "command", f"{name!r} is not supported"))

    def _delegation_command(self, cmd: WireModel, key: CommandKey, now: float) -> Effects:
        def ok(**payload: Any) -> Effects:
            return self.desk.respond("delegation", key,
                                     DelegationResponse(response="ok", response_to=key[1],
                                                        **payload))

        if isinstance(cmd, DelegationPing | Ping):
            return self.desk.respond("delegation", key, DelegationResponse(response="pong",
                                                                           response_to=key[1]))
        if isinstance(cmd, Delegate):
            options = self.planning.options(cmd.strategy, cmd.objective, cmd.time_limit,
                                            cmd.split)
            return self.planning.job("delegation", key, cmd.tst, now, options,
                                     start=cmd.start and not cmd.preview,
                                     source="preview" if cmd.preview else "delegate",
                                     preview_id=cmd.preview_id, waits=self._start_running)
        if isinstance(cmd, GetBids):
            return self.planning.job("delegation", key, cmd.tst, now,
                                     self.planning.options(None, None, None),
                                     start=False, source="bids", kind="bids")
        if isinstance(cmd, QueryMission):
            return ok(mission=self.desk.authorise(cmd.command, self.book.get(cmd.root_uuid),
                                                  key).to_json())
        if isinstance(cmd, ListMissions):  # a page of the caller's own (an operator: every one)
            missions, total = self.desk.missions_page(self.book, key, cmd.offset, cmd.limit)
            end = cmd.offset + len(missions)
            return ok(missions=missions, total=total, next=end if end < total else None)
        if isinstance(cmd, ListAgents):
            return ok(agents=self.view.agents(now))
        if isinstance(cmd, CancelMission):
            return self.engine_use.cancel(cmd, key, now)
        raise InputError(InputProblem("delegation/command", "command",
                                      f"{getattr(cmd, 'command', '?')!r} is not supported"))

    def on_job_done(self, done: JobDone, now: float) -> Effects:
        """A planning job finished: answer it, and with ``start`` send the tree to the engine."""
        self.planner_jobs = max(0, self.planner_jobs - 1)
        effects = self._counted(self._job_done(done, now), now)
        effects.jobs.extend(self._next_start(done, now))  # counted when it came
        return effects

    def _job_done(self, done: JobDone, now: float) -> Effects:
        job: Job = done.job
        result: JobResult = (done.result if isinstance(done.result, PlanDone | BidsDone | JobFailed)
                             else internal_error(done.result))
        if job.redelegate:
            return self.repair.redelegated(job, result, now)
        if isinstance(result, JobFailed):
            return self.desk.fail(job.face, job.key, job.com_uuid, result.reason)
        if isinstance(result, BidsDone):
            return self.desk.respond(job.face, job.key, DelegationResponse(
                response="ok", response_to=job.com_uuid, bids=list(result.bids)))
        return self.planning.planned(job, result.plan, now, done.seconds)
