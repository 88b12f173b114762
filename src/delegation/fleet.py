"""The fleet: the planner's view of a unit (``UnitState``) and the live registry that builds it.

The registry is pure: it is fed decoded messages together with ``now`` and never reads the clock,
so liveness, reboots and busy/idle are tested with explicit times.

Default speeds (m/s) per agent type, used when neither the scenario nor a fleet profile gives a
unit's speeds:

==========  =====  ========  =====  ==========================================================
type        slow   standard  fast   why
==========  =====  ========  =====  ==========================================================
air         1.5    3.0       6.0    the public WARA-PS example agent (type ``air``), our
                                    reference peer, flies exactly these
surface     1.0    2.5       5.0    small survey boats / USVs at harbour speeds
ground      0.5    1.0       2.0    wheeled field robots (walking pace at ``standard``)
subsurface  0.5    1.0       1.5    small AUVs
==========  =====  ========  =====  ==========================================================

Default sweep altitude (m above ground, or sensor height for surface/ground units) used for the
coverage footprint (see ``delegation.costs.sweep_width``): air 40, surface 10, ground 3,
subsurface 5. The default camera field of view is 60 degrees.

An unknown agent type gets the ``air`` values (the reference peer's).

Liveness: a unit is alive while its last heartbeat is younger than ``periods`` heartbeat periods
(``1/rate``), never less than ``min_timeout`` and never more than ``max_timeout`` seconds (a unit
advertising a very low rate is still declared lost within a bounded time). A heartbeat with a new
``agent-uuid`` means the unit rebooted: everything it reported executing is forgotten. `check`
reports each unit whose heartbeat stopped as a ``lost`` event, once per loss.

Bound identities (docs/security.md): a name is bound to the base topic of its first heartbeat. A
heartbeat (or any message) for the same name from another base topic is an impostor's: logged
once per topic and ignored, so that neither the service's trees nor the engine's tasks follow it.
Only `forget` unbinds a name.

Fleet profiles (``FleetRegistry(profiles=...)``) give what heartbeats do not carry: a dict keyed
by unit name or agent type (a name entry wins), each value with any of ``speeds``, ``home``,
``endurance``, ``battery``, ``camera-fov``, ``sweep-altitude`` (scenario spelling, see
``delegation.scenario``).
"""

from __future__ import annotations

import functools
import logging
import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING, Any

from delegation.geo import GeoPoint
from delegation.topics import split_unit_topic, type_from_base

if TYPE_CHECKING:
    from delegation.messages import DelegationInfo, DirectExecutionInfo, HeartBeat, SensorReading

log = logging.getLogger(__name__)

#: The speed classes every ``UnitState.speeds`` holds.
SPEED_KEYS: tuple[str, str, str] = ("slow", "standard", "fast")

#: m/s per speed class and agent type (table in the module docstring).
DEFAULT_SPEEDS: dict[str, dict[str, float]] = {
    "air": {"slow": 1.5, "standard": 3.0, "fast": 6.0},
    "surface": {"slow": 1.0, "standard": 2.5, "fast": 5.0},
    "ground": {"slow": 0.5, "standard": 1.0, "fast": 2.0},
    "subsurface": {"slow": 0.5, "standard": 1.0, "fast": 1.5},
}

#: Metres above ground (sensor height) for the coverage footprint, per agent type.
DEFAULT_SWEEP_ALTITUDE: dict[str, float] = {
    "air": 40.0,
    "surface": 10.0,
    "ground": 3.0,
    "subsurface": 5.0,
}

DEFAULT_CAMERA_FOV_DEG = 60.0


def default_speeds(agent_type: str) -> dict[str, float]:
    """A fresh copy of the default speeds for ``agent_type`` (``air`` for unknown types)."""
    return dict(DEFAULT_SPEEDS.get(agent_type, DEFAULT_SPEEDS["air"]))


def complete_speeds(agent_type: str, given: Mapping[str, float] | None) -> dict[str, float]:
    """All three speed classes: the given ones, the rest from the type's defaults.

    When ``standard`` is given the missing classes keep the defaults' ratios to it (a unit twice as
    fast as the default at ``standard`` is also twice as fast at ``fast``).
    """
    base = default_speeds(agent_type)
    if not given:
        return base
    scale = 1.0
    if "standard" in given:
        scale = float(given["standard"]) / base["standard"]
    return {k: float(given[k]) if k in given else base[k] * scale for k in SPEED_KEYS}


