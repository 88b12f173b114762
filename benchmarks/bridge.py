"""Throughput of `delegation bridge` (prints the figures; issue 24's target: 2,000 msg/s, the
heartbeats and sensors of 100 units at 10 Hz, without loss or growing memory).

Set-up: a private mosquitto; ``delegation bridge`` as a child process (its own ROS 2 participant)
on the loopback-only Fast DDS profile in a random domain; in this process a publisher on one side,
and a counting subscriber on the other side in a child process of its own (our own clients:
`Ros2Client`, `MqttClient`), so that the three share no interpreter.

``--direction ros2mqtt`` (default; ROS 2 robots seen on MQTT): units publish ``heartbeat`` and
``sensor/position`` on ROS 2, counted on MQTT. ``mqtt2ros``: the other way. ``both``: both at
once, ``--units`` units on each side (units ``r*`` on ROS 2, ``m*`` on MQTT; each receiver counts
the other side's units only). First a warm-up (every topic at 1 Hz until each one has arrived:
discovery), then ``--seconds`` at the full rate, every message numbered; then a drain of 3 s.
Loss = numbered messages sent - received. Memory: the bridge's VmRSS every ``--sample`` seconds
of the measured phase and at its end, and its peak (VmHWM).

    python benchmarks/bridge.py [--units 100] [--rate 10] [--seconds 20] [--direction ...]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from delegation.runtime.broker import PrivateMosquitto
from delegation.runtime.mqtt import Message
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.transport import make_client

ROOT = Path(__file__).resolve().parent.parent
SUFFIXES = ("heartbeat", "sensor/position")


def _rss_kb(pid: int, field: str = "VmRSS") -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return 0


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _payload(unit: str, suffix: str, seq: int) -> str:
    if suffix == "heartbeat":
        return json.dumps({"agent-type": "air", "agent-uuid": f"uuid-{unit}", "levels": ["sensor"],
                           "name": unit, "rate": 10.0, "stamp": time.time(), "type": "HeartBeat",
                           "seq": seq})
    return json.dumps({"latitude": 57.76, "longitude": 16.68, "altitude": 20.0,
                       "rostype": "GeoPoint", "seq": seq})


def receive(side: str, port: int, names: str) -> int:
    """The counting subscriber (a child process): prints, every 0.5 s, how many topics of units
    whose names start with ``names`` have sent their warm-up message and how many numbered
    messages arrived, until terminated."""
    settings = BrokerSettings(transport="ros2") if side == "ros2" else \
        BrokerSettings(host="127.0.0.1", port=port)
    got: dict[str, set[int]] = {}
    lock = threading.Lock()

    def count(msg: Message) -> None:
        key = "/".join(msg.topic.split("/")[4:])
        if not key.startswith(names):
            return
        try:
            seq = json.loads(msg.payload).get("seq")
        except ValueError:
            return
        with lock:
            got.setdefault(key, set()).add(seq)

    client = make_client(settings, "bench-receiver", sink=count)
    client.subscribe("waraps/unit/+/+/+/#")
    client.connect()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.wait(0.5):
            with lock:
                ready = sum(1 for v in got.values() if -1 in v)
                received = sum(len(v - {-1}) for v in got.values())
            print(json.dumps({"ready": ready, "received": received}), flush=True)
    finally:
        client.disconnect()
    return 0


class _Flow:
    """One direction: units publishing on ``source``, counted by a receiver process on the other
    side."""

    def __init__(self, name: str, source: BrokerSettings, names: str, units: int, port: int,
                 env: dict[str, str]) -> None:
        self.name = name
        self.topics = [f"waraps/unit/air/real/{names}{i}/{s}" for i in range(units)
                       for s in SUFFIXES]
        self.sender = make_client(source, f"bench-sender-{names}")
        self.latest: dict[str, int] = {"ready": 0, "received": 0}
        self.sent = 0
        self.receiver = subprocess.Popen(
            [sys.executable, __file__, "--receive", "mqtt" if source.transport == "ros2"
             else "ros2", "--port", str(port), "--names", names], env=env,
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True)
        threading.Thread(target=self._follow, daemon=True).start()

    def _follow(self) -> None:
        for line in self.receiver.stdout or []:
            self.latest.update(json.loads(line))

    def publish_round(self, seq: int, spread_until: float | None = None,
                      period: float = 0.0) -> None:
        for i, topic in enumerate(self.topics):
            unit, suffix = topic.split("/")[4], "/".join(topic.split("/")[5:])
            self.sender.publish(topic, _payload(unit, suffix, seq))
            if seq >= 0:
                self.sent += 1
            if spread_until is not None and i % 20 == 19:  # units do not all publish at once
                slot = spread_until + (i + 1) / len(self.topics) * period
                time.sleep(max(0.0, slot - time.monotonic()))

    def run(self, t0: float, seconds: float, rate: float, spread: bool) -> None:
        """Numbered rounds at ``rate`` for ``seconds`` (a thread per direction)."""
        period, seq = 1.0 / rate, 0
        while time.monotonic() - t0 < seconds:
            self.publish_round(seq, t0 + seq * period if spread else None, period)
            seq += 1
            time.sleep(max(0.0, t0 + seq * period - time.monotonic()))

    def stop(self) -> None:
        self.sender.disconnect()
        self.receiver.terminate()
        self.receiver.wait(10)


def _warm_up(flows: list[_Flow]) -> bool:
    """Every topic at 1 Hz (seq -1) until each arrived once (discovery done)."""
    deadline = time.monotonic() + 120
    while True:
        for flow in flows:
            flow.publish_round(-1)
        time.sleep(1.0)
        if all(f.latest["ready"] == len(f.topics) for f in flows):
            return True
        if time.monotonic() > deadline:
            for f in flows:
                print(f"warm-up {f.name}: only {f.latest['ready']}/{len(f.topics)} topics "
                      "arrived", file=sys.stderr)
            return False


def _measure(flows: list[_Flow], pid: int, args: argparse.Namespace) -> None:
    rss0, cpu0 = _rss_kb(pid), _cpu_s(pid)
    t0 = time.monotonic()
    threads = [threading.Thread(target=f.run, args=(t0, args.seconds, args.rate, args.spread))
               for f in flows]
    for t in threads:
        t.start()
    samples: list[int] = []
    while any(t.is_alive() for t in threads):
        samples.append(_rss_kb(pid))
        for t in threads:
            t.join(max(0.0, t0 + len(samples) * args.sample - time.monotonic()))
    elapsed = time.monotonic() - t0
    rss1, cpu1 = _rss_kb(pid), _cpu_s(pid)
    time.sleep(3.0)  # drain
    rss_peak = _rss_kb(pid, "VmHWM")
    sent_all = sum(f.sent for f in flows)
    for f in flows:
        received = f.latest["received"]
        print(f"bridge {f.name}: {args.units} units x {len(SUFFIXES)} topics at "
              f"{args.rate:g} Hz for {elapsed:.1f} s")
        print(f"  offered {f.sent / elapsed:,.0f} msg/s: sent {f.sent}, received {received}, "
              f"lost {f.sent - received} ({100 * (f.sent - received) / max(1, f.sent):.2f} %)")
    print(f"  bridge RSS {rss0 / 1024:.1f} MiB at start, {rss1 / 1024:.1f} MiB at end, "
          f"peak {rss_peak / 1024:.1f} MiB; every {args.sample:g} s: "
          + ", ".join(f"{kb / 1024:.1f}" for kb in samples))
    print(f"  bridge CPU {cpu1 - cpu0:.1f} s in {elapsed:.1f} s "
          f"({100 * (cpu1 - cpu0) / elapsed:.0f} % of a core; "
          f"{1e6 * (cpu1 - cpu0) / max(1, sent_all):.0f} us per message offered)")
    print("  (the bridge's counts below: forwarded vs sent locates a loss before or after it)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--units", type=int, default=100)
    parser.add_argument("--rate", type=float, default=10.0, help="Hz per unit and topic pair")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--sample", type=float, default=10.0,
                        help="seconds between two looks at the bridge's RSS")
    parser.add_argument("--direction", choices=("ros2mqtt", "mqtt2ros", "both"),
                        default="ros2mqtt")
    parser.add_argument("--spread", action="store_true",
                        help="spread each round's messages over the period (20 at a time) "
                        "instead of one burst")
    parser.add_argument("--receive", choices=("ros2", "mqtt"), help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--names", default="", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.receive:
        return receive(args.receive, args.port, args.names)
    os.environ.setdefault("FASTDDS_DEFAULT_PROFILES_FILE",
                          str(ROOT / "deploy" / "ros2" / "fastdds-loopback.xml"))
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 200)))
    broker = PrivateMosquitto().start()
    mqtt, ros = broker.settings(), BrokerSettings(transport="ros2")
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    flows: list[_Flow] = []
    if args.direction in ("ros2mqtt", "both"):
        flows.append(_Flow("ros2mqtt", ros, "r" if args.direction == "both" else "b",
                           args.units, mqtt.port, env))
    if args.direction in ("mqtt2ros", "both"):
        flows.append(_Flow("mqtt2ros", mqtt, "m" if args.direction == "both" else "b",
                           args.units, mqtt.port, env))
    bridge = subprocess.Popen(
        [sys.executable, "-m", "delegation", "bridge", "--broker", mqtt.host, "--port",
         str(mqtt.port), "--report", "5", "-v"], env=env, stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    log_lines: list[str] = []
    reader = threading.Thread(target=lambda: log_lines.extend(bridge.stdout or []), daemon=True)
    reader.start()
    try:
        for flow in flows:
            flow.sender.connect()
        if not _warm_up(flows):
            return 1
        _measure(flows, bridge.pid, args)
        return 0
    finally:
        for flow in flows:
            flow.stop()
        bridge.terminate()
        try:
            bridge.wait(10)
        except subprocess.TimeoutExpired:
            bridge.kill()
            bridge.wait(10)
        reader.join(5)
        counts = [line.strip() for line in log_lines if "BridgeCounts" in line]
        if counts:
            print("  " + counts[-1].split("INFO ", 1)[-1])
        broker.stop()


if __name__ == "__main__":
    sys.exit(main())
