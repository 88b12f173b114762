"""The whole system on one machine: broker, simulated fleet, reference engine and service.

`LocalSystem` is the one composition root: the demo, the end-to-end tests and
``benchmarks/latency.py`` start the system through it instead of each wiring the parts by hand.

Start order matters for speed, not correctness: listeners start first (service, then engine, then
the fleet), and every unit publishes its status as soon as it is subscribed, so each part is seen
by the ones already running at once instead of at their next heartbeat.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import replace
from typing import Any

from delegation.engine import TstEngine
from delegation.errors import DelegationError
from delegation.fleet import UnitState
from delegation.runtime.broker import BrokerProcess
from delegation.runtime.lifecycle import StartStop
from delegation.runtime.settings import BrokerSettings
from delegation.scenario import Scenario
from delegation.service import DelegationService, ServiceConfig
from delegation.sim import SimFleet, agent_rates

log = logging.getLogger(__name__)


class SystemNotReady(DelegationError):
    """The parts did not see each other within the start-up deadline."""


class LocalSystem(StartStop):
    """Fleet, engine and service on a broker (an embedded one when ``settings`` is None).

    ``engine=False`` / ``service=False`` leave a part out (a test of the engine alone, a benchmark
    with a stand-in engine). ``planner`` replaces the service's planning worker (tests hold it).
    Use as a context manager, or `start` / `stop`.
    """

    def __init__(
        self,
        units: Sequence[UnitState],
        *,
        settings: BrokerSettings | None = None,
        config: ServiceConfig | None = None,
        prefix: str | None = None,
        speedup: float = 1.0,
        rates: Mapping[str, float] | None = None,
        example_agent: bool = False,
        engine: bool = True,
        service: bool = True,
        planner: Callable[[Any], Any] | None = None,
        ready_timeout: float = 15.0,
        credentials: Mapping[str, BrokerSettings] | None = None,
    ) -> None:
        self.units = list(units)
        self.settings = settings
        config = config or ServiceConfig()
        self.config = replace(config, prefix=prefix) if prefix is not None else config
        self.prefix = self.config.prefix
        self.speedup = speedup
        self.rates = dict(rates or {})
        self.example_agent = example_agent
        self.with_engine = engine
        self.with_service = service
        self.planner = planner
        self.ready_timeout = ready_timeout
        #: Per-part settings by part name (service, engine, unit): each its own broker login,
        #: as a broker with an ACL wants (docs/security.md); other parts use ``settings``.
        self.credentials = dict(credentials or {})
        self.broker: BrokerProcess | None = None
        self.fleet: SimFleet | None = None
        self.engine: TstEngine | None = None
        self.service: DelegationService | None = None
        self._stack = ExitStack()

    @classmethod
    def from_scenario(cls, scenario: Scenario, **options: Any) -> LocalSystem:
        """A system for a scenario's agents: their rates, and their profiles for the service."""
        rates = agent_rates(scenario)
        rates.update(options.pop("rates", None) or {})
        config = options.pop("config", None) or ServiceConfig()
        if config.profiles is None:
            config = replace(config, profiles=scenario.profiles())
        return cls(scenario.units(), rates=rates, config=config, **options)

    @property
    def names(self) -> list[str]:
        """The simulated units' names."""
        return [u.name for u in self.units]

    # ---- lifecycle

    def start(self) -> LocalSystem:
        """Start every part and wait until the engine and the service see the whole fleet."""
        try:
            self._start_parts()
            self._wait_ready()
        except BaseException:
            self.stop()
            raise
        return self

    def _start_parts(self) -> None:
        stack = self._stack
        if self.settings is None:
            self.broker = BrokerProcess().start()
            stack.callback(self.broker.stop)
            self.settings = self.broker.settings()
            log.info("embedded broker on %s", self.settings.describe())
        settings = self.settings
        creds = self.credentials
        if self.with_service:
            own = creds.get(self.config.name, settings)
            if self.planner is not None:
                self.service = DelegationService(own, self.config, planner=self.planner)
            else:
                self.service = DelegationService(own, self.config)
            self.service.start()
            stack.callback(self.service.stop)
        if self.with_engine:
            self.engine = TstEngine(
                creds.get(self.config.engine, settings), self.config.engine, prefix=self.prefix
            )
            self.engine.start()
            stack.callback(self.engine.stop)
        self.fleet = SimFleet(
            settings,
            self.units,
            prefix=self.prefix,
            speedup=self.speedup,
            rates=self.rates,
            example_agent=self.example_agent,
            unit_settings=creds,
        )
        self.fleet.start()
        stack.callback(self.fleet.stop)

    def _wait_ready(self) -> None:
        names, timeout = self.names, self.ready_timeout
        if self.engine is not None and not self.engine.wait_for_units(names, timeout):
            raise SystemNotReady(f"the engine did not see units {names} within {timeout:g} s")
        if self.service is not None and not self.service.wait_ready(
            names, timeout=timeout, engine=self.engine is not None
        ):
            raise SystemNotReady(
                f"the service did not see units {names}"
                + (" and the engine" if self.engine is not None else "")
                + f" within {timeout:g} s"
            )

    def stop(self) -> None:
        """Stop every part that was started, the last started first (idempotent)."""
        self._stack.close()
