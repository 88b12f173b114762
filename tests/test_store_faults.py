"""The store failing under a real ``delegation serve`` (issue 22 item 4): the PostgreSQL backend
terminated mid-mission, the SQLite disk full. The service keeps its heartbeat, holds what it could
not store, retries, and recovers; past ``--store-bound`` it exits 1; a standby that took the lock
meanwhile stays the only active one.

Real processes and brokers: the fleet and the reference engine run in this process
(`LocalSystem`, ``service=False``); the service is ``python -m delegation serve`` in a subprocess.
PostgreSQL at 127.0.0.1:5432 db ``test`` (trust auth): each test has its own schema and its own
login role (so that the test can refuse it new sessions, ``ALTER ROLE ... NOLOGIN``, as an
unreachable server would); the disk is a tmpfs of a few MB mounted for the test (root only).
"""

from __future__ import annotations

import errno
import itertools
import json
import os
import signal
import subprocess
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

import cli_forks
from conftest import one_broker
from delegation.fleet import make_unit
from delegation.geo import LocalFrame
from delegation.local import LocalSystem
from delegation.runtime.settings import BrokerSettings
from delegation.service import ServiceConfig
from delegation.service.store import PostgresStore, SqliteStore

# The store and the serve process are under test, not the broker: one broker (conftest).
pytestmark = [pytest.mark.mqtt, pytest.mark.slow, one_broker()]

FRAME = LocalFrame(57.7605, 16.6815)
PG_BASE = "postgresql://127.0.0.1:5432/test"


