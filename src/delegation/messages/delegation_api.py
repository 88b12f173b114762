"""The Delegation API on ``delegation/command`` (docs/protocol.md §5; the seed names it, we define
it).

Commands carrying a tree keep it as raw JSON, like ``start-tst``. Response payloads (plan, bids,
mission, missions, agents) are plain JSON built by the service; see docs/plan.md §1 for the plan.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any, Literal

from pydantic import Field, StrictBool

from delegation.messages.base import Answer, Command, WireModel, new_com_uuid


class MissionStatus(StrEnum):
    """Mission lifecycle events on ``delegation/feedback``."""

    PLANNED = "planned"
    STARTED = "started"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    ABORTED = "aborted"
    #: Not a state: an event while running, when a lost unit's tasks moved to other units
    #: (`DelegationFeedback.tasks` names them); the mission stays ``running``.
    RE_DELEGATED = "re-delegated"


#: Mission statuses after which a mission never changes again.
FINAL_MISSION_STATUSES: frozenset[MissionStatus] = frozenset(
    {MissionStatus.SUCCEEDED, MissionStatus.FAILED, MissionStatus.ABORTED}
)


class Delegate(Command):
    """``delegate``: plan a tree (and with ``start`` also run it)."""

    command: Literal["delegate"] = "delegate"
    tst: dict[str, Any]
    strategy: str | None = None
    objective: str | None = None
    time_limit: float | None = Field(default=None, gt=0, allow_inf_nan=False, strict=True)
    #: Strict: ``"yes"`` is no boolean (it once started 17 missions).
    start: StrictBool = False
    #: A plan to look at (the page's previews): answered with the plan, never stored as a
    #: mission (nothing to cancel, nothing in ``list-missions``), never started (``start``
    #: ignored).
    preview: StrictBool = False
    #: With ``start``: start the plan this caller's preview answered (its plan's ``preview-id``)
    #: when it still holds, else plan again and say why (docs/protocol.md, "Starting a preview").
    preview_id: str | None = Field(default=None, min_length=1, max_length=128, strict=True)
    #: ``false``: no search is shared among units (DESIGN 3.11); the planner's choice otherwise.
    split: StrictBool = True


class GetBids(Command):
    """``get-bids``: every task node x live unit: estimated travel, work, distance or why not."""

    command: Literal["get-bids"] = "get-bids"
    tst: dict[str, Any]


class QueryMission(Command):
    """``query-mission``: status, node statuses and assignments of one mission."""

    command: Literal["query-mission"] = "query-mission"
    root_uuid: str


class ListMissions(Command):
    """``list-missions``: the missions with their status, a page at a time (oldest first)."""

    command: Literal["list-missions"] = "list-missions"
    offset: int = Field(default=0, ge=0, strict=True)
    limit: int = Field(default=100, ge=1, le=1000, strict=True)


class ListAgents(Command):
    """``list-agents``: the live units."""

    command: Literal["list-agents"] = "list-agents"


class CancelMission(Command):
    """``cancel-mission``: abort a mission; answered ``ok`` once the engine confirmed."""

    command: Literal["cancel-mission"] = "cancel-mission"
    root_uuid: str


class DelegationPing(Command):
    """``ping`` on ``delegation/command``: answered ``pong``."""

    command: Literal["ping"] = "ping"


class DelegationResponse(Answer):
    """The answer on ``delegation/response``: ``ok``/``started``/``pong``/``failed``, always with
    ``fail-reason``, plus the payload of the command answered."""

    plan: dict[str, Any] | None = None
    bids: list[dict[str, Any]] | None = None
    mission: dict[str, Any] | None = None
    missions: list[dict[str, Any]] | None = None
    #: ``list-missions``: how many missions there are in all; the offset of the next page.
    total: int | None = None
    next: int | None = None
    agents: list[dict[str, Any]] | None = None


class DelegationFeedback(WireModel):
    """Mission lifecycle events on ``delegation/feedback``."""

    com_uuid: str = Field(default_factory=new_com_uuid)
    root_uuid: str
    status: str
    fail_reason: str = ""
    #: With ``re-delegated``: one entry per task moved (``node-uuid`` of the new node,
    #: ``replaces`` the node it replaces, ``name``, ``path``, ``unit`` its new unit).
    tasks: list[dict[str, Any]] | None = None
