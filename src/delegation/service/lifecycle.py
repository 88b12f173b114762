"""Missions moving on, told to the operator (pure: ``now`` is passed in).

Every status change of a mission (`MissionBook.set_status`, engine feedback) is published on
``delegation/feedback`` and logged; a mission ending answers the cancels waiting for it
(`delegation.service.cancels`). Mission records are stamped in epoch seconds: ``now`` is
monotonic, and `Epoch` holds the offset learnt from the unit's status ``stamp``.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass

from delegation.allocation import OBJECTIVES, STRATEGIES
from delegation.messages import (
    FINAL_MISSION_STATUSES,
    DelegationFeedback,
    DelegationInfo,
    MissionStatus,
    TstExecutionInfo,
)
from delegation.runtime.commands import CommandKey
from delegation.runtime.core import Effects, Identity, Outgoing, heartbeat
from delegation.service.cancels import Cancels
from delegation.service.commands import CommandDesk
from delegation.service.config import ServiceConfig
from delegation.service.missions import LifecycleEvent, MissionBook
from delegation.topics import QOS_PERIODIC

log = logging.getLogger(__name__)

#: The levels the service's heartbeat announces.
LEVELS = ("tst execution", "delegation")


@dataclass(slots=True)
class Epoch:
    """Epoch seconds minus ``now`` (learnt from `status`): mission records are epoch stamps."""

    offset: float = 0.0

    def __call__(self, now: float) -> float:
        """``now`` (monotonic) as epoch seconds."""
        return now + self.offset


class Lifecycle:
    """Set a mission's status, publish the change, answer the cancels its end settles."""

    def __init__(self, book: MissionBook, desk: CommandDesk, cancels: Cancels,
                 epoch: Epoch) -> None:
        self.book = book
        self.desk = desk
        self.cancels = cancels
        self.epoch = epoch

    def set_status(
        self, root_uuid: str, status: MissionStatus, now: float, fail_reason: str = ""
    ) -> Effects:
        """Move a mission on (`MissionBook.set_status`) and publish the change, if any."""
        event = self.book.set_status(root_uuid, status, self.epoch(now), fail_reason)
        return self.publish([event] if event else [])

    def publish(self, events: Iterable[LifecycleEvent]) -> Effects:
        """``delegation/feedback`` for each change; an end answers its waiting cancels."""
        effects = Effects()
        for e in events:
            effects.send(self.desk.topics.delegation_feedback,
                         DelegationFeedback(root_uuid=e.root_uuid, status=e.status.value,
                                            fail_reason=e.fail_reason))
            if e.status in FINAL_MISSION_STATUSES:
                for key, answer in self.cancels.ended(e.root_uuid, e.status, e.fail_reason):
                    effects.extend(self.desk.respond("delegation", key, answer))
            log.info("mission %s %s%s", e.root_uuid, e.status.value,
                     f": {e.fail_reason}" if e.fail_reason else "")
        return effects

    def wait_cancel(self, root_uuid: str, key: CommandKey, now: float) -> None:
        """Answer the cancel ``key`` when the mission ends, or ``pending`` at its deadline."""
        self.cancels.wait(root_uuid, key, now)

    def cancel_deadlines(self, now: float) -> Effects:
        """Cancels whose abort the engine did not confirm in time: answered ``pending``."""
        effects = Effects()
        for key, answer in self.cancels.due(now):
            effects.extend(self.desk.respond("delegation", key, answer))
        return effects


def status_messages(config: ServiceConfig, identity: Identity, book: MissionBook,
                    stamp: float,
                    fleet: tuple[list[str], list[str]] = ([], [])) -> list[Outgoing]:
    """Heartbeat, ``tst_execution_info`` (the trees executing) and ``delegation_info`` with the
    own fleet's summary (``fleet``: tasks available, units managed), which makes this service a
    delegator other services can ask for offers (docs/protocol.md §15)."""
    c = config
    active = [m.root_uuid for m in book if not m.ended and m.status is not MissionStatus.PLANNED]
    tst_info = TstExecutionInfo(name=c.name, rate=c.rate, stamp=stamp, trees_executing=active)
    info = DelegationInfo(name=c.name, rate=c.rate, stamp=stamp, strategies=list(STRATEGIES),
                          objectives=list(OBJECTIVES), missions_active=len(active),
                          tasks_available=fleet[0], units_managed=fleet[1])
    return [
        heartbeat(identity, LEVELS, stamp),
        Outgoing.of(identity.topic("tst_execution_info"), tst_info, QOS_PERIODIC),
        Outgoing.of(identity.topic("delegation_info"), info, QOS_PERIODIC),
    ]
