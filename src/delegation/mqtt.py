"""The MQTT boundary: the only module that imports paho.

Incoming messages become an own value type (`Message`) at the edge and go to a queue that the
unit's own thread consumes; paho's callbacks convert and enqueue, nothing else (DESIGN 4). The
pure topic helpers (`Topic`, `Wildcard`, the WARA-PS naming scheme) need no broker.

`MqttUnit` is the reusable base of everything that runs on MQTT here (simulated units, the
reference TST engine, the delegation service): it owns one client and one loop thread that
handles messages and calls a periodic `tick`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import queue
import socket
import ssl
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion
from pydantic import BaseModel, ConfigDict, Field

from delegation.errors import DelegationError

log = logging.getLogger(__name__)

#: Default first topic level (seed section 3.1: the context, e.g. ``waraps``).
DEFAULT_PREFIX = "waraps"
#: Roles the seed names for the fourth topic level.
ROLES: tuple[str, ...] = ("simulation", "real", "playback")
#: Agent types the seed allows.
AGENT_TYPES: tuple[str, ...] = ("air", "ground", "surface", "subsurface")

#: Commands, responses and feedback are QoS 1; periodic heartbeats and sensors QoS 0.
QOS_COMMAND = 1
QOS_PERIODIC = 0

Protocol = Literal["auto", "5", "3.1.1"]


# --------------------------------------------------------------------------- errors


class MqttError(DelegationError):
    """Anything that went wrong talking to the broker."""


class MqttConnectError(MqttError):
    """The broker could not be reached or refused the connection."""


# --------------------------------------------------------------------------- values


@dataclass(frozen=True, slots=True)
class Message:
    """One received MQTT message, independent of paho."""

    topic: str
    payload: bytes
    qos: int = 0
    retain: bool = False

    @property
    def text(self) -> str:
        """The payload decoded as UTF-8 (undecodable bytes replaced)."""
        return self.payload.decode("utf-8", errors="replace")


def _message_from_paho(msg: paho.MQTTMessage) -> Message:
    return Message(msg.topic, bytes(msg.payload), qos=msg.qos, retain=bool(msg.retain))


# --------------------------------------------------------------------------- topics (pure)


def _check_levels(value: str, what: str) -> None:
    if not value:
        raise ValueError(f"{what} must not be empty")
    if "\x00" in value:
        raise ValueError(f"{what} must not contain NUL")
    if len(value.encode("utf-8")) > 65535:
        raise ValueError(f"{what} is longer than 65535 bytes")


@dataclass(frozen=True, slots=True)
class Topic:
    """A concrete topic name (no wildcards), as messages are published to."""

    value: str

    def __post_init__(self) -> None:
        _check_levels(self.value, "a topic")
        if "+" in self.value or "#" in self.value:
            raise ValueError(f"a topic cannot contain wildcards: {self.value!r}")

    @property
    def levels(self) -> list[str]:
        return self.value.split("/")

    def matches(self, wildcard: Wildcard | str) -> bool:
        """True when this topic is matched by ``wildcard``."""
        wc = wildcard if isinstance(wildcard, Wildcard) else Wildcard(wildcard)
        return wc.matches(self)

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True, slots=True)
class Wildcard:
    """A subscription filter with MQTT's ``+`` (one level) and ``#`` (the rest) wildcards."""

    value: str

    def __post_init__(self) -> None:
        _check_levels(self.value, "a topic filter")
        levels = self.value.split("/")
        for i, level in enumerate(levels):
            if "#" in level and (level != "#" or i != len(levels) - 1):
                raise ValueError(f"'#' must be a whole last level: {self.value!r}")
            if "+" in level and level != "+":
                raise ValueError(f"'+' must be a whole level: {self.value!r}")

    def matches(self, topic: Topic | str) -> bool:
        """MQTT matching: ``a/#`` matches ``a``; wildcards never match a leading ``$``."""
        name = topic.value if isinstance(topic, Topic) else topic
        t_levels = name.split("/")
        f_levels = self.value.split("/")
        if name.startswith("$") and f_levels[0] in ("+", "#"):
            return False
        for i, f in enumerate(f_levels):
            if f == "#":
                return True
            if i >= len(t_levels):
                return False
            if f != "+" and f != t_levels[i]:
                return False
        return len(t_levels) == len(f_levels)

    def __str__(self) -> str:
        return self.value


