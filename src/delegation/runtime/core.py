"""What every MQTT unit's core looks like, and the values it returns: pure, no paho, no threads,
no clock.

A core (the delegation service, the TST engine, a simulated unit) holds every decision of its
unit. It is fed what arrives (``on_message``), the passing of time (``on_tick``) and finished
background work (``on_job_done``), each with ``now``, and returns `Effects`: messages to publish
and jobs to run off the receive path. `delegation.runtime.unit.CoreUnit` runs any core on a
broker; tests drive a core directly, message by message.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

from delegation.messages import HeartBeat, WireModel, encode
from delegation.topics import DEFAULT_PREFIX, QOS_COMMAND, QOS_PERIODIC, unit_base_topic

__all__ = [
    "Core",
    "Effects",
    "Identified",
    "Identity",
    "JobCore",
    "JobDone",
    "Outgoing",
    "heartbeat",
]


@dataclass(frozen=True, slots=True)
class Outgoing:
    """A message to publish: topic, encoded payload, QoS."""

    topic: str
    payload: bytes
    qos: int = QOS_COMMAND

    @classmethod
    def of(
        cls, topic: str, payload: WireModel | Mapping[str, Any] | bytes, qos: int = QOS_COMMAND
    ) -> Outgoing:
        """Encode a model (canonically, `messages.encode`), a JSON object (sorted, compact like
        `encode`) or bytes."""
        if isinstance(payload, WireModel):
            data = encode(payload)
        elif isinstance(payload, bytes):
            data = payload
        else:
            data = json.dumps(payload, sort_keys=True, separators=(",", ":")).encode()
        return cls(topic, data, qos)


@dataclass(slots=True)
class Effects:
    """What a core wants done: messages to publish (in order) and jobs to run in the background.

    A job is any value the unit's worker understands (the service's planning jobs); its result
    comes back to the core as a `JobDone`.
    """

    publish: list[Outgoing] = field(default_factory=list)
    jobs: list[Any] = field(default_factory=list)

    def extend(self, other: Effects) -> Effects:
        """Append ``other``'s messages and jobs (in order); returns self for chaining."""
        self.publish.extend(other.publish)
        self.jobs.extend(other.jobs)
        return self

    def send(
        self, topic: str, payload: WireModel | Mapping[str, Any] | bytes, qos: int = QOS_COMMAND
    ) -> Effects:
        """Append one message (see `Outgoing.of`); returns self for chaining."""
        self.publish.append(Outgoing.of(topic, payload, qos))
        return self

    @classmethod
    def of(cls, messages: Iterable[Outgoing]) -> Effects:
        return cls(publish=list(messages))


@dataclass(frozen=True, slots=True)
class JobDone:
    """A background job finished: the job as it was handed out, its result, and how many seconds
    of work it took (for latency figures). Reaches the core on the unit's thread, in order."""

    job: Any
    result: Any
    seconds: float = 0.0


@dataclass(frozen=True, slots=True)
class Identity:
    """Who a unit is on the broker: name, agent type, role, topic prefix, agent-uuid, rate (Hz)."""

    name: str
    agent_type: str
    agent_uuid: str
    role: str = "simulation"
    prefix: str = DEFAULT_PREFIX
    rate: float = 1.0

    @property
    def base(self) -> str:
        """``{prefix}/unit/{agent-type}/{role}/{name}``."""
        return unit_base_topic(self.name, self.agent_type, self.role, self.prefix)

    def topic(self, rest: str) -> str:
        """A topic under this unit, e.g. ``topic("tst/response")``."""
        return f"{self.base}/{rest}"


class Identified:
    """Who a core holding its unit's `Identity` is (the engine, a simulated unit): the `Core`
    protocol's ``name`` and ``status_period``, and the identity's parts, derived in one place."""

    identity: Identity

    @property
    def name(self) -> str:
        return self.identity.name

    @property
    def agent_uuid(self) -> str:
        return self.identity.agent_uuid

    @property
    def rate(self) -> float:
        """Status rounds per second."""
        return self.identity.rate

    @property
    def base(self) -> str:
        """The unit's base topic (`Identity.base`)."""
        return self.identity.base

    @property
    def status_period(self) -> float:
        return 1.0 / self.identity.rate


def heartbeat(
    identity: Identity,
    levels: Sequence[str],
    stamp: float,
    extra: Mapping[str, Any] | None = None,
) -> Outgoing:
    """The unit's ``heartbeat`` (QoS 0). ``levels`` are published exactly as spelt (the example
    agent says ``direct_execution``); ``extra`` adds fields such as ``agent-description``."""
    data = HeartBeat(
        agent_type=identity.agent_type,
        agent_uuid=identity.agent_uuid,
        levels=list(levels),
        name=identity.name,
        rate=identity.rate,
        stamp=stamp,
    ).to_wire()
    data["levels"] = list(levels)
    data.update(extra or {})
    return Outgoing.of(identity.topic("heartbeat"), data, QOS_PERIODIC)


@runtime_checkable
class Core(Protocol):
    """The protocol every unit core speaks (`CoreUnit` runs it)."""

    @property
    def name(self) -> str:
        """The unit's name (logs, client ids)."""
        ...

    @property
    def status_period(self) -> float:
        """Seconds between two rounds of `status` messages (1 / rate)."""
        ...

    def subscriptions(self) -> list[str]:
        """The topic filters the unit listens on."""
        ...

    def on_message(self, topic: str, payload: bytes, now: float) -> Effects:
        """One message from the broker."""
        ...

    def on_tick(self, now: float) -> Effects:
        """Time passed (called every tick interval of the unit)."""
        ...

    def status(self, now: float, stamp: float) -> list[Outgoing]:
        """Heartbeat and info messages (periodic, and once as soon as the unit is subscribed);
        ``stamp`` is wall-clock seconds for the messages' ``stamp`` field."""
        ...


@runtime_checkable
class JobCore(Core, Protocol):
    """A core that hands work to a background worker (`Effects.jobs`) and takes the results."""

    def on_job_done(self, done: JobDone, now: float) -> Effects:
        """A job finished (on the unit's thread, in completion order)."""
        ...
