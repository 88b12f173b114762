"""Fault tests of the service's state: ``kill -9`` and restart, and two instances of one name.

Real processes and brokers: the fleet and the reference engine run in this process
(`LocalSystem`, ``service=False``); the service is ``python -m delegation serve`` in a subprocess,
killed with SIGKILL. State in an SQLite file, and in PostgreSQL at 127.0.0.1:5432 db ``test`` (a
schema of each test's own, dropped after; skipped when no server answers).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import threading
import time
import uuid
from collections.abc import Callable, Iterator
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

# The store and the serve process are under test, not the broker: one broker (conftest).
pytestmark = [pytest.mark.mqtt, pytest.mark.slow, one_broker()]

FRAME = LocalFrame(57.7605, 16.6815)
PG_BASE = "postgresql://127.0.0.1:5432/test"


def _pg_available() -> bool:
    try:
        import psycopg
    except ImportError:
        return False
    try:
        psycopg.connect(PG_BASE, connect_timeout=3).close()
    except psycopg.Error:
        return False
    return True


@pytest.fixture
def pg_dsn() -> Iterator[str]:
    """A DSN whose tables live in a schema of this test alone (dropped at the end)."""
    if not _pg_available():
        pytest.skip("no PostgreSQL at 127.0.0.1:5432/test (or psycopg not installed)")
    import psycopg

    schema = f"t_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(PG_BASE, autocommit=True) as conn:
        conn.execute(f"CREATE SCHEMA {schema}")
    try:
        yield f"{PG_BASE}?options=-csearch_path%3D{schema}"
    finally:
        with psycopg.connect(PG_BASE, autocommit=True) as conn:
            conn.execute(f"DROP SCHEMA {schema} CASCADE")


@pytest.fixture(params=["sqlite", "postgres"])
def state(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    if request.param == "sqlite":
        return str(tmp_path / "state.sqlite")
    return str(request.getfixturevalue("pg_dsn"))


class Serve:
    """One ``delegation serve`` subprocess; a reader thread collects its output so that tests
    wait on it (a condition with a deadline), and keeps a copy in ``log``."""

    def __init__(self, settings: BrokerSettings, prefix: str, name: str, state: str,
                 log: Path) -> None:
        self.log = log
        self._lines: list[str] = []
        self._ended = False
        self._cond = threading.Condition()
        # forked with the CLI imported (`cli_forks`): still a process of its own
        self.proc = cli_forks.spawn_piped(
            ["-v", "serve", "--broker", settings.host,
             "--port", str(settings.port), "--prefix", prefix, "--name", name,
             "--state", state, "--retention", "1"], dict(os.environ), log.parent)
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
        with self._cond:
            self._ended = True
            self._cond.notify_all()

    def output(self) -> str:
        """What it printed so far (all of it once it has exited)."""
        if self.proc.poll() is not None:
            self._reader.join(10)
        with self._cond:
            return "".join(self._lines)

    def wait_output(self, text: str, timeout: float) -> None:
        with self._cond:
            self._cond.wait_for(lambda: text in "".join(self._lines) or self._ended, timeout)
        if text not in self.output():
            raise AssertionError(f"no {text!r} from serve within {timeout} s:\n"
                                 + self.output()[-3000:])

    def _join(self) -> None:
        self._reader.join(10)
        assert self.proc.stdout is not None
        self.proc.stdout.close()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)
        self._join()

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._join()


@pytest.fixture
def serves(mqtt_settings: BrokerSettings, prefix: str,
           tmp_path: Path) -> Iterator[Callable[[str, str], Serve]]:
    started: list[Serve] = []

    def start(name: str, state: str) -> Serve:
        s = Serve(mqtt_settings, prefix, name, state, tmp_path / f"serve{len(started)}.log")
        started.append(s)
        return s

    yield start
    for s in started:
        s.stop()


def _heartbeat_uuids(watch: Any, base: str) -> list[str]:
    return [d.get("agent-uuid", "") for d in watch.json_on(f"{base}/heartbeat")]


def _wait_new_heartbeat(watch: Any, base: str, known: set[str], timeout: float) -> str:
    found = watch.wait_json(f"{base}/heartbeat", lambda d: d.get("agent-uuid") not in known,
                            timeout=timeout, what="a heartbeat of a new instance")
    return str(found["agent-uuid"])


def _wait_seen_after_start(watch: Any, base: str, topic_filter: str, service_uuid: str) -> None:
    """Wait until a message on ``topic_filter`` arrived after the service's first heartbeat (the
    service, subscribed before it beats, has then seen it too)."""
    from delegation.topics import Wildcard

    wc = Wildcard(topic_filter)

    def seen(_m: Any) -> bool:
        msgs = list(watch.messages)
        first = next(i for i, m in enumerate(msgs) if m.topic == f"{base}/heartbeat"
                     and json.loads(m.payload).get("agent-uuid") == service_uuid)
        return any(wc.matches(m.topic) for m in msgs[first + 1:])

    watch.wait_for(seen, timeout=15, what=f"{topic_filter} after the service started")


def _request(watch: Any, base: str, body: dict[str, Any], timeout: float = 20.0,
             nth: int = 1) -> dict[str, Any]:
    """Publish a command and wait for the ``nth`` answer to its com-uuid."""
    com = body.setdefault("com-uuid", str(uuid.uuid4()))
    watch.publish(f"{base}/delegation/command", json.dumps(body).encode())
    watch.wait_for(lambda m: m.topic == f"{base}/delegation/response"
                   and json.loads(m.payload).get("response-to") == com
                   and sum(1 for d in watch.json_on(f"{base}/delegation/response")
                           if d.get("response-to") == com) >= nth,
                   timeout=timeout, what=f"answer {nth} to {com}")
    return _answers(watch, base, com)[nth - 1]


def _answers(watch: Any, base: str, com: str) -> list[dict[str, Any]]:
    return [d for d in watch.json_on(f"{base}/delegation/response") if d.get("response-to") == com]


def _raw_answers(watch: Any, base: str, com: str) -> list[bytes]:
    return [m.payload for m in list(watch.messages) if m.topic == f"{base}/delegation/response"
            and json.loads(m.payload).get("response-to") == com]


def test_kill_9_and_restart_keeps_missions_and_answers(
    mqtt_settings: BrokerSettings, prefix: str, state: str, collector: Callable[..., Any],
    serves: Callable[[str, str], Serve],
) -> None:
    name = f"svc{uuid.uuid4().hex[:6]}"
    config = ServiceConfig(prefix=prefix, name=name)
    base = config.base_topic
    watch = collector(f"{base}/#", f"{prefix}/unit/+/+/op0/tst/command",
                      f"{prefix}/unit/+/+/op0/tst/feedback",
                      f"{prefix}/unit/+/+/+/exec/command", f"{prefix}/unit/+/+/+/heartbeat",
                      f"{prefix}/unit/+/+/+/sensor/position")
    units = [make_unit("dji0", "air", FRAME.geopoint(0, 0, 30), ["move-to"],
                       speeds={"slow": 4.0, "standard": 8.0, "fast": 14.0})]
    # 200 m at 8 m/s = 25 s of mission time; x10: 2.5 s of wall time. The service is killed as
    # the mission runs and started again only once the tree has ended: the new instance learns
    # it from the engine (issue 22 item 1), it never heard the end.
    with LocalSystem(units, settings=mqtt_settings, config=config, service=False,
                     speedup=10.0, rates={"dji0": 5.0}):
        first = serves(name, state)
        first_uuid = _wait_new_heartbeat(watch, base, set(), timeout=30)
        for topic in ("op0/heartbeat", "dji0/heartbeat", "dji0/sensor/position"):
            _wait_seen_after_start(watch, base, f"{prefix}/unit/+/+/{topic}", first_uuid)
        tree = {"name": "move-to", "params": {"waypoint": FRAME.geopoint(200, 0, 30).to_wire()}}
        command = {"command": "delegate", "start": True, "tst": tree, "sender": "test"}
        started = _request(watch, base, dict(command, **{"com-uuid": "c-1"}), timeout=30)
        assert started["response"] == "started", started
        root = started["plan"]["tst"]["common_params"]["node-uuid"]
        watch.wait_json(f"{base}/delegation/feedback",
                        lambda d: d.get("root-uuid") == root and d.get("status") == "running",
                        timeout=20, what="the mission running")

        first.kill()
        watch.wait_json(f"{prefix}/unit/+/+/op0/tst/feedback",
                        lambda d: d.get("node-uuid") == root and d.get("status") == "succeeded",
                        timeout=30, what="the tree ended while no service was up")
        second = serves(name, state)
        _wait_new_heartbeat(watch, base, {first_uuid}, timeout=30)
        back = time.monotonic()
        # Reported final within 10 s of the new instance's first heartbeat.
        watch.wait_json(f"{base}/delegation/feedback",
                        lambda d: d.get("root-uuid") == root and d.get("status") == "succeeded",
                        timeout=10, what="the end missed while down, reported")
        logging.getLogger(__name__).info("the missed end reported %.2f s after the restart",
                                         time.monotonic() - back)

        known = _request(watch, base, {"command": "query-mission", "root-uuid": root,
                                       "sender": "test"})  # the owner (restored from the store)
        assert known["response"] == "ok", known
        assert known["mission"]["status"] == "succeeded", known
        resent = _request(watch, base, dict(command, **{"com-uuid": "c-1"}), nth=2)
        assert resent == started
        raw = _raw_answers(watch, base, "c-1")
        assert len(raw) == 2 and raw[0] == raw[1]  # the identical bytes

        # Nothing ran twice.
        done = _request(watch, base, {"command": "query-mission", "root-uuid": root,
                                      "sender": "test"})
        assert done["mission"]["status"] == "succeeded"
        assert all(n["status"] == "succeeded" for n in done["mission"]["nodes"]), done
        start_tsts = [d for d in watch.json_on(f"{prefix}/unit/+/+/op0/tst/command")
                      if d.get("command") == "start-tst"]
        assert len(start_tsts) == 1
        start_tasks = [d for d in watch.json_on(f"{prefix}/unit/+/+/+/exec/command")
                       if d.get("command") == "start-task"]
        assert len({d["task-uuid"] for d in start_tasks}) == 1
        # Past the 1 s retention the mission is read back from the store.
        time.sleep(1.5)  # the retention period itself is what is tested
        later = _request(watch, base, {"command": "query-mission", "root-uuid": root,
                                       "sender": "test"})
        assert later["mission"] == done["mission"]
        listed = _request(watch, base, {"command": "list-missions", "limit": 10, "sender": "test"})
        assert listed["total"] == 1 and listed["missions"][0]["root-uuid"] == root
        second.stop()
        assert second.proc.returncode == 0, second.output()[-2000:]


def test_postgres_standby_takes_over_within_10_s(
    mqtt_settings: BrokerSettings, prefix: str, pg_dsn: str, collector: Callable[..., Any],
    serves: Callable[[str, str], Serve],
) -> None:
    name = f"svc{uuid.uuid4().hex[:6]}"
    config = ServiceConfig(prefix=prefix, name=name)
    base = config.base_topic
    watch = collector(f"{base}/#", f"{prefix}/unit/+/+/+/heartbeat",
                      f"{prefix}/unit/+/+/+/sensor/position")
    units = [make_unit("dji0", "air", FRAME.geopoint(0, 0, 30), ["move-to"])]
    with LocalSystem(units, settings=mqtt_settings, config=config, service=False,
                     engine=False, rates={"dji0": 5.0}):
        active = serves(name, pg_dsn)
        active_uuid = _wait_new_heartbeat(watch, base, set(), timeout=30)
        active.wait_output("active", 10)
        for topic in ("dji0/heartbeat", "dji0/sensor/position"):
            _wait_seen_after_start(watch, base, f"{prefix}/unit/+/+/{topic}", active_uuid)
        standby = serves(name, pg_dsn)
        standby.wait_output("standby", 20)
        tree = {"name": "move-to", "params": {"waypoint": FRAME.geopoint(100, 0, 30).to_wire()}}
        planned = _request(watch, base, {"command": "delegate", "tst": tree}, timeout=30)
        assert planned["response"] == "ok", planned
        root = planned["plan"]["tst"]["common_params"]["node-uuid"]
        pong = _request(watch, base, {"command": "ping", "com-uuid": "p-1"})
        assert pong["response"] == "pong"
        assert set(_heartbeat_uuids(watch, base)) == {active_uuid}  # the standby is silent

        killed = time.monotonic()
        active.kill()
        new_uuid = _wait_new_heartbeat(watch, base, {active_uuid}, timeout=10)
        took = time.monotonic() - killed
        logging.getLogger(__name__).info("standby's first heartbeat %.2f s after kill -9", took)
        assert took < 10.0, took
        standby.wait_output("taking over", 5)
        known = _request(watch, base, {"command": "query-mission", "root-uuid": root,
                                       "sender": "test"})  # the owner (restored from the store)
        assert known["response"] == "ok" and known["mission"]["status"] == "planned"
        again = _request(watch, base, {"command": "ping", "com-uuid": "p-1"}, nth=2)
        assert again == pong and len(_answers(watch, base, "p-1")) == 2
        assert new_uuid != active_uuid


def test_sqlite_second_instance_refuses_to_start(
    mqtt_settings: BrokerSettings, prefix: str, tmp_path: Path, collector: Callable[..., Any],
    serves: Callable[[str, str], Serve],
) -> None:
    name = f"svc{uuid.uuid4().hex[:6]}"
    base = ServiceConfig(prefix=prefix, name=name).base_topic
    watch = collector(f"{base}/heartbeat")
    path = str(tmp_path / "one.sqlite")
    first = serves(name, path)
    _wait_new_heartbeat(watch, base, set(), timeout=30)
    # The same file: its lock says who has it.
    same_file = serves(name, path)
    assert same_file.proc.wait(30) == 1
    assert "another delegation service uses the state" in same_file.output()
    assert f"lock held by {first.proc.pid} {name}" in same_file.output()
    # Another file, same name on the same broker: its heartbeat gives it away.
    other_file = serves(name, str(tmp_path / "two.sqlite"))
    assert other_file.proc.wait(30) == 1
    assert f"another delegation service named {name!r} is live" in other_file.output()
    assert first.proc.poll() is None


def test_after_kill_9_a_reused_com_uuid_is_refused_on_the_callers_topic(
    mqtt_settings: BrokerSettings, prefix: str, state: str, collector: Callable[..., Any],
    serves: Callable[[str, str], Serve],
) -> None:
    """Issue 23 item 5: the store keeps each command's digest, caller and reply topic, so after a
    restart a different command reusing a com-uuid is refused (not given the other's answer), and
    the answers still go to the caller's own response topic."""
    name = f"svc{uuid.uuid4().hex[:6]}"
    base = ServiceConfig(prefix=prefix, name=name).base_topic
    mine, shared = f"{base}/delegation/response/alice", f"{base}/delegation/response"
    watch = collector(f"{base}/#")

    def ask(body: dict[str, Any], nth: int) -> dict[str, Any]:
        watch.publish(f"{base}/delegation/command/alice", json.dumps(body).encode())
        watch.wait_for(lambda _m: len(watch.json_on(mine)) >= nth, timeout=20,
                       what=f"answer {nth} on alice's topic")
        return watch.json_on(mine)[nth - 1]

    first = serves(name, state)
    first_uuid = _wait_new_heartbeat(watch, base, set(), timeout=30)
    listed = ask({"com-uuid": "c-1", "command": "list-missions"}, 1)
    assert listed["response"] == "ok" and listed["response-to"] == "c-1"
    first.kill()
    serves(name, state)
    _wait_new_heartbeat(watch, base, {first_uuid}, timeout=30)

    other = ask({"com-uuid": "c-1", "command": "list-agents"}, 2)
    assert other["response"] == "failed", other
    assert "reused for a different command" in other["fail-reason"]
    again = ask({"com-uuid": "c-1", "command": "list-missions"}, 3)
    assert again == listed  # the re-send: the stored answer, on alice's topic
    assert not [d for d in watch.json_on(shared) if d.get("response-to") == "c-1"]
