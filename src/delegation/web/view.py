"""The operator page's live state: units, missions, node statuses, an event log (pure).

Fed already-decoded JSON values with ``now`` (epoch seconds) by the bridge, under its lock; never
reads the clock, starts no thread. Every change bumps ``seq``: unit changes are stamped on the
unit (so a stream asks "which units changed since my seq", coalesced by the caller), mission,
node and log changes are kept as stream items in a bounded queue (a stream that fell behind gets
a fresh snapshot). JSON shapes are docs/ui.md's (UNIT, MISSION, EVENT, NODE).

Liveness follows the service's rule (`FleetRegistry.timeout`: 3 heartbeat periods, 5..15 s), and
a name is bound to the base topic of its first heartbeat (docs/security.md): messages for that
name from another base are ignored.
"""

from __future__ import annotations

import math
from collections import OrderedDict, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from delegation.fleet import FleetRegistry
from delegation.tst.node import COMMON_KEYS, stored_nodes
from delegation.web.parts import engine_of, part_uuids, reshared, search_parts, span

#: Flown track: points closer than this (m) to the last kept one are not kept.
TRACK_STEP_M = 2.0
#: Flown track: at most this many points per unit (halved by thinning when full).
TRACK_MAX = 300
#: Events in /api/state and the snapshot.
LOG_MAX = 200
#: Mission/node/log items a stream can catch up on before it needs a new snapshot.
STREAM_MAX = 4000
#: Node feedback held for missions not yet known (their tree arrives after the feedback).
PENDING_MAX = 4096
#: Missions kept (the oldest ended ones go first).
MISSIONS_MAX = 500

MISSION_ORDER = {"planned": 0, "started": 1, "running": 2}
FINAL = frozenset({"succeeded", "failed", "aborted"})
NODE_FINAL = frozenset({"succeeded", "failed", "aborted", "revoked", "finished"})
SIGNALS = ("$enough", "$pause", "$continue")

_M_PER_DEG = 111_320.0


def _levels_direct(levels: Any) -> bool:
    if not isinstance(levels, list):
        return False
    for level in levels:
        if isinstance(level, str) and level.lower().replace("_", " ").replace("-", " ") == (
            "direct execution"
        ):
            return True
    return False


def number(value: Any, key: str = "") -> float | None:
    """A finite float from a bare number or an object holding one (``value``, ``data``, the
    sensor's name, ``percentage``); None otherwise."""
    if isinstance(value, dict):
        for k in ("value", "data", key, "percentage", "percent", "level"):
            if k and k in value:
                return number(value[k])
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        v = float(value)
    except OverflowError:  # an int beyond float's range
        return None
    return v if math.isfinite(v) else None


def battery_fraction(value: Any) -> float | None:
    """State of charge 0..1 from a fraction, a percentage or a BatteryState object."""
    v = number(value, "battery")
    if v is None or v < 0.0:
        return None
    return v / 100.0 if v > 1.0 else v


def _task_names(items: Any) -> list[str]:
    out: list[str] = []
    if isinstance(items, list):
        for t in items:
            name = t.get("name") if isinstance(t, dict) else t
            if isinstance(name, str):
                out.append(name)
    return sorted(out)


def _executing(items: Any) -> list[dict[str, str]]:
    out: list[dict[str, str]] = []
    if isinstance(items, list):
        for t in items:
            if isinstance(t, dict):
                name = t.get("task-name", t.get("name"))
                uid = t.get("task-uuid", t.get("uuid"))
                out.append({"name": str(name or ""), "uuid": str(uid or "")})
    return out


