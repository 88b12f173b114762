"""`delegation bridge`: one ROS 2 domain and one MQTT broker as one WARA-PS world (DESIGN 3.12).

Every unit topic goes both ways: ``{prefix}/unit/{type}/{role}/{name}/{rest}`` on MQTT is
``/{name}/{prefix}/{rest}`` on ROS 2 (`delegation.ros_topics`). A ROS 2 unit appears on MQTT with
the type its heartbeat says and the role the bridge is given; a MQTT unit keeps its own type and
role (what the bridge publishes on ROS is remembered, so commands to it go back to its base).
One mission can then use ROS 2 robots and MQTT robots, with the service on either side.

No echo loops: what the bridge publishes on one side comes back to it there (it reads
everything); such a message (same topic, same payload, within `ECHO_SECONDS`) is dropped once per
time it was sent. Bounded queues: each direction has its own queue of `QUEUE_MAX` messages and
its own thread (a new ROS writer may wait for its reader: that must not stall MQTT's network
thread); a full queue drops the message and counts it.
"""

from __future__ import annotations

import collections
import hashlib
import logging
import queue
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass

from delegation.messages.ros_text import json_text
from delegation.ros_topics import UNKNOWN_TYPE, ros_topic
from delegation.runtime.lifecycle import StartStop
from delegation.runtime.mqtt import Message, MqttError
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.transport import MessageClient, make_client
from delegation.topics import DEFAULT_PREFIX, QOS_COMMAND, parse_unit_topic, unit_filter

log = logging.getLogger(__name__)

__all__ = ["Bridge", "BridgeCounts"]

#: Messages waiting per direction; past it a message is dropped (and counted).
QUEUE_MAX = 10_000
#: How long a message the bridge sent is recognised when it comes back (seconds).
ECHO_SECONDS = 10.0


@dataclass
class BridgeCounts:
    """What went through, per direction: forwarded, echoes dropped, dropped on a full queue,
    held back (a ROS unit whose type no heartbeat said yet), failed to publish."""

    to_mqtt: int = 0
    to_ros: int = 0
    echoes: int = 0
    full: int = 0
    untyped: int = 0
    failed: int = 0


