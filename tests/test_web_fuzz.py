"""Any payload on any topic the page or the units read: nothing escapes a paho callback, the page
keeps updating and a mission still runs to the end (issue 23: ~100,000 ``[`` on one heartbeat
raised RecursionError out of the bridge's network loop and the page froze for good). A bridge
whose network loop ended anyway reconnects by itself.

A real system (service, engine, two simulated units) and the page's bridge on the private broker;
payloads from hypothesis and the named nasty cases.
"""

from __future__ import annotations

import gc
import json
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import httpx
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import Collector
from delegation.fleet import make_unit
from delegation.local import LocalSystem
from delegation.runtime.broker import LocalBroker
from delegation.runtime.mqtt import MqttClient
from delegation.topics import Wildcard
from delegation.web.app import create_app
from delegation.web.bridge import Bridge
from delegation.web.server import WebServer
from test_web_api import FRAME, SPEEDUP, TASKS, Events, pt

pytestmark = [pytest.mark.mqtt, pytest.mark.slow]

NASTY: list[bytes] = [
    b"[" * 100_000,
    b'{"a":' * 100_000,
    b"9" * 5000,  # more digits than int() converts
    b"-" + b"9" * 4000,  # converts, but overflows float()
    b"1e400",
    b'{"latitude": 1e400, "longitude": -1e400, "altitude": NaN}',
    b'{"latitude": ' + b"9" * 4000 + b', "longitude": 16.0}',
    b"NaN", b"Infinity", b"-Infinity", b"null", b"true", b"\"\"", b"",
    b"\xff\xfe\x00\x80 invalid utf-8 \xc3\x28",
    b'{"name": "\xff\xfe", "agent-uuid": "\xed\xa0\x80"}',
    b"x" * (256 * 1024 + 1),
    json.dumps({"value": {"value": {"value": {"value": 10**300}}}}).encode(),
    json.dumps({"levels": [["direct execution"]], "name": ["dji0"], "rate": {"x": 1},
                "agent-type": {}, "agent-uuid": 7, "tasks-available": [None, 1, {"name": 2}],
                "tasks-executing": "x"}).encode(),
    json.dumps({"status": ["running"], "root-uuid": {"a": 1}, "node-uuid": [1], "com-uuid": {},
                "response-to": None, "time": 1e308, "tasks": "x", "mission": []}).encode(),
]

KEYS = ["latitude", "longitude", "altitude", "name", "agent-uuid", "agent-type", "levels",
        "rate", "status", "node-uuid", "root-uuid", "com-uuid", "response-to", "command",
        "tasks-available", "tasks-executing", "value", "time", "mission", "sender", "tst"]
SCALARS = st.one_of(st.none(), st.booleans(), st.integers(-(10**30), 10**30),
                    st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=20),
                    st.sampled_from(["dji0", "running", "succeeded", "direct execution", ""]))
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.sampled_from(KEYS), inner, max_size=6)),
    max_leaves=20)
PAYLOADS = st.one_of(st.binary(max_size=300), VALUES.map(lambda v: json.dumps(v).encode()),
                     st.dictionaries(st.sampled_from(KEYS), VALUES, max_size=8).map(
                         lambda v: json.dumps(v).encode()))


@dataclass
class Fuzzed:
    system: LocalSystem
    bridge: Bridge
    url: str
    topics: list[str]
    sender: MqttClient


def _topics(prefix: str, bases: list[str]) -> list[str]:
    """A concrete topic for every subscription of every client of this system (its units' own
    bases where a wildcard allows, and a made-up unit's)."""
    patterns = {p for c in gc.get_objects() if isinstance(c, MqttClient)
                for p in c.subscriptions if p.startswith(f"{prefix}/")}
    topics: set[str] = set()
    for pattern in patterns:
        levels = pattern.split("/")
        topics.add("/".join("fuzz" if x in ("+", "#") else x for x in levels))
        tail = "/".join(levels[5:])
        for base in bases:
            if tail and "#" not in tail and "+" not in tail:
                candidate = f"{base}/{tail}"
                if Wildcard(pattern).matches(candidate):
                    topics.add(candidate)
    return sorted(topics)