def topic_matches(pattern: str, topic: str) -> bool:
    """Shorthand for ``Wildcard(pattern).matches(topic)``."""
    return Wildcard(pattern).matches(topic)


@dataclass(frozen=True, slots=True)
class UnitTopic:
    """A topic split by the WARA-PS scheme ``{prefix}/unit/{agent-type}/{role}/{name}/{rest}``."""

    prefix: str
    agent_type: str
    role: str
    name: str
    rest: str

    @property
    def base(self) -> str:
        """The unit's base topic (everything before ``rest``)."""
        return unit_base_topic(self.name, self.agent_type, self.role, self.prefix)


def unit_base_topic(
    name: str, agent_type: str, role: str = "simulation", prefix: str = DEFAULT_PREFIX
) -> str:
    """``{prefix}/unit/{agent-type}/{role}/{name}``; names are given without a leading ``/``."""
    parts = {"name": name.strip("/"), "agent type": agent_type, "role": role, "prefix": prefix}
    for what, value in parts.items():
        if not value or "/" in value or "+" in value or "#" in value:
            raise ValueError(f"invalid {what} for a topic: {value!r}")
    return f"{prefix}/unit/{agent_type}/{role}/{parts['name']}"


def parse_unit_topic(topic: str) -> UnitTopic | None:
    """Split a unit topic; None when it does not follow the scheme.

    The prefix may itself have several levels; the ``unit`` level is found from the end so that
    ``a/b/unit/air/simulation/dji0/heartbeat`` works.
    """
    levels = topic.split("/")
    for i in range(len(levels) - 5, -1, -1):
        if levels[i + 1] == "unit" and i >= 0:
            prefix = "/".join(levels[: i + 1])
            agent_type, role, name = levels[i + 2], levels[i + 3], levels[i + 4]
            rest = "/".join(levels[i + 5 :])
            if prefix and agent_type and role and name and rest:
                return UnitTopic(prefix, agent_type, role, name, rest)
    return None


def base_from_heartbeat(topic: str) -> str | None:
    """A unit's base topic from where its heartbeat arrived (topic minus ``/heartbeat``)."""
    suffix = "/heartbeat"
    if topic.endswith(suffix) and len(topic) > len(suffix):
        return topic[: -len(suffix)]
    return None


def unit_filter(prefix: str = DEFAULT_PREFIX, rest: str = "#") -> str:
    """A filter over every unit's ``rest`` under ``prefix`` (``heartbeat``, ``exec/response``)."""
    return f"{prefix}/unit/+/+/+/{rest}"


# --------------------------------------------------------------------------- settings


def _env_flag(value: str | None) -> bool:
    return (value or "").strip().lower() in ("1", "true", "yes", "on")


class BrokerSettings(BaseModel):
    """Where the broker is and how to log in (WARA-PS example agents' ``WARAPS_*`` names).

    ``protocol="auto"`` connects with MQTT v5 and falls back to 3.1.1 only when the broker answers
    "unsupported protocol version" (amqtt 0.12 speaks 3.1.1 only); the choice is logged.
    """

    model_config = ConfigDict(frozen=True)

    host: str = "127.0.0.1"
    port: int = Field(default=1883, ge=1, le=65535)
    tls: bool = False
    username: str = ""
    password: str = Field(default="", repr=False)
    protocol: Protocol = "auto"
    keepalive: int = Field(default=30, ge=5)
    #: CA bundle to verify the broker's certificate with; None: the system's trusted CAs.
    ca_certs: str | None = None

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> BrokerSettings | None:
        """Settings from ``WARAPS_BROKER`` and friends; None when no broker is configured."""
        env = os.environ if environ is None else environ
        host = (env.get("WARAPS_BROKER") or "").strip()
        if not host:
            return None
        return cls.from_values(
            host=host,
            port=env.get("WARAPS_PORT"),
            tls=_env_flag(env.get("WARAPS_TLS_CONNECTION")),
            username=env.get("WARAPS_USERNAME", ""),
            password=env.get("WARAPS_PASSWORD", ""),
        )

    @classmethod
    def from_values(
        cls,
        host: str,
        port: int | str | None = None,
        tls: bool = False,
        username: str | None = "",
        password: str | None = "",
        protocol: Protocol = "auto",
    ) -> BrokerSettings:
        """Settings from CLI-like values: an empty or zero port means the default for ``tls``."""
        port_value = int(port) if port not in (None, "", "0", 0) else (8883 if tls else 1883)
        return cls(
            host=host,
            port=port_value,
            tls=tls,
            username=username or "",
            password=password or "",
            protocol=protocol,
        )

    def describe(self) -> str:
        """host:port for logs (never the password)."""
        scheme = "mqtts" if self.tls else "mqtt"
        return f"{scheme}://{self.host}:{self.port}"


