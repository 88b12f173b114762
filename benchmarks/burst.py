"""Burst: 500 small missions at once from 5 clients; how fast are they answered, and what does the
service spend per mission (prints the figures; the load case of the reliability review).

Set-up: a private mosquitto on a free loopback port; 15 simulated units and the reference engine
in this process (`LocalSystem`, ``service=False``); the service as ``python -m delegation serve``
in a subprocess with an SQLite state file, so its CPU time (``utime + stime`` of
``/proc/PID/stat``) is the service's alone. Each client publishes its share of ``delegate`` with
``start`` (2-5 move-tos under a ``conc`` or ``seq``) on its own per-client command topic, all at
once, and reads the answers on its own response topic.

Printed: answers/s (missions / first send -> last answer), p50/p99/max seconds from send to
answer, the service's CPU per mission up to the last answer and up to the end of the run (all
missions ended, or ``--settle`` seconds; also net of what the idle service spends per second on
the fleet's periodic messages, measured for ``--idle`` seconds before the burst), the answers'
kinds, whether every command was answered exactly once on its client's topic (exit 1
otherwise), and how many plans the service made (more than one per mission: plans made again).
The machine's share is printed too: the CPU of this process (the engine, the units, the clients)
and of mosquitto per mission, and the answers/s that all the machine's cores could give at that
cost (the three together are what a burst needs of the machine, whatever the service does).
The service plans in a child process (``serve``'s default; ``--planner thread`` on a thread).
``--profile OUT`` runs ``py-spy record`` on the service from the burst to the end of
the run or (``--profile-until answers``) to the last answer (``--format raw --threads``, with
``--profile-gil`` only the thread holding the GIL:
collapsed stacks, one line per stack with its sample count). With py-spy installed, the
service's CPU to the last answer is also split per thread (``/proc/PID/task/TID/stat``, the
threads named by ``py-spy dump``: the unit's loop, the planner worker, paho's network loop, the
store writer).

    PYTHONPATH=src python benchmarks/burst.py [--missions 500] [--clients 5] [--units 15]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections import Counter
from pathlib import Path
from typing import Any

from delegation.fleet import make_unit
from delegation.geo import LocalFrame
from delegation.local import LocalSystem
from delegation.runtime.broker import PrivateMosquitto
from delegation.runtime.mqtt import Message, MqttClient
from delegation.runtime.settings import BrokerSettings
from delegation.service import ServiceConfig

PREFIX = "burst"
NAME = "burst0"
FRAME = LocalFrame(57.7605, 16.6815)
FINAL = {"succeeded", "failed", "aborted"}
TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` and its live descendants so far (the
    planner process, the forkserver: ``/proc/PID/stat``)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except FileNotFoundError:
        return 0.0
    own = (int(fields[11]) + int(fields[12])) / TICKS
    children: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        children.extend(int(c) for c in task.read_text().split())
    return own + sum(cpu_seconds(child) for child in children)


def own_cpu() -> float:
    """User + system CPU seconds of this process so far (every thread: the engine, the units,
    the clients and the watch)."""
    times = os.times()
    return times.user + times.system


def thread_cpu(pid: int) -> dict[int, float]:
    """User + system CPU seconds of each thread of process ``pid`` so far, by thread id."""
    out: dict[int, float] = {}
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError):
            continue
        out[int(task.name)] = (int(fields[11]) + int(fields[12])) / TICKS
    return out


def thread_names(pid: int) -> dict[int, str]:
    """Thread id -> Python thread name (``py-spy dump``; empty without py-spy). A random
    suffix (paho's client id) is cut, so that runs compare."""
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(spy).exists():
        return {}
    try:
        dump = subprocess.run([spy, "dump", "--pid", str(pid), "--nonblocking"],
                              capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.TimeoutExpired):
        return {}
    return {int(tid): re.sub(r"-[0-9a-f]{8}$", "", name)
            for tid, name in re.findall(r'^Thread (\d+) \([^)]*\): "([^"]*)"', dump, re.M)}


def per_thread(names: dict[int, str], before: dict[int, float], after: dict[int, float],
               missions: int) -> str:
    """``name ms/mission`` of each named thread between two `thread_cpu` readings (the
    threads py-spy did not name counted together as ``other``)."""
    spent: Counter[str] = Counter()
    for tid, cpu in after.items():
        spent[names.get(tid, "other")] += cpu - before.get(tid, 0.0)
    return ", ".join(f"{name} {seconds * 1000 / missions:.1f}"
                     for name, seconds in spent.most_common())


class Watch:
    """Every answer (by com-uuid, with its arrival time) and every mission's final status."""

    def __init__(self, settings: BrokerSettings, base: str, clients: list[str]) -> None:
        self.answers: dict[str, list[tuple[float, str]]] = {}
        self.misrouted = 0
        self.root_of: dict[str, str] = {}
        self.final: dict[str, str] = {}
        self.beats = 0
        self.cond = threading.Condition()
        self.client = MqttClient(settings, f"burst-watch-{uuid.uuid4().hex[:6]}", sink=self._sink)
        self.client.subscribe(f"{base}/delegation/response/#")
        self.client.subscribe(f"{base}/delegation/response")
        self.client.subscribe(f"{base}/delegation/feedback")
        self.client.subscribe(f"{base}/heartbeat")
        self.owner: dict[str, str] = {}  # com-uuid -> the client that sent it

    def _sink(self, msg: Message) -> None:
        at = time.monotonic()
        data = json.loads(msg.payload)
        with self.cond:
            if msg.topic.endswith("/heartbeat"):
                self.beats += 1
            elif "/delegation/response" in msg.topic:
                com = str(data.get("response-to", ""))
                client = msg.topic.rsplit("/", 1)[1]
                if self.owner.get(com) != client:
                    self.misrouted += 1
                self.answers.setdefault(com, []).append((at, str(data.get("response", ""))))
                plan = data.get("plan") or {}
                root = (plan.get("tst") or {}).get("common_params", {}).get("node-uuid")
                if root:
                    self.root_of[com] = root
            elif data.get("status") in FINAL:
                self.final[data["root-uuid"]] = data["status"]
            self.cond.notify_all()

    def wait(self, predicate: Any, timeout: float) -> bool:
        with self.cond:
            return self.cond.wait_for(predicate, timeout)


def tree(rng: random.Random, span: float) -> dict[str, Any]:
    """2-5 move-tos near the fleet under a ``conc`` or ``seq``."""
    def move() -> dict[str, Any]:
        x, y = rng.uniform(0, span), rng.uniform(-100, 100)
        return {"name": "move-to", "params": {"waypoint": FRAME.geopoint(x, y, 30).to_wire()}}

    return {"name": rng.choice(["conc", "seq"]),
            "children": [move() for _ in range(rng.randint(2, 5))]}


def start_service(settings: BrokerSettings, tmp: Path, planner: str
                  ) -> subprocess.Popen[bytes]:
    log = (tmp / "serve.log").open("w")
    return subprocess.Popen(
        [sys.executable, "-m", "delegation", "serve", "--broker", settings.host, "--port",
         str(settings.port), "--prefix", PREFIX, "--name", NAME, "--state",
         str(tmp / "state.sqlite"), "--planner", planner],
        stdout=log, stderr=subprocess.STDOUT)


def plans_made(log: Path, missions: int) -> str:
    """How many plans the service made (its ``planned:`` and ``planned again:`` log lines):
    more than one per mission when a start plan is made again around a unit that got busy
    meanwhile."""
    try:
        plans = sum(" planned: " in line or " planned again: " in line
                    for line in log.read_text().splitlines())
    except FileNotFoundError:
        return "plans: no service log"
    return f"plans: {plans} for {missions} missions ({plans / max(1, missions):.2f} per mission)"


def profiler(pid: int, out: str, gil: bool = False) -> subprocess.Popen[bytes] | None:
    """``py-spy record`` on ``pid`` until stopped with SIGINT (None if py-spy is missing); with
    ``gil`` only the thread holding the GIL is sampled (where the CPU goes, not where threads
    wait for it)."""
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(spy).exists():
        print("no py-spy: not profiling", file=sys.stderr)
        return None
    return subprocess.Popen([spy, "record", "--pid", str(pid), "--format", "raw", "-o", out,
                             "--rate", "200", "--nonblocking", "--threads",
                             *(["--gil"] if gil else [])],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def publish_burst(settings: BrokerSettings, base: str, watch: Watch, bodies: list[list[dict[str,
                  Any]]]) -> dict[str, float]:
    """Each client publishes its bodies at once from its own thread; returns com -> sent at."""
    sent: dict[str, float] = {}
    lock = threading.Lock()
    clients = [MqttClient(settings, f"burst-c{i}-{uuid.uuid4().hex[:4]}")
               for i in range(len(bodies))]
    for c in clients:
        c.connect()
    go = threading.Event()

    def run(i: int) -> None:
        go.wait()
        topic = f"{base}/delegation/command/client{i}"
        for body in bodies[i]:
            at = time.monotonic()
            clients[i].publish(topic, json.dumps(body).encode(), qos=1)
            with lock:
                sent[body["com-uuid"]] = at

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(bodies))]
    for t in threads:
        t.start()
    go.set()
    for t in threads:
        t.join()
    watch.wait(lambda: all(c in watch.answers for c in sent), 600)
    for c in clients:
        c.disconnect()
    return sent