@pytest.fixture(scope="module")
def fuzzed(broker: LocalBroker) -> Iterator[Fuzzed]:
    settings_ = broker.settings()
    prefix = f"fz-{uuid.uuid4().hex[:8]}"
    units = [make_unit(n, "air", FRAME.geopoint(x, 0.0, 30.0), TASKS)
             for n, x in (("dji0", 0.0), ("dji1", 40.0))]
    with LocalSystem(units, settings=settings_, prefix=prefix, speedup=SPEEDUP) as system:
        bridge = Bridge(settings_, prefix=prefix, service=system.config.name).start()
        server = WebServer(create_app(bridge), "127.0.0.1", 0).start()
        sender = MqttClient(settings_)
        sender.connect()
        beats = Collector(settings_, [f"{prefix}/unit/+/+/+/heartbeat"]).start()
        try:
            deadline = time.monotonic() + 15.0
            # Both units seen, their bases known (not any two: the engine's and the service's
            # heartbeats count as units too, and under load they can come first): the view is
            # looked at again on each heartbeat, until the deadline. (It waited 1 s for the
            # service's first heartbeat, failed at load average 20, and then spun.)
            try:
                bridge.client.wait_service(max(0.0, deadline - time.monotonic()))
                while not {"dji0", "dji1"} <= set(bridge.view.units):
                    old = {id(m) for m in beats.messages}
                    beats.wait_for(lambda m, old=old: id(m) not in old,
                                   timeout=max(0.0, deadline - time.monotonic()),
                                   what="a heartbeat while the page had not seen both units")
            finally:
                beats.stop()
            bases = [u.base for u in bridge.view.units.values()]
            service = f"{prefix}/unit/{system.config.agent_type}/{system.config.role}/" \
                      f"{system.config.name}"
            yield Fuzzed(system, bridge, server.url, _topics(prefix, [*bases, service]), sender)
        finally:
            sender.disconnect()
            server.stop()
            bridge.stop()


def _flood(f: Fuzzed, payload: bytes) -> None:
    for topic in f.topics:
        f.sender.publish(topic, payload, qos=0)


def _alive_and_updating(f: Fuzzed, timeout: float = 20.0) -> None:
    """The page's loop runs, its state is strict JSON, and it takes new unit positions."""
    assert f.bridge.client.client.loop_alive, "the page's network loop ended"
    json.dumps(f.bridge.state(), allow_nan=False)
    seen = f.bridge.messages
    deadline = time.monotonic() + timeout
    tick = threading.Event()  # never set: a bounded wait between looks
    while f.bridge.messages < seen + 20:  # the units publish several messages a second
        assert time.monotonic() < deadline, "the page stopped taking messages"
        tick.wait(0.1)


def test_the_named_nasty_payloads_on_every_topic(fuzzed: Fuzzed) -> None:
    assert len(fuzzed.topics) > 10, fuzzed.topics
    assert any(t.endswith("/tst/feedback") for t in fuzzed.topics)
    assert any(t.endswith("/dji0/heartbeat") for t in fuzzed.topics)
    for payload in NASTY:
        _flood(fuzzed, payload)
    _alive_and_updating(fuzzed)


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(payload=PAYLOADS)
def test_any_payload_on_every_topic(fuzzed: Fuzzed, payload: bytes) -> None:
    _flood(fuzzed, payload)
    assert fuzzed.bridge.client.client.loop_alive


def _planned_for_again(f: Fuzzed, timeout: float = 20.0) -> None:
    """Wait until the service would plan with both units again. The fuzz sends well-formed
    readings too: a ``sensor/battery_state`` of 0 % on a unit's topic (no broker checks who
    publishes there, docs/security.md) leaves the unit out, rightly, until its own next reading,
    which the page may have taken before the service has (a mission refused with "battery 0 %
    is below 20 %" was the result, 1 run in 3 with 400 fuzz examples)."""
    service = f.system.service
    assert service is not None
    names = {"dji0", "dji1"}

    def usable(core: Any) -> bool:
        units = core.view.units(service.clock())
        return names <= {u.name for u in units if u.alive and (
            u.battery is None or u.battery >= core.config.min_battery)}

    assert service.wait_until(usable, timeout), "the service never planned with both units again"


def test_after_the_fuzz_a_mission_runs_to_the_end_on_the_page(fuzzed: Fuzzed) -> None:
    _alive_and_updating(fuzzed)
    _planned_for_again(fuzzed)
    events = Events(fuzzed.url, "no users").start()
    try:
        tree = {"name": "move-to", "params": {"waypoint": pt(60.0, 40.0)}}
        answer = httpx.post(f"{fuzzed.url}/api/missions", json={"mission": tree}, timeout=60.0)
        assert answer.status_code == 200, answer.text
        root = answer.json()["id"]
        events.wait(lambda k, d: k == "mission" and d.get("id") == root
                    and d.get("status") == "succeeded", 60.0, "the mission succeeded")
    finally:
        events.close()


def test_a_bridge_whose_network_loop_ended_reconnects(fuzzed: Fuzzed) -> None:
    mqtt = fuzzed.bridge.client.client
    before = mqtt.connect_count
    paho_client: Any = mqtt._client
    paho_client.loop_stop()  # what an exception escaping a callback did: the thread is gone
    assert not mqtt.loop_alive
    deadline = time.monotonic() + 20.0
    tick = threading.Event()
    while mqtt.connect_count == before:
        assert time.monotonic() < deadline, "the bridge did not reconnect"
        tick.wait(0.1)
    _alive_and_updating(fuzzed)
