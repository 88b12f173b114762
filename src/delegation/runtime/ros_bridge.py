"""`delegation bridge`: one ROS 2 domain and one MQTT broker as one WARA-PS world (DESIGN 3.12).

Every unit topic goes both ways: ``{prefix}/unit/{type}/{role}/{name}/{rest}`` on MQTT is
``/{name}/{prefix}/{rest}`` on ROS 2 (`delegation.ros_topics`). A ROS 2 unit appears on MQTT with
the type its heartbeat says and the role the bridge is given; a MQTT unit keeps its own type and
role (what the bridge publishes on ROS is remembered, so commands to it go back to its base).
One mission can then use ROS 2 robots and MQTT robots, with the service on either side.

No echo loops: what the bridge publishes on one side would come back to it there (it reads
everything). On MQTT 5 it subscribes with "No Local", so the broker never sends its own messages
back; on ROS 2 it does not read a topic that only it writes (the topics of MQTT units: the ROS
graph's publisher count says so, looked at with every discovery). Where that is not enough (a
3.1.1 broker; a ROS topic someone else writes too), such a message (same topic, same payload,
within `ECHO_SECONDS`) is dropped once per time it was sent (`_Echoes`).

What it checks: a unit topic under the prefix (and of a unit in ``units`` when given), a payload
of at most `MAX_PAYLOAD` bytes (larger is refused and counted: no reader accepts it on either
side), and, from ROS 2, the text made JSON as every ROS 2 reader does (`delegation.messages.
ros_text`). The JSON itself is not parsed again: the receiving reader checks it strictly, as on
MQTT, and answers a malformed command with its fail-reason, which the bridge carries back.

Bounded queues: each direction has its own outbox of `QUEUE_MAX` messages and its own thread (a
new ROS writer may wait for its reader: that must not stall MQTT's network thread); a full
outbox drops the message and counts it. The receiving thread only appends; the forwarding
thread drains everything waiting at each wake-up (one wake-up per burst, not per message).
"""

from __future__ import annotations

import collections
import hashlib
import logging
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass

from delegation.messages.ros_text import json_text
from delegation.ros_topics import UNKNOWN_TYPE, ros_topic
from delegation.runtime.lifecycle import StartStop
from delegation.runtime.mqtt import Message, MqttClient, MqttError
from delegation.runtime.settings import BrokerSettings
from delegation.topics import (
    DEFAULT_PREFIX,
    MAX_PAYLOAD,
    QOS_COMMAND,
    parse_unit_topic,
    unit_filter,
)

log = logging.getLogger(__name__)

__all__ = ["Bridge", "BridgeCounts"]

#: Messages waiting per direction; past it a message is dropped (and counted).
QUEUE_MAX = 10_000
#: How long a message the bridge sent is recognised when it comes back (seconds).
ECHO_SECONDS = 10.0
#: What a topic of a ROS 2 unit whose type no heartbeat said yet holds.
_UNTYPED = f"/unit/{UNKNOWN_TYPE}/"


@dataclass
class BridgeCounts:
    """What went through, per direction: forwarded, echoes dropped, dropped on a full queue,
    held back (a ROS unit whose type no heartbeat said yet), failed to publish, refused (over
    `MAX_PAYLOAD`)."""

    to_mqtt: int = 0
    to_ros: int = 0
    echoes: int = 0
    full: int = 0
    untyped: int = 0
    failed: int = 0
    refused: int = 0


