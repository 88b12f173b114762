"""Fault tests on a real broker with real processes (docs/protocol.md §11, issue 10 item 6).

Each test runs a private mosquitto, one ``delegation sim`` process per unit (so one unit can be
killed), the reference engine and the service, then breaks something: a unit killed -9, a unit
rebooted, the engine killed -9 (not back: its missions fail; restarted: they go on, nothing started
twice), the broker down for longer than anyone's heartbeat timeout, two missions at once. Each
asserts the mission's final status and that nothing ran twice: every task finished exactly once,
counted from the units' own ``exec/feedback``. Every wait has a deadline.

Time is scaled down, not skipped: the simulated units fly 20 times faster than real time, and the
service judges a unit lost after 3 heartbeat periods but at least `MIN_TIMEOUT` (2.5 s, not the
default 5 s): the units beat at 2 Hz, the engine at 1 Hz, so every loss rule still applies.
The processes are forked from one that imported the CLI once (`cli_forks.spawn`): each is still
a process of its own, killed and restarted as one.
"""

from __future__ import annotations

import json
import os
import signal
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import cli_forks
from conftest import Collector
from delegation.engine import TstEngine
from delegation.runtime.broker import PrivateMosquitto, free_port, mosquitto_binary
from delegation.runtime.mqtt import MqttError
from delegation.runtime.settings import BrokerSettings
from delegation.service import DelegationService, ServiceConfig

pytestmark = [
    pytest.mark.mqtt,
    pytest.mark.slow,
    pytest.mark.skipif(mosquitto_binary() is None, reason="no mosquitto binary"),
]

SRC = str(Path(__file__).resolve().parents[1] / "src")
#: Simulated seconds per wall second: a 300 m move-to at 4 m/s takes 75 s, 3.75 s wall.
SPEEDUP = 20.0
#: The service's shortest heartbeat timeout (its default is 5 s): 3 periods of the units' 2 Hz
#: would be 1.5 s, so this is what applies to them; the engine (1 Hz) is lost after 3 s.
MIN_TIMEOUT = 2.5
#: The broker outage: longer than every heartbeat timeout above, so that the service must hold
#: its judgement while it is off the broker (and give everyone a grace after); shorter than the
#: third reconnect attempt of the clients' 1, 2, 4 s back-off (7 s after the outage began).
OUTAGE = 6.0
#: How long the service waits for a lost engine to come back (its default is 30 s).
ENGINE_RETURN = 4.0
#: The heartbeat timeout of the reboot test: longer than its wait for the re-delegation, so that
#: only the new agent-uuid can cause it. With `MIN_TIMEOUT`, a loaded machine that took more than
#: 2.5 s to start the new process (Python, the imports, the connection) saw "/u1 lost" instead.
REBOOT_LOSS = 60.0
HOME = {"u0": (57.7600, 16.6800), "u1": (57.7600, 16.6840), "u2": (57.7624, 16.6842)}
GOAL = {"u0": (57.7627, 16.6800), "u1": (57.7627, 16.6840), "near-u0": (57.7627, 16.6808)}


# --------------------------------------------------------------------------- the parts


@pytest.fixture
def mosquitto() -> Iterator[PrivateMosquitto]:
    broker = PrivateMosquitto().start(port=free_port(stable=True))
    try:
        yield broker
    finally:
        broker.stop()


@pytest.fixture
def prefix() -> str:
    return f"fault-{uuid.uuid4().hex[:10]}"


