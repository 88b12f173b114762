"""Mission book-keeping for the delegation service (pure state).

The service core feeds these values with decoded messages and ``now``; nothing here reads the
clock, touches the network or locks. The book is an in-memory map; persistence is the unit's
(`delegation.service.store`): every mutation goes through a method that notes the mission in
``dirty``, the unit drains it after each step and writes those missions before publishing. Missions
that left memory (`forget_ended`) are read back through an injected `MissionArchive`. Command
idempotency is `delegation.runtime.commands.CommandLog`, shared by every unit.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from enum import IntFlag
from typing import Any, Protocol

from delegation.errors import InputError, InputProblem
from delegation.messages import FINAL_MISSION_STATUSES, TERMINAL_NODE_STATUSES, MissionStatus
from delegation.service.operator_view import OperatorView
from delegation.service.redelegation import first_origin, statuses_by_first
from delegation.tst.node import TstNode, parse_tree, walk

#: Statuses only move forward: a late "started" answer cannot undo "running".
_RANK = {MissionStatus.PLANNED: 0, MissionStatus.STARTED: 1, MissionStatus.RUNNING: 2}

#: Root node statuses from the engine (seed 14.5) that end a mission, and what they mean.
_ROOT_FINAL: dict[str, MissionStatus] = {
    "succeeded": MissionStatus.SUCCEEDED,
    "failed": MissionStatus.FAILED,
    "aborted": MissionStatus.ABORTED,
    "revoked": MissionStatus.ABORTED,
}


@dataclass(frozen=True, slots=True)
class NodeInfo:
    """What the mission knows about one node of its instantiated tree."""

    node_uuid: str
    name: str
    execunit: str
    path: str
    is_task: bool


@dataclass(frozen=True, slots=True)
class LifecycleEvent:
    """A mission status change, to be published on ``delegation/feedback``."""

    root_uuid: str
    status: MissionStatus
    fail_reason: str = ""


@dataclass(slots=True)
class Mission:
    """One delegated tree: its plan, where it is, and what every node did and when."""

    root_uuid: str
    source: str  # "tst" (start-tst on the TST face) or "delegate"
    created: float
    tst: dict[str, Any]  # the fully instantiated tree, as sent to the engine
    plan: dict[str, Any]  # docs/plan.md §1
    nodes: dict[str, NodeInfo]
    #: Who created it ("" anonymous: anyone may manage it); see ``service.access``.
    owner: str = ""
    status: MissionStatus = MissionStatus.PLANNED
    fail_reason: str = ""
    started_at: float | None = None
    ended_at: float | None = None
    node_status: dict[str, str] = field(default_factory=dict)
    node_started: dict[str, float] = field(default_factory=dict)  # first "running"
    node_ended: dict[str, float] = field(default_factory=dict)  # first final status
    #: The tree as received (validated, uuids completed), and the command that created it.
    received: dict[str, Any] | None = None
    command: tuple[str, str] | None = None  # (face, com-uuid)
    #: The root uuid of the tree the engine executes for this mission: ``root_uuid`` until a
    #: re-delegation replaces the tree, ``""`` while a replacement is being planned (no root
    #: status then ends the mission).
    current_root: str = ""
    #: The tree the engine executes (``tst`` until a re-delegation).
    current_tst: dict[str, Any] = field(default_factory=dict)
    #: Node uuid of a replacement tree -> the node it replaces.
    origin: dict[str, str] = field(default_factory=dict)
    #: Re-delegations per original task uuid (the retry budget).
    retries: dict[str, int] = field(default_factory=dict)
    redelegations: int = 0
    #: The node uuids of the current tree.
    current_nodes: set[str] = field(default_factory=set)
    #: The operator's own tree (the tree sent may regroup its control nodes): what feedback and
    #: ``query-mission`` show. None: the sent tree is shown as it is.
    operator: OperatorView | None = None
    #: Task node uuid -> (unit, task-uuid) of the last ``start-task`` the engine was seen to send
    #: for it: what the service asks the unit about (``query-status``) when the engine cannot say
    #: how the tree stands (`delegation.service.unit_catch_up`).
    node_tasks: dict[str, tuple[str, str]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.current_root = self.current_root or self.root_uuid
        self.current_tst = self.current_tst or self.tst
        self.current_nodes = self.current_nodes or set(self.nodes)

    @property
    def redelegating(self) -> bool:
        """True while a replacement tree is being planned or sent."""
        return not self.current_root

    def operator_statuses(self) -> dict[str, str]:
        """Node statuses under the first tree's uuids (the operator's), whatever tree runs now."""
        if not self.origin:
            return self.node_status
        return statuses_by_first(self.node_status, self.origin, self.current_nodes)

    @property
    def ended(self) -> bool:
        """True once the mission succeeded, failed or was aborted."""
        return self.status in FINAL_MISSION_STATUSES

    @property
    def name(self) -> str:
        root = self.nodes.get(self.root_uuid)
        return root.name if root else ""

    def summary(self) -> dict[str, Any]:
        """The short form listed by ``list-missions``."""
        return {
            "root-uuid": self.root_uuid,
            "name": self.name,
            "source": self.source,
            "owner": self.owner,
            "status": self.status.value,
            "fail-reason": self.fail_reason,
            "created": self.created,
            "started": self.started_at,
            "ended": self.ended_at,
        }

    def to_json(self) -> dict[str, Any]:
        """The full form answered by ``query-mission``: status, node statuses, assignments."""
        nodes = []
        view = self.operator
        statuses = self.operator_statuses()
        # The node standing for each of the first tree's now (its unit may have changed).
        now_for = {first_origin(self.origin, u): u for u in self.current_nodes} \
            if self.origin else {}
        for uid, info in self.nodes.items():
            if view is not None and uid not in view:
                continue  # only in the sent tree
            status = (view.derive(uid, statuses) if view is not None
                      else statuses.get(uid, "not-active"))
            nodes.append(
                {
                    "node-uuid": uid,
                    "name": info.name,
                    "execunit": self.nodes.get(now_for.get(uid, uid), info).execunit,
                    "path": info.path,
                    "status": status,
                    "started": _rel(self.node_started.get(uid), self.started_at),
                    "ended": _rel(self.node_ended.get(uid), self.started_at),
                }
            )
        return {
            **self.summary(),
            "nodes": nodes,
            "assignments": list(self.plan.get("assignments", [])),
            "unassigned": list(self.plan.get("unassigned", [])),
            # Searches shared among units and their parts (DESIGN 3.11; the page draws them).
            "shared-searches": list(self.plan.get("shared-searches", [])),
            "makespan": self.plan.get("makespan"),
            "strategy": self.plan.get("strategy"),
            # The strategy whose plan this is when the strategy fell back to it (docs/plan.md §1).
            "fallback": self.plan.get("fallback"),
            "objective": self.plan.get("objective"),
            "current-root": self.current_root,
            "re-delegations": self.redelegations,
            "notes": list(self.plan.get("notes", [])),
            "tst": self.tst,
            # The operator's own tree (uuids completed): what node feedback is about (§8).
            "received": self.received,
            # After a re-delegation, the tree the engine executes now (a lost unit's remainder
            # of a search runs in its task's place: the page draws those pieces, DESIGN 3.11).
            **({"current-tst": self.current_tst} if self.current_tst is not self.tst else {}),
        }


class Change(IntFlag):
    """What of a mission changed since it was last stored (the store writes only that part)."""

    STATE = 1
    """Status, times, node statuses, retries: `mission_state`."""
    TREE = 2
    """The tree the engine executes was replaced (a re-delegation): `mission_tree`."""
    NEW = 4
    """Not stored yet (or replaced): every part, the unchanging one (`mission_fixed`) too."""


def _nodes(nodes: dict[str, NodeInfo]) -> list[list[Any]]:
    return [[i.node_uuid, i.name, i.execunit, i.path, i.is_task] for i in nodes.values()]


def mission_fixed(m: Mission) -> dict[str, Any]:
    """What never changes once a mission exists: the trees received and sent, the plan (its
    ``tst`` is the sent tree, kept once), the command, the owner. Written once."""
    plan = m.plan
    plan_tst = plan.get("tst") is m.tst
    return {
        "root-uuid": m.root_uuid,
        "source": m.source,
        "created": m.created,
        "tst": m.tst,
        "plan": {k: v for k, v in plan.items() if k != "tst"} if plan_tst else plan,
        "plan-tst": plan_tst,
        "nodes": _nodes(m.nodes),
        "received": m.received,
        "command": list(m.command) if m.command else None,
        "operator-view": m.operator is not None,  # rebuilt from `received` and `tst` on load
        "owner": m.owner,
    }


def mission_state(m: Mission) -> dict[str, Any]:
    """What moves while a mission runs (small: statuses and times)."""
    return {
        "status": m.status.value,
        "fail-reason": m.fail_reason,
        "started": m.started_at,
        "ended": m.ended_at,
        "node-status": m.node_status,
        "node-started": m.node_started,
        "node-ended": m.node_ended,
        "current-root": m.current_root,
        "retries": m.retries,
        "redelegations": m.redelegations,
        "node-tasks": {uid: list(pair) for uid, pair in m.node_tasks.items()},
    }


def mission_tree(m: Mission) -> dict[str, Any] | None:
    """The tree the engine executes after a re-delegation, its nodes and where they came from;
    None while it is still the tree sent first."""
    if (not m.redelegations and not m.origin and m.current_nodes == set(m.nodes)
            and (m.current_tst is m.tst or m.current_tst == m.tst)):
        return None
    return {
        "current-tst": m.current_tst,
        "current-nodes": sorted(m.current_nodes),
        "origin": m.origin,
        "nodes": _nodes(m.nodes),  # the replacement trees' nodes joined the mission
    }


def mission_record(m: Mission) -> dict[str, Any]:
    """Every field of a mission as JSON-able data (the three parts the store keeps, in one;
    `mission_from_record` reads it back)."""
    return {**mission_fixed(m), **mission_state(m), **(mission_tree(m) or {})}


def mission_from_record(r: dict[str, Any]) -> Mission:
    """The mission `mission_record` wrote (or the parts merged; a record of an earlier version,
    with the plan's ``tst`` in it, reads the same)."""
    nodes = {n[0]: NodeInfo(n[0], n[1], n[2], n[3], bool(n[4])) for n in r["nodes"]}
    command = r.get("command")
    received = r.get("received")
    plan = {**r["plan"], "tst": r["tst"]} if r.get("plan-tst") else r["plan"]
    return Mission(
        root_uuid=r["root-uuid"], source=r["source"], created=r["created"], tst=r["tst"],
        plan=plan, nodes=nodes, status=MissionStatus(r["status"]),
        fail_reason=r["fail-reason"], started_at=r["started"], ended_at=r["ended"],
        node_status=dict(r["node-status"]), node_started=dict(r["node-started"]),
        node_ended=dict(r["node-ended"]), received=received,
        command=(command[0], command[1]) if command else None,
        current_root=r.get("current-root", ""),
        current_tst=r.get("current-tst") or {},
        current_nodes=set(r.get("current-nodes") or ()),
        origin=dict(r.get("origin") or {}),
        retries=dict(r.get("retries") or {}),
        redelegations=int(r.get("redelegations") or 0),
        owner=str(r.get("owner") or ""),
        node_tasks={uid: (str(pair[0]), str(pair[1]))
                    for uid, pair in (r.get("node-tasks") or {}).items()},
        # The operator's view is derived again from the tree received and the tree sent.
        operator=(OperatorView.of(parse_tree(received), parse_tree(r["tst"]),
                                  _part_map(r.get("plan") or {}))
                  if received and r.get("operator-view") else None),
    )


class MissionArchive(Protocol):
    """Where missions that left memory are read back (the store; implemented by the unit)."""

    def load_mission(self, root_uuid: str) -> Mission | None:
        """One mission by root uuid, or None."""
        ...

    def page_missions(self, offset: int, limit: int) -> tuple[list[dict[str, Any]], int]:
        """Summaries (oldest first) of every mission, from ``offset``, at most ``limit``; and
        how many there are in all."""
        ...


def _rel(t: float | None, origin: float | None) -> float | None:
    """Seconds since mission start (the plan's clock), or None."""
    if t is None or origin is None:
        return None
    return round(t - origin, 3)


def node_infos(tree: TstNode) -> dict[str, NodeInfo]:
    """Index an instantiated tree's nodes by uuid (every node has one after instantiation)."""
    out: dict[str, NodeInfo] = {}
    for path, node in walk(tree):
        uid = node.node_uuid
        if uid is None:
            continue
        unit = node.execunit if isinstance(node.execunit, str) else ""
        out[uid] = NodeInfo(uid, node.name, unit, path, not node.is_control)
    return out


def _with_execunits(tst: dict[str, Any], execunits: dict[str, str]) -> dict[str, Any]:
    """A copy of the JSON tree ``tst`` with the ``execunit`` of the nodes named changed (either
    spelling of ``common_params``; walked with a stack, any depth)."""
    root = dict(tst)
    stack = [root]
    while stack:
        node = stack.pop()
        for key in ("common_params", "common-params"):
            common = node.get(key)
            if isinstance(common, dict) and common.get("node-uuid") in execunits:
                node[key] = {**common, "execunit": execunits[common["node-uuid"]]}
        children = node.get("children")
        if isinstance(children, list):
            node["children"] = [dict(c) if isinstance(c, dict) else c for c in children]
            stack.extend(c for c in node["children"] if isinstance(c, dict))
    return root


def _with_subtrees(tst: dict[str, Any], subtrees: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """A copy of the JSON tree ``tst`` with the nodes named replaced by the subtrees given."""

    def common(node: dict[str, Any]) -> dict[str, Any]:
        got = node.get("common_params", node.get("common-params"))
        return got if isinstance(got, dict) else {}

    root = dict(tst)
    if common(root).get("node-uuid") in subtrees:
        return dict(subtrees[common(root)["node-uuid"]])
    stack = [root]
    while stack:
        node = stack.pop()
        children = node.get("children")
        if isinstance(children, list):
            node["children"] = [
                dict(subtrees.get(str(common(c).get("node-uuid")), c)) if isinstance(c, dict)
                else c
                for c in children]
            stack.extend(c for c in node["children"] if isinstance(c, dict))
    return root


class MissionBook:
    """Every mission the service has planned or run, indexed by root and by node uuid."""

    def __init__(self, archive: MissionArchive | None = None) -> None:
        self._missions: dict[str, Mission] = {}
        self._node_root: dict[str, str] = {}
        self.archive = archive
        #: Root uuid -> what changed since the unit last drained it (to persist; kept only with
        #: an archive, so a book nobody drains does not grow).
        self.dirty: dict[str, Change] = {}
        #: Counts changes (every `touch`, every mission forgotten): what is derived from the
        #: whole book (`FleetView.committed`) is computed again only when it moved.
        self.revision = 0
        #: Root uuid -> the `revision` of its last change (what is derived per mission is kept
        #: until it moves), in the order of those revisions (the last changed last): what
        #: changed since a revision is read from the end, not by a walk of the whole book.
        self.changed_at: dict[str, int] = {}
        #: Root uuid -> its place in the book (added later, greater), and the missions changed
        #: or forgotten since `FleetView` last read them (`touched`; it empties the set).
        self.order: dict[str, int] = {}
        self.touched: set[str] = set()
        self._added = 0

    def touch(self, root_uuid: str, change: Change = Change.STATE) -> None:
        """Note what of a mission changed (every mutating method does, only when something did;
        code that changes a `Mission` in place must call it too)."""
        self.revision += 1
        self.changed_at.pop(root_uuid, None)  # to the end: `changed_since` reads from there
        self.changed_at[root_uuid] = self.revision
        self.touched.add(root_uuid)
        if self.archive is not None and root_uuid in self._missions:
            self.dirty[root_uuid] = self.dirty.get(root_uuid, Change(0)) | change

    def changed_since(self, revision: int) -> list[str]:
        """The missions in memory changed after ``revision``, the last changed last."""
        changed = []
        for root, at in reversed(self.changed_at.items()):
            if at <= revision:
                break
            changed.append(root)
        changed.reverse()
        return changed

    def drain_dirty(self) -> list[tuple[Mission, Change]]:
        """The missions changed since the last call (in memory) with what changed, and forget
        the notes."""
        changed = [(self._missions[r], c) for r, c in sorted(self.dirty.items())
                   if r in self._missions]
        self.dirty.clear()
        return changed

    def undrain(self, changed: Iterable[tuple[Mission, Change]]) -> None:
        """Note again what `drain_dirty` returned (it could not be stored: the next try writes
        it)."""
        for mission, change in changed:
            self.touch(mission.root_uuid, change)

    def forget_ended(self, ended_before: float) -> list[str]:
        """Drop from memory the missions that ended before ``ended_before`` (they stay in the
        archive); returns their root uuids. Nothing is dropped while it is still dirty."""
        gone = [m.root_uuid for m in self._missions.values()
                if m.ended and m.ended_at is not None and m.ended_at < ended_before
                and m.root_uuid not in self.dirty]
        for root in gone:
            self._remove(root)
        return gone

    def _remove(self, root_uuid: str) -> Mission | None:
        old = self._missions.pop(root_uuid, None)
        if old is not None:
            self.revision += 1
            self.changed_at.pop(root_uuid, None)
            self.order.pop(root_uuid, None)
            self.touched.add(root_uuid)
            for uid in old.nodes:
                if self._node_root.get(uid) == old.root_uuid:
                    del self._node_root[uid]
        return old

    def page(self, offset: int, limit: int) -> tuple[list[dict[str, Any]], int]:
        """Summaries (oldest first) from ``offset``, at most ``limit``, and the total: from the
        archive when there is one (it holds every mission, memory only the recent ones)."""
        if self.archive is not None:
            return self.archive.page_missions(offset, limit)
        ordered = sorted(self._missions.values(), key=lambda m: (m.created, m.root_uuid))
        return [m.summary() for m in ordered[offset:offset + limit]], len(ordered)

    def __len__(self) -> int:
        return len(self._missions)

    def __iter__(self) -> Iterator[Mission]:
        return iter(list(self._missions.values()))

    def __contains__(self, root_uuid: object) -> bool:
        return root_uuid in self._missions

    def conflicts(self, tree: TstNode) -> list[InputProblem]:
        """Node uuids of ``tree`` already used by a mission that has not ended."""
        problems: list[InputProblem] = []
        for path, node in walk(tree):
            uid = node.node_uuid
            root = self._node_root.get(uid) if uid else None
            if root is not None and not self._missions[root].ended:
                problems.append(
                    InputProblem(
                        path,
                        "common_params.node-uuid",
                        f"{uid} is already part of mission {root} "
                        f"({self._missions[root].status.value})",
                    )
                )
        return problems

    def add(self, mission: Mission) -> None:
        """Record a new mission; an ended mission with the same uuids is replaced."""
        self._remove(mission.root_uuid)
        self._missions[mission.root_uuid] = mission
        self._added += 1
        self.order[mission.root_uuid] = self._added
        for uid in mission.nodes:
            self._node_root[uid] = mission.root_uuid
        self.touch(mission.root_uuid, Change.NEW)

    def replace_tree(
        self, mission: Mission, tst: dict[str, Any], root: str, nodes: dict[str, NodeInfo],
        origin: dict[str, str],
    ) -> None:
        """A re-delegation: the mission continues with a new tree (its nodes join the mission)."""
        mission.current_tst = tst
        mission.current_nodes = set(nodes)
        mission.origin.update(origin)
        mission.nodes.update(nodes)
        for uid in nodes:
            self._node_root[uid] = mission.root_uuid
        mission.current_root = root
        mission.redelegations += 1
        if mission.operator is not None:
            mission.operator.reset()
        self.touch(mission.root_uuid, Change.TREE | Change.STATE)

    def rebind(self, mission: Mission, execunits: dict[str, str]) -> None:
        """Tasks of the running tree moved to other units (``rebind-tst-nodes``, node uuid ->
        ``/unit``): same nodes, same tree, new units."""
        for uid, unit in execunits.items():
            info = mission.nodes.get(uid)
            if info is not None:
                mission.nodes[uid] = NodeInfo(uid, info.name, unit, info.path, info.is_task)
        mission.current_tst = _with_execunits(mission.current_tst, execunits)
        mission.redelegations += 1
        self.touch(mission.root_uuid, Change.TREE | Change.STATE)

    def graft(self, mission: Mission, subtrees: dict[str, dict[str, Any]]) -> None:
        """Nodes of the running tree replaced by subtrees under their uuids
        (``rebind-tst-nodes`` ``subtrees``: a lost unit's unswept remainder shared again, a lost
        delegator's part run by our own units); the subtrees' nodes join the mission, their
        paths under the node they replace, and the nodes under a replaced one leave it."""
        replaced = {uid: node for _, node in walk(parse_tree(mission.current_tst))
                    if (uid := node.node_uuid or "") in subtrees}
        for uid, raw in subtrees.items():
            if uid in replaced:  # the nodes under it (a subtree replaced) leave the tree
                mission.current_nodes.difference_update(
                    n.node_uuid or "" for _, n in walk(replaced[uid]) if n.node_uuid != uid)
            info = mission.nodes.get(uid)
            where_ = info.path if info is not None else "root"
            for new_uid, new in node_infos(parse_tree(raw)).items():
                path = where_ + new.path.removeprefix("root")
                mission.nodes[new_uid] = NodeInfo(new_uid, new.name, new.execunit, path,
                                                  new.is_task)
                mission.current_nodes.add(new_uid)
                self._node_root[new_uid] = mission.root_uuid
        mission.current_tst = _with_subtrees(mission.current_tst, subtrees)
        mission.redelegations += 1
        self.touch(mission.root_uuid, Change.TREE | Change.STATE)

    def get(self, root_uuid: str) -> Mission:
        """The mission with this root uuid; ``InputError`` naming it if there is none."""
        mission = self.find(root_uuid)
        if mission is None:
            raise InputError(InputProblem("command", "root-uuid", f"unknown mission {root_uuid!r}"))
        return mission

    def in_memory(self, root_uuid: str) -> Mission | None:
        """The mission if it is in memory (the archive is not asked)."""
        return self._missions.get(root_uuid)

    def find(self, root_uuid: str) -> Mission | None:
        """In memory, else in the archive (a mission past its retention; not brought back)."""
        mission = self._missions.get(root_uuid)
        if mission is None and self.archive is not None:
            mission = self.archive.load_mission(root_uuid)
        return mission

    def of_node(self, node_uuid: str) -> Mission | None:
        """The mission a node belongs to, if any."""
        root = self._node_root.get(node_uuid)
        return self._missions.get(root) if root is not None else None

    def set_status(
        self, root_uuid: str, status: MissionStatus, now: float, fail_reason: str = ""
    ) -> LifecycleEvent | None:
        """Move a mission on; returns the event to publish, or None if nothing changed.

        A mission that has ended stays ended: a late feedback cannot revive it.
        """
        mission = self._missions.get(root_uuid)
        if mission is None or mission.ended or mission.status is status:
            return None
        if status not in FINAL_MISSION_STATUSES and _RANK[status] <= _RANK[mission.status]:
            return None
        if status in (MissionStatus.STARTED, MissionStatus.RUNNING) and mission.started_at is None:
            mission.started_at = now
        if status in FINAL_MISSION_STATUSES:
            mission.ended_at = now
        mission.status = status
        mission.fail_reason = fail_reason
        self.touch(root_uuid)
        return LifecycleEvent(root_uuid, status, fail_reason)

    def observe_feedback(
        self, node_uuid: str, status: str, root_flag: bool, fail_reason: str, now: float
    ) -> tuple[Mission | None, list[LifecycleEvent]]:
        """Apply one engine ``tst/feedback``; returns its mission and the lifecycle events.

        A node's first ``running`` and first final status are timestamped (plan vs actual).
        """
        mission = self.of_node(node_uuid)
        if mission is None:
            return None, []
        if _note_node(mission, node_uuid, status, now):
            self.touch(mission.root_uuid)  # a repeated status (a re-sent feedback) changes nothing
        events: list[LifecycleEvent] = []
        # Only the root of the tree the engine executes for the mission now ends it.
        is_root = node_uuid == mission.current_root
        if not is_root:
            return mission, events
        if status in ("running", "active", "waiting") and mission.status in (
            MissionStatus.PLANNED,
            MissionStatus.STARTED,
        ):
            if mission.status is MissionStatus.PLANNED:
                ev = self.set_status(mission.root_uuid, MissionStatus.STARTED, now)
                if ev:
                    events.append(ev)
            if status == "running":
                ev = self.set_status(mission.root_uuid, MissionStatus.RUNNING, now)
                if ev:
                    events.append(ev)
        final = _ROOT_FINAL.get(status)
        if final is not None:
            reason = fail_reason
            if final is MissionStatus.FAILED and not reason:
                reason = failed_nodes_reason(mission)
            ev = self.set_status(mission.root_uuid, final, now, reason)
            if ev:
                events.append(ev)
        return mission, events


def _note_node(mission: Mission, node_uuid: str, status: str, now: float) -> bool:
    """A node's status (a final one stays) and its first ``running`` and first final times;
    True when any of it changed."""
    changed = False
    old = mission.node_status.get(node_uuid)
    if old not in TERMINAL_NODE_STATUSES and old != status:
        mission.node_status[node_uuid] = status
        changed = True
    times = (mission.node_started if status == "running"
             else mission.node_ended if status in TERMINAL_NODE_STATUSES else None)
    if times is not None and node_uuid not in times:
        times[node_uuid] = now
        changed = True
    return changed


def failed_nodes_reason(mission: Mission) -> str:
    """A fail-reason naming the task nodes that failed, for a root that failed without one."""
    parts = [
        f"{info.path} ({info.name} {uid} on {info.execunit or '?'}) failed"
        for uid, info in mission.nodes.items()
        if info.is_task and mission.node_status.get(uid) == "failed"
    ]
    return "; ".join(parts)


def _part_map(plan: Mapping[str, Any]) -> dict[str, list[str]]:
    """Each shared search's uuid -> its parts' uuids, from a stored plan's ``shared-searches``
    (DESIGN 3.11), so the operator's view is rebuilt the same after a restart."""
    out: dict[str, list[str]] = {}
    for search in plan.get("shared-searches") or ():
        if isinstance(search, Mapping) and isinstance(search.get("parts"), list):
            out[str(search.get("node-uuid"))] = [str(p.get("node-uuid")) for p in search["parts"]
                                                 if isinstance(p, Mapping)]
    return out
