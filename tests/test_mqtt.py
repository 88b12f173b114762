"""The MQTT boundary: pure topic helpers and settings, then a real client on a real broker."""

from __future__ import annotations

import queue
import socket
import threading
import time
import uuid

import pytest

from delegation.runtime.broker import EmbeddedBroker, free_port
from delegation.runtime.mqtt import Message, MqttClient, MqttConnectError
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.unit import MqttUnit
from delegation.topics import (
    Topic,
    Wildcard,
    base_from_heartbeat,
    parse_unit_topic,
    topic_matches,
    unit_base_topic,
    unit_filter,
)

# --------------------------------------------------------------------------- pure


@pytest.mark.parametrize(
    ("pattern", "topic", "expected"),
    [
        ("a/b", "a/b", True),
        ("a/b", "a/c", False),
        ("a/+", "a/b", True),
        ("a/+", "a/b/c", False),
        ("a/#", "a", True),
        ("a/#", "a/b/c", True),
        ("#", "a/b", True),
        ("#", "$SYS/x", False),
        ("+/x", "$SYS/x", False),
        ("waraps/unit/+/+/+/heartbeat", "waraps/unit/air/simulation/dji0/heartbeat", True),
        ("waraps/unit/+/+/+/heartbeat", "waraps/unit/air/simulation/dji0/sensor/speed", False),
        ("a/+/c", "a//c", True),
    ],
)
def test_wildcard_matching(pattern: str, topic: str, expected: bool) -> None:
    assert Wildcard(pattern).matches(topic) is expected
    assert topic_matches(pattern, topic) is expected
    if not topic.startswith("$"):
        assert Topic(topic).matches(pattern) is expected


@pytest.mark.parametrize("bad", ["a/#/b", "a/b#", "a+/b", ""])
def test_bad_wildcards_are_refused(bad: str) -> None:
    with pytest.raises(ValueError):
        Wildcard(bad)


@pytest.mark.parametrize("bad", ["a/+", "a/#", ""])
def test_topics_cannot_hold_wildcards(bad: str) -> None:
    with pytest.raises(ValueError):
        Topic(bad)


def test_unit_topics_follow_the_seed_scheme() -> None:
    base = unit_base_topic("/dji0", "air")
    assert base == "waraps/unit/air/simulation/dji0"
    assert unit_base_topic("usv1", "surface", "real", "exp") == "exp/unit/surface/real/usv1"
    parsed = parse_unit_topic(base + "/exec/command")
    assert parsed is not None
    assert (parsed.prefix, parsed.agent_type, parsed.role, parsed.name, parsed.rest) == (
        "waraps",
        "air",
        "simulation",
        "dji0",
        "exec/command",
    )
    assert parsed.base == base
    deep = parse_unit_topic("a/b/unit/ground/real/rover2/sensor/position")
    assert deep is not None and deep.prefix == "a/b" and deep.name == "rover2"
    assert parse_unit_topic("waraps/other/air/simulation/dji0/heartbeat") is None
    assert base_from_heartbeat(base + "/heartbeat") == base
    assert base_from_heartbeat(base + "/sensor_info") is None
    assert unit_filter("p", "heartbeat") == "p/unit/+/+/+/heartbeat"
    with pytest.raises(ValueError):
        unit_base_topic("a/b", "air")


def test_settings_from_env() -> None:
    assert BrokerSettings.from_env({}) is None
    s = BrokerSettings.from_env(
        {
            "WARAPS_BROKER": "broker.example",
            "WARAPS_TLS_CONNECTION": "TRUE",
            "WARAPS_USERNAME": "u",
            "WARAPS_PASSWORD": "secret",
        }
    )
    assert s is not None
    assert (s.host, s.port, s.tls) == ("broker.example", 8883, True)
    assert (s.username, s.password) == ("u", "secret")
    assert "secret" not in repr(s) and "secret" not in s.describe()
    plain = BrokerSettings.from_env({"WARAPS_BROKER": "h", "WARAPS_PORT": "1999"})
    assert plain is not None and (plain.port, plain.tls) == (1999, False)


# --------------------------------------------------------------------------- on a broker


def _round_trip(settings: BrokerSettings, prefix: str) -> MqttClient:
    """A connected client subscribed to prefix/#, after one message made it through."""
    client = MqttClient(settings)
    client.subscribe(f"{prefix}/#")
    client.connect()
    try:
        deadline = time.monotonic() + 10
        got: Message | None = None
        while got is None and time.monotonic() < deadline:
            client.publish(f"{prefix}/hello", b"hi", qos=1)
            try:
                got = client.messages.get(timeout=0.5)
            except queue.Empty:
                got = None
        assert got is not None and got.topic == f"{prefix}/hello" and got.payload == b"hi"
    except BaseException:
        client.disconnect()  # the caller only stops a client it got back
        raise
    return client


def _publish_until_received(
    sender: MqttClient, receiver: MqttClient, topic: str, payload: bytes, deadline: float
) -> Message | None:
    """Publish ``payload`` on ``topic`` (QoS 1) until ``receiver`` gets a message on it.

    Messages on other topics are skipped: after a reconnect, a QoS 1 message of the first
    round trip may be delivered again.
    """
    while time.monotonic() < deadline:
        sender.publish(topic, payload, qos=1)
        try:
            got = receiver.messages.get(timeout=0.5)
        except queue.Empty:
            continue
        if got.topic == topic:
            return got
    return None