class Processes:
    """``delegation`` subprocesses, killed at the end of the test whatever happened."""

    def __init__(self, settings: BrokerSettings, prefix: str, workdir: Path) -> None:
        self.settings, self.prefix, self.workdir = settings, prefix, workdir
        self.procs: dict[str, cli_forks.Forked] = {}

    def _run(self, key: str, *args: str) -> cli_forks.Forked:
        """``delegation ARGS`` as its own process, forked with the CLI imported (`cli_forks`)."""
        env = {**os.environ, "PYTHONPATH": SRC}
        for k in [k for k in env if k.startswith("WARAPS_")]:
            del env[k]
        proc = cli_forks.spawn(
            [*args, "--broker", self.settings.host, "--port", str(self.settings.port),
             "--prefix", self.prefix], env, self.workdir / f"{key}.log")
        self.procs[key] = proc
        return proc

    def sim(self, name: str, speedup: float = SPEEDUP) -> cli_forks.Forked:
        lat, lon = HOME[name]
        scenario = {
            "name": name, "description": "one unit of a fault test",
            "agents": [{"name": name, "type": "air", "rate": 2.0,
                        "position": {"latitude": lat, "longitude": lon, "altitude": 20.0},
                        "speeds": {"slow": 2.0, "standard": 4.0, "fast": 8.0},
                        "tasks": ["move-to"]}],
            "mission": move_to(GOAL["u0"], "*"),
        }
        path = self.workdir / f"{name}.json"
        path.write_text(json.dumps(scenario))
        return self._run(name, "sim", str(path), "--speedup", str(speedup))

    def engine(self) -> cli_forks.Forked:
        return self._run("op0", "engine")

    def kill(self, key: str) -> None:
        proc = self.procs[key]
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)

    def stop(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)


@pytest.fixture
def procs(mosquitto: PrivateMosquitto, prefix: str, tmp_path: Path) -> Iterator[Processes]:
    p = Processes(mosquitto.settings(), prefix, tmp_path)
    try:
        yield p
    finally:
        p.stop()


def move_to(goal: tuple[float, float], unit: str) -> dict[str, Any]:
    return {"name": "move-to", "common_params": {"execunit": unit},
            "params": {"speed": "standard",
                       "waypoint": {"latitude": goal[0], "longitude": goal[1], "altitude": 20.0}}}


def conc(*children: dict[str, Any]) -> dict[str, Any]:
    return {"name": "conc", "common_params": {}, "children": list(children)}


def start_service(settings: BrokerSettings, prefix: str, **config: Any) -> DelegationService:
    """The service (started by ``with``), quick to judge a unit lost (`MIN_TIMEOUT`, unless
    ``min_heartbeat_timeout`` says otherwise)."""
    config.setdefault("min_heartbeat_timeout", MIN_TIMEOUT)
    return DelegationService(settings, ServiceConfig(prefix=prefix, **config))


def watch(settings: BrokerSettings, prefix: str) -> Collector:
    return Collector(settings, [f"{prefix}/unit/+/+/+/exec/#",
                                f"{prefix}/unit/+/+/delegator0/delegation/#"]).start()


def delegate(col: Collector, service: DelegationService, tree: dict[str, Any]) -> str:
    """Send ``delegate start``; the root uuid of the started mission."""
    com = str(uuid.uuid4())
    col.publish(f"{service.config.base_topic}/delegation/command",
                {"com-uuid": com, "command": "delegate", "tst": tree, "start": True})
    answer = col.wait_json("+/unit/+/+/+/delegation/response",
                           lambda d: d.get("response-to") == com, timeout=30.0)
    assert answer["response"] == "started", answer
    return str(answer["plan"]["tst"]["common_params"]["node-uuid"])


def final_status(col: Collector, root: str, timeout: float) -> dict[str, Any]:
    return col.wait_json("+/unit/+/+/+/delegation/feedback",
                         lambda d: d.get("root-uuid") == root and d.get("status") in (
                             "succeeded", "failed", "aborted"), timeout=timeout,
                         what=f"the end of mission {root}")


def wait_running(col: Collector, units: set[str], timeout: float = 30.0) -> None:
    col.wait_for(lambda m: units <= running_units(col), timeout, f"tasks running on {units}")


def running_units(col: Collector) -> set[str]:
    return {m.topic.split("/")[-3] for m in list(col.messages)
            if m.topic.endswith("exec/feedback") and b'"running"' in m.payload}


