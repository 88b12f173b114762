"""`Ros2Client` against real ROS 2 nodes in this process (rclpy, Fast DDS on the loopback-only
profile, a domain of this module's own): topics both ways, wildcard filters by discovery, the
first command on a new topic not lost, payloads from plain rclpy publishers made JSON.
Skipped, with one reason, where the ``[ros2]`` extra is not installed."""

from __future__ import annotations

import json
import os
import queue
import random
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from delegation.runtime.mqtt import Message, MqttError
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.transport import make_client, ros2_missing

PROFILE = Path(__file__).resolve().parent.parent / "deploy" / "ros2" / "fastdds-loopback.xml"
_MISSING = ros2_missing()
pytestmark = pytest.mark.skipif(_MISSING is not None,
                                reason=f"the [ros2] extra is not installed ({_MISSING})")

ROS = BrokerSettings(transport="ros2")


@pytest.fixture(scope="module", autouse=True)
def ros_domain() -> Iterator[int]:
    """The loopback-only profile and a domain of this module's own, for every node it makes."""
    saved = {k: os.environ.get(k) for k in ("ROS_DOMAIN_ID", "FASTDDS_DEFAULT_PROFILES_FILE")}
    domain = random.SystemRandom().randint(1, 200)
    os.environ.update(ROS_DOMAIN_ID=str(domain), FASTDDS_DEFAULT_PROFILES_FILE=str(PROFILE))
    try:
        yield domain
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


class PlainNode:
    """A plain rclpy node on its own context and thread: what a ROS 2 user's robot does."""

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.signals import SignalHandlerOptions

        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.got: queue.Queue[tuple[str, str]] = queue.Queue()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def publisher(self, topic: str) -> Any:
        from std_msgs.msg import String

        return self.node.create_publisher(String, topic, 10)

    def listen(self, topic: str) -> None:
        from std_msgs.msg import String

        self.node.create_subscription(
            String, topic, lambda m, t=topic: self.got.put((t, m.data)), 10)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()


def _until(predicate: Any, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


def _next(q: queue.Queue[Message], topic: str, timeout: float = 10.0) -> Message:
    deadline = time.monotonic() + timeout
    while True:
        msg = q.get(timeout=max(0.01, deadline - time.monotonic()))
        if msg.topic == topic:
            return msg


@pytest.fixture
def plain() -> Iterator[PlainNode]:
    node = PlainNode(f"plain_{random.SystemRandom().randint(0, 10**6)}")
    try:
        yield node
    finally:
        node.stop()


def test_a_concrete_filter_gets_its_own_topic_back_whatever_the_sender_thinks() -> None:
    mine = "waraps/unit/air/simulation/u-1/exec/command"
    a, b = make_client(ROS, "a-1"), make_client(ROS, "b-1")
    a.subscribe(mine)
    a.connect()
    b.connect()
    try:
        b.publish("waraps/unit/ground/real/u-1/exec/command", b'{"command":"ping"}', qos=1)
        msg = _next(a.messages, mine)
        assert json.loads(msg.payload) == {"command": "ping"}
        assert msg.qos == 1
    finally:
        a.disconnect()
        b.disconnect()


def test_plain_ros_publishers_are_read_by_wildcards_with_their_real_name(
        plain: PlainNode) -> None:
    client = make_client(ROS, "svc-1")
    client.subscribe("waraps/unit/+/+/+/heartbeat")
    client.subscribe("waraps/unit/+/+/+/exec/response")
    client.connect()
    try:
        beat = plain.publisher("/bot_1/waraps/heartbeat")
        heartbeat = {"agent-type": "surface", "agent-uuid": "u", "name": "bot-1", "rate": 1.0,
                     "stamp": 1.0, "levels": ["sensor"], "ok": True, "note": None}
        from std_msgs.msg import String

        got = _until_message(client, "waraps/unit/surface/real/bot-1/heartbeat",
                             lambda: beat.publish(String(data=str(heartbeat))))
        assert json.loads(got.payload) == heartbeat  # a Python literal became JSON
        # The response topic is read as soon as the unit is seen, before it publishes there.
        assert _until(lambda: "/bot_1/waraps/exec/response" in client._readers)  # type: ignore[attr-defined]
        answer = plain.publisher("/bot_1/waraps/exec/response")
        assert _until(lambda: answer.get_subscription_count() > 0)
        answer.publish(String(data=json.dumps(json.dumps({"response": "running"}))))
        msg = _next(client.messages, "waraps/unit/surface/real/bot-1/exec/response")
        assert json.loads(msg.payload) == {"response": "running"}  # quoted JSON unwrapped
    finally:
        client.disconnect()


def _until_message(client: Any, topic: str, send: Any, timeout: float = 10.0) -> Message:
    """Send periodically (as a heartbeat is) until ``topic`` arrives."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        send()
        try:
            return _next(client.messages, topic, timeout=0.3)
        except queue.Empty:
            continue
    raise AssertionError(f"nothing on {topic} within {timeout}s")


def test_the_first_command_on_a_new_topic_is_not_lost(plain: PlainNode) -> None:
    """A writer made for the command waits until discovery matched the reader."""
    plain.listen("/robot_7/waraps/exec/command")
    client = make_client(ROS, "engine-7")
    client.connect()
    try:
        client.publish("waraps/unit/air/real/robot-7/exec/command", '{"command":"start-task"}',
                       qos=1)
        topic, data = plain.got.get(timeout=10)
        assert topic == "/robot_7/waraps/exec/command"
        assert json.loads(data) == {"command": "start-task"}
    finally:
        client.disconnect()


def test_unsubscribed_topics_are_not_read_and_a_closed_client_refuses_to_publish() -> None:
    a, b = make_client(ROS, "a-2"), make_client(ROS, "b-2")
    topic = "waraps/unit/air/real/x2/tst/command"
    a.subscribe(topic)
    a.connect()
    b.connect()
    try:
        b.publish(topic, b"{}", qos=1)
        _next(a.messages, topic)
        a.unsubscribe(topic)
        assert a.subscriptions == {}
        b.publish(topic, b'{"late":1}', qos=1)
        with pytest.raises(queue.Empty):
            _next(a.messages, topic, timeout=1.0)
    finally:
        a.disconnect()
        b.disconnect()
    with pytest.raises(MqttError):
        b.publish(topic, b"{}")
