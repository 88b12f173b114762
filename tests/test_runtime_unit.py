"""`CoreUnit` runs a pure core on a real broker: status at once, messages, ticks and jobs."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import pytest

from delegation.runtime.core import Effects, Identity, JobCore, JobDone, Outgoing, heartbeat
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.unit import CoreUnit

pytestmark = pytest.mark.mqtt


@dataclass
class EchoCore:
    """Answers ``x/in`` with a job; the job's result goes out on ``x/out``."""

    identity: Identity
    status_period: float = 60.0
    done: list[JobDone] = field(default_factory=list)
    ticks: int = 0

    @property
    def name(self) -> str:
        return self.identity.name

    def subscriptions(self) -> list[str]:
        return [self.identity.topic("in")]

    def on_message(self, topic: str, payload: bytes, now: float) -> Effects:
        return Effects(jobs=[payload.decode()])

    def on_tick(self, now: float) -> Effects:
        self.ticks += 1
        return Effects()

    def on_job_done(self, done: JobDone, now: float) -> Effects:
        self.done.append(done)
        return Effects().send(self.identity.topic("out"), {"result": repr(done.result)})

    def status(self, now: float, stamp: float) -> list[Outgoing]:
        return [heartbeat(self.identity, ["sensor"], stamp)]


def work(job: str) -> str:
    if job == "boom":
        raise RuntimeError("a bug in a job")
    return job.upper()


def test_core_unit_runs_a_core(
    mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any]
) -> None:
    identity = Identity(name="echo0", agent_type="air", agent_uuid="u1", prefix=prefix)
    core = EchoCore(identity)
    assert isinstance(core, JobCore)
    watch = collector(f"{identity.base}/#")
    unit = CoreUnit(mqtt_settings, core, worker=work, tick_interval=0.01)
    unit.start()
    try:
        # Status goes out as soon as the unit is subscribed, not a period later (60 s here).
        watch.wait_json(f"{identity.base}/heartbeat", timeout=5.0)
        watch.publish(identity.topic("in"), b"hello")
        watch.publish(identity.topic("in"), b"boom")
        assert watch.wait_json(identity.topic("out"), lambda d: d["result"] == "'HELLO'")
        failed = watch.wait_json(identity.topic("out"), lambda d: "RuntimeError" in d["result"])
        assert "a bug in a job" in failed["result"]
        assert unit.wait_until(lambda c: len(c.done) == 2 and c.ticks > 0, timeout=5.0)
        assert unit.inspect(lambda c: [d.job for d in c.done]) == ["hello", "boom"]
    finally:
        unit.stop()
    assert not unit.running


@dataclass
class RelayCore(EchoCore):
    """Relays every ``x/in`` payload to ``x/out`` at once."""

    def on_message(self, topic: str, payload: bytes, now: float) -> Effects:
        return Effects().send(self.identity.topic("out"), payload)


def test_queued_messages_are_one_batch_published_in_order(
    mqtt_settings: BrokerSettings, prefix: str, collector: Callable[..., Any]
) -> None:
    from delegation.runtime.mqtt import Message

    identity = Identity(name="relay0", agent_type="air", agent_uuid="u1", prefix=prefix)
    batches: list[list[bytes]] = []

    class Recording(CoreUnit[RelayCore]):
        def apply(self, effects: Effects) -> None:
            if effects.publish:
                batches.append([o.payload for o in effects.publish])
            super().apply(effects)

    watch = collector(identity.topic("out"))
    unit = Recording(mqtt_settings, RelayCore(identity), tick_interval=60.0)
    unit.start()
    try:
        sent = [f"m{i}".encode() for i in range(20)]
        with unit._state:  # the loop waits: all 20 are queued when it goes on
            for payload in sent:
                unit.call_soon(Message(identity.topic("in"), payload))
        watch.wait_for(lambda _m: len(watch.messages) >= 20, timeout=5.0, what="20 relays")
        assert [m.payload for m in watch.messages] == sent  # in order
        assert [p for b in batches for p in b] == sent
        assert len(batches) <= 2  # the first may go alone, the 19 queued behind it go together
    finally:
        unit.stop()
