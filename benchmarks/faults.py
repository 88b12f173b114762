"""How fast a lost unit's tasks move (prints the figures): loss -> ``re-delegated`` -> mission end.

Set-up per run: a private mosquitto, three ``delegation sim`` processes (one unit each, heartbeat
2 Hz, speed-up 10), the reference engine and the service in this process. A ``conc`` of two
300 m move-tos on u0 and u1 is delegated; once both run, u1's process is killed with SIGKILL.

Measured (wall seconds, monotonic): kill -> ``re-delegated`` on ``delegation/feedback`` (the
bound is u1's timeout, 3 periods at 2 Hz but at least 5 s, + a 0.2 s tick + planning); kill ->
mission ``succeeded``; and whether every task finished exactly once.

    PYTHONPATH=src python benchmarks/faults.py [--runs 3] [--min-timeout 5]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

from delegation.engine import TstEngine
from delegation.runtime.broker import PrivateMosquitto
from delegation.runtime.mqtt import Message, MqttClient
from delegation.service import DelegationService, ServiceConfig

SRC = str(Path(__file__).resolve().parents[1] / "src")
HOME = {"u0": (57.7600, 16.6800), "u1": (57.7600, 16.6840), "u2": (57.7624, 16.6842)}
GOAL = {"u0": (57.7627, 16.6800), "u1": (57.7627, 16.6840)}


class Watch:
    """Records messages; ``wait`` blocks on a condition until one matches (with a deadline)."""

    def __init__(self, settings: Any) -> None:
        self.messages: list[Message] = []
        self.cond = threading.Condition()
        self.client = MqttClient(settings, sink=self.record)

    def record(self, m: Message) -> None:
        with self.cond:
            self.messages.append(m)
            self.cond.notify_all()

    def wait(self, pred: Any, timeout: float) -> Message:
        found: list[Message] = []

        def check() -> bool:
            found[:] = [m for m in self.messages if pred(m)]
            return bool(found)

        with self.cond:
            if not self.cond.wait_for(check, timeout):
                raise TimeoutError(f"nothing matching within {timeout} s")
        return found[0]


def move_to(goal: tuple[float, float], unit: str) -> dict[str, Any]:
    return {"name": "move-to", "common_params": {"execunit": unit},
            "params": {"speed": "standard",
                       "waypoint": {"latitude": goal[0], "longitude": goal[1], "altitude": 20.0}}}


def sim(name: str, port: int, prefix: str, workdir: Path) -> subprocess.Popen[bytes]:
    lat, lon = HOME[name]
    path = workdir / f"{name}.json"
    path.write_text(json.dumps({
        "name": name, "description": "one unit",
        "agents": [{"name": name, "type": "air", "rate": 2.0,
                    "position": {"latitude": lat, "longitude": lon, "altitude": 20.0},
                    "speeds": {"slow": 2.0, "standard": 4.0, "fast": 8.0}, "tasks": ["move-to"]}],
        "mission": move_to(GOAL["u0"], "*")}))
    return subprocess.Popen(
        [sys.executable, "-m", "delegation", "sim", str(path), "--speedup", "10", "--broker",
         "127.0.0.1", "--port", str(port), "--prefix", prefix],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        env={**os.environ, "PYTHONPATH": SRC})


def one_run(min_timeout: float) -> dict[str, Any]:
    prefix = f"bench-{uuid.uuid4().hex[:8]}"
    with PrivateMosquitto() as broker, tempfile.TemporaryDirectory() as tmp:
        settings = broker.settings()
        procs = {n: sim(n, settings.port, prefix, Path(tmp)) for n in HOME}
        try:
            config = ServiceConfig(prefix=prefix, min_heartbeat_timeout=min_timeout)
            service = DelegationService(settings, config)
            with TstEngine(settings, prefix=prefix), service:
                if not service.wait_ready(list(HOME), timeout=30.0):
                    raise TimeoutError("units not seen within 30 s")
                watch = Watch(settings)
                client = watch.client
                client.subscribe(f"{prefix}/unit/+/+/+/exec/#")
                client.subscribe(f"{prefix}/unit/+/+/delegator0/delegation/#")
                client.connect()
                try:
                    return measure(service, watch, procs)
                finally:
                    client.disconnect()
        finally:
            for p in procs.values():
                p.kill()
                p.wait(10)


def measure(service: DelegationService, watch: Watch,
            procs: dict[str, subprocess.Popen[bytes]]) -> dict[str, Any]:
    com = str(uuid.uuid4())
    tree = {"name": "conc", "common_params": {},
            "children": [move_to(GOAL["u0"], "/u0"), move_to(GOAL["u1"], "/u1")]}
    # Our SUBSCRIBEs went out in on_connect on this connection, so the broker has them first.
    watch.client.publish(f"{service.config.base_topic}/delegation/command", json.dumps(
        {"com-uuid": com, "command": "delegate", "tst": tree, "start": True}).encode(), qos=1)

    def js(m: Message) -> dict[str, Any]:
        data = json.loads(m.payload)
        return data if isinstance(data, dict) else {}

    answer = js(watch.wait(lambda m: js(m).get("response-to") == com, 30.0))
    root = answer["plan"]["tst"]["common_params"]["node-uuid"]
    for unit in ("u0", "u1"):
        watch.wait(lambda m, u=unit: m.topic.endswith(f"{u}/exec/feedback")
                   and js(m).get("status") == "running", 30.0)
    procs["u1"].send_signal(signal.SIGKILL)
    killed = time.monotonic()
    watch.wait(lambda m: js(m).get("status") == "re-delegated", 30.0)
    moved = time.monotonic() - killed
    end = js(watch.wait(lambda m: js(m).get("root-uuid") == root
                        and js(m).get("status") in ("succeeded", "failed", "aborted"), 90.0))
    ended = time.monotonic() - killed
    finished = [js(m).get("task-uuid") for m in watch.messages
                if m.topic.endswith("exec/feedback") and js(m).get("status") == "finished"]
    return {"re-delegated": moved, "ended": ended, "status": end["status"],
            "finished": len(set(finished))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--min-timeout", type=float, default=5.0,
                        help="the service's min_heartbeat_timeout (s; 3 periods at 2 Hz is 1.5)")
    args = parser.parse_args()
    rows = []
    for i in range(args.runs):
        row = one_run(args.min_timeout)
        rows.append(row)
        print(f"run {i + 1}: kill -> re-delegated {row['re-delegated']:.2f} s, kill -> "
              f"{row['status']} {row['ended']:.2f} s, tasks finished {row['finished']} (of 2)")
    moved = [r["re-delegated"] for r in rows]
    print(f"kill -> re-delegated: median {statistics.median(moved):.2f} s, max {max(moved):.2f} s "
          f"over {len(rows)} runs (bound: max(1.5 s, {args.min_timeout:g} s) timeout + "
          f"0.2 s tick + planning)")


if __name__ == "__main__":
    main()
