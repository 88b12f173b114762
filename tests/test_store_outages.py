"""The store failing (issue 22 item 4), in process: what is not stored waits and is retried,
heartbeats go on, past the bound the instance leaves the broker; PostgreSQL reconnects, takes its
lock again before writing, and bounds every statement.

Real processes (``delegation serve`` with the backend terminated or the disk full) are in
``test_store_faults.py``.
"""

from __future__ import annotations

import json
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from delegation.runtime.commands import CommandState
from delegation.runtime.core import Outgoing
from delegation.runtime.settings import BrokerSettings
from delegation.service import DelegationService, ServiceConfig
from delegation.service.outage import Outage
from delegation.service.store import (
    PG_STATEMENT_TIMEOUT_MS,
    LockLost,
    PostgresStore,
    SqliteStore,
    StoreError,
)

PG_BASE = "postgresql://127.0.0.1:5432/test"


class FlakyStore(SqliteStore):
    """An SQLite store whose writes fail while ``failing`` is set (as a full disk would)."""

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.failing = threading.Event()
        self.failures = 0
        self.answered: set[str] = set()
        self.changed = threading.Condition()

    def save(self, missions: Any, commands: Any) -> None:
        with self.changed:
            self.changed.notify_all()
            if self.failing.is_set() and (missions or commands):
                self.failures += 1
                raise StoreError("database or disk is full (simulated)")
        super().save(missions, commands)
        self.answered.update(e.key[1] for e in commands if e.state is CommandState.DONE)

    def wait_failures(self, n: int, timeout: float) -> bool:
        with self.changed:
            return self.changed.wait_for(lambda: self.failures >= n, timeout)


def test_outage_backs_off_and_gives_up_past_the_bound() -> None:
    outage = Outage(bound=10.0, first=0.5, longest=4.0)
    assert outage.due(0.0) and not outage.ongoing
    assert not outage.failed(100.0)
    assert outage.ongoing and not outage.due(100.4) and outage.due(100.5)
    assert not outage.failed(100.5)  # next try 1 s later, then 2, then 4 (the longest)
    assert outage.retry_at == 101.5
    assert not outage.failed(101.5) and outage.retry_at == 103.5
    assert not outage.failed(103.5) and outage.retry_at == 107.5
    assert not outage.failed(107.5) and outage.retry_at == 111.5
    assert outage.failed(110.0)  # 10 s of failures: give up
    assert outage.recovered(111.0) == 11.0 and not outage.ongoing and outage.due(0.0)
    assert outage.recovered(112.0) is None


@pytest.fixture
def flaky(tmp_path: Path) -> Iterator[FlakyStore]:
    store = FlakyStore(tmp_path / "state.sqlite")
    assert store.acquire("svc")
    yield store
    store.close()


def _ping(watch: Any, topic: str) -> str:
    com = str(uuid.uuid4())
    watch.publish(topic, json.dumps({"command": "ping", "com-uuid": com, "sender": "t"}).encode())
    return com