class _Echoes:
    """Messages sent to one side, recognised once each when they come back."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counts: dict[tuple[str, bytes], int] = {}
        #: Messages pending per topic: a message on another topic is no echo, known unhashed.
        self._topics: collections.Counter[str] = collections.Counter()
        self._order: collections.deque[tuple[float, tuple[str, bytes]]] = collections.deque()
        #: Sendings whose echo came back but whose entry in ``_order`` has not expired yet.
        self._consumed: collections.Counter[tuple[str, bytes]] = collections.Counter()

    @staticmethod
    def _key(topic: str, data: str | bytes) -> tuple[str, bytes]:
        raw = data.encode("utf-8", "replace") if isinstance(data, str) else data
        return topic, hashlib.blake2b(raw, digest_size=16).digest()

    def sent(self, topic: str, data: str | bytes, now: float) -> None:
        key = self._key(topic, data)
        with self._lock:
            self._expire(now)
            self._counts[key] = self._counts.get(key, 0) + 1
            self._topics[topic] += 1
            self._order.append((now, key))

    def pending(self) -> bool:
        """Anything sent that may come back (read without the lock: a dict read is atomic)."""
        return bool(self._topics)

    def is_echo(self, topic: str, data: str | bytes, now: float) -> bool:
        with self._lock:
            self._expire(now)
            if topic not in self._topics:
                return False
            key = self._key(topic, data)
            count = self._counts.get(key, 0)
            if count <= 0:
                return False
            self._drop(key)
            self._consumed[key] += 1
            return True

    def _drop(self, key: tuple[str, bytes]) -> None:
        """One sending of ``key`` is accounted for (under the lock)."""
        left = self._counts.get(key, 0) - 1
        if left > 0:
            self._counts[key] = left
        else:
            self._counts.pop(key, None)
        topic = key[0]
        if self._topics[topic] > 1:
            self._topics[topic] -= 1
        else:
            del self._topics[topic]

    def _expire(self, now: float) -> None:
        while self._order and (now - self._order[0][0] > ECHO_SECONDS
                               or len(self._order) > 4 * QUEUE_MAX):
            _, key = self._order.popleft()
            if self._consumed[key] > 0:  # its echo came back (echoes come back in order)
                self._consumed[key] -= 1
                if not self._consumed[key]:
                    del self._consumed[key]
            else:
                self._drop(key)

    def __len__(self) -> int:
        with self._lock:
            return len(self._order)


class _Outbox:
    """One direction's bounded FIFO: the receiving client's thread appends, the forwarding
    thread drains. The event is set only when the forwarder may be asleep, so a burst costs one
    wake-up, not one per message (a `queue.Queue` takes two locks and notifies per message)."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.items: collections.deque[Message | None] = collections.deque()
        self.ready = threading.Event()

    def put(self, msg: Message | None, force: bool = False) -> bool:
        """Append (None: stop); False when full (``force``: append even then)."""
        if not force and len(self.items) >= self.limit:
            return False
        self.items.append(msg)
        if not self.ready.is_set():
            self.ready.set()
        return True

    def wait(self) -> None:
        """Sleep until something was appended after the outbox was drained."""
        self.ready.clear()
        if not self.items:  # appended between the drain and the clear: it set nothing
            self.ready.wait(1.0)


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
        self._outboxes = {"mqtt": _Outbox(QUEUE_MAX), "ros": _Outbox(QUEUE_MAX)}
        self._echo = {"mqtt": _Echoes(), "ros": _Echoes()}
        #: Whether a topic is a unit topic the bridge forwards (bounded: cleared when large).
        self._wanted: dict[str, bool] = {}
        self.mqtt = MqttClient(mqtt.model_copy(update={"transport": "mqtt"}),
                               sink=lambda m: self._take("ros", m))
        self.mqtt.no_local = True  # MQTT 5: the broker keeps our own messages from us
        self.mqtt.buffered_reads = True  # many small messages: one recv for many
        from delegation.runtime.ros2 import Ros2Client  # only with the [ros2] extra

        self.ros = Ros2Client(BrokerSettings(transport="ros2"),
                              sink=lambda m: self._take("mqtt", m))
        self.ros.names.default_role = role
        self.ros.ignore_own = True  # topics only the bridge writes (MQTT units'): not read
        self.ros.wait_unseen = False  # no 2 s stall per new topic that no ROS node reads
        self._threads: list[threading.Thread] = []

    # ---- lifecycle

    def start(self, timeout: float = 10.0) -> Bridge:
        everything = unit_filter(self.prefix, "#")
        self.mqtt.subscribe(everything, QOS_COMMAND)
        self.ros.subscribe(everything, QOS_COMMAND)
        # Both sides joined before anything is forwarded: what arrives meanwhile waits queued.
        self.mqtt.connect(timeout)
        self.ros.connect(timeout)
        if not self.mqtt.no_local_active:
            log.info("the broker speaks MQTT 3.1.1 (no 'No Local'): echoes of what the bridge "
                     "publishes there are recognised by topic and payload (%.0f s)", ECHO_SECONDS)
        for side in ("mqtt", "ros"):
            thread = threading.Thread(target=self._forward, args=(side,), daemon=True,
                                      name=f"bridge-to-{side}")
            thread.start()
            self._threads.append(thread)
        log.info("bridging ROS 2 and MQTT under %s/ (ROS 2 units as role %s)", self.prefix,
                 self.role)
        return self

    def stop(self) -> None:
        for box in self._outboxes.values():
            box.put(None, force=True)
        for thread in self._threads:
            thread.join(5.0)
        self._threads.clear()
        self.mqtt.disconnect()
        self.ros.disconnect()

    def queued(self) -> dict[str, int]:
        """Messages waiting per direction (memory stays bounded by `QUEUE_MAX` each)."""
        return {side: len(box.items) for side, box in self._outboxes.items()}

    # ---- receiving (each client's thread: check and queue only)

    def _take(self, to: str, msg: Message) -> None:
        """A message from the side other than ``to``: an echo of ours is dropped, the rest
        queued for ``to``."""
        source = "ros" if to == "mqtt" else "mqtt"
        echoes = self._echo[source]
        if echoes.pending() and echoes.is_echo(self._echo_topic(source, msg.topic),
                                               msg.payload, self.clock()):
            self.counts.echoes += 1
            return
        if not self._forwards(msg.topic):
            return
        if len(msg.payload) > MAX_PAYLOAD:
            self.counts.refused += 1
            if self.counts.refused in (1, 100) or self.counts.refused % 10_000 == 0:
                log.warning("bridge: %d messages over %d bytes refused (the last on %s)",
                            self.counts.refused, MAX_PAYLOAD, msg.topic[:200])
            return
        if not self._outboxes[to].put(msg):
            self.counts.full += 1
            if self.counts.full in (1, 100) or self.counts.full % 10_000 == 0:
                log.warning("bridge: the queue to %s is full: %d messages dropped", to,
                            self.counts.full)

    def _forwards(self, topic: str) -> bool:
        """A unit topic (of a unit in ``units`` when given): remembered per topic."""
        wanted = self._wanted.get(topic)
        if wanted is None:
            parsed = parse_unit_topic(topic)
            wanted = parsed is not None and (not self.units or parsed.name in self.units)
            if len(self._wanted) >= 4 * QUEUE_MAX:
                self._wanted.clear()
            self._wanted[topic] = wanted
        return wanted

    @staticmethod
    def _echo_topic(side: str, topic: str) -> str:
        """What identifies a topic on ``side``: on ROS 2 only the ROS name is sure (the type and
        role the client gives it may be learned later)."""
        return ros_topic(topic) if side == "ros" else topic

    # ---- forwarding (one thread per direction)

    def _forward(self, to: str) -> None:
        box = self._outboxes[to]
        items = box.items
        while True:
            while items:
                msg = items.popleft()
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
            box.wait()

    def _send(self, to: str, msg: Message) -> None:
        topic = msg.topic
        if to == "mqtt":
            if _UNTYPED in topic:
                parsed = parse_unit_topic(topic)
                if parsed is not None and parsed.agent_type == UNKNOWN_TYPE:
                    if self.agent_type is None:
                        self.counts.untyped += 1
                        return
                    topic = topic.replace(_UNTYPED, f"/unit/{self.agent_type}/", 1)
            if not self.mqtt.no_local_active:
                self._echo["mqtt"].sent(topic, msg.payload, self.clock())
            self.mqtt.publish(topic, msg.payload, qos=msg.qos)
            self.counts.to_mqtt += 1
        else:
            text = msg.text
            self._echo["ros"].sent(ros_topic(topic), json_text(text), self.clock())
            self.ros.publish(topic, text, qos=msg.qos)
            self.counts.to_ros += 1
