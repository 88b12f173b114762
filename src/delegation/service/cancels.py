"""Cancels waiting for the engine to confirm an abort (pure: ``now`` is passed in).

A ``cancel-mission`` the engine accepted is answered when the mission ends: ``ok`` if it ended
``aborted``, ``failed`` if it ended otherwise first; if the engine does not confirm within
``cancel_timeout``, ``pending`` with the reason (the mission ends when the engine reports it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from delegation.messages import DelegationResponse, MissionStatus
from delegation.runtime.commands import CommandKey


@dataclass(slots=True)
class Cancels:
    """Accepted cancels by mission root: (the cancel command's key, its deadline)."""

    engine: str
    timeout: float
    waiting: dict[str, list[tuple[CommandKey, float]]] = field(default_factory=dict)

    def wait(self, root_uuid: str, key: CommandKey, now: float) -> None:
        """The engine accepted the ``$abort``: answer when the mission ends, or at the deadline."""
        self.waiting.setdefault(root_uuid, []).append((key, now + self.timeout))

    def due(self, now: float) -> list[tuple[CommandKey, DelegationResponse]]:
        """The cancels whose deadline passed, each with its ``pending`` answer (forgotten)."""
        out: list[tuple[CommandKey, DelegationResponse]] = []
        for root, waiting in list(self.waiting.items()):
            due = [(k, d) for k, d in waiting if d <= now]
            for key, _ in due:
                why = (f"$abort accepted by engine {self.engine} but not confirmed within "
                       f"{self.timeout:g} s; the mission ends when the engine "
                       f"reports it (query-mission)")
                out.append((key, DelegationResponse(response="pending", response_to=key[1],
                                                    fail_reason=why)))
            rest = [w for w in waiting if w not in due]
            if rest:
                self.waiting[root] = rest
            else:
                del self.waiting[root]
        return out

    def ended(self, root_uuid: str, status: MissionStatus, fail_reason: str
              ) -> list[tuple[CommandKey, DelegationResponse]]:
        """A mission ended: the answers of the cancels waiting for it (forgotten)."""
        out: list[tuple[CommandKey, DelegationResponse]] = []
        for key, _ in self.waiting.pop(root_uuid, []):
            if status is MissionStatus.ABORTED:
                answer = DelegationResponse(response="ok", response_to=key[1])
            else:
                answer = DelegationResponse(
                    response="failed", response_to=key[1],
                    fail_reason=f"mission {root_uuid} ended {status.value} before the "
                                f"abort took effect" + (f": {fail_reason}" if fail_reason
                                                        else ""))
            out.append((key, answer))
        return out
