"""One active instance per service name: lock, stand by, take over, or refuse to start.

* Shared store (PostgreSQL): the instance holding the store's lock (`Store.acquire`:
  ``pg_try_advisory_lock`` on a dedicated connection) is active; the others stand by, with no
  MQTT connection at all, and try the lock every ``poll`` seconds. The server releases the lock
  when the active instance's connection ends (``kill -9`` included), so a standby takes over within
  about ``poll`` s plus its start (loading the missions from the store and connecting).
* Own store (SQLite): a second instance on the same file finds it locked and refuses; one on
  another file but the same name and broker is caught by its heartbeat (``probe`` seconds of
  listening for a heartbeat of the same name with another ``agent-uuid`` before acting).

docs/deployment-ha.md says how this extends to several active instances.
"""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from collections.abc import Callable

from delegation.errors import DelegationError
from delegation.runtime.mqtt import Message, MqttError
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.transport import make_client
from delegation.service.config import ServiceConfig
from delegation.service.jobs import Job, JobResult, run_job
from delegation.service.outage import DEFAULT_BOUND
from delegation.service.store import SqliteStore, Store, StoreError
from delegation.service.unit import DEFAULT_RETENTION, DelegationService

log = logging.getLogger(__name__)

#: Seconds between two tries of the lock by a standby instance.
STANDBY_POLL = 1.0
#: Seconds a new instance listens for another live instance of its name (3 heartbeat periods).
PROBE_SECONDS = 3.0


class InstanceConflict(DelegationError):
    """Another instance of this service is active and the state cannot be shared."""


def other_instance(
    settings: BrokerSettings, config: ServiceConfig, agent_uuid: str, seconds: float
) -> str | None:
    """Listen ``seconds`` for a heartbeat of ``config.name`` with another agent-uuid; its topic
    and agent-uuid if one came, else None."""
    found: list[str] = []
    got = threading.Event()

    def sink(message: Message) -> None:
        try:
            data = json.loads(message.payload)
        except ValueError:
            return
        other = data.get("agent-uuid") if isinstance(data, dict) else None
        if other and other != agent_uuid:
            found.append(f"{message.topic} (agent-uuid {other})")
            got.set()

    client = make_client(settings, f"{config.name}-probe-{uuid.uuid4().hex[:8]}", sink=sink)
    client.subscribe(f"{config.prefix}/unit/+/+/{config.name}/heartbeat")
    try:
        client.connect(timeout=10.0)
    except MqttError as exc:
        raise DelegationError(f"cannot connect to {settings.describe()}: {exc}") from exc
    try:
        got.wait(seconds)
    finally:
        client.disconnect()
    return found[0] if found else None


def _try(store: Store, name: str) -> bool:
    """One try of the lock by a standby; the database unreachable for now is no reason to stop
    standing by (logged; tried again at the next poll)."""
    try:
        return store.acquire(name)
    except StoreError as exc:
        log.warning("%s: standby: cannot try the lock: %s", name, exc)
        return False


def run_active(
    settings: BrokerSettings,
    config: ServiceConfig,
    store: Store,
    stop: threading.Event,
    *,
    retention: float = DEFAULT_RETENTION,
    store_bound: float = DEFAULT_BOUND,
    poll: float = STANDBY_POLL,
    probe: float = PROBE_SECONDS,
    announce: Callable[[str], None] = log.info,
    planner: Callable[[Job], JobResult] = run_job,
) -> int:
    """Become the active instance (or stand by until it can), then serve until ``stop``; 0 after
    ``stop``, 1 if it gave up: the lock was lost, or the store failed for ``store_bound`` s (the
    service has left the broker by then; the caller closes the store, which releases the lock).
    `InstanceConflict` when it must not start at all."""
    if not store.acquire(config.name):
        if not store.shared:
            holder = store.holder() if isinstance(store, SqliteStore) else "?"
            raise InstanceConflict(
                f"another delegation service uses the state {store.where} (lock held by "
                f"{holder}); one store serves one active instance: stop it, or give this one "
                f"another --state (and --name), or share a PostgreSQL --state to stand by")
        announce(f"{config.name}: standby: another instance is active on {store.where}; "
                 f"taking over when it stops")
        while not _try(store, config.name):
            if stop.wait(poll):
                return 0
        announce(f"{config.name}: the active instance stopped; taking over")
    agent_uuid = str(uuid.uuid4())
    if not store.shared and probe > 0:
        other = other_instance(settings, config, agent_uuid, probe)
        if other is not None:
            raise InstanceConflict(
                f"another delegation service named {config.name!r} is live on "
                f"{settings.describe()}: heartbeat on {other}; two instances would answer every "
                f"command twice: stop it or use another --name")
    began = time.monotonic()
    service = DelegationService(settings, config, planner=planner, store=store,
                                retention=retention, store_bound=store_bound)
    service.core.identity = config.identity(agent_uuid)
    service.start()
    announce(f"{config.name}: active ({len(service.core.book)} open missions from "
             f"{store.where}, ready in {time.monotonic() - began:.1f} s)")
    try:
        while not stop.wait(0.5):
            if service.failed.is_set():
                announce(f"{config.name}: gave up: {service.failure}")
                return 1
        return 0
    finally:
        service.stop()
