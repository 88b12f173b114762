"""Throughput of `delegation bridge` (prints the figures; issue 24's target: 2,000 msg/s, the
heartbeats and sensors of 100 units at 10 Hz, without loss or growing memory).

Set-up: a private mosquitto; ``delegation bridge`` as a child process (its own ROS 2 participant)
on the loopback-only Fast DDS profile in a random domain; in this process a publisher on one side
and a counting subscriber on the other (our own clients: `Ros2Client`, `MqttClient`).

``--direction ros2mqtt`` (default; ROS 2 robots seen on MQTT): units publish ``heartbeat`` and
``sensor/position`` on ROS 2, counted on MQTT. ``mqtt2ros``: the other way. First a warm-up
(every topic at 1 Hz until each one has arrived: discovery), then ``--seconds`` at the full rate,
every message numbered; then a drain of 3 s. Loss = numbered messages sent - received. Memory:
the bridge's VmRSS at the start and end of the measured phase, and its peak (VmHWM).

    python benchmarks/bridge.py [--units 100] [--rate 10] [--seconds 20] [--direction ...]
"""

from __future__ import annotations

import argparse
import json
import os
import random
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


def _payload(unit: str, suffix: str, seq: int) -> str:
    if suffix == "heartbeat":
        return json.dumps({"agent-type": "air", "agent-uuid": f"uuid-{unit}", "levels": ["sensor"],
                           "name": unit, "rate": 10.0, "stamp": time.time(), "type": "HeartBeat",
                           "seq": seq})
    return json.dumps({"latitude": 57.76, "longitude": 16.68, "altitude": 20.0,
                       "rostype": "GeoPoint", "seq": seq})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--units", type=int, default=100)
    parser.add_argument("--rate", type=float, default=10.0, help="Hz per unit and topic pair")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--direction", choices=("ros2mqtt", "mqtt2ros"), default="ros2mqtt")
    args = parser.parse_args(argv)
    os.environ.setdefault("FASTDDS_DEFAULT_PROFILES_FILE",
                          str(ROOT / "deploy" / "ros2" / "fastdds-loopback.xml"))
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 200)))
    broker = PrivateMosquitto().start()
    mqtt = broker.settings()
    ros = BrokerSettings(transport="ros2")
    source, sink_side = (ros, mqtt) if args.direction == "ros2mqtt" else (mqtt, ros)
    units = [f"b{i}" for i in range(args.units)]
    topics = [f"waraps/unit/air/real/{u}/{s}" for u in units for s in SUFFIXES]

    got: dict[str, set[int]] = {}
    lock = threading.Lock()

    def count(msg: Message) -> None:
        try:
            seq = json.loads(msg.payload).get("seq")
        except ValueError:
            return
        name = msg.topic.split("/")[4]
        suffix = "/".join(msg.topic.split("/")[5:])
        with lock:
            got.setdefault(f"{name}/{suffix}", set()).add(seq)

    receiver = make_client(sink_side, "bench-receiver", sink=count)
    receiver.subscribe("waraps/unit/+/+/+/#")
    sender = make_client(source, "bench-sender")
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    bridge = subprocess.Popen(
        [sys.executable, "-m", "delegation", "bridge", "--broker", mqtt.host, "--port",
         str(mqtt.port), "--report", "5", "-v"], env=env, stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    log_lines: list[str] = []
    reader = threading.Thread(target=lambda: log_lines.extend(bridge.stdout or []), daemon=True)
    reader.start()
    try:
        receiver.connect()
        sender.connect()
        # Warm-up: every topic at 1 Hz (seq -1) until each arrived once (discovery done).
        deadline = time.monotonic() + 120
        while True:
            for topic in topics:
                unit, suffix = topic.split("/")[4], "/".join(topic.split("/")[5:])
                sender.publish(topic, _payload(unit, suffix, -1))
            time.sleep(1.0)
            with lock:
                ready = sum(1 for k in got if -1 in got[k])
            if ready == len(topics):
                break
            if time.monotonic() > deadline:
                print(f"warm-up: only {ready}/{len(topics)} topics arrived", file=sys.stderr)
                return 1
        with lock:
            got.clear()
        rss0 = _rss_kb(bridge.pid)
        period = 1.0 / args.rate
        sent = 0
        t0 = time.monotonic()
        seq = 0
        samples: list[tuple[float, int]] = []
        while time.monotonic() - t0 < args.seconds:
            if not samples or time.monotonic() - t0 >= samples[-1][0] + 10:
                samples.append((time.monotonic() - t0, _rss_kb(bridge.pid)))
            for topic in topics:
                unit, suffix = topic.split("/")[4], "/".join(topic.split("/")[5:])
                sender.publish(topic, _payload(unit, suffix, seq))
                sent += 1
            seq += 1
            time.sleep(max(0.0, t0 + seq * period - time.monotonic()))
        elapsed = time.monotonic() - t0
        rss1 = _rss_kb(bridge.pid)
        time.sleep(3.0)  # drain
        rss_peak = _rss_kb(bridge.pid, "VmHWM")
        with lock:
            received = sum(len(v) for v in got.values())
        print(f"bridge {args.direction}: {args.units} units x {len(SUFFIXES)} topics at "
              f"{args.rate:g} Hz for {elapsed:.1f} s")
        print(f"  offered {sent / elapsed:,.0f} msg/s: sent {sent}, received {received}, "
              f"lost {sent - received} ({100 * (sent - received) / max(1, sent):.2f} %)")
        print(f"  bridge RSS {rss0 / 1024:.1f} MiB at start, {rss1 / 1024:.1f} MiB at end, "
              f"peak {rss_peak / 1024:.1f} MiB; every 10 s: "
              + ", ".join(f"{kb / 1024:.1f}" for _, kb in samples))
        print("  (the bridge's counts below: forwarded vs sent locates a loss before or after "
              "it)")
        return 0
    finally:
        sender.disconnect()
        receiver.disconnect()
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