@dataclass(frozen=True, slots=True)
class UnitState:
    """The planner's view of one unit: where it is, what it can do, how fast, how long."""

    name: str
    agent_type: str
    position: GeoPoint
    speeds: dict[str, float]
    tasks: frozenset[str]
    alive: bool = True
    busy: bool = False
    battery: float | None = None
    endurance: float | None = None
    home: GeoPoint | None = None
    camera_fov_deg: float = DEFAULT_CAMERA_FOV_DEG
    sweep_altitude: float | None = None
    base_topic: str | None = None
    #: Seconds from now until the unit is free of earlier commitments (another mission); its
    #: ``position`` is then where it will be. The schedule starts its first task no earlier.
    available_at: float = 0.0

    @property
    def remaining_endurance(self) -> float | None:
        """Seconds of operation left (``battery * endurance``), or None when unknown.

        A known endurance with an unknown battery counts as a full battery.
        """
        if self.endurance is None:
            return None
        return (1.0 if self.battery is None else self.battery) * self.endurance

    @property
    def execunit(self) -> str:
        """The unit as a TST ``execunit`` (``/dji0``)."""
        return f"/{self.name}"

    @property
    def effective_sweep_altitude(self) -> float:
        """The sweep altitude, or the default for the agent type."""
        if self.sweep_altitude is not None:
            return self.sweep_altitude
        return DEFAULT_SWEEP_ALTITUDE.get(self.agent_type, DEFAULT_SWEEP_ALTITUDE["air"])


def make_unit(
    name: str,
    agent_type: str,
    position: GeoPoint,
    tasks: frozenset[str] | set[str] | list[str] | tuple[str, ...],
    speeds: Mapping[str, float] | None = None,
    **kw: Any,
) -> UnitState:
    """A ``UnitState`` with speeds completed from the type defaults (handy for tests and tools)."""
    return UnitState(
        name=name.strip("/"),
        agent_type=agent_type,
        position=position,
        speeds=complete_speeds(agent_type, speeds),
        tasks=frozenset(tasks),
        **kw,
    )


# --------------------------------------------------------------------------- the live registry

#: Positions kept per unit (at 2 Hz, about half an hour of flight).
TRACK = 4096

#: Sensors that carry the battery's state of charge.
_BATTERY_SENSORS: frozenset[str] = frozenset({"battery_state", "battery", "battery_level"})


def _battery_fraction(value: Any) -> float | None:
    """A state of charge in 0..1 from a number (0..1 or percent) or a ROS BatteryState object."""
    if isinstance(value, dict):
        for key in ("percentage", "percent", "level", "value", "data", "battery"):
            if key in value:
                return _battery_fraction(value[key])
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    v = float(value)
    if not math.isfinite(v) or v < 0.0:
        return None
    if v > 1.0:
        v = v / 100.0 if v <= 100.0 else 1.0
    return v


@dataclass(frozen=True, slots=True)
class Delegator:
    """Another delegation service seen on the broker (docs/protocol.md §15.1): heartbeat level
    ``delegation`` and a ``delegation_info`` saying what its fleet can do and whom it manages."""

    name: str
    base_topic: str
    alive: bool
    tasks: frozenset[str]
    units_managed: frozenset[str]

    @property
    def execunit(self) -> str:
        """The delegator as a TST ``execunit`` (``/delegator-b``)."""
        return f"/{self.name}"

    def can_take(self, task_names: Iterable[str]) -> bool:
        """True when its fleet lists every one of the tasks (and it lists any at all)."""
        names = set(task_names)
        return bool(names) and names <= self.tasks


class FleetEventKind(Enum):
    """Things the registry noticed while observing (for logs and re-delegation)."""

    APPEARED = "appeared"
    """First heartbeat from a unit."""
    REBOOTED = "rebooted"
    """A heartbeat with a new ``agent-uuid``: the unit lost its tasks."""
    LOST = "lost"
    """No heartbeat for the unit's timeout (reported by `FleetRegistry.check`)."""
    IMPOSTOR = "impostor"
    """A message for a bound name from another base topic: ignored."""


