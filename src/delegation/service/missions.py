"""Mission book-keeping for the delegation service (pure state).

The service core feeds these values with decoded messages and ``now``; nothing here reads the
clock, touches the network or locks. The book is a plain in-memory map today, shaped so that it
can later be persisted: every mutation goes through a small method. Command
idempotency is `delegation.runtime.commands.CommandLog`, shared by every unit.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from delegation.errors import InputError, Problem
from delegation.messages import FINAL_MISSION_STATUSES, TERMINAL_NODE_STATUSES, MissionStatus
from delegation.tst.node import TstNode, walk

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
        for uid, info in self.nodes.items():
            nodes.append(
                {
                    "node-uuid": uid,
                    "name": info.name,
                    "execunit": info.execunit,
                    "path": info.path,
                    "status": self.node_status.get(uid, "not-active"),
                    "started": _rel(self.node_started.get(uid), self.started_at),
                    "ended": _rel(self.node_ended.get(uid), self.started_at),
                }
            )
        return {
            **self.summary(),
            "nodes": nodes,
            "assignments": list(self.plan.get("assignments", [])),
            "unassigned": list(self.plan.get("unassigned", [])),
            "makespan": self.plan.get("makespan"),
            "strategy": self.plan.get("strategy"),
        }


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


class MissionBook:
    """Every mission the service has planned or run, indexed by root and by node uuid."""

    def __init__(self) -> None:
        self._missions: dict[str, Mission] = {}
        self._node_root: dict[str, str] = {}

    def __len__(self) -> int:
        return len(self._missions)

    def __iter__(self) -> Iterator[Mission]:
        return iter(list(self._missions.values()))

    def __contains__(self, root_uuid: object) -> bool:
        return root_uuid in self._missions

    def conflicts(self, tree: TstNode) -> list[Problem]:
        """Node uuids of ``tree`` already used by a mission that has not ended."""
        problems: list[Problem] = []
        for path, node in walk(tree):
            uid = node.node_uuid
            root = self._node_root.get(uid) if uid else None
            if root is not None and not self._missions[root].ended:
                problems.append(
                    Problem(
                        path,
                        "common_params.node-uuid",
                        f"{uid} is already part of mission {root} "
                        f"({self._missions[root].status.value})",
                    )
                )
        return problems

    def add(self, mission: Mission) -> None:
        """Record a new mission; an ended mission with the same uuids is replaced."""
        old = self._missions.pop(mission.root_uuid, None)
        if old is not None:
            for uid in old.nodes:
                if self._node_root.get(uid) == old.root_uuid:
                    del self._node_root[uid]
        self._missions[mission.root_uuid] = mission
        for uid in mission.nodes:
            self._node_root[uid] = mission.root_uuid

    def get(self, root_uuid: str) -> Mission:
        """The mission with this root uuid; ``InputError`` naming it if there is none."""
        mission = self._missions.get(root_uuid)
        if mission is None:
            raise InputError(Problem("command", "root-uuid", f"unknown mission {root_uuid!r}"))
        return mission

    def find(self, root_uuid: str) -> Mission | None:
        return self._missions.get(root_uuid)

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
        if mission.node_status.get(node_uuid) not in TERMINAL_NODE_STATUSES:
            mission.node_status[node_uuid] = status
        if status == "running":
            mission.node_started.setdefault(node_uuid, now)
        elif status in TERMINAL_NODE_STATUSES:
            mission.node_ended.setdefault(node_uuid, now)
        events: list[LifecycleEvent] = []
        is_root = root_flag or node_uuid == mission.root_uuid
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


def failed_nodes_reason(mission: Mission) -> str:
    """A fail-reason naming the task nodes that failed, for a root that failed without one."""
    parts = [
        f"{info.path} ({info.name} {uid} on {info.execunit or '?'}) failed"
        for uid, info in mission.nodes.items()
        if info.is_task and mission.node_status.get(uid) == "failed"
    ]
    return "; ".join(parts)
