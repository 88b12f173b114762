"""The page's MQTT side: one connection feeds the live view and carries commands to the service.

paho's thread does the least it can per message: split the topic, ``json.loads`` the payload and
apply it to the view under a short lock (no pydantic on the hot path: 200 units at 2 Hz are some
2400 messages a second). A ticker thread marks lost units at 1 Hz and a fetch thread asks the
service (``query-mission``) about missions heard of in feedback. asyncio SSE streams register a
waker; mission, node and log changes wake them with ``loop.call_soon_threadsafe`` (unit moves do
not: streams pick them up on their 500 ms coalescing tick).

Commands go to the service with the caller's ``sender``, so the service's own authorisation
(owners, ``--operator``) applies exactly as over MQTT.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import queue
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from delegation.errors import DelegationError
from delegation.messages.errors import json_value
from delegation.runtime.client import ServiceClient, ServiceUnavailable
from delegation.runtime.mqtt import Message, MqttClient, MqttError
from delegation.runtime.settings import BrokerSettings
from delegation.topics import DEFAULT_PREFIX, QOS_COMMAND, QOS_PERIODIC
from delegation.tst import without_node_uuids
from delegation.web.geometry import plan_geometry
from delegation.web.mission_input import with_node_uuids
from delegation.web.view import SIGNALS, LiveView, node_uuid_of

log = logging.getLogger(__name__)

STRATEGIES = ("nearest", "auction", "optimal")
#: Previewed trees kept (with their node uuids) so that Start sends the very tree previewed.
PREVIEWED = 256
OBJECTIVES = ("makespan", "total")
_BATTERY = ("battery_state", "battery", "battery_level")


def _decode(payload: bytes) -> Any:
    """A payload as plain JSON, or None for anything else (not UTF-8, too deep, NaN, 1e400,
    huge integers): the page's streams must stay JSON a browser parses."""
    try:
        return json_value(payload, max_depth=None)
    except DelegationError:
        return None


#: Unit topics the view reads (everything else a unit sends is not subscribed to).
_UNIT_TOPICS = ("heartbeat", "direct_execution_info", "delegation_info", "sensor/position",
                "sensor/heading", "sensor/speed", *(f"sensor/{b}" for b in _BATTERY))


class ApiError(DelegationError):
    """A request the page cannot serve: an HTTP status and the service's (or our) reason."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason


def _status_of(reason: str) -> int:
    """The HTTP status for a service's ``failed`` answer."""
    if "is neither its owner nor an operator" in reason:
        return 403
    if "unknown mission" in reason:
        return 404
    if "no TST engine" in reason:
        return 503
    return 400


class _Client(ServiceClient):
    """The service client whose connection also carries the units' and the service's feedback
    into the bridge (one MQTT connection)."""

    def __init__(self, take: Callable[[Message], bool], settings: BrokerSettings,
                 **kw: Any) -> None:
        self._take = take  # set before the client exists: its sink is this object's _sink
        super().__init__(settings, **kw)
        if isinstance(self.client, MqttClient):  # ROS 2 has no socket of ours to read
            self.client.buffered_reads = True  # many small messages: one recv serves many

    def _sink(self, msg: Message) -> None:
        if not self._take(msg):
            super()._sink(msg)

    def abort(self) -> None:
        """Answer every request still waiting with ``failed`` (the page is stopping), so that
        no thread waits out its deadline."""
        with self._cond:
            for com in self._waiting:
                self._responses.setdefault(com, {"response": "failed",
                                                 "fail-reason": "the page is stopping"})
            self._cond.notify_all()


