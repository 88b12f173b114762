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

When the store fails (SQLite busy or its disk full, PostgreSQL gone), the service goes on: ticks,
heartbeats and liveness never wait for a write; what the batch changed stays noted and the batch's
messages are held, in order, behind it; both are retried with a back-off (`Outage`; PostgreSQL
reconnects and takes its lock again first). Past ``store_bound`` seconds of failures, or as soon
as the lock is held by another instance, the instance is fenced: it publishes nothing more, leaves
the broker, and `failed` is set (`run_active` then releases the lock and exits non-zero, so a
standby or a supervisor's restart takes over).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from delegation.runtime.commands import CommandEntry, CommandLog, CommandState
from delegation.runtime.core import Effects, Outgoing
from delegation.runtime.mqtt import Message
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.unit import CoreUnit
from delegation.service.config import ServiceConfig
from delegation.service.core import ServiceCore, Timing
from delegation.service.faces import failure
from delegation.service.jobs import Job, JobResult, run_job
from delegation.service.missions import MissionBook
from delegation.service.outage import DEFAULT_BOUND, Outage
from delegation.service.store import LockLost, Store, StoreError
from delegation.topics import QOS_PERIODIC

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
        store_bound: float = DEFAULT_BOUND,
    ) -> None:
        self.config = config or ServiceConfig()
        super().__init__(settings, ServiceCore(self.config), worker=planner, clock=time.monotonic,
                         wall=time.time, tick_interval=TICK_INTERVAL)
        self.store = store
        self.retention = retention
        #: Set when the store's lock was lost: this instance must stop acting.
        self.lock_lost = threading.Event()
        #: Set when this instance gave up (lock lost, or the store failed past ``store_bound``):
        #: it is fenced (publishes nothing, left the broker); ``failure`` says why.
        self.failed = threading.Event()
        self.failure = ""
        self._fenced = False
        self._next_lock_check = 0.0
        #: Messages waiting for their batch's state to be stored (in order).
        self._held: list[Outgoing] = []
        #: Received messages whose step needed a read the store could not do (queued again when
        #: the store is tried next).
        self._unread: list[Message] = []
        self._writes = Outage(store_bound)
        self._lock_checks = Outage(store_bound)
        #: Whether the store's lock was taken (`run_active`): only then can it be lost.
        self._locked = False
        if store is not None:
            self._load(store)
            self._locked = store.holds()

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
        that went out is stored). While the store fails, the messages wait behind the ones
        already waiting, and the write is retried (`_flush`)."""
        if self.store is None:
            super().apply(effects)
            return
        self._held.extend(effects.publish)
        self._queue(effects.jobs)
        self._flush(self.store)

    @property
    def held(self) -> int:
        """Messages waiting for the store (for tests and logs)."""
        return len(self._held)

    def handle(self, message: Message) -> None:
        """As `CoreUnit.handle`; a step that needed the store (a command seen long ago, a
        mission no longer in memory) and could not read it changed nothing yet: the message is
        kept and queued again when the store is tried next (`_flush`)."""
        try:
            super().handle(message)
        except StoreError as exc:
            if self.store is None:
                raise
            self._unread.append(message)
            self._store_failed(self._writes, self.clock(),
                               f"a read from {self.store.where} failed", exc)

    def _flush(self, store: Store) -> None:
        """Write what is noted (when not backing off), then publish what waited for it."""
        if self._fenced:
            return
        now = self.clock()
        if not self._writes.due(now):
            return
        unread, self._unread = self._unread, []
        for message in unread:  # handled again in the next batch (the store is tried again)
            self.call_soon(message)
        try:
            wrote = self._persist(store)
        except LockLost as exc:
            self._give_up(f"lost the lock on {store.where}: {exc}", lock=True)
            return
        except Exception as exc:
            self._store_failed(self._writes, now, f"a write to {store.where} failed", exc)
            return
        # Only a write shows that the store works again (a read may still fail: it counts).
        lasted = self._writes.recovered(now) if wrote else None
        if lasted is not None:
            log.warning("%s: the store %s works again after %.1f s; %d held messages go out",
                        self.name, store.where, lasted, len(self._held))
        held, self._held = self._held, []
        for out in held:
            self.send(out)

    def _persist(self, store: Store) -> bool:
        """Write what the core changed; False when there was nothing to write."""
        core = self.core
        with self._state:  # only this thread changes the core: it may read it unlocked below
            missions = core.book.drain_dirty()
            commands = core.commands.drain_dirty()
        if not missions and not commands:
            return False
        try:
            store.save(missions, commands)
        except BaseException:
            # Not stored: note them again (the next try writes them) and publish nothing.
            with self._state:
                core.book.undrain(missions)
                core.commands.dirty.update(e.key for e in commands)
            raise
        return True

    def _store_failed(self, outage: Outage, now: float, what: str, exc: Exception) -> None:
        first = not outage.ongoing
        past = outage.failed(now)
        if first:
            log.error("%s: %s: %s; retrying (messages held until it is stored, giving up after "
                      "%.0f s)", self.name, what, exc, outage.bound)
        else:
            log.warning("%s: %s again (%d tries, %.1f s): %s", self.name, what, outage.failures,
                        now - (outage.since or now), exc)
        if past:
            self._give_up(f"{what} for {now - (outage.since or now):.1f} s "
                          f"(bound {outage.bound:g} s): {exc}")

    def _give_up(self, why: str, lock: bool = False) -> None:
        """Fence this instance: publish nothing more, leave the broker at once (before the lock
        is released, by `run_active`), and say why."""
        if self._fenced:
            return
        self._fenced = True
        self.failure = why
        log.critical("%s: %s; leaving the broker (%d messages not sent) and stopping so that "
                     "another instance takes over", self.name, why, len(self._held))
        self._held.clear()
        self.client.disconnect()
        if lock:
            self.lock_lost.set()
        self.failed.set()

    def publish(self, topic: str, payload: bytes | str | Any, qos: int = QOS_PERIODIC,
                retain: bool = False) -> None:
        """Nothing once fenced (another instance may be active, or this one's state is not
        stored)."""
        if not self._fenced:
            super().publish(topic, payload, qos, retain)

    def tick(self, now: float) -> None:
        super().tick(now)
        store = self.store
        if store is None:
            return
        with self._state:  # mission records carry epoch seconds (the core's `now` is monotonic)
            gone = self.core.book.forget_ended(self.wall() - self.retention)
        if gone:
            log.debug("%s: %d ended missions left memory", self.name, len(gone))
        self._check_lock(store)

    def _check_lock(self, store: Store) -> None:
        """Every `LOCK_CHECK_INTERVAL` s (and every retry while it cannot be told): is this
        still the active instance? Lost: give up at once; unknown (the store cannot be reached):
        an outage, given up past the bound."""
        now = self.clock()  # real time: the tick's ``now`` lags by the queued work
        if (not self._locked or self._fenced or now < self._next_lock_check
                or not self._lock_checks.due(now)):
            return
        self._next_lock_check = now + LOCK_CHECK_INTERVAL
        try:
            holds = store.holds()
        except Exception as exc:
            self._store_failed(self._lock_checks, now, f"the lock on {store.where} cannot be "
                               "checked", exc)
            return
        if not holds:
            self._give_up(f"lost the lock on {store.where}: another instance may be active",
                          lock=True)
            return
        lasted = self._lock_checks.recovered(now)
        if lasted is not None:
            log.warning("%s: the lock on %s is still ours after %.1f s unreachable", self.name,
                        store.where, lasted)

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
