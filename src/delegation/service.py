"""The delegation service: an MQTT unit that turns partial trees into running missions.

Two layers:

* ``ServiceCore`` holds every decision and all state. It is fed raw messages, finished planning
  jobs and ticks, each with ``now``, and returns ``Effects``: messages to publish and planning jobs
  to run. No network, no threads, no clock, so it is tested message by message.
* ``DelegationService`` (an ``MqttUnit``) wires it to a broker: paho's thread enqueues, the unit's
  loop thread runs the core, and a planner thread runs ``run_job`` so that planning never blocks
  the receive path (a ``ping`` is answered while a tree is being planned).

Faces (DESIGN 3.2): the TST face on ``tst/command`` (a drop-in delegator: ``start-tst`` with a
partial tree, signals forwarded to the engine) and the Delegation API on ``delegation/command``.
Every command is answered once per com-uuid; a re-send gets the stored answer again (while the
first is still being planned, the one answer sent when ready serves both).

Payloads of ``delegation/response`` (besides ``com-uuid``, ``response-to``, ``response``,
``fail-reason``):

* ``delegate``: ``plan`` (DESIGN 3.5); ``response`` ``ok`` (planned only) or ``started`` (with
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

Planning runs on one planner thread, in arrival order: a long ``optimal`` plan delays the next
plan, never a ``ping``, a signal or feedback.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from delegation.allocation import OBJECTIVES, STRATEGIES, plan_mission
from delegation.costs import cost_tables
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
    HeartBeat,
    ListAgents,
    ListMissions,
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
    encode,
    new_com_uuid,
)
from delegation.messages.answers import com_uuid_of
from delegation.missions import (
    CommandEntry,
    CommandLog,
    CommandState,
    LifecycleEvent,
    Mission,
    MissionBook,
    MissionStatus,
    node_infos,
)
from delegation.runtime.mqtt import Message
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.unit import MqttUnit
from delegation.topics import (
    DEFAULT_PREFIX,
    QOS_COMMAND,
    QOS_PERIODIC,
    parse_unit_topic,
    unit_base_topic,
)
from delegation.tst.node import TstNode, leaves, walk, where, with_uuids
from delegation.tst.validate import parse_and_validate, with_defaults

log = logging.getLogger(__name__)

Face = Literal["tst", "delegation"]
CmdKey = tuple[str, str]

#: Topic of the internal "a planning job finished" wake-up (``$`` topics never come from a broker
#: subscription with wildcards, and the service subscribes to none).
_JOB_DONE_TOPIC = "$delegation/job-done"


@dataclass(frozen=True, slots=True)
class ServiceConfig:
    """How the service names itself, finds its engine and plans by default."""

    name: str = "delegator0"
    prefix: str = DEFAULT_PREFIX
    agent_type: str = "ground"
    role: str = "simulation"
    engine: str = "op0"
    strategy: str = "auction"
    objective: str = "makespan"
    time_limit: float = 2.0
    #: The longest ``time-limit`` a ``delegate`` may ask for (plans run one at a time).
    max_time_limit: float = 60.0
    #: Seconds to wait for the engine's answer before a command is answered ``failed``.
    engine_timeout: float = 15.0
    #: Heartbeat / info rate (Hz).
    rate: float = 1.0
    #: Fleet profiles for what heartbeats do not carry (speeds, endurance, ...); see ``fleet``.
    profiles: dict[str, dict[str, Any]] | None = None

    @property
    def base_topic(self) -> str:
        return unit_base_topic(self.name, self.agent_type, self.role, self.prefix)


@dataclass(frozen=True, slots=True)
class Outgoing:
    """A message to publish."""

    topic: str
    payload: bytes
    qos: int = QOS_COMMAND


@dataclass(slots=True)
class Job:
    """Work for the planner thread: a plan (``delegate``, ``start-tst``) or bids (``get-bids``)."""

    id: int
    kind: Literal["plan", "bids"]
    key: CmdKey
    face: Face
    tree: TstNode
    units: tuple[UnitState, ...]
    strategy: str
    objective: str
    time_limit: float
    engine: str
    start: bool
    source: str
    received: float
    #: Seconds the planner thread spent on it (set there; for timings).
    compute_seconds: float = 0.0

    @property
    def com_uuid(self) -> str:
        """The com-uuid of the command the job answers."""
        return self.key[1]


@dataclass(slots=True)
class Effects:
    """What the core wants done: messages to publish and jobs to run."""

    publish: list[Outgoing] = field(default_factory=list)
    jobs: list[Job] = field(default_factory=list)

    def extend(self, other: Effects) -> Effects:
        self.publish.extend(other.publish)
        self.jobs.extend(other.jobs)
        return self


@dataclass(slots=True)
class EngineRequest:
    """A command the service sent to the engine and whose answer someone is waiting for."""

    kind: Literal["start", "signal", "cancel"]
    key: CmdKey
    face: Face
    deadline: float
    root_uuid: str = ""
    plan: dict[str, Any] | None = None

    @property
    def caller_com_uuid(self) -> str:
        """The com-uuid of the caller's command, which the engine's answer completes."""
        return self.key[1]


@dataclass(frozen=True, slots=True)
class Timing:
    """When a mission's command arrived and when its instantiated tree left for the engine, and
    how much of that the planner itself took."""

    root_uuid: str
    received: float
    sent: float
    planning: float


# --------------------------------------------------------------------------- planning jobs


def run_job(job: Job) -> Any:
    """Run one job (on the planner thread): a ``Plan``, a list of bids, or an ``InputError``."""
    try:
        if job.kind == "bids":
            return compute_bids(job.tree, job.units)
        return plan_mission(
            job.tree,
            job.units,
            strategy=job.strategy,
            objective=job.objective,
            time_limit=job.time_limit,
            engine_unit=job.engine,
        )
    except InputError as exc:
        return exc
    except Exception as exc:  # a planner bug must not kill the service: answer it
        log.exception("planning job %s failed", job.id)
        return InputError(Problem("planner", "", f"internal error: {type(exc).__name__}: {exc}"))


def compute_bids(tree: TstNode, units: Sequence[UnitState]) -> list[dict[str, Any]]:
    """Every task node x unit: estimated travel, work and distance, or why the unit cannot bid."""
    tasks = leaves(with_defaults(tree))
    if not tasks or not units:
        return []
    tables = cost_tables(units, tasks)
    to_start = tables.dist_unit_to_start()
    bids: list[dict[str, Any]] = []
    for t, task in enumerate(tables.tasks):
        for u, unit in enumerate(tables.units):
            base = {"node-uuid": task.node_uuid, "name": task.name, "unit": f"/{unit.name}"}
            if not tables.capable[u, t]:
                bids.append({**base, "reason": tables.reason(u, t) or "cannot take this task"})
                continue
            travel = float(to_start[u, t])  # 0 for tasks done in place
            bids.append({
                **base,
                "travel-time": round(travel / float(tables.speed[u, t]), 3),
                "work-time": round(float(tables.work_time[u, t]), 3),
                "distance": round(travel + float(tables.work_distance[u, t]), 3),
                "open-ended": bool(tables.open_ended[t]),
            })
    return bids


def _infeasible_reason(plan: Any, tree: TstNode) -> str:
    """A fail-reason naming every node the plan could not give a unit (path, name, uuid) and
    why."""
    paths = {node.node_uuid: where(path, node) for path, node in walk(tree) if node.node_uuid}
    parts = [f"{paths.get(u.node_uuid, f'{u.name} {u.node_uuid}')}: {u.reason}"
             for u in plan.unassigned]
    return "cannot instantiate the tree: " + ("; ".join(parts) or "no feasible plan")


# --------------------------------------------------------------------------- the core


class ServiceCore:
    """Every decision of the delegation service, fed with messages and ``now``."""

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
        self.agent_uuid = agent_uuid or str(uuid.uuid4())
        self.pending: dict[str, EngineRequest] = {}  # engine com-uuid -> request
        self.timings: deque[Timing] = deque(maxlen=10_000)
        self._job_ids = 0
        base = self.config.base_topic
        self.tst_command_topic = f"{base}/tst/command"
        self.delegation_command_topic = f"{base}/delegation/command"
        self.tst_response_topic = f"{base}/tst/response"
        self.tst_feedback_topic = f"{base}/tst/feedback"
        self.delegation_response_topic = f"{base}/delegation/response"
        self.delegation_feedback_topic = f"{base}/delegation/feedback"

    # ------------------------------------------------------------------ inputs

    def subscriptions(self) -> list[str]:
        """The filters the service listens on."""
        p = self.config.prefix
        e = self.config.engine
        return [
            self.tst_command_topic,
            self.delegation_command_topic,
            f"{p}/unit/+/+/+/heartbeat",
            f"{p}/unit/+/+/+/direct_execution_info",
            f"{p}/unit/+/+/+/sensor_info",
            f"{p}/unit/+/+/+/sensor/#",
            f"{p}/unit/+/+/{e}/tst/response",
            f"{p}/unit/+/+/{e}/tst/feedback",
        ]

    def on_message(self, topic: str, payload: bytes, now: float) -> Effects:
        """One message from the broker."""
        if topic == self.tst_command_topic:
            return self._command("tst", topic, payload, now)
        if topic == self.delegation_command_topic:
            return self._command("delegation", topic, payload, now)
        parsed = parse_unit_topic(topic)
        if parsed is None or parsed.name == self.config.name:
            return Effects()
        if parsed.name == self.config.engine and parsed.rest in ("tst/response", "tst/feedback"):
            return self._from_engine(topic, payload, parsed.rest, now)
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
        """The engine's base topic (from its heartbeat) while the heartbeat is fresh, else None."""
        if not self.fleet.is_alive(self.config.engine, now):
            return None
        return self.fleet.base_topic(self.config.engine)

    def _engine_problem(self, now: float) -> str | None:
        if self.engine_base(now) is None:
            return (
                f"no TST engine {self.config.engine!r} is live on the broker "
                f"(no recent heartbeat under {self.config.prefix}/unit/+/+/{self.config.engine})"
            )
        return None

    def agents(self, now: float) -> list[dict[str, Any]]:
        """The live units for ``list-agents`` (those that can be delegated to)."""
        names = {u.name for u in self.units(now)}
        return [row for row in self.fleet.agents(now, alive_only=True) if row["name"] in names]

    # ------------------------------------------------------------------ commands

    def _command(self, face: Face, topic: str, payload: bytes, now: float) -> Effects:
        try:
            cmd: WireModel | None = decode(topic, payload)
        except MessageError as exc:
            cmd, error = None, exc
        com_uuid = getattr(cmd, "com_uuid", None) if cmd is not None else com_uuid_of(payload)
        key: CmdKey | None = (face, com_uuid) if com_uuid else None
        if key is not None:
            entry = self.commands.seen(key)
            if entry is not None:
                return self._resend(entry)
            self.commands.begin(key, now)
        if cmd is None:
            log.info("bad command on %s: %s", topic, error)
            return self._fail(face, key, com_uuid or "", error.fail_reason)
        assert key is not None  # a decoded command always has a com-uuid
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
        return Effects(publish=[Outgoing(t, p) for t, p in entry.answer])

    def _answer(self, key: CmdKey | None, out: Outgoing) -> Effects:
        """Publish the answer to a command once; remember it for re-sends."""
        if key is None:
            return Effects(publish=[out])
        if not self.commands.finish(key, [(out.topic, out.payload)]):
            return Effects()
        return Effects(publish=[out])

    def _respond(self, face: Face, key: CmdKey | None, response: WireModel) -> Effects:
        topic = self.tst_response_topic if face == "tst" else self.delegation_response_topic
        return self._answer(key, Outgoing(topic, encode(response)))

    def _fail(self, face: Face, key: CmdKey | None, com_uuid: str, reason: str) -> Effects:
        if face == "tst":
            return self._respond(
                face, key, TstResponse(response="failed", response_to=com_uuid, fail_reason=reason)
            )
        return self._respond(
            face,
            key,
            DelegationResponse(response="failed", response_to=com_uuid, fail_reason=reason),
        )

    # ---- TST face

    def _tst_command(self, cmd: WireModel, key: CmdKey, now: float) -> Effects:
        if isinstance(cmd, StartTst):
            return self._plan_job(
                "tst", key, cmd.tst, now, strategy=None, objective=None, time_limit=None,
                start=True, source="tst",
            )
        if isinstance(cmd, SignalTstNode | SignalTstTree):
            mission = self.book.of_node(cmd.node_uuid)
            if mission is None:
                raise InputError(
                    Problem(
                        cmd.command,
                        "node-uuid",
                        f"{cmd.node_uuid!r} is not a node of any mission of {self.config.name}",
                    )
                )
            model: WireModel = type(cmd)(
                node_uuid=cmd.node_uuid, signal=cmd.signal, sender=self.config.name
            )
            return self._to_engine("signal", key, "tst", model, now, mission.root_uuid)
        if isinstance(cmd, SignalUnit):
            model = SignalUnit(unit=cmd.unit, signal=cmd.signal, sender=self.config.name)
            return self._to_engine("signal", key, "tst", model, now)
        if isinstance(cmd, Ping):
            return self._respond("tst", key, TstResponse(response="pong", response_to=key[1]))
        name = getattr(cmd, "command", "?")
        raise InputError(Problem("tst/command", "command", f"{name!r} is not supported"))

    # ---- Delegation API

    def _delegation_command(self, cmd: WireModel, key: CmdKey, now: float) -> Effects:
        def ok(**payload: Any) -> DelegationResponse:
            return DelegationResponse(response="ok", response_to=key[1], **payload)

        if isinstance(cmd, DelegationPing | Ping):
            return self._respond("delegation", key, DelegationResponse(response="pong",
                                                                       response_to=key[1]))
        if isinstance(cmd, Delegate):
            return self._plan_job(
                "delegation", key, cmd.tst, now, strategy=cmd.strategy, objective=cmd.objective,
                time_limit=cmd.time_limit, start=cmd.start, source="delegate",
            )
        if isinstance(cmd, GetBids):
            return self._plan_job(
                "delegation", key, cmd.tst, now, strategy=None, objective=None, time_limit=None,
                start=False, source="bids", kind="bids",
            )
        if isinstance(cmd, QueryMission):
            mission = self.book.get(cmd.root_uuid)
            return self._respond("delegation", key,
                                 ok(mission=mission.to_json()))
        if isinstance(cmd, ListMissions):
            missions = [m.summary() for m in self.book]
            return self._respond("delegation", key, ok(missions=missions))
        if isinstance(cmd, ListAgents):
            return self._respond("delegation", key,
                                 ok(agents=self.agents(now)))
        if isinstance(cmd, CancelMission):
            return self._cancel(cmd, key, now)
        raise InputError(Problem("delegation/command", "command",
                                 f"{getattr(cmd, 'command', '?')!r} is not supported"))

    def _cancel(self, cmd: CancelMission, key: CmdKey, now: float) -> Effects:
        mission = self.book.get(cmd.root_uuid)
        if mission.ended:
            raise InputError(Problem("cancel-mission", "root-uuid",
                                     f"mission {cmd.root_uuid} already ended "
                                     f"({mission.status.value})"))
        starting = any(r.kind == "start" and r.root_uuid == mission.root_uuid
                       for r in self.pending.values())
        if mission.status is MissionStatus.PLANNED and not starting:
            out = self._respond("delegation", key,
                                DelegationResponse(response="ok", response_to=key[1]))
            return out.extend(self._set_status(mission.root_uuid, MissionStatus.ABORTED, now,
                                               "cancelled before it started"))
        model = SignalTstTree(node_uuid=mission.root_uuid, signal="$abort",
                              sender=self.config.name)
        return self._to_engine("cancel", key, "delegation", model, now, mission.root_uuid)

    # ---- planning

    def _plan_job(
        self,
        face: Face,
        key: CmdKey,
        raw_tree: dict[str, Any],
        now: float,
        *,
        strategy: str | None,
        objective: str | None,
        time_limit: float | None,
        start: bool,
        source: str,
        kind: Literal["plan", "bids"] = "plan",
    ) -> Effects:
        strategy = strategy or self.config.strategy
        objective = objective or self.config.objective
        if strategy not in STRATEGIES:
            raise InputError(Problem("command", "strategy",
                                     f"unknown strategy {strategy!r}; expected one of "
                                     f"{', '.join(STRATEGIES)}"))
        if objective not in OBJECTIVES:
            raise InputError(Problem("command", "objective",
                                     f"unknown objective {objective!r}; expected one of "
                                     f"{', '.join(OBJECTIVES)}"))
        if time_limit is not None and time_limit > self.config.max_time_limit:
            raise InputError(Problem("command", "time-limit",
                                     f"{time_limit:g} s is above this service's maximum of "
                                     f"{self.config.max_time_limit:g} s"))
        tree = with_uuids(parse_and_validate(raw_tree))
        if kind == "plan":
            conflicts = self.book.conflicts(tree)
            if conflicts:
                raise InputError(conflicts)
            if start:
                problem = self._engine_problem(now)
                if problem:
                    raise InputError(Problem("engine", "", problem))
        self._job_ids += 1
        job = Job(
            id=self._job_ids,
            kind=kind,
            key=key,
            face=face,
            tree=tree,
            units=self.units(now),
            strategy=strategy,
            objective=objective,
            time_limit=time_limit or self.config.time_limit,
            engine=self.config.engine,
            start=start,
            source=source,
            received=entry.received if (entry := self.commands.get(key)) else now,
        )
        return Effects(jobs=[job])

    def on_job_done(self, job: Job, result: Any, now: float) -> Effects:
        """A planning job finished (result from ``run_job``)."""
        if isinstance(result, InputError):
            return self._fail(job.face, job.key, job.com_uuid, result.fail_reason)
        if job.kind == "bids":
            return self._respond(job.face, job.key, DelegationResponse(
                response="ok", response_to=job.com_uuid, bids=list(result)))
        plan = result
        plan_json = plan.to_json()
        if not plan.feasible:
            reason = _infeasible_reason(plan, job.tree)
            if job.face == "tst":
                return self._fail("tst", job.key, job.com_uuid, reason)
            return self._respond("delegation", job.key, DelegationResponse(
                response="failed", response_to=job.com_uuid, fail_reason=reason, plan=plan_json))
        tree = plan.tst
        root_uuid = tree.node_uuid or ""
        conflicts = self.book.conflicts(tree)
        if conflicts:  # a twin command with the same tree was planned meanwhile
            return self._fail(job.face, job.key, job.com_uuid, InputError(conflicts).fail_reason)
        mission = Mission(
            root_uuid=root_uuid,
            source=job.source,
            created=now,
            tst=plan_json["tst"],
            plan=plan_json,
            nodes=node_infos(tree),
        )
        self.book.add(mission)
        effects = self._lifecycle([LifecycleEvent(root_uuid, MissionStatus.PLANNED)])
        if not job.start:
            return effects.extend(self._respond("delegation", job.key, DelegationResponse(
                response="ok", response_to=job.com_uuid, plan=plan_json)))
        problem = self._engine_problem(now)
        if problem:
            effects.extend(self._set_status(root_uuid, MissionStatus.FAILED, now, problem))
            return effects.extend(self._fail(job.face, job.key, job.com_uuid, problem))
        start = StartTst(receiver=self.config.engine, sender=self.config.name, tst=plan_json["tst"])
        effects.extend(self._to_engine("start", job.key, job.face, start, now, root_uuid,
                                       plan=plan_json))
        self.timings.append(Timing(root_uuid, job.received, now, job.compute_seconds))
        return effects

    # ---- the engine

    def _to_engine(
        self,
        kind: Literal["start", "signal", "cancel"],
        key: CmdKey,
        face: Face,
        model: WireModel,
        now: float,
        root_uuid: str = "",
        plan: dict[str, Any] | None = None,
    ) -> Effects:
        base = self.engine_base(now)
        if base is None:
            raise InputError(Problem("engine", "", self._engine_problem(now) or "no engine"))
        com = getattr(model, "com_uuid", "") or new_com_uuid()
        self.pending[com] = EngineRequest(
            kind=kind,
            key=key,
            face=face,
            deadline=now + self.config.engine_timeout,
            root_uuid=root_uuid,
            plan=plan,
        )
        return Effects(publish=[Outgoing(f"{base}/tst/command", encode(model))])

    def _from_engine(self, topic: str, payload: bytes, rest: str, now: float) -> Effects:
        try:
            message = decode(topic, payload)
        except MessageError as exc:
            log.warning("unreadable message from the engine on %s: %s", topic, exc)
            return Effects()
        if isinstance(message, TstFeedback):
            return self._engine_feedback(message, now)
        if isinstance(message, TstResponse):
            return self._engine_response(message, now)
        return Effects()

    def _engine_feedback(self, fb: TstFeedback, now: float) -> Effects:
        mission, events = self.book.observe_feedback(
            fb.node_uuid, fb.status, fb.root_flag, fb.fail_reason, now
        )
        if mission is None:
            return Effects()  # a tree someone else gave the engine
        relay = TstFeedback(node_uuid=fb.node_uuid, root_flag=fb.root_flag, status=fb.status,
                            fail_reason=fb.fail_reason)
        effects = Effects(publish=[Outgoing(self.tst_feedback_topic, encode(relay))])
        return effects.extend(self._lifecycle(events))

    def _engine_response(self, resp: TstResponse, now: float) -> Effects:
        req = self.pending.pop(resp.response_to, None)
        if req is None:
            return Effects()
        engine = self.config.engine
        if req.kind == "start":
            if resp.response == "started":
                effects = self._set_status(req.root_uuid, MissionStatus.STARTED, now)
                if req.face == "tst":
                    answer: WireModel = TstResponse(response="started",
                                                    response_to=req.caller_com_uuid,
                                                    root_uuid=req.root_uuid)
                else:
                    answer = DelegationResponse(response="started",
                                                response_to=req.caller_com_uuid, plan=req.plan)
                return effects.extend(self._respond(req.face, req.key, answer))
            reason = f"engine {engine} refused the tree: {resp.fail_reason or resp.response}"
            effects = self._set_status(req.root_uuid, MissionStatus.FAILED, now, reason)
            return effects.extend(self._fail(req.face, req.key, req.caller_com_uuid, reason))
        if req.kind == "cancel":
            if resp.response == "ok":
                return self._respond(req.face, req.key,
                                     DelegationResponse(response="ok",
                                                        response_to=req.caller_com_uuid))
            reason = f"engine {engine} did not abort: {resp.fail_reason or resp.response}"
            return self._fail(req.face, req.key, req.caller_com_uuid, reason)
        # a forwarded signal: pass the engine's answer on
        if resp.response == "failed":
            return self._fail(req.face, req.key, req.caller_com_uuid,
                              f"engine {engine}: {resp.fail_reason}")
        return self._respond(req.face, req.key,
                             TstResponse(response=resp.response, response_to=req.caller_com_uuid))

    # ------------------------------------------------------------------ ticks and status

    def on_tick(self, now: float) -> Effects:
        """Expire engine requests that were never answered."""
        effects = Effects()
        for com, req in list(self.pending.items()):
            if now < req.deadline:
                continue
            del self.pending[com]
            reason = (f"engine {self.config.engine} did not answer within "
                      f"{self.config.engine_timeout:g} s")
            if req.kind == "start":
                effects.extend(self._set_status(req.root_uuid, MissionStatus.FAILED, now, reason))
            effects.extend(self._fail(req.face, req.key, req.caller_com_uuid, reason))
        return effects

    def status_messages(self, now: float) -> list[Outgoing]:
        """Heartbeat, ``tst_execution_info`` and ``delegation_info`` (periodic, QoS 0)."""
        c = self.config
        base = c.base_topic
        active = [m.root_uuid for m in self.book if not m.ended
                  and m.status is not MissionStatus.PLANNED]
        heartbeat = HeartBeat(agent_type=c.agent_type, agent_uuid=self.agent_uuid,
                              levels=["tst execution", "delegation"], name=c.name, rate=c.rate,
                              stamp=now)
        tst_info = TstExecutionInfo(name=c.name, rate=c.rate, stamp=now, trees_executing=active)
        info = DelegationInfo(name=c.name, rate=c.rate, stamp=now, strategies=list(STRATEGIES),
                              objectives=list(OBJECTIVES), missions_active=len(active))
        return [
            Outgoing(f"{base}/heartbeat", encode(heartbeat), QOS_PERIODIC),
            Outgoing(f"{base}/tst_execution_info", encode(tst_info), QOS_PERIODIC),
            Outgoing(f"{base}/delegation_info", encode(info), QOS_PERIODIC),
        ]

    def _set_status(
        self, root_uuid: str, status: MissionStatus, now: float, fail_reason: str = ""
    ) -> Effects:
        """Move a mission on (`MissionBook.set_status`) and publish the change, if any."""
        event = self.book.set_status(root_uuid, status, now, fail_reason)
        return self._lifecycle([event] if event else [])

    def _lifecycle(self, events: Iterable[LifecycleEvent]) -> Effects:
        out = [
            Outgoing(
                self.delegation_feedback_topic,
                encode(DelegationFeedback(root_uuid=e.root_uuid, status=e.status.value,
                                          fail_reason=e.fail_reason)),
            )
            for e in events
        ]
        for e in events:
            log.info("mission %s %s%s", e.root_uuid, e.status.value,
                     f": {e.fail_reason}" if e.fail_reason else "")
        return Effects(publish=out)