@pytest.mark.mqtt
def test_a_failing_store_holds_answers_retries_and_heartbeats_go_on(
    mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any], flaky: FlakyStore,
) -> None:
    config = ServiceConfig(name="svc", prefix=prefix, rate=10.0)
    base = config.base_topic
    unstored: list[str] = []

    class Checked(DelegationService):
        def send(self, out: Outgoing) -> None:
            if out.topic.endswith("/delegation/response"):
                com = json.loads(out.payload)["response-to"]
                if com not in flaky.answered:
                    unstored.append(com)
            super().send(out)

    watch = collector(f"{base}/heartbeat", f"{base}/delegation/response")
    service = Checked(mqtt_settings, config, store=flaky, store_bound=60.0)
    service.start()
    try:
        first = _ping(watch, f"{base}/delegation/command")
        watch.wait_json(f"{base}/delegation/response", lambda d: d.get("response-to") == first)
        flaky.failing.set()
        coms = [_ping(watch, f"{base}/delegation/command") for _ in range(3)]
        assert flaky.wait_failures(3, timeout=10.0)  # tried, failed, retried (backing off)
        beats = len(watch.json_on(f"{base}/heartbeat"))
        watch.wait_for(lambda _m: len(watch.json_on(f"{base}/heartbeat")) >= beats + 5,
                       timeout=5.0, what="heartbeats while the store fails")
        answered = {d.get("response-to") for d in watch.json_on(f"{base}/delegation/response")}
        assert not answered & set(coms)  # nothing published that is not stored
        assert service.held >= 3 and not service.failed.is_set()
        flaky.failing.clear()
        watch.wait_for(lambda _m: set(coms) <= {d.get("response-to") for d in watch.json_on(
            f"{base}/delegation/response")}, timeout=10.0, what="the held answers")
        assert unstored == [] and set(coms) <= flaky.answered
        order = [d.get("response-to") for d in watch.json_on(f"{base}/delegation/response")]
        assert [c for c in order if c in coms] == coms  # in the order they were asked
        assert service.held == 0 and not service.failed.is_set()
    finally:
        service.stop()


@pytest.mark.mqtt
def test_past_the_bound_the_instance_leaves_the_broker_and_says_why(
    mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any], flaky: FlakyStore,
) -> None:
    config = ServiceConfig(name="svc", prefix=prefix, rate=10.0)
    base = config.base_topic
    watch = collector(f"{base}/heartbeat", f"{base}/delegation/response")
    service = DelegationService(mqtt_settings, config, store=flaky, store_bound=1.5)
    service.start()
    try:
        watch.wait_json(f"{base}/heartbeat")
        flaky.failing.set()
        began = time.monotonic()
        com = _ping(watch, f"{base}/delegation/command")
        assert service.failed.wait(10.0)
        assert time.monotonic() - began >= 1.5
        assert "failed for" in service.failure and "bound 1.5 s" in service.failure
        assert not service.lock_lost.is_set()
        assert not service.client.connected.is_set()  # left the broker: publishes nothing
        assert com not in {d.get("response-to") for d in
                           watch.json_on(f"{base}/delegation/response")}
    finally:
        service.stop()


# ---------------------------------------------------------------- PostgreSQL: lock and timeouts


@pytest.fixture
def pg_dsn() -> Iterator[str]:
    psycopg = pytest.importorskip("psycopg")
    try:
        psycopg.connect(PG_BASE, connect_timeout=3).close()
    except psycopg.Error:
        pytest.skip("no PostgreSQL at 127.0.0.1:5432/test")
    schema = f"t_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(PG_BASE, autocommit=True) as conn:
        conn.execute(f"CREATE SCHEMA {schema}")
    try:
        yield f"{PG_BASE}?options=-csearch_path%3D{schema}&application_name={schema}"
    finally:
        with psycopg.connect(PG_BASE, autocommit=True) as conn:
            conn.execute(f"DROP SCHEMA {schema} CASCADE")


def _terminate(store: PostgresStore) -> None:
    """``pg_terminate_backend`` of the store's session (as a dropped connection would end)."""
    import psycopg

    pid = store._conn.info.backend_pid
    with psycopg.connect(PG_BASE, autocommit=True) as admin:
        admin.execute("SELECT pg_terminate_backend(%s, 5000)", (pid,))


def test_postgres_reconnects_and_takes_its_lock_again_before_writing(pg_dsn: str) -> None:
    store = PostgresStore(pg_dsn)
    name = f"svc-{uuid.uuid4().hex}"
    try:
        assert store.acquire(name)
        _terminate(store)
        store.save([], [])  # nothing to write: no round trip
        from delegation.runtime.commands import CommandEntry

        entry = CommandEntry(("delegation", "c1"), 1.0, CommandState.DONE, [])
        store.save([], [entry])  # reconnected, the lock taken again, then written
        assert store.holds()
        assert store.load_command(("delegation", "c1")) is not None
        other = PostgresStore(pg_dsn)
        try:
            assert not other.acquire(name)  # still ours
        finally:
            other.close()
    finally:
        store.close()


