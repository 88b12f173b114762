"""Catching up after a ``kill -9`` of the service (issue 22 item 1, DESIGN 3.13): how long after
its return a mission that ended while it was down is reported final, when the engine answers
``query-tst`` (ours) and when it does not (the public op0: the service asks the units
``query-status``). Prints the figures.

Set-up per run: a private mosquitto; two simulated air units (`LocalSystem`, speed-up 10,
heartbeat 5 Hz) and the reference engine in this process, the engine with ``answers_query_tst``
on (``engine``) or off (``units``); the service as ``python -m delegation serve`` in a subprocess
with an SQLite state file. A ``conc`` of two ``move-to`` (one per unit, about 200 m: 2.5 s of
wall time) is delegated; once both run (as the service relays them), the service is killed with
SIGKILL; once the engine reports the tree ``succeeded`` (nobody listening), the service is
started again.

Measured (wall seconds, monotonic): from the new instance's first heartbeat to its
``succeeded`` on ``delegation/feedback``; and how the end was learnt (``query-status`` sent by
the service, or not). Bound (docs/protocol.md §11): the engine's heartbeat heard (1 Hz) +
``catch_up_timeout`` (2 s) for a silent engine + the units' answers. Measured 2026-11-26 (5 runs
each, load average 16-30 on 2 cores): engine median 0.81 s (max 1.01 s); units median 2.63 s
(max 3.04 s), 2 ``query-status`` sent each run.

    PYTHONPATH=src python benchmarks/catch_up.py [--runs 5] [--mode both]
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
import time
import uuid
from pathlib import Path
from typing import Any

from faults import Watch, js

from delegation.engine import TstEngine
from delegation.fleet import make_unit
from delegation.geo import LocalFrame
from delegation.local import LocalSystem
from delegation.runtime.broker import PrivateMosquitto
from delegation.runtime.settings import BrokerSettings
from delegation.service import ServiceConfig

SRC = str(Path(__file__).resolve().parents[1] / "src")
FRAME = LocalFrame(57.7605, 16.6815)
SPEEDS = {"slow": 4.0, "standard": 8.0, "fast": 14.0}
UNITS = ("dji0", "dji1")


def serve(settings: BrokerSettings, prefix: str, name: str, state: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "delegation", "serve", "--broker", settings.host, "--port",
         str(settings.port), "--prefix", prefix, "--name", name, "--state", state],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        env={**os.environ, "PYTHONPATH": SRC})


def _move(unit: str, east: float) -> dict[str, Any]:
    return {"name": "move-to", "common_params": {"execunit": f"/{unit}"},
            "params": {"waypoint": FRAME.geopoint(east, 40, 30).to_wire()}}


def one_run(mode: str) -> dict[str, Any]:
    prefix = f"bench-{uuid.uuid4().hex[:8]}"
    name = f"svc{uuid.uuid4().hex[:6]}"
    config = ServiceConfig(prefix=prefix, name=name)
    base = config.base_topic
    units = [make_unit(u, "air", FRAME.geopoint(i * 20.0, 0, 30), ["move-to"], speeds=SPEEDS)
             for i, u in enumerate(UNITS)]
    with PrivateMosquitto() as broker, tempfile.TemporaryDirectory() as tmp:
        settings = broker.settings()
        watch = Watch(settings)
        for topic in (f"{base}/#", f"{prefix}/unit/+/+/op0/tst/feedback",
                      f"{prefix}/unit/+/+/+/exec/command"):
            watch.client.subscribe(topic)
        watch.client.connect()
        state = str(Path(tmp) / "state.sqlite")
        procs: list[subprocess.Popen[bytes]] = []
        engine = TstEngine(settings, "op0", prefix=prefix, answers_query_tst=mode == "engine")
        try:
            with LocalSystem(units, settings=settings, config=config, service=False,
                             engine=False, speedup=10.0, rates={u: 5.0 for u in UNITS}), engine:
                if not engine.wait_for_units(UNITS, 15):
                    raise TimeoutError("the engine did not see the units within 15 s")
                procs.append(serve(settings, prefix, name, state))
                return measure(watch, base, prefix, settings, name, state, procs)
        finally:
            for p in procs:
                p.kill()
                p.wait(10)
            watch.client.disconnect()


def measure(watch: Watch, base: str, prefix: str, settings: BrokerSettings, name: str,
            state: str, procs: list[subprocess.Popen[bytes]]) -> dict[str, Any]:
    def heartbeat_after(t0: float) -> float:
        with watch.cond:
            watch.cond.wait_for(lambda: any(
                t > t0 and m.topic == f"{base}/heartbeat" for t, m in watch.messages), 30)
        return next(t for t, m in watch.messages if t > t0 and m.topic == f"{base}/heartbeat")

    heartbeat_after(0.0)
    tree = {"name": "conc", "children": [_move("dji0", 200), _move("dji1", 220)]}
    started: dict[str, Any] = {}
    for _ in range(10):  # the service holds plans until it heard the engine; ask until started
        com = str(uuid.uuid4())
        watch.client.publish(f"{base}/delegation/command", json.dumps(
            {"com-uuid": com, "command": "delegate", "start": True, "tst": tree,
             "sender": "bench"}).encode())
        _, answer = watch.wait(lambda m, c=com: m.topic == f"{base}/delegation/response"
                               and js(m).get("response-to") == c, 30)
        started = js(answer)
        if started.get("response") == "started":
            break
    sent = started["plan"]["tst"]
    root = sent["common_params"]["node-uuid"]
    for task in (c["common_params"]["node-uuid"] for c in sent["children"]):
        watch.wait(lambda m, t=task: m.topic == f"{base}/tst/feedback"
                   and js(m).get("node-uuid") == t and js(m).get("status") == "running", 30)
    procs[0].send_signal(signal.SIGKILL)
    procs[0].wait(10)
    watch.wait(lambda m: m.topic.endswith("/op0/tst/feedback") and js(m).get("node-uuid") == root
               and js(m).get("status") == "succeeded", 30)
    restarted = time.monotonic()
    procs.append(serve(settings, prefix, name, state))
    back = heartbeat_after(restarted)
    ended, _ = watch.wait(lambda m: m.topic == f"{base}/delegation/feedback"
                          and js(m).get("root-uuid") == root
                          and js(m).get("status") == "succeeded", 60)
    asked = sum(1 for t, m in watch.messages if t > restarted
                and m.topic.endswith("/exec/command") and js(m).get("command") == "query-status"
                and js(m).get("sender") == name)
    return {"final": ended - back, "query-status": asked}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--mode", choices=("engine", "units", "both"), default="both",
                        help="the engine answers query-tst (engine), or not (units)")
    args = parser.parse_args()
    modes = ("engine", "units") if args.mode == "both" else (args.mode,)
    summary: dict[str, list[dict[str, Any]]] = {}
    for mode in modes:
        rows = summary.setdefault(mode, [])
        for i in range(args.runs):
            row = one_run(mode)
            rows.append(row)
            print(f"{mode} run {i + 1}: restarted (first heartbeat) -> succeeded reported "
                  f"{row['final']:.2f} s; query-status sent by the service: "
                  f"{row['query-status']}", flush=True)
    load = Path("/proc/loadavg").read_text().split()[:3]
    for mode, rows in summary.items():
        finals = [r["final"] for r in rows]
        print(f"{mode}: over {len(rows)} runs: median {statistics.median(finals):.2f} s, max "
              f"{max(finals):.2f} s from the restarted service's first heartbeat to the "
              f"mission reported succeeded (load average {' '.join(load)})")


if __name__ == "__main__":
    main()