class _Echoes:
    """Messages sent to one side, recognised once each when they come back."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counts: dict[tuple[str, bytes], int] = {}
        self._order: collections.deque[tuple[float, tuple[str, bytes]]] = collections.deque()

    @staticmethod
    def _key(topic: str, text: str) -> tuple[str, bytes]:
        return topic, hashlib.blake2b(text.encode("utf-8", "replace"), digest_size=16).digest()

    def sent(self, topic: str, text: str, now: float) -> None:
        key = self._key(topic, text)
        with self._lock:
            self._expire(now)
            self._counts[key] = self._counts.get(key, 0) + 1
            self._order.append((now, key))

    def is_echo(self, topic: str, text: str, now: float) -> bool:
        key = self._key(topic, text)
        with self._lock:
            self._expire(now)
            count = self._counts.get(key, 0)
            if count <= 0:
                return False
            self._counts[key] = count - 1
            return True

    def _expire(self, now: float) -> None:
        while self._order and (now - self._order[0][0] > ECHO_SECONDS
                               or len(self._order) > 4 * QUEUE_MAX):
            _, key = self._order.popleft()
            left = self._counts.get(key, 0) - 1
            if left > 0:
                self._counts[key] = left
            else:
                self._counts.pop(key, None)

    def __len__(self) -> int:
        with self._lock:
            return len(self._order)


class Bridge(StartStop):
    """A ROS 2 domain and an MQTT broker, both ways (see the module's docstring)."""

    def __init__(
        self,
        mqtt: BrokerSettings,
        *,
        prefix: str = DEFAULT_PREFIX,
        role: str = "real",
        agent_type: str | None = None,
        units: Collection[str] = (),
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """``role``: the role ROS 2 units get on MQTT; ``agent_type``: the type of a ROS 2 unit
        before its heartbeat said one (None: its messages wait for the heartbeat); ``units``:
        bridge only these (every unit when empty)."""
        self.prefix, self.role, self.agent_type = prefix, role, agent_type
        self.units = frozenset(units)
        self.clock = clock
        self.counts = BridgeCounts()
        self._queues: dict[str, queue.Queue[Message | None]] = {
            "mqtt": queue.Queue(QUEUE_MAX), "ros": queue.Queue(QUEUE_MAX)}
        self._echo = {"mqtt": _Echoes(), "ros": _Echoes()}
        self.mqtt: MessageClient = make_client(
            mqtt.model_copy(update={"transport": "mqtt"}), sink=lambda m: self._take("ros", m))
        self.ros: MessageClient = make_client(
            BrokerSettings(transport="ros2"), sink=lambda m: self._take("mqtt", m))
        names = getattr(self.ros, "names", None)
        if names is not None:
            names.default_role = role
        self._threads: list[threading.Thread] = []

    # ---- lifecycle

    def start(self, timeout: float = 10.0) -> Bridge:
        everything = unit_filter(self.prefix, "#")
        self.mqtt.subscribe(everything, QOS_COMMAND)
        self.ros.subscribe(everything, QOS_COMMAND)
        # Both sides joined before anything is forwarded: what arrives meanwhile waits queued.
        self.mqtt.connect(timeout)
        self.ros.connect(timeout)
        for side in ("mqtt", "ros"):
            thread = threading.Thread(target=self._forward, args=(side,), daemon=True,
                                      name=f"bridge-to-{side}")
            thread.start()
            self._threads.append(thread)
        log.info("bridging ROS 2 and MQTT under %s/ (ROS 2 units as role %s)", self.prefix,
                 self.role)
        return self

    def stop(self) -> None:
        for q in self._queues.values():
            try:
                q.put(None, timeout=1.0)
            except queue.Full:
                log.warning("bridge queue full at stop: its messages are dropped")
        for thread in self._threads:
            thread.join(5.0)
        self._threads.clear()
        self.mqtt.disconnect()
        self.ros.disconnect()

    def queued(self) -> dict[str, int]:
        """Messages waiting per direction (memory stays bounded by `QUEUE_MAX` each)."""
        return {side: q.qsize() for side, q in self._queues.items()}

    # ---- receiving (each client's thread: check and queue only)

    def _take(self, to: str, msg: Message) -> None:
        """A message from the side other than ``to``: an echo of ours is dropped, the rest
        queued for ``to``."""
        source = "ros" if to == "mqtt" else "mqtt"
        text = msg.text
        if self._echo[source].is_echo(self._echo_topic(source, msg.topic), text, self.clock()):
            self.counts.echoes += 1
            return
        parsed = parse_unit_topic(msg.topic)
        if parsed is None or (self.units and parsed.name not in self.units):
            return
        try:
            self._queues[to].put_nowait(msg)
        except queue.Full:
            self.counts.full += 1
            if self.counts.full in (1, 100) or self.counts.full % 10_000 == 0:
                log.warning("bridge: the queue to %s is full: %d messages dropped", to,
                            self.counts.full)

    @staticmethod
    def _echo_topic(side: str, topic: str) -> str:
        """What identifies a topic on ``side``: on ROS 2 only the ROS name is sure (the type and
        role the client gives it may be learned later)."""
        return ros_topic(topic) if side == "ros" else topic

    # ---- forwarding (one thread per direction)

    def _forward(self, to: str) -> None:
        q = self._queues[to]
        while True:
            msg = q.get()
            if msg is None:
                return
            try:
                self._send(to, msg)
            except MqttError as exc:
                self.counts.failed += 1
                log.warning("bridge: to %s: %s", to, exc)
            except Exception:
                self.counts.failed += 1
                log.exception("bridge: forwarding %s to %s failed", msg.topic[:200], to)

    def _send(self, to: str, msg: Message) -> None:
        topic, text = msg.topic, msg.text
        if to == "mqtt":
            parsed = parse_unit_topic(topic)
            if parsed is not None and parsed.agent_type == UNKNOWN_TYPE:
                if self.agent_type is None:
                    self.counts.untyped += 1
                    return
                topic = topic.replace(f"/unit/{UNKNOWN_TYPE}/", f"/unit/{self.agent_type}/", 1)
            self._echo["mqtt"].sent(topic, text, self.clock())
            self.mqtt.publish(topic, msg.payload, qos=msg.qos)
            self.counts.to_mqtt += 1
        else:
            self._echo["ros"].sent(ros_topic(topic), json_text(text), self.clock())
            self.ros.publish(topic, msg.payload, qos=msg.qos)
            self.counts.to_ros += 1
