"""The delegation service on a broker: `ServiceCore` run by the generic `CoreUnit`, planning on
its worker thread so that a plan never blocks the receive path (a ``ping`` is answered while a
tree is being planned).

At ``stop`` the worker is given 10 s to finish the plan it is running (an ``optimal`` plan may ask
for up to ``max_time_limit``); a plan still running then is abandoned and never answered.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable

from delegation.runtime.settings import BrokerSettings
from delegation.runtime.unit import CoreUnit
from delegation.service.config import ServiceConfig
from delegation.service.core import ServiceCore, Timing
from delegation.service.jobs import Job, JobResult, run_job

log = logging.getLogger(__name__)

#: Seconds between two engine-timeout checks.
TICK_INTERVAL = 0.2


class DelegationService(CoreUnit[ServiceCore]):
    """The service on a broker. ``planner`` runs a job on the worker thread (``run_job``; tests
    pass one they can hold).

    The core's clock is monotonic (every timeout; a wall-clock jump changes nothing); mission
    times (``created``, ``started``, ...) are answered as epoch seconds, from the status
    ``stamp`` (``wall``).
    """

    def __init__(
        self,
        settings: BrokerSettings,
        config: ServiceConfig | None = None,
        planner: Callable[[Job], JobResult] = run_job,
    ) -> None:
        self.config = config or ServiceConfig()
        super().__init__(settings, ServiceCore(self.config), worker=planner, clock=time.monotonic,
                         wall=time.time, tick_interval=TICK_INTERVAL)

    def on_start(self) -> None:
        super().on_start()
        log.info("%s serving on %s (engine %s)", self.name, self.config.base_topic,
                 self.config.engine)

    def wait_ready(
        self, units: Iterable[str] = (), timeout: float = 10.0, engine: bool = True
    ) -> bool:
        """Wait until the named units (and the engine, with ``engine``) are live as the service
        sees them."""
        wanted = frozenset(units)
        return self.wait_until(lambda core: core.ready(wanted, engine, self.clock()), timeout)

    @property
    def timings(self) -> list[Timing]:
        """Arrival -> sent-to-engine timestamps per mission (a copy, read consistently)."""
        return self.inspect(lambda core: list(core.timings))


def serve(settings: BrokerSettings, config: ServiceConfig, stop: threading.Event) -> None:
    """Run the service until ``stop`` is set (the CLI sets it on Ctrl-C)."""
    service = DelegationService(settings, config)
    service.start()
    try:
        stop.wait()
    finally:
        service.stop()