@pytest.mark.mqtt
def test_connect_subscribe_publish(mqtt_settings: BrokerSettings, prefix: str) -> None:
    client = _round_trip(mqtt_settings, prefix)
    try:
        assert client.connected.is_set()
        assert client.connect_count == 1
    finally:
        client.disconnect()
    assert not client.connected.is_set()


@pytest.mark.mqtt
def test_tcp_nodelay_is_set(mqtt_settings: BrokerSettings, prefix: str) -> None:
    client = _round_trip(mqtt_settings, prefix)
    try:
        assert client._client is not None
        sock = client._client.socket()
        assert isinstance(sock, socket.socket)
        assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0
    finally:
        client.disconnect()


@pytest.mark.mqtt
def test_protocol_auto_detection(mqtt_settings: BrokerSettings, broker_kind: str) -> None:
    client = MqttClient(mqtt_settings.model_copy(update={"protocol": "auto"}))
    client.connect()
    try:
        expected = "3.1.1" if broker_kind == "amqtt" else "5"
        assert client.protocol_version is not None
        assert {4: "3.1.1", 5: "5"}[int(client.protocol_version)] == expected
    finally:
        client.disconnect()


@pytest.mark.mqtt
def test_reconnect_resubscribes(mqtt_settings: BrokerSettings, prefix: str) -> None:
    client = _round_trip(mqtt_settings, prefix)
    try:
        assert client._client is not None
        sock = client._client.socket()
        assert isinstance(sock, socket.socket)
        client.connected.clear()
        sock.shutdown(socket.SHUT_RDWR)  # the network drops the connection under paho
        deadline = time.monotonic() + 20
        while client.connect_count < 2 and time.monotonic() < deadline:
            client.connected.wait(0.5)
        assert client.connect_count >= 2, "paho did not reconnect"
        # The subscription made before the drop works again without being asked for.
        while not client.messages.empty():
            client.messages.get_nowait()
        sender = MqttClient(mqtt_settings)
        sender.connect()
        try:
            got = _publish_until_received(sender, client, f"{prefix}/after", b"again", deadline)
            assert got is not None and got.topic == f"{prefix}/after"
        finally:
            sender.disconnect()
    finally:
        client.disconnect()


@pytest.mark.mqtt
@pytest.mark.slow
def test_reconnect_after_broker_restart(prefix: str) -> None:
    # A port outside the ephemeral range: no outgoing connection takes it while the broker is down.
    port = free_port(stable=True)
    first = EmbeddedBroker(port=port).start()
    try:
        client = _round_trip(first.settings(), prefix)
    except BaseException:
        first.stop()
        raise
    second: EmbeddedBroker | None = None
    try:
        first.stop()
        second = EmbeddedBroker(port=port).start()
        deadline = time.monotonic() + 20
        while client.connect_count < 2 and time.monotonic() < deadline:
            client.connected.wait(0.5)
        assert client.connect_count >= 2
        while not client.messages.empty():
            client.messages.get_nowait()
        got = _publish_until_received(client, client, f"{prefix}/back", b"1", deadline)
        assert got is not None and got.topic == f"{prefix}/back"
    finally:
        client.disconnect()
        first.stop()
        if second is not None:
            second.stop()


def test_connect_to_a_closed_port_fails_clearly() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # bound, never listening: connections are refused
        client = MqttClient(BrokerSettings(host="127.0.0.1", port=port, protocol="3.1.1"))
        with pytest.raises(MqttConnectError, match="cannot connect"):
            client.connect(timeout=3)


class _Echo(MqttUnit):
    """Answers every message on prefix/in with the same payload on prefix/out; counts ticks."""

    def __init__(self, settings: BrokerSettings, prefix: str) -> None:
        super().__init__(settings, f"echo-{uuid.uuid4().hex[:6]}", tick_interval=0.05)
        self.prefix = prefix
        self.ticked = threading.Event()
        self.stopped_cleanly = False
        self.thread_names: set[str] = set()

    def subscriptions(self) -> list[str]:
        return [f"{self.prefix}/in"]

    def handle(self, message: Message) -> None:
        self.thread_names.add(threading.current_thread().name)
        if message.payload == b"boom":
            raise RuntimeError("a bad message must not kill the loop")
        self.publish(f"{self.prefix}/out", message.payload, qos=1)

    def tick(self, now: float) -> None:
        self.ticked.set()

    def on_stop(self) -> None:
        self.stopped_cleanly = True


@pytest.mark.mqtt
def test_unit_base_runs_its_own_loop(mqtt_settings: BrokerSettings, prefix: str, collector) -> None:
    out = collector(f"{prefix}/out")
    unit = _Echo(mqtt_settings, prefix)
    unit.start()
    try:
        # start() returns once subscriptions are active: the first message is not lost.
        out.publish(f"{prefix}/in", b"boom")
        out.publish(f"{prefix}/in", b"one")
        got = out.wait_for(lambda m: m.payload == b"one", what="echo")
        assert got.topic == f"{prefix}/out"
        assert unit.ticked.wait(5)
        assert unit.errors == 1
        assert unit.thread_names == {f"unit-{unit.name}"}
    finally:
        unit.stop()
    assert unit.stopped_cleanly
    assert not unit.running