@dataclass(slots=True)
class UnitRecord:
    """What the page shows of one unit (mutable, private to the view)."""

    name: str
    base: str
    agent_type: str
    bound: bool = False
    executor: bool = False
    latitude: float | None = None
    longitude: float | None = None
    altitude: float | None = None
    heading: float | None = None
    speed: float | None = None
    battery: float | None = None
    rate: float | None = None
    agent_uuid: str | None = None
    last_heartbeat: float | None = None
    lost: bool = False
    tasks_available: list[str] = field(default_factory=list)
    executing: list[dict[str, str]] = field(default_factory=list)
    track: list[list[float]] = field(default_factory=list)
    seq: int = 0
    #: The delegator whose ``delegation_info`` lists this unit in ``units-managed`` ("": none).
    managed_by: str = ""

    @property
    def shown(self) -> bool:
        return self.executor and self.latitude is not None

    def to_json(self, *, track: bool) -> dict[str, Any]:
        out: dict[str, Any] = {
            "name": self.name,
            "type": self.agent_type,
            "base": self.base,
            "latitude": self.latitude,
            "longitude": self.longitude,
            "altitude": self.altitude,
            "heading": self.heading,
            "speed": self.speed,
            "battery": self.battery,
            "status": "lost" if self.lost else "alive",
            "tasks-available": list(self.tasks_available),
            "executing": [dict(e) for e in self.executing],
        }
        if self.managed_by:
            out["managed-by"] = self.managed_by
        if track:
            out["track"] = [list(p) for p in self.track]
        else:
            out["point"] = [self.latitude, self.longitude]
        return out


@dataclass(slots=True)
class MissionRecord:
    """What the page shows of one mission; times are epoch seconds (the view's clock)."""

    id: str
    name: str = ""
    status: str = "planned"
    owner: str = ""
    strategy: str | None = None
    #: The strategy whose plan this is when ``strategy`` fell back to it (``optimal (= auction)``).
    fallback: str | None = None
    objective: str | None = None
    makespan: float | None = None
    created: float | None = None
    started_at: float | None = None
    ended_at: float | None = None
    fail_reason: str = ""
    units: list[str] = field(default_factory=list)
    plan: dict[str, Any] | None = None
    #: The tree the engine executes after a re-delegation (``query-mission``'s ``current-tst``):
    #: a lost unit's part of a shared search re-shared runs as pieces in its place.
    current_tst: dict[str, Any] | None = None
    #: The operator's own tree (as received), or the tree sent when that is all we know.
    tree: dict[str, Any] | None = None
    node_status: dict[str, str] = field(default_factory=dict)
    node_start: dict[str, float] = field(default_factory=dict)
    node_end: dict[str, float] = field(default_factory=dict)
    #: Where each unit was when the plan arrived (the planned routes start there).
    starts: dict[str, list[float]] = field(default_factory=dict)
    detailed: bool = False
    #: The operator's task uuid -> the unit a re-delegation moved it to.
    reassigned: dict[str, str] = field(default_factory=dict)
    #: When the service last said the mission was re-delegated: a node that had ended before
    #: may run again under the operator's uuid (docs/protocol.md §4).
    redelegated_at: float | None = None
    #: Mission seconds per wall second (the demo's simulation speed-up; 1 in the field).
    scale: float = 1.0

    @property
    def ended(self) -> bool:
        return self.status in FINAL

    @property
    def shown_plan(self) -> dict[str, Any] | None:
        """The plan with its shared searches' parts as they are now (``parts.reshared``)."""
        shown = reshared(self.plan, self.current_tst)
        return None if shown is None else dict(shown)

    def elapsed(self, now: float) -> float | None:
        if self.started_at is None:
            return None
        end = self.ended_at if self.ended_at is not None else now
        return round(max(0.0, end - self.started_at) * self.scale, 3)

    def rel(self, at: float | None) -> float | None:
        """Mission seconds from the start to ``at`` (epoch), or None."""
        if at is None or self.started_at is None:
            return None
        return round((at - self.started_at) * self.scale, 3)

    def to_json(self, now: float) -> dict[str, Any]:
        return {
            "id": self.id,
            "name": self.name,
            "status": self.status,
            "owner": self.owner,
            "strategy": self.strategy,
            "fallback": self.fallback,
            "objective": self.objective,
            "planned-makespan": self.makespan,
            "elapsed": self.elapsed(now),
            "started-at": self.started_at,
            "ended-at": self.ended_at,
            "units": list(self.units),
            "fail-reason": self.fail_reason,
        }


