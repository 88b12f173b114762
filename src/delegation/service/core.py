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
engine lost or restarted fails its missions with the reason. ``now`` is monotonic (every timeout);
mission records are stamped in epoch seconds from the ``stamp`` of `status` (``now`` + offset).

Planning is a job (`Effects.jobs`) the unit runs on its worker, in arrival order: a long
``optimal`` plan delays the next plan, never a ``ping``, a signal or feedback. The tree and the
options are validated here, once on the service's path, so bad input is answered at once.
"""

from __future__ import annotations

import logging
import uuid
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Any, Literal

from delegation.allocation import OBJECTIVES, STRATEGIES
from delegation.errors import InputError, InputProblem, MessageError
from delegation.fleet import FleetEvent, FleetEventKind, FleetRegistry, UnitState
from delegation.geo import GeoPoint
from delegation.learning import SpeedLearner, input_warnings, speed_class
from delegation.messages import (
    FINAL_MISSION_STATUSES,
    TERMINAL_NODE_STATUSES,
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
from delegation.service.operator_view import OperatorView
from delegation.service.redelegation import (
    Remaining,
    first_origin,
    moved_tasks,
    remaining_tree,
    unfinished_on,
)
from delegation.topics import QOS_PERIODIC, parse_unit_topic
from delegation.tst.node import parse_tree, to_dict, walk, where, with_uuids
from delegation.tst.validate import parse_and_validate

log = logging.getLogger(__name__)

#: The levels the service's heartbeat announces.
LEVELS = ("tst execution", "delegation")
#: Node statuses after which a task no longer holds its unit.
TERMINAL = TERMINAL_NODE_STATUSES
#: How often a start plan is made again because a unit it uses got busy meanwhile.
MAX_REPLANS = 3
#: The `CommandKey` face of the service's own engine commands (re-delegation): never answered.
INTERNAL = "internal"


@dataclass(frozen=True, slots=True)
class Replan:
    """A re-delegation being planned: what remains, why, and the tree it replaces."""

    remaining: Remaining
    why: str
    old_root: str
    units: frozenset[str]


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
        self.fleet = fleet or FleetRegistry(profiles=self.config.profiles,
                                            min_timeout=self.config.min_heartbeat_timeout,
                                            max_timeout=self.config.max_heartbeat_timeout)
        self.book = MissionBook()
        self.commands = CommandLog()
        self.engine = EngineLink(self.config, self.fleet)
        self.identity = self.config.identity(agent_uuid or str(uuid.uuid4()))
        self.timings: deque[Timing] = deque(maxlen=10_000)
        #: Speeds learnt from the units' flights (`delegation.learning`).
        self.learner = SpeedLearner()
        self._task_class: dict[str, tuple[str, str]] = {}  # node-uuid -> (unit, speed class)
        self._alive: set[str] = set()  # units alive at the last tick (to log the silent ones)
        self._job_ids = 0
        self._replanned: dict[CommandKey, int] = {}
        self._replans: dict[str, Replan] = {}
        self._offline_since: float | None = None
        #: Cancels the engine accepted, waiting for the mission to end: root -> (key, deadline).
        self._cancels: dict[str, list[tuple[CommandKey, float]]] = {}
        #: Epoch seconds minus ``now`` (learnt from `status`): mission records are epoch stamps.
        self._epoch_offset = 0.0
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
        return self._fleet_events(now)

    def _epoch(self, now: float) -> float:
        """``now`` (monotonic) as epoch seconds, for mission records."""
        return now + self._epoch_offset

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
        if topic.endswith("/sensor/speed"):
            self._learn_speed(topic, message, now)

    def _fleet_events(self, now: float) -> Effects:
        """What the registry noticed: a lost or rebooted unit re-delegates, a lost or restarted
        engine ends its missions (consumed here: events would otherwise pile up)."""
        effects = Effects()
        for event in self.fleet.drain_events():
            log.info("unit %s %s", event.name, event.kind.value)
            if event.kind is FleetEventKind.APPEARED:
                continue
            if event.name == self.config.engine:
                effects.extend(self._engine_gone(event, now))
            else:
                effects.extend(self._unit_lost(event, now))
        return effects

    def _learn_speed(self, topic: str, message: Any, now: float) -> None:
        parsed = parse_unit_topic(topic)
        value = getattr(message, "value", message)
        if parsed is None or isinstance(value, bool) or not isinstance(value, int | float):
            return
        cls = self.learner.observe_speed(parsed.name, float(value), now)
        if cls is not None:
            log.info("unit %s: learnt its %s speed, %.2f m/s (plans use it from now on)",
                     parsed.name, cls, self.learner.learnt(parsed.name)[cls])

    # ------------------------------------------------------------------ fleet views

    def units(self, now: float) -> tuple[UnitState, ...]:
        """The units to plan for (the registry leaves out engines and delegators), with the
        speeds learnt from their flights."""
        return self.learner.apply(self.fleet.snapshot(now))

    def speed_sources(self, units: Iterable[UnitState]) -> dict[str, str]:
        """Per unit: ``learnt``, ``profile`` or ``default`` (`delegation.learning`)."""
        return {u.name: self.learner.source(u.name, self.fleet.has_profile_speeds(u.name))
                for u in units}

    def engine_base(self, now: float) -> str | None:
        """The engine's base topic while its heartbeat is fresh, else None."""
        return self.engine.base(now)

    def agents(self, now: float) -> list[dict[str, Any]]:
        """The live units for ``list-agents`` (those that can be delegated to)."""
        units = {u.name: u for u in self.units(now)}
        sources = self.speed_sources(units.values())
        return [{**row, "speeds": units[row["name"]].speeds, "speeds-source": sources[row["name"]]}
                for row in self.fleet.agents(now, alive_only=True) if row["name"] in units]

    def ready(self, units: Iterable[str], engine: bool, now: float) -> bool:
        """True once the named units (and the engine, with ``engine``) are live as seen here."""
        if engine and self.engine_base(now) is None:
            return False
        return set(units) <= {u.name for u in self.units(now) if u.alive}

    def plannable(
        self, now: float, exclude: Iterable[str] = (), mission: str = ""
    ) -> tuple[tuple[UnitState, ...], tuple[str, ...]]:
        """The units to plan a mission with, and notes naming those left out: battery below
        ``min_battery``, ``exclude`` (a lost or failing unit being re-delegated from). A unit busy
        in another running mission is planned from when and where it becomes free
        (``commitments: wait``, said in the notes), or left out (``exclude``, or when its end is
        not known)."""
        mode = self.config.commitments
        busy = self._committed(mission) if mode != "share" else {}
        skip = set(exclude)
        units: list[UnitState] = []
        notes: list[str] = []
        for unit in self.units(now):
            if unit.name in skip:
                notes.append(f"{unit.name}: left out (lost or failed a task of this mission)")
            elif unit.battery is not None and unit.battery < self.config.min_battery:
                notes.append(f"{unit.name}: left out, battery {unit.battery:.0%} is below "
                             f"{self.config.min_battery:.0%}")
            elif unit.name in busy:
                free = self._free_at(unit, busy[unit.name], now) if mode == "wait" else None
                if free is None:
                    notes.append(f"{unit.name}: left out, busy in mission {busy[unit.name]}")
                    continue
                units.append(replace(unit, available_at=free[0], position=free[1]))
                notes.append(f"{unit.name}: busy in mission {busy[unit.name]}, planned from when "
                             f"and where it becomes free (in {free[0]:.0f} s)")
            else:
                units.append(unit)
        return tuple(units), tuple(notes)

    def _free_at(self, unit: UnitState, root: str, now: float) -> tuple[float, GeoPoint] | None:
        """(seconds from now, position) when ``unit`` ends its last task in mission ``root``, by
        that mission's plan; None when the plan does not say (a re-delegated tree)."""
        m = self.book.find(root)
        if m is None:
            return None
        mine = [a for a in m.plan.get("assignments", [])
                if a.get("execunit") == unit.execunit and m.node_status.get(
                    a.get("node-uuid", "")) not in TERMINAL]
        if not mine or any(a.get("node-uuid") not in m.current_nodes for a in mine):
            return None
        last = max(mine, key=lambda a: float(a.get("end", 0.0)))
        began = m.started_at if m.started_at is not None else self._epoch(now)
        wait = max(0.0, began + float(last.get("end", 0.0)) - self._epoch(now))
        node = next((n for _, n in walk(parse_tree(m.current_tst))
                     if n.node_uuid == last.get("node-uuid")), None)
        points = ([node.params.get("waypoint")] if node is not None and node.name == "move-to"
                  else list(node.params.get("waypoints", [])) if node is not None
                  and node.name == "move-path" else [])
        try:
            where_then = GeoPoint.model_validate(points[-1]) if points else unit.position
        except ValueError:
            where_then = unit.position
        return wait, where_then

    def _committed(self, but: str = "") -> dict[str, str]:
        """Unit -> a running mission (other than ``but``) with a task on it not yet ended."""
        busy: dict[str, str] = {}
        for m in self.book:
            if m.ended or m.root_uuid == but:
                continue
            if m.status is MissionStatus.PLANNED and not self.engine.starting(m.root_uuid):
                continue  # planned only (start: false)
            for uid in m.current_nodes:
                info, status = m.nodes[uid], m.node_status.get(uid)
                if info.is_task and info.execunit and status not in TERMINAL:
                    busy.setdefault(info.execunit.strip("/"), m.root_uuid)
        return busy

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
            return (None, MessageError(InputProblem(where, "", f"{len(payload)} bytes is more than "
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
        log.info("command %s on %s refused: %s", com_uuid or "?", face, reason)
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
                raise InputError(InputProblem(
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
        raise InputError(InputProblem("tst/command", "command", f"{name!r} is not supported"))

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
                                  start=cmd.start and not cmd.preview,
                                  source="preview" if cmd.preview else "delegate")
        if isinstance(cmd, GetBids):
            return self._plan_job("delegation", key, cmd.tst, now, self._options(None, None, None),
                                  start=False, source="bids", kind="bids")
        if isinstance(cmd, QueryMission):
            return ok(mission=self._authorise(cmd.command, self.book.get(cmd.root_uuid),
                                              key).to_json())
        if isinstance(cmd, ListMissions):  # a page of the caller's own (an operator: every one)
            caller = self._caller(key)
            if caller in self.config.operators:
                missions, total = self.book.page(cmd.offset, cmd.limit)
            else:
                every, _ = self.book.page(0, 1 << 30)
                mine = [s for s in every if may_manage(str(s.get("owner") or ""), caller, ())]
                missions, total = mine[cmd.offset:cmd.offset + cmd.limit], len(mine)
            end = cmd.offset + len(missions)
            return ok(missions=missions, total=total, next=end if end < total else None)
        if isinstance(cmd, ListAgents):
            return ok(agents=self.agents(now))
        if isinstance(cmd, CancelMission):
            return self._cancel(cmd, key, now)
        raise InputError(InputProblem("delegation/command", "command",
                                 f"{getattr(cmd, 'command', '?')!r} is not supported"))

    def _cancel(self, cmd: CancelMission, key: CommandKey, now: float) -> Effects:
        mission = self._authorise(cmd.command, self.book.get(cmd.root_uuid), key)
        if mission.ended:
            raise InputError(InputProblem("cancel-mission", "root-uuid",
                                     f"mission {cmd.root_uuid} already ended "
                                     f"({mission.status.value})"))
        if mission.status is MissionStatus.PLANNED and not self.engine.starting(mission.root_uuid):
            out = self._respond("delegation", key,
                                DelegationResponse(response="ok", response_to=key[1]))
            return out.extend(self._set_status(mission.root_uuid, MissionStatus.ABORTED, now,
                                               "cancelled before it started"))
        problem = self.engine.problem(now)
        if problem or mission.redelegating:
            # Nothing to wait for: no engine runs the tree (or its replacement is not sent yet).
            why = f"cancelled ({problem})" if problem else "cancelled while re-delegating"
            out = self._respond("delegation", key,
                                DelegationResponse(response="ok", response_to=key[1]))
            replan = self._replans.pop(mission.root_uuid, None)
            if replan is not None:  # the old tree may still run on a live engine
                out.extend(self._abort_tree(replan.old_root, now))
            return out.extend(self._set_status(mission.root_uuid, MissionStatus.ABORTED, now,
                                               why))
        model = SignalTstTree(node_uuid=mission.current_root, signal="$abort",
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
                raise InputError(InputProblem("engine", "", problem))
        self._job_ids += 1
        entry = self.commands.get(key)
        units, notes = self.plannable(now) if kind == "plan" else (self.units(now), ())
        warnings = tuple(input_warnings(tree, units, self.fleet.names())) if kind == "plan" else ()
        for w in warnings:
            log.warning("mission %s: %s", tree.node_uuid, w)
        log.info("mission %s (%s) received on %s (%s%s): %d units to plan for", tree.node_uuid,
                 tree.name, face, source, ", start" if start else "", len(units))
        job = Job(id=self._job_ids, kind=kind, key=key, face=face, tree=tree,
                  units=units, options=options, engine=self.config.engine,
                  start=start, source=source, received=entry.received if entry else now,
                  speed_sources=self.speed_sources(units), warnings=warnings, notes=notes,
                  limits=self.config.limits)
        return Effects(jobs=[job])

    def on_job_done(self, done: JobDone, now: float) -> Effects:
        """A planning job finished: answer it, and with ``start`` send the tree to the engine."""
        job: Job = done.job
        result: JobResult = (done.result if isinstance(done.result, PlanDone | BidsDone | JobFailed)
                             else internal_error(done.result))
        if job.redelegate:
            return self._redelegated(job, result, now)
        if isinstance(result, JobFailed):
            return self._fail(job.face, job.key, job.com_uuid, result.reason)
        if isinstance(result, BidsDone):
            return self._respond(job.face, job.key, DelegationResponse(
                response="ok", response_to=job.com_uuid, bids=list(result.bids)))
        plan = result.plan
        plan_json = {**plan.to_json(), "notes": list(plan.notes)}
        clash = self._clash(plan, job) if job.start and plan.feasible else set()
        if clash and self._replanned.get(job.key, 0) < MAX_REPLANS:
            # A unit it uses got busy in a mission started meanwhile: plan again around it.
            self._replanned[job.key] = self._replanned.get(job.key, 0) + 1
            self._job_ids += 1
            units, notes = self.plannable(now)
            return Effects(jobs=[replace(job, id=self._job_ids, units=units, notes=notes)])
        self._replanned.pop(job.key, None)
        log.info("mission %s planned: %s/%s, %s, makespan %.0f s, units %s", plan.tst.node_uuid,
                 plan.strategy, plan.objective, "feasible" if plan.feasible else "infeasible",
                 plan.makespan or 0.0,
                 ", ".join(sorted({a.execunit for a in plan.assignments})) or "none")
        for note in plan.notes:
            log.info("mission %s: %s", plan.tst.node_uuid, note)
        if not plan.feasible:
            reason = infeasible_reason(plan, job.tree)
            log.info("mission %s refused: %s", plan.tst.node_uuid, reason)
            if job.face == "tst":
                return self._fail("tst", job.key, job.com_uuid, reason)
            return self._respond("delegation", job.key, DelegationResponse(
                response="failed", response_to=job.com_uuid, fail_reason=reason, plan=plan_json))
        if job.source == "preview":  # answered, never stored as a mission
            return self._respond("delegation", job.key, DelegationResponse(
                response="ok", response_to=job.com_uuid, plan=plan_json))
        conflicts = self.book.conflicts(plan.tst)
        if conflicts:  # a twin command with the same tree was planned meanwhile
            return self._fail(job.face, job.key, job.com_uuid, InputError(conflicts).fail_reason)
        root_uuid = plan.tst.node_uuid or ""
        self.book.add(Mission(root_uuid=root_uuid, source=job.source, created=self._epoch(now),
                              tst=plan_json["tst"], plan=plan_json,
                              nodes={**(node_infos(plan.source) if plan.source else {}),
                                     **node_infos(plan.tst)},
                              operator=(OperatorView.of(plan.source, plan.tst)
                                        if plan.source else None),
                              received=to_dict(job.tree), command=job.key,
                              owner=self._caller(job.key)))
        for _, node in walk(plan.tst):
            cls = speed_class(node)
            if cls and node.node_uuid and isinstance(node.execunit, str):
                self._task_class[node.node_uuid] = (node.execunit.strip("/"), cls)
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
        log.info("mission %s sent to engine %s", root_uuid, self.config.engine)
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
            bound = self.fleet.base_topic(self.config.engine)
            if mission is not None and not self.engine.sent_from(mission.root_uuid, topic, bound):
                log.warning("ignoring feedback on %s for %s: mission %s was sent to %s",
                            topic, got.node_uuid, mission.root_uuid,
                            self.engine.sent_to.get(mission.root_uuid, "no engine"))
                return Effects()
            return self._engine_feedback(got, now)
        if isinstance(got, EngineAnswer):
            return self._engine_answer(got, now)
        return Effects()

    def _engine_feedback(self, fb: TstFeedback, now: float) -> Effects:
        # A task failing on its unit is re-delegated (within its retry budget) before the
        # engine's root ``failed`` that follows could end the mission.
        retry = self._failed_task(fb)
        mission, events = self.book.observe_feedback(
            fb.node_uuid, fb.status, fb.root_flag, fb.fail_reason, self._epoch(now)
        )
        if mission is None:
            return Effects()  # a tree someone else gave the engine
        task = self._task_class.get(fb.node_uuid)
        if task is not None and fb.status == "running":
            self.learner.task_started(task[0], fb.node_uuid, task[1], now)
        elif task is not None and fb.status in TERMINAL_NODE_STATUSES:
            self.learner.task_ended(task[0], fb.node_uuid, now)
            del self._task_class[fb.node_uuid]
        effects = Effects()
        view = mission.operator
        if view is None or view.relayed(fb.node_uuid):  # leaves and kept nodes: unchanged
            effects.send(self.tst_feedback_topic, TstFeedback(
                node_uuid=fb.node_uuid, root_flag=fb.root_flag, status=fb.status,
                fail_reason=fb.fail_reason))
        if view is not None and view.relayed(fb.node_uuid):
            # The operator's control nodes the sent tree regrouped away: derived from their
            # children (docs/protocol.md §8).
            for uid, status in view.changes(fb.node_uuid, mission.node_status):
                effects.send(self.tst_feedback_topic, TstFeedback(
                    node_uuid=uid, root_flag=uid == view.root, status=status,
                    fail_reason=fb.fail_reason if status in ("failed", "aborted") else ""))
        effects.extend(self._lifecycle(events))
        if retry is not None:
            effects.extend(self._redelegate(mission, retry[0], retry[1], now))
        return effects

    def _failed_task(self, fb: TstFeedback) -> tuple[str, str] | None:
        """(unit, why) when ``fb`` is a task of a running mission's current tree failing on its
        unit with retry budget left, else None."""
        if fb.status != "failed":
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
        why = f"{info.path} ({info.name}) failed on /{unit}: {fb.fail_reason or 'failed'}"
        return unit, why

    def _engine_answer(self, got: EngineAnswer, now: float) -> Effects:
        """The mission moves on (if it does), then the caller gets its answer."""
        req = got.request
        effects = Effects()
        if got.mission_status is not None:
            effects.extend(self._set_status(req.root_uuid, got.mission_status, now,
                                            got.fail_reason))
        if req.key[0] == INTERNAL:
            return effects  # the service's own command (re-delegation): nobody to answer
        mission = self.book.find(req.root_uuid) if req.kind == "cancel" else None
        if mission is not None and not mission.ended \
                and getattr(got.answer, "response", "") == "ok":
            # Answered when the engine confirms (the root ends), or `pending` at the deadline.
            self._cancels.setdefault(req.root_uuid, []).append(
                (req.key, now + self.config.cancel_timeout))
            return effects
        return effects.extend(self._respond(req.face, req.key, got.answer))

    # ------------------------------------------------------------------ ticks and status

    def on_tick(self, now: float) -> Effects:
        """Answer ``failed`` the engine commands that were never answered."""
        self._log_silent(now)
        effects = Effects()
        for got in self.engine.expire(now):
            effects.extend(self._engine_answer(got, now))
        effects.extend(self._cancel_deadlines(now))
        if self._offline_since is None:  # nobody is lost while we cannot hear them
            self.fleet.check(now)
        return effects.extend(self._fleet_events(now))

    def on_disconnect(self, now: float) -> Effects:
        """Our own connection to the broker is lost: stop judging liveness until it is back."""
        self._offline_since = now
        return Effects()

    def on_reconnect(self, now: float) -> Effects:
        """Back on the broker: every unit and the engine get a full timeout from now to be heard
        again (they reconnect too); whoever is not is lost then."""
        self._offline_since = None
        self.fleet.grace(now, self.config.reconnect_grace)
        return Effects()

    def _log_silent(self, now: float) -> None:
        """Log the units whose heartbeat stopped (appearing and rebooting are logged as the
        registry notices them)."""
        alive = {u.name for u in self.fleet.snapshot(now) if u.alive}
        for name in sorted(self._alive - alive):
            seen = self.fleet.last_seen(name)
            ago = f" (last message {now - seen:.0f} s ago)" if seen is not None else ""
            log.warning("unit %s fell silent%s", name, ago)
        for name in sorted(alive - self._alive):
            log.debug("unit %s is live", name)
        self._alive = alive

    def status(self, now: float, stamp: float) -> list[Outgoing]:
        """Heartbeat, ``tst_execution_info`` and ``delegation_info`` (periodic, QoS 0)."""
        c = self.config
        self._epoch_offset = stamp - now
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
        event = self.book.set_status(root_uuid, status, self._epoch(now), fail_reason)
        return self._lifecycle([event] if event else [])

    def _cancel_deadlines(self, now: float) -> Effects:
        """Cancels whose abort the engine did not confirm in time: answered ``pending``."""
        effects = Effects()
        for root, waiting in list(self._cancels.items()):
            due = [(k, d) for k, d in waiting if d <= now]
            for key, _ in due:
                why = (f"$abort accepted by engine {self.config.engine} but not confirmed within "
                       f"{self.config.cancel_timeout:g} s; the mission ends when the engine "
                       f"reports it (query-mission)")
                effects.extend(self._respond("delegation", key, DelegationResponse(
                    response="pending", response_to=key[1], fail_reason=why)))
            rest = [w for w in waiting if w not in due]
            if rest:
                self._cancels[root] = rest
            else:
                del self._cancels[root]
        return effects

    def _cancels_answered(self, e: LifecycleEvent) -> Effects:
        """A mission ended: answer the cancels waiting for it."""
        effects = Effects()
        for key, _ in self._cancels.pop(e.root_uuid, []):
            if e.status is MissionStatus.ABORTED:
                answer = DelegationResponse(response="ok", response_to=key[1])
            else:
                answer = DelegationResponse(
                    response="failed", response_to=key[1],
                    fail_reason=f"mission {e.root_uuid} ended {e.status.value} before the "
                                f"abort took effect" + (f": {e.fail_reason}" if e.fail_reason
                                                        else ""))
            effects.extend(self._respond("delegation", key, answer))
        return effects

    def _lifecycle(self, events: Iterable[LifecycleEvent]) -> Effects:
        effects = Effects()
        for e in events:
            effects.send(self.delegation_feedback_topic,
                         DelegationFeedback(root_uuid=e.root_uuid, status=e.status.value,
                                            fail_reason=e.fail_reason))
            if e.status in FINAL_MISSION_STATUSES:
                effects.extend(self._cancels_answered(e))
            log.info("mission %s %s%s", e.root_uuid, e.status.value,
                     f": {e.fail_reason}" if e.fail_reason else "")
        return effects

    # ------------------------------------------------------------- faults (docs/protocol.md §11)

    def _engine_gone(self, event: FleetEvent, now: float) -> Effects:
        """The engine's heartbeat stopped, or it came back with a new agent-uuid: the trees it
        executed are gone with it, so its missions end ``failed`` saying so (never a wait)."""
        engine = self.config.engine
        if event.kind is FleetEventKind.LOST:
            why = f"engine {engine} lost (no heartbeat): the trees it executed are gone"
        else:
            why = f"engine {engine} restarted (new agent-uuid): the trees it executed are gone"
        effects = Effects()
        for m in self.book:
            if m.ended or m.status is MissionStatus.PLANNED:
                continue
            self._replans.pop(m.root_uuid, None)
            effects.extend(self._set_status(m.root_uuid, MissionStatus.FAILED, now, why))
        return effects

    def _unit_lost(self, event: FleetEvent, now: float) -> Effects:
        """A unit lost or rebooted: re-delegate its unfinished tasks in every running mission."""
        why = (f"/{event.name} lost (no heartbeat)" if event.kind is FleetEventKind.LOST
               else f"/{event.name} rebooted (new agent-uuid): its tasks are gone")
        effects = Effects()
        for m in self.book:
            if m.ended or m.redelegating or m.status not in (MissionStatus.STARTED,
                                                             MissionStatus.RUNNING):
                continue
            if unfinished_on(parse_tree(m.current_tst), m.node_status, event.name):
                effects.extend(self._redelegate(m, event.name, why, now))
        return effects

    def _redelegate(self, mission: Mission, unit: str, why: str, now: float) -> Effects:
        """Plan what ``mission`` still has to do without ``unit`` (a job); the mission waits for
        it (``redelegating``: no root status ends it meanwhile)."""
        tree = parse_tree(mission.current_tst)
        # Every unit of the tree that is gone too (e.g. lost while this was being planned).
        lost = {unit} | {n.execunit.strip("/") for _, n in walk(tree) if not n.is_control
                         and isinstance(n.execunit, str) and n.execunit.startswith("/")
                         and not self.fleet.is_alive(n.execunit, now)}
        remaining = remaining_tree(tree, mission.node_status, lost, lambda: str(uuid.uuid4()))
        if remaining is None:
            return Effects()
        paths = {n.node_uuid: where(p, n) for p, n in walk(parse_tree(mission.current_tst))}
        for uid in remaining.freed:
            old = remaining.origin[uid]
            if mission.retries.get(first_origin(mission.origin, old), 0) >= self.config.max_retries:
                reason = (f"{why}; {paths.get(old, old)} was re-delegated "
                          f"{self.config.max_retries} times already (retry budget)")
                return self._abort_and_fail(mission, mission.current_root, reason, now)
        old_root = mission.current_root
        mission.current_root = ""  # re-delegating
        units, notes = self.plannable(now, exclude=lost, mission=mission.root_uuid)
        self._replans[mission.root_uuid] = Replan(remaining, why, old_root, frozenset(lost))
        self._job_ids += 1
        options = self._options(mission.plan.get("strategy"), mission.plan.get("objective"),
                                None)
        job = Job(id=self._job_ids, kind="plan",
                  key=(INTERNAL, f"{mission.root_uuid}#{mission.redelegations + 1}"),
                  face="delegation", tree=remaining.tree, units=units, options=options,
                  engine=self.config.engine, start=True, source="redelegate", received=now,
                  notes=notes, redelegate=mission.root_uuid)
        log.info("mission %s: re-delegating %d task(s): %s", mission.root_uuid,
                 len(remaining.freed), why)
        return Effects(jobs=[job])

    def _redelegated(self, job: Job, result: JobResult, now: float) -> Effects:
        """A re-delegation was planned: abort the old tree, start the new one, tell the operator;
        or fail the mission naming the unit and the tasks nobody can take."""
        replan = self._replans.pop(job.redelegate, None)
        mission = self.book.find(job.redelegate)
        if replan is None or mission is None or mission.ended:
            return Effects()  # cancelled or ended meanwhile
        if isinstance(result, JobFailed):
            return self._abort_and_fail(mission, replan.old_root, f"{replan.why}; {result.reason}",
                                        now)
        if not isinstance(result, PlanDone):
            return self._abort_and_fail(mission, replan.old_root,
                                        internal_error(result).reason, now)
        plan = result.plan
        origin = replan.remaining.origin
        if not plan.feasible:
            paths = {n.node_uuid: where(p, n) for p, n in walk(parse_tree(mission.current_tst))}
            parts = [f"{paths.get(origin.get(u.node_uuid, ''), u.name)}: {u.reason}"
                     for u in plan.unassigned]
            reason = f"{replan.why}; nobody can take " + "; ".join(parts)
            return self._abort_and_fail(mission, replan.old_root, reason, now)
        if any(mission.node_status.get(origin.get(uid, "")) == "succeeded"
               for uid in origin):
            # A task finished while this was planned: plan again without it (never run twice).
            mission.current_root = replan.old_root
            return self._redelegate(mission, next(iter(replan.units)), replan.why, now)
        problem = self.engine.problem(now)
        if problem:
            return self._abort_and_fail(mission, replan.old_root, f"{replan.why}; {problem}", now)
        plan_json = {**plan.to_json(), "notes": list(plan.notes)}
        new_root = plan.tst.node_uuid or ""
        self.book.replace_tree(mission, plan_json["tst"], new_root, node_infos(plan.tst), origin)
        moved = moved_tasks(plan.tst, replan.remaining)
        for uid in replan.remaining.freed:
            first = first_origin(mission.origin, uid)
            mission.retries[first] = mission.retries.get(first, 0) + 1
        effects = self._abort_tree(replan.old_root, now)
        start = StartTst(receiver=self.config.engine, sender=self.config.name, tst=plan_json["tst"])
        effects.extend(self._to_engine("start", (INTERNAL, f"{new_root}#start"), "delegation",
                                       start, now, mission.root_uuid, plan=plan_json))
        effects.send(self.delegation_feedback_topic, DelegationFeedback(
            root_uuid=mission.root_uuid, status=MissionStatus.RE_DELEGATED.value,
            fail_reason=replan.why, tasks=moved))
        log.info("mission %s re-delegated: %s", mission.root_uuid,
                 ", ".join(f"{t['path']} -> {t['unit']}" for t in moved))
        for note in plan.notes:
            log.info("mission %s (re-delegation): %s", mission.root_uuid, note)
        return effects

    def _abort_tree(self, root: str, now: float) -> Effects:
        """``$abort`` a tree the service gave the engine (no caller waits for the answer)."""
        if not root or self.engine.problem(now):
            return Effects()
        model = SignalTstTree(node_uuid=root, signal="$abort", sender=self.config.name)
        return self._to_engine("signal", (INTERNAL, f"{root}#abort"), "delegation", model, now)

    def _abort_and_fail(self, mission: Mission, root: str, reason: str, now: float) -> Effects:
        effects = self._abort_tree(root, now)
        return effects.extend(self._set_status(mission.root_uuid, MissionStatus.FAILED, now,
                                               reason))

    def _clash(self, plan: Any, job: Job) -> set[str]:
        """Units a start plan uses that got busy in a mission started meanwhile (the plan did
        not know: it used them as free now)."""
        if self.config.commitments == "share":
            return set()
        known = {u.name for u in job.units if u.available_at > 0.0}
        used = {a.execunit.strip("/") for a in plan.assignments}
        return (used & set(self._committed())) - known
