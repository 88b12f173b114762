"""The fleet as the service plans with it (pure: ``now`` is passed in).

The registry's units with the speeds learnt from their flights, the rows of ``list-agents``, and
which units a new plan may use: battery, units excluded by a re-delegation, and units busy in
another running mission (left out, or planned from when and where they become free, by the
``commitments`` setting). Speed learning is fed here too: speed sensors, and the start and end of
every task whose speed class is known.
"""

from __future__ import annotations

import bisect
import logging
from collections.abc import Callable, Iterable
from dataclasses import replace
from typing import Any

from delegation.errors import InputError, MessageError
from delegation.fleet import FleetRegistry, UnitState
from delegation.geo import GeoPoint
from delegation.learning import SpeedLearner, speed_class
from delegation.messages import TERMINAL_NODE_STATUSES, MissionStatus, TstFeedback, decode
from delegation.service.config import ServiceConfig
from delegation.service.engine_link import EngineLink
from delegation.service.missions import Mission, MissionBook
from delegation.topics import parse_unit_topic
from delegation.tst.node import TstNode, stored_nodes, walk

log = logging.getLogger(__name__)

#: Node statuses after which a task no longer holds its unit.
TERMINAL = TERMINAL_NODE_STATUSES

#: Topics whose last decoded message is kept (`FleetView.observe`): ~10 per unit.
MAX_DECODED = 4096
#: The largest payload kept so (a flood of large messages on many topics keeps at most ~8 MB).
MAX_DECODED_BYTES = 2048


