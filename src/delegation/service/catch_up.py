"""Catching up (pure; docs/protocol.md §11, §12.5): after the service's restart or its own
reconnect, or the engine's return, every open mission is brought up to date before it is judged.

Clean MQTT sessions lose what is published while a client is away, so the service asks instead of
trusting that it heard everything: a ``query-tst`` to the engine for the tree each open mission
runs. The answer's node statuses are applied as the feedback they would have been (a tree that
ended meanwhile ends its mission now). An engine that does not know the tree (it restarted: the
trees it executed are gone) is given the unfinished part again: the same nodes with their uuids,
without the tasks that succeeded, under the ``start-tst`` com-uuid the tree first went with, so
the engine re-sends the very start-tasks its units already got (they answer again, and do not
run them again) and asks each unit ``query-status`` (``resume``).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from delegation.errors import InputError
from delegation.messages import MissionStatus, QueryTst, StartTst, TstFeedback, TstResponse
from delegation.runtime.commands import CommandKey
from delegation.runtime.core import Effects
from delegation.service.engine_link import INTERNAL, start_command_uuid
from delegation.service.missions import Mission
from delegation.service.planning import MissionPart
from delegation.tst.node import TstNode, parse_tree, to_dict

log = logging.getLogger(__name__)

#: Task statuses after which a task is not sent again.
DONE = frozenset({"succeeded", "revoked"})


def unfinished(tree: TstNode, node_status: Mapping[str, str]) -> TstNode | None:
    """``tree`` without the tasks that succeeded (or were skipped) and the control nodes left
    empty; every node keeps its uuid. None when nothing is left to do."""

    def keep(node: TstNode) -> TstNode | None:
        if not node.is_control:
            return None if node_status.get(node.node_uuid or "") in DONE else node
        children = [c for c in (keep(child) for child in node.children) if c is not None]
        return node.with_children(children) if children else None

    return keep(tree)


def missed(mission: Mission, nodes: list[dict[str, Any]]) -> list[TstFeedback]:
    """The feedback ``query-tst``'s ``nodes`` say the mission missed: nodes whose status differs
    from the book's, children before parents, the root last (it ends the mission)."""
    out: list[TstFeedback] = []
    for row in reversed(nodes):
        uid, status = row.get("node-uuid"), row.get("status")
        if not isinstance(uid, str) or not isinstance(status, str) or uid not in mission.nodes:
            continue
        if mission.node_status.get(uid, "not-active") == status:
            continue
        out.append(TstFeedback(node_uuid=uid, status=status, root_flag=uid == mission.current_root,
                               fail_reason=str(row.get("fail-reason") or "")))
    return out


def first_start_key(mission: Mission) -> CommandKey:
    """The key whose `start_command_uuid` the mission's current tree was first sent under: the
    creating command for its first tree, the service's own for a re-delegated one."""
    if mission.current_root == mission.root_uuid and mission.command is not None:
        return mission.command
    return (INTERNAL, f"{mission.current_root}#start")


@dataclass(eq=False)
class CatchUp(MissionPart):
    """Which missions to ask the engine about, the asking, and what the answers mean."""

    #: Root uuids of the missions to ask about once the engine is live.
    due: set[str] = field(default_factory=set)
    #: Queries sent per mission since it was last wanted (bounded by ``catch_up_attempts``).
    tries: dict[str, int] = field(default_factory=dict)

    def want_open(self) -> None:
        """Every mission that runs a tree on the engine is to be asked about."""
        for m in self.book:
            if not m.ended and m.current_root and m.status in (MissionStatus.STARTED,
                                                               MissionStatus.RUNNING):
                self.due.add(m.root_uuid)
                self.tries[m.root_uuid] = 0

    def queries(self, now: float) -> Effects:
        """``query-tst`` for each mission due, once the engine is live."""
        effects = Effects()
        if not self.due or self.engine.base(now) is None:
            return effects
        due, self.due = self.due, set()
        for root in sorted(due):
            mission = self.book.find(root)
            if mission is None or mission.ended or not mission.current_root \
                    or self.engine.starting(root):
                continue
            self.tries[root] = self.tries.get(root, 0) + 1
            query = QueryTst(node_uuid=mission.current_root, sender=self.config.name)
            effects.publish.append(self.engine.send("query", (INTERNAL, f"{root}#query"),
                                                    "delegation", query, now, root,
                                                    tree=mission.current_root))
        return effects

    def unanswered(self, root: str) -> None:
        """A query went unanswered: ask again, up to ``catch_up_attempts`` times."""
        if self.tries.get(root, 0) < self.config.catch_up_attempts:
            self.due.add(root)
        else:
            log.warning("mission %s: engine %s answered no query-tst (%d attempts): its state "
                        "is known from its feedback only", root, self.config.engine,
                        self.tries.get(root, 0))

    def resume(self, mission: Mission, now: float) -> Effects:
        """The engine does not know the mission's tree (it restarted): send it what is left,
        under the tree's first ``start-tst`` com-uuid (`first_start_key`); a tree with nothing
        left succeeded while nobody listened."""
        left = unfinished(parse_tree(mission.current_tst), mission.node_status)
        if left is None:
            return self.lifecycle.set_status(mission.root_uuid, MissionStatus.SUCCEEDED, now)
        start = StartTst(receiver=self.config.engine, sender=self.config.name, tst=to_dict(left),
                         resume=True)
        com = start_command_uuid(self.config.name, first_start_key(mission), mission.root_uuid)
        try:
            out = self.engine.send("start", (INTERNAL, f"{mission.current_root}#resume"),
                                   "delegation", start, now, mission.root_uuid, com=com)
        except InputError:  # the engine went again: asked again when it is back
            self.due.add(mission.root_uuid)
            return Effects()
        log.info("mission %s: engine %s does not know tree %s (restarted): its unfinished part "
                 "sent again", mission.root_uuid, self.config.engine, mission.current_root)
        return Effects(publish=[out])

    def answered(self, root: str, resp: TstResponse, now: float) -> tuple[list[TstFeedback],
                                                                           Effects]:
        """The engine's answer about a mission's tree: the feedback it missed to apply, or the
        tree sent again (``unknown``)."""
        mission = self.book.find(root)
        if mission is None or mission.ended or mission.redelegating:
            return [], Effects()
        if resp.response == "ok":
            return missed(mission, resp.nodes or []), Effects()
        if resp.response == "unknown":
            return [], self.resume(mission, now)
        log.warning("mission %s: engine %s cannot say how tree %s stands: %s", root,
                    self.config.engine, mission.current_root, resp.fail_reason or resp.response)
        return [], Effects()
