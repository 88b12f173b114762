"""The ROS 2 boundary: the only module that imports rclpy (DESIGN 3.12, docs/ros2.md).

`Ros2Client` has `MqttClient`'s interface, so every unit and client runs on ROS 2 unchanged: the
cores publish and subscribe MQTT topics, this client puts the same JSON in ``std_msgs/String``
on ``/<name>/<prefix>/<suffix>`` (`delegation.ros_topics` translates both ways) and hands
received messages to the sink as `Message` values with the MQTT topic the core expects.

ROS has no broker: a subscription on a filter with wildcards is made per topic that discovery
finds (the ROS graph, polled every `DISCOVERY_PERIOD`), and for a name wildcard with a concrete
rest (``{p}/unit/+/+/+/exec/response``) as soon as any topic of the unit is seen, before the unit
publishes there. A publisher's first command-class message (QoS 1) waits, bounded by
`MATCH_WAIT`, until a subscriber is matched: DDS drops what a new writer sends before it has
matched its readers, and the reader of a wildcard filter appears only once discovery saw the
topic.

The executor is rclpy's `EventsExecutor` (rclpy.experimental): the default
`SingleThreadedExecutor` rebuilds its wait set of every reader at each wake-up, in Python; the
service reads ~100 topics of 10 units, and with it ``benchmarks/latency.py --transport both``
measured start-tst p50 at 2.6 x MQTT's, with `EventsExecutor` 0.83-0.88 x (docs/ros2.md).

QoS: we publish reliable (matched by reliable and best-effort readers alike); we read heartbeats,
info and sensors best-effort (ROS sensor publishers are often best-effort) and everything else
reliable; all volatile (a plain ROS publisher is volatile), keep-last `DEPTH`.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import String

from delegation.messages.ros_text import NOT_JSON, read_text
from delegation.ros_topics import RosFilter, UnitNames, ros_token, ros_topic
from delegation.runtime.mqtt import ClientBase, Message, MqttConnectError, MqttError
from delegation.topics import INFO_LEVELS, MAX_PAYLOAD, QOS_COMMAND, QOS_PERIODIC, Wildcard

log = logging.getLogger(__name__)

__all__ = ["Ros2Client", "Ros2Error"]

#: Seconds between two looks at the ROS graph for topics that wildcard filters match.
DISCOVERY_PERIOD = 0.1
#: The longest a first command-class message on a new topic waits for a subscriber (seconds).
MATCH_WAIT = 2.0
#: Keep-last depth of every reader and writer.
DEPTH = 100
_STRING = "std_msgs/msg/String"


class Ros2Error(MqttError):
    """Anything that went wrong on ROS 2 (an `MqttError`: callers catch the transport's one
    error type, whichever transport runs)."""


def _qos(reliable: bool) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


def _periodic(ros: str) -> bool:
    """Heartbeats, info and sensors: read best-effort (matches any publisher)."""
    levels = ros.strip("/").split("/")
    return levels[-1] in INFO_LEVELS or (len(levels) >= 2 and levels[-2] == "sensor")


class _SharedContext:
    """One rclpy context per process (one DDS participant), shared by every client in it and
    shut down with the last; rclpy's signal handlers are not installed (ours stop commands)."""

    _lock = threading.Lock()
    _context: Context | None = None
    _users = 0

    @classmethod
    def acquire(cls) -> Context:
        with cls._lock:
            if cls._context is None:
                context = Context()
                rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
                cls._context = context
            cls._users += 1
            return cls._context

    @classmethod
    def release(cls) -> None:
        with cls._lock:
            cls._users -= 1
            if cls._users <= 0 and cls._context is not None:
                context, cls._context, cls._users = cls._context, None, 0
                with contextlib.suppress(Exception):
                    context.try_shutdown()


