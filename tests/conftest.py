"""Shared fixtures: real brokers for `@pytest.mark.mqtt` tests, unique topic prefixes, collectors.

The session-scoped ``broker`` fixture is parametrised over every broker available here: a private
``mosquitto`` (when the binary exists) and the in-process ``amqtt`` broker, so each MQTT test runs
against both in one ``pytest`` run. ``DELEGATION_TEST_BROKERS=amqtt`` (comma-separated) narrows it.
"""

from __future__ import annotations

import itertools
import json
import os
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from hypothesis import settings as hypothesis_settings

from delegation.runtime.broker import (
    EmbeddedBroker,
    LocalBroker,
    PrivateMosquitto,
    mosquitto_binary,
)
from delegation.runtime.mqtt import Message, MqttClient
from delegation.runtime.settings import BrokerSettings
from delegation.topics import Wildcard

# The suite starts hundreds of Python processes (the CLI, services, engines, simulated units, the
# xdist workers): with PYTHONDONTWRITEBYTECODE set (as on this project's CI machine) each of them
# compiles every module it imports from source again (measured: collection took 6.1 s of CPU per
# worker instead of 2.2 s). The suite writes bytecode (git ignores it) for what it starts.
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

# Property tests are derandomised in CI (``CI`` set, as CI runs do): the same examples every run, so
# a red CI is reproducible and never a roll of the dice. Locally they explore (``dev`` profile).
hypothesis_settings.register_profile("ci", derandomize=True, print_blob=True)
hypothesis_settings.register_profile("dev")
hypothesis_settings.load_profile(
    os.environ.get("HYPOTHESIS_PROFILE") or ("ci" if os.environ.get("CI") else "dev")
)


