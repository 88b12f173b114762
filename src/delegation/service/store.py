"""Where the service's state survives a crash: missions and the answer to every com-uuid.

One schema, two back ends behind the `Store` protocol:

* `SqliteStore` (default): one file, WAL, ``synchronous=FULL`` (a transaction the service
  committed survives ``kill -9`` and a power cut). No server. The file is locked (``flock`` on
  ``PATH.lock``) by the one service using it: a second one on the same file refuses to start.
* `PostgresStore` (``--state postgresql://...``, psycopg 3, extra ``postgres``): the same tables;
  several instances share it, and ``pg_try_advisory_lock`` on a dedicated connection decides which
  one is active (the others stand by, `delegation.service.active`). Put the tables in a schema of
  your own with ``?options=-csearch_path%3DNAME`` in the DSN (the schema must exist).

The unit (`delegation.service.unit`) writes what a batch of messages changed in one transaction
before it publishes that batch's messages, so an answer that went out is stored. Of a mission only
what changed is written (`Change`): its unchanging part once, its state on a real change, its tree
when a re-delegation replaced it. A command keeps its digest, caller and reply topic, so after a
restart a com-uuid reused for another command is still refused and answers go to the caller's own
topic. The pure core never sees this module: it reads back through `MissionArchive` /
`CommandArchive`.

Why ``synchronous=FULL`` rather than ``NORMAL``: in WAL mode both keep every committed transaction
across a crash of the process (the WAL frames are in the OS's cache when ``commit`` returns), but
with ``NORMAL`` an OS crash or power cut can lose the last commits, whose answers may already have
gone out (a re-send would then run the command again). ``FULL`` syncs the WAL at each commit; with
one commit per batch the burst benchmark measured no difference in CPU or answers/s between the
two (``benchmarks/burst.py``), so the stronger promise stays.
"""

from __future__ import annotations

import base64
import contextlib
import fcntl
import hashlib
import json
import logging
import os
import sqlite3
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol, TypeVar

from delegation.errors import DelegationError
from delegation.runtime.commands import CommandEntry, CommandKey, CommandState
from delegation.runtime.core import Outgoing
from delegation.service.missions import (
    Change,
    Mission,
    mission_fixed,
    mission_from_record,
    mission_state,
    mission_tree,
)

log = logging.getLogger(__name__)
T = TypeVar("T")

#: Tables (the same DDL for SQLite and PostgreSQL; times are epoch seconds). A mission is three
#: JSON parts: ``data`` what never changes (written once: the trees, the plan, the command),
#: ``state`` what moves (statuses, times: rewritten on a real change), ``tree`` the tree a
#: re-delegation put in place (NULL until one). A command keeps what tells a re-send from another
#: command reusing its com-uuid (``digest``) and whose it is (``caller``, ``reply_topic``).
SCHEMA = (
    """CREATE TABLE IF NOT EXISTS missions (
        root_uuid TEXT PRIMARY KEY,
        created DOUBLE PRECISION NOT NULL,
        status TEXT NOT NULL,
        ended DOUBLE PRECISION,
        summary TEXT NOT NULL,
        data TEXT NOT NULL,
        state TEXT,
        tree TEXT)""",
    "CREATE INDEX IF NOT EXISTS missions_by_created ON missions (created, root_uuid)",
    "CREATE INDEX IF NOT EXISTS missions_by_status ON missions (status)",
    """CREATE TABLE IF NOT EXISTS commands (
        face TEXT NOT NULL,
        com_uuid TEXT NOT NULL,
        state TEXT NOT NULL,
        received DOUBLE PRECISION NOT NULL,
        answer TEXT NOT NULL,
        digest TEXT NOT NULL DEFAULT '',
        caller TEXT NOT NULL DEFAULT '',
        reply_topic TEXT NOT NULL DEFAULT '',
        PRIMARY KEY (face, com_uuid))""",
    "CREATE INDEX IF NOT EXISTS commands_by_received ON commands (received)",
)
#: Columns a store made by an earlier version lacks (added when it is opened; its rows read as
#: before: a mission's ``data`` was then the whole record).
_ADDED_COLUMNS = (
    ("missions", "state", "TEXT"),
    ("missions", "tree", "TEXT"),
    ("commands", "digest", "TEXT NOT NULL DEFAULT ''"),
    ("commands", "caller", "TEXT NOT NULL DEFAULT ''"),
    ("commands", "reply_topic", "TEXT NOT NULL DEFAULT ''"),
)

