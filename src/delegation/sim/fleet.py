"""A simulated fleet: one `SimUnit` per scenario agent, started and stopped together."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping, Sequence

from delegation.fleet import UnitState
from delegation.runtime.lifecycle import StartStop
from delegation.runtime.settings import BrokerSettings
from delegation.scenario import Scenario
from delegation.sim.unit import SimUnit
from delegation.topics import DEFAULT_PREFIX

log = logging.getLogger(__name__)


def agent_rates(scenario: Scenario) -> dict[str, float]:
    """The status rates a scenario gives its agents (those it gives one)."""
    return {a.name: a.rate for a in scenario.agents if a.rate is not None}


class SimFleet(StartStop):
    """Simulated units for a list of `UnitState`s (a scenario's: ``scenario.units()`` with
    ``rates=agent_rates(scenario)``)."""

    def __init__(
        self,
        settings: BrokerSettings,
        units: Sequence[UnitState],
        *,
        prefix: str = DEFAULT_PREFIX,
        role: str = "simulation",
        speedup: float = 1.0,
        rates: dict[str, float] | None = None,
        example_agent: bool = False,
        unit_settings: Mapping[str, BrokerSettings] | None = None,
    ) -> None:
        """``unit_settings``: a unit's own broker login by name (else ``settings``)."""
        rates = rates or {}
        own = unit_settings or {}
        self.units: dict[str, SimUnit] = {}
        for unit in units:
            if unit.name in self.units:
                raise ValueError(f"two simulated units are named {unit.name!r}")
            self.units[unit.name] = SimUnit(
                own.get(unit.name, settings),
                unit,
                prefix=prefix,
                role=role,
                rate=rates.get(unit.name),
                speedup=speedup,
                example_agent=example_agent,
            )

    def start(self, timeout: float = 10.0) -> SimFleet:
        """Start every unit; if one fails, stop those already started and re-raise."""
        started: list[SimUnit] = []
        try:
            for unit in self.units.values():
                unit.start(timeout)
                started.append(unit)
        except BaseException:
            for unit in started:
                unit.stop()
            raise
        log.info("simulated fleet of %d units started", len(started))
        return self

    def stop(self) -> None:
        for unit in self.units.values():
            unit.stop()

    def __iter__(self) -> Iterator[SimUnit]:
        return iter(self.units.values())

    def __getitem__(self, name: str) -> SimUnit:
        return self.units[name.strip("/")]

    def __len__(self) -> int:
        return len(self.units)
