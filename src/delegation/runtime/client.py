"""A client of a running delegation service: send commands, get answers, follow missions.

Used by ``delegation submit`` and ``delegation demo`` (and by tests and the latency benchmark).
Commands are re-sent with the same com-uuid until answered, as the seed prescribes for unreliable
links; the service answers a re-send with the same answer and never runs it twice.
"""

from __future__ import annotations

import json
import queue
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from delegation.errors import DelegationError
from delegation.geo import GeoPoint
from delegation.messages import json_value, new_com_uuid, parse_sensor
from delegation.runtime.mqtt import Message, MqttClient
from delegation.runtime.settings import BrokerSettings
from delegation.topics import (
    DEFAULT_PREFIX,
    QOS_COMMAND,
    Wildcard,
    base_from_heartbeat,
    parse_unit_topic,
)


class ServiceUnavailable(DelegationError):
    """No delegation service answered (no heartbeat, or no response before the deadline)."""


@dataclass(frozen=True, slots=True)
class Event:
    """Something the service (or a unit) said: ``kind`` is ``tst-feedback``, ``mission`` or
    ``position``; ``data`` the decoded JSON (a GeoPoint for positions)."""

    kind: str
    unit: str
    data: Any
    at: float


class ServiceClient:
    """Talks to the service named ``service`` under ``prefix`` on a broker."""

    def __init__(
        self,
        settings: BrokerSettings,
        prefix: str = DEFAULT_PREFIX,
        service: str = "delegator0",
        track_positions: bool = False,
        clock: Callable[[], float] = time.time,
        service_timeout: float = 10.0,
    ) -> None:
        self.prefix = prefix
        self.service_timeout = service_timeout
        self.service = service
        self.clock = clock
        self.events: queue.Queue[Event] = queue.Queue()
        self.base: str | None = None
        self._cond = threading.Condition()
        # Answers are kept only for the com-uuids this client is waiting for (every client sees
        # every answer on the service's response topics): bounded by the requests in flight.
        self._waiting: set[str] = set()
        self._responses: dict[str, dict[str, Any]] = {}
        self._svc = f"{prefix}/unit/+/+/{service}"
        self._filters = {
            "heartbeat": Wildcard(f"{self._svc}/heartbeat"),
            "response": Wildcard(f"{self._svc}/+/response"),
            "tst-feedback": Wildcard(f"{self._svc}/tst/feedback"),
            "mission": Wildcard(f"{self._svc}/delegation/feedback"),
            "position": Wildcard(f"{prefix}/unit/+/+/+/sensor/position"),
        }
        self.client = MqttClient(settings, f"client-{uuid.uuid4().hex[:8]}", sink=self._sink)
        for name, wc in self._filters.items():
            if name != "position" or track_positions:
                self.client.subscribe(wc.value, QOS_COMMAND)

    # ---- lifecycle

    def start(self, timeout: float = 10.0) -> ServiceClient:
        self.client.connect(timeout=timeout)
        return self

    def stop(self) -> None:
        self.client.disconnect()

    def __enter__(self) -> ServiceClient:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---- receiving (paho's thread: decode and hand over only)

    def _sink(self, msg: Message) -> None:
        now = self.clock()
        f = self._filters
        if f["position"].matches(msg.topic):
            parsed = parse_unit_topic(msg.topic)
            try:
                value = parse_sensor("position", msg.payload)
            except DelegationError:
                return
            if parsed is not None and isinstance(value, GeoPoint):
                self.events.put(Event("position", parsed.name, value, now))
            return
        try:
            data = json_value(msg.payload)
        except DelegationError:
            return
        if not isinstance(data, dict):
            return
        if f["heartbeat"].matches(msg.topic):
            with self._cond:
                self.base = base_from_heartbeat(msg.topic)
                self._cond.notify_all()
        elif f["response"].matches(msg.topic):
            to = data.get("response-to")
            if isinstance(to, str):
                with self._cond:
                    if to in self._waiting:
                        self._responses.setdefault(to, data)
                        self._cond.notify_all()
        elif f["tst-feedback"].matches(msg.topic):
            self.events.put(Event("tst-feedback", self.service, data, now))
        elif f["mission"].matches(msg.topic):
            self.events.put(Event("mission", self.service, data, now))

    # ---- requests

    @property
    def answers_held(self) -> int:
        """Answers received and not yet taken by their request (0 when idle)."""
        with self._cond:
            return len(self._responses)

    def wait_service(self, timeout: float = 10.0) -> str:
        """The service's base topic, learned from its heartbeat."""
        with self._cond:
            if not self._cond.wait_for(lambda: self.base is not None, timeout):
                raise ServiceUnavailable(
                    f"no heartbeat from {self.service!r} under {self.prefix} within {timeout:g} s"
                )
            assert self.base is not None
            return self.base

    def request(
        self,
        command: dict[str, Any],
        api: str = "delegation",
        timeout: float = 30.0,
        resend_every: float = 3.0,
    ) -> dict[str, Any]:
        """Send a command (``com-uuid`` and ``sender`` added if missing) and return the answer.

        Re-sent with the same com-uuid every ``resend_every`` s until answered.
        """
        base = self.wait_service(min(timeout, self.service_timeout))
        body = dict(command)
        body.setdefault("com-uuid", new_com_uuid())
        body.setdefault("sender", self.client.client_id)
        com = body["com-uuid"]
        payload = json.dumps(body).encode("utf-8")
        topic = f"{base}/{api}/command"
        deadline = time.monotonic() + timeout
        with self._cond:
            self._waiting.add(com)
        try:
            while True:
                self.client.publish(topic, payload, qos=QOS_COMMAND)
                wait = min(resend_every, deadline - time.monotonic())
                with self._cond:
                    if self._cond.wait_for(lambda: com in self._responses, max(0.0, wait)):
                        return self._responses[com]
                if time.monotonic() >= deadline:
                    raise ServiceUnavailable(
                        f"{self.service} did not answer {body.get('command')!r} "
                        f"within {timeout:g} s"
                    )
        finally:
            with self._cond:
                self._waiting.discard(com)
                self._responses.pop(com, None)
