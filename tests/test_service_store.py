"""The state store (SQLite, and PostgreSQL when one answers at 127.0.0.1:5432), the book's and the
command log's dirty journals, retention and paging; no broker."""

from __future__ import annotations

import json
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from delegation.messages import MissionStatus
from delegation.runtime.commands import CommandLog, CommandState
from delegation.runtime.core import Outgoing
from delegation.service.missions import (
    Change,
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
    assert not book.dirty and not log.dirty

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
    assert not book.dirty  # nobody drains a book without a store: nothing is noted
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


# ---- what is written, and when (issue 19: the unchanging parts once, changes only when real)


def _row(store: Store, root: str) -> tuple[str, str, str | None]:
    assert isinstance(store, SqliteStore | PostgresStore)
    rows = store._fetch("SELECT data, state, tree FROM missions WHERE root_uuid = ?", (root,))
    return rows[0][0], rows[0][1], rows[0][2]


def test_unchanging_parts_are_written_once_and_changes_only_when_real(store: Store) -> None:
    book = MissionBook(archive=store)
    m = mission("r1", 10.0)
    m.tst = m.current_tst = {"name": "move-to", "common_params": {"node-uuid": "r1"}}
    m.plan = {"strategy": "auction", "tst": m.tst}  # the plan carries the sent tree
    book.add(m)
    assert book.drain_dirty() == [(m, Change.NEW)]
    store.save([(m, Change.NEW)], [])
    data, state, tree = _row(store, "r1")
    assert "tst" not in json.loads(data)["plan"] and tree is None  # the sent tree once
    node = next(uid for uid, info in m.nodes.items() if info.is_task)

    book.observe_feedback(node, "running", False, "", 12.0)  # already running since 11.0
    assert not book.dirty  # a feedback that changes nothing is not written
    book.observe_feedback(node, "succeeded", False, "", 13.0)
    changed = book.drain_dirty()
    assert changed == [(m, Change.STATE)]
    store.save(changed, [])
    data2, state2, _ = _row(store, "r1")
    assert data2 == data and state2 != state  # only the moving part was rewritten
    book.observe_feedback(node, "succeeded", False, "", 14.0)  # a re-sent final feedback
    assert not book.dirty

    loaded = store.load_mission("r1")
    assert loaded is not None and loaded.plan["tst"] == m.tst
    assert loaded.node_status[node] == "succeeded" and loaded.node_ended[node] == 13.0
    assert loaded.to_json() == m.to_json()


def test_a_re_delegated_tree_is_written_with_the_state(store: Store) -> None:
    book = MissionBook(archive=store)
    m = mission("r1", 10.0)
    book.add(m)
    store.save(book.drain_dirty(), [])
    new = NodeInfo("n2", "move-to", "/u1", "root/children[0]", True)
    tree = {"name": "move-to", "common_params": {"node-uuid": "n2"}}
    book.replace_tree(m, tree, "n2", {"n2": new}, {"n2": "x"})
    changed = book.drain_dirty()
    assert changed == [(m, Change.TREE | Change.STATE)]
    store.save(changed, [])
    loaded = store.load_mission("r1")
    assert loaded is not None
    assert (loaded.current_tst, loaded.current_root, loaded.redelegations) == (tree, "n2", 1)
    assert loaded.nodes["n2"] == new and loaded.origin == {"n2": "x"}
    assert loaded.current_nodes == {"n2"}


def test_a_store_of_the_earlier_schema_is_opened_and_read(tmp_path: Path) -> None:
    """Tables made before the split (a mission's whole record in ``data``, no digest/caller):
    columns are added, old rows read as before."""
    import sqlite3

    path = tmp_path / "old.sqlite"
    m = mission("r1", 10.0)
    conn = sqlite3.connect(path)
    conn.execute("CREATE TABLE missions (root_uuid TEXT PRIMARY KEY, created DOUBLE PRECISION "
                 "NOT NULL, status TEXT NOT NULL, ended DOUBLE PRECISION, summary TEXT NOT NULL, "
                 "data TEXT NOT NULL)")
    conn.execute("CREATE TABLE commands (face TEXT NOT NULL, com_uuid TEXT NOT NULL, state TEXT "
                 "NOT NULL, received DOUBLE PRECISION NOT NULL, answer TEXT NOT NULL, "
                 "PRIMARY KEY (face, com_uuid))")
    conn.execute("INSERT INTO missions VALUES (?, ?, ?, ?, ?, ?)",
                 ("r1", 10.0, "planned", None, json.dumps(m.summary()),
                  json.dumps(mission_record(m))))
    conn.execute("INSERT INTO commands VALUES ('delegation', 'c-1', 'done', 1.0, '[]')")
    conn.commit()
    conn.close()
    store = SqliteStore(path)
    try:
        loaded = store.load_mission("r1")
        assert loaded is not None and loaded.to_json() == m.to_json()
        entry = store.load_command(("delegation", "c-1"))
        assert entry is not None and (entry.digest, entry.caller, entry.reply_topic) == ("", "", "")
        book = MissionBook(archive=store)
        book.add(loaded)
        store.save(book.drain_dirty(), [])
        book.set_status("r1", MissionStatus.FAILED, 20.0, "x")
        store.save(book.drain_dirty(), [])
        again = store.load_mission("r1")
        assert again is not None and again.status is MissionStatus.FAILED
    finally:
        store.close()


# ---- who asked (issue 23, item 5)


def test_the_command_log_keeps_digest_caller_and_reply_topic(store: Store) -> None:
    log = CommandLog(archive=store)
    key = ("delegation", "c-1")
    entry = log.begin(key, 5.0, "d1")
    entry.caller, entry.reply_topic = "alice", "p/delegation/response/alice"
    store.save([], log.drain_dirty())
    pending = store.load_command(key)
    assert pending is not None and pending.state is CommandState.PENDING
    assert (pending.digest, pending.caller, pending.reply_topic) == (
        "d1", "alice", "p/delegation/response/alice")
    log.finish(key, [Outgoing("p/delegation/response/alice", b"{}", 1)])
    store.save([], log.drain_dirty())
    again = CommandLog(archive=store)  # a new instance: the command left memory
    seen = again.seen(key)
    assert seen is not None and seen.state is CommandState.DONE
    assert not seen.same_command("d2") and seen.same_command("d1")
    assert [e.caller for e in store.commands(CommandState.DONE, 10)] == ["alice"]


def test_restart_answers_on_the_callers_own_topic(tmp_path: Path) -> None:
    """A command in progress when the instance died is answered on its caller's topic, and a
    different command reusing its com-uuid is still refused."""
    from delegation.runtime.commands import payload_digest
    from delegation.runtime.settings import BrokerSettings
    from delegation.service import DelegationService, ServiceConfig

    config = ServiceConfig(name="svc")
    reply = f"{config.base_topic}/delegation/response/alice"
    store = SqliteStore(tmp_path / "s.sqlite")
    log = CommandLog(archive=store)
    body = b'{"com-uuid": "c-1", "command": "delegate", "tst": {"name": "move-to"}}'
    entry = log.begin(("delegation", "c-1"), 1.0, payload_digest(body))
    entry.caller, entry.reply_topic = "alice", reply
    store.save([], log.drain_dirty())

    service = DelegationService(BrokerSettings(host="127.0.0.1", port=1), config, store=store)
    core = service.core
    done = core.commands.get(("delegation", "c-1"))
    assert done is not None and done.state is CommandState.DONE
    assert [o.topic for o in done.answer] == [reply]
    assert (done.caller, done.reply_topic) == ("alice", reply)
    stored = store.load_command(("delegation", "c-1"))
    assert stored is not None and [o.topic for o in stored.answer] == [reply]

    other = b'{"com-uuid": "c-1", "command": "list-missions"}'
    refused = core.on_message(f"{config.base_topic}/delegation/command/alice", other, 5.0)
    assert [o.topic for o in refused.publish] == [reply]
    assert "reused for a different command" in json.loads(refused.publish[0].payload)[
        "fail-reason"]
    again = core.on_message(f"{config.base_topic}/delegation/command/alice", body, 6.0)
    assert again.publish == done.answer  # the re-send: the stored answer again
    store.close()


# ---- one commit per batch, answers published after it


@pytest.mark.mqtt
def test_a_batch_is_stored_in_one_commit_before_its_answers_go_out(
    mqtt_settings: Any, prefix: str, collector: Any, tmp_path: Path
) -> None:
    from delegation.runtime.mqtt import Message
    from delegation.service import DelegationService, ServiceConfig

    class Recording(SqliteStore):
        def __init__(self, path: Path) -> None:
            super().__init__(path)
            self.commits = 0
            self.answered: set[str] = set()

        def save(self, missions: Any, commands: Any) -> None:
            super().save(missions, commands)
            if missions or commands:
                self.commits += 1
                self.answered.update(e.key[1] for e in commands
                                     if e.state is CommandState.DONE)

    unstored: list[str] = []  # answers published before they were stored

    class Checked(DelegationService):
        def send(self, out: Outgoing) -> None:
            if "/delegation/response" in out.topic:
                com = json.loads(out.payload)["response-to"]
                if com not in store.answered:
                    unstored.append(com)
            super().send(out)

    config = ServiceConfig(prefix=prefix, name="svc")
    store = Recording(tmp_path / "s.sqlite")
    watch = collector(f"{config.base_topic}/delegation/response")
    service = Checked(mqtt_settings, config, store=store)
    service.start()
    try:
        coms = [f"c-{i}" for i in range(30)]
        with service._state:  # the loop waits: the 30 pings are all queued when it goes on
            before = store.commits
            for com in coms:
                body = {"com-uuid": com, "command": "ping"}
                service.call_soon(Message(f"{config.base_topic}/delegation/command",
                                          json.dumps(body).encode()))
        watch.wait_for(lambda _m: {d.get("response-to") for d in watch.json_on(
            f"{config.base_topic}/delegation/response")} >= set(coms), timeout=10,
            what="the 30 answers")
        assert store.commits - before <= 2  # one commit for the batch (a first one maybe alone)
        assert unstored == []
        assert store.answered >= set(coms)
    finally:
        service.stop()
        store.close()
