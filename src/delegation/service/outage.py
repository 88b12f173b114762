"""How long a failing store is retried, and when to give up: `Outage`, pure (``now`` is given).

The service keeps working while its store fails (heartbeats, liveness, answers from memory);
what it cannot store waits, and is retried with a back-off that doubles from ``first`` up to
``longest`` seconds. Past ``bound`` seconds of failures with no success in between, the instance
gives up (it leaves the broker, releases its lock and exits non-zero) so that a standby with a
working store, or a restart under a supervisor, takes over.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Default seconds of continuous store failures before the instance gives up.
DEFAULT_BOUND = 60.0


@dataclass(slots=True)
class Outage:
    """The state of one kind of store operation (writes, lock checks) that can fail."""

    bound: float = DEFAULT_BOUND
    first: float = 0.5
    longest: float = 5.0
    #: When the current run of failures began (None: the last try worked).
    since: float | None = None
    failures: int = 0
    retry_at: float = 0.0

    @property
    def ongoing(self) -> bool:
        return self.since is not None

    def due(self, now: float) -> bool:
        """True when a try may be made now (always, unless backing off)."""
        return self.since is None or now >= self.retry_at

    def failed(self, now: float) -> bool:
        """Note a failure at ``now`` and schedule the next try; True when past the bound."""
        if self.since is None:
            self.since = now
        self.failures += 1
        self.retry_at = now + min(self.first * 2 ** min(self.failures - 1, 30), self.longest)
        return now - self.since >= self.bound

    def recovered(self, now: float) -> float | None:
        """Note a success; how long the outage lasted (None if there was none)."""
        lasted = None if self.since is None else now - self.since
        self.since, self.failures, self.retry_at = None, 0, 0.0
        return lasted
