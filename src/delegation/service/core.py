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
  ``assignments``, ``unassigned``, ``makespan``, ``strategy``.
* ``list-missions``: ``missions``: the summary fields above.
* ``list-agents``: ``agents``: the fleet registry's rows (``name``, ``type``, ``position``,
  ``tasks-available``, ``last-seen``, ``busy``/``state``, ``battery``, ...).
* ``cancel-mission``: ``ok`` once the engine confirmed the ``$abort`` of the tree.

Planning is a job (`Effects.jobs`) the unit runs on its worker, in arrival order: a long
``optimal`` plan delays the next plan, never a ``ping``, a signal or feedback. The tree and the
options are validated here, once on the service's path, so bad input is answered at once.
"""

from __future__ import annotations

import logging
import uuid
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Literal

from delegation.allocation import OBJECTIVES, STRATEGIES
from delegation.errors import InputError, MessageError, Problem
from delegation.fleet import FleetRegistry, UnitState
from delegation.messages import (
    CancelMission,
    Delegate,
    DelegationFeedback,
    DelegationInfo,
    DelegationPing,
    DelegationResponse,
    GetBids,
    ListAgents,
    ListMissions,
    MissionStatus,
    Ping,
    QueryMission,
    SignalTstNode,
    SignalTstTree,
    SignalUnit,
    StartTst,
    TstExecutionInfo,
    TstFeedback,
    TstResponse,
    WireModel,
    decode,
    parse_command,
)
from delegation.messages.errors import json_value
from delegation.runtime.commands import (
    CommandEntry,
    CommandKey,
    CommandLog,
    CommandState,
    com_uuid_of,
    payload_digest,
)
from delegation.runtime.core import Effects, JobDone, Outgoing, heartbeat
from delegation.service.access import Caller, caller_of, client_of, may_manage, refusal
from delegation.service.config import ServiceConfig
from delegation.service.engine_link import EngineAnswer, EngineLink
from delegation.service.faces import Face, failure
from delegation.service.jobs import (
    BidsDone,
    Job,
    JobFailed,
    JobResult,
    PlanDone,
    PlanOptions,
    infeasible_reason,
    internal_error,
    plan_options,
)
from delegation.service.missions import LifecycleEvent, Mission, MissionBook, node_infos
from delegation.topics import QOS_PERIODIC, parse_unit_topic
from delegation.tst.node import with_uuids
from delegation.tst.validate import parse_and_validate

log = logging.getLogger(__name__)

#: The levels the service's heartbeat announces.
LEVELS = ("tst execution", "delegation")


@dataclass(frozen=True, slots=True)
class Timing:
    """When a mission's command arrived and when its instantiated tree left for the engine, and
    how much of that the planner itself took."""

    root_uuid: str
    received: float
    sent: float
    planning: float


class ServiceCore:
    """Every decision of the delegation service (a `JobCore`: planning runs as jobs)."""

    def __init__(
        self,
        config: ServiceConfig | None = None,
        fleet: FleetRegistry | None = None,
        agent_uuid: str | None = None,
    ) -> None:
        self.config = config or ServiceConfig()
        self.fleet = fleet or FleetRegistry(profiles=self.config.profiles)
        self.book = MissionBook()
        self.commands = CommandLog()
        self.engine = EngineLink(self.config, self.fleet)
        self.identity = self.config.identity(agent_uuid or str(uuid.uuid4()))
        self.timings: deque[Timing] = deque(maxlen=10_000)
        self._job_ids = 0
        base = self.config.base_topic
        self.tst_command_topic = f"{base}/tst/command"
        self.delegation_command_topic = f"{base}/delegation/command"
        self.tst_response_topic = f"{base}/tst/response"
        self.tst_feedback_topic = f"{base}/tst/feedback"
        self.delegation_response_topic = f"{base}/delegation/response"
        self.delegation_feedback_topic = f"{base}/delegation/feedback"

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def status_period(self) -> float:
        return 1.0 / self.config.rate

    @property
    def agent_uuid(self) -> str:
        return self.identity.agent_uuid

    # ------------------------------------------------------------------ inputs

    def subscriptions(self) -> list[str]:
        """The filters the service listens on (the command topics also per client)."""
        p = self.config.prefix
        return [
            self.tst_command_topic,
            self.delegation_command_topic,
            f"{self.tst_command_topic}/+",
            f"{self.delegation_command_topic}/+",
            f"{p}/unit/+/+/+/heartbeat",
            f"{p}/unit/+/+/+/direct_execution_info",
            f"{p}/unit/+/+/+/sensor_info",
            f"{p}/unit/+/+/+/sensor/#",
            *self.engine.subscriptions(),
        ]

    def on_message(self, topic: str, payload: bytes, now: float) -> Effects:
        """One message from the broker (a command on a shared or a per-client command topic)."""
        faces: tuple[tuple[Face, str], ...] = (("tst", self.tst_command_topic),
                                               ("delegation", self.delegation_command_topic))
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
            return self._from_engine(topic, payload, now)
        self._observe_fleet(topic, payload, now)
        return Effects()

    def _observe_fleet(self, topic: str, payload: bytes, now: float) -> None:
        """Units, and the engine: the registry knows every heartbeat's base topic and age, and
        plans only for units on the direct execution level."""
        try:
            message = decode(topic, payload)
        except MessageError as exc:
            log.debug("ignoring %s: %s", topic, exc)
            return
        try:
            self.fleet.observe(topic, message, now)
        except InputError as exc:
            log.debug("fleet ignored %s: %s", topic, exc)
        # Consume what the registry noticed (it would otherwise pile up in a long-running service).
        for event in self.fleet.drain_events():
            log.info("unit %s %s", event.name, event.kind.value)

    # ------------------------------------------------------------------ fleet views

    def units(self, now: float) -> tuple[UnitState, ...]:
        """The units to plan for (the registry leaves out engines and delegators)."""
        return tuple(self.fleet.snapshot(now))

    def engine_base(self, now: float) -> str | None:
        """The engine's base topic while its heartbeat is fresh, else None."""
        return self.engine.base(now)

    def agents(self, now: float) -> list[dict[str, Any]]:
        """The live units for ``list-agents`` (those that can be delegated to)."""
        names = {u.name for u in self.units(now)}
        return [row for row in self.fleet.agents(now, alive_only=True) if row["name"] in names]

    def ready(self, units: Iterable[str], engine: bool, now: float) -> bool:
        """True once the named units (and the engine, with ``engine``) are live as seen here."""
        if engine and self.engine_base(now) is None:
            return False
        return set(units) <= {u.name for u in self.units(now) if u.alive}

    # ------------------------------------------------------------------ commands

    def _read_command(
        self, face: Face, payload: bytes, client: str | None
    ) -> tuple[WireModel | None, MessageError | InputError | None, str | None, Caller]:
        """(command or None, why not, its com-uuid if readable, its caller). Size first, so that
        nothing of an oversized payload is parsed or kept; the com-uuid is bounded."""
        where, limit = f"{face}/command", self.config.max_payload
        response_base = self.tst_response_topic if face == "tst" else self.delegation_response_topic
        caller = Caller(client or "", f"{response_base}/{client}" if client else "")
        if len(payload) > limit:
            return (None, MessageError(Problem(where, "", f"{len(payload)} bytes is more than "
                                                          f"the {limit} allowed")),
                    com_uuid_of(payload, max_bytes=limit), caller)
        data: Any = None
        cmd: WireModel | None = None
        error: MessageError | InputError | None = None
        try:
            data = json_value(payload, where)
            cmd = parse_command(data, face)
        except MessageError as exc:
            error = exc
        com_uuid = getattr(cmd, "com_uuid", None) if cmd is not None else com_uuid_of(payload)
        try:
            caller = caller_of(where, data if isinstance(data, dict) else None, client,
                               response_base)
        except InputError as exc:
            cmd, error = None, exc
        return cmd, error, com_uuid, caller

    def _command(self, face: Face, payload: bytes, now: float, client: str | None = None
                 ) -> Effects:
        cmd, error, com_uuid, caller = self._read_command(face, payload, client)
        key: CommandKey | None = (face, com_uuid) if com_uuid else None
        if key is not None:
            digest = payload_digest(payload, self.config.max_payload)
            entry = self.commands.seen(key)
            if entry is not None and not entry.same_command(digest):
                log.info("com-uuid %s reused for a different command", key[1])
                reason = f"{face}/command: com-uuid: {key[1]!r} reused for a different command"
                return self._respond(face, None, failure(face, key[1], reason),
                                     caller.reply_topic)
            if entry is not None:
                return self._resend(entry)
            entry = self.commands.begin(key, now, digest)
            entry.caller, entry.reply_topic = caller.name, caller.reply_topic
        if cmd is None or key is None:
            reason = error.fail_reason if error is not None else f"{face}/command: unreadable"
            log.info("bad command on %s/command: %s", face, reason)
            return self._fail(face, key, com_uuid or "", reason, caller.reply_topic)
        try:
            if face == "tst":
                return self._tst_command(cmd, key, now)
            return self._delegation_command(cmd, key, now)
        except InputError as exc:
            return self._fail(face, key, key[1], exc.fail_reason)

    def _resend(self, entry: CommandEntry) -> Effects:
        """A command seen before: its stored answer again, or nothing while it is being worked on
        (the answer goes out once ready and serves every copy)."""
        if entry.state is CommandState.PENDING:
            log.info("re-sent command %s is still being worked on", entry.key[1])
            return Effects()
        log.info("re-sent command %s: answering again", entry.key[1])
        return Effects.of(entry.answer)

    def _respond(
        self, face: Face, key: CommandKey | None, response: WireModel, reply_topic: str = ""
    ) -> Effects:
        """Publish the answer to a command once, on its caller's response topic; remember it for
        re-sends."""
        entry = self.commands.get(key) if key is not None else None
        topic = (entry.reply_topic if entry is not None else reply_topic) or (
            self.tst_response_topic if face == "tst" else self.delegation_response_topic)
        out = Outgoing.of(topic, response)
        if key is not None and not self.commands.finish(key, [out]):
            return Effects()
        return Effects(publish=[out])

    def _fail(self, face: Face, key: CommandKey | None, com_uuid: str, reason: str,
              reply_topic: str = "") -> Effects:
        return self._respond(face, key, failure(face, com_uuid, reason), reply_topic)

    # ---- who may do what (service.access)

    def _caller(self, key: CommandKey) -> str:
        entry = self.commands.get(key)
        return entry.caller if entry is not None else ""

    def _may_manage(self, mission: Mission, key: CommandKey) -> bool:
        return may_manage(mission.owner, self._caller(key), self.config.operators)

    def _authorise(self, command: str, mission: Mission, key: CommandKey) -> Mission:
        """The mission, if the caller may touch it; else ``InputError`` saying whose it is."""
        if not self._may_manage(mission, key):
            caller = self._caller(key)
            log.warning("refused %s of mission %s (owner %r) to %r", command, mission.root_uuid,
                        mission.owner, caller)
            raise refusal(command, mission.root_uuid, mission.owner, caller)
        return mission

    # ---- TST face

    def _tst_command(self, cmd: WireModel, key: CommandKey, now: float) -> Effects:
        if isinstance(cmd, StartTst):
            return self._plan_job("tst", key, cmd.tst, now, self._options(None, None, None),
                                  start=True, source="tst")
        if isinstance(cmd, SignalTstNode | SignalTstTree):
            mission = self.book.of_node(cmd.node_uuid)
            if mission is None:
                raise InputError(Problem(
                    cmd.command, "node-uuid",
                    f"{cmd.node_uuid!r} is not a node of any mission of {self.config.name}"))
            self._authorise(cmd.command, mission, key)
            model: WireModel = type(cmd)(
                node_uuid=cmd.node_uuid, signal=cmd.signal, sender=self.config.name
            )
            return self._to_engine("signal", key, "tst", model, now, mission.root_uuid)
        if isinstance(cmd, SignalUnit):
            unit = cmd.unit.strip("/")
            for mission in self.book:
                if not mission.ended and any(n.execunit.strip("/") == unit
                                             for n in mission.nodes.values()):
                    self._authorise(cmd.command, mission, key)
            model = SignalUnit(unit=cmd.unit, signal=cmd.signal, sender=self.config.name)
            return self._to_engine("signal", key, "tst", model, now)
        if isinstance(cmd, Ping):
            return self._respond("tst", key, TstResponse(response="pong", response_to=key[1]))
        name = getattr(cmd, "command", "?")
        raise InputError(Problem("tst/command", "command", f"{name!r} is not supported"))

    # ---- Delegation API

    def _delegation_command(self, cmd: WireModel, key: CommandKey, now: float) -> Effects:
        def ok(**payload: Any) -> Effects:
            return self._respond("delegation", key,
                                 DelegationResponse(response="ok", response_to=key[1], **payload))

        if isinstance(cmd, DelegationPing | Ping):
            return self._respond("delegation", key, DelegationResponse(response="pong",
                                                                       response_to=key[1]))
        if isinstance(cmd, Delegate):
            options = self._options(cmd.strategy, cmd.objective, cmd.time_limit)
            return self._plan_job("delegation", key, cmd.tst, now, options,
                                  start=cmd.start, source="delegate")
        if isinstance(cmd, GetBids):
            return self._plan_job("delegation", key, cmd.tst, now, self._options(None, None, None),
                                  start=False, source="bids", kind="bids")
        if isinstance(cmd, QueryMission):
            return ok(mission=self._authorise(cmd.command, self.book.get(cmd.root_uuid),
                                              key).to_json())
        if isinstance(cmd, ListMissions):  # the caller's own (an operator: every one)
            return ok(missions=[m.summary() for m in self.book if self._may_manage(m, key)])
        if isinstance(cmd, ListAgents):
            return ok(agents=self.agents(now))
        if isinstance(cmd, CancelMission):
            return self._cancel(cmd, key, now)
        raise InputError(Problem("delegation/command", "command",
                                 f"{getattr(cmd, 'command', '?')!r} is not supported"))

    def _cancel(self, cmd: CancelMission, key: CommandKey, now: float) -> Effects:
        mission = self._authorise(cmd.command, self.book.get(cmd.root_uuid), key)
        if mission.ended:
            raise InputError(Problem("cancel-mission", "root-uuid",
                                     f"mission {cmd.root_uuid} already ended "
                                     f"({mission.status.value})"))
        if mission.status is MissionStatus.PLANNED and not self.engine.starting(mission.root_uuid):
            out = self._respond("delegation", key,
                                DelegationResponse(response="ok", response_to=key[1]))
            return out.extend(self._set_status(mission.root_uuid, MissionStatus.ABORTED, now,
                                               "cancelled before it started"))
        model = SignalTstTree(node_uuid=mission.root_uuid, signal="$abort",
                              sender=self.config.name)
        return self._to_engine("cancel", key, "delegation", model, now, mission.root_uuid)

    # ---- planning

    def _options(
        self, strategy: str | None, objective: str | None, time_limit: float | None
    ) -> PlanOptions:
        c = self.config
        return plan_options(strategy, objective, time_limit,
                            defaults=PlanOptions(c.strategy, c.objective, c.time_limit),
                            max_time_limit=c.max_time_limit)

    def _plan_job(
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
    ) -> Effects:
        """Validate the tree (once, here: a bad one is answered at once) and hand it to the
        planner as a job."""
        tree = with_uuids(parse_and_validate(raw_tree, self.config.limits))
        if kind == "plan":
            conflicts = self.book.conflicts(tree)
            if conflicts:
                raise InputError(conflicts)
            problem = self.engine.problem(now) if start else None
            if problem:
                raise InputError(Problem("engine", "", problem))
        self._job_ids += 1
        entry = self.commands.get(key)
        job = Job(id=self._job_ids, kind=kind, key=key, face=face, tree=tree,
                  units=self.units(now), options=options, engine=self.config.engine,
                  start=start, source=source, received=entry.received if entry else now,
                  limits=self.config.limits)
        return Effects(jobs=[job])

    def on_job_done(self, done: JobDone, now: float) -> Effects:
        """A planning job finished: answer it, and with ``start`` send the tree to the engine."""
        job: Job = done.job
        result: JobResult = (done.result if isinstance(done.result, PlanDone | BidsDone | JobFailed)
                             else internal_error(done.result))
        if isinstance(result, JobFailed):
            return self._fail(job.face, job.key, job.com_uuid, result.reason)
        if isinstance(result, BidsDone):
            return self._respond(job.face, job.key, DelegationResponse(
                response="ok", response_to=job.com_uuid, bids=list(result.bids)))
        plan = result.plan
        plan_json = plan.to_json()
        if not plan.feasible:
            reason = infeasible_reason(plan, job.tree)
            if job.face == "tst":
                return self._fail("tst", job.key, job.com_uuid, reason)
            return self._respond("delegation", job.key, DelegationResponse(
                response="failed", response_to=job.com_uuid, fail_reason=reason, plan=plan_json))
        conflicts = self.book.conflicts(plan.tst)
        if conflicts:  # a twin command with the same tree was planned meanwhile
            return self._fail(job.face, job.key, job.com_uuid, InputError(conflicts).fail_reason)
        root_uuid = plan.tst.node_uuid or ""
        self.book.add(Mission(root_uuid=root_uuid, source=job.source, created=now,
                              tst=plan_json["tst"], plan=plan_json, nodes=node_infos(plan.tst),
                              owner=self._caller(job.key)))
        effects = self._lifecycle([LifecycleEvent(root_uuid, MissionStatus.PLANNED)])
        if not job.start:
            return effects.extend(self._respond("delegation", job.key, DelegationResponse(
                response="ok", response_to=job.com_uuid, plan=plan_json)))
        problem = self.engine.problem(now)
        if problem:
            effects.extend(self._set_status(root_uuid, MissionStatus.FAILED, now, problem))
            return effects.extend(self._fail(job.face, job.key, job.com_uuid, problem))
        start = StartTst(receiver=self.config.engine, sender=self.config.name, tst=plan_json["tst"])
        effects.extend(self._to_engine("start", job.key, job.face, start, now, root_uuid,
                                       plan=plan_json))
        self.timings.append(Timing(root_uuid, job.received, now, done.seconds))
        return effects

    # ---- the engine

    def _to_engine(
        self,
        kind: Literal["start", "signal", "cancel"],
        key: CommandKey,
        face: Face,
        model: WireModel,
        now: float,
        root_uuid: str = "",
        plan: dict[str, Any] | None = None,
    ) -> Effects:
        """Send a command to the engine; the caller is answered when the engine answers."""
        return Effects(publish=[self.engine.send(kind, key, face, model, now, root_uuid, plan)])

    def _from_engine(self, topic: str, payload: bytes, now: float) -> Effects:
        got = self.engine.receive(topic, payload)
        if isinstance(got, TstFeedback):
            mission = self.book.of_node(got.node_uuid)
            if mission is not None and not self.engine.sent_from(mission.root_uuid, topic):
                log.warning("ignoring feedback on %s for %s: mission %s was sent to %s",
                            topic, got.node_uuid, mission.root_uuid,
                            self.engine.sent_to.get(mission.root_uuid, "no engine"))
                return Effects()
            return self._engine_feedback(got, now)
        if isinstance(got, EngineAnswer):
            return self._engine_answer(got, now)
        return Effects()

    def _engine_feedback(self, fb: TstFeedback, now: float) -> Effects:
        mission, events = self.book.observe_feedback(
            fb.node_uuid, fb.status, fb.root_flag, fb.fail_reason, now
        )
        if mission is None:
            return Effects()  # a tree someone else gave the engine
        relay = TstFeedback(node_uuid=fb.node_uuid, root_flag=fb.root_flag, status=fb.status,
                            fail_reason=fb.fail_reason)
        return Effects().send(self.tst_feedback_topic, relay).extend(self._lifecycle(events))

    def _engine_answer(self, got: EngineAnswer, now: float) -> Effects:
        """The mission moves on (if it does), then the caller gets its answer."""
        req = got.request
        effects = Effects()
        if got.mission_status is not None:
            effects.extend(self._set_status(req.root_uuid, got.mission_status, now,
                                            got.fail_reason))
        return effects.extend(self._respond(req.face, req.key, got.answer))

    # ------------------------------------------------------------------ ticks and status

    def on_tick(self, now: float) -> Effects:
        """Answer ``failed`` the engine commands that were never answered."""
        effects = Effects()
        for got in self.engine.expire(now):
            effects.extend(self._engine_answer(got, now))
        return effects

    def status(self, now: float, stamp: float) -> list[Outgoing]:
        """Heartbeat, ``tst_execution_info`` and ``delegation_info`` (periodic, QoS 0)."""
        c = self.config
        active = [m.root_uuid for m in self.book if not m.ended
                  and m.status is not MissionStatus.PLANNED]
        tst_info = TstExecutionInfo(name=c.name, rate=c.rate, stamp=stamp, trees_executing=active)
        info = DelegationInfo(name=c.name, rate=c.rate, stamp=stamp, strategies=list(STRATEGIES),
                              objectives=list(OBJECTIVES), missions_active=len(active))
        return [
            heartbeat(self.identity, LEVELS, stamp),
            Outgoing.of(self.identity.topic("tst_execution_info"), tst_info, QOS_PERIODIC),
            Outgoing.of(self.identity.topic("delegation_info"), info, QOS_PERIODIC),
        ]

    def _set_status(
        self, root_uuid: str, status: MissionStatus, now: float, fail_reason: str = ""
    ) -> Effects:
        """Move a mission on (`MissionBook.set_status`) and publish the change, if any."""
        event = self.book.set_status(root_uuid, status, now, fail_reason)
        return self._lifecycle([event] if event else [])

    def _lifecycle(self, events: Iterable[LifecycleEvent]) -> Effects:
        effects = Effects()
        for e in events:
            effects.send(self.delegation_feedback_topic,
                         DelegationFeedback(root_uuid=e.root_uuid, status=e.status.value,
                                            fail_reason=e.fail_reason))
            log.info("mission %s %s%s", e.root_uuid, e.status.value,
                     f": {e.fail_reason}" if e.fail_reason else "")
        return effects