class Ros2Client(ClientBase):
    """One ROS 2 node with `MqttClient`'s interface (see the module's docstring).

    Received messages are handed to ``sink`` (by default put into ``self.messages``) on this
    client's executor thread; the sink must not block.
    """

    def _init_transport(self) -> None:
        # ``self._lock`` (`ClientBase`) guards the filters, readers, writers and routes too
        # (re-entrant: discovery, under it, reads the topics it finds).
        self._filters: dict[str, RosFilter] = {}
        self.names = UnitNames()
        self._node: Node | None = None
        self._executor: Executor | None = None
        self._thread: threading.Thread | None = None
        self._running = threading.Event()
        self._readers: dict[str, Any] = {}
        self._writers: dict[str, Any] = {}
        #: ROS topic -> the MQTT topic it is delivered as and its QoS (None: no filter wants
        #: it); cleared whenever the filters or what is known of the units change.
        self._routes: dict[str, tuple[str, int] | None] = {}
        #: The ROS graph's topics at the last look (None: look again in full).
        self._graph: list[tuple[str, list[str]]] | None = None
        #: Do not read a topic that only this client publishes: what it wrote would come back
        #: to it (MQTT 5's "No Local", for the bridge); set before `connect`.
        self.ignore_own = False
        #: Topics found but not read for that reason.
        self._own: set[str] = set()
        #: A first command-class message waits for a reader even before the ROS graph shows
        #: one (discovery may lag). A relay (the bridge) sets False: waiting 2 s for each new
        #: topic nobody reads would stall everything it forwards behind it.
        self.wait_unseen = True

    # ---- lifecycle

    def connect(self, timeout: float = 10.0) -> None:
        """Join the ROS 2 domain (a node and its executor thread); subscribe what is asked."""
        if self._node is not None:
            return
        try:
            context = _SharedContext.acquire()
            node = Node(ros_token(self.client_id), context=context)
        except Exception as exc:  # rclpy raises its own types (RCLError, RMW errors)
            raise MqttConnectError(f"cannot join {self.settings.describe()}: {exc}") from exc
        executor = EventsExecutor(context=context)
        executor.add_node(node)
        with self._lock:
            self._node, self._executor = node, executor
            for pattern in list(self._subscriptions):
                self._add_filter(pattern)
        node.create_timer(DISCOVERY_PERIOD, self._discover)
        self._running.set()
        self._thread = threading.Thread(target=self._spin, name=f"ros2-{self.client_id}",
                                        daemon=True)
        self._thread.start()
        self.connect_count += 1
        self.connected.set()
        log.info("%s joined %s", self.client_id, self.settings.describe())
        if self._on_connection is not None:
            self._on_connection(True, self.connect_count)

    def _spin(self) -> None:
        executor = self._executor
        while self._running.is_set() and executor is not None:
            try:
                executor.spin_once(timeout_sec=0.1)
            except ExternalShutdownException:
                break
            except Exception as exc:
                self._callback_failed("the executor", exc)

    @property
    def loop_alive(self) -> bool:
        thread = self._thread
        return thread is not None and thread.is_alive()

    def restart(self, timeout: float = 10.0) -> None:
        """A new node and executor thread; subscriptions are renewed."""
        self.disconnect()
        self.connect(timeout)

    def disconnect(self) -> None:
        """Leave the domain: stop the executor thread, destroy the node (idempotent)."""
        self._running.clear()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(5.0)
        with self._lock:
            node, executor = self._node, self._executor
            self._node = self._executor = None
            self._readers.clear()
            self._writers.clear()
        was_connected = self.connected.is_set()
        self.connected.clear()
        if executor is not None:
            with contextlib.suppress(Exception):
                executor.shutdown(timeout_sec=1.0)
        if node is not None:
            with contextlib.suppress(Exception):
                node.destroy_node()
            _SharedContext.release()
        if was_connected and self._on_connection is not None:
            with contextlib.suppress(Exception):
                self._on_connection(False, self.connect_count)

    # ---- subscribe / publish

    def subscribe(self, pattern: str, qos: int = QOS_COMMAND) -> None:
        """Subscribe now (the concrete topic, or what discovery finds) and after a restart."""
        Wildcard(pattern)
        with self._lock:
            self._subscriptions[pattern] = qos
            if self._node is not None:
                self._add_filter(pattern)

    def unsubscribe(self, pattern: str) -> None:
        with self._lock:
            self._subscriptions.pop(pattern, None)
            self._filters.pop(pattern, None)
            self._forget_routes()
            node = self._node
            for ros in [r for r in self._readers if not self._wanted(r)]:
                reader = self._readers.pop(ros)
                if node is not None:
                    node.destroy_subscription(reader)

    def publish(
        self, topic: str, payload: bytes | str, qos: int = QOS_PERIODIC, retain: bool = False
    ) -> None:
        """Publish the payload as a ``std_msgs/String`` (``retain`` has no ROS meaning: volatile
        topics keep nothing for late readers)."""
        text = payload.decode("utf-8", errors="replace") if isinstance(payload, bytes) \
            else payload
        ros = ros_topic(topic)
        with self._lock:
            node = self._node
            if node is None:
                raise Ros2Error(f"not connected: cannot publish to {topic}")
            if self.names.published(topic):
                self._forget_routes()
            writer = self._writers.get(ros)
            new = writer is None
            if writer is None:
                try:
                    writer = node.create_publisher(String, ros, _qos(True))
                except Exception as exc:
                    raise Ros2Error(f"cannot publish to {ros}: {exc}") from exc
                self._writers[ros] = writer
        if new and qos >= QOS_COMMAND:
            self._await_reader(node, writer, ros)
        writer.publish(String(data=text))

    def _await_reader(self, node: Node, writer: Any, ros: str) -> None:
        """Wait (at most `MATCH_WAIT`) until the new writer has matched a reader (with
        `wait_unseen` False, only when the ROS graph shows one)."""
        if not self.wait_unseen and node.count_subscribers(ros) == 0:
            return
        deadline = time.monotonic() + MATCH_WAIT
        while writer.get_subscription_count() == 0:
            if time.monotonic() >= deadline:
                log.debug("%s: no reader of %s within %.1fs", self.client_id, ros, MATCH_WAIT)
                return
            time.sleep(0.005)

    # ---- readers (under the lock)

    def _add_filter(self, pattern: str) -> None:
        flt = RosFilter.of(pattern)
        self._filters[pattern] = flt
        self._forget_routes()
        concrete = flt.concrete
        if concrete is not None:
            self._read(concrete)
        elif self._node is not None:
            self._discover_now()

    def _read(self, ros: str) -> None:
        node = self._node
        if node is None or ros in self._readers:
            return
        try:
            self._readers[ros] = node.create_subscription(
                String, ros, lambda msg, r=ros: self._on_message(r, msg),
                _qos(not _periodic(ros)))
            log.debug("%s reads %s", self.client_id, ros)
        except Exception as exc:  # an invalid name from a foreign topic: skip it
            log.warning("%s: cannot read %s: %s", self.client_id, ros, exc)

    def _wanted(self, ros: str) -> bool:
        filters = list(self._filters.values())
        if any(f.concrete == ros or f.mqtt_topic(ros, self.names) for f in filters):
            return True
        return any(f.for_unit(t) == ros for f in filters if (t := f.unit_token(ros)))

    def _discover(self) -> None:
        """The executor's timer: look at the ROS graph for topics our filters match."""
        try:
            with self._lock:
                self._discover_now()
        except Exception as exc:
            self._callback_failed("discovery", exc)

    def _discover_now(self) -> None:
        node = self._node
        if node is None:
            return
        wild = [f for f in self._filters.values() if f.concrete is None]
        if not wild:
            return
        graph = node.get_topic_names_and_types()
        if graph == self._graph and not any(self._others_publish(node, r) for r in self._own):
            return  # nothing new since the last look (and no filter or name changed)
        self._graph = graph
        self._own.clear()
        for ros, types in graph:
            if _STRING not in types:
                continue
            for flt in wild:
                token = flt.unit_token(ros)
                per_unit = flt.for_unit(token) if token is not None else None
                if per_unit is not None:
                    self._read_found(node, per_unit)
                if ros not in self._readers and flt.mqtt_topic(ros, self.names) is not None:
                    self._read_found(node, ros)

    def _read_found(self, node: Node, ros: str) -> None:
        """Read a topic discovery found, unless `ignore_own` and no one else publishes there."""
        if ros in self._readers:
            return
        if self.ignore_own and not self._others_publish(node, ros):
            self._own.add(ros)  # looked at again at each discovery, until someone else does
            return
        self._read(ros)

    def _others_publish(self, node: Node, ros: str) -> bool:
        """Whether a writer other than this client's is on ``ros`` (the ROS graph's count)."""
        return node.count_publishers(ros) > (1 if ros in self._writers else 0)

    # ---- the executor thread: convert and hand over only

    def _on_message(self, ros: str, msg: Any) -> None:
        try:
            text, value = read_text(str(msg.data))
            data = text.encode("utf-8")
            if value is not NOT_JSON and ros.endswith("/heartbeat") and len(data) <= MAX_PAYLOAD:
                self._learn(ros, value)
            try:
                route = self._routes[ros]  # without the lock: a dict read is atomic
            except KeyError:
                route = self._route(ros)
            if route is not None:
                self._sink(Message(route[0], data, qos=route[1]))
        except Exception as exc:
            self._callback_failed(f"a message on {ros[:200]}", exc)

    def _learn(self, ros: str, value: Any) -> None:
        token = ros.strip("/").split("/")[0]
        with self._lock:
            if self.names.heard(token, value):
                self._forget_routes()

    def _forget_routes(self) -> None:
        """What the filters or the units' names mean changed (under the lock)."""
        self._routes.clear()
        self._graph = None

    def _route(self, ros: str) -> tuple[str, int] | None:
        """The MQTT topic for the first filter that means ``ros`` (a concrete one first), and
        the QoS it is delivered with."""
        with self._lock:
            if ros in self._routes:
                return self._routes[ros]
            topic: str | None = None
            for flt in sorted(self._filters.values(), key=lambda f: f.concrete is None):
                topic = flt.mqtt if flt.concrete == ros and flt.prefix is None \
                    else flt.mqtt_topic(ros, self.names)
                if topic is not None:
                    break
            route = None if topic is None else \
                (topic, QOS_PERIODIC if _periodic(ros) else QOS_COMMAND)
            self._routes[ros] = route
            return route
