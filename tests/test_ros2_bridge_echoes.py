"""How `delegation bridge` keeps what it publishes on MQTT from coming back to it (docs/ros2.md):
on MQTT 5 the broker is asked not to ("No Local"), on a 3.1.1 broker the echo is recognised and
dropped. A private mosquitto (real broker, loopback); the bridge in this process with a ROS 2
domain of this module's own on the loopback-only profile."""

from __future__ import annotations

import json
import os
import queue
import random
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from delegation.runtime.broker import PrivateMosquitto
from delegation.runtime.mqtt import Message, MqttClient
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.transport import make_client, ros2_missing

PROFILE = Path(__file__).resolve().parent.parent / "deploy" / "ros2" / "fastdds-loopback.xml"
_MISSING = ros2_missing()
WAIT = 20.0


def _client(broker: PrivateMosquitto, protocol: str, no_local: bool,
            got: queue.Queue[Message]) -> MqttClient:
    settings = broker.settings().model_copy(update={"protocol": protocol})
    client = MqttClient(settings, sink=got.put)
    client.no_local = no_local
    return client


def _until(got: queue.Queue[Message], payload: bytes) -> list[bytes]:
    """Every payload ``got`` received up to ``payload`` (within `WAIT`)."""
    seen: list[bytes] = []
    deadline = time.monotonic() + WAIT
    while payload not in seen:
        seen.append(got.get(timeout=max(0.0, deadline - time.monotonic())).payload)
    return seen


def _both_subscribed(sender: MqttClient, topic: str, queues: list[queue.Queue[Message]]) -> None:
    """Probe until every queue got a probe: subscriptions are made after CONNACK (later probes
    may still arrive; the checks look only for their own payloads)."""
    deadline = time.monotonic() + WAIT
    pending = list(queues)
    while pending:
        assert time.monotonic() < deadline, "a subscription never became active"
        sender.publish(topic, b"probe", qos=1)
        try:
            pending[0].get(timeout=0.2)
            pending.pop(0)
        except queue.Empty:
            continue


@pytest.mark.parametrize("protocol", ["5", "3.1.1"])
def test_no_local_keeps_a_client_s_own_messages_from_it_on_mqtt_5_only(
        mosquitto: PrivateMosquitto, prefix: str, protocol: str) -> None:
    mine: queue.Queue[Message] = queue.Queue()
    theirs: queue.Queue[Message] = queue.Queue()
    me = _client(mosquitto, protocol, True, mine)
    other = _client(mosquitto, protocol, False, theirs)
    topic = f"{prefix}/x"
    try:
        for c in (me, other):
            c.subscribe(f"{prefix}/#", 1)
            c.connect()
        assert me.no_local_active == (protocol == "5")
        _both_subscribed(other, f"{prefix}/probe", [mine, theirs])
        me.publish(topic, b"mine", qos=1)
        assert b"mine" in _until(theirs, b"mine")  # the broker routed it before "theirs"
        other.publish(topic, b"theirs", qos=1)
        # In order on my connection: my own message, had it come back, is before "theirs".
        seen = _until(mine, b"theirs")
    finally:
        me.disconnect()
        other.disconnect()
    assert (b"mine" in seen) == (protocol == "3.1.1"), seen


@pytest.fixture(scope="module")
def ros_domain() -> Iterator[int]:
    """The loopback-only profile and a domain of this module's own, for every node it makes."""
    if _MISSING is not None:
        pytest.skip(f"the [ros2] extra is not installed ({_MISSING})")
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


@pytest.mark.parametrize("protocol", ["5", "3.1.1"])
def test_the_bridge_never_forwards_back_what_it_published_on_mqtt(
        ros_domain: int, mosquitto: PrivateMosquitto, protocol: str) -> None:
    """A ROS 2 unit's feedback reaches MQTT once each and nothing goes back to ROS 2: on MQTT 5
    the broker sends the bridge none of its own messages, on 3.1.1 it sends each back and the
    bridge drops every one as an echo."""
    from delegation.runtime.ros_bridge import Bridge

    settings = mosquitto.settings().model_copy(update={"protocol": protocol})
    on_mqtt: queue.Queue[Message] = queue.Queue()
    watcher = MqttClient(settings, sink=on_mqtt.put)
    bridge = Bridge(settings, prefix="waraps", role="real", agent_type="air",
                    units=["echo_bot"])
    # What reaches the bridge from MQTT, in order (then handled as usual).
    reached: queue.Queue[str] = queue.Queue()
    take = bridge.mqtt._sink
    bridge.mqtt._sink = lambda m: (reached.put(m.topic), take(m))[1]
    robot = make_client(BrokerSettings(transport="ros2"), "echo_robot")
    feedback = "waraps/unit/air/real/echo_bot/exec/feedback"
    try:
        watcher.subscribe("waraps/unit/+/+/+/#", 1)
        watcher.connect()
        bridge.start()
        robot.connect()
        deadline = time.monotonic() + WAIT
        while on_mqtt.empty():  # discovery: until the bridge reads the robot's topic
            assert time.monotonic() < deadline, "the robot's feedback never reached MQTT"
            robot.publish(feedback, json.dumps({"seq": -1}), qos=1)
            time.sleep(0.1)
        for seq in range(20):
            robot.publish(feedback, json.dumps({"seq": seq}), qos=1)
        seqs: list[int] = []
        while 19 not in seqs:  # reliable and in order: then everything before it is in
            msg = on_mqtt.get(timeout=max(0.0, deadline - time.monotonic()))
            assert msg.topic == feedback
            seqs.append(json.loads(msg.payload)["seq"])
        # After every message the bridge published: on 3.1.1 their echoes reached it first.
        marker = "waraps/unit/air/real/not_bridged/marker"
        watcher.publish(marker, b"{}", qos=1)
        while reached.get(timeout=max(0.0, deadline - time.monotonic())) != marker:
            pass
    finally:
        robot.disconnect()
        bridge.stop()
        watcher.disconnect()
    numbered = [s for s in seqs if s >= 0]
    assert numbered == list(range(20)), seqs  # each once, none looped back
    counts = bridge.counts
    assert counts.to_mqtt == len(seqs), (counts, seqs)
    assert counts.to_ros == 0 and counts.failed == 0 and counts.full == 0, counts
    assert counts.echoes == (0 if protocol == "5" else counts.to_mqtt), counts
