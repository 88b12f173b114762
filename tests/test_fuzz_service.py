"""Fuzzing the service (issue 11): Hypothesis against the pure core, then a few thousand hostile
messages against a running service on a real broker.

Properties: nothing raises; every command whose com-uuid can be read (``com_uuid_of``) is answered
exactly once, naming that com-uuid; the command log stays within its capacity; the running
service still answers a ping afterwards and its retained memory stays bounded.
"""

from __future__ import annotations

import gc
import json
import random
import threading
import time
import tracemalloc
import uuid
from collections import Counter
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from delegation.fleet import make_unit
from delegation.geo import LocalFrame
from delegation.local import LocalSystem
from delegation.messages.codec import DELEGATION_COMMANDS, TST_COMMANDS
from delegation.runtime.commands import com_uuid_of
from delegation.runtime.mqtt import Message, MqttClient
from delegation.runtime.settings import BrokerSettings
from delegation.service import ServiceConfig, ServiceCore
from test_service_core import PREFIX, _wp, feed_engine, feed_unit, run_jobs

BASE = f"{PREFIX}/unit/ground/simulation/delegator0"
CAPACITY = 40

# ---------------------------------------------------------------- the pure core

scalars = (
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False)
    | st.text(max_size=12) | st.sampled_from(["yes", "", "/dji0", "$abort", "move-to", "NaN"])
)  # fmt: skip
json_values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=20,
)
node = st.fixed_dictionaries(
    {"name": st.sampled_from(["move-to", "seq", "conc", "search-area", "x"])},
    optional={
        "params": st.fixed_dictionaries({}, optional={
            "waypoint": st.just(_wp(57.761, 16.68)) | json_values,
            "speed": st.sampled_from(["fast", "yes", None, 1e308, -1, 7.0]),
            "area": st.lists(st.just(_wp(57.76, 16.68)), max_size=3)}),
        "common_params": st.fixed_dictionaries({}, optional={
            "execunit": st.sampled_from(["/dji0", "*", "A", 5]),
            "node-uuid": st.text(max_size=6)}),
        "children": st.lists(json_values, max_size=2),
    },
)  # fmt: skip
com_uuids = (st.text(max_size=8) | st.just("") | st.integers() | st.just("u" * 200)
             | st.none())  # fmt: skip


@st.composite
def commands(draw: st.DrawFn) -> dict[str, Any]:
    """A JSON object shaped like a command: a known or odd name, odd fields, odd values."""
    names = sorted({*DELEGATION_COMMANDS, *TST_COMMANDS, "nope"})
    body: dict[str, Any] = {"command": draw(st.sampled_from(names) | json_values)}
    optional = {
        "com-uuid": com_uuids, "sender": st.sampled_from(["alice", "ops", "", 7]),
        "tst": node | json_values, "start": st.sampled_from([True, False, "yes", 1, None]),
        "root-uuid": st.text(max_size=6), "node-uuid": st.text(max_size=6),
        "signal": st.sampled_from(["$abort", "$pause", 3]), "unit": st.sampled_from(["/dji0", 1]),
        "strategy": st.sampled_from(["nearest", "auction", "warp", None]),
        "time-limit": st.sampled_from([0.2, -1, "2", 1e308]),
        "response-topic": st.sampled_from([f"{BASE}/delegation/response/alice", "x/y", 5]),
        "extra": json_values,
    }  # fmt: skip
    for key in draw(st.lists(st.sampled_from(sorted(optional)), unique=True, max_size=6)):
        body[key] = draw(optional[key])
    return body


def payloads() -> st.SearchStrategy[bytes]:
    as_json = commands().map(lambda d: json.dumps(d).encode())
    truncated = as_json.flatmap(lambda b: st.integers(0, len(b)).map(lambda n: b[:n]))
    non_finite = as_json.map(lambda b: b.replace(b"7.0", b"NaN", 1).replace(b"0.2", b"1e999"))
    return (
        as_json
        | truncated
        | non_finite
        | st.binary(max_size=200)
        | json_values.map(lambda v: json.dumps(v).encode())
    )


def fresh_core() -> ServiceCore:
    core = ServiceCore(
        ServiceConfig(
            prefix=PREFIX, operators=frozenset({"ops"}), max_time_limit=1.0, strategy="nearest"
        )
    )
    core.commands.capacity = CAPACITY
    feed_unit(core, "dji0", 57.7605, 16.6815, ["move-to", "search-area"], 100.0)
    feed_engine(core, 100.0)
    return core


@pytest.mark.slow  # hundreds of generated command sequences
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.tuples(st.sampled_from(["tst", "delegation", "delegation/alice"]), payloads()),
        min_size=1,
        max_size=8,
    )
)
def test_the_core_answers_every_readable_command_exactly_once(
    messages: list[tuple[str, bytes]],
) -> None:
    core = fresh_core()
    published: list[dict[str, Any]] = []
    expected: list[str] = []
    for i, (where, payload) in enumerate(messages):
        face, _, client = where.partition("/")
        topic = f"{BASE}/{face}/command" + (f"/{client}" if client else "")
        com = com_uuid_of(payload, max_bytes=core.config.max_payload)
        if com is not None:
            if com in expected:  # a re-send is answered again by design: keep com-uuids unique
                continue
            expected.append(com)
        now = 101.0 + i
        effects = run_jobs(core, core.on_message(topic, payload, now), now)
        effects.extend(core.on_tick(now + 60.0))  # whatever waits for the engine times out
        published += [
            json.loads(o.payload)
            for o in effects.publish
            if o.topic.split("/")[-1] == "response" or "/response/" in o.topic
        ]
    counts = Counter(a.get("response-to") for a in published)
    for com in expected:
        assert counts[com] == 1, (com, published)
    assert len(core.commands) <= CAPACITY