_INSERT_MISSION = (
    "INSERT INTO missions (root_uuid, created, status, ended, summary, data, state, tree) "
    "VALUES (?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (root_uuid) DO UPDATE SET "
    "created = excluded.created, status = excluded.status, ended = excluded.ended, "
    "summary = excluded.summary, data = excluded.data, state = excluded.state, "
    "tree = excluded.tree"
)
_UPDATE_STATE = ("UPDATE missions SET status = ?, ended = ?, summary = ?, state = ? "
                 "WHERE root_uuid = ?")
_UPDATE_TREE = ("UPDATE missions SET status = ?, ended = ?, summary = ?, state = ?, tree = ? "
                "WHERE root_uuid = ?")
_MISSION_COLUMNS = "data, state, tree"
_UPSERT_COMMAND = (
    "INSERT INTO commands (face, com_uuid, state, received, answer, digest, caller, reply_topic) "
    "VALUES (?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (face, com_uuid) DO UPDATE SET "
    "state = excluded.state, answer = excluded.answer, digest = excluded.digest, "
    "caller = excluded.caller, reply_topic = excluded.reply_topic"
)
_COMMAND_COLUMNS = "face, com_uuid, state, received, answer, digest, caller, reply_topic"
_OPEN_STATUSES = ("planned", "started", "running")


class StoreError(DelegationError):
    """The state store cannot be opened or used."""


class LockLost(StoreError):
    """The lock that made this instance the active one is gone and another instance holds it:
    nothing may be written or published any more."""


#: Seconds an SQLite write waits for a reader's lock before it fails (and is retried later by
#: the unit): short, because the unit's thread (ticks, heartbeats) waits with it.
SQLITE_BUSY_SECONDS = 2.0
#: PostgreSQL connection settings the service adds to a DSN that does not set them: bounded
#: connects, TCP keep-alives and a TCP user timeout, so that a dropped connection (a NAT's idle
#: timeout, a dead server) is noticed in seconds, not at the kernel's ~15 minutes.
PG_CONNECTION = {
    "connect_timeout": "3",
    "keepalives": "1",
    "keepalives_idle": "5",
    "keepalives_interval": "2",
    "keepalives_count": "3",
    "tcp_user_timeout": "6000",
}
#: Milliseconds one PostgreSQL statement may run (a write normally takes a few).
PG_STATEMENT_TIMEOUT_MS = 3000


class Store(Protocol):
    """What the service keeps across restarts (also its `MissionArchive` and
    `CommandArchive`)."""

    #: Where the state is, for messages (no password).
    where: str
    #: True when other instances can share this store (one active, the others stand by).
    shared: bool

    def acquire(self, name: str) -> bool:
        """Become the one active instance of service ``name`` on this store; False if another
        one is (it keeps the lock until it dies or `close`)."""
        ...

    def holds(self) -> bool:
        """True while the lock taken by `acquire` is still held; False once it is known lost
        (another instance took it); `StoreError` when that cannot be told now (the database
        cannot be reached)."""
        ...

    def save(self, missions: Sequence[tuple[Mission, Change]],
             commands: Sequence[CommandEntry]) -> None:
        """Write what changed of missions, and commands, in one transaction; `StoreError` when
        it could not (nothing of it is written; the caller retries), `LockLost` when this
        instance is no longer the active one."""
        ...

    def load_mission(self, root_uuid: str) -> Mission | None: ...

    def page_missions(self, offset: int, limit: int) -> tuple[list[dict[str, Any]], int]: ...

    def open_missions(self) -> list[Mission]:
        """Missions that have not ended (to follow them after a restart)."""
        ...

    def load_command(self, key: CommandKey) -> CommandEntry | None: ...

    def commands(self, state: CommandState, limit: int) -> list[CommandEntry]:
        """The latest ``limit`` commands in ``state``, oldest first."""
        ...

    def close(self) -> None: ...


def _answer_json(answer: Sequence[Outgoing]) -> str:
    return json.dumps([[o.topic, base64.b64encode(o.payload).decode(), o.qos] for o in answer])


def _answer_of(text: str) -> list[Outgoing]:
    return [Outgoing(t, base64.b64decode(p), int(q)) for t, p, q in json.loads(text)]


def _entry(row: Sequence[Any]) -> CommandEntry:
    face, com, state, received, answer, digest, caller, reply_topic = row
    return CommandEntry((face, com), float(received), CommandState(state), _answer_of(answer),
                        digest=digest or "", caller=caller or "", reply_topic=reply_topic or "")


def _mission(row: Sequence[Any]) -> Mission:
    """A mission from its ``data, state, tree`` columns (later parts override earlier ones)."""
    record: dict[str, Any] = {}
    for part in row:
        if part:
            record.update(json.loads(part))
    return mission_from_record(record)