def finished_per_goal(col: Collector) -> dict[tuple[float, float], list[str]]:
    """Waypoint -> the units that reported a task to it ``finished`` (once each task)."""
    goal_of: dict[str, tuple[float, float]] = {}
    for d in col.json_on("+/unit/+/+/+/exec/command"):
        if d.get("command") == "start-task":
            wp = d["task"]["params"]["waypoint"]
            goal_of[d["task-uuid"]] = (round(wp["latitude"], 6), round(wp["longitude"], 6))
    done: dict[tuple[float, float], list[str]] = {}
    seen: set[str] = set()
    for m in list(col.messages):
        if not m.topic.endswith("exec/feedback"):
            continue
        d = json.loads(m.payload)
        uid = d.get("task-uuid")
        if d.get("status") == "finished" and uid in goal_of and uid not in seen:
            seen.add(uid)
            done.setdefault(goal_of[uid], []).append(m.topic.split("/")[-3])
    return done


def ready(service: Any, units: list[str]) -> None:
    assert service.wait_ready(units, timeout=30.0), "units and engine not seen within 30 s"


# --------------------------------------------------------------------------- the faults


def test_a_unit_killed_mid_task_is_re_delegated_and_nothing_runs_twice(
        mosquitto: PrivateMosquitto, procs: Processes, prefix: str) -> None:
    settings = mosquitto.settings()
    for name in HOME:
        procs.sim(name)
    with TstEngine(settings, prefix=prefix), start_service(settings, prefix) as service:
        ready(service, list(HOME))
        col = watch(settings, prefix)
        try:
            root = delegate(col, service, conc(move_to(GOAL["u0"], "/u0"),
                                               move_to(GOAL["u1"], "/u1")))
            wait_running(col, {"u0", "u1"})
            procs.kill("u1")
            killed = time.monotonic()
            moved = col.wait_json("+/unit/+/+/+/delegation/feedback",
                                  lambda d: d.get("status") == "re-delegated", timeout=20.0)
            # 3 heartbeat periods (at least MIN_TIMEOUT) + a tick + planning.
            assert time.monotonic() - killed < MIN_TIMEOUT + 5.0
            assert "/u1 lost" in moved["fail-reason"]
            assert [t["unit"] for t in moved["tasks"]] == ["/u2"]
            end = final_status(col, root, timeout=90.0)
            assert end["status"] == "succeeded", end
            done = finished_per_goal(col)
            assert done == {GOAL["u0"]: ["u0"], GOAL["u1"]: ["u2"]}, done
        finally:
            col.stop()


def test_a_rebooted_unit_is_re_delegated_at_once(
        mosquitto: PrivateMosquitto, procs: Processes, prefix: str) -> None:
    settings = mosquitto.settings()
    for name in HOME:
        procs.sim(name)
    with TstEngine(settings, prefix=prefix), \
            start_service(settings, prefix, min_heartbeat_timeout=REBOOT_LOSS) as service:
        ready(service, list(HOME))
        col = watch(settings, prefix)
        try:
            root = delegate(col, service, conc(move_to(GOAL["u1"], "/u1")))
            wait_running(col, {"u1"})
            procs.kill("u1")
            procs.sim("u1")  # the same unit, a new process: a new agent-uuid, no tasks
            # Within REBOOT_LOSS / 2: the re-delegation cannot come from a loss.
            moved = col.wait_json("+/unit/+/+/+/delegation/feedback",
                                  lambda d: d.get("status") == "re-delegated",
                                  timeout=REBOOT_LOSS / 2)
            assert "/u1 rebooted" in moved["fail-reason"], moved
            assert [t["unit"] for t in moved["tasks"]] in (["/u0"], ["/u2"])
            end = final_status(col, root, timeout=90.0)
            assert end["status"] == "succeeded", end
            done = finished_per_goal(col)
            assert list(done) == [GOAL["u1"]] and len(done[GOAL["u1"]]) == 1, done
        finally:
            col.stop()