# --------------------------------------------------------------------------- the client


def _set_nodelay(sock: Any) -> None:
    """Disable Nagle's algorithm: 88 ms -> 0.8 ms per round trip, measured (DESIGN 4)."""
    try:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    except (OSError, AttributeError) as exc:  # a websocket wrapper, or a closed socket
        log.debug("could not set TCP_NODELAY: %s", exc)


MessageSink = Callable[[Message], None]

_UNSUPPORTED_PROTOCOL = 132  # CONNACK reason "Unsupported protocol version" (v3 rc 1 maps here)


class MqttClient:
    """One paho client: connect (with protocol detection), subscribe in on_connect, publish.

    Received messages are handed to ``sink`` (by default put into ``self.messages``) on paho's
    thread; the sink must not block.
    """

    def __init__(
        self,
        settings: BrokerSettings,
        client_id: str | None = None,
        sink: MessageSink | None = None,
    ) -> None:
        self.settings = settings
        self.client_id = client_id or f"delegation-{uuid.uuid4().hex[:12]}"
        self.messages: queue.Queue[Message] = queue.Queue()
        self._sink: MessageSink = sink or self.messages.put
        self._subscriptions: dict[str, int] = {}
        self._sub_lock = threading.Lock()
        self.connected = threading.Event()
        self._connack = threading.Event()
        self._connack_code: int | None = None
        self._connack_reason = ""
        self._client: paho.Client | None = None
        self.protocol_version: paho.MQTTProtocolVersion | None = None
        self.connect_count = 0
        self.nodelay_sockets = 0

    # ---- lifecycle

    def connect(self, timeout: float = 10.0) -> None:
        """Connect and start paho's network thread; raise `MqttConnectError` within ``timeout``.

        After this returns, paho reconnects by itself (back-off 1..8 s) and subscriptions are
        renewed in on_connect.
        """
        order = {"auto": [paho.MQTTv5, paho.MQTTv311], "5": [paho.MQTTv5], "3.1.1": [paho.MQTTv311]}
        deadline = time.monotonic() + timeout
        last = ""
        for protocol in order[self.settings.protocol]:
            code = self._try_connect(protocol, deadline)
            if code == 0:
                self.protocol_version = protocol
                log.info(
                    "%s connected to %s with MQTT %s",
                    self.client_id,
                    self.settings.describe(),
                    "5" if protocol == paho.MQTTv5 else "3.1.1",
                )
                return
            last = self._connack_reason or f"code {code}"
            if code == _UNSUPPORTED_PROTOCOL and self.settings.protocol == "auto":
                log.info("%s does not speak MQTT 5; using 3.1.1", self.settings.describe())
                continue
            break
        raise MqttConnectError(f"cannot connect to {self.settings.describe()}: {last}")

    def _make_client(self, protocol: paho.MQTTProtocolVersion) -> paho.Client:
        client = paho.Client(
            CallbackAPIVersion.VERSION2,
            client_id=self.client_id,
            protocol=protocol,
            clean_session=None if protocol == paho.MQTTv5 else True,
        )
        client.reconnect_delay_set(1, 8)
        client.max_queued_messages_set(0)
        if self.settings.username:
            client.username_pw_set(self.settings.username, self.settings.password or None)
        if self.settings.tls:
            client.tls_set(ca_certs=self.settings.ca_certs, cert_reqs=ssl.CERT_REQUIRED)
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.on_message = self._on_message
        client.on_socket_open = self._on_socket_open
        return client

    def _try_connect(self, protocol: paho.MQTTProtocolVersion, deadline: float) -> int:
        client = self._make_client(protocol)
        self._connack.clear()
        self._connack_code = None
        self._connack_reason = ""
        try:
            s = self.settings
            if protocol == paho.MQTTv5:
                client.connect(s.host, s.port, s.keepalive, clean_start=True)
            else:
                client.connect(s.host, s.port, s.keepalive)
        except (OSError, ValueError, ssl.SSLError) as exc:
            self._connack_reason = str(exc) or type(exc).__name__
            return -1
        self._client = client
        client.loop_start()
        if not self._connack.wait(max(0.0, deadline - time.monotonic())):
            self._connack_reason = "no CONNACK before the deadline"
            self._shutdown_client()
            return -1
        code = self._connack_code if self._connack_code is not None else -1
        if code != 0:
            self._shutdown_client()
        return code

    def _shutdown_client(self) -> None:
        client, self._client = self._client, None
        if client is None:
            return
        with contextlib.suppress(Exception):
            client.disconnect()
        client.loop_stop()

    def disconnect(self) -> None:
        """Disconnect cleanly and stop paho's thread (idempotent)."""
        self._shutdown_client()
        self.connected.clear()

    def __enter__(self) -> MqttClient:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()

    # ---- subscribe / publish

    def subscribe(self, pattern: str, qos: int = QOS_COMMAND) -> None:
        """Subscribe now (when connected) and again after every reconnect."""
        Wildcard(pattern)  # validate early, with a clear message
        with self._sub_lock:
            self._subscriptions[pattern] = qos
        client = self._client
        if client is not None and self.connected.is_set():
            client.subscribe(pattern, qos)

    def unsubscribe(self, pattern: str) -> None:
        with self._sub_lock:
            self._subscriptions.pop(pattern, None)
        client = self._client
        if client is not None and self.connected.is_set():
            client.unsubscribe(pattern)

    @property
    def subscriptions(self) -> dict[str, int]:
        with self._sub_lock:
            return dict(self._subscriptions)

    def publish(
        self, topic: str, payload: bytes | str, qos: int = QOS_PERIODIC, retain: bool = False
    ) -> None:
        """Queue a message with paho (QoS 0 is dropped while disconnected, as paho does)."""
        client = self._client
        if client is None:
            raise MqttError(f"not connected: cannot publish to {topic}")
        data = payload.encode("utf-8") if isinstance(payload, str) else payload
        info = client.publish(topic, data, qos=qos, retain=retain)
        if info.rc not in (paho.MQTT_ERR_SUCCESS, paho.MQTT_ERR_NO_CONN):
            raise MqttError(f"publish to {topic} failed: {paho.error_string(info.rc)}")

    # ---- paho callbacks (paho's thread: convert and enqueue only)

    def _on_socket_open(self, client: paho.Client, userdata: Any, sock: Any) -> None:
        _set_nodelay(sock)
        self.nodelay_sockets += 1

    def _on_connect(
        self, client: paho.Client, userdata: Any, flags: Any, reason: Any, properties: Any
    ) -> None:
        code = int(getattr(reason, "value", reason))
        self._connack_code = code
        self._connack_reason = str(reason)
        if code == 0:
            with self._sub_lock:
                subs = list(self._subscriptions.items())
            if subs:
                client.subscribe(subs)
            self.connect_count += 1
            self.connected.set()
        self._connack.set()

    def _on_disconnect(
        self, client: paho.Client, userdata: Any, flags: Any, reason: Any, properties: Any
    ) -> None:
        self.connected.clear()
        log.debug("%s disconnected: %s", self.client_id, reason)

    def _on_message(self, client: paho.Client, userdata: Any, msg: paho.MQTTMessage) -> None:
        self._sink(_message_from_paho(msg))


