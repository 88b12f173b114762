"""The MQTT boundary: the only module that imports paho.

Incoming messages become an own value type (`Message`) at the edge and go to a sink (a queue that
a unit's own thread consumes); paho's callbacks convert and enqueue, nothing else. Topic helpers
are in `delegation.topics` (pure), broker settings in `delegation.runtime.settings`.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import socket
import ssl
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Self

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion, MQTTErrorCode, MQTTProtocolVersion
from paho.mqtt.subscribeoptions import SubscribeOptions

from delegation.errors import DelegationError
from delegation.runtime.settings import BrokerSettings
from delegation.topics import QOS_COMMAND, QOS_PERIODIC, Wildcard

log = logging.getLogger(__name__)

#: Seconds a disconnect waits for paho's network thread to stop.
SHUTDOWN_TIMEOUT = 5.0

__all__ = [
    "QOS_COMMAND",
    "QOS_PERIODIC",
    "ClientBase",
    "Message",
    "MessageSink",
    "MqttClient",
    "MqttConnectError",
    "MqttError",
]

# --------------------------------------------------------------------------- errors


class MqttError(DelegationError):
    """Anything that went wrong talking to the broker."""


class MqttConnectError(MqttError):
    """The broker could not be reached or refused the connection."""


#: OpenSSL's reasons when the other end does not speak TLS at all (a plain MQTT port).
_PLAIN_PORT_SSL_REASONS = frozenset(
    {"WRONG_VERSION_NUMBER", "RECORD_LAYER_FAILURE", "PACKET_LENGTH_TOO_LONG", "HTTP_REQUEST"}
)


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


# --------------------------------------------------------------------------- the client


def _set_nodelay(sock: Any) -> None:
    """Disable Nagle's algorithm: 88 ms -> 0.8 ms per round trip, measured (docs/protocol.md
    §10)."""
    try:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    except (OSError, AttributeError) as exc:  # a websocket wrapper, or a closed socket
        log.debug("could not set TCP_NODELAY: %s", exc)


MessageSink = Callable[[Message], None]


class ClientBase:
    """What `MqttClient` and `Ros2Client` (`delegation.runtime.ros2`) share, so that the two
    transports cannot drift apart where they must agree: the constructor `make_client` calls,
    who the client is, where received messages go, the subscriptions it keeps (renewed after
    every reconnect), ``with`` as connect/disconnect, and the rule that a callback never raises
    into the transport's thread. A transport adds its own state in `_init_transport`.
    """

    def __init__(
        self,
        settings: BrokerSettings,
        client_id: str | None = None,
        sink: MessageSink | None = None,
        on_connection: Callable[[bool, int], None] | None = None,
    ) -> None:
        """``on_connection(up, connect_count)`` is called on the transport's thread at every
        connect and disconnect (it must not block): units catch up after an outage with it."""
        self.settings = settings
        self._on_connection = on_connection
        self.client_id = client_id or f"delegation-{uuid.uuid4().hex[:12]}"
        self.messages: queue.Queue[Message] = queue.Queue()
        self._sink: MessageSink = sink or self.messages.put
        self._subscriptions: dict[str, int] = {}
        #: Guards ``_subscriptions`` (paho's callbacks and the ROS 2 executor read them on their
        #: own threads), and in `Ros2Client` all its reader state; re-entrant for that.
        self._lock = threading.RLock()
        self.connected = threading.Event()
        self.connect_count = 0
        #: Exceptions caught in callbacks (each dropped what it was handling).
        self.callback_errors = 0
        self._init_transport()

    def _init_transport(self) -> None:
        """The transport's own state (called at the end of ``__init__``)."""

    def connect(self, timeout: float = 10.0) -> None:
        raise NotImplementedError

    def disconnect(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()

    @property
    def subscriptions(self) -> dict[str, int]:
        with self._lock:
            return dict(self._subscriptions)

    def _callback_failed(self, what: str, exc: Exception) -> None:
        """An exception out of a callback would end the transport's thread for good (paho
        re-raises it; rclpy's executor stops spinning): it is logged (the first with its
        traceback) and counted instead."""
        self.callback_errors += 1
        log.error("%s: %s dropped: %s: %.200s", self.client_id, what, type(exc).__name__, exc,
                  exc_info=self.callback_errors == 1)


#: Bytes a buffered client reads from the socket at once.
_READ_CHUNK = 65536


class _BufferedReadClient(paho.Client):
    """paho, reading the socket in chunks: paho asks for 1 byte (the command), 1 byte per
    remaining-length byte, then the rest, each a ``recv`` after a ``select`` per packet. With a
    buffer, one ``recv`` serves many small packets; `loop_read` goes on while whole packets are
    buffered (nothing in the kernel would wake ``select`` for them). For a subscriber of many
    small periodic messages (the operator page: 200 units x 2 Hz)."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self._rbuf = bytearray()

    def _sock_recv(self, bufsize: int) -> bytes:
        if not self._rbuf:
            chunk = super()._sock_recv(max(bufsize, _READ_CHUNK))  # BlockingIOError when empty
            if len(chunk) <= bufsize:
                return chunk  # also b"": connection closed
            self._rbuf += chunk
        data = bytes(self._rbuf[:bufsize])
        del self._rbuf[:bufsize]
        return data

    def loop_read(self, max_packets: int = 1) -> MQTTErrorCode:
        rc = super().loop_read(max_packets)
        while rc == paho.MQTT_ERR_SUCCESS and self._rbuf and self._sock is not None:
            before = len(self._rbuf)
            rc = super().loop_read(max_packets)
            if len(self._rbuf) >= before:  # nothing consumed: a partial packet waits
                break
        return rc

    def _sock_close(self) -> None:
        self._rbuf.clear()
        super()._sock_close()

_UNSUPPORTED_PROTOCOL = 132  # CONNACK reason "Unsupported protocol version" (v3 rc 1 maps here)


class MqttClient(ClientBase):
    """One paho client: connect (with protocol detection), subscribe in on_connect, publish.

    Received messages are handed to ``sink`` (by default put into ``self.messages``) on paho's
    thread; the sink must not block.
    """

    def _init_transport(self) -> None:
        self._connack = threading.Event()
        self._connack_code: int | None = None
        self._connack_reason = ""
        self._client: paho.Client | None = None
        self.protocol_version: MQTTProtocolVersion | None = None
        self.nodelay_sockets = 0
        #: Read the socket in chunks (`_BufferedReadClient`); set before `connect`.
        self.buffered_reads = False
        #: Ask the broker not to send back what this client publishes (MQTT 5 "No Local"; a
        #: 3.1.1 broker has no such option: see `no_local_active`); set before `connect`.
        self.no_local = False

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

    def _make_client(self, protocol: MQTTProtocolVersion) -> paho.Client:
        kind = _BufferedReadClient if self.buffered_reads else paho.Client
        client = kind(
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
            s = self.settings
            # Verification stays on: CERT_REQUIRED and a hostname check against ``host``.
            client.tls_set(
                ca_certs=s.ca_certs,
                certfile=s.certfile,
                keyfile=s.keyfile,
                cert_reqs=ssl.CERT_REQUIRED,
            )
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.on_message = self._on_message
        client.on_socket_open = self._on_socket_open
        return client

    def _try_connect(self, protocol: MQTTProtocolVersion, deadline: float) -> int:
        client = self._make_client(protocol)
        self._connack.clear()
        self._connack_code = None
        self._connack_reason = ""
        # The TCP connect (DNS, SYN to an unreachable host) is bounded by the same deadline.
        client.connect_timeout = max(0.1, deadline - time.monotonic())
        try:
            s = self.settings
            if protocol == paho.MQTTv5:
                client.connect(s.host, s.port, s.keepalive, clean_start=True)
            else:
                client.connect(s.host, s.port, s.keepalive)
        except (OSError, ValueError, ssl.SSLError) as exc:
            self._connack_reason = self._connect_failure(exc)
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

    def _connect_failure(self, exc: BaseException) -> str:
        """Why a connect failed, naming TLS when the handshake did: a TLS client on a plain
        MQTT port sees only "Connection reset by peer" or an SSL record error."""
        text = str(exc) or type(exc).__name__
        plain_port = (
            isinstance(exc, ConnectionResetError | ConnectionAbortedError | ssl.SSLEOFError)
            or (isinstance(exc, ssl.SSLError) and exc.reason in _PLAIN_PORT_SSL_REASONS)
            or (isinstance(exc, TimeoutError) and "handshake" in text)  # a broker that waits
        )  # not a certificate that fails to verify: that message says so already
        if self.settings.tls and plain_port:
            return (f"the TLS handshake failed ({text}); is port {self.settings.port} a plain "
                    "MQTT port? (--tls or WARAPS_TLS_CONNECTION asks for TLS)")
        return text

    def _shutdown_client(self) -> None:
        """Disconnect and stop paho's network thread, waiting at most `SHUTDOWN_TIMEOUT`: a stop
        must not hang on paho (a command stopped by SIGTERM while paho's thread is busy, or one
        of its locks taken when the signal unwound the main thread); its thread is a daemon."""
        client, self._client = self._client, None
        if client is None:
            return

        def stop() -> None:
            with contextlib.suppress(Exception):
                client.disconnect()
            client.loop_stop()

        if threading.current_thread() is getattr(client, "_thread", None):
            stop()  # from paho's own thread: loop_stop does not join it
            return
        stopper = threading.Thread(target=stop, name=f"{self.client_id}-stop", daemon=True)
        stopper.start()
        stopper.join(SHUTDOWN_TIMEOUT)
        if stopper.is_alive():
            log.warning("%s: paho's network thread did not stop within %.0f s; left behind",
                        self.client_id, SHUTDOWN_TIMEOUT)

    @property
    def loop_alive(self) -> bool:
        """paho's network thread runs (it ends for good on an exception it does not catch)."""
        client = self._client
        thread = getattr(client, "_thread", None) if client is not None else None
        return isinstance(thread, threading.Thread) and thread.is_alive()

    def restart(self, timeout: float = 10.0) -> None:
        """A new connection and network loop for one whose loop ended (paho never restarts a
        loop thread that died); subscriptions are renewed. `MqttConnectError` as `connect`."""
        self.connected.clear()
        self._shutdown_client()
        self.connect(timeout)

    def disconnect(self) -> None:
        """Disconnect cleanly and stop paho's thread (idempotent)."""
        self._shutdown_client()
        self.connected.clear()

    # ---- subscribe / publish

    def subscribe(self, pattern: str, qos: int = QOS_COMMAND) -> None:
        """Subscribe now (when connected) and again after every reconnect."""
        Wildcard(pattern)  # validate early, with a clear message
        with self._lock:
            self._subscriptions[pattern] = qos
        client = self._client
        if client is not None and self.connected.is_set():
            client.subscribe(self._sub_options(client, [(pattern, qos)]))

    @property
    def no_local_active(self) -> bool:
        """True when the broker was asked not to echo this client's messages (MQTT 5)."""
        return self.no_local and self.protocol_version == paho.MQTTv5

    def _sub_options(self, client: paho.Client, subs: list[tuple[str, int]]) -> list[Any]:
        """paho's subscribe list: with "No Local" on MQTT 5 when `no_local` is set."""
        if not (self.no_local and client.protocol == paho.MQTTv5):
            return list(subs)
        return [(pattern, SubscribeOptions(qos=qos, noLocal=True)) for pattern, qos in subs]

    def unsubscribe(self, pattern: str) -> None:
        with self._lock:
            self._subscriptions.pop(pattern, None)
        client = self._client
        if client is not None and self.connected.is_set():
            client.unsubscribe(pattern)

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
        try:
            code = int(getattr(reason, "value", reason))
            self._connack_code = code
            self._connack_reason = str(reason)
            if code == 0:
                with self._lock:
                    subs = list(self._subscriptions.items())
                if subs:
                    client.subscribe(self._sub_options(client, subs))
                self.connect_count += 1
                self.connected.set()
                if self._on_connection is not None:
                    self._on_connection(True, self.connect_count)
        except Exception as exc:
            self._callback_failed("connect", exc)
        finally:
            self._connack.set()

    def _on_disconnect(
        self, client: paho.Client, userdata: Any, flags: Any, reason: Any, properties: Any
    ) -> None:
        was_up = self.connected.is_set()
        self.connected.clear()
        log.debug("%s disconnected: %s", self.client_id, reason)
        # Only a connection that was up is lost: the refused MQTT 5 attempt before falling back to
        # 3.1.1 (amqtt) closes too, and told as a loss it left the unit offline for good.
        if self._on_connection is not None and was_up:
            try:
                self._on_connection(False, self.connect_count)
            except Exception as exc:
                self._callback_failed("disconnect", exc)

    def _on_message(self, client: paho.Client, userdata: Any, msg: paho.MQTTMessage) -> None:
        try:
            self._sink(_message_from_paho(msg))
        except Exception as exc:
            self._callback_failed(f"a message on {msg.topic[:200]}", exc)
