"""Latency of the delegation service on a private local mosquitto (prints the figures).

Set-up: a private mosquitto (``set_tcp_nodelay``), 10 simulated units (real ``SimUnit``s, in this
process, publishing heartbeats and positions), the delegation service, and a stand-in engine that
only answers ``started`` (this measures the service, not tree execution).

Measured:
1. ``start-tst`` -> instantiated ``start-tst``: from just before the bench publishes a partial
   20-task tree to the service's ``tst/command`` until the stand-in engine's client receives the
   instantiated tree on ``op0/tst/command`` (on the wire, both hops through the broker included),
   with the ``auction`` strategy, over 100 missions run one after another. Also the service's own
   figures from its timings: the plan itself (on the planner), and the rest (the command's arrival
   in the service's inbox -> the plan back from the planner, less the plan).
2. ``ping`` on ``delegation/command`` -> ``pong`` on ``delegation/response``, 200 round trips.
3. ``plan_mission`` alone (in this process, no broker, no service threads around it) on trees of
   the same shapes and the same units, and on ``small`` missions (a ``conc`` of 2-5 move-tos,
   what a burst sends): the planner's own cost, apart from what sharing the interpreter costs it
   in the service; wall clock and CPU time (the CPU figure holds on a loaded machine).
   ``--planner-only`` measures only this (no broker). The units are idle here; in the service
   they are busy with the earlier missions (the stand-in engine never ends one), so the
   in-service plans also fit each task after the units' current work (more bids simulated).

``--transport ros2`` runs the same on ROS 2 (no broker: every client in this process on Fast DDS
with the loopback-only profile of deploy/ros2/ unless FASTDDS_DEFAULT_PROFILES_FILE names another,
in ROS_DOMAIN_ID or a random domain); ``--transport both`` runs MQTT, then ROS 2, in the same run
and prints the ratio of the start-tst p50s (target: ROS 2 within 2 x MQTT, issue 24).

Targets: start-tst p50 < 50 ms and p99 < 150 ms; ping p50 < 5 ms.

    .venv/bin/python benchmarks/latency.py [--missions 100] [--tasks 20] [--units 10]
        [--shape mixed|flat|both] [--planner-only] [--transport mqtt|ros2|both]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import statistics
import sys
import threading
import time
import uuid
from typing import Any

from delegation.allocation import plan_mission
from delegation.fleet import make_unit
from delegation.geo import GeoPoint, LocalFrame
from delegation.local import LocalSystem
from delegation.messages import HeartBeat, TstResponse, encode
from delegation.runtime.broker import PrivateMosquitto
from delegation.runtime.mqtt import Message
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.transport import make_client
from delegation.service import ServiceConfig
from delegation.topics import unit_base_topic
from delegation.tst import parse_tree

PREFIX = "bench"
ORIGIN = GeoPoint(latitude=57.7605, longitude=16.6815)
TASKS = ["move-to", "move-path", "search-area", "search-around-position", "look-at-position"]


class StandInEngine:
    """Publishes op0's heartbeat and answers every start-tst ``started``; records arrivals."""

    def __init__(self, settings: BrokerSettings) -> None:
        self.base = unit_base_topic("op0", "ground", "simulation", PREFIX)
        self.arrivals: dict[str, float] = {}  # root node-uuid -> perf_counter at arrival
        self.cond = threading.Condition()
        self.client = make_client(settings, "bench-engine", sink=self._sink)
        self.client.subscribe(f"{self.base}/tst/command")
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, daemon=True)

    def _sink(self, msg: Message) -> None:
        t = time.perf_counter()
        data = json.loads(msg.payload)
        if data.get("command") != "start-tst":
            return
        root = data["tst"].get("common_params", {}).get("node-uuid", "")
        with self.cond:
            self.arrivals[root] = t
            self.cond.notify_all()
        resp = TstResponse(response="started", response_to=data["com-uuid"], root_uuid=root)
        self.client.publish(f"{self.base}/tst/response", encode(resp), qos=1)

    def _beat(self) -> None:
        while not self._stop.is_set():
            hb = HeartBeat(agent_type="ground", agent_uuid="bench-engine",
                           levels=["tst execution"], name="op0", rate=1.0, stamp=time.time())
            self.client.publish(f"{self.base}/heartbeat", encode(hb))
            self._stop.wait(1.0)

    def start(self) -> None:
        self.client.connect()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.client.disconnect()

    def wait(self, root: str, timeout: float) -> float | None:
        with self.cond:
            if self.cond.wait_for(lambda: root in self.arrivals, timeout):
                return self.arrivals[root]
        return None