def _common_text(node: Mapping[str, Any], key: str) -> str | None:
    """A string common parameter of a node as JSON, under either spelling of common params."""
    for common_key in COMMON_KEYS:
        common = node.get(common_key)
        if isinstance(common, dict) and isinstance(common.get(key), str):
            return str(common[key])
    return None


def node_uuid_of(node: Mapping[str, Any]) -> str | None:
    return _common_text(node, "node-uuid")


def _node_execunit(node: Mapping[str, Any]) -> str | None:
    return (_common_text(node, "execunit") or "").strip("/") or None


def tree_uuids(tree: dict[str, Any]) -> list[str]:
    """Every node uuid of a tree given as JSON (`stored_nodes`: the service's trees, valid)."""
    return [uid for _, common in stored_nodes(tree)
            if isinstance(uid := common.get("node-uuid"), str) and uid]


#: Units remembered as some delegator's before they are heard (a bound on hostile lists).
OWNERS_MAX = 10_000


class LiveView:
    """The live operator state. Not thread-safe: the caller serialises calls."""

    def __init__(self, timeout: Callable[[float | None], float] | None = None,
                 scale: float = 1.0) -> None:
        """``timeout(rate)``: how long a heartbeat keeps a unit alive (the service's rule by
        default); ``scale``: mission seconds per wall second for elapsed and actual times (the
        demo's speed-up)."""
        self.timeout = timeout or FleetRegistry().timeout
        self.scale = scale
        self.seq = 0
        self.units: dict[str, UnitRecord] = {}
        #: Unit -> the delegator that says it manages it (for units not heard yet; bounded).
        self._owners: dict[str, str] = {}
        self.missions: OrderedDict[str, MissionRecord] = OrderedDict()
        self.log: deque[dict[str, Any]] = deque(maxlen=LOG_MAX)
        self.items: deque[tuple[int, str, dict[str, Any]]] = deque(maxlen=STREAM_MAX)
        self._dropped = 0  # seq of the newest item dropped from ``items``
        self.hidden: set[str] = set()
        self._node_mission: dict[str, str] = {}
        self._alias: dict[str, str] = {}  # a re-delegated task's new node -> the operator's node
        self._pending: OrderedDict[str, list[tuple[str, float]]] = OrderedDict()
        #: A shared search's part uuid -> its mission (its engine's feedback is read for it).
        self._part_mission: dict[str, str] = {}
        self._engines: set[str] = set()
        self._engines_told: set[str] = set()
        self._to_fetch: set[str] = set()

    # ------------------------------------------------------------------ units

    def _unit(self, base: str, name: str, agent_type: str, heartbeat: bool) -> UnitRecord | None:
        rec = self.units.get(name)
        if rec is None:
            rec = self.units[name] = UnitRecord(name=name, base=base, agent_type=agent_type,
                                                managed_by=self._owners.get(name, ""))
        elif base != rec.base:
            if rec.bound or not heartbeat:
                return None  # bound to another base (an impostor), or not bound by this
            rec.base, rec.agent_type = base, agent_type
            rec.latitude = rec.longitude = None
            rec.track.clear()
        return rec

    def delegation_info(self, base: str, name: str, data: Mapping[str, Any]) -> None:
        """A delegator's ``delegation_info``: the units it manages are shown as its
        (docs/protocol.md §15.1); a unit it no longer lists is no longer shown as its."""
        managed = data.get("units-managed")
        names = ({u.strip("/") for u in managed if isinstance(u, str)}
                 if isinstance(managed, list) else set())
        for rec in self.units.values():
            owner = name if rec.name in names else ("" if rec.managed_by == name
                                                    else rec.managed_by)
            if owner != rec.managed_by and rec.name != name:
                rec.managed_by = owner
                self._touch(rec)
        self._owners = {u: o for u, o in self._owners.items() if o != name}
        room = max(0, OWNERS_MAX - len(self._owners))
        self._owners.update(dict.fromkeys(sorted(names - {name})[:room], name))

    def _touch(self, rec: UnitRecord) -> None:
        self.seq += 1
        rec.seq = self.seq

    def heartbeat(self, base: str, name: str, agent_type: str, data: Mapping[str, Any],
                  now: float) -> None:
        """A unit's heartbeat (decoded JSON)."""
        rec = self._unit(base, name, agent_type, heartbeat=True)
        if rec is None:
            return
        first = not rec.bound
        rec.bound = True
        rate = number(data.get("rate"))
        rec.rate = rate
        kind = data.get("agent-type")
        if isinstance(kind, str) and kind:
            rec.agent_type = kind
        if _levels_direct(data.get("levels")):
            rec.executor = True
        uid = data.get("agent-uuid")
        rebooted = rec.agent_uuid is not None and isinstance(uid, str) and uid != rec.agent_uuid
        if isinstance(uid, str):
            rec.agent_uuid = uid
        rec.last_heartbeat = now
        if rec.lost:
            rec.lost = False
            self._touch(rec)
            self._log(now, "unit-back", None, name, f"{name} is back (heartbeat again)")
        elif first and rec.executor:
            self._touch(rec)
            self._log(now, "unit-new", None, name, f"{name} ({rec.agent_type}) appeared")
        elif rebooted:
            rec.executing = []
            self._touch(rec)
            self._log(now, "unit-back", None, name, f"{name} rebooted (new agent-uuid)")

    def execution_info(self, base: str, name: str, agent_type: str, data: Mapping[str, Any],
                       now: float) -> None:
        """``direct_execution_info``: what the unit offers and runs."""
        rec = self._unit(base, name, agent_type, heartbeat=False)
        if rec is None:
            return
        new = not rec.executor
        rec.executor = True
        available = _task_names(data.get("tasks-available"))
        executing = _executing(data.get("tasks-executing"))
        if new or available != rec.tasks_available or executing != rec.executing:
            rec.tasks_available, rec.executing = available, executing
            self._touch(rec)

    def engine_feedback(self, engine: str, data: Mapping[str, Any], now: float) -> None:
        """A TST engine's ``tst/feedback``: taken only for the parts of a shared search (the
        service relays none for them, DESIGN 3.4) of a mission that engine runs."""
        uid, status = data.get("node-uuid"), data.get("status")
        if not isinstance(uid, str) or not isinstance(status, str):
            return
        m = self.missions.get(self._part_mission.get(uid, ""))
        if m is not None and engine_of(m.plan) == engine:
            self._apply_node(m, uid, status, now)

    def drain_engines(self) -> list[str]:
        """Engines running missions with shared searches, not asked for before: the bridge
        listens to their feedback (for the parts)."""
        new = sorted(self._engines - self._engines_told)
        self._engines_told.update(new)
        return new

    def position(self, base: str, name: str, agent_type: str, data: Any, now: float) -> None:
        """``sensor/position`` (a GeoPoint object)."""
        if not isinstance(data, dict):
            return
        lat, lon = number(data.get("latitude")), number(data.get("longitude"))
        if lat is None or lon is None or not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return
        rec = self._unit(base, name, agent_type, heartbeat=False)
        if rec is None:
            return
        rec.latitude, rec.longitude = lat, lon
        rec.altitude = number(data.get("altitude"))
        track = rec.track
        if not track or _metres(track[-1], lat, lon) >= TRACK_STEP_M:
            if len(track) >= TRACK_MAX:
                del track[1:-1:2]  # thin: every other point, first and last kept
            track.append([lat, lon])
        self._touch(rec)

    def sensor(self, base: str, name: str, agent_type: str, sensor: str, data: Any,
               now: float) -> None:
        """``sensor/heading``, ``sensor/speed`` or a battery sensor."""
        rec = self._unit(base, name, agent_type, heartbeat=False)
        if rec is None:
            return
        if sensor in ("heading", "speed"):
            value = number(data, sensor)
            if value is None or value == getattr(rec, sensor):
                return
            setattr(rec, sensor, value)
        else:
            frac = battery_fraction(data)
            if frac is None or frac == rec.battery:
                return
            rec.battery = frac
        self._touch(rec)

    def tick(self, now: float) -> int:
        """Mark units whose heartbeat stopped as lost; returns how many were newly lost."""
        lost = 0
        for rec in self.units.values():
            if rec.lost or rec.last_heartbeat is None:
                continue
            if now - rec.last_heartbeat >= self.timeout(rec.rate):
                rec.lost = True
                lost += 1
                self._touch(rec)
                if rec.executor:
                    self._log(now, "unit-lost", None, rec.name,
                              f"{rec.name} lost (no heartbeat for "
                              f"{now - rec.last_heartbeat:.0f} s)")
        return lost

    def unit_positions(self) -> dict[str, list[float]]:
        """Where each shown unit is now."""
        return {n: [r.latitude, r.longitude] for n, r in self.units.items()
                if r.shown and r.latitude is not None and r.longitude is not None}

    def units_since(self, seq: int) -> list[dict[str, Any]]:
        """Shown units changed after ``seq`` (without tracks, with their ``point``)."""
        return [r.to_json(track=False) for r in self.units.values() if r.seq > seq and r.shown]

    # ------------------------------------------------------------------ missions

    def _mission(self, root: str, now: float) -> MissionRecord:
        m = self.missions.get(root)
        if m is None:
            m = self.missions[root] = MissionRecord(id=root, created=now, scale=self.scale)
            self._node_mission[root] = root
            if not m.detailed:
                self._to_fetch.add(root)
            self._trim()
        return m

    def _trim(self) -> None:
        while len(self.missions) > MISSIONS_MAX:
            victim = next((k for k, m in self.missions.items() if m.ended),
                          next(iter(self.missions)))
            gone = self.missions.pop(victim)
            for uid in tree_uuids(gone.tree or {}):
                self._node_mission.pop(uid, None)
            for uid in part_uuids(gone.shown_plan):
                self._part_mission.pop(uid, None)
            self._node_mission.pop(victim, None)

    def hide(self, root: str) -> None:
        """Never show this mission (the page's own dry-run plans)."""
        self.hidden.add(root)
        if len(self.hidden) > 10_000:
            self.hidden.pop()
        self.missions.pop(root, None)
        self._to_fetch.discard(root)

    def drain_fetch(self) -> list[str]:
        """Missions heard of whose details (owner, plan, tree) the bridge should ask for."""
        out = sorted(self._to_fetch)
        self._to_fetch.clear()
        return out

    def _changed(self, m: MissionRecord, now: float) -> None:
        self.seq += 1
        self._item("mission", m.to_json(now))

    def _advance(self, m: MissionRecord, status: str, now: float, at: float | None = None) -> bool:
        """Move a mission's status forward only; True when it changed."""
        if m.ended or status == m.status:
            return False
        if status not in FINAL and MISSION_ORDER.get(status, -1) <= MISSION_ORDER.get(m.status, -1):
            return False
        m.status = status
        when = now if at is None else at
        if status in ("started", "running") and m.started_at is None:
            m.started_at = when
        if status in FINAL and m.ended_at is None:
            m.ended_at = when
        return True

    def mission_feedback(self, data: Mapping[str, Any], now: float) -> None:
        """One ``delegation/feedback`` message of the service."""
        root = data.get("root-uuid")
        status = data.get("status")
        if not isinstance(root, str) or not root or not isinstance(status, str):
            return
        if root in self.hidden:
            return
        first = root not in self.missions
        m = self._mission(root, now)
        reason = str(data.get("fail-reason") or "")
        if status == "re-delegated":
            m.redelegated_at = now
            moved = []
            for t in data.get("tasks") or []:
                if not isinstance(t, dict):
                    continue
                new, old = t.get("node-uuid"), t.get("replaces")
                unit = str(t.get("unit") or "").strip("/")
                if isinstance(new, str) and isinstance(old, str):
                    self._alias[new] = self._alias.get(old, old)
                    self._node_mission[new] = root
                    if old in self._part_mission:  # a part re-shared: its pieces are parts
                        self._part_mission[new] = root
                    if unit:
                        m.reassigned[self._alias[new]] = unit
                if unit and unit not in m.units:
                    m.units = sorted([*m.units, unit])
                moved.append(f"{t.get('name')} -> {unit}")
            self._changed(m, now)
            self._log(now, "re-delegated", root, None,
                      f"{m.name or root[:8]} re-delegated: {', '.join(moved) or '-'}"
                      + (f" ({reason})" if reason else ""))
            self._to_fetch.add(root)
            return
        if reason:
            m.fail_reason = reason
        if self._advance(m, status, now) or first:
            self._changed(m, now)
            self._log(now, status, root, None,
                      f"{m.name or root[:8]} {status}" + (f": {reason}" if reason else ""))

    def node_feedback(self, data: Mapping[str, Any], now: float) -> None:
        """One ``tst/feedback`` message of the service (the operator's tree's nodes)."""
        uid = data.get("node-uuid")
        status = data.get("status")
        if not isinstance(uid, str) or not isinstance(status, str):
            return
        uid = self._alias.get(uid, uid)
        root = self._node_mission.get(uid)
        if root is None or root not in self.missions:
            held = self._pending.setdefault(uid, [])
            if len(held) < 16:
                held.append((status, now))
            while len(self._pending) > PENDING_MAX:
                self._pending.popitem(last=False)
            return
        self._apply_node(self.missions[root], uid, status, now)

    def _apply_node(self, m: MissionRecord, uid: str, status: str, now: float) -> None:
        previous = m.node_status.get(uid)
        if previous in NODE_FINAL:
            # A node's end is kept, unless the mission was re-delegated after it: the task then
            # runs again (on another unit, under the operator's uuid) and ends again.
            ended = m.node_end.get(uid, now)
            if status == previous or m.redelegated_at is None or ended > m.redelegated_at:
                return
            m.node_end.pop(uid, None)
            m.node_start.pop(uid, None)
        m.node_status[uid] = status
        if status in ("running", "active") and uid not in m.node_start:
            m.node_start[uid] = now
        if status in NODE_FINAL:
            m.node_start.setdefault(uid, now)
            m.node_end.setdefault(uid, now)
        if uid == m.id and status in ("active", "running") and m.started_at is None:
            m.started_at = now
            self._changed(m, now)
        self.seq += 1
        self._item("node", self._node_item(m, uid))

    def _node_item(self, m: MissionRecord, uid: str) -> dict[str, Any]:
        return {"mission": m.id, "uuid": uid, "status": m.node_status.get(uid),
                "actual-start": m.rel(m.node_start.get(uid)),
                "actual-end": m.rel(m.node_end.get(uid))}

    def _index(self, m: MissionRecord) -> None:
        """Index the mission's node uuids and apply feedback that arrived before its tree."""
        uids = set(tree_uuids(m.tree or {}))
        uids.update(tree_uuids((m.plan or {}).get("tst") or {}))
        uids.update(tree_uuids(m.current_tst or {}))
        for uid in uids:
            self._node_mission[uid] = m.id
        parts = part_uuids(m.shown_plan)
        for uid in parts:
            self._part_mission[uid] = m.id
        engine = engine_of(m.plan) if parts else None
        if engine and len(self._engines) < 64:
            self._engines.add(engine)
        for uid in uids:
            for status, at in self._pending.pop(uid, []):
                self._apply_node(m, uid, status, at)

    def mission_planned(self, root: str, plan: Mapping[str, Any], tree: Mapping[str, Any] | None,
                        owner: str, now: float) -> None:
        """A plan the page itself asked for and started (the ``delegate`` answer)."""
        if root in self.hidden:
            return
        m = self._mission(root, now)
        m.owner = owner
        self._take_plan(m, plan)
        if tree is not None:
            m.tree = dict(tree)
        if not m.starts:
            m.starts = self.unit_positions()
        m.detailed = True
        self._to_fetch.discard(root)
        self._index(m)
        self._changed(m, now)

    def _take_plan(self, m: MissionRecord, plan: Mapping[str, Any]) -> None:
        m.plan = dict(plan)
        m.strategy = plan.get("strategy") or m.strategy
        fallback = plan.get("fallback")
        m.fallback = fallback if isinstance(fallback, str) and fallback else None
        m.objective = plan.get("objective") or m.objective
        makespan = number(plan.get("makespan"))
        m.makespan = round(makespan, 3) if makespan is not None else m.makespan
        tst = plan.get("tst")
        if isinstance(tst, dict):
            name = tst.get("name")
            m.name = m.name or (str(name) if isinstance(name, str) else "")
        m.units = sorted({str(a.get("execunit", "")).strip("/")
                          for a in plan.get("assignments") or [] if isinstance(a, dict)} - {""})

    def mission_summary(self, row: Mapping[str, Any], now: float) -> None:
        """One ``list-missions`` row (short form)."""
        m = self._summarised(row, now)
        if m is not None:
            self._changed(m, now)

    def _summarised(self, row: Mapping[str, Any], now: float) -> MissionRecord | None:
        """The mission a row (a summary or a ``query-mission`` answer) names, its summary
        fields taken; None when the row names none or one the operator hid."""
        root = row.get("root-uuid")
        if not isinstance(root, str) or not root or root in self.hidden:
            return None
        m = self._mission(root, now)
        self._summary_fields(m, row)
        return m

    def _summary_fields(self, m: MissionRecord, row: Mapping[str, Any]) -> None:
        m.name = str(row.get("name") or m.name)
        m.owner = str(row.get("owner") or m.owner)
        m.created = number(row.get("created")) or m.created
        started, ended = number(row.get("started")), number(row.get("ended"))
        m.started_at = started if started is not None else m.started_at
        m.ended_at = ended if ended is not None else m.ended_at
        status = row.get("status")
        forward = isinstance(status, str) and (
            status in FINAL or MISSION_ORDER.get(status, -1) > MISSION_ORDER.get(m.status, -1))
        if forward and not m.ended:
            m.status = str(status)
        if row.get("fail-reason"):
            m.fail_reason = str(row["fail-reason"])

    def mission_answer(self, mission: Mapping[str, Any], now: float) -> None:
        """A ``query-mission`` answer's ``mission``: owner, plan, tree, node statuses."""
        m = self._summarised(mission, now)
        if m is None:
            return
        if m.plan is None or not m.detailed:
            plan = {k: mission.get(k) for k in ("strategy", "fallback", "makespan", "assignments",
                                                "unassigned", "notes", "tst", "shared-searches")}
            if mission.get("objective"):
                plan["objective"] = mission["objective"]
            self._take_plan(m, plan)
        current = mission.get("current-tst")
        if isinstance(current, dict):
            m.current_tst = dict(current)
        received = mission.get("received")
        if isinstance(received, dict):
            m.tree = dict(received)
        elif m.tree is None and isinstance(mission.get("tst"), dict):
            m.tree = dict(mission["tst"])
        if not m.starts:
            m.starts = self.unit_positions()
        for node in mission.get("nodes") or []:
            if not isinstance(node, dict) or not isinstance(node.get("node-uuid"), str):
                continue
            uid = node["node-uuid"]
            status = node.get("status")
            if isinstance(status, str) and status != "not-active" and uid not in m.node_status:
                m.node_status[uid] = status
            for key, times in (("started", m.node_start), ("ended", m.node_end)):
                rel = number(node.get(key))
                if rel is not None and m.started_at is not None and uid not in times:
                    times[uid] = m.started_at + rel / m.scale
        m.detailed = True
        self._index(m)
        self._changed(m, now)

    def mission_json(self, root: str, now: float) -> dict[str, Any] | None:
        m = self.missions.get(root)
        return m.to_json(now) if m is not None else None

    def mission_record(self, root: str) -> MissionRecord | None:
        return self.missions.get(root)

    def node_tree(self, root: str) -> dict[str, Any] | None:
        """The operator's tree as NODE JSON with plan and actual times (docs/ui.md)."""
        m = self.missions.get(root)
        if m is None or m.tree is None:
            return None
        plan = m.shown_plan or {}
        planned: dict[str, tuple[float | None, float | None]] = {}
        for a in plan.get("assignments") or []:
            if isinstance(a, dict) and isinstance(a.get("node-uuid"), str):
                planned[a["node-uuid"]] = (number(a.get("start")), number(a.get("end")))
        units = {uid: unit for uid, unit in
                 ((a.get("node-uuid"), str(a.get("execunit", "")).strip("/"))
                  for a in plan.get("assignments") or [] if isinstance(a, dict))
                 if isinstance(uid, str)}
        units.update(m.reassigned)
        def actual(uid: str) -> tuple[str | None, float | None, float | None]:
            return m.node_status.get(uid), m.rel(m.node_start.get(uid)), m.rel(m.node_end.get(uid))

        parts = search_parts(plan, actual)
        # A search's planned interval is its plan's: re-shared pieces have no planned times.
        spans = {uid: span(first) for uid, first in search_parts(m.plan, actual).items()}
        return _node_json(m.tree, m, planned, units, parts, spans)

    # ------------------------------------------------------------------ log and reads

    def _log(self, now: float, kind: str, mission: str | None, unit: str | None,
             text: str) -> None:
        self.seq += 1
        event = {"seq": self.seq, "at": round(now, 3), "kind": kind, "mission": mission,
                 "unit": unit, "text": text}
        self.log.append(event)
        self._item("log", event)

    def _item(self, kind: str, data: dict[str, Any]) -> None:
        """Queue a stream item at the current ``seq``, remembering the newest one dropped."""
        if len(self.items) == self.items.maxlen:
            self._dropped = self.items[0][0]
        self.items.append((self.seq, kind, data))

    def items_since(self, seq: int) -> list[tuple[int, str, dict[str, Any]]] | None:
        """Mission, node and log items after ``seq``; None when some were already dropped (the
        stream must start again from a snapshot)."""
        if self._dropped > seq:
            return None
        return [item for item in self.items if item[0] > seq]

    def state(self, now: float, sees: Callable[[str], bool] | None = None) -> dict[str, Any]:
        """GET /api/state; with ``sees``, only the missions (and their events) it allows."""
        return {
            "seq": self.seq,
            "units": [r.to_json(track=True) for r in self.units.values() if r.shown],
            "missions": [m.to_json(now) for m in self.missions.values()
                         if sees is None or sees(m.id)],
            "events": [e for e in self.log
                       if sees is None or e["mission"] is None or sees(e["mission"])],
        }