def report(args: argparse.Namespace, watch: Watch, sent: dict[str, float], cpu: dict[str, float],
           t0: float) -> bool:
    with watch.cond:
        firsts = {c: a[0][0] for c, a in watch.answers.items() if c in sent}
        counts = Counter(len(watch.answers.get(c, [])) for c in sent)
        kinds = Counter(watch.answers[c][0][1] for c in firsts)
        ended = Counter(watch.final.get(watch.root_of.get(c, ""), "not ended") for c in sent)
        misrouted = watch.misrouted
    lat = sorted(firsts[c] - sent[c] for c in firsts)
    n = len(sent)
    span = max(firsts.values()) - t0 if firsts else float("nan")
    print(f"burst: {n} missions from {args.clients} clients, {args.units} units "
          f"(speed-up {args.speedup:g}), seed {args.seed}")
    if lat:
        p99 = lat[min(len(lat) - 1, int(0.99 * len(lat)))]
        print(f"answers: {len(firsts) / span:.1f} answers/s ({len(firsts)} in {span:.2f} s); "
              f"send -> answer p50 {statistics.median(lat):.2f} s, p99 {p99:.2f} s, "
              f"max {lat[-1]:.2f} s")
    print(f"service CPU: {cpu['answers'] * 1000 / n:.1f} ms/mission up to the last answer "
          f"({cpu['answers']:.2f} s), {cpu['end'] * 1000 / n:.1f} ms/mission to the end of the "
          f"run ({cpu['end']:.2f} s), {cpu['end_net'] * 1000 / n:.1f} ms/mission to the end "
          f"without the idle service's {cpu['idle'] * 1000:.0f} ms/s (the fleet's periodic "
          f"messages)")
    total = cpu["answers"] + cpu["bench"] + cpu["broker"]
    print(f"machine CPU up to the last answer: service {cpu['answers'] * 1000 / n:.1f}, this "
          f"process (engine, {args.units} units, clients) {cpu['bench'] * 1000 / n:.1f}, "
          f"mosquitto {cpu['broker'] * 1000 / n:.1f} ms/mission; {total * 1000 / n:.1f} "
          f"ms/mission in all: {os.cpu_count()} cores busy all the time give at most "
          f"{(os.cpu_count() or 1) * n / total:.0f} answers/s")
    once = counts.get(1, 0)
    print(f"answered exactly once: {once}/{n}; never {counts.get(0, 0)}, more than once "
          f"{sum(v for k, v in counts.items() if k > 1)}; on another client's topic {misrouted}; "
          f"responses {dict(kinds)}")
    print(f"missions: {dict(ended)}")
    return once == n and misrouted == 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--missions", type=int, default=500)
    ap.add_argument("--clients", type=int, default=5)
    ap.add_argument("--units", type=int, default=15)
    ap.add_argument("--speedup", type=float, default=50.0)
    ap.add_argument("--settle", type=float, default=120.0,
                    help="seconds after the last answer to wait for the missions to end")
    ap.add_argument("--idle", type=float, default=3.0,
                    help="seconds of the idle service measured before the burst")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--planner", choices=("process", "thread"), default="process",
                    help="serve --planner: plans in a child process (default) or on a thread")
    ap.add_argument("--profile", metavar="OUT", help="py-spy raw profile of the service")
    ap.add_argument("--profile-until", choices=("answers", "end"), default="end",
                    help="profile the burst up to the last answer, or to the end of the run")
    ap.add_argument("--profile-gil", action="store_true",
                    help="profile only the thread holding the GIL (py-spy --gil)")
    args = ap.parse_args(argv)
    rng = random.Random(args.seed)
    config = ServiceConfig(prefix=PREFIX, name=NAME)
    base = config.base_topic
    units = [make_unit(f"v{i:02d}", "air", FRAME.geopoint(80 * i, 0, 30), ["move-to"],
                       speeds={"slow": 4.0, "standard": 8.0, "fast": 14.0})
             for i in range(args.units)]
    bodies: list[list[dict[str, Any]]] = [[] for _ in range(args.clients)]
    for i in range(args.missions):
        bodies[i % args.clients].append({"com-uuid": str(uuid.uuid4()), "command": "delegate",
                                         "start": True, "tst": tree(rng, 80 * args.units)})
    tmp = Path(tempfile.mkdtemp(prefix="burst-"))
    with PrivateMosquitto() as broker:
        settings = broker.settings()
        watch = Watch(settings, base, [f"client{i}" for i in range(args.clients)])
        watch.owner = {b["com-uuid"]: f"client{i}" for i, bs in enumerate(bodies) for b in bs}
        watch.client.connect()
        system = LocalSystem(units, settings=settings, config=config, service=False,
                             speedup=args.speedup, rates={u.name: 2.0 for u in units})
        system.start()
        proc = start_service(settings, tmp, args.planner)
        spy: subprocess.Popen[bytes] | None = None
        try:
            if not watch.wait(lambda: watch.beats >= 3, 30):
                raise SystemExit(f"the service did not start (see {tmp}/serve.log)")
            idle0, i0 = cpu_seconds(proc.pid), time.monotonic()
            watch.wait(lambda: False, args.idle)  # the fleet's periodic messages alone
            idle = (cpu_seconds(proc.pid) - idle0) / (time.monotonic() - i0)
            names = thread_names(proc.pid)
            if args.profile:
                spy = profiler(proc.pid, args.profile, args.profile_gil)
            threads0 = thread_cpu(proc.pid)
            cpu0, t0 = cpu_seconds(proc.pid), time.monotonic()
            others0 = own_cpu(), cpu_seconds(broker.pid or 0)
            sent = publish_burst(settings, base, watch, bodies)
            cpu = {"answers": cpu_seconds(proc.pid) - cpu0, "idle": idle,
                   "bench": own_cpu() - others0[0],
                   "broker": cpu_seconds(broker.pid or 0) - others0[1]}
            threads = per_thread(names, threads0, thread_cpu(proc.pid), len(sent)) \
                if names else ""
            if spy is not None and args.profile_until == "answers":
                spy.send_signal(2)
                spy.wait(30)
                spy = None
            watch.wait(lambda: all(watch.root_of.get(c) in watch.final for c in sent
                                   if watch.answers.get(c, [(0, "")])[0][1] == "started"),
                       args.settle)
            cpu["end"] = cpu_seconds(proc.pid) - cpu0
            cpu["end_net"] = cpu["end"] - idle * (time.monotonic() - t0)
            if spy is not None:
                spy.send_signal(2)
                spy.wait(30)
                spy = None
            watch.wait(lambda: False, 1.0)  # late duplicates would come within a moment
        finally:
            if spy is not None:
                spy.kill()
                spy.wait()
            proc.terminate()
            proc.wait(20)
            system.stop()
            watch.client.disconnect()
    ok = report(args, watch, sent, cpu, t0)
    if threads:
        print(f"service threads, CPU ms/mission up to the last answer: {threads}")
    print(plans_made(tmp / "serve.log", len(sent)))
    shutil.rmtree(tmp, ignore_errors=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