@dataclass(frozen=True, slots=True)
class FleetEvent:
    """One registry event: what, which unit, when (``now`` of the message)."""

    kind: FleetEventKind
    name: str
    at: float


@dataclass(slots=True)
class _Record:
    """What the registry knows about one unit (mutable, private)."""

    name: str
    base_topic: str
    agent_type: str | None = None
    agent_uuid: str | None = None
    levels: tuple[str, ...] = ()
    rate: float | None = None
    last_heartbeat: float | None = None
    last_seen: float | None = None
    position: GeoPoint | None = None
    #: The last positions heard and when (what a lost unit had swept, `service.sweep_progress`).
    track: deque[tuple[float, GeoPoint]] = field(default_factory=lambda: deque(maxlen=TRACK))
    battery: float | None = None
    tasks_available: frozenset[str] = frozenset()
    tasks_executing: tuple[tuple[str, str], ...] = ()
    has_direct_execution: bool = False
    #: From ``delegation_info`` (None until one arrived): what its fleet can do, whom it manages.
    delegates_tasks: frozenset[str] | None = None
    units_managed: frozenset[str] = frozenset()
    reboots: int = 0
    lost: bool = False
    #: Base topics that claimed this name after it was bound (logged once each; bounded).
    impostors: set[str] = field(default_factory=set)


@functools.cache
def _read_models() -> tuple[type[HeartBeat], type[DirectExecutionInfo], type[DelegationInfo],
                            type[SensorReading]]:
    """The models `FleetRegistry.observe` reads, imported on first use so that ``UnitState``
    users do not load every message model (kept: an import per message cost ~2 us)."""
    from delegation.messages import DelegationInfo, DirectExecutionInfo, HeartBeat, SensorReading

    return HeartBeat, DirectExecutionInfo, DelegationInfo, SensorReading


