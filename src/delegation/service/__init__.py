"""The delegation service: an MQTT unit that turns partial trees into running missions.

* `core` — `ServiceCore`: every decision, pure (messages, ticks, finished jobs and ``now`` in;
  `Effects` out). Tested message by message without a broker. It dispatches to its parts, each
  pure and tested alone: `commands` (decode once, re-sends, answers, authorisation),
  `fleet_view` (units, learnt speeds, commitments), `planning` (jobs, plans to missions),
  `engine_use` (the engine's feedback and answers, signals, cancels), `repair` (re-delegation,
  lost engines), `lifecycle` and `cancels` (status changes published, cancels settled).
* `engine_link` — the commands the core sends the engine and the waiting for their answers.
* `jobs` — planning jobs and their typed results (`run_job` runs on the unit's worker).
* `missions` — the mission book.
* `unit` — `DelegationService`: the core on a broker (`CoreUnit`), and `serve`.
* `store` — where missions and answers survive a restart (SQLite file, PostgreSQL).
* `active` — one active instance per name: lock, standby and takeover, or refuse to start.
"""

from __future__ import annotations

from delegation.allocation.bids import compute_bids
from delegation.runtime.core import Effects, Outgoing
from delegation.service.config import ServiceConfig
from delegation.service.core import ServiceCore, Timing
from delegation.service.jobs import (
    BidsDone,
    Job,
    JobFailed,
    JobResult,
    PlanDone,
    PlanOptions,
    run_job,
)
from delegation.service.unit import DelegationService, serve

__all__ = [
    "BidsDone",
    "DelegationService",
    "Effects",
    "Job",
    "JobFailed",
    "JobResult",
    "Outgoing",
    "PlanDone",
    "PlanOptions",
    "ServiceConfig",
    "ServiceCore",
    "Timing",
    "compute_bids",
    "run_job",
    "serve",
]
