"""`TstEngine`: the engine's core (`EngineCore`) on a broker, by the generic `CoreUnit`."""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Iterable

from delegation.engine.core import EngineCore
from delegation.engine.executor import EngineOptions
from delegation.runtime.core import Identity
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.unit import CoreUnit
from delegation.topics import DEFAULT_PREFIX

__all__ = ["TstEngine"]


class TstEngine(CoreUnit[EngineCore]):
    """The reference TST engine unit (``op0`` by default); ``options`` are its timing rules."""

    def __init__(
        self,
        settings: BrokerSettings,
        name: str = "op0",
        *,
        prefix: str = DEFAULT_PREFIX,
        agent_type: str = "ground",
        role: str = "simulation",
        rate: float = 1.0,
        options: EngineOptions | None = None,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        tick_interval: float = 0.1,
        answers_query_tst: bool = True,
    ) -> None:
        identity = Identity(name, agent_type, str(uuid.uuid4()), role, prefix, rate)
        core = EngineCore(identity, options, answers_query_tst=answers_query_tst)
        super().__init__(settings, core, clock=clock, wall=wall, tick_interval=tick_interval)
        self.base = identity.base

    def wait_for_units(self, names: Iterable[str], timeout: float) -> bool:
        """Block until the engine has heard a heartbeat of every unit in ``names``."""
        wanted = list(names)
        return self.wait_until(lambda core: core.knows(wanted), timeout)