def make_units(n: int, rng: random.Random) -> list[Any]:
    frame = LocalFrame(ORIGIN.latitude, ORIGIN.longitude)
    units = []
    for i in range(n):
        kind = "air" if i % 3 else "surface"
        pos = frame.geopoint(rng.uniform(-800, 800), rng.uniform(-800, 800), 30.0)
        tasks = TASKS if kind == "air" else ["move-to", "move-path", "search-area"]
        units.append(make_unit(f"u{i}", kind, pos, tasks))
    return units


def make_tree(n: int, rng: random.Random, shape: str = "mixed") -> dict[str, Any]:
    frame = LocalFrame(ORIGIN.latitude, ORIGIN.longitude)

    def pt(x: float, y: float) -> dict[str, Any]:
        return frame.geopoint(x, y, 30.0).to_wire()

    children = []
    for i in range(n):
        x, y = rng.uniform(-1500, 1500), rng.uniform(-1500, 1500)
        kind = ("move-to", "move-to", "move-path", "search-area")[i % 4]
        if kind == "move-to":
            params: dict[str, Any] = {"waypoint": pt(x, y)}
        elif kind == "move-path":
            params = {"waypoints": [pt(x, y), pt(x + 100, y + 50), pt(x + 200, y)]}
        else:
            params = {"area": [pt(x, y), pt(x + 80, y), pt(x + 80, y + 60), pt(x, y + 60)]}
        children.append({"name": kind, "common_params": {"execunit": "*"}, "params": params})
    root = {"node-uuid": str(uuid.uuid4())}
    if shape == "flat":  # every task activated at mission start
        return {"name": "conc", "common_params": root, "children": children}
    # "mixed": half in a seq (a chain), half concurrent.
    half = n // 2
    return {"name": "conc", "common_params": root,
            "children": [{"name": "seq", "children": children[:half]}, *children[half:]]}


def make_small(rng: random.Random) -> dict[str, Any]:
    """A burst's mission: a ``conc`` of 2-5 move-tos."""
    frame = LocalFrame(ORIGIN.latitude, ORIGIN.longitude)
    children = [{"name": "move-to", "common_params": {"execunit": "*"},
                 "params": {"waypoint": frame.geopoint(rng.uniform(-1500, 1500),
                                                       rng.uniform(-1500, 1500), 30.0).to_wire()}}
                for _ in range(rng.randint(2, 5))]
    return {"name": "conc", "common_params": {"node-uuid": str(uuid.uuid4())},
            "children": children}


def planner_alone(
    units: list[Any], trees: list[dict[str, Any]], strategy: str
) -> tuple[list[float], list[float]]:
    """Milliseconds of ``plan_mission`` per tree in this process (after one warm-up plan): wall
    clock, and this thread's CPU time (what other processes on a loaded machine do not change)."""
    nodes = [parse_tree(tree) for tree in trees]
    plan_mission(nodes[0], units, strategy=strategy)
    wall, cpu = [], []
    for node in nodes:
        t0, c0 = time.perf_counter(), time.thread_time()
        plan_mission(node, units, strategy=strategy)
        cpu.append((time.thread_time() - c0) * 1000)
        wall.append((time.perf_counter() - t0) * 1000)
    return wall, cpu


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    k = min(len(ordered) - 1, max(0, round(q / 100 * (len(ordered) - 1))))
    return ordered[k]


