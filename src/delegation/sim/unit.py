"""A simulated unit on MQTT: a `SimUnitCore` (or an `ExampleAgentCore`) run by `CoreUnit`."""

from __future__ import annotations

import time
from collections.abc import Callable

from delegation.fleet import UnitState
from delegation.runtime.settings import BrokerSettings
from delegation.runtime.unit import CoreUnit
from delegation.sim.core import SIM_SIGNALS, SimCore, SimUnitCore
from delegation.sim.example_agent import ExampleAgentCore
from delegation.sim.vehicle import SimVehicle
from delegation.topics import DEFAULT_PREFIX

__all__ = ["SIM_SIGNALS", "TICK_S", "SimUnit"]

#: Simulation step on the unit's thread (wall seconds).
TICK_S = 0.05


class SimUnit(CoreUnit[SimCore]):
    """One simulated unit on its own loop thread.

    ``example_agent=True`` runs an `ExampleAgentCore` (the public example agent's protocol)
    instead of a `SimUnitCore`. ``speedup`` multiplies simulated time; ``clock`` (monotonic
    seconds) and ``wall`` (epoch seconds for ``stamp``) are injectable.
    """

    def __init__(
        self,
        settings: BrokerSettings,
        unit: UnitState,
        *,
        prefix: str = DEFAULT_PREFIX,
        role: str = "simulation",
        rate: float | None = None,
        speedup: float = 1.0,
        example_agent: bool = False,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        kind: type[SimCore] = ExampleAgentCore if example_agent else SimUnitCore
        core = kind(unit, prefix=prefix, role=role, rate=rate, speedup=speedup)
        super().__init__(settings, core, clock=clock, wall=wall, tick_interval=TICK_S)

    # Read-only views of the core (tests and the CLI read them; the core changes on the unit's
    # thread only).

    @property
    def unit(self) -> UnitState:
        return self.core.unit

    @property
    def vehicle(self) -> SimVehicle:
        return self.core.vehicle

    @property
    def base(self) -> str:
        return self.core.base

    @property
    def agent_uuid(self) -> str:
        return self.core.agent_uuid

    @property
    def rate(self) -> float:
        return self.core.rate

    @property
    def speedup(self) -> float:
        return self.core.speedup

    @property
    def commands_handled(self) -> int:
        return self.core.commands_handled

    @property
    def example_agent(self) -> bool:
        return isinstance(self.core, ExampleAgentCore)
