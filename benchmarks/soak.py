"""Soak: many missions through one running service; its memory must stay flat and every command
must be answered exactly once (prints the figures).

Set-up: a private mosquitto; the simulated fleet and the reference engine in this process
(`LocalSystem`, ``service=False``); the service as ``python -m delegation serve`` in a subprocess
with an SQLite state file and a short ``--retention``, so its RSS (``VmRSS`` of
``/proc/PID/status``) is the service's alone. Missions: ``delegate`` with ``start`` of a 1-2 task
tree (short move-tos near the units, high speed-up), ``--window`` missions in flight at a time; a
mission counts as done at its final ``delegation/feedback``.

Printed: RSS at start, after the warm-up, at the end, and the slope after the warm-up (kB per
mission); answers received, commands answered more than once, commands never answered; final
statuses.

    .venv/bin/python benchmarks/soak.py [--missions 2000] [--warmup 1000] [--units 8]
"""

from __future__ import annotations

import argparse
import json
import random
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
from delegation.service import ServiceConfig

PREFIX = "soak"
FRAME = LocalFrame(57.7605, 16.6815)
FINAL = {"succeeded", "failed", "aborted"}


def rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError("no VmRSS")


class Watch:
    """Answers and lifecycle events of the service, counted per com-uuid / root-uuid."""

    def __init__(self, client_settings: Any, base: str) -> None:
        self.base = base
        self.answers: Counter[str] = Counter()
        self.answer_kind: dict[str, str] = {}
        self.final: dict[str, str] = {}
        self.reasons: Counter[str] = Counter()
        self.root_of: dict[str, str] = {}
        self.beats = 0
        self.cond = threading.Condition()
        self.client = MqttClient(client_settings, f"soak-{uuid.uuid4().hex[:6]}", sink=self._sink)
        for rest in ("delegation/response", "delegation/feedback", "heartbeat"):
            self.client.subscribe(f"{base}/{rest}")

    def _sink(self, msg: Message) -> None:
        data = json.loads(msg.payload)
        with self.cond:
            if msg.topic.endswith("/heartbeat"):
                self.beats += 1
            elif msg.topic.endswith("/delegation/response"):
                com = data.get("response-to", "")
                self.answers[com] += 1
                self.answer_kind[com] = data.get("response", "")
                plan = data.get("plan") or {}
                root = (plan.get("tst") or {}).get("common_params", {}).get("node-uuid")
                if data.get("response") == "failed":  # refused or infeasible: nothing will run
                    root = f"refused:{com}"
                    self.final[root] = "refused"
                if root:
                    self.root_of[com] = root
            elif data.get("status") in FINAL:
                self.final[data["root-uuid"]] = data["status"]
                if data.get("fail-reason"):
                    self.reasons[_shape(data["fail-reason"])] += 1
            self.cond.notify_all()

    def done(self, com: str) -> bool:
        root = self.root_of.get(com)
        return root is not None and root in self.final

    def wait(self, predicate: Any, timeout: float) -> bool:
        with self.cond:
            return self.cond.wait_for(predicate, timeout)


def _shape(reason: str) -> str:
    """A fail-reason without its uuids (to count the kinds)."""
    return " ".join("<id>" if len(w) > 30 or w.count("-") >= 4 else w
                    for w in reason.split())[:160]