# ---------------------------------------------------------------- a running service


class Answers:
    """Counts answers per response-to on the service's response topics (no per-message scan)."""

    def __init__(self, settings: BrokerSettings, base: str) -> None:
        self.counts: Counter[str] = Counter()
        self._cond = threading.Condition()
        self.client = MqttClient(settings, f"fuzz-{uuid.uuid4().hex[:8]}", sink=self._record)
        self.client.subscribe(f"{base}/+/response")

    def _record(self, msg: Message) -> None:
        try:
            to = json.loads(msg.payload).get("response-to")
        except (ValueError, AttributeError):
            return
        with self._cond:
            self.counts[str(to)] += 1
            self._cond.notify_all()

    def wait(self, coms: set[str], timeout: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: all(self.counts[c] for c in coms), timeout)


def hostile_messages(rng: random.Random, n: int) -> list[tuple[str, bytes, str | None]]:
    """(face, payload, com-uuid expected to be answered or None) for n messages."""
    out: list[tuple[str, bytes, str | None]] = []
    for i in range(n):
        com = f"f{i}"
        kind = rng.randrange(10)
        face = rng.choice(["tst", "delegation"])
        if kind == 0:
            out.append((face, rng.randbytes(rng.randrange(1, 300)), None))
        elif kind == 1:  # truncated JSON: still answered by its com-uuid
            full = json.dumps({"com-uuid": com, "command": "ping", "pad": "x" * 40}).encode()
            out.append((face, full[: rng.randrange(20, len(full))], com))
        elif kind == 2:  # an over-long com-uuid: answered with an empty response-to, not kept
            out.append(
                (face, json.dumps({"com-uuid": "u" * 200_000, "command": "ping"}).encode(), None)
            )
        elif kind == 3:
            bad = rng.choice(['"yes"', "NaN", "1e999", "null"])
            body = (
                f'{{"com-uuid": "{com}", "command": "delegate", "start": {bad}, "tst": '
                '{"name": "move-to", "params": {"speed": 1e308}}}'
            )
            out.append(("delegation", body.encode(), com))
        elif kind == 4:
            out.append(
                (
                    face,
                    json.dumps(
                        {
                            "com-uuid": com,
                            "command": rng.choice(
                                ["nope", "cancel-mission", "query-mission", "signal-tst-node"]
                            ),
                            "root-uuid": "r",
                            "node-uuid": "n",
                            "signal": "$abort",
                        }
                    ).encode(),
                    com,
                )
            )
        elif kind == 5 and i % 97 == 0:  # an oversized payload, refused unread
            out.append(
                (
                    face,
                    b'{"com-uuid": "' + com.encode() + b'", "x": "' + b"x" * 400_000 + b'"}',
                    com,
                )
            )
        else:
            out.append(
                (
                    face,
                    json.dumps(
                        {"com-uuid": com, "command": "ping", "sender": rng.choice(["a", "b", ""])}
                    ).encode(),
                    com,
                )
            )
    return out


@pytest.mark.slow
def test_a_running_service_survives_thousands_of_hostile_messages(
    mqtt_settings: BrokerSettings, prefix: str
) -> None:
    frame = LocalFrame(57.7605, 16.6815)
    units = [make_unit("dji0", "air", frame.geopoint(0, 0, 30), ["move-to"])]
    rng = random.Random(11)
    # 1000 on either broker (824 with a com-uuid, 85 of them over-long: 17 MB if kept, twice the
    # bound below), and a command log of 300 entries, so that the log's bound is reached and
    # tested, not just a 10,000 never filled. (1500 and 500 told the same and cost half as much
    # again: 14.5 s of CPU on the two brokers, traced by tracemalloc.)
    count, capacity = 1000, 300
    messages = hostile_messages(rng, count)
    with LocalSystem(units, settings=mqtt_settings, prefix=prefix) as system:
        service = system.service
        assert service is not None
        service.inspect(lambda core: setattr(core.commands, "capacity", capacity))
        base = service.config.base_topic
        answers = Answers(mqtt_settings, base)
        sender = MqttClient(mqtt_settings, f"fuzz-send-{uuid.uuid4().hex[:8]}")
        answers.client.connect()
        sender.connect()
        try:
            # Warm up (first plan imports, logging), then measure what the service retains.
            sender.publish(
                f"{base}/delegation/command",
                json.dumps({"com-uuid": "warm", "command": "ping"}),
                qos=1,
            )
            assert answers.wait({"warm"}, 20)
            gc.collect()
            tracemalloc.start()
            before = tracemalloc.get_traced_memory()[0]
            began = time.monotonic()
            for face, payload, _ in messages:
                sender.publish(f"{base}/{face}/command", payload, qos=1)
            expected = {com for _, _, com in messages if com is not None}
            assert answers.wait(expected, 120), "not every readable command was answered"
            sender.publish(
                f"{base}/delegation/command",
                json.dumps({"com-uuid": "after", "command": "ping"}),
                qos=1,
            )
            assert answers.wait({"after"}, 10)  # still responsive
            elapsed = time.monotonic() - began
            retained = service.inspect(lambda core: len(core.commands))
            gc.collect()
            grown = tracemalloc.get_traced_memory()[0] - before
            tracemalloc.stop()
        finally:
            sender.disconnect()
            answers.client.disconnect()
    twice = sorted(c for c in expected if answers.counts[c] != 1)
    assert twice == [], twice[:10]
    assert retained <= capacity
    # ~60 refused 200 kB com-uuids would retain > 12 MB if kept; the answers kept are small.
    assert grown < 8_000_000, f"{grown / 1e6:.1f} MB retained after {count} messages"
    assert elapsed < 120