def line(name: str, values_ms: list[float]) -> str:
    return (f"{name:<44} n={len(values_ms):4d}  p50={pct(values_ms, 50):7.2f} ms  "
            f"p90={pct(values_ms, 90):7.2f} ms  p99={pct(values_ms, 99):7.2f} ms  "
            f"max={max(values_ms):7.2f} ms  mean={statistics.fmean(values_ms):7.2f} ms")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--missions", type=int, default=100)
    parser.add_argument("--tasks", type=int, default=20)
    parser.add_argument("--units", type=int, default=10)
    parser.add_argument("--pings", type=int, default=200)
    parser.add_argument("--strategy", default="auction")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--shape", choices=("mixed", "flat", "both"), default="both",
                        help="mixed: conc of a 10-task seq and 10 tasks; flat: conc of 20 tasks")
    parser.add_argument("--planner-only", action="store_true",
                        help="only plan_mission in this process (no broker, no service)")
    parser.add_argument("--transport", choices=("mqtt", "ros2", "both"), default="mqtt")
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    shapes = ("mixed", "flat") if args.shape == "both" else (args.shape,)
    alone_units = make_units(args.units, random.Random(args.seed))
    alone = {shape: [make_tree(args.tasks, rng, shape) for _ in range(args.missions)]
             for shape in shapes}
    alone["small"] = [make_small(rng) for _ in range(args.missions)]
    for shape, trees in alone.items():
        wall, cpu = planner_alone(alone_units, trees, args.strategy)
        print(line(f"[{shape}] plan_mission alone", wall))
        print(line(f"[{shape}] plan_mission alone, CPU", cpu))
    if args.planner_only:
        return 0
    p50s: dict[str, float] = {}
    for transport in ("mqtt", "ros2") if args.transport == "both" else (args.transport,):
        code = measure(args, shapes, transport, p50s)
        if code:
            return code
    if len(p50s) == 2:
        ratio = p50s["ros2"] / p50s["mqtt"]
        print(f"start-tst p50, ROS 2 / MQTT: {p50s['ros2']:.2f} / {p50s['mqtt']:.2f} ms = "
              f"{ratio:.2f} x; target within 2 x:", "met" if ratio <= 2 else "NOT met")
    return 0


def _ros2_environment() -> None:
    """The loopback-only DDS profile and a domain of this run's own, unless already chosen."""
    profile = os.path.join(os.path.dirname(__file__), "..", "deploy", "ros2",
                           "fastdds-loopback.xml")
    os.environ.setdefault("FASTDDS_DEFAULT_PROFILES_FILE", os.path.abspath(profile))
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 200)))


def measure(args: argparse.Namespace, shapes: tuple[str, ...], transport: str,
            p50s: dict[str, float]) -> int:
    """The service's latencies on one transport (prints them; the first shape's start-tst p50
    into ``p50s[transport]``)."""
    rng = random.Random(args.seed)
    with contextlib.ExitStack() as stack:
        if transport == "ros2":
            _ros2_environment()
            settings = BrokerSettings(transport="ros2")
            where = f"ROS 2 (domain {os.environ['ROS_DOMAIN_ID']}, Fast DDS, loopback)"
        else:
            broker = PrivateMosquitto().start()
            stack.callback(broker.stop)
            settings = broker.settings()
            where = "private mosquitto"
        return _measure(args, shapes, settings, where, rng, p50s, transport)
    return 1


