"""Units on a broker: `MqttUnit` (one client, one loop thread) and `CoreUnit`, which runs any
pure core (`delegation.runtime.core.Core`) on it.

The framework owns the lifecycle (`start`/`stop`); subclasses fill in small hooks. Every hook runs
on the unit's thread, so a core needs no locks: other threads read it only through
`CoreUnit.inspect` and `CoreUnit.wait_until`, which hold the lock the loop holds while it runs the
core.

The loop takes messages in batches: whatever is queued when it wakes (at most `BATCH_MAX`), one
step of the core each, then `MqttUnit.end_batch`, where `CoreUnit` publishes the batch's messages
in order (and a unit with a store commits once before that: `delegation.service.unit`). Jobs are
queued as soon as a step asks for them.
"""

from __future__ import annotations

import contextlib
import json
import logging
import queue
import threading
import time
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from pydantic import BaseModel

from delegation.runtime.core import Core, Effects, JobCore, JobDone, Outgoing
from delegation.runtime.inbox import DEFAULT_LIMIT, Arrival, Inbox
from delegation.runtime.mqtt import Message, MqttClient, MqttConnectError, MqttError
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.transport import make_client
from delegation.topics import QOS_COMMAND, QOS_PERIODIC

log = logging.getLogger(__name__)

#: The most inbox items handled in one batch (between two `MqttUnit.end_batch`): a burst is
#: stored in one commit, yet ticks still run between batches.
BATCH_MAX = 256


class _Stop:
    """Sentinel that ends a unit's loop."""


@dataclass(frozen=True, slots=True)
class Disconnected:
    """Inbox event: the connection to the broker was lost (paho reconnects by itself)."""


@dataclass(frozen=True, slots=True)
class Reconnected:
    """Inbox event: connected again after a loss. Messages published meanwhile (QoS 1 from
    clean-start peers included) may be lost: a core catches up (``on_reconnect``)."""