def _dumps(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"))


def _mission_write(m: Mission, change: Change) -> tuple[str, tuple[Any, ...]]:
    """The one statement that stores what ``change`` says changed of ``m``."""
    head = (m.status.value, m.ended_at, _dumps(m.summary()), _dumps(mission_state(m)))
    if not change & (Change.NEW | Change.TREE):
        return _UPDATE_STATE, (*head, m.root_uuid)
    tree = mission_tree(m)
    tree_json = _dumps(tree) if tree is not None else None
    if change & Change.NEW:
        return _INSERT_MISSION, (m.root_uuid, m.created, *head[:3], _dumps(mission_fixed(m)),
                                 head[3], tree_json)
    return _UPDATE_TREE, (*head, tree_json, m.root_uuid)


def lock_key(name: str) -> int:
    """The advisory-lock key of a service name (64-bit, signed, stable across processes)."""
    digest = hashlib.sha256(f"delegation-service:{name}".encode()).digest()
    return int.from_bytes(digest[:8], "big", signed=True)


class _SqlStore:
    """The queries, for any DB-API connection; subclasses open it and lock."""

    placeholder = "?"
    where = ""
    shared = False

    def __init__(self, conn: Any) -> None:
        self._conn = conn
        self._lock = threading.Lock()  # the loop thread and the starting thread share the store

    def _q(self, sql: str) -> str:
        return sql if self.placeholder == "?" else sql.replace("?", self.placeholder)

    def _connection(self) -> Any:
        """The connection to use now (held under ``_lock``); PostgreSQL reconnects here."""
        return self._conn

    def _failed(self, conn: Any, exc: Exception) -> None:
        """After an error on ``conn``: roll back what can be (a broken connection cannot)."""
        with contextlib.suppress(Exception):
            conn.rollback()

    def _fetch(self, sql: str, args: Sequence[Any] = ()) -> list[Any]:
        with self._lock:
            conn = self._connection()
            cur = conn.cursor()
            try:
                cur.execute(self._q(sql), tuple(args))
                rows = list(cur.fetchall())
                conn.commit()
            except Exception as exc:
                self._failed(conn, exc)
                raise StoreError(f"cannot read from {self.where}: "
                                 f"{type(exc).__name__}: {exc}".strip()) from exc
            finally:
                with contextlib.suppress(Exception):
                    cur.close()
            return rows

    def _create(self) -> None:
        with self._lock:
            cur = self._conn.cursor()
            for ddl in SCHEMA:
                cur.execute(ddl)
            cur.close()
            self._conn.commit()
            for table, column, kind in _ADDED_COLUMNS:
                self._add_column(table, column, kind)

    def _has_column(self, table: str, column: str) -> bool:
        cur = self._conn.cursor()
        try:
            cur.execute(f"SELECT {column} FROM {table} WHERE 1 = 0")
            cur.fetchall()
            self._conn.commit()
            return True
        except Exception:  # sqlite3's or psycopg's error: the column is missing
            self._conn.rollback()
            return False
        finally:
            cur.close()

    def _add_column(self, table: str, column: str, kind: str) -> None:
        """Add ``column`` to a table an earlier version created without it (an instance that
        starts at the same moment may add it first)."""
        if self._has_column(table, column):
            return
        log.info("state store: adding %s.%s", table, column)
        cur = self._conn.cursor()
        try:
            cur.execute(f"ALTER TABLE {table} ADD COLUMN {column} {kind}")
            self._conn.commit()
        except Exception:
            self._conn.rollback()
            if not self._has_column(table, column):
                raise
        finally:
            cur.close()

    def save(self, missions: Sequence[tuple[Mission, Change]],
             commands: Sequence[CommandEntry]) -> None:
        if not missions and not commands:
            return
        writes: dict[str, list[tuple[Any, ...]]] = {}
        for m, change in missions:
            sql, row = _mission_write(m, change)
            writes.setdefault(sql, []).append(row)
        c_rows = [(e.key[0], e.key[1], e.state.value, e.received, _answer_json(e.answer),
                   e.digest, e.caller, e.reply_topic) for e in commands]
        with self._lock:
            conn = self._connection()
            cur = conn.cursor()
            try:
                for sql, rows in writes.items():
                    cur.executemany(self._q(sql), rows)
                if c_rows:
                    cur.executemany(self._q(_UPSERT_COMMAND), c_rows)
                conn.commit()
            except Exception as exc:
                self._failed(conn, exc)
                raise StoreError(f"cannot write to {self.where}: "
                                 f"{type(exc).__name__}: {exc}".strip()) from exc
            except BaseException:
                self._failed(conn, RuntimeError("interrupted"))
                raise
            finally:
                with contextlib.suppress(Exception):
                    cur.close()

    def load_mission(self, root_uuid: str) -> Mission | None:
        rows = self._fetch(f"SELECT {_MISSION_COLUMNS} FROM missions WHERE root_uuid = ?",
                           (root_uuid,))
        return _mission(rows[0]) if rows else None

    def page_missions(self, offset: int, limit: int) -> tuple[list[dict[str, Any]], int]:
        total = int(self._fetch("SELECT COUNT(*) FROM missions")[0][0])
        rows = self._fetch("SELECT summary FROM missions ORDER BY created, root_uuid "
                           "LIMIT ? OFFSET ?", (limit, offset))
        return [json.loads(r[0]) for r in rows], total

    def open_missions(self) -> list[Mission]:
        rows = self._fetch(f"SELECT {_MISSION_COLUMNS} FROM missions WHERE status IN (?, ?, ?) "
                           "ORDER BY created, root_uuid", _OPEN_STATUSES)
        return [_mission(r) for r in rows]

    def load_command(self, key: CommandKey) -> CommandEntry | None:
        rows = self._fetch(f"SELECT {_COMMAND_COLUMNS} FROM commands "
                           "WHERE face = ? AND com_uuid = ?", key)
        return _entry(rows[0]) if rows else None

    def commands(self, state: CommandState, limit: int) -> list[CommandEntry]:
        rows = self._fetch(f"SELECT {_COMMAND_COLUMNS} FROM commands "
                           "WHERE state = ? ORDER BY received DESC LIMIT ?", (state.value, limit))
        return [_entry(r) for r in reversed(rows)]


def default_state_path(name: str) -> Path:
    """``$XDG_STATE_HOME/delegation/NAME.sqlite`` (``~/.local/state`` when unset)."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "delegation" / f"{name}.sqlite"


class SqliteStore(_SqlStore):
    """One SQLite file (or ``:memory:``), WAL, ``synchronous=FULL``; locked by one service."""

    def __init__(self, path: str | Path) -> None:
        self.path = str(path)
        self.where = self.path
        self._lock_fd: int | None = None
        if self.path != ":memory:":
            Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        try:
            conn = sqlite3.connect(self.path, check_same_thread=False,
                                   timeout=SQLITE_BUSY_SECONDS)
            conn.execute("PRAGMA journal_mode=WAL")
            conn.execute("PRAGMA synchronous=FULL")
        except sqlite3.Error as exc:
            raise StoreError(f"cannot open state file {self.path}: {exc}") from exc
        super().__init__(conn)
        self._create()

    def acquire(self, name: str) -> bool:
        """An exclusive ``flock`` on ``PATH.lock`` (released by the kernel when the process
        dies); always True for ``:memory:``."""
        if self.path == ":memory:" or self._lock_fd is not None:
            return True
        fd = os.open(f"{self.path}.lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            return False
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()} {name}\n".encode())
        self._lock_fd = fd
        return True

    def holder(self) -> str:
        """What the lock file says (``PID NAME``) of the process holding it."""
        try:
            return Path(f"{self.path}.lock").read_text().strip()
        except OSError:
            return "?"

    def holds(self) -> bool:
        return self.path == ":memory:" or self._lock_fd is not None

    def close(self) -> None:
        with self._lock:
            self._conn.close()
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None


class PostgresStore(_SqlStore):
    """The same tables in PostgreSQL (psycopg 3); the active instance holds an advisory lock.

    One connection carries both the lock and the writes, so a write is only ever made by the
    session that holds the lock: if that session ends (the server restarted, the backend was
    terminated, the network dropped it), the lock is gone with it, and the next use reconnects
    and takes the lock again before anything is written; if another instance has taken it
    meanwhile, `LockLost`. Connections have keep-alives, a TCP user timeout, a connect timeout
    and a statement timeout (`PG_CONNECTION`, `PG_STATEMENT_TIMEOUT_MS`).
    """

    placeholder = "%s"
    shared = True

    def __init__(self, dsn: str) -> None:
        try:
            import psycopg
        except ImportError as exc:
            raise StoreError('a PostgreSQL state needs psycopg: pip install "delegation[postgres]"'
                             ) from exc
        self._psycopg = psycopg
        self.dsn = dsn
        try:
            info = psycopg.conninfo.conninfo_to_dict(dsn)
        except psycopg.Error as exc:
            raise StoreError(f"bad PostgreSQL DSN: {exc}") from exc
        self.where = (f"postgresql://{info.get('host', '')}:{info.get('port', 5432)}/"
                      f"{info.get('dbname', '')}")
        params = {**PG_CONNECTION, **{k: str(v) for k, v in info.items() if v is not None}}
        self._conninfo = psycopg.conninfo.make_conninfo("", **params)
        #: The service name whose lock this store took (`acquire`), to take it again.
        self._lock_name: str | None = None
        self._lost = False
        super().__init__(self._connect())
        self._create()

    def _connect(self) -> Any:
        psycopg = self._psycopg
        try:
            conn = psycopg.connect(self._conninfo)
            conn.execute(f"SET statement_timeout = {PG_STATEMENT_TIMEOUT_MS}")
            conn.commit()
        except psycopg.Error as exc:
            raise StoreError(f"cannot connect to {self.where}: {exc}") from exc
        return conn

    def _try_lock(self, conn: Any, name: str) -> bool:
        row = conn.execute("SELECT pg_try_advisory_lock(%s)", (lock_key(name),)).fetchone()
        conn.commit()  # a session-level lock: it outlives the transaction
        return bool(row and row[0])

    def _connection(self) -> Any:
        """The live connection, reconnected (and the lock taken again) if it was lost."""
        if self._lost:
            raise LockLost(f"the lock on {self.where} is held by another instance")
        if not self._conn.closed and not self._conn.broken:
            return self._conn
        with contextlib.suppress(Exception):
            self._conn.close()
        conn = self._connect()
        if self._lock_name is not None:
            try:
                took = self._try_lock(conn, self._lock_name)
            except self._psycopg.Error as exc:
                conn.close()
                raise StoreError(f"cannot take the lock on {self.where} again: {exc}") from exc
            if not took:
                conn.close()
                self._lost = True
                raise LockLost(f"reconnected to {self.where}, but another instance holds the "
                               f"lock of {self._lock_name!r} now")
            log.warning("state store: reconnected to %s and took the lock again", self.where)
        else:
            log.warning("state store: reconnected to %s", self.where)
        self._conn = conn
        return conn

    def acquire(self, name: str) -> bool:
        """``pg_try_advisory_lock`` on the store's connection, kept open: the server releases
        the lock when that session ends, however the process died."""
        with self._lock:
            conn = self._connection()
            try:
                took = self._try_lock(conn, name)
            except self._psycopg.Error as exc:
                self._failed(conn, exc)
                raise StoreError(f"cannot try the lock on {self.where}: {exc}") from exc
            if took:
                self._lock_name = name
            return took

    def save(self, missions: Sequence[tuple[Mission, Change]],
             commands: Sequence[CommandEntry]) -> None:
        """As `_SqlStore.save`; a connection found dropped when used (idle, cut by a NAT or the
        server) is replaced and the write made once more at once (every write is idempotent: an
        upsert or an update to the whole state)."""
        self._again_if_dropped(lambda: super(PostgresStore, self).save(missions, commands))

    def _fetch(self, sql: str, args: Sequence[Any] = ()) -> list[Any]:
        return self._again_if_dropped(lambda: super(PostgresStore, self)._fetch(sql, args))

    def _again_if_dropped(self, call: Callable[[], T]) -> T:
        """``call()``, and once more if it found the connection dropped (not when it was
        already known dropped: then ``call`` tried to reconnect, and that failed)."""
        known_down = self._conn.broken or self._conn.closed
        try:
            return call()
        except LockLost:
            raise
        except StoreError:
            if known_down or not self._conn.broken:
                raise
            log.warning("state store: the connection to %s was dropped; reconnecting", self.where)
            return call()

    def holds(self) -> bool:
        if self._lock_name is None:
            return False
        with self._lock:
            for last in (False, True):  # a dropped connection: once more on a new one
                try:
                    conn = self._connection()
                    conn.execute("SELECT 1").fetchone()
                    conn.commit()
                    return True
                except LockLost:
                    return False
                except self._psycopg.Error as exc:
                    self._failed(self._conn, exc)
                    if last or not self._conn.broken:
                        raise StoreError(f"cannot reach {self.where}: {exc}") from exc
        return True  # not reached (the second try returns or raises)

    def close(self) -> None:
        with self._lock, contextlib.suppress(Exception):
            self._conn.close()


def open_store(spec: str) -> SqliteStore | PostgresStore:
    """``postgresql://...`` / ``postgres://...``: PostgreSQL; anything else: an SQLite file
    (``:memory:`` for none)."""
    if spec.startswith(("postgresql://", "postgres://")):
        return PostgresStore(spec)
    return SqliteStore(spec)