def test_an_engine_killed_and_not_back_fails_its_missions_with_the_reason_within_a_bound(
        mosquitto: PrivateMosquitto, procs: Processes, prefix: str) -> None:
    settings = mosquitto.settings()
    procs.sim("u0", speedup=SPEEDUP / 4)  # still flying when the engine is given up
    procs.engine()
    with start_service(settings, prefix, engine_return_timeout=ENGINE_RETURN) as service:
        ready(service, ["u0"])
        col = watch(settings, prefix)
        try:
            root = delegate(col, service, conc(move_to(GOAL["u0"], "/u0")))
            wait_running(col, {"u0"})
            procs.kill("op0")
            killed = time.monotonic()
            end = final_status(col, root, timeout=30.0)
            # 3 s without a heartbeat + the wait for its return + a tick.
            assert time.monotonic() - killed < 3.0 + ENGINE_RETURN + 5.0
            assert end["status"] == "failed" and "engine op0 lost" in end["fail-reason"], end
            assert f"not back within {ENGINE_RETURN:g} s" in end["fail-reason"], end
            starts = [d for d in col.json_on("+/unit/+/+/+/exec/command")
                      if d.get("command") == "start-task"]
            assert len({d["task-uuid"] for d in starts}) == 1  # started once, never again
        finally:
            col.stop()


def test_an_engine_killed_mid_task_and_restarted_finishes_the_mission_starting_nothing_twice(
        mosquitto: PrivateMosquitto, procs: Processes, prefix: str) -> None:
    """Issue 22 item 2: the restarted engine is given the unfinished part of the tree again;
    the tasks the units are flying are adopted (their start-task re-sent with the same com-uuid
    is answered again, not run again), what finished is not redone, the rest runs."""
    settings = mosquitto.settings()
    for name in ("u0", "u1"):
        procs.sim(name, speedup=SPEEDUP / 2)  # 7.5 s of wall time per flight
    procs.engine()
    with start_service(settings, prefix) as service:
        ready(service, ["u0", "u1"])
        col = watch(settings, prefix)
        try:
            tree = {"name": "seq", "common_params": {}, "children": [
                conc(move_to(GOAL["u0"], "/u0"), move_to(GOAL["u1"], "/u1")),
                move_to(GOAL["near-u0"], "/u0")]}
            root = delegate(col, service, tree)
            wait_running(col, {"u0", "u1"})
            procs.kill("op0")
            procs.engine()
            end = final_status(col, root, timeout=60.0)
            assert end["status"] == "succeeded", end
            done = finished_per_goal(col)
            assert done == {GOAL["u0"]: ["u0"], GOAL["u1"]: ["u1"], GOAL["near-u0"]: ["u0"]}, done
            assert_each_task_started_once(col)
            # The tasks flying at the kill were adopted: the restarted engine re-sent their
            # start-task (same com-uuid), the units answered it again.
            resent = [d["task"]["params"]["waypoint"]["longitude"]
                      for d in col.json_on("+/unit/+/+/+/exec/command")
                      if d.get("command") == "start-task"]
            assert resent.count(GOAL["u0"][1]) >= 2, resent
            assert resent.count(GOAL["u1"][1]) >= 2, resent
            assert not [f for f in col.json_on("+/unit/+/+/+/delegation/feedback")
                        if f.get("status") in ("failed", "re-delegated")]
        finally:
            col.stop()


def assert_each_task_started_once(col: Collector) -> None:
    """Each task (by waypoint) got one start-task com-uuid and one task-uuid (re-sends of the
    same com-uuid do not count), and each unit ran it once (one ``running`` feedback each)."""
    coms: dict[tuple[float, float], set[tuple[str, str]]] = {}
    for d in col.json_on("+/unit/+/+/+/exec/command"):
        if d.get("command") == "start-task":
            wp = d["task"]["params"]["waypoint"]
            goal = (round(wp["latitude"], 6), round(wp["longitude"], 6))
            coms.setdefault(goal, set()).add((d["com-uuid"], d["task-uuid"]))
    assert all(len(ids) == 1 for ids in coms.values()), coms
    running = [d["task-uuid"] for d in col.json_on("+/unit/+/+/+/exec/feedback")
               if d.get("status") == "running"]
    assert sorted(running) == sorted({t for ids in coms.values() for _, t in ids}), running


