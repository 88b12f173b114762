"""Throughput of `delegation bridge` (prints the figures; issue 24's target: 2,000 msg/s, the
heartbeats and sensors of 100 units at 10 Hz, without loss or growing memory).

Set-up: a private mosquitto; ``delegation bridge`` as a child process (its own ROS 2 participant)
on the loopback-only Fast DDS profile in a random domain; in this process a publisher on one side,
and a counting subscriber on the other side in a child process of its own (our own clients:
`Ros2Client`, `MqttClient`), so that the three share no interpreter.

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


def receive(side: str, port: int) -> int:
    """The counting subscriber (a child process): prints, every 0.5 s, how many topics have
    sent their warm-up message and how many numbered messages arrived, until terminated."""
    settings = BrokerSettings(transport="ros2") if side == "ros2" else \
        BrokerSettings(host="127.0.0.1", port=port)
    got: dict[str, set[int]] = {}
    lock = threading.Lock()

    def count(msg: Message) -> None:
        try:
            seq = json.loads(msg.payload).get("seq")
        except ValueError:
            return
        key = "/".join(msg.topic.split("/")[4:])
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--units", type=int, default=100)
    parser.add_argument("--rate", type=float, default=10.0, help="Hz per unit and topic pair")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--direction", choices=("ros2mqtt", "mqtt2ros"), default="ros2mqtt")
    parser.add_argument("--spread", action="store_true",
                        help="spread each round's messages over the period (20 at a time) "
                        "instead of one burst")
    parser.add_argument("--receive", choices=("ros2", "mqtt"), help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.receive:
        return receive(args.receive, args.port)
    os.environ.setdefault("FASTDDS_DEFAULT_PROFILES_FILE",
                          str(ROOT / "deploy" / "ros2" / "fastdds-loopback.xml"))
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 200)))
    broker = PrivateMosquitto().start()
    mqtt = broker.settings()
    ros = BrokerSettings(transport="ros2")
    source, sink_side = (ros, mqtt) if args.direction == "ros2mqtt" else (mqtt, ros)
    units = [f"b{i}" for i in range(args.units)]
    topics = [f"waraps/unit/air/real/{u}/{s}" for u in units for s in SUFFIXES]

    receiver = subprocess.Popen(
        [sys.executable, __file__, "--receive", "ros2" if sink_side is ros else "mqtt",
         "--port", str(mqtt.port)], env={**os.environ, "PYTHONPATH": str(ROOT / "src")},
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True)
    latest: dict[str, int] = {"ready": 0, "received": 0}

    def follow() -> None:
        for line in receiver.stdout or []:
            latest.update(json.loads(line))

    follower = threading.Thread(target=follow, daemon=True)
    follower.start()
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
        sender.connect()
        # Warm-up: every topic at 1 Hz (seq -1) until each arrived once (discovery done).
        deadline = time.monotonic() + 120
        while True:
            for topic in topics:
                unit, suffix = topic.split("/")[4], "/".join(topic.split("/")[5:])
                sender.publish(topic, _payload(unit, suffix, -1))
            time.sleep(1.0)
            ready = latest["ready"]
            if ready == len(topics):
                break
            if time.monotonic() > deadline:
                print(f"warm-up: only {ready}/{len(topics)} topics arrived", file=sys.stderr)
                return 1
        rss0, cpu0 = _rss_kb(bridge.pid), _cpu_s(bridge.pid)
        period = 1.0 / args.rate
        sent = 0
        t0 = time.monotonic()
        seq = 0
        samples: list[tuple[float, int]] = []
        while time.monotonic() - t0 < args.seconds:
            if not samples or time.monotonic() - t0 >= samples[-1][0] + 10:
                samples.append((time.monotonic() - t0, _rss_kb(bridge.pid)))
            for i, topic in enumerate(topics):
                unit, suffix = topic.split("/")[4], "/".join(topic.split("/")[5:])
                sender.publish(topic, _payload(unit, suffix, seq))
                sent += 1
                if args.spread and i % 20 == 19:  # units do not all publish at one instant
                    slot = t0 + (seq + (i + 1) / len(topics)) * period
                    time.sleep(max(0.0, slot - time.monotonic()))
            seq += 1
            time.sleep(max(0.0, t0 + seq * period - time.monotonic()))
        elapsed = time.monotonic() - t0
        rss1, cpu1 = _rss_kb(bridge.pid), _cpu_s(bridge.pid)
        time.sleep(3.0)  # drain
        rss_peak = _rss_kb(bridge.pid, "VmHWM")
        received = latest["received"]
        print(f"bridge {args.direction}: {args.units} units x {len(SUFFIXES)} topics at "
              f"{args.rate:g} Hz for {elapsed:.1f} s")
        print(f"  offered {sent / elapsed:,.0f} msg/s: sent {sent}, received {received}, "
              f"lost {sent - received} ({100 * (sent - received) / max(1, sent):.2f} %)")
        print(f"  bridge RSS {rss0 / 1024:.1f} MiB at start, {rss1 / 1024:.1f} MiB at end, "
              f"peak {rss_peak / 1024:.1f} MiB; every 10 s: "
              + ", ".join(f"{kb / 1024:.1f}" for _, kb in samples))
        print(f"  bridge CPU {cpu1 - cpu0:.1f} s in {elapsed:.1f} s "
              f"({100 * (cpu1 - cpu0) / elapsed:.0f} % of a core; "
              f"{1e6 * (cpu1 - cpu0) / max(1, sent):.0f} us per message offered)")
        print("  (the bridge's counts below: forwarded vs sent locates a loss before or after "
              "it)")
        return 0
    finally:
        sender.disconnect()
        receiver.terminate()
        receiver.wait(10)
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