class MqttUnit:
    """Base of an MQTT unit that runs its own loop thread.

    The framework owns the lifecycle (`start`/`stop`); subclasses fill in hooks:
    `subscriptions()` (filters to subscribe), `handle(message)` (one received message),
    `tick(now)` (every ``tick_interval`` seconds of ``clock``), `on_start()`/`on_stop()`.
    Every hook runs on the unit's thread, so a subclass needs no locks of its own for state it
    touches only there.

    Time is when things arrived (`delegation.runtime.inbox`): while `handle` or `handle_event`
    runs, ``self.arrived`` is when that item arrived, and `tick` is given the arrival time of the
    oldest item still queued (the clock when none is), so a backlog never looks like silence.
    """

    def __init__(
        self,
        settings: BrokerSettings,
        name: str,
        *,
        tick_interval: float | None = 1.0,
        clock: Callable[[], float] = time.monotonic,
        client_id: str | None = None,
        inbox_limit: int = DEFAULT_LIMIT,
    ) -> None:
        self.settings = settings
        self.name = name
        self.tick_interval = tick_interval
        self.clock = clock
        self._inbox = Inbox(clock, inbox_limit, name)
        #: When the item being handled arrived (``clock`` time): what a hook takes as ``now``.
        self.arrived = 0.0
        # The transport seam: MQTT or ROS 2, as ``settings.transport`` says.
        self.client = make_client(
            settings, client_id or f"{name}-{uuid.uuid4().hex[:8]}", sink=self._inbox.put,
            on_connection=self._connection,
        )
        if isinstance(self.client, MqttClient):  # heartbeats, sensors, feedback: many small
            self.client.buffered_reads = True  # messages, one recv for many instead of 3 each
        self._thread: threading.Thread | None = None
        self._started = threading.Event()
        self._stopped = threading.Event()
        self.errors = 0

    def _connection(self, up: bool, count: int) -> None:
        """paho's thread: a lost or renewed connection becomes an inbox event."""
        if not up:
            self._inbox.put(Disconnected())
        elif count > 1:
            self._inbox.put(Reconnected())

    # ---- hooks

    def subscriptions(self) -> Iterable[str]:
        return ()

    def handle(self, message: Message) -> None:
        """One received message (on the unit's thread)."""

    def handle_event(self, event: object) -> None:
        """One item put in the inbox with `call_soon` that is not a `Message` (unit's thread)."""
        if isinstance(event, Reconnected | Disconnected):
            log.info("%s: %s", self.name, type(event).__name__.lower())
            return
        log.warning("%s: unexpected inbox item %r", self.name, type(event).__name__)

    def tick(self, now: float) -> None:
        """Periodic work (on the unit's thread); ``now`` is the inbox's frontier (everything
        that arrived before it has been handled)."""

    def on_start(self) -> None:
        """Called on the unit's thread before the first message or tick."""

    def on_stop(self) -> None:
        """Called on the unit's thread after the last message (still connected)."""

    def end_batch(self) -> None:
        """Called on the unit's thread after a batch of queued messages (and after a tick): a
        unit that defers its output to this point sends it here."""

    def between(self) -> None:
        """Called on the unit's thread after each item of a batch: work that must not wait for
        the batch to end (a batch of slow steps can take seconds)."""

    # ---- lifecycle

    def start(self, timeout: float = 10.0) -> None:
        """Connect, subscribe, start the loop thread; return once it runs."""
        if self._thread is not None:
            raise MqttError(f"{self.name} is already started")
        for pattern in self.subscriptions():
            self.client.subscribe(pattern)
        self.client.connect(timeout=timeout)
        if not self._wait_subscribed(timeout):
            self.client.disconnect()
            raise MqttConnectError(f"{self.name}: subscriptions not acknowledged within {timeout}s")
        self._stopped.clear()
        self._thread = threading.Thread(target=self._run, name=f"unit-{self.name}", daemon=True)
        self._thread.start()
        self._started.wait(timeout)

    def _wait_subscribed(self, timeout: float) -> bool:
        """Round-trip a message through the broker so the SUBSCRIBEs are surely processed."""
        patterns = list(self.client.subscriptions)
        if not patterns:
            return True
        # Brokers process a client's packets in order: a probe published to a private topic we
        # subscribe to last comes back only once the subscriptions before it are in place.
        probe = f"delegation-probe/{self.client.client_id}"
        got = threading.Event()
        original = self.client._sink

        def sink(msg: Message) -> None:
            if msg.topic == probe:
                got.set()
            else:
                original(msg)

        self.client._sink = sink
        try:
            self.client.subscribe(probe, QOS_COMMAND)
            deadline = time.monotonic() + timeout
            while not got.is_set() and time.monotonic() < deadline:
                with contextlib.suppress(MqttError):
                    self.client.publish(probe, b"", qos=QOS_COMMAND)
                got.wait(0.25)
            return got.is_set()
        finally:
            self.client.unsubscribe(probe)
            self.client._sink = original

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the loop (after on_stop) and disconnect; idempotent."""
        thread = self._thread
        if thread is not None:
            self._inbox.put(_Stop())
            thread.join(timeout)
            if thread.is_alive():
                log.warning("%s: loop thread did not stop within %.1fs", self.name, timeout)
            self._thread = None
        self.client.disconnect()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> MqttUnit:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---- helpers for subclasses

    def publish(
        self,
        topic: str,
        payload: bytes | str | BaseModel | dict[str, Any],
        qos: int = QOS_PERIODIC,
        retain: bool = False,
    ) -> None:
        """Publish bytes, text, a JSON-able dict, or a pydantic model (by alias, no None)."""
        if isinstance(payload, BaseModel):
            data: bytes | str = payload.model_dump_json(by_alias=True, exclude_none=True)
        elif isinstance(payload, dict):
            data = json.dumps(payload, sort_keys=True)
        else:
            data = payload
        try:
            self.client.publish(topic, data, qos=qos, retain=retain)
        except MqttError as exc:
            log.warning("%s: %s", self.name, exc)

    def call_soon(self, item: object) -> None:
        """Feed an item to the loop: a `Message` as if it had arrived, or a typed event (such as a
        finished job) that `handle_event` takes."""
        self._inbox.put(item)

    # ---- the loop

    def _run(self) -> None:
        try:
            self._guard(self.on_start)
        finally:
            self._started.set()
        next_tick = self.clock()
        while True:
            wait: float | None = None
            if self.tick_interval is not None:
                now = self.clock()
                if now >= next_tick:
                    seen = self._inbox.frontier()
                    self._guard(lambda n=seen: self.tick(n))  # type: ignore[misc]
                    self._guard(self.end_batch)
                    next_tick = max(next_tick + self.tick_interval, now)
                wait = max(0.0, next_tick - self.clock())
            entry = self._inbox.get(timeout=wait)
            if entry is None:
                continue
            if isinstance(entry.item, _Stop) or self._batch(entry):
                break
        self._guard(self.on_stop)
        self._stopped.set()

    def _batch(self, entry: Arrival) -> bool:
        """Take ``entry`` and whatever else is already queued (at most ``BATCH_MAX``), then end
        the batch (`end_batch`: one commit and the batch's messages, for a unit that stores);
        True when a stop was among them (it ends the loop after this batch)."""
        stop, handled = False, 0
        while True:
            item, self.arrived = entry.item, entry.arrived
            if isinstance(item, Message):
                self._guard(lambda m=item: self.handle(m))  # type: ignore[misc]
            else:
                self._guard(lambda e=item: self.handle_event(e))  # type: ignore[misc]
            handled += 1
            self._guard(self.between)
            if handled >= BATCH_MAX:
                break  # the rest opens the next batch (a tick may run first)
            next_entry = self._inbox.get_nowait()
            if next_entry is None:
                break
            entry = next_entry
            if isinstance(entry.item, _Stop):
                stop = True
                break
        self._guard(self.end_batch)
        return stop

    def _guard(self, fn: Callable[[], None]) -> None:
        """Run a hook; an exception is logged and counted, never kills the loop."""
        try:
            fn()
        except Exception:
            self.errors += 1
            log.exception("%s: error in %s", self.name, getattr(fn, "__name__", "hook"))


# --------------------------------------------------------------------------- a core on a broker

C = TypeVar("C", bound=Core)
T = TypeVar("T")


class CoreUnit(MqttUnit, Generic[C]):
    """Runs a pure core on a broker: messages, ticks and finished jobs go to the core on the
    unit's thread; its `Effects` are published, its jobs run on one worker thread in order.

    ``clock`` gives the core's ``now`` (monotonic by default), read when each message or event
    arrived, and for a tick the arrival of the oldest item still queued (`MqttUnit`); ``wall``
    gives epoch seconds for the ``stamp`` of status messages. Status goes out as soon as the
    unit is subscribed (so peers started earlier see it at once) and then every
    ``core.status_period`` seconds.
    """

    def __init__(
        self,
        settings: BrokerSettings,
        core: C,
        *,
        worker: Callable[[Any], Any] | None = None,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        tick_interval: float = 0.1,
        client_id: str | None = None,
    ) -> None:
        super().__init__(
            settings, core.name, tick_interval=tick_interval, clock=clock, client_id=client_id
        )
        self.core = core
        self.wall = wall
        self._worker = worker
        # SimpleQueue: put is one C call (no Condition to notify), done for every job a step asks.
        self._jobs: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._worker_thread: threading.Thread | None = None
        self._state = threading.Condition()
        self._next_status = 0.0
        #: The current batch's effects, applied together at its end.
        self._pending = Effects()

    # ---- reading the core from other threads

    def inspect(self, read: Callable[[C], T]) -> T:
        """``read(core)`` while the loop is not running the core (a consistent view)."""
        with self._state:
            return read(self.core)

    def wait_until(self, predicate: Callable[[C], bool], timeout: float) -> bool:
        """Block until ``predicate(core)`` holds (checked after every message, tick and job);
        False at the deadline."""
        with self._state:
            return self._state.wait_for(lambda: predicate(self.core), timeout)

    # ---- MqttUnit hooks

    def subscriptions(self) -> Iterable[str]:
        return self.core.subscriptions()

    def on_start(self) -> None:
        if self._worker is not None:
            self._worker_thread = threading.Thread(
                target=self._work, name=f"{self.name}-worker", daemon=True
            )
            self._worker_thread.start()
        self._publish_status(self.clock())

    def on_stop(self) -> None:
        if self._worker_thread is not None:
            self._jobs.put(_Stop())
            self._worker_thread.join(10.0)
            if self._worker_thread.is_alive():
                log.warning("%s: a job was still running at stop; it is abandoned", self.name)
            self._worker_thread = None

    def handle(self, message: Message) -> None:
        self._run_core(lambda: self.core.on_message(message.topic, message.payload, self.arrived))

    def handle_event(self, event: object) -> None:
        if isinstance(event, JobDone) and isinstance(self.core, JobCore):
            core = self.core
            self._run_core(lambda: core.on_job_done(event, self.arrived))
        elif isinstance(event, Reconnected | Disconnected):
            # Optional core hooks: ``on_reconnect(now)`` / ``on_disconnect(now)`` -> Effects.
            hook = getattr(self.core, "on_reconnect" if isinstance(event, Reconnected)
                           else "on_disconnect", None)
            if hook is not None:
                log.info("%s: %s", self.name, type(event).__name__.lower())
                self._run_core(lambda: hook(self.arrived))
        else:
            super().handle_event(event)

    def tick(self, now: float) -> None:
        self._run_core(lambda: self.core.on_tick(now))
        self.between()

    def between(self) -> None:
        """Status when it is due, also between the items of a long batch (peers must not take a
        unit busy with a backlog for a lost one). On the clock, not the inbox's frontier: it says
        the unit is alive now, and its ``now`` pairs with the wall clock's stamp."""
        real = self.clock()
        if real >= self._next_status:
            self._publish_status(real)

    # ---- helpers

    def _run_core(self, step: Callable[[], Effects]) -> None:
        """One step of the core; its effects wait for the end of the batch (`end_batch`)."""
        with self._state:
            try:
                effects = step()
            finally:
                self._state.notify_all()
        self._pending.publish.extend(effects.publish)
        self._queue(effects.jobs)  # a job publishes nothing: it may start before the batch ends

    def end_batch(self) -> None:
        """Apply the messages the batch's steps asked for, in their order, at once."""
        effects, self._pending = self._pending, Effects()
        self.apply(effects)

    def apply(self, effects: Effects) -> None:
        """Publish the messages and queue the jobs of ``effects``."""
        for out in effects.publish:
            self.send(out)
        self._queue(effects.jobs)

    def _queue(self, jobs: list[Any]) -> None:
        for job in jobs:
            if self._worker is None:
                log.error("%s: a job but no worker to run it: %r", self.name, job)
            else:
                self._jobs.put(job)

    def send(self, out: Outgoing) -> None:
        self.publish(out.topic, out.payload, qos=out.qos)

    def _publish_status(self, now: float) -> None:
        with self._state:
            messages = self.core.status(now, self.wall())
        # Keep the period's phase (no drift from tick granularity), but never fall behind.
        period = self.core.status_period
        first = self._next_status == 0.0
        self._next_status = now + period if first else max(self._next_status + period, now)
        for out in messages:
            self.send(out)

    def _work(self) -> None:
        """The worker thread: run jobs in order, hand each result back as a `JobDone`."""
        assert self._worker is not None
        while True:
            job = self._jobs.get()
            if isinstance(job, _Stop):
                return
            began = time.perf_counter()
            try:
                result = self._worker(job)
            except Exception as exc:  # a bug in a job must not stop the worker: hand it back
                log.exception("%s: job %r failed", self.name, job)
                result = exc
            self.call_soon(JobDone(job, result, time.perf_counter() - began))
