"""How the delegation service names itself, finds its engine and plans by default."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from delegation.runtime.core import Identity
from delegation.topics import DEFAULT_PREFIX, unit_base_topic
from delegation.tst.validate import Limits


@dataclass(frozen=True, slots=True)
class ServiceConfig:
    """How the service names itself, finds its engine and plans by default."""

    name: str = "delegator0"
    prefix: str = DEFAULT_PREFIX
    agent_type: str = "ground"
    role: str = "simulation"
    engine: str = "op0"
    strategy: str = "auction"
    objective: str = "makespan"
    time_limit: float = 2.0
    #: The longest ``time-limit`` a ``delegate`` may ask for (plans run one at a time).
    max_time_limit: float = 60.0
    #: Seconds to wait for the engine's answer before a command is answered ``failed``.
    engine_timeout: float = 15.0
    #: Heartbeat / info rate (Hz).
    rate: float = 1.0
    #: Fleet profiles for what heartbeats do not carry (speeds, endurance, ...); see ``fleet``.
    profiles: dict[str, dict[str, Any]] | None = None
    #: Who may query, cancel and signal every mission (others: only their own), by the name a
    #: command carries (its per-client command topic, ``sender``, or ``response-topic``).
    operators: frozenset[str] = frozenset()
    #: The largest command or status message read (bytes); a larger one is refused unread.
    max_payload: int = 256 * 1024
    #: The highest explicit speed (m/s) a task may ask for.
    max_speed: float = 100.0

    @property
    def limits(self) -> Limits:
        """The physical ranges trees are validated with."""
        return Limits(max_speed=self.max_speed)

    @property
    def base_topic(self) -> str:
        return unit_base_topic(self.name, self.agent_type, self.role, self.prefix)

    def identity(self, agent_uuid: str) -> Identity:
        """The service as a unit on the broker (for its heartbeat)."""
        return Identity(
            name=self.name,
            agent_type=self.agent_type,
            agent_uuid=agent_uuid,
            role=self.role,
            prefix=self.prefix,
            rate=self.rate,
        )