def _measure(args: argparse.Namespace, shapes: tuple[str, ...], settings: BrokerSettings,
             where: str, rng: random.Random, p50s: dict[str, float], transport: str) -> int:
    units = make_units(args.units, rng)
    engine = StandInEngine(settings)
    system = LocalSystem(units, settings=settings, engine=False,
                         config=ServiceConfig(prefix=PREFIX, strategy=args.strategy),
                         rates={u.name: 2.0 for u in units}, ready_timeout=20)
    responses: dict[str, float] = {}
    cond = threading.Condition()

    def sink(msg: Message) -> None:
        t = time.perf_counter()
        data = json.loads(msg.payload)
        with cond:
            responses[data.get("response-to", "")] = t
            cond.notify_all()

    bench = make_client(settings, "bench-client", sink=sink)
    base = system.config.base_topic
    bench.subscribe(f"{base}/+/response")
    try:
        engine.start()  # the stand-in first: the service sees its first heartbeat at once
        system.start()
        service = system.service
        assert service is not None
        bench.connect()
        if not service.wait_ready([u.name for u in units], timeout=20):
            print("service did not see the fleet and the engine", file=sys.stderr)
            return 1

        def roundtrip(topic: str, body: dict[str, Any]) -> tuple[float, float]:
            com = str(uuid.uuid4())
            payload = json.dumps({**body, "com-uuid": com, "sender": "bench"}).encode()
            t0 = time.perf_counter()
            bench.publish(topic, payload, qos=1)
            with cond:
                if not cond.wait_for(lambda: com in responses, 30):
                    raise RuntimeError(f"no answer to {body['command']}")
            return t0, responses[com]

        # Warm-up (imports, first plan).
        for _ in range(3):
            roundtrip(f"{base}/tst/command", {"command": "start-tst",
                                               "tst": make_tree(args.tasks, rng)})

        results: dict[str, tuple[list[float], list[float], list[float], int]] = {}
        for shape in shapes:
            wire_ms: list[float] = []
            failed = 0
            first_timing = len(service.timings)
            for _ in range(args.missions):
                tree = make_tree(args.tasks, rng, shape)
                root = tree["common_params"]["node-uuid"]
                com = str(uuid.uuid4())
                payload = json.dumps({"com-uuid": com, "command": "start-tst",
                                      "sender": "bench", "receiver": "delegator0",
                                      "tst": tree}).encode()
                t0 = time.perf_counter()
                bench.publish(f"{base}/tst/command", payload, qos=1)
                arrived = engine.wait(root, 30)
                with cond:
                    cond.wait_for(lambda c=com: c in responses, 30)
                if arrived is None:
                    failed += 1
                    continue
                wire_ms.append((arrived - t0) * 1000)
            timings = service.timings[first_timing:]
            planning_ms = [t.planning * 1000 for t in timings]
            overhead_ms = [(t.sent - t.received - t.planning) * 1000 for t in timings]
            results[shape] = (wire_ms, planning_ms, overhead_ms, failed)

        ping_ms = []
        for _ in range(args.pings):
            t0, t1 = roundtrip(f"{base}/delegation/command", {"command": "ping"})
            ping_ms.append((t1 - t0) * 1000)

        print(f"latency: {where}, {args.units} simulated units, {args.tasks}-task "
              f"missions, strategy {args.strategy}, {args.missions} missions per shape")
        for shape, (wire_ms, planning_ms, overhead_ms, failed) in results.items():
            if wire_ms:
                print(line(f"[{shape}] start-tst -> instantiated start-tst", wire_ms))
                print(line(f"[{shape}]   of which plan_mission", planning_ms))
                print(line(f"[{shape}]   service, without plan_mission", overhead_ms))
            if failed:
                print(f"[{shape}] missions that never reached the engine: {failed}")
            met = bool(wire_ms) and pct(wire_ms, 50) < 50 and pct(wire_ms, 99) < 150
            print(f"[{shape}] target p50 < 50 ms, p99 < 150 ms:", "met" if met else "NOT met")
            if wire_ms and transport not in p50s:
                p50s[transport] = pct(wire_ms, 50)
        print(line("ping -> pong (delegation/command)", ping_ms))
        print("target ping p50 < 5 ms:", "met" if pct(ping_ms, 50) < 5 else "NOT met")
        return 0
    finally:
        bench.disconnect()
        system.stop()
        engine.stop()




if __name__ == "__main__":
    sys.exit(main())
