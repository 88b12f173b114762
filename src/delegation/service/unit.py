"""The delegation service on a broker: `ServiceCore` run by the generic `CoreUnit`, planning on
its worker thread so that a plan never blocks the receive path (a ``ping`` is answered while a
tree is being planned).

At ``stop`` the worker is given 10 s to finish the plan it is running (an ``optimal`` plan may ask
for up to ``max_time_limit``); a plan still running then is abandoned and never answered.

With a `Store`, the state survives a crash: after every batch of queued messages (`CoreUnit`
handles whatever is queued, then ends the batch) what the core changed (the ``dirty`` journals of
its missions and commands) is written in one transaction BEFORE the batch's messages are
published, so an answer that went out is stored; at start the missions that had not ended and the
latest answers are loaded, and a command that was still being worked on when the last instance
died is answered ``failed`` (never run again). Ended missions leave memory ``retention`` seconds
after they ended; they are read back from the store when asked for.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable

from delegation.runtime.commands import CommandEntry, CommandLog, CommandState
from delegation.runtime.core import Effects, Outgoing
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.unit import CoreUnit
from delegation.service.config import ServiceConfig
from delegation.service.core import ServiceCore, Timing
from delegation.service.faces import failure
from delegation.service.jobs import Job, JobResult, run_job
from delegation.service.missions import MissionBook
from delegation.service.store import Store

log = logging.getLogger(__name__)

#: Seconds between two engine-timeout checks.
TICK_INTERVAL = 0.2
#: Default seconds an ended mission stays in memory (it stays in the store).
DEFAULT_RETENTION = 600.0
#: Answered commands kept in memory with a store (older ones are read back from it).
COMMANDS_IN_MEMORY = 1000
#: Seconds between two checks that the store's lock is still held.
LOCK_CHECK_INTERVAL = 2.0


class DelegationService(CoreUnit[ServiceCore]):
    """The service on a broker. ``planner`` runs a job on the worker thread (``run_job``; tests
    pass one they can hold).

    The core's clock is monotonic (every timeout; a wall-clock jump changes nothing); mission
    times (``created``, ``started``, ...) are answered as epoch seconds, from the status
    ``stamp`` (``wall``).
    """

    def __init__(
        self,
        settings: BrokerSettings,
        config: ServiceConfig | None = None,
        planner: Callable[[Job], JobResult] = run_job,
        store: Store | None = None,
        retention: float = DEFAULT_RETENTION,
    ) -> None:
        self.config = config or ServiceConfig()
        super().__init__(settings, ServiceCore(self.config), worker=planner, clock=time.monotonic,
                         wall=time.time, tick_interval=TICK_INTERVAL)
        self.store = store
        self.retention = retention
        #: Set when the store's lock was lost: this instance must stop acting.
        self.lock_lost = threading.Event()
        self._next_lock_check = 0.0
        if store is not None:
            self._load(store)

    def _load(self, store: Store) -> None:
        """Missions that had not ended, the latest answers, and an answer for every command the
        previous instance was still working on (``failed``: it is not run again)."""
        core = self.core
        core.book = MissionBook(archive=store)
        core.commands = CommandLog(COMMANDS_IN_MEMORY, archive=store)
        core.timings = deque(maxlen=COMMANDS_IN_MEMORY)  # latency figures: the latest only
        missions = store.open_missions()
        for mission in missions:
            core.book.add(mission)
        core.book.drain_dirty()
        for entry in store.commands(CommandState.DONE, COMMANDS_IN_MEMORY):
            core.commands.restore(entry)
        by_command = {m.command: m.root_uuid for m in missions if m.command}
        interrupted = []
        for entry in store.commands(CommandState.PENDING, 1_000_000):
            face, com = entry.key
            root = by_command.get(entry.key)
            reason = (f"{self.config.name} restarted while this command was being worked on; "
                      + (f"it created mission {root} (query-mission for its state)" if root
                         else "nothing was started: send it again with a new com-uuid"))
            topic = entry.reply_topic or (core.tst_response_topic if face == "tst"
                                          else core.delegation_response_topic)
            answer = [Outgoing.of(topic, failure(face, com, reason))]  # type: ignore[arg-type]
            done = CommandEntry(entry.key, entry.received, CommandState.DONE, answer,
                                digest=entry.digest, caller=entry.caller,
                                reply_topic=entry.reply_topic)
            core.commands.restore(done)
            interrupted.append(done)
        store.save([], interrupted)
        log.info("%s: state from %s: %d open missions, %d commands answered at restart",
                 self.name, store.where, len(missions), len(interrupted))

    def on_start(self) -> None:
        super().on_start()
        log.info("%s serving on %s (engine %s)", self.name, self.config.base_topic,
                 self.config.engine)

    def on_stop(self) -> None:
        """The plan running gets its 10 s (`CoreUnit.on_stop`); a planner process then ends,
        with it a plan still running."""
        super().on_stop()
        close = getattr(self._worker, "close", None)
        if close is not None:
            close()

    # ---- persistence

    def apply(self, effects: Effects) -> None:
        """Store what the batch changed (one commit), then publish its messages (an answer
        that went out is stored)."""
        if self.store is not None:
            self._persist(self.store)
        super().apply(effects)

    def _persist(self, store: Store) -> None:
        core = self.core
        with self._state:  # only this thread changes the core: it may read it unlocked below
            missions = core.book.drain_dirty()
            commands = core.commands.drain_dirty()
        try:
            store.save(missions, commands)
        except Exception:
            # Not stored: note them again (the next batch retries) and publish nothing of this one.
            with self._state:
                core.book.undrain(missions)
                core.commands.dirty.update(e.key for e in commands)
            raise

    def tick(self, now: float) -> None:
        super().tick(now)
        store = self.store
        if store is None:
            return
        with self._state:  # mission records carry epoch seconds (the core's `now` is monotonic)
            gone = self.core.book.forget_ended(self.wall() - self.retention)
        if gone:
            log.debug("%s: %d ended missions left memory", self.name, len(gone))
        if now >= self._next_lock_check:
            self._next_lock_check = now + LOCK_CHECK_INTERVAL
            if not store.holds() and not self.lock_lost.is_set():
                log.critical("%s: lost the lock on %s: another instance may take over; stopping",
                             self.name, store.where)
                self.lock_lost.set()

    def wait_ready(
        self, units: Iterable[str] = (), timeout: float = 10.0, engine: bool = True
    ) -> bool:
        """Wait until the named units (and the engine, with ``engine``) are live as the service
        sees them."""
        wanted = frozenset(units)
        return self.wait_until(lambda core: core.ready(wanted, engine, self.clock()), timeout)

    @property
    def timings(self) -> list[Timing]:
        """Arrival -> sent-to-engine timestamps per mission (a copy, read consistently)."""
        return self.inspect(lambda core: list(core.timings))


def serve(settings: BrokerSettings, config: ServiceConfig, stop: threading.Event) -> None:
    """Run the service until ``stop`` is set (no store: state in memory only)."""
    service = DelegationService(settings, config)
    service.start()
    try:
        stop.wait()
    finally:
        service.stop()