# --------------------------------------------------------------------------- the unit base


class _Stop:
    """Sentinel that ends a unit's loop."""


class MqttUnit:
    """Base of an MQTT unit that runs its own loop thread.

    The framework owns the lifecycle (`start`/`stop`); subclasses fill in hooks:
    `subscriptions()` (filters to subscribe), `handle(message)` (one received message),
    `tick(now)` (every ``tick_interval`` seconds of ``clock``), `on_start()`/`on_stop()`.
    Every hook runs on the unit's thread, so a subclass needs no locks of its own for state it
    touches only there.
    """

    def __init__(
        self,
        settings: BrokerSettings,
        name: str,
        *,
        tick_interval: float | None = 1.0,
        clock: Callable[[], float] = time.monotonic,
        client_id: str | None = None,
    ) -> None:
        self.settings = settings
        self.name = name
        self.tick_interval = tick_interval
        self.clock = clock
        self._inbox: queue.Queue[Message | _Stop] = queue.Queue()
        self.client = MqttClient(
            settings, client_id or f"{name}-{uuid.uuid4().hex[:8]}", sink=self._inbox.put
        )
        self._thread: threading.Thread | None = None
        self._started = threading.Event()
        self._stopped = threading.Event()
        self.errors = 0

    # ---- hooks

    def subscriptions(self) -> Iterable[str]:
        return ()

    def handle(self, message: Message) -> None:
        """One received message (on the unit's thread)."""

    def tick(self, now: float) -> None:
        """Periodic work (on the unit's thread)."""

    def on_start(self) -> None:
        """Called on the unit's thread before the first message or tick."""

    def on_stop(self) -> None:
        """Called on the unit's thread after the last message (still connected)."""

    # ---- lifecycle

    def start(self, timeout: float = 10.0) -> None:
        """Connect, subscribe, start the loop thread; return once it runs."""
        if self._thread is not None:
            raise MqttError(f"{self.name} is already started")
        for pattern in self.subscriptions():
            self.client.subscribe(pattern)
        self.client.connect(timeout=timeout)
        if not self._wait_subscribed(timeout):
            self.client.disconnect()
            raise MqttConnectError(f"{self.name}: subscriptions not acknowledged within {timeout}s")
        self._stopped.clear()
        self._thread = threading.Thread(target=self._run, name=f"unit-{self.name}", daemon=True)
        self._thread.start()
        self._started.wait(timeout)

    def _wait_subscribed(self, timeout: float) -> bool:
        """Round-trip a message through the broker so the SUBSCRIBEs are surely processed."""
        patterns = list(self.client.subscriptions)
        if not patterns:
            return True
        # Brokers process a client's packets in order: a probe published to a private topic we
        # subscribe to last comes back only once the subscriptions before it are in place.
        probe = f"delegation-probe/{self.client.client_id}"
        got = threading.Event()
        original = self.client._sink

        def sink(msg: Message) -> None:
            if msg.topic == probe:
                got.set()
            else:
                original(msg)

        self.client._sink = sink
        try:
            self.client.subscribe(probe, QOS_COMMAND)
            deadline = time.monotonic() + timeout
            while not got.is_set() and time.monotonic() < deadline:
                with contextlib.suppress(MqttError):
                    self.client.publish(probe, b"", qos=QOS_COMMAND)
                got.wait(0.25)
            return got.is_set()
        finally:
            self.client.unsubscribe(probe)
            self.client._sink = original

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the loop (after on_stop) and disconnect; idempotent."""
        thread = self._thread
        if thread is not None:
            self._inbox.put(_Stop())
            thread.join(timeout)
            if thread.is_alive():
                log.warning("%s: loop thread did not stop within %.1fs", self.name, timeout)
            self._thread = None
        self.client.disconnect()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> MqttUnit:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---- helpers for subclasses

    def publish(
        self,
        topic: str,
        payload: bytes | str | BaseModel | dict[str, Any],
        qos: int = QOS_PERIODIC,
        retain: bool = False,
    ) -> None:
        """Publish bytes, text, a JSON-able dict, or a pydantic model (by alias, no None)."""
        if isinstance(payload, BaseModel):
            data: bytes | str = payload.model_dump_json(by_alias=True, exclude_none=True)
        elif isinstance(payload, dict):
            data = json.dumps(payload, sort_keys=True)
        else:
            data = payload
        try:
            self.client.publish(topic, data, qos=qos, retain=retain)
        except MqttError as exc:
            log.warning("%s: %s", self.name, exc)

    def call_soon(self, message: Message) -> None:
        """Feed a message to the loop as if it had arrived (tests, internal events)."""
        self._inbox.put(message)

    # ---- the loop

    def _run(self) -> None:
        try:
            self._guard(self.on_start)
        finally:
            self._started.set()
        next_tick = self.clock()
        while True:
            wait: float | None = None
            if self.tick_interval is not None:
                now = self.clock()
                if now >= next_tick:
                    self._guard(lambda n=now: self.tick(n))  # type: ignore[misc]
                    next_tick = max(next_tick + self.tick_interval, now)
                wait = max(0.0, next_tick - self.clock())
            try:
                item = self._inbox.get(timeout=wait)
            except queue.Empty:
                continue
            if isinstance(item, _Stop):
                break
            self._guard(lambda m=item: self.handle(m))  # type: ignore[misc]
        self._guard(self.on_stop)
        self._stopped.set()

    def _guard(self, fn: Callable[[], None]) -> None:
        """Run a hook; an exception is logged and counted, never kills the loop."""
        try:
            fn()
        except Exception:
            self.errors += 1
            log.exception("%s: error in %s", self.name, getattr(fn, "__name__", "hook"))
