"""Planning jobs: what the core hands to the planner worker, and the typed result it gets back.

A job is a value (the validated tree, the fleet snapshot, the options), so the worker needs
nothing from the core; `run_job` never raises, so a planner bug becomes a ``failed`` answer
instead of a dead worker.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from delegation.allocation import OBJECTIVES, STRATEGIES, Plan, compute_bids, plan_mission
from delegation.errors import InputError, InputProblem
from delegation.fleet import UnitState
from delegation.learning import speed_notes
from delegation.runtime.commands import CommandKey
from delegation.service.faces import Face
from delegation.service.federated import FederatedPlanner, Offer, kept_delegations
from delegation.tst.node import TstNode, walk, where
from delegation.tst.validate import DEFAULT_LIMITS, Limits, ValidatedTree

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class PlanOptions:
    """How to plan: strategy, objective and the planner's time limit (s)."""

    strategy: str
    objective: str
    time_limit: float
    #: Searches may be shared among units (DESIGN 3.11; ``delegate``'s ``split``).
    split: bool = True


def plan_options(
    strategy: str | None,
    objective: str | None,
    time_limit: float | None,
    *,
    defaults: PlanOptions,
    max_time_limit: float,
    split: bool = True,
) -> PlanOptions:
    """The options a command asked for (``defaults`` where it did not); ``InputError`` naming a
    bad one, so the command is answered at once instead of after a trip to the planner."""
    strategy = strategy or defaults.strategy
    objective = objective or defaults.objective
    if strategy not in STRATEGIES:
        raise InputError(InputProblem("command", "strategy",
                                 f"unknown strategy {strategy!r}; expected one of "
                                 f"{', '.join(STRATEGIES)}"))
    if objective not in OBJECTIVES:
        raise InputError(InputProblem("command", "objective",
                                 f"unknown objective {objective!r}; expected one of "
                                 f"{', '.join(OBJECTIVES)}"))
    if time_limit is not None and time_limit > max_time_limit:
        raise InputError(InputProblem("command", "time-limit",
                                 f"{time_limit:g} s is above this service's maximum of "
                                 f"{max_time_limit:g} s"))
    return PlanOptions(strategy, objective, time_limit or defaults.time_limit, split)


@dataclass(frozen=True, slots=True)
class Job:
    """Work for the planner: a plan (``delegate``, ``start-tst``) or bids (``get-bids``)."""

    id: int
    kind: Literal["plan", "bids"]
    key: CommandKey
    face: Face
    #: Validated (once: the planner does not check it again), a node-uuid on every node.
    tree: ValidatedTree
    units: tuple[UnitState, ...]
    options: PlanOptions
    engine: str
    start: bool
    source: str
    #: When the command arrived (core clock), for `Timing`.
    received: float
    #: Said in the plan's notes (units left out: busy in another mission, battery low).
    notes: tuple[str, ...] = ()
    #: The root uuid of the mission this plan re-delegates ("" for a command's plan).
    redelegate: str = ""
    #: Per unit: where its speeds come from (``learnt``/``profile``/``default``) for the notes.
    speed_sources: Mapping[str, str] = field(default_factory=dict)
    #: Suspicious input (`delegation.learning.input_warnings`), added to the plan's notes.
    warnings: tuple[str, ...] = ()
    #: The physical ranges the tree was validated with.
    limits: Limits = DEFAULT_LIMITS
    #: Other delegators' offers on subtrees (`delegation.service.offers`): they compete with
    #: ``units`` (`delegation.service.federated`).
    offers: tuple[Offer, ...] = ()
    #: Delegators known when a re-delegation was made: their subtrees stay with them.
    delegators: frozenset[str] = frozenset()
    #: A start plan that arrived while another was being made: it waits for it and gets the
    #: units (with their notes, warnings and speed sources) only when handed out
    #: (`Planning.refreshed`), so ``units`` is empty until then (a burst read the fleet twice).
    deferred: bool = False

    @property
    def com_uuid(self) -> str:
        """The com-uuid of the command the job answers."""
        return self.key[1]


@dataclass(frozen=True, slots=True)
class PlanDone:
    """A plan was made (feasible or not)."""

    plan: Plan


@dataclass(frozen=True, slots=True)
class BidsDone:
    """Bids were computed (see `compute_bids`)."""

    bids: list[dict[str, Any]]


@dataclass(frozen=True, slots=True)
class JobFailed:
    """The planner refused the input or broke; ``reason`` is the answer's fail-reason."""

    reason: str


JobResult = PlanDone | BidsDone | JobFailed


def run_job(job: Job) -> JobResult:
    """Run one job (on the planner worker). Never raises."""
    try:
        if job.kind == "bids":
            return BidsDone(compute_bids(job.tree.root, job.units))
        kept = [o for o in kept_delegations(job.tree.root, {u.name for u in job.units},
                                            job.engine)
                if o.delegator in job.delegators] if job.redelegate else []
        if job.offers or kept:
            plan = FederatedPlanner(
                job.tree.root, job.units, job.offers, strategy=job.options.strategy,
                objective=job.options.objective, time_limit=job.options.time_limit,
                engine_unit=job.engine, limits=job.limits, kept=kept,
                split=job.options.split).plan()
        else:
            plan = plan_mission(
                job.tree,
                job.units,
                strategy=job.options.strategy,
                objective=job.options.objective,
                time_limit=job.options.time_limit,
                engine_unit=job.engine,
                split=job.options.split,
                limits=job.limits,
            )
        used = {a.execunit.strip("/") for a in plan.assignments}
        plan.notes.extend([*job.warnings, *speed_notes(job.units, job.speed_sources, used),
                           *job.notes])
        return PlanDone(plan)
    except InputError as exc:
        return JobFailed(exc.fail_reason)
    except Exception as exc:  # a planner bug must not kill the service: answer it
        log.exception("planning job %s failed", job.id)
        return internal_error(exc)


def internal_error(exc: object) -> JobFailed:
    """The answer to a job that raised (or returned something else than a `JobResult`)."""
    problem = InputProblem("planner", "", f"internal error: {type(exc).__name__}: {exc}")
    return JobFailed(InputError(problem).fail_reason)



def infeasible_reason(plan: Plan, tree: TstNode) -> str:
    """A fail-reason naming every node the plan could not give a unit (path, name, uuid) and
    why."""
    paths = {node.node_uuid: where(path, node) for path, node in walk(tree) if node.node_uuid}
    parts = [f"{paths.get(u.node_uuid, f'{u.name} {u.node_uuid}')}: {u.reason}"
             for u in plan.unassigned]
    return "cannot instantiate the tree: " + ("; ".join(parts) or "no feasible plan")
