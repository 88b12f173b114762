"""How a lost unit's work moves, and what it costs the healthy units (prints the figures):
loss -> ``re-delegated`` -> the lost task restarting elsewhere -> mission end, and how often the
healthy units' running tasks were signalled or started again. Compares the service's two repairs
(docs/protocol.md §11): ``rebind`` (the default: the lost unit's task moves within the running
tree) and ``restart`` (the old one: the tree is aborted and the remaining one started).

Set-up per run: a private mosquitto, five ``delegation sim`` processes (one unit each, heartbeat
2 Hz, speed-up 10), the reference engine and the service in this process. A ``conc`` of four
``search-area`` tasks (a 120 m square at each of u0..u3's homes, u1's 60 m) is delegated; u4 is
idle, 100 m from u1. Once the four run, u1's process is killed with SIGKILL: the healthy units'
searches are the mission's critical path, so a repair that restarts them shows in its end.

Measured (wall seconds, monotonic, from the kill): ``re-delegated`` on ``delegation/feedback``
(the bound is u1's timeout, 3 periods at 2 Hz but at least ``--min-timeout``, + a 0.2 s tick +
planning); the first new ``start-task`` of u1's search on another unit; the mission's end; and,
counted on the healthy units' ``exec/command``, the signal-tasks and the start-tasks (distinct
com-uuids) beyond their own first one.

The shared-search case (``--case search``, issue 22 item 3 / issue 21 item 4): one
``search-area`` (360 m x 330 m) shared by ``auction`` among u0..u2 (three ``delegation sim``
processes, speed-up 10); u1 is killed once 12 of its reported positions lie in its part (about
halfway). Compares ``repair_sweep: remainder`` (what u1's positions swept is subtracted, the rest
shared among u0 and u2 in u1's part's place) with ``whole`` (u1's part planned again whole):
kill -> mission end, the share credited as swept, and the healthy units' signal-tasks and own
parts started again. Measured 2026-11-26 (2 runs each, load average 11-23 on 2 cores):
remainder 64.5 s (19 % of u1's part credited as swept), whole 71.8 s; 0 signal-tasks and 0 own
parts started again for u0/u2 in both.

    PYTHONPATH=src python benchmarks/faults.py [--runs 2] [--min-timeout 5] [--repair both]
    PYTHONPATH=src python benchmarks/faults.py --case search [--runs 2]
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
#: u0..u3 400 m apart, each searching a square at home (120 m; u1's 60 m, so that the healthy
#: units' searches are what the mission waits for); u4 idle, 100 m north of u1.
HOME = {f"u{i}": (57.7600, 16.6800 + 0.0066 * i) for i in range(4)} | {"u4": (57.7609, 16.6866)}
BUSY = ("u0", "u1", "u2", "u3")
LOST = "u1"
SIDE = (0.00108, 0.002)  # 120 m in latitude and longitude degrees at 57.76 N


class Watch:
    """Records messages; ``wait`` blocks on a condition until one matches (with a deadline)."""

    def __init__(self, settings: Any) -> None:
        self.messages: list[tuple[float, Message]] = []
        self.cond = threading.Condition()
        self.client = MqttClient(settings, sink=self.record)

    def record(self, m: Message) -> None:
        with self.cond:
            self.messages.append((time.monotonic(), m))
            self.cond.notify_all()

    def wait(self, pred: Any, timeout: float) -> tuple[float, Message]:
        found: list[tuple[float, Message]] = []

        def check() -> bool:
            found[:] = [(t, m) for t, m in self.messages if pred(m)]
            return bool(found)

        with self.cond:
            if not self.cond.wait_for(check, timeout):
                raise TimeoutError(f"nothing matching within {timeout} s")
        return found[0]


def js(m: Message) -> dict[str, Any]:
    try:
        data = json.loads(m.payload)
    except ValueError:
        return {}
    return data if isinstance(data, dict) else {}


def area_of(unit: str) -> list[dict[str, float]]:
    lat, lon = HOME[unit]
    dlat, dlon = (SIDE[0] / 2, SIDE[1] / 2) if unit == LOST else SIDE
    return [{"latitude": la, "longitude": lo, "altitude": 20.0}
            for la, lo in ((lat, lon), (lat + dlat, lon), (lat + dlat, lon + dlon),
                           (lat, lon + dlon))]


def search(unit: str) -> dict[str, Any]:
    return {"name": "search-area", "common_params": {"execunit": f"/{unit}"},
            "params": {"area": area_of(unit), "speed": "standard"}}


def spawn_sim(name: str, port: int, prefix: str, workdir: Path, home: tuple[float, float],
              tasks: list[str], mission: dict[str, Any] | None = None
              ) -> subprocess.Popen[bytes]:
    """``delegation sim`` of one air unit at ``home`` doing ``tasks`` (its scenario's mission:
    ``mission``, else a move-to where it is), at speed-up 10 on the private broker."""
    here = {"latitude": home[0], "longitude": home[1], "altitude": 20.0}
    path = workdir / f"{name}.json"
    path.write_text(json.dumps({
        "name": name, "description": f"{name}, simulated",
        "agents": [{"name": name, "type": "air", "rate": 2.0, "position": here,
                    "speeds": {"slow": 2.0, "standard": 4.0, "fast": 8.0}, "tasks": tasks}],
        "mission": mission or {"name": "move-to", "common_params": {},
                               "params": {"waypoint": here}}}))
    return subprocess.Popen(
        [sys.executable, "-m", "delegation", "sim", str(path), "--speedup", "10", "--broker",
         "127.0.0.1", "--port", str(port), "--prefix", prefix],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        env={**os.environ, "PYTHONPATH": SRC})


def sim(name: str, port: int, prefix: str, workdir: Path) -> subprocess.Popen[bytes]:
    return spawn_sim(name, port, prefix, workdir, HOME[name], ["move-to", "search-area"],
                     search(name))


def one_run(min_timeout: float, repair: str) -> dict[str, Any]:
    prefix = f"bench-{uuid.uuid4().hex[:8]}"
    with PrivateMosquitto() as broker, tempfile.TemporaryDirectory() as tmp:
        settings = broker.settings()
        procs = {n: sim(n, settings.port, prefix, Path(tmp)) for n in HOME}
        try:
            config = ServiceConfig(prefix=prefix, min_heartbeat_timeout=min_timeout,
                                   repair=repair)
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
    tree = {"name": "conc", "common_params": {}, "children": [search(u) for u in BUSY]}
    # Our SUBSCRIBEs went out in on_connect on this connection, so the broker has them first.
    watch.client.publish(f"{service.config.base_topic}/delegation/command", json.dumps(
        {"com-uuid": com, "command": "delegate", "tst": tree, "start": True}).encode(), qos=1)
    _, m = watch.wait(lambda m: js(m).get("response-to") == com, 30.0)
    answer = js(m)
    if answer.get("response") != "started":
        raise RuntimeError(f"not started: {answer}")
    root = answer["plan"]["tst"]["common_params"]["node-uuid"]
    for unit in BUSY:
        watch.wait(lambda m, u=unit: m.topic.endswith(f"/{u}/exec/feedback")
                   and js(m).get("status") == "running", 30.0)
    procs[LOST].send_signal(signal.SIGKILL)
    killed = time.monotonic()
    moved_at, _ = watch.wait(lambda m: js(m).get("status") == "re-delegated", 30.0)
    lost_area = area_of(LOST)
    restarted_at, m = watch.wait(
        lambda m: js(m).get("command") == "start-task" and f"/{LOST}/" not in m.topic
        and js(m).get("task", {}).get("params", {}).get("area") == lost_area, 120.0)
    taken_by = m.topic.split("/")[-3]
    ended_at, m = watch.wait(lambda m: js(m).get("root-uuid") == root and js(m).get("status")
                             in ("succeeded", "failed", "aborted"), 240.0)
    healthy = [u for u in BUSY if u != LOST]
    signals = starts = 0
    for _, msg in list(watch.messages):
        unit = msg.topic.split("/")[-3]
        d = js(msg)
        if unit in healthy and msg.topic.endswith("exec/command"):
            signals += d.get("command") == "signal-task"
    for unit in healthy:
        own = {js(msg).get("com-uuid") for _, msg in list(watch.messages)
               if msg.topic.endswith(f"/{unit}/exec/command")
               and js(msg).get("command") == "start-task"
               and js(msg).get("task", {}).get("params", {}).get("area") == area_of(unit)}
        starts += len(own) - 1
    return {"re-delegated": moved_at - killed, "restarted": restarted_at - killed,
            "ended": ended_at - killed, "status": js(m)["status"], "taken-by": taken_by,
            "signals": signals, "starts-again": starts}


#: The shared-search case: three drones south of the area, one search shared among them.
SEARCH_HOME = {"u0": (57.7590, 16.6800), "u1": (57.7590, 16.6830), "u2": (57.7590, 16.6860)}
SEARCH_SW, SEARCH_SIZE = (57.7600, 16.6800), (0.0030, 0.0060)


def search_sim(name: str, port: int, prefix: str, workdir: Path) -> subprocess.Popen[bytes]:
    return spawn_sim(name, port, prefix, workdir, SEARCH_HOME[name],
                     ["move-to", "search-area", "search-areas"])


def search_run(min_timeout: float, sweep: str) -> dict[str, Any]:
    prefix = f"bench-{uuid.uuid4().hex[:8]}"
    with PrivateMosquitto() as broker, tempfile.TemporaryDirectory() as tmp:
        settings = broker.settings()
        procs = {n: search_sim(n, settings.port, prefix, Path(tmp)) for n in SEARCH_HOME}
        try:
            config = ServiceConfig(prefix=prefix, min_heartbeat_timeout=min_timeout,
                                   repair_sweep=sweep)
            service = DelegationService(settings, config)
            with TstEngine(settings, prefix=prefix), service:
                if not service.wait_ready(list(SEARCH_HOME), timeout=30.0):
                    raise TimeoutError("units not seen within 30 s")
                watch = Watch(settings)
                for topic in ("+/+/+/exec/#", "+/+/u1/sensor/position",
                              "+/+/delegator0/delegation/#"):
                    watch.client.subscribe(f"{prefix}/unit/{topic}")
                watch.client.connect()
                try:
                    return measure_search(service, watch, procs)
                finally:
                    watch.client.disconnect()
        finally:
            for p in procs.values():
                p.kill()
                p.wait(10)


def measure_search(service: DelegationService, watch: Watch,
                   procs: dict[str, subprocess.Popen[bytes]]) -> dict[str, Any]:
    import shapely  # here: the other case needs no geometry
    from shapely.geometry import Polygon

    from delegation.geo import GeoPoint, LocalFrame

    (lat, lon), (dlat, dlon) = SEARCH_SW, SEARCH_SIZE
    ring = [{"latitude": a, "longitude": b, "altitude": 20.0}
            for a, b in ((lat, lon), (lat + dlat, lon), (lat + dlat, lon + dlon),
                         (lat, lon + dlon))]
    com = str(uuid.uuid4())
    tree = {"name": "search-area", "common_params": {"execunit": "*"},
            "params": {"area": ring, "speed": "standard"}}
    watch.client.publish(f"{service.config.base_topic}/delegation/command", json.dumps(
        {"com-uuid": com, "command": "delegate", "tst": tree, "start": True,
         "strategy": "auction"}).encode(), qos=1)
    _, m = watch.wait(lambda m: js(m).get("response-to") == com, 30.0)
    answer = js(m)
    if answer.get("response") != "started":
        raise RuntimeError(f"not started: {answer}")
    root = answer["plan"]["tst"]["common_params"]["node-uuid"]
    parts = {c["common_params"]["execunit"].strip("/"): c
             for c in answer["plan"]["tst"].get("children", [])}
    if set(parts) != set(SEARCH_HOME):
        raise RuntimeError(f"the search was not shared among three: {sorted(parts)}")
    frame = LocalFrame(lat, lon)
    mine = shapely.union_all([Polygon([frame.point_xy(GeoPoint.model_validate(p)) for p in r])
                              for r in ([parts[LOST]["params"]["area"]]
                                        if "area" in parts[LOST]["params"]
                                        else parts[LOST]["params"]["areas"])]).buffer(5.0)

    def inside(msg: Message) -> bool:
        return msg.topic.endswith("/sensor/position") and mine.contains(
            shapely.Point(frame.point_xy(GeoPoint.model_validate(js(msg)))))

    watch.wait(lambda _m: sum(inside(x) for _, x in list(watch.messages)) >= 12, 120.0)
    procs[LOST].send_signal(signal.SIGKILL)
    killed = time.monotonic()
    moved_at, m = watch.wait(lambda m: js(m).get("status") == "re-delegated", 30.0)
    swept = max((t.get("swept", 0.0) for t in js(m).get("tasks", [])), default=0.0)
    ended_at, m = watch.wait(lambda m: js(m).get("root-uuid") == root and js(m).get("status")
                             in ("succeeded", "failed", "aborted"), 300.0)
    signals = starts = 0
    for unit in ("u0", "u2"):
        sent = [js(x) for _, x in list(watch.messages)
                if x.topic.endswith(f"/{unit}/exec/command")]
        signals += sum(d.get("command") == "signal-task" for d in sent)
        own = {d.get("com-uuid") for d in sent if d.get("command") == "start-task"
               and d.get("task", {}).get("params") == parts[unit]["params"]}
        starts += len(own) - 1
    return {"re-delegated": moved_at - killed, "ended": ended_at - killed,
            "status": js(m)["status"], "swept": swept, "signals": signals,
            "starts-again": starts}


def search_main(runs: int, min_timeout: float) -> None:
    summary: dict[str, list[dict[str, Any]]] = {}
    for sweep in ("remainder", "whole"):
        rows = summary.setdefault(sweep, [])
        for i in range(runs):
            row = search_run(min_timeout, sweep)
            rows.append(row)
            print(f"search, {sweep} run {i + 1}: kill -> re-delegated {row['re-delegated']:.2f} s"
                  f" (swept {100 * row['swept']:.0f} % credited), -> {row['status']} "
                  f"{row['ended']:.2f} s; u0/u2: {row['signals']} signal-task, "
                  f"{row['starts-again']} own part started again", flush=True)
    for sweep, rows in summary.items():
        print(f"search, {sweep}: median over {len(rows)} runs: kill -> mission end "
              f"{statistics.median(r['ended'] for r in rows):.2f} s, credited swept "
              f"{100 * statistics.median(r['swept'] for r in rows):.0f} %; signal-tasks to "
              f"u0/u2 {sum(r['signals'] for r in rows)}, own parts started again "
              f"{sum(r['starts-again'] for r in rows)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--min-timeout", type=float, default=5.0,
                        help="the service's min_heartbeat_timeout (s; 3 periods at 2 Hz is 1.5)")
    parser.add_argument("--repair", choices=("rebind", "restart", "both"), default="both")
    parser.add_argument("--case", choices=("tasks", "search"), default="tasks",
                        help="four searches, one unit's moved (tasks); or one search shared by "
                             "three units, the lost unit's remainder vs its whole part (search)")
    args = parser.parse_args()
    if args.case == "search":
        search_main(args.runs, args.min_timeout)
        return
    modes = ("rebind", "restart") if args.repair == "both" else (args.repair,)
    summary = {}
    for mode in modes:
        rows = []
        for i in range(args.runs):
            row = one_run(args.min_timeout, mode)
            rows.append(row)
            print(f"{mode} run {i + 1}: kill -> re-delegated {row['re-delegated']:.2f} s, -> "
                  f"u1's search restarted on {row['taken-by']} {row['restarted']:.2f} s, -> "
                  f"{row['status']} {row['ended']:.2f} s; healthy units' running tasks: "
                  f"{row['signals']} signal-task, {row['starts-again']} start-task again",
                  flush=True)
        summary[mode] = rows
    for mode, rows in summary.items():
        med = {k: statistics.median(r[k] for r in rows)
               for k in ("re-delegated", "restarted", "ended")}
        print(f"{mode}: median over {len(rows)} runs: kill -> re-delegated "
              f"{med['re-delegated']:.2f} s, -> restarted elsewhere {med['restarted']:.2f} s, "
              f"-> mission end {med['ended']:.2f} s; signal-tasks to the 3 healthy units "
              f"{sum(r['signals'] for r in rows)}, start-tasks again "
              f"{sum(r['starts-again'] for r in rows)} (bound for the first two: "
              f"max(1.5 s, {args.min_timeout:g} s) timeout + 0.2 s tick + planning)")


if __name__ == "__main__":
    main()