# --------------------------------------------------------------------------- the MQTT unit


class DelegationService(MqttUnit):
    """The service on a broker: the core on the unit's thread, planning on a planner thread.

    ``planner`` runs a job on the planner thread (``run_job``; tests pass one they can hold).
    """

    def __init__(
        self,
        settings: BrokerSettings,
        config: ServiceConfig | None = None,
        planner: Callable[[Job], Any] = run_job,
    ) -> None:
        self.config = config or ServiceConfig()
        self._run_job = planner
        super().__init__(settings, self.config.name, tick_interval=0.2, clock=time.time)
        self.core = ServiceCore(self.config)
        self._jobs: queue.Queue[Job | None] = queue.Queue()
        self._done: queue.Queue[tuple[Job, Any]] = queue.Queue()
        self._planner: threading.Thread | None = None
        self._next_status = 0.0
        self._ready = threading.Condition()
        self._engine_live = False
        self._agents_seen: frozenset[str] = frozenset()

    def subscriptions(self) -> Iterable[str]:
        return self.core.subscriptions()

    # ---- lifecycle hooks (unit thread)

    def on_start(self) -> None:
        self._planner = threading.Thread(target=self._plan_loop, name=f"{self.name}-planner",
                                         daemon=True)
        self._planner.start()
        self._publish_status(self.clock())
        log.info("%s serving on %s (engine %s)", self.name, self.config.base_topic,
                 self.config.engine)

    def on_stop(self) -> None:
        self._jobs.put(None)
        if self._planner is not None:
            self._planner.join(10.0)
            self._planner = None

    def handle(self, message: Message) -> None:
        now = self.clock()
        if message.topic == _JOB_DONE_TOPIC:
            while True:
                try:
                    job, result = self._done.get_nowait()
                except queue.Empty:
                    break
                self._apply(self.core.on_job_done(job, result, self.clock()))
            return
        self._apply(self.core.on_message(message.topic, message.payload, now))
        if not self._engine_live and self.core.engine_base(now) is not None:
            self._update_ready(now)

    def tick(self, now: float) -> None:
        if now >= self._next_status:
            self._publish_status(now)
        self._apply(self.core.on_tick(now))
        self._update_ready(now)

    def _update_ready(self, now: float) -> None:
        with self._ready:
            self._engine_live = self.core.engine_base(now) is not None
            self._agents_seen = frozenset(u.name for u in self.core.units(now) if u.alive)
            self._ready.notify_all()

    # ---- helpers

    def _publish_status(self, now: float) -> None:
        self._next_status = now + 1.0 / self.config.rate
        for out in self.core.status_messages(now):
            self.client_publish(out)

    def _apply(self, effects: Effects) -> None:
        for out in effects.publish:
            self.client_publish(out)
        for job in effects.jobs:
            self._jobs.put(job)

    def client_publish(self, out: Outgoing) -> None:
        self.publish(out.topic, out.payload, qos=out.qos)

    def _plan_loop(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            began = time.perf_counter()
            result = self._run_job(job)
            job.compute_seconds = time.perf_counter() - began
            self._done.put((job, result))
            self.call_soon(Message(_JOB_DONE_TOPIC, b""))

    # ---- readiness (any thread)

    def wait_ready(
        self, units: Iterable[str] = (), timeout: float = 10.0, engine: bool = True
    ) -> bool:
        """Wait until the named units (and the engine, with ``engine``) are live as the service
        sees them."""
        wanted = set(units)
        with self._ready:
            return self._ready.wait_for(
                lambda: (self._engine_live or not engine) and wanted <= self._agents_seen, timeout
            )

    @property
    def timings(self) -> list[Timing]:
        """Arrival -> sent-to-engine timestamps per mission (read from another thread: a copy)."""
        while True:
            try:
                return list(self.core.timings)
            except RuntimeError:  # appended to while copying: copy again
                continue


def serve(settings: BrokerSettings, config: ServiceConfig, stop: threading.Event) -> None:
    """Run the service until ``stop`` is set (the CLI sets it on Ctrl-C)."""
    service = DelegationService(settings, config)
    service.start()
    try:
        stop.wait()
    finally:
        service.stop()


__all__ = [
    "DelegationService",
    "Effects",
    "Job",
    "Outgoing",
    "ServiceConfig",
    "ServiceCore",
    "Timing",
    "compute_bids",
    "run_job",
    "serve",
]