class Bridge:
    """Live view + commands. `start`/`stop`, or a context manager."""

    def __init__(
        self,
        settings: BrokerSettings,
        *,
        prefix: str = DEFAULT_PREFIX,
        service: str = "delegator0",
        sender: str | None = None,
        clock: Callable[[], float] = time.time,
        request_timeout: float = 30.0,
        time_scale: float = 1.0,
    ) -> None:
        """``time_scale``: mission seconds per wall second (a simulated fleet's speed-up), so that
        elapsed and actual times compare with the plan's."""
        self.prefix = prefix
        self.service = service
        self.clock = clock
        self.request_timeout = request_timeout
        self.view = LiveView(scale=time_scale)
        self.lock = threading.Lock()
        self._levels = len(prefix.split("/"))
        self._routes: dict[str, tuple[str, str, str, str]] = {}
        # MQTT 3.1.1: the page needs nothing of v5, and paho parses v5 properties on every
        # message (a quarter of its read path under 200 units x 2 Hz, py-spy).
        if settings.protocol == "auto":
            settings = settings.model_copy(update={"protocol": "3.1.1"})
        self.client = _Client(self._take, settings, prefix=prefix, service=service,
                              sender=sender, service_timeout=5.0)
        self.sender = self.client.sender
        for rest in _UNIT_TOPICS:
            self.client.client.subscribe(f"{prefix}/unit/+/+/+/{rest}", QOS_PERIODIC)
        self._stop = threading.Event()
        self._fetch: queue.Queue[str | None] = queue.Queue()
        self._threads: list[threading.Thread] = []
        self._wakers: dict[int, tuple[asyncio.AbstractEventLoop, asyncio.Event]] = {}
        self._wake_lock = threading.Lock()
        self._pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="ui-cmd")
        #: (sender, preview-id) -> the tree previewed, node uuids and all (oldest first).
        self._previewed: OrderedDict[tuple[str, str], dict[str, Any]] = OrderedDict()
        self._previewed_lock = threading.Lock()
        self.messages = 0
        #: Messages the view could not take (see `_take`).
        self.dropped = 0

    # ------------------------------------------------------------------ lifecycle

    def start(self, timeout: float = 10.0) -> Bridge:
        self.client.start(timeout=timeout)
        for name, target in (("ui-tick", self._ticker), ("ui-fetch", self._fetcher)):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        self._fetch.put("")  # "": list the service's missions first
        return self

    def stop(self) -> None:
        self._stop.set()
        self._fetch.put(None)
        self.client.abort()
        self.client.stop()
        for t in self._threads:
            t.join(timeout=5.0)
        self._threads.clear()
        self._pool.shutdown(wait=False, cancel_futures=True)
        self.wake()

    def __enter__(self) -> Bridge:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ paho's thread

    def _route(self, topic: str) -> tuple[str, str, str, str] | None:
        """(what, base, name, agent type) for a topic, cached (a fleet has a few topics per
        unit): ``what`` is the suffix after the base, or ``""`` for the service client."""
        route = self._routes.get(topic)
        if route is not None:
            return route
        levels = topic.split("/")
        p = self._levels
        if len(levels) < p + 5 or levels[p] != "unit":
            return None
        name, rest = levels[p + 3], "/".join(levels[p + 4 :])
        if name == self.service and rest not in ("tst/feedback", "delegation/feedback"):
            rest = ""
        route = (rest, "/".join(levels[: p + 4]), name, levels[p + 1])
        if len(self._routes) < 20_000:
            self._routes[topic] = route
        return route

    def _take(self, msg: Message) -> bool:
        """Apply one message to the view; False hands it to the service client (answers, the
        service's heartbeat). A message the view cannot take is dropped and counted: nothing
        may escape paho's network loop (issue 23)."""
        route = self._route(msg.topic)
        if route is None or not route[0]:
            return False
        try:
            self._apply(msg, *route)
        except Exception as exc:  # a bug the payload found: drop it, keep the loop
            self.dropped += 1
            log.warning("ui: message on %.200s dropped: %s: %.200s", msg.topic,
                        type(exc).__name__, exc, exc_info=self.dropped == 1)
        return True

    def _apply(self, msg: Message, rest: str, base: str, name: str, kind: str) -> None:
        if name == self.service:
            self._feedback(msg, node=rest == "tst/feedback")
            return
        data = _decode(msg.payload)
        if data is None:
            return
        now = self.clock()
        self.messages += 1
        with self.lock:
            view = self.view
            if rest == "sensor/position":
                view.position(base, name, kind, data, now)
            elif rest.startswith("sensor/"):
                view.sensor(base, name, kind, rest[7:], data, now)
            elif not isinstance(data, dict):
                pass
            elif rest == "heartbeat":
                view.heartbeat(base, name, kind, data, now)
            elif rest == "direct_execution_info":
                view.execution_info(base, name, kind, data, now)
            elif rest == "delegation_info":
                view.delegation_info(base, name, data)
            elif rest == "tst/feedback":  # an engine's: for shared searches' parts alone
                view.engine_feedback(name, data, now)

    def _feedback(self, msg: Message, *, node: bool) -> None:
        data = _decode(msg.payload)
        if not isinstance(data, dict):
            return
        now = self.clock()
        with self.lock:
            if node:
                self.view.node_feedback(data, now)
            else:
                self.view.mission_feedback(data, now)
            wanted = self.view.drain_fetch()
        for root in wanted:
            self._fetch.put(root)
        self._listen_engines()
        self.wake()

    # ------------------------------------------------------------------ background threads

    def _listen_engines(self) -> None:
        """Listen to the feedback of engines running missions with shared searches (the parts'
        statuses: the service relays none, DESIGN 3.4); their other feedback is ignored."""
        with self.lock:
            engines = self.view.drain_engines()
        for engine in engines:
            if engine != self.service:
                self.client.client.subscribe(f"{self.prefix}/unit/+/+/{engine}/tst/feedback",
                                             QOS_COMMAND)

    def _ticker(self) -> None:
        while not self._stop.wait(1.0):
            self._listen_engines()
            self._revive()
            with self.lock:
                lost = self.view.tick(self.clock())
            if lost:
                self.wake()

    def _revive(self) -> None:
        """Reconnect when paho's network loop ended (it never restarts by itself): otherwise the
        page stops updating for good while ``connected`` stays set."""
        mqtt = self.client.client
        if mqtt.loop_alive or self._stop.is_set():
            return
        log.warning("ui: the MQTT network loop ended; reconnecting")
        try:
            mqtt.restart(timeout=5.0)
        except MqttError as exc:
            log.warning("ui: reconnecting failed (tried again in a second): %s", exc)
            return
        self._fetch.put("")  # what changed meanwhile

    def _fetcher(self) -> None:
        while True:
            root = self._fetch.get()
            if root is None or not self._service_seen():
                return
            try:
                if root == "":
                    self._list_missions()
                else:
                    self._query(root)
            except (DelegationError, OSError) as exc:
                log.info("ui: could not fetch %s: %s", root or "the missions", exc)
            self.wake()

    def _service_seen(self) -> bool:
        """Wait for the service's heartbeat in short slices; False once stopping."""
        while not self._stop.is_set():
            try:
                self.client.wait_service(0.5)
                return True
            except ServiceUnavailable:
                continue
        return False

    def _list_missions(self) -> None:
        answer = self.client.request({"command": "list-missions", "limit": 100},
                                     timeout=self.request_timeout)
        if answer.get("response") != "ok":
            return
        total = int(answer.get("total") or 0)
        rows = list(answer.get("missions") or [])
        if total > 100:  # the newest page too
            last = self.client.request({"command": "list-missions", "limit": 100,
                                        "offset": total - 100}, timeout=self.request_timeout)
            rows += list(last.get("missions") or [])
        now = self.clock()
        with self.lock:
            for row in rows:
                if isinstance(row, dict):
                    self.view.mission_summary(row, now)
            wanted = self.view.drain_fetch()
        ended = {r.get("root-uuid") for r in rows if isinstance(r, dict)
                 and r.get("status") in ("succeeded", "failed", "aborted")}
        for root in wanted:
            if root not in ended:
                self._fetch.put(root)
        self._listen_engines()

    def _query(self, root: str) -> None:
        answer = self.client.request({"command": "query-mission", "root-uuid": root},
                                     timeout=self.request_timeout)
        if answer.get("response") == "ok" and isinstance(answer.get("mission"), dict):
            with self.lock:
                self.view.mission_answer(answer["mission"], self.clock())
            self._listen_engines()

    # ------------------------------------------------------------------ waking SSE streams

    def add_waker(self, loop: asyncio.AbstractEventLoop, event: asyncio.Event) -> int:
        with self._wake_lock:
            key = id(event)
            self._wakers[key] = (loop, event)
            return key

    def remove_waker(self, key: int) -> None:
        with self._wake_lock:
            self._wakers.pop(key, None)

    def wake(self) -> None:
        """Wake every SSE stream (any thread)."""
        with self._wake_lock:
            wakers = list(self._wakers.values())
        for loop, event in wakers:
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                loop.call_soon_threadsafe(event.set)

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    # ------------------------------------------------------------------ reads

    def state(self, sees: Callable[[str], bool] | None = None) -> dict[str, Any]:
        """The view's state; with ``sees``, only the missions it allows (`LiveView.state`)."""
        with self.lock:
            return self.view.state(self.clock(), sees)

    # ------------------------------------------------------------------ commands (blocking)

    def _request(self, command: dict[str, Any], sender: str, api: str = "delegation",
                 timeout: float | None = None) -> dict[str, Any]:
        """One command with the caller's sender; 503 without a service, 504 without an answer."""
        try:
            self.client.wait_service(min(5.0, timeout or self.request_timeout))
        except ServiceUnavailable as exc:
            raise ApiError(503, str(exc)) from None
        try:
            return self.client.request({**command, "sender": sender}, api=api,
                                       timeout=timeout or self.request_timeout)
        except ServiceUnavailable as exc:
            raise ApiError(504, str(exc)) from None

    def _planned(self, tree: dict[str, Any], strategy: str, objective: str | None,
                 time_limit: float | None, sender: str) -> dict[str, Any]:
        """One preview plan with geometry, or {"fail-reason"}: the service answers it and
        stores nothing (``preview``)."""
        fresh = with_node_uuids(without_node_uuids(tree))
        command: dict[str, Any] = {"command": "delegate", "tst": fresh,
                                   "strategy": strategy, "preview": True}
        if objective:
            command["objective"] = objective
        if time_limit:
            command["time-limit"] = time_limit
        answer = self._request(command, sender, timeout=self.request_timeout + (time_limit or 0))
        plan = answer.get("plan")
        if answer.get("response") != "ok" or not isinstance(plan, dict):
            out: dict[str, Any] = {"fail-reason": str(answer.get("fail-reason") or "not planned")}
            if isinstance(plan, dict):
                out["plan"] = plan
            return out
        preview_id = plan.get("preview-id")
        if isinstance(preview_id, str):
            with self._previewed_lock:
                self._previewed[(sender, preview_id)] = fresh
                while len(self._previewed) > PREVIEWED:
                    self._previewed.popitem(last=False)
        with self.lock:
            starts = self.view.unit_positions()
        routes, tasks = plan_geometry(plan, starts)
        return {**plan, "notes": list(plan.get("notes") or []), "routes": routes, "tasks": tasks}

    def plan(self, tree: dict[str, Any], strategies: list[str], objective: str | None,
             time_limit: float | None, sender: str) -> dict[str, Any]:
        """POST /api/plan: a plan per strategy, nothing started (in parallel)."""
        futures = {s: self._pool.submit(self._planned, tree, s, objective, time_limit, sender)
                   for s in strategies}
        out: dict[str, Any] = {}
        for s, fut in futures.items():
            try:
                out[s] = fut.result()
            except ApiError as exc:
                if exc.status in (503, 504) and len(strategies) == 1:
                    raise
                out[s] = {"fail-reason": exc.reason}
        return out

    def _previewed_tree(self, tree: dict[str, Any], sender: str,
                        preview_id: str) -> dict[str, Any] | None:
        """The tree ``sender`` previewed as ``preview_id`` (its node uuids: those of the plan
        the service keeps), when ``tree`` is that mission; else None."""
        with self._previewed_lock:
            previewed = self._previewed.get((sender, preview_id))
        if previewed is None or without_node_uuids(previewed) != without_node_uuids(tree):
            return None
        return previewed

    def start_mission(self, tree: dict[str, Any], strategy: str | None, objective: str | None,
                      time_limit: float | None, sender: str,
                      preview_id: str | None = None) -> dict[str, Any]:
        """POST /api/missions: start a mission; {"id", "plan"}. With ``preview_id`` the service
        starts that previewed plan (or plans again and says why in ``plan["from-preview"]``)."""
        previewed = self._previewed_tree(tree, sender, preview_id) if preview_id else None
        tree = previewed or with_node_uuids(tree)
        command: dict[str, Any] = {"command": "delegate", "tst": tree, "start": True}
        if preview_id:
            command["preview-id"] = preview_id
        for key, value in (("strategy", strategy), ("objective", objective),
                           ("time-limit", time_limit)):
            if value:
                command[key] = value
        answer = self._request(command, sender, timeout=self.request_timeout * 4)
        if answer.get("response") != "started":
            reason = str(answer.get("fail-reason") or answer.get("response"))
            raise ApiError(_status_of(reason), reason)
        plan = dict(answer.get("plan") or {})
        root = node_uuid_of(plan.get("tst") or {}) or ""
        said = plan.get("from-preview")
        # The service started a previewed tree this page did not keep (other node uuids): the
        # operator's tree is read back with query-mission instead.
        shown = None if isinstance(said, dict) and said.get("started") and previewed is None \
            else tree
        with self.lock:
            self.view.mission_planned(root, plan, shown, sender, self.clock())
        self._listen_engines()
        self.wake()
        return {"id": root, "plan": plan}

    def _ok(self, answer: dict[str, Any]) -> dict[str, Any]:
        if answer.get("response") in ("ok", "pending", "started"):
            return answer
        reason = str(answer.get("fail-reason") or answer.get("response"))
        raise ApiError(_status_of(reason), reason)

    def cancel(self, root: str, sender: str) -> str:
        answer = self._ok(self._request({"command": "cancel-mission", "root-uuid": root}, sender,
                                        timeout=max(self.request_timeout, 30.0)))
        return str(answer.get("response"))

    def signal(self, root: str, signal: str, sender: str) -> str:
        if signal not in SIGNALS:
            raise ApiError(400, f"signal: must be one of {', '.join(SIGNALS)}, not {signal!r}")
        answer = self._ok(self._request(
            {"command": "signal-tst-tree", "node-uuid": root, "signal": signal}, sender,
            api="tst"))
        return str(answer.get("response"))

    def missions_of(self, user: str) -> set[str]:
        """The root-uuids `list-missions` answers ``user``: what the service lets them see
        (their own, every one for an operator)."""
        seen: set[str] = set()
        offset = 0
        while True:
            answer = self._ok(self._request({"command": "list-missions", "limit": 1000,
                                             "offset": offset}, user))
            rows = answer.get("missions") or []
            seen.update(str(r.get("root-uuid")) for r in rows if isinstance(r, dict))
            following = answer.get("next")
            if not isinstance(following, int) or following <= offset:
                return seen
            offset = following

    def mission(self, root: str, sender: str) -> dict[str, Any]:
        """GET /api/missions/{id}: asked of the service as the caller (owners apply), merged
        with what the page saw (node times, the operator's tree, routes and tasks)."""
        answer = self._ok(self._request({"command": "query-mission", "root-uuid": root}, sender))
        mission = answer.get("mission")
        if not isinstance(mission, dict):
            raise ApiError(404, f"root-uuid: unknown mission {root!r}")
        now = self.clock()
        with self.lock:
            view = self.view
            view.mission_answer(mission, now)
            out = view.mission_json(root, now)
            rec = view.mission_record(root)
            if out is None:  # one of the page's own dry-run plans
                raise ApiError(404, f"root-uuid: {root!r} is a preview, not a mission")
            tree = view.node_tree(root)
            plan = rec.shown_plan if rec is not None else None
            starts = dict(rec.starts) if rec is not None else {}
        self._listen_engines()
        routes, tasks = plan_geometry(plan, starts) if plan is not None else ({}, [])
        if plan is not None:
            plan.setdefault("notes", list(mission.get("notes") or []))
        return {**out, "tree": tree, "plan": plan, "routes": routes, "tasks": tasks}
