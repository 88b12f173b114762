"""A client of a running delegation service: send commands, get answers, follow missions.

Used by ``delegation submit`` and ``delegation demo`` (and by tests and the latency benchmark).
Commands are re-sent with the same com-uuid until answered, as the seed prescribes for unreliable
links; the service answers a re-send with the same answer and never runs it twice.
"""

from __future__ import annotations

import getpass
import json
import os
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
from delegation.runtime.lifecycle import StartStop
from delegation.runtime.mqtt import Message
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.transport import make_client
from delegation.topics import (
    DEFAULT_PREFIX,
    QOS_COMMAND,
    Wildcard,
    base_from_heartbeat,
    parse_unit_topic,
)


def default_sender() -> str:
    """``WARAPS_SENDER``, else the login name (``delegation`` when there is none)."""
    name = os.environ.get("WARAPS_SENDER", "").strip()
    if name:
        return name
    try:
        return getpass.getuser() or "delegation"
    except (KeyError, OSError):  # no passwd entry (containers)
        return "delegation"


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


class ServiceClient(StartStop):
    """Talks to the service named ``service`` under ``prefix`` on a broker."""

    def __init__(
        self,
        settings: BrokerSettings,
        prefix: str = DEFAULT_PREFIX,
        service: str = "delegator0",
        track_positions: bool = False,
        clock: Callable[[], float] = time.time,
        service_timeout: float = 10.0,
        sender: str | None = None,
    ) -> None:
        self.prefix = prefix
        #: Who this client is to the service (``sender`` of its commands): the owner of the
        #: missions it starts, so the same operator can cancel or signal them from another
        #: process. ``WARAPS_SENDER``, else the login name.
        self.sender = sender or default_sender()
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
        self.client = make_client(settings, f"client-{uuid.uuid4().hex[:8]}", sink=self._sink)
        for name, wc in self._filters.items():
            if name != "position" or track_positions:
                self.client.subscribe(wc.value, QOS_COMMAND)

    # ---- lifecycle

    def start(self, timeout: float = 10.0) -> ServiceClient:
        self.client.connect(timeout=timeout)
        return self

    def stop(self) -> None:
        self.client.disconnect()

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
        body.setdefault("sender", self.sender)
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

    # ---- the Delegation API, one helper per command (``delegation missions``, ``status``, ...)

    def _ok(self, command: dict[str, Any], key: str | None, api: str = "delegation",
            timeout: float = 30.0) -> Any:
        answer = self.request(command, api=api, timeout=timeout)
        if answer.get("response") not in ("ok", "started"):
            raise CommandFailed(str(answer.get("fail-reason") or answer.get("response")))
        return answer.get(key) if key else answer

    def list_missions(self) -> list[dict[str, Any]]:
        """Every mission the service knows (``list-missions``), oldest first."""
        return list(self._ok({"command": "list-missions"}, "missions") or [])

    def query_mission(self, root_uuid: str) -> dict[str, Any]:
        """One mission with its nodes, plan and times (``query-mission``)."""
        return dict(self._ok({"command": "query-mission", "root-uuid": root_uuid}, "mission"))

    def cancel_mission(self, root_uuid: str, timeout: float = 30.0) -> None:
        """Abort a mission (``cancel-mission``); `CommandFailed` with the service's reason."""
        self._ok({"command": "cancel-mission", "root-uuid": root_uuid}, None, timeout=timeout)

    def signal_mission(self, root_uuid: str, signal: str) -> None:
        """``signal-tst-tree`` on the service's TST face (``$enough``, ``$pause``, ...)."""
        self._ok({"command": "signal-tst-tree", "node-uuid": root_uuid, "signal": signal},
                 None, api="tst")

    def get_bids(self, tst: dict[str, Any], timeout: float = 60.0) -> list[dict[str, Any]]:
        """Every task x live unit estimate for a tree (``get-bids``)."""
        return list(self._ok({"command": "get-bids", "tst": tst}, "bids", timeout=timeout) or [])

    def list_agents(self) -> list[dict[str, Any]]:
        """The live units the service would plan for (``list-agents``)."""
        return list(self._ok({"command": "list-agents"}, "agents") or [])

    def resolve_mission(self, prefix: str) -> str:
        """The full root-uuid of the one mission whose id starts with ``prefix``.

        `CommandFailed` (one line) when none or several match; an exact id always wins.
        """
        wanted = prefix.strip().lower()
        ids = [str(m.get("root-uuid", "")) for m in self.list_missions()]
        if wanted in ids:
            return wanted
        found = [i for i in ids if i.lower().startswith(wanted)] if wanted else []
        if len(found) == 1:
            return found[0]
        if not found:
            raise CommandFailed(
                f"no mission id starts with {prefix!r} ({len(ids)} missions known to "
                f"{self.service}; list them with 'delegation missions')"
            )
        shown = ", ".join(found[:4]) + (", ..." if len(found) > 4 else "")
        raise CommandFailed(f"{prefix!r} is ambiguous: {len(found)} missions match ({shown})")


class CommandFailed(DelegationError):
    """The service answered a command with ``failed`` (the message is its fail-reason)."""