def test_postgres_refuses_to_write_once_another_instance_took_the_lock(pg_dsn: str) -> None:
    from delegation.runtime.commands import CommandEntry

    active, standby = PostgresStore(pg_dsn), PostgresStore(pg_dsn)
    name = f"svc-{uuid.uuid4().hex}"
    try:
        assert active.acquire(name) and not standby.acquire(name)
        _terminate(active)
        deadline = time.monotonic() + 10.0
        while not standby.acquire(name):  # the server ends the session, then the lock is free
            assert time.monotonic() < deadline, "the lock was never released"
            time.sleep(0.05)
        entry = CommandEntry(("delegation", "late"), 1.0, CommandState.DONE, [])
        with pytest.raises(LockLost):
            active.save([], [entry])
        assert not active.holds()
        assert standby.load_command(("delegation", "late")) is None  # nothing written
    finally:
        active.close()
        standby.close()


def test_postgres_statements_are_bounded_in_time(pg_dsn: str) -> None:
    import psycopg

    from delegation.runtime.commands import CommandEntry

    store = PostgresStore(pg_dsn)
    try:
        with psycopg.connect(pg_dsn) as blocker:
            blocker.execute("LOCK TABLE commands IN ACCESS EXCLUSIVE MODE")  # held till the end
            entry = CommandEntry(("delegation", "c1"), 1.0, CommandState.DONE, [])
            began = time.monotonic()
            with pytest.raises(StoreError, match="statement timeout"):
                store.save([], [entry])
            took = time.monotonic() - began
            blocker.rollback()
        assert PG_STATEMENT_TIMEOUT_MS / 1000 <= took < PG_STATEMENT_TIMEOUT_MS / 1000 + 2
        store.save([], [entry])  # the same connection works on
        assert store.load_command(("delegation", "c1")) is not None
        params = store._conn.info.get_parameters()
        assert params["keepalives"] == "1" and params["tcp_user_timeout"] == "6000"
    finally:
        store.close()




def test_postgres_lock_check_reconnects_a_dropped_session(pg_dsn: str) -> None:
    store = PostgresStore(pg_dsn)
    name = f"svc-{uuid.uuid4().hex}"
    try:
        assert store.acquire(name)
        before = store._conn.info.backend_pid
        _terminate(store)
        assert store.holds()  # reconnected and the lock is ours again
        assert store._conn.info.backend_pid != before
    finally:
        store.close()


@pytest.mark.mqtt
def test_a_standby_keeps_standing_by_while_the_database_is_unreachable(
    mqtt_settings: BrokerSettings, prefix: str, tmp_path: Path,
) -> None:
    from delegation.service.active import run_active

    class Shared(SqliteStore):
        """Tries of the lock: unreachable twice, held by another once, then free."""

        shared = True

        def __init__(self, path: Path) -> None:
            super().__init__(path)
            self.tries = 0

        def acquire(self, name: str) -> bool:
            self.tries += 1
            if self.tries in (2, 3):
                raise StoreError("cannot connect to the database (simulated)")
            return self.tries >= 5 and super().acquire(name)

    store = Shared(tmp_path / "state.sqlite")
    said: list[str] = []
    stop = threading.Event()
    active = threading.Event()

    def announce(text: str) -> None:
        said.append(text)
        if ": active" in text:
            active.set()

    result: list[int] = []
    runner = threading.Thread(target=lambda: result.append(run_active(
        mqtt_settings, ServiceConfig(name="svc", prefix=prefix), store, stop, poll=0.05,
        announce=announce)))
    runner.start()
    try:
        assert active.wait(15.0), said
    finally:
        stop.set()
        runner.join(15.0)
        store.close()
    assert not runner.is_alive() and result == [0]
    assert store.tries == 5
    assert any("standby" in s for s in said) and any("taking over" in s for s in said)