class Serve:
    """One ``delegation serve`` subprocess; its output is collected by a thread (tests wait on
    it with a deadline) and copied to ``log``."""

    def __init__(self, settings: BrokerSettings, prefix: str, name: str, state: str, log: Path,
                 extra: Sequence[str] = ()) -> None:
        self.log = log
        self._lines: list[str] = []
        self._cond = threading.Condition()
        # forked with the CLI imported (`cli_forks`): still a process of its own
        self.proc = cli_forks.spawn_piped(
            ["-v", "serve", "--broker", settings.host,
             "--port", str(settings.port), "--prefix", prefix, "--name", name,
             "--state", state, *extra], dict(os.environ), log.parent)
        self._reader = threading.Thread(target=self._read, name=f"serve-{name}", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        with self.log.open("w") as copy:
            for line in self.proc.stdout:
                copy.write(line)
                with self._cond:
                    self._lines.append(line)
                    self._cond.notify_all()

    def output(self) -> str:
        with self._cond:
            return "".join(self._lines)

    def wait_output(self, text: str, timeout: float) -> None:
        with self._cond:
            found = self._cond.wait_for(lambda: text in "".join(self._lines), timeout)
        if not found:
            raise AssertionError(f"no {text!r} from serve within {timeout} s:\n"
                                 + self.output()[-3000:])

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._reader.join(10)
        assert self.proc.stdout is not None
        self.proc.stdout.close()


@pytest.fixture
def serves(mqtt_settings: BrokerSettings, prefix: str,
           tmp_path: Path) -> Iterator[Callable[..., Serve]]:
    started: list[Serve] = []

    def start(name: str, state: str, *extra: str) -> Serve:
        s = Serve(mqtt_settings, prefix, name, state, tmp_path / f"serve{len(started)}.log",
                  extra)
        started.append(s)
        return s

    yield start
    for s in started:
        s.stop()


class Role:
    """A PostgreSQL login role of one test, with a schema it owns the tables of."""

    def __init__(self, schema: str, tag: str) -> None:
        self.name = f"{schema}_{tag}"
        self.dsn = (f"postgresql://{self.name}@127.0.0.1:5432/test"
                    f"?options=-csearch_path%3D{schema}")

    def _admin(self, *sql: str) -> None:
        import psycopg

        with psycopg.connect(PG_BASE, autocommit=True) as conn:
            for statement in sql:
                conn.execute(statement)

    def cut(self) -> None:
        """End its sessions and refuse new ones (the database is gone, as it sees it)."""
        self._admin(f"ALTER ROLE {self.name} NOLOGIN",
                    "SELECT pg_terminate_backend(pid, 5000) FROM pg_stat_activity "
                    f"WHERE usename = '{self.name}'")

    def restore(self) -> None:
        self._admin(f"ALTER ROLE {self.name} LOGIN")


@pytest.fixture
def pg_roles() -> Iterator[Callable[[str], Role]]:
    psycopg = pytest.importorskip("psycopg")
    try:
        psycopg.connect(PG_BASE, connect_timeout=3).close()
    except psycopg.Error:
        pytest.skip("no PostgreSQL at 127.0.0.1:5432/test")
    schema = f"t_{uuid.uuid4().hex[:12]}"
    made: list[Role] = []
    with psycopg.connect(PG_BASE, autocommit=True) as conn:
        conn.execute(f"CREATE SCHEMA {schema}")

    def role(tag: str) -> Role:
        r = Role(schema, tag)
        with psycopg.connect(PG_BASE, autocommit=True) as conn:
            conn.execute(f"CREATE ROLE {r.name} LOGIN")
            conn.execute(f"GRANT USAGE, CREATE ON SCHEMA {schema} TO {r.name}")
            if made:  # the tables belong to the first role: the others may use them
                conn.execute(f"GRANT {made[0].name} TO {r.name}")
        made.append(r)
        return r

    yield role
    with psycopg.connect(PG_BASE, autocommit=True) as conn:
        conn.execute(f"DROP SCHEMA {schema} CASCADE")
        for r in made:
            conn.execute("SELECT pg_terminate_backend(pid, 5000) FROM pg_stat_activity "
                         f"WHERE usename = '{r.name}'")
            conn.execute(f"DROP ROLE {r.name}")


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A 16 MB tmpfs (root only; skipped elsewhere), unmounted after."""
    mount = tmp_path / "disk"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16m", "tmpfs", str(mount)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(disk: Path) -> Path:
    """Fill ``disk`` to the last byte; the filler file (delete it to free the space)."""
    filler = disk / "filler"
    chunk = b"\0" * (1 << 16)
    with filler.open("wb", buffering=0) as f:
        for size in (1 << 16, 4096, 512, 1):
            try:
                while True:
                    f.write(chunk[:size])
            except OSError as exc:
                assert exc.errno == errno.ENOSPC, exc
    return filler


# ---------------------------------------------------------------- helpers on the broker


def _wait_heartbeat(watch: Any, base: str, known: set[str], timeout: float) -> str:
    found = watch.wait_json(f"{base}/heartbeat", lambda d: d.get("agent-uuid") not in known,
                            timeout=timeout, what="a heartbeat of a new instance")
    return str(found["agent-uuid"])


def _send(watch: Any, base: str, body: dict[str, Any]) -> str:
    com = body.setdefault("com-uuid", str(uuid.uuid4()))
    body.setdefault("sender", "test")
    watch.publish(f"{base}/delegation/command", json.dumps(body).encode())
    return str(com)


def _answer(watch: Any, base: str, com: str, timeout: float) -> dict[str, Any]:
    return dict(watch.wait_json(f"{base}/delegation/response",
                                lambda d: d.get("response-to") == com, timeout=timeout,
                                what=f"the answer to {com}"))


def _answered(watch: Any, base: str, com: str) -> bool:
    return any(d.get("response-to") == com
               for d in watch.json_on(f"{base}/delegation/response"))


def _beats(watch: Any, base: str, agent_uuid: str) -> list[float]:
    """The stamps (epoch s, when it was sent) of one instance's heartbeats."""
    return [float(d["stamp"]) for d in watch.json_on(f"{base}/heartbeat")
            if d.get("agent-uuid") == agent_uuid]


def _largest_gap(stamps: list[float], since: float, until: float) -> float:
    """The longest time without a heartbeat between ``since`` and ``until`` (epoch s)."""
    inside = [since] + [s for s in stamps if since < s < until] + [until]
    return max(b - a for a, b in itertools.pairwise(inside))


def _start_mission(watch: Any, base: str, prefix: str, metres: float) -> str:
    tree = {"name": "move-to", "params": {"waypoint": FRAME.geopoint(metres, 0, 30).to_wire()}}
    com = _send(watch, base, {"command": "delegate", "start": True, "tst": tree})
    started = _answer(watch, base, com, timeout=30)
    assert started["response"] == "started", started
    root = str(started["plan"]["tst"]["common_params"]["node-uuid"])
    watch.wait_json(f"{base}/delegation/feedback",
                    lambda d: d.get("root-uuid") == root and d.get("status") == "running",
                    timeout=20, what="the mission running")
    return root


def _wait_ready(watch: Any, base: str, prefix: str, service_uuid: str) -> None:
    """The service has heard the engine and the unit (a message of each after its first beat)."""
    for topic in ("op0/heartbeat", "dji0/heartbeat", "dji0/sensor/position"):
        def seen(_m: Any, topic: str = topic) -> bool:
            msgs = list(watch.messages)
            first = next((i for i, m in enumerate(msgs) if m.topic == f"{base}/heartbeat"
                          and json.loads(m.payload).get("agent-uuid") == service_uuid), None)
            return first is not None and any(m.topic.endswith(f"/{topic}")
                                              for m in msgs[first + 1:])
        watch.wait_for(seen, timeout=15, what=f"{topic} after the service started")


def _fleet(mqtt_settings: BrokerSettings, config: ServiceConfig) -> LocalSystem:
    units = [make_unit("dji0", "air", FRAME.geopoint(0, 0, 30), ["move-to"],
                       speeds={"slow": 4.0, "standard": 8.0, "fast": 14.0})]
    return LocalSystem(units, settings=mqtt_settings, config=config, service=False,
                       speedup=10.0, rates={"dji0": 5.0})


def _watch(collector: Callable[..., Any], base: str, prefix: str) -> Any:
    return collector(f"{base}/#", f"{prefix}/unit/+/+/+/heartbeat",
                     f"{prefix}/unit/+/+/+/sensor/position")


# ---------------------------------------------------------------- the tests


def test_postgres_backend_terminated_mid_mission_the_service_beats_holds_and_recovers(
    mqtt_settings: BrokerSettings, prefix: str, pg_roles: Callable[[str], Role],
    collector: Callable[..., Any], serves: Callable[..., Serve],
) -> None:
    name = f"svc{uuid.uuid4().hex[:6]}"
    config = ServiceConfig(prefix=prefix, name=name)
    base = config.base_topic
    role = pg_roles("a")
    watch = _watch(collector, base, prefix)
    with _fleet(mqtt_settings, config):
        service = serves(name, role.dsn, "--store-bound", "60")
        agent = _wait_heartbeat(watch, base, set(), timeout=30)
        _wait_ready(watch, base, prefix, agent)
        # 700 m at 8 m/s x10: ~9 s of wall time; the outage (4 beats at 1 Hz, then the held answer)
        # takes about 5 s of it.
        root = _start_mission(watch, base, prefix, 700.0)

        cut = time.time()
        role.cut()  # the backend terminated, and no new session for now
        ping = _send(watch, base, {"command": "ping"})
        service.wait_output("a read from", 10)  # its com-uuid looked up: tried, kept for later
        watch.wait_for(lambda _m: len([s for s in _beats(watch, base, agent) if s > cut]) >= 4,
                       timeout=10, what="heartbeats while the database is away")
        assert not _answered(watch, base, ping)
        role.restore()
        restored = time.time()
        assert _answer(watch, base, ping, timeout=15)["response"] == "pong"
        service.wait_output("works again", 5)
        assert _largest_gap(_beats(watch, base, agent), cut, restored) < 2.5

        watch.wait_json(f"{base}/delegation/feedback",
                        lambda d: d.get("root-uuid") == root and d.get("status") == "succeeded",
                        timeout=40, what="the mission succeeded")
        done = _answer(watch, base, _send(watch, base, {"command": "query-mission",
                                                        "root-uuid": root}), timeout=15)
        assert done["mission"]["status"] == "succeeded", done
        service.stop()
        assert service.proc.returncode == 0, service.output()[-3000:]
    # What it held was stored: the store says so.
    store = PostgresStore(role.dsn)
    try:
        mission = store.load_mission(root)
        assert mission is not None and mission.status.value == "succeeded"
        assert store.load_command(("delegation", ping)) is not None
    finally:
        store.close()


def test_postgres_lock_taken_by_a_standby_the_old_instance_leaves_and_exits_1(
    mqtt_settings: BrokerSettings, prefix: str, pg_roles: Callable[[str], Role],
    collector: Callable[..., Any], serves: Callable[..., Serve],
) -> None:
    name = f"svc{uuid.uuid4().hex[:6]}"
    config = ServiceConfig(prefix=prefix, name=name)
    base = config.base_topic
    first_role, second_role = pg_roles("a"), pg_roles("b")
    watch = _watch(collector, base, prefix)
    with _fleet(mqtt_settings, config):
        active = serves(name, first_role.dsn, "--store-bound", "60")
        first = _wait_heartbeat(watch, base, set(), timeout=30)
        active.wait_output("active", 10)
        _wait_ready(watch, base, prefix, first)
        standby = serves(name, second_role.dsn)
        standby.wait_output("standby", 20)
        root = _start_mission(watch, base, prefix, 1200.0)

        first_role.cut()  # its session ends: the lock is free, and the standby takes it
        second = _wait_heartbeat(watch, base, {first}, timeout=15)
        standby.wait_output("taking over", 5)
        assert active.proc.poll() is None  # still waiting for its database
        first_role.restore()  # back: the lock is the standby's now
        assert active.proc.wait(20) == 1, active.output()[-3000:]
        out = active.output()
        assert "lost the lock" in out and "gave up" in out, out[-3000:]
        assert out.index("leaving the broker") < out.index(f"{name} stopped")
        gone = time.time()
        # The old instance is silent; the new one follows the mission to its end.
        watch.wait_json(f"{base}/delegation/feedback",
                        lambda d: d.get("root-uuid") == root and d.get("status") == "succeeded",
                        timeout=40, what="the mission succeeded under the new instance")
        assert [s for s in _beats(watch, base, first) if s > gone] == []
        assert second != first


def test_sqlite_disk_full_mid_mission_the_service_beats_holds_and_recovers(
    mqtt_settings: BrokerSettings, prefix: str, small_disk: Path,
    collector: Callable[..., Any], serves: Callable[..., Serve],
) -> None:
    name = f"svc{uuid.uuid4().hex[:6]}"
    config = ServiceConfig(prefix=prefix, name=name)
    base = config.base_topic
    state = small_disk / "state.sqlite"
    watch = _watch(collector, base, prefix)
    with _fleet(mqtt_settings, config):
        service = serves(name, str(state), "--store-bound", "60")
        agent = _wait_heartbeat(watch, base, set(), timeout=30)
        _wait_ready(watch, base, prefix, agent)
        root = _start_mission(watch, base, prefix, 700.0)  # as above: ~9 s of flight

        full = time.time()
        filler = fill(small_disk)
        ping = _send(watch, base, {"command": "ping"})
        service.wait_output("a write to", 10)
        watch.wait_for(lambda _m: len([s for s in _beats(watch, base, agent) if s > full]) >= 4,
                       timeout=10, what="heartbeats while the disk is full")
        assert not _answered(watch, base, ping)
        filler.unlink()
        freed = time.time()
        assert _answer(watch, base, ping, timeout=15)["response"] == "pong"
        service.wait_output("works again", 5)
        assert _largest_gap(_beats(watch, base, agent), full, freed) < 2.5
        watch.wait_json(f"{base}/delegation/feedback",
                        lambda d: d.get("root-uuid") == root and d.get("status") == "succeeded",
                        timeout=40, what="the mission succeeded")
        service.stop()
        assert service.proc.returncode == 0, service.output()[-3000:]
    store = SqliteStore(state)
    try:
        mission = store.load_mission(root)
        assert mission is not None and mission.status.value == "succeeded"
        assert store.load_command(("delegation", ping)) is not None
    finally:
        store.close()


def test_sqlite_disk_full_past_the_bound_the_service_exits_1(
    mqtt_settings: BrokerSettings, prefix: str, small_disk: Path,
    collector: Callable[..., Any], serves: Callable[..., Serve],
) -> None:
    name = f"svc{uuid.uuid4().hex[:6]}"
    config = ServiceConfig(prefix=prefix, name=name)
    base = config.base_topic
    state = small_disk / "state.sqlite"
    watch = collector(f"{base}/#")
    service = serves(name, str(state), "--store-bound", "3")
    agent = _wait_heartbeat(watch, base, set(), timeout=30)
    fill(small_disk)
    full = time.monotonic()
    ping = _send(watch, base, {"command": "ping"})
    assert service.proc.wait(30) == 1, service.output()[-3000:]
    took = time.monotonic() - full
    out = service.output()
    assert "gave up" in out and "(bound 3 s)" in out, out[-3000:]
    assert 3.0 <= took < 15.0, took
    gone = time.time()
    assert not _answered(watch, base, ping)  # never published unstored
    # The lock is free: another instance may start on this state at once.
    store = SqliteStore(state)
    try:
        assert store.acquire(name)
    finally:
        store.close()
    assert all(s <= gone for s in _beats(watch, base, agent))
    assert os.path.exists(state)