def test_the_broker_down_while_a_task_finishes_the_mission_still_ends(
        mosquitto: PrivateMosquitto, procs: Processes, prefix: str) -> None:
    settings = mosquitto.settings()
    procs.sim("u0")
    with TstEngine(settings, prefix=prefix), start_service(settings, prefix) as service:
        ready(service, ["u0"])
        col = watch(settings, prefix)
        try:
            root = delegate(col, service, conc(move_to(GOAL["u0"], "/u0")))
            wait_running(col, {"u0"})
            mosquitto.kill()  # the task (3.75 s wall) finishes while the broker is away
            down = time.monotonic()
            # Nothing to wait on while the broker is away: the outage itself is the test input.
            time.sleep(OUTAGE)
            mosquitto.start(port=settings.port)
            assert time.monotonic() - down >= OUTAGE
            mission = query_until_ended(col, service, root, timeout=60.0)
            assert mission["status"] == "succeeded", mission
            assert [n["status"] for n in mission["nodes"] if n["name"] == "move-to"] == [
                "succeeded"]
            starts = {d["task-uuid"] for d in col.json_on("+/unit/+/+/+/exec/command")
                      if d.get("command") == "start-task"}
            assert len(starts) == 1  # never started again
        finally:
            col.stop()


def query_until_ended(col: Collector, service: DelegationService, root: str,
                      timeout: float) -> dict[str, Any]:
    """``query-mission`` every second until the mission ended (the collector may have missed the
    feedback while it was reconnecting)."""
    deadline = time.monotonic() + timeout
    last: dict[str, Any] = {}
    while time.monotonic() < deadline:
        com = str(uuid.uuid4())
        try:
            col.publish(f"{service.config.base_topic}/delegation/command",
                        {"com-uuid": com, "command": "query-mission", "root-uuid": root})
            answer = col.wait_json("+/unit/+/+/+/delegation/response",
                                   lambda d, c=com: d.get("response-to") == c, timeout=1.0)
        except (AssertionError, MqttError):  # not reconnected yet, or no answer: ask again
            continue
        last = answer["mission"]
        if last["status"] in ("succeeded", "failed", "aborted"):
            return last
    raise AssertionError(f"mission {root} did not end within {timeout} s: {last}")


def test_concurrent_missions_never_double_book_a_unit(
        mosquitto: PrivateMosquitto, procs: Processes, prefix: str) -> None:
    settings = mosquitto.settings()
    for name in ("u0", "u1"):
        procs.sim(name)
    with TstEngine(settings, prefix=prefix), start_service(settings, prefix) as service:
        ready(service, ["u0", "u1"])
        col = watch(settings, prefix)
        try:
            first = delegate(col, service, conc(move_to(GOAL["u0"], "/u0")))
            # Nearest to u0 as well: without commitments it would be planned onto u0 at once.
            second = delegate(col, service, conc(move_to(GOAL["near-u0"], "*")))
            plans = {d["plan"]["tst"]["common_params"]["node-uuid"]: d["plan"]
                     for d in col.json_on("+/unit/+/+/+/delegation/response") if "plan" in d}
            (a1,), (a2,) = plans[first]["assignments"], plans[second]["assignments"]
            assert any("u0: busy in mission" in n for n in plans[second]["notes"]), plans[second]
            # u0 free at the first goal (75 s) + 50 m beats u1 now (about 390 m): u0, after.
            assert a2["execunit"] == "/u0", a2
            assert a2["start"] >= a1["end"] - 5.0, (a1, a2)  # the first started < 5 s earlier
            for root in (first, second):
                assert final_status(col, root, timeout=90.0)["status"] == "succeeded"
            done = finished_per_goal(col)
            assert sorted(len(v) for v in done.values()) == [1, 1], done
            assert_one_task_at_a_time(col)
        finally:
            col.stop()


def assert_one_task_at_a_time(col: Collector) -> None:
    """On the wire: no unit got a start-task while a task of its was running (not finished)."""
    running: dict[str, str] = {}
    for m in list(col.messages):
        unit = m.topic.split("/")[-3]
        d = json.loads(m.payload)
        if m.topic.endswith("exec/command") and d.get("command") == "start-task":
            assert unit not in running, f"/{unit} got a start-task while {running[unit]} ran"
        elif m.topic.endswith("exec/feedback") and d.get("status") == "running":
            running[unit] = str(d.get("task-uuid"))
        elif m.topic.endswith("exec/feedback") and d.get("status") in (
                "finished", "failed", "aborted"):
            running.pop(unit, None)