class FleetView:
    """Units to plan for and what is known of them (the registry, learnt speeds, commitments)."""

    def __init__(
        self,
        config: ServiceConfig,
        fleet: FleetRegistry,
        book: MissionBook,
        engine: EngineLink,
        epoch: Callable[[float], float],
    ) -> None:
        self.config = config
        self.fleet = fleet
        self.book = book
        self.engine = engine
        #: ``now`` as epoch seconds (mission records are epoch stamps).
        self.epoch = epoch
        #: Speeds learnt from the units' flights (`delegation.learning`).
        self.learner = SpeedLearner()
        self._task_class: dict[str, tuple[str, str]] = {}  # node-uuid -> (unit, speed class)
        self._alive: set[str] = set()  # units alive at the last tick (to log the silent ones)
        #: `committed`'s last answer and the revisions it was computed at.
        self._committed: tuple[tuple[int, int, str, int], dict[str, str]] | None = None
        #: Per mission: the units its unfinished tasks hold (none: not kept); read again only
        #: when it changed (a burst changes one mission between two plans).
        self._held: dict[str, frozenset[str]] = {}
        #: Per unit: (place in the book, root) of every mission holding it, in book order; and
        #: the book they were read from.
        self._holders: dict[str, list[tuple[int, str]]] = {}
        self._holds_of: MissionBook | None = None
        #: Per (mission, unit): `_last_end`'s answer and the (mission, unit, change, record) it
        #: was read at.
        self._ends: dict[tuple[str, str], tuple[tuple[str, str, int, int],
                                                tuple[float, GeoPoint | None] | None]] = {}
        #: Per topic: the last payload decoded and its message. A unit at rest publishes the
        #: same bytes on most of its topics twice a second: they are not decoded again (the
        #: registry still hears each one: a message refreshes "last seen").
        self._decoded: dict[str, tuple[bytes, Any]] = {}
        #: Per unit: the state it was last given its learnt speeds from, what was learnt then,
        #: and the result (`_learnt`).
        self._with_learnt: dict[str, tuple[UnitState, dict[str, float], UnitState]] = {}

    # ---- what the units say

    def observe(self, topic: str, payload: bytes, now: float) -> None:
        """Units, and the engine: the registry knows every heartbeat's base topic and age, and
        plans only for units on the direct execution level."""
        known = self._decoded.get(topic)
        if known is not None and known[0] == payload:
            message = known[1]
        else:
            try:
                message = decode(topic, payload)
            except MessageError as exc:
                log.debug("ignoring %s: %s", topic, exc)
                return
            if len(payload) <= MAX_DECODED_BYTES:  # periodic messages are small
                if len(self._decoded) >= MAX_DECODED and topic not in self._decoded:
                    self._decoded.clear()  # topics of units long gone: start again
                self._decoded[topic] = (bytes(payload), message)
        try:
            self.fleet.observe(topic, message, now)
        except InputError as exc:
            log.debug("fleet ignored %s: %s", topic, exc)
        if topic.endswith("/sensor/speed"):
            self._learn_speed(topic, message, now)

    def _learn_speed(self, topic: str, message: Any, now: float) -> None:
        parsed = parse_unit_topic(topic)
        value = getattr(message, "value", message)
        if parsed is None or isinstance(value, bool) or not isinstance(value, int | float):
            return
        cls = self.learner.observe_speed(parsed.name, float(value), now)
        if cls is not None:
            log.info("unit %s: learnt its %s speed, %.2f m/s (plans use it from now on)",
                     parsed.name, cls, self.learner.learnt(parsed.name)[cls])

    def planned(self, tree: TstNode) -> None:
        """Note the speed class of every task of a planned tree, to learn from its flight."""
        for _, node in walk(tree):
            cls = speed_class(node)
            if cls and node.node_uuid and isinstance(node.execunit, str):
                self._task_class[node.node_uuid] = (node.execunit.strip("/"), cls)

    def task_feedback(self, fb: TstFeedback, now: float) -> None:
        """A task of a planned tree started or ended: the learner times it."""
        task = self._task_class.get(fb.node_uuid)
        if task is not None and fb.status == "running":
            self.learner.task_started(task[0], fb.node_uuid, task[1], now)
        elif task is not None and fb.status in TERMINAL:
            self.learner.task_ended(task[0], fb.node_uuid, now)
            del self._task_class[fb.node_uuid]

    def log_silent(self, now: float) -> None:
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

    # ---- views

    def units(self, now: float) -> tuple[UnitState, ...]:
        """The units to plan for (the registry leaves out engines and delegators), with the
        speeds learnt from their flights: this service's own fleet (`own`)."""
        own = self.own(now)
        return tuple(self._learnt(u) for u in self.fleet.snapshot(now) if own(u.name))

    def _learnt(self, unit: UnitState) -> UnitState:
        """``unit`` with its learnt speeds (`SpeedLearner.apply`), the same object again while
        neither the unit nor what was learnt of it changed (asked for every unit per plan)."""
        learnt = self.learner.learnt(unit.name)
        if not learnt:
            return unit
        known = self._with_learnt.get(unit.name)
        if known is not None and known[0] is unit and known[1] == learnt:
            return known[2]
        (applied,) = self.learner.apply((unit,))
        self._with_learnt[unit.name] = (unit, learnt, applied)
        return applied

    def own(self, now: float) -> Callable[[str], bool]:
        """Whether a unit is this service's: named in ``fleet`` when that is set, else any unit
        no other live delegator says it manages (reached by offers, docs/protocol.md §15.1)."""
        if self.config.fleet:
            return self.config.fleet.__contains__
        managed = self.fleet.managed_by(now)
        return lambda name: name not in managed

    def summary(self, now: float) -> tuple[list[str], list[str]]:
        """(tasks available, units managed) of the own live fleet, for ``delegation_info``. Only
        a fleet named with ``--fleet`` is claimed: a service that plans for whatever it hears
        claims nothing, so a second service on the same broker (a test instance, a service
        started a moment earlier) does not take every unit from the others by claiming first."""
        live = [u for u in self.units(now) if u.alive]
        managed = sorted(u.name for u in live) if self.config.fleet else []
        return sorted({t for u in live for t in u.tasks}), managed

    def speed_sources(self, units: Iterable[UnitState]) -> dict[str, str]:
        """Per unit: ``learnt``, ``profile`` or ``default`` (`delegation.learning`)."""
        return {u.name: self.learner.source(u.name, self.fleet.has_profile_speeds(u.name))
                for u in units}

    def agents(self, now: float) -> list[dict[str, Any]]:
        """The live units for ``list-agents``: those that can be delegated to (own units with
        their planning speeds, and other delegators, ``delegator: true``), and the units other
        delegators manage (``managed-by``: reached only through offers to it)."""
        units = {u.name: u for u in self.units(now)}
        sources = self.speed_sources(units.values())
        rows = []
        for row in self.fleet.agents(now, alive_only=True):
            if row["name"] in units:
                rows.append({**row, "speeds": units[row["name"]].speeds,
                             "speeds-source": sources[row["name"]]})
            elif row.get("delegator") or row.get("managed-by"):
                rows.append(row)
        return rows

    def ready(self, units: Iterable[str], engine: bool, now: float) -> bool:
        """True once the named units (and the engine, with ``engine``) are live as seen here."""
        if engine and self.engine.base(now) is None:
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
        busy = self.committed(mission) if mode != "share" else {}
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
                free = self.free_at(unit, busy[unit.name], now) if mode == "wait" else None
                if free is None:
                    notes.append(f"{unit.name}: left out, busy in mission {busy[unit.name]}")
                    continue
                units.append(replace(unit, available_at=free[0], position=free[1]))
                notes.append(f"{unit.name}: busy in mission {busy[unit.name]}, planned from when "
                             f"and where it becomes free (in {free[0]:.0f} s)")
            else:
                units.append(unit)
        return tuple(units), tuple(notes)

    def free_at(self, unit: UnitState, root: str, now: float) -> tuple[float, GeoPoint] | None:
        """(seconds from now, position) when ``unit`` ends its last task in mission ``root``, by
        that mission's plan; None when the plan does not say (a re-delegated tree, or a task
        moved onto the unit since). Asked for every busy unit per plan: what the mission says
        is kept until it changes (`MissionBook.changed_at`)."""
        m = self.book.find(root)
        if m is None:
            return None
        key = (root, unit.execunit, self.book.changed_at.get(root, 0), id(m))
        ends = self._ends.get(key[:2])
        if ends is None or ends[0] != key:
            ends = (key, self._last_end(m, unit))
            self._ends[key[:2]] = ends
            if len(self._ends) > 4 * len(self.book) + 100:  # forget the missions that left
                self._ends = {k: v for k, v in self._ends.items() if k[0] in self.book}
        if ends[1] is None:
            return None
        end, where_then = ends[1]
        began = m.started_at if m.started_at is not None else self.epoch(now)
        wait = max(0.0, began + end - self.epoch(now))
        return wait, where_then if where_then is not None else unit.position

    def _last_end(self, m: Mission, unit: UnitState) -> tuple[float, GeoPoint | None] | None:
        """(end of ``unit``'s last task in ``m``'s plan, where that task ends: None for where the
        unit is), or None when the plan does not say (see `free_at`)."""
        mine = [a for a in m.plan.get("assignments", [])
                if a.get("execunit") == unit.execunit and m.node_status.get(
                    a.get("node-uuid", "")) not in TERMINAL]
        if not mine or any(a.get("node-uuid") not in m.current_nodes for a in mine):
            return None
        planned = {a.get("node-uuid") for a in mine}
        if any(m.nodes[uid].is_task and m.nodes[uid].execunit == unit.execunit
               and uid not in planned and m.node_status.get(uid) not in TERMINAL
               for uid in m.current_nodes):
            return None  # a task moved onto it (re-delegated in place): its end is not known
        last = max(mine, key=lambda a: float(a.get("end", 0.0)))
        name, params = _node_in(m.current_tst, str(last.get("node-uuid")))
        points = ([params.get("waypoint")] if name == "move-to"
                  else list(params.get("waypoints", [])) if name == "move-path" else [])
        try:
            where_then = GeoPoint.model_validate(points[-1]) if points else None
        except ValueError:
            where_then = None
        return float(last.get("end", 0.0)), where_then

    def committed(self, but: str = "") -> dict[str, str]:
        """Unit -> a running mission (other than ``but``) with a task on it not yet ended.
        Asked twice per plan and a walk of every open mission: kept until the book or the
        engine's starts change."""
        key = (self.book.revision, self.engine.revision, but, id(self.book))
        if self._committed is not None and self._committed[0] == key:
            return dict(self._committed[1])
        busy = self._busy(but)
        self._committed = (key, busy)
        return dict(busy)

    def _busy(self, but: str) -> dict[str, str]:
        """Unit -> the mission earliest in the book (other than ``but``) holding it. Only the
        missions changed since the last call are read again (`MissionBook.touched`,
        `EngineLink.touched`): a burst adds one mission between two plans."""
        book = self.book
        if self._holds_of is not book:  # a new book (restored): read every mission
            self._holds_of, self._held, self._holders = book, {}, {}
            changed: set[str] = {m.root_uuid for m in book}
        else:
            changed = book.touched | self.engine.touched
        book.touched.clear()
        self.engine.touched.clear()
        for root in changed:
            self._rehold(root)
        busy: dict[str, str] = {}
        for unit, holders in self._holders.items():
            first = holders[0][1] if holders[0][1] != but else \
                holders[1][1] if len(holders) > 1 else None
            if first is not None:
                busy[unit] = first
        return busy

    def _rehold(self, root: str) -> None:
        """Read again which units mission ``root`` holds (none once it left the book)."""
        m = self.book.in_memory(root)
        now_held = frozenset(_held_units(m, self.engine.starting(root))) if m else frozenset()
        for unit in self._held.pop(root, frozenset()):  # its place may have moved: re-added
            holders = self._holders[unit]
            holders.remove(next(h for h in holders if h[1] == root))
            if not holders:
                del self._holders[unit]
        if now_held:
            self._held[root] = now_held
        place = (self.book.order.get(root, 0), root)
        for unit in now_held:
            bisect.insort(self._holders.setdefault(unit, []), place)


def _held_units(m: Mission, starting: bool) -> tuple[str, ...]:
    """The units ``m``'s unfinished tasks are on (none once it ended, or while it is planned
    only: ``start: false``)."""
    if m.ended or (m.status is MissionStatus.PLANNED and not starting):
        return ()
    units = []
    for uid in m.current_nodes:
        info, status = m.nodes[uid], m.node_status.get(uid)
        if info.is_task and info.execunit and status not in TERMINAL:
            units.append(info.execunit.strip("/"))
    return tuple(units)


def _node_in(tree: dict[str, Any], node_uuid: str) -> tuple[str, dict[str, Any]]:
    """(name, params) of the node ``node_uuid`` in an instantiated tree as stored (JSON), or
    ("", {}): read without building the tree, as it is asked for every busy unit per plan."""
    for node, common in stored_nodes(tree):
        if common.get("node-uuid") == node_uuid:
            params = node.get("params")
            return str(node.get("name", "")), params if isinstance(params, dict) else {}
    return "", {}