#: xdist workers per CPU (pyproject's addopts say ``-n auto``). The suite waits more than it
#: computes (brokers, simulated flights, child processes): on the 2-core machine, idle, 4
#: workers ran it in 198 s (184 s of CPU), 8 in 135-137 s (3 runs of 3 passed), and
#: ``-m "not slow"`` in 54 and 49 s.
WORKERS_PER_CPU = 4
#: At most this many, whatever the CPUs: each worker starts its own brokers and processes, and
#: more than were measured is not a speed anyone has seen pass.
MAX_WORKERS = 8


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: ``WORKERS_PER_CPU`` workers per CPU this process may run on, at most
    ``MAX_WORKERS`` (not xdist's 1 per core, which leaves the cores idle while tests wait)."""
    return min(MAX_WORKERS, WORKERS_PER_CPU * len(os.sched_getaffinity(0)))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Modules with slow tests first, each module's tests kept together and in order.

    xdist hands a worker its next test when it has two left, in this order: the slow modules
    (processes killed and restarted, flights, Chromium) start while the many quick tests are
    still queued, and those fill the workers at the end instead of one worker finishing a 20 s
    test alone. Only the order changes; every test still runs.
    """
    slow_modules = {item.module.__name__ for item in items
                    if item.get_closest_marker("slow") is not None and item.module is not None}
    items.sort(key=lambda item: item.module is None or item.module.__name__ not in slow_modules)


@pytest.hookimpl(trylast=True, specname="pytest_collection_modifyitems")
def pytest_collection_modifyitems_xdist_groups(
    config: pytest.Config, items: list[pytest.Item]
) -> None:
    """On an xdist worker under ``--dist loadgroup``, end each ``xdist_group`` test's node id in
    ``@<group>``, which is how the controller keeps a group on one worker.

    pytest-xdist 3.8 does it by setting ``item._nodeid``, which pytest 9 no longer reads (the id
    lives in ``item._id``): the groups were silently ignored, and Chromium and the Dask cluster
    started on every worker that drew one of their tests (measured: 4 browsers, 2 clusters).
    This runs after xdist's hook and adds the suffix only where it is still missing.
    """
    if not config.getoption("loadgroup", default=False):  # set on workers only
        return
    for item in items:
        groups = sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default"))
                         for m in item.iter_markers("xdist_group")})
        if not groups or "@" in item.nodeid:
            continue
        grouped = f"{item.nodeid}@{'_'.join(groups)}"
        node_id = getattr(item, "_id", None)
        if node_id is not None and hasattr(type(node_id), "parse"):
            item._id = type(node_id).parse(grouped)
        else:
            item._nodeid = grouped


def _broker_kinds() -> list[Any]:
    wanted = os.environ.get("DELEGATION_TEST_BROKERS", "mosquitto,amqtt").split(",")
    kinds: list[Any] = []
    for kind in (k.strip() for k in wanted if k.strip()):
        if kind == "mosquitto" and mosquitto_binary() is None:
            kinds.append(pytest.param(kind, marks=pytest.mark.skip(reason="no mosquitto binary")))
        else:
            kinds.append(kind)
    return kinds


def one_broker() -> pytest.MarkDecorator:
    """Run a test on the first broker of `_broker_kinds` only (mosquitto where it exists).

    For tests whose subject is not the broker (a service's store failing, ``kill -9`` of a
    ``serve`` process): there both brokers run the same code path twice, and the MQTT client's
    behaviour on each broker is what the MQTT tests check. Use as ``pytestmark = [one_broker()]``.
    """
    kinds = _broker_kinds()
    runnable = [k for k in kinds if isinstance(k, str)]
    return pytest.mark.parametrize("broker", runnable[:1] or kinds[:1], indirect=True)


@pytest.fixture(scope="session", params=_broker_kinds())
def broker(request: pytest.FixtureRequest) -> Iterator[LocalBroker]:
    """A broker for the whole session, on a free loopback port; stopped at the end."""
    kind = request.param
    started: LocalBroker = PrivateMosquitto() if kind == "mosquitto" else EmbeddedBroker()
    started.start()
    try:
        yield started
    finally:
        started.stop()


@pytest.fixture(scope="module")
def mosquitto() -> Iterator[PrivateMosquitto]:
    """A private mosquitto of the module's own, for tests that start real processes against it
    (skipped, saying why, where the binary is missing)."""
    if mosquitto_binary() is None:
        pytest.skip("no mosquitto binary (apt-get install mosquitto)")
    started = PrivateMosquitto()
    started.start()
    try:
        yield started
    finally:
        started.stop()


@pytest.fixture
def mqtt_settings(broker: LocalBroker) -> BrokerSettings:
    """Client settings for the session's broker."""
    return broker.settings()


@pytest.fixture
def broker_kind(broker: LocalBroker) -> str:
    """``mosquitto`` or ``amqtt``: for the few tests whose deadlines must allow for amqtt."""
    return broker.kind


@pytest.fixture
def prefix() -> str:
    """A topic prefix of this test alone, so tests never see each other's messages."""
    return f"test-{uuid.uuid4().hex[:12]}"


class Collector:
    """A plain MQTT client that records what arrives on its filters; tests wait on it.

    ``wait_for`` blocks on a condition variable (no sleeping) until a recorded message satisfies a
    predicate, or fails the test at the deadline with what did arrive.
    """

    def __init__(self, settings: BrokerSettings, patterns: list[str]) -> None:
        self.patterns = [Wildcard(p) for p in patterns]
        self.messages: list[Message] = []
        self.arrived: list[float] = []  # when each message arrived here (``time.monotonic``)
        self._cond = threading.Condition()
        self.client = MqttClient(settings, f"collector-{uuid.uuid4().hex[:8]}", sink=self._record)
        for p in patterns:
            self.client.subscribe(p)

    def _record(self, message: Message) -> None:
        with self._cond:
            self.messages.append(message)
            self.arrived.append(time.monotonic())
            self._cond.notify_all()

    def start(self) -> Collector:
        self.client.connect()
        # Make sure the subscriptions are active before the test goes on: round-trip a probe.
        probe = f"collector-probe/{self.client.client_id}"
        self.client.subscribe(probe)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            self.client.publish(probe, b"probe", qos=1)
            with self._cond:
                if self._cond.wait_for(
                    lambda: any(m.topic == probe for m in self.messages), timeout=0.5
                ):
                    break
        else:
            raise AssertionError("collector subscriptions not active within 10 s")
        self.client.unsubscribe(probe)
        with self._cond:
            kept = [(m, t) for m, t in zip(self.messages, self.arrived, strict=True)
                    if m.topic != probe]
            self.messages, self.arrived = [m for m, _ in kept], [t for _, t in kept]
        return self

    def stop(self) -> None:
        self.client.disconnect()

    def publish(self, topic: str, payload: dict[str, Any] | bytes | str, qos: int = 1) -> None:
        data = json.dumps(payload).encode() if isinstance(payload, dict) else payload
        self.client.publish(topic, data, qos=qos)

    def wait_for(
        self,
        predicate: Callable[[Message], bool],
        timeout: float = 10.0,
        what: str = "a message",
    ) -> Message:
        """The first recorded message (old or new) that satisfies ``predicate``."""
        found: list[Message] = []

        def check() -> bool:
            for m in self.messages:
                try:
                    ok = predicate(m)
                except (ValueError, KeyError, TypeError):
                    ok = False
                if ok:
                    found.append(m)
                    return True
            return False

        with self._cond:
            if not self._cond.wait_for(check, timeout=timeout):
                seen = [f"{m.topic}: {m.text[:200]}" for m in self.messages[-15:]]
                raise AssertionError(f"no {what} within {timeout}s; last seen:\n" + "\n".join(seen))
        return found[0]

    def wait_json(
        self,
        topic_filter: str,
        predicate: Callable[[dict[str, Any]], bool] = lambda _d: True,
        timeout: float = 10.0,
        what: str | None = None,
    ) -> dict[str, Any]:
        """The first JSON object on a topic matching ``topic_filter`` satisfying ``predicate``."""
        wc = Wildcard(topic_filter)

        def pred(m: Message) -> bool:
            if not wc.matches(m.topic):
                return False
            data = json.loads(m.payload)
            return isinstance(data, dict) and bool(predicate(data))

        found = self.wait_for(pred, timeout, what or f"message on {topic_filter}")
        return dict(json.loads(found.payload))

    def longest_gap(self, topic_filter: str, until: float | None = None) -> float:
        """The longest time (s) between two messages on ``topic_filter`` as they arrived here, and
        from the last to ``until`` (``time.monotonic``) if given: how long a sender really went
        silent on the wire, as a client behind no backlog saw it."""
        wc = Wildcard(topic_filter)
        with self._cond:
            times = [t for m, t in zip(self.messages, self.arrived, strict=True)
                     if wc.matches(m.topic)]
        if until is not None:
            times.append(until)
        return max((b - a for a, b in itertools.pairwise(times)), default=0.0)

    def json_on(self, topic_filter: str) -> list[dict[str, Any]]:
        """Every JSON object recorded so far on topics matching ``topic_filter``."""
        wc = Wildcard(topic_filter)
        out: list[dict[str, Any]] = []
        with self._cond:
            for m in self.messages:
                if wc.matches(m.topic):
                    try:
                        data = json.loads(m.payload)
                    except ValueError:
                        continue
                    if isinstance(data, dict):
                        out.append(data)
        return out


@pytest.fixture
def collector(mqtt_settings: BrokerSettings) -> Iterator[Callable[..., Collector]]:
    """A factory: ``collector("prefix/#")`` starts a `Collector`; all are stopped after the test."""
    made: list[Collector] = []

    def make(*patterns: str) -> Collector:
        c = Collector(mqtt_settings, list(patterns)).start()
        made.append(c)
        return c

    yield make
    for c in made:
        c.stop()
