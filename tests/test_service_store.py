"""The state store (SQLite, and PostgreSQL when one answers at 127.0.0.1:5432), the book's and the
command log's dirty journals, retention and paging; no broker."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from delegation.messages import MissionStatus
from delegation.runtime.commands import CommandLog, CommandState
from delegation.runtime.core import Outgoing
from delegation.service.missions import (
    Mission,
    MissionBook,
    NodeInfo,
    mission_from_record,
    mission_record,
)
from delegation.service.store import PostgresStore, SqliteStore, Store, lock_key, open_store

PG_BASE = "postgresql://127.0.0.1:5432/test"


def mission(root: str, created: float) -> Mission:
    node = str(uuid.uuid4())
    m = Mission(root_uuid=root, source="delegate", created=created, tst={"name": "conc"},
                plan={"strategy": "auction", "makespan": 1.5},
                nodes={root: NodeInfo(root, "conc", "", "root", False),
                       node: NodeInfo(node, "move-to", "/u0", "root/children[0]", True)},
                received={"name": "conc"}, command=("delegation", f"c-{root}"))
    m.node_status[node] = "running"
    m.node_started[node] = created + 1
    return m


@pytest.fixture
def pg_store() -> Iterator[PostgresStore]:
    """A PostgreSQL store in a schema of this test alone (dropped after); skipped without one."""
    psycopg = pytest.importorskip("psycopg")
    try:
        psycopg.connect(PG_BASE, connect_timeout=3).close()
    except psycopg.Error:
        pytest.skip("no PostgreSQL at 127.0.0.1:5432/test")
    schema = f"t_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(PG_BASE, autocommit=True) as conn:
        conn.execute(f"CREATE SCHEMA {schema}")
    s = PostgresStore(f"{PG_BASE}?options=-csearch_path%3D{schema}")
    try:
        yield s
    finally:
        s.close()
        with psycopg.connect(PG_BASE, autocommit=True) as conn:
            conn.execute(f"DROP SCHEMA {schema} CASCADE")


@pytest.fixture(params=["sqlite", "postgres"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Store]:
    if request.param == "postgres":
        yield request.getfixturevalue("pg_store")
        return
    s = SqliteStore(tmp_path / "s.sqlite")
    yield s
    s.close()


def test_mission_record_round_trip() -> None:
    m = mission("r1", 100.0)
    m.status, m.started_at = MissionStatus.RUNNING, 101.0
    back = mission_from_record(mission_record(m))
    assert back == m
    assert back.to_json() == m.to_json()


def test_store_keeps_missions_and_exact_answers(store: Store) -> None:
    log = CommandLog(archive=store)
    key = ("delegation", "c-1")
    log.begin(key, 5.0)
    answer = [Outgoing("a/delegation/response", b'{"response":"ok","x":"\xc3\xa9"}', 1)]
    assert log.finish(key, answer)
    book = MissionBook(archive=store)
    book.add(mission("r1", 10.0))
    book.add(mission("r2", 20.0))
    book.set_status("r2", MissionStatus.SUCCEEDED, 30.0)
    store.save(book.drain_dirty(), log.drain_dirty())
    assert book.dirty == set() and log.dirty == set()

    entry = store.load_command(key)
    assert entry is not None and entry.state is CommandState.DONE
    assert entry.answer == answer  # the same bytes
    assert [m.root_uuid for m in store.open_missions()] == ["r1"]
    loaded = store.load_mission("r2")
    assert loaded is not None and loaded.status is MissionStatus.SUCCEEDED
    assert loaded.to_json() == book.get("r2").to_json()
    page, total = store.page_missions(1, 5)
    assert total == 2 and [p["root-uuid"] for p in page] == ["r2"]
    assert store.load_mission("nope") is None and store.load_command(("tst", "c-1")) is None


def test_command_log_reads_back_what_left_memory(store: Store) -> None:
    log = CommandLog(capacity=2, archive=store)
    for i in range(4):
        key = ("delegation", f"c-{i}")
        log.begin(key, float(i))
        log.finish(key, [Outgoing("t", f"answer {i}".encode())])
        store.save([], log.drain_dirty())
    assert len(log) == 2
    entry = log.seen(("delegation", "c-0"))  # forgotten in memory, found in the store
    assert entry is not None and entry.answer[0].payload == b"answer 0"
    assert log.seen(("delegation", "c-9")) is None


def test_retention_drops_ended_missions_from_memory_only(store: Store) -> None:
    book = MissionBook(archive=store)
    book.add(mission("old", 1.0))
    book.add(mission("live", 2.0))
    book.set_status("old", MissionStatus.FAILED, 5.0, "x")
    assert book.forget_ended(100.0) == []  # still dirty: not stored yet, kept
    store.save(book.drain_dirty(), [])
    assert book.forget_ended(4.0) == []  # ended at 5.0: not past retention
    assert book.forget_ended(6.0) == ["old"]
    assert "old" not in book and "live" in book
    assert book.get("old").fail_reason == "x"  # read back from the store
    missions, total = book.page(0, 10)
    assert total == 2 and [m["root-uuid"] for m in missions] == ["old", "live"]


def test_page_in_memory_without_a_store() -> None:
    book = MissionBook()
    for i in range(5):
        book.add(mission(f"r{i}", float(i)))
    assert book.dirty == set()  # nobody drains a book without a store: nothing is noted
    page, total = book.page(3, 10)
    assert total == 5 and [p["root-uuid"] for p in page] == ["r3", "r4"]


def test_sqlite_file_is_locked_by_one_instance(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    one, two = open_store(str(path)), open_store(str(path))
    try:
        assert one.acquire("svc") and one.holds()
        assert not two.acquire("svc")
        assert isinstance(one, SqliteStore) and one.holder().endswith(" svc")
    finally:
        one.close()
    assert two.acquire("svc")  # released with the holder
    two.close()


def test_postgres_lock_one_holder(pg_store: PostgresStore) -> None:
    store = pg_store
    other = PostgresStore(store.dsn)
    name = f"svc-{uuid.uuid4().hex}"
    try:
        assert store.acquire(name) and store.holds()
        assert not other.acquire(name)
        store.close()
        # The server releases the lock when it has ended the closed session (a moment later):
        # a blocking pg_advisory_lock on a third session waits for that, bounded by lock_timeout.
        import psycopg

        with psycopg.connect(store.dsn, autocommit=True) as waiter:
            waiter.execute("SET lock_timeout = '5s'")
            waiter.execute("SELECT pg_advisory_lock(%s)", (lock_key(name),))
            waiter.execute("SELECT pg_advisory_unlock(%s)", (lock_key(name),))
        assert other.acquire(name)
    finally:
        other.close()
    assert lock_key("a") == lock_key("a") != lock_key("b")


def test_restart_answers_commands_that_were_in_progress(tmp_path: Path) -> None:
    """A command the dead instance was working on is answered ``failed`` (never run again),
    naming the mission it created; open missions are loaded, ended ones left in the store."""
    import json

    from delegation.runtime.settings import BrokerSettings
    from delegation.service import DelegationService, ServiceConfig

    store = SqliteStore(tmp_path / "s.sqlite")
    log = CommandLog(archive=store)
    log.begin(("delegation", "c-r1"), 1.0)  # waiting for the engine when the instance died
    log.begin(("tst", "c-plan"), 2.0)  # still being planned
    book = MissionBook(archive=store)
    book.add(mission("r1", 1.0))
    book.add(mission("r2", 1.5))
    book.set_status("r2", MissionStatus.SUCCEEDED, 3.0)
    store.save(book.drain_dirty(), log.drain_dirty())

    service = DelegationService(BrokerSettings(host="127.0.0.1", port=1),
                                ServiceConfig(name="svc"), store=store)
    core = service.core
    assert "r1" in core.book and "r2" not in core.book  # open in memory, ended in the store
    assert core.book.get("r2").status is MissionStatus.SUCCEEDED
    first = core.commands.get(("delegation", "c-r1"))
    assert first is not None and first.state is CommandState.DONE
    answer = json.loads(first.answer[0].payload)
    assert first.answer[0].topic.endswith("/svc/delegation/response")
    assert answer["response"] == "failed" and "it created mission r1" in answer["fail-reason"]
    planning = store.load_command(("tst", "c-plan"))  # stored too: a later instance agrees
    assert planning is not None and planning.answer[0].topic.endswith("/svc/tst/response")
    assert "nothing was started" in json.loads(planning.answer[0].payload)["fail-reason"]
    store.close()


def test_a_regrouped_and_re_delegated_mission_round_trips() -> None:
    """The operator's view (rebuilt from the tree received and the tree sent) and the
    re-delegation fields come back from the record, so feedback after a restart still maps."""
    from delegation.service.operator_view import OperatorView
    from delegation.tst.node import parse_tree

    a, b = str(uuid.uuid4()), str(uuid.uuid4())
    received = {"name": "seq", "common_params": {"node-uuid": "r3"}, "children": [
        {"name": "move-to", "common_params": {"node-uuid": a}, "params": {}},
        {"name": "move-to", "common_params": {"node-uuid": b}, "params": {}}]}
    sent = {"name": "conc", "common_params": {"node-uuid": "new-root"}, "children":
            received["children"]}
    m = mission("r3", 5.0)
    m.received, m.tst = received, sent
    m.operator = OperatorView.of(parse_tree(received), parse_tree(sent))
    m.current_root, m.redelegations = "r3-second", 1
    m.origin, m.retries, m.current_nodes = {"x": a}, {a: 1}, {"x"}
    back = mission_from_record(mission_record(m))
    assert back.operator is not None and back.operator.root == "r3"
    assert back.operator.leaves == m.operator.leaves and back.operator.kept == m.operator.kept
    assert (back.current_root, back.redelegations) == ("r3-second", 1)
    assert (back.origin, back.retries, back.current_nodes) == ({"x": a}, {a: 1}, {"x"})