class FleetRegistry:
    """Live units built from heartbeat, direct_execution_info and sensor messages.

    Pure: ``observe`` is fed decoded messages (``delegation.messages.decode``) with the time they
    arrived, ``snapshot`` is asked with the current time; nothing here reads the clock. Liveness
    uses arrival times, not the units' ``stamp`` (their clocks are not ours). Not thread-safe: the
    caller serialises calls.

    A unit is keyed by the last level of its base topic (``.../dji0`` -> ``dji0``). Only units on
    the direct execution level (by heartbeat ``levels`` or a ``direct_execution_info``) with a
    known position appear in ``snapshot``; TST engines and delegators do not.
    """

    def __init__(
        self,
        profiles: dict[str, dict[str, Any]] | None = None,
        min_timeout: float = 5.0,
        periods: float = 3.0,
        max_timeout: float = 15.0,
    ) -> None:
        self.profiles: dict[str, dict[str, Any]] = dict(profiles or {})
        self.min_timeout = float(min_timeout)
        self.max_timeout = max(float(max_timeout), self.min_timeout)
        self.periods = float(periods)
        self._units: dict[str, _Record] = {}
        self._events: list[FleetEvent] = []
        #: Per unit: `_state`'s last answer and what it was built from (a snapshot is asked for
        #: every plan; most units did not change since: the same state is handed out again).
        self._states: dict[str, tuple[tuple[Any, ...], UnitState]] = {}

    # ------------------------------------------------------------------ feeding

    def observe(self, topic: str, message: Any, now: float) -> None:
        """Take in one decoded message that arrived on ``topic`` at ``now``.

        Reads ``HeartBeat``, ``DirectExecutionInfo`` and the position and battery sensors (a
        ``SensorReading`` or the bare value from ``parse_sensor``); other messages only refresh
        ``last_seen``. Topics outside a unit are ignored.
        """
        HeartBeat, DirectExecutionInfo, DelegationInfo, SensorReading = _read_models()
        parts = split_unit_topic(topic)
        if parts is None:
            log.debug("fleet: ignoring %s (not under a unit)", topic)
            return
        base, rest = parts
        name = base.rsplit("/", 1)[-1]
        rec = self._units.get(name)
        if rec is None:
            rec = self._units[name] = _Record(name=name, base_topic=base)
        if base != rec.base_topic:
            if rec.last_heartbeat is not None:  # bound: someone else claims this name
                self._impostor(rec, base, now)
                return
            if not isinstance(message, HeartBeat):
                return  # not bound yet, and only a heartbeat binds
            rec.base_topic = base
            rec.position, rec.battery, rec.agent_type = None, None, None
            rec.track.clear()
        rec.last_seen = now if rec.last_seen is None else max(rec.last_seen, now)

        if isinstance(message, HeartBeat):
            self._heartbeat(rec, base, message, now)
        elif isinstance(message, DirectExecutionInfo):
            rec.has_direct_execution = True
            rec.tasks_available = frozenset(t.name for t in message.tasks_available)
            rec.tasks_executing = tuple((t.task_name, t.task_uuid) for t in message.tasks_executing)
        elif isinstance(message, DelegationInfo):
            rec.delegates_tasks = frozenset(message.tasks_available)
            rec.units_managed = frozenset(u.strip("/") for u in message.units_managed)
        elif rest.startswith("sensor/"):
            sensor = rest.split("/", 1)[1]
            value = message.value if isinstance(message, SensorReading) else message
            self._sensor(rec, sensor, value)
            if sensor == "position" and rec.position is not None:
                rec.track.append((now, rec.position))
        if rec.agent_type is None:
            rec.agent_type = type_from_base(base)

    def _impostor(self, rec: _Record, base: str, now: float) -> None:
        if base in rec.impostors:
            return
        if len(rec.impostors) < 16:
            rec.impostors.add(base)
        log.warning("fleet: ignoring %s: %s is bound to %s", base, rec.name, rec.base_topic)
        self._events.append(FleetEvent(FleetEventKind.IMPOSTOR, rec.name, now))

    def _heartbeat(self, rec: _Record, base: str, hb: HeartBeat, now: float) -> None:
        if rec.last_heartbeat is None:
            self._events.append(FleetEvent(FleetEventKind.APPEARED, rec.name, now))
        elif rec.agent_uuid is not None and hb.agent_uuid != rec.agent_uuid:
            log.info(
                "fleet: %s rebooted (agent-uuid %s -> %s)", rec.name, rec.agent_uuid, hb.agent_uuid
            )
            rec.tasks_executing = ()
            rec.reboots += 1
            self._events.append(FleetEvent(FleetEventKind.REBOOTED, rec.name, now))
        if hb.name and hb.name != rec.name:
            log.debug("fleet: heartbeat name %r differs from topic name %r", hb.name, rec.name)
        rec.base_topic = base
        rec.agent_uuid = hb.agent_uuid
        rec.agent_type = hb.agent_type or rec.agent_type
        rec.levels = tuple(hb.levels)
        rec.rate = hb.rate
        rec.lost = False
        rec.last_heartbeat = now if rec.last_heartbeat is None else max(rec.last_heartbeat, now)

    def _sensor(self, rec: _Record, sensor: str, value: Any) -> None:
        if sensor == "position":
            if isinstance(value, GeoPoint):
                rec.position = value
            elif isinstance(value, dict):
                try:
                    rec.position = GeoPoint.model_validate(value)
                except ValueError:
                    log.debug("fleet: %s sent a bad position %r", rec.name, value)
        elif sensor in _BATTERY_SENSORS:
            fraction = _battery_fraction(value)
            if fraction is not None:
                rec.battery = fraction

    def forget(self, name: str) -> None:
        """Drop a unit (e.g. one that has been dead for long)."""
        self._units.pop(name.strip("/"), None)
        self._states.pop(name.strip("/"), None)

    def drain_events(self) -> list[FleetEvent]:
        """The events noticed since the last call (appearances, reboots, losses), oldest first."""
        events, self._events = self._events, []
        return events

    # ------------------------------------------------------------------ reading

    def timeout(self, rate: float | None) -> float:
        """How long a heartbeat at ``rate`` Hz keeps a unit alive: ``periods / rate``, at least
        ``min_timeout`` (also for a missing or non-positive rate), at most ``max_timeout``."""
        if rate is None or not rate > 0.0 or not math.isfinite(rate):
            return self.min_timeout
        return min(self.max_timeout, max(self.min_timeout, self.periods / rate))

    def grace(self, now: float, extra: float = 0.0) -> None:
        """After the observer's own outage: nobody is judged on the time it could not hear
        them, so every unit not already lost counts as heard at ``now + extra`` (``extra``: the
        peers' own reconnect back-off, as they come back later than we may)."""
        for rec in self._units.values():
            if rec.last_heartbeat is not None and not rec.lost:
                rec.last_heartbeat = max(rec.last_heartbeat, now + extra)

    def check(self, now: float) -> list[FleetEvent]:
        """Record a ``lost`` event (see `drain_events`) for every unit whose heartbeat stopped
        since the last check; returns them too. A unit is reported lost once until it comes
        back."""
        lost: list[FleetEvent] = []
        for rec in self._units.values():
            if rec.last_heartbeat is None or rec.lost or self._alive(rec, now):
                continue
            rec.lost = True
            log.info("fleet: %s lost (no heartbeat for %.1f s)", rec.name,
                     now - rec.last_heartbeat)
            lost.append(FleetEvent(FleetEventKind.LOST, rec.name, now))
        self._events.extend(lost)
        return lost

    def track(self, name: str, since: float) -> list[GeoPoint]:
        """The positions ``name`` reported from ``since`` on, oldest first (the last `TRACK`)."""
        rec = self._units.get(name.strip("/"))
        return [p for t, p in rec.track if t >= since] if rec is not None else []

    def is_alive(self, name: str, now: float) -> bool:
        """True while the unit's last heartbeat is fresher than its timeout."""
        rec = self._units.get(name.strip("/"))
        return rec is not None and self._alive(rec, now)

    def _alive(self, rec: _Record, now: float) -> bool:
        if rec.last_heartbeat is None:
            return False
        return now - rec.last_heartbeat < self.timeout(rec.rate)

    def base_topic(self, name: str) -> str | None:
        """The unit's base topic (its heartbeat topic minus ``/heartbeat``), if known."""
        rec = self._units.get(name.strip("/"))
        return rec.base_topic if rec is not None else None

    def levels(self, name: str) -> tuple[str, ...]:
        """The levels of the unit's last heartbeat (none when never heard)."""
        rec = self._units.get(name.strip("/"))
        return rec.levels if rec is not None else ()

    def names(self) -> list[str]:
        """Every unit heard of, sorted."""
        return sorted(self._units)

    def last_seen(self, name: str) -> float | None:
        """When any message from the unit last arrived."""
        rec = self._units.get(name.strip("/"))
        return rec.last_seen if rec is not None else None

    def executing(self, name: str) -> list[tuple[str, str]]:
        """(task-name, task-uuid) the unit last reported executing."""
        rec = self._units.get(name.strip("/"))
        return list(rec.tasks_executing) if rec is not None else []

    def has_profile_speeds(self, name: str) -> bool:
        """True when a fleet profile (by name or agent type) gives the unit's speeds."""
        rec = self._units.get(name.strip("/"))
        return rec is not None and "speeds" in self._profile(rec)

    def _profile(self, rec: _Record) -> dict[str, Any]:
        merged: dict[str, Any] = {}
        if rec.agent_type and rec.agent_type in self.profiles:
            merged.update(self.profiles[rec.agent_type])
        if rec.name in self.profiles:
            merged.update(self.profiles[rec.name])
        return merged

    def _state(self, rec: _Record, now: float) -> UnitState:
        """``rec`` as the planner sees it ``now``; built again only when what it reads changed
        (the profiles are not changed after construction; a new position is a new object)."""
        key = (rec.position, rec.agent_type, rec.tasks_available, self._alive(rec, now),
               bool(rec.tasks_executing), rec.battery, rec.base_topic)
        known = self._states.get(rec.name)
        if known is not None and known[0] == key:
            return known[1]
        state = self._build_state(rec, now)
        self._states[rec.name] = (key, state)
        return state

    def _build_state(self, rec: _Record, now: float) -> UnitState:
        assert rec.position is not None
        profile = self._profile(rec)
        agent_type = rec.agent_type or str(profile.get("type", "air"))
        speeds = profile.get("speeds")
        home = profile.get("home")
        battery = rec.battery if rec.battery is not None else profile.get("battery")
        fov = profile.get("camera-fov", profile.get("camera_fov_deg"))
        altitude = profile.get("sweep-altitude", profile.get("sweep_altitude"))
        endurance = profile.get("endurance")
        return UnitState(
            name=rec.name,
            agent_type=agent_type,
            position=rec.position,
            speeds=complete_speeds(agent_type, speeds),
            tasks=rec.tasks_available,
            alive=self._alive(rec, now),
            busy=bool(rec.tasks_executing),
            battery=None if battery is None else float(battery),
            endurance=None if endurance is None else float(endurance),
            home=None if home is None else GeoPoint.model_validate(home),
            camera_fov_deg=DEFAULT_CAMERA_FOV_DEG if fov is None else float(fov),
            sweep_altitude=None if altitude is None else float(altitude),
            base_topic=rec.base_topic,
        )

    def _is_executor(self, rec: _Record) -> bool:
        return rec.has_direct_execution or "direct execution" in rec.levels

    def snapshot(self, now: float) -> list[UnitState]:
        """Every known unit on the direct execution level with a position, ``alive`` set for
        ``now``, sorted by name."""
        return [
            self._state(rec, now)
            for name, rec in sorted(self._units.items())
            if rec.position is not None and self._is_executor(rec)
        ]

    def _is_delegator(self, rec: _Record) -> bool:
        return "delegation" in rec.levels and rec.delegates_tasks is not None

    def delegators(self, now: float, *, alive_only: bool = True) -> list[Delegator]:
        """Other delegation services heard (heartbeat level ``delegation`` and a
        ``delegation_info``), sorted by name."""
        found = []
        for name, rec in sorted(self._units.items()):
            alive = self._alive(rec, now)
            if not self._is_delegator(rec) or (alive_only and not alive):
                continue
            found.append(Delegator(name, rec.base_topic, alive, rec.delegates_tasks or frozenset(),
                                   rec.units_managed))
        return found

    def managed_by(self, now: float) -> dict[str, str]:
        """Unit -> the live delegator that says it manages it (the first by name when two say
        so): such units are reached only through offers to their delegator."""
        owners: dict[str, str] = {}
        for d in self.delegators(now):
            for unit in sorted(d.units_managed):
                if unit != d.name:
                    owners.setdefault(unit, d.name)
        return owners

    def agents(self, now: float, *, alive_only: bool = False) -> list[dict[str, Any]]:
        """Every unit heard of as JSON-ready rows (hyphenated keys) for ``list-agents`` and the
        ``agents`` command: name, type, base-topic, levels, alive, busy, state, position (or
        None), tasks-available, tasks-executing, battery, last-seen, last-heartbeat, reboots;
        a delegator also ``delegator``, ``delegates-tasks``, ``units-managed``, a unit another
        delegator manages ``managed-by``."""
        rows = []
        owners = self.managed_by(now)
        for name, rec in sorted(self._units.items()):
            alive = self._alive(rec, now)
            if alive_only and not alive:
                continue
            rows.append(self._federation_keys(rec, owners) |
                {
                    "name": name,
                    "type": rec.agent_type,
                    "base-topic": rec.base_topic,
                    "levels": list(rec.levels),
                    "alive": alive,
                    "busy": bool(rec.tasks_executing),
                    "state": "busy" if rec.tasks_executing else "idle",
                    "position": rec.position.to_wire() if rec.position is not None else None,
                    "tasks-available": sorted(rec.tasks_available),
                    "tasks-executing": [
                        {"task-name": n, "task-uuid": u} for n, u in rec.tasks_executing
                    ],
                    "battery": rec.battery,
                    "last-seen": rec.last_seen,
                    "last-heartbeat": rec.last_heartbeat,
                    "reboots": rec.reboots,
                }
            )
        return rows

    def _federation_keys(self, rec: _Record, owners: Mapping[str, str]) -> dict[str, Any]:
        """``delegator`` (with its ``delegates-tasks`` and ``units-managed``) for a delegator,
        ``managed-by`` for a unit another delegator manages; nothing for the others."""
        keys: dict[str, Any] = {}
        if self._is_delegator(rec):
            keys.update({"delegator": True,
                         "delegates-tasks": sorted(rec.delegates_tasks or ()),
                         "units-managed": sorted(rec.units_managed)})
        if rec.name in owners:
            keys["managed-by"] = owners[rec.name]
        return keys
