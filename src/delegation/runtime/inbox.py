"""A unit's inbox: what arrived, in order, each item stamped with the time it arrived.

Why arrival time: a unit's core judges liveness ("no heartbeat of X for 5 s") against ``now``.
Taken when a message is *processed*, a backlog of queued work looks like silence: heartbeats that
arrived on time but wait behind 20 s of work make their sender look lost. Stamped when paho hands
the message over, the core sees each message at the time it really came, and a tick is given the
arrival time of the oldest item still waiting (`Inbox.frontier`): everything before it has been
seen, nothing after it can be judged missing yet.

Why bounded, and how: paho's thread must never block (it also sends our messages), so a full
inbox cannot push back. Periodic state (heartbeats, ``sensor/...``, ``..._info``) only says "as of
now": once ``limit`` items wait, a newer one on a topic replaces the older one still queued on
that topic (the older is dropped, counted and logged). Nothing else is ever dropped (commands,
answers, feedback, jobs' results): past the limit they are kept and the overflow is logged, so
memory beyond the limit grows only with such messages and with one periodic item per topic.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from delegation.runtime.mqtt import Message

log = logging.getLogger(__name__)

#: Items waiting before periodic duplicates are dropped (a few seconds of a busy broker's traffic
#: for one unit; far above what a healthy unit ever holds).
DEFAULT_LIMIT = 10_000
#: Seconds between two warnings about drops or overflow (each says how many since the last).
WARN_EVERY = 5.0


def periodic(topic: str) -> bool:
    """True for topics that carry periodic state a newer message supersedes: ``heartbeat``,
    ``sensor/<x>``, ``<x>_info``."""
    last = topic.rsplit("/", 1)[-1]
    return last == "heartbeat" or last.endswith("_info") or "/sensor/" in topic


@dataclass(slots=True)
class Arrival:
    """One queued item and the ``clock`` time it arrived; ``dropped`` once superseded."""

    item: object
    arrived: float
    dropped: bool = False


class Inbox:
    """A thread-safe FIFO of `Arrival`s (any thread puts; the unit's thread takes)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic,
                 limit: int = DEFAULT_LIMIT, name: str = "unit") -> None:
        self.clock = clock
        self.limit = limit
        self.name = name
        self._items: deque[Arrival] = deque()
        self._cond = threading.Condition()
        self._live = 0
        #: The newest queued periodic message per topic (what a newer one supersedes).
        self._latest: dict[str, Arrival] = {}
        #: Periodic messages dropped because a newer one on their topic came while full.
        self.dropped = 0
        #: Items kept past the limit (never dropped: not periodic).
        self.overflow = 0
        self._warned = (0, 0)
        self._next_warning = 0.0

    def __len__(self) -> int:
        with self._cond:
            return self._live

    def put(self, item: object) -> None:
        """Queue ``item`` stamped now (never blocks)."""
        with self._cond:
            now = self.clock()  # under the lock: arrival times follow queue order
            topic = item.topic if isinstance(item, Message) and periodic(item.topic) else None
            if self._live >= self.limit:
                older = self._latest.get(topic) if topic is not None else None
                if older is not None:
                    older.dropped = True
                    self._live -= 1
                    self.dropped += 1
                else:
                    self.overflow += 1
                self._warn(now)
            entry = Arrival(item, now)
            if topic is not None:
                self._latest[topic] = entry
            self._items.append(entry)
            self._live += 1
            self._cond.notify()

    def get(self, timeout: float | None = None) -> Arrival | None:
        """The oldest item (waiting up to ``timeout`` s, forever for None); None if none came."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._live > 0, timeout):
                return None
            return self._pop()

    def get_nowait(self) -> Arrival | None:
        with self._cond:
            return self._pop() if self._live > 0 else None

    def frontier(self) -> float:
        """The arrival time of the oldest item still waiting, or the clock when none waits: the
        time up to which everything that arrived has been taken."""
        with self._cond:
            self._skip_dropped()
            return self._items[0].arrived if self._items else self.clock()

    def _skip_dropped(self) -> None:
        while self._items and self._items[0].dropped:
            self._items.popleft()

    def _pop(self) -> Arrival:
        self._skip_dropped()
        entry = self._items.popleft()
        self._live -= 1
        item = entry.item
        if isinstance(item, Message) and self._latest.get(item.topic) is entry:
            del self._latest[item.topic]
        return entry

    def _warn(self, now: float) -> None:
        """Log drops and overflow at most every `WARN_EVERY` s (a flood must not flood the log)."""
        if now < self._next_warning:
            return
        self._next_warning = now + WARN_EVERY
        dropped, overflow = self.dropped - self._warned[0], self.overflow - self._warned[1]
        self._warned = (self.dropped, self.overflow)
        log.warning("%s: inbox full (%d waiting, limit %d): %d superseded periodic messages "
                    "dropped, %d other items kept past the limit (%d and %d in all)", self.name,
                    self._live, self.limit, dropped, overflow, self.dropped, self.overflow)