def tree(rng: random.Random, units: int) -> dict[str, Any]:
    def move() -> dict[str, Any]:
        x, y = rng.uniform(-60, 60 * units), rng.uniform(-60, 60)
        return {"name": "move-to", "params": {"waypoint": FRAME.geopoint(x, y, 30).to_wire()}}

    if rng.random() < 0.5:
        return move()
    return {"name": rng.choice(["conc", "seq"]), "children": [move(), move()]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--missions", type=int, default=2000)
    ap.add_argument("--warmup", type=int, default=1000,
                    help="missions before the RSS baseline (the service keeps the latest 1000 "
                    "answers in memory: its caches are full by then)")
    ap.add_argument("--units", type=int, default=8)
    ap.add_argument("--window", type=int, default=8, help="missions in flight at once")
    ap.add_argument("--speedup", type=float, default=100.0)
    ap.add_argument("--retention", type=float, default=5.0)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    rng = random.Random(args.seed)

    broker = PrivateMosquitto().start()
    settings = broker.settings()
    name = "soak0"
    config = ServiceConfig(prefix=PREFIX, name=name)
    units = [make_unit(f"u{i}", "air", FRAME.geopoint(60 * i, 0, 30), ["move-to"],
                       speeds={"slow": 4.0, "standard": 8.0, "fast": 14.0})
             for i in range(args.units)]
    tmp = Path(tempfile.mkdtemp(prefix="soak-"))
    log = (tmp / "serve.log").open("w")
    watch = Watch(settings, config.base_topic)
    watch.client.connect()
    system = LocalSystem(units, settings=settings, config=config, service=False,
                         speedup=args.speedup, rates={u.name: 2.0 for u in units})
    system.start()
    proc = subprocess.Popen(
        [sys.executable, "-m", "delegation", "serve", "--broker", settings.host, "--port",
         str(settings.port), "--prefix", PREFIX, "--name", name, "--state",
         str(tmp / "state.sqlite"), "--retention", str(args.retention)],
        stdout=log, stderr=subprocess.STDOUT)
    samples: list[tuple[int, int]] = []
    sent: list[str] = []
    t0 = time.monotonic()
    try:
        if not watch.wait(lambda: watch.beats >= 3, 30):
            raise SystemExit("the service did not start (see serve.log in " + str(tmp) + ")")
        samples.append((0, rss_kb(proc.pid)))
        for i in range(args.missions):
            com = str(uuid.uuid4())
            if not watch.wait(lambda: sum(1 for c in sent[-args.window * 4:]
                                          if not watch.done(c)) < args.window, 60):
                raise SystemExit(f"missions stuck at {i} (in flight: window full for 60 s)")
            sent.append(com)
            body = {"com-uuid": com, "command": "delegate", "start": True,
                    "tst": tree(rng, args.units)}
            watch.client.publish(f"{config.base_topic}/delegation/command",
                                 json.dumps(body).encode(), qos=1)
            if (i + 1) % 100 == 0:
                samples.append((i + 1, rss_kb(proc.pid)))
        watch.wait(lambda: all(watch.done(c) for c in sent), 120)
        # Late duplicates would come within a moment of the last answer.
        watch.wait(lambda: False, 2.0)
        samples.append((args.missions, rss_kb(proc.pid)))
    finally:
        proc.terminate()
        proc.wait(20)
        system.stop()
        watch.client.disconnect()
        broker.stop()
        log.close()
    wall = time.monotonic() - t0
    with watch.cond:
        answered = [c for c in sent if watch.answers[c] >= 1]
        dupes = [c for c in sent if watch.answers[c] > 1]
        kinds = Counter(watch.answer_kind.get(c, "none") for c in sent)
        finals = Counter(watch.final.get(watch.root_of.get(c, ""), "not ended") for c in sent)
        total_answers = sum(watch.answers[c] for c in sent)
    start_kb = samples[0][1]
    warm = next(kb for n, kb in samples if n >= args.warmup)
    end_kb = samples[-1][1]
    slope = (end_kb - warm) / max(1, args.missions - args.warmup)
    half = next(kb for n, kb in samples if n >= args.missions // 2)
    slope2 = (end_kb - half) / max(1, args.missions - args.missions // 2)
    print(f"soak: {args.missions} missions ({args.units} units, window {args.window}, speed-up "
          f"{args.speedup:g}, retention {args.retention:g} s) in {wall:.1f} s")
    print(f"service RSS: start {start_kb / 1024:.1f} MB, after {args.warmup} (warm-up) "
          f"{warm / 1024:.1f} MB, end {end_kb / 1024:.1f} MB; after warm-up "
          f"{slope:+.2f} kB/mission, second half {slope2:+.2f} kB/mission "
          f"(max {max(kb for _, kb in samples) / 1024:.1f} MB)")
    print("RSS every 100 missions (MB): "
          + " ".join(f"{kb / 1024:.1f}" for _, kb in samples))
    print(f"answers: {total_answers} for {len(sent)} commands; answered {len(answered)}, "
          f"more than once {len(dupes)}, never {len(sent) - len(answered)}; "
          f"responses {dict(kinds)}")
    print(f"missions: {dict(finals)}")
    for reason, n in watch.reasons.most_common(5):
        print(f"  {n} x {reason}")
    ok = not dupes and len(answered) == len(sent)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