def item_mission(kind: str, data: Mapping[str, Any]) -> str | None:
    """The mission a stream item is about (None: a unit's event, for everyone)."""
    found = data.get("id") if kind == "mission" else data.get("mission")
    return found if isinstance(found, str) else None


def _metres(p: list[float], lat: float, lon: float) -> float:
    """Equirectangular distance (m): exact enough for thinning a track."""
    dy = (lat - p[0]) * _M_PER_DEG
    dx = (lon - p[1]) * _M_PER_DEG * math.cos(math.radians(lat))
    return math.hypot(dx, dy)


def _node_json(tree: Mapping[str, Any], m: MissionRecord,
               planned: Mapping[str, tuple[float | None, float | None]],
               units: Mapping[str, str],
               parts: Mapping[str, list[dict[str, Any]]],
               spans: Mapping[str, tuple[float | None, float | None]]) -> dict[str, Any]:
    """NODE JSON of a tree (recursive on children; trees are bounded by the service's limits);
    a search shared among units carries its ``parts`` (as they are now) and its planned
    interval (``spans``: its planned parts')."""

    def build(node: Mapping[str, Any], depth: int) -> dict[str, Any]:
        uid = node_uuid_of(node) or ""
        kids = node.get("children") if depth < 64 else None
        shared = parts.get(uid)
        plan = spans.get(uid, (None, None)) if shared else planned.get(uid, (None, None))
        extra = {"parts": shared} if shared else {}
        return {**extra,
            "uuid": uid,
            "name": str(node.get("name", "")),
            "execunit": units.get(uid) or _node_execunit(node),
            "status": m.node_status.get(uid),
            "plan-start": plan[0],
            "plan-end": plan[1],
            "actual-start": m.rel(m.node_start.get(uid)),
            "actual-end": m.rel(m.node_end.get(uid)),
            "children": [build(c, depth + 1) for c in kids or [] if isinstance(c, dict)]
            if isinstance(kids, list) else [],
        }

    return build(tree, 0)

