"""``plan_mission``: from (tree, fleet snapshot, options) to a Plan, with the chosen strategy."""

from __future__ import annotations

import logging
import math
import time
import uuid as uuid_module
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from delegation.allocation.auction import unassigned_reason
from delegation.allocation.bounds import makespan_lower_bound
from delegation.allocation.instantiate import Placement
from delegation.allocation.plan import Assignment, Plan, SharedPart, SharedSearch, Unassigned
from delegation.allocation.plausibility import plausibility_notes
from delegation.allocation.problem import Problem, build_problem, flatten_tree
from delegation.allocation.schedule import Schedule
from delegation.allocation.sent_tree import choose_tree
from delegation.allocation.share_plan import (
    ENDURANCE_ROUNDS,
    REFINEMENTS,
    RESEAT_GAIN,
    Fits,
    SharedTree,
    lateness,
    measured,
    overrun,
    seen_in,
    share_searches,
    strained,
    worth_sharing,
)
from delegation.allocation.strategies import OBJECTIVES, STRATEGIES, Objective, StrategyResult
from delegation.costs import CostTables, cost_tables
from delegation.errors import InputError, InputProblem
from delegation.tst import TstNode, with_defaults, with_uuids
from delegation.tst.node import walk
from delegation.tst.validate import DEFAULT_LIMITS, Limits, ValidatedTree, validate_tree

if TYPE_CHECKING:
    from delegation.fleet import UnitState

log = logging.getLogger(__name__)

__all__ = ["OBJECTIVES", "STRATEGIES", "check_options", "make_plan", "plan_mission"]


def check_options(strategy: str, objective: str, time_limit: float) -> None:
    """Raise ``InputError`` naming the bad option."""
    problems = []
    if strategy not in STRATEGIES:
        problems.append(
            InputProblem("options", "strategy", f"unknown strategy {strategy!r}; choose one of "
                         + ", ".join(STRATEGIES))
        )
    if objective not in OBJECTIVES:
        problems.append(
            InputProblem("options", "objective", f"unknown objective {objective!r}; choose one of "
                         + ", ".join(OBJECTIVES))
        )
    if not (isinstance(time_limit, int | float) and time_limit > 0 and np.isfinite(time_limit)):
        problems.append(
            InputProblem("options", "time-limit", f"must be a positive number of seconds, not "
                         f"{time_limit!r}")
        )
    if problems:
        raise InputError(problems)


def plan_mission(
    tree: TstNode | ValidatedTree,
    units: Sequence[UnitState],
    *,
    strategy: str = "auction",
    objective: Objective | str = Objective.MAKESPAN,
    time_limit: float = 5.0,
    engine_unit: str = "op0",
    new_uuid: Callable[[], str] | None = None,
    limits: Limits = DEFAULT_LIMITS,
    stages: dict[str, float] | None = None,
    split: bool = True,
) -> Plan:
    """Allocate ``units`` to the tasks of ``tree`` and return the plan with the instantiated tree.

    With ``split`` (the default), ``auction`` and ``optimal`` may share a search among several
    units (DESIGN 3.11, ``share_plan``); ``nearest`` never does.

    Never raises for infeasibility (those tasks go to ``unassigned``); raises ``InputError`` for an
    unknown strategy or objective or a tree that is not valid (a `ValidatedTree` was checked by
    the validator already, with its own limits, and is not checked again). ``stages``, when
    given, receives the seconds each stage took (``validation``, ``problem``, ``strategy``,
    ``sent-tree``): the breakdown ``benchmarks/auction_speed.py`` prints.
    """
    clock = time.perf_counter()
    check_options(strategy, objective, time_limit)
    tree = (tree if isinstance(tree, ValidatedTree) else validate_tree(tree, limits)).root
    if not any(not node.is_control for _, node in walk(tree)):
        raise InputError(InputProblem(
            "root", "children", f"the tree has no task node ({sum(1 for _ in walk(tree))} "
            "control nodes only): there is nothing to plan"))
    warnings = plausibility_notes(tree, units)
    for warning in warnings:
        log.warning("implausible input: %s", warning)
    began = time.perf_counter()
    prepared = with_defaults(with_uuids(tree, new_uuid))
    tables = cost_tables(list(units), [node for _, node in flatten_tree(prepared)[1]])
    problem = build_problem(prepared, units, tables)
    built = time.perf_counter()
    sharing = split and strategy != "nearest" and any(
        worth_sharing(problem, tables, t) for t in range(problem.n_tasks))
    planned, shared = prepared, None
    if sharing:
        shared, problem, result = _share_or_not(
            prepared, units, problem, tables, strategy, Objective(objective), time_limit,
            new_uuid or _uuid4)
        if shared is not None:
            planned = shared.tree
    else:
        result = STRATEGIES[strategy](problem, Objective(objective), time_limit)
    solved = time.perf_counter()
    plan = make_plan(
        problem, result.schedule, planned, strategy=strategy, objective=objective,
        solve_time=solved - began, bound=result.bound, engine_unit=engine_unit,
        new_uuid=new_uuid, notes=[*warnings, *result.notes], fallback=result.fallback,
        source=prepared, shared=shared,
    )
    if stages is not None:
        stages.update({"validation": began - clock, "problem": built - began,
                       "strategy": solved - built, "sent-tree": time.perf_counter() - solved})
    return plan


def _uuid4() -> str:
    return str(uuid_module.uuid4())


def _share_or_not(
    prepared: TstNode, units: Sequence[UnitState], problem: Problem, tables: CostTables,
    strategy: str, objective: Objective, time_limit: float, new_uuid: Callable[[], str],
) -> tuple[SharedTree | None, Problem, StrategyResult]:
    """Plan with the searches shared or not, whichever is better: ``auction`` decides (for
    ``optimal`` too, which then runs with its whole time limit on the tree chosen)."""
    probe = "auction"
    base = STRATEGIES[probe](problem, objective, time_limit)
    better = _shared_plan(prepared, units, problem, tables, base, probe, objective, time_limit,
                          new_uuid)
    shared, chosen, result = (None, problem, base) if better is None else better
    if strategy != probe:
        result = STRATEGIES[strategy](chosen, objective, time_limit)
    return shared, chosen, result


def _shared_plan(
    prepared: TstNode, units: Sequence[UnitState], problem: Problem, tables: CostTables,
    result: StrategyResult, strategy: str, objective: Objective, time_limit: float,
    new_uuid: Callable[[], str],
) -> tuple[SharedTree, Problem, StrategyResult] | None:
    """The plan with searches shared (``share_plan``), when it is better than ``result``:
    parts sized from ``result``'s schedule, cut, measured, sized and cut again with their real
    sweeps (``REFINEMENTS`` times), then planned by the same strategy with the rest of the
    tree. A part its unit cannot fly within its endurance (its real sweep longer than sized)
    shrinks that unit's share and the area is cut again (``ENDURANCE_ROUNDS`` times at most):
    the best of these plans is kept, so an area no one unit can cover is planned feasibly
    whenever the fleet's endurance allows. Last, the parts may be sized once more for what that
    plan has the units do before the search (``_reseated``)."""
    shared = share_searches(prepared, problem, tables, result.schedule, new_uuid)
    if shared is None:
        return None
    sized: Fits = {}  # what the parts of ``shared`` were sized with
    for _ in range(REFINEMENTS):
        fits = measured(shared, tables)
        again = share_searches(prepared, problem, tables, result.schedule, new_uuid, fits)
        if again is None:
            break
        shared, sized = again, fits
    best: _Planned | None = None
    for round_ in range(ENDURANCE_ROUNDS + 1):
        planned = _plan_shared(shared, units, tables, strategy, objective, time_limit)
        if best is None or planned.better_than(best, objective):
            best = planned
        over = overrun(shared, planned.problem, planned.tables, planned.result.schedule)
        if not over or round_ == ENDURANCE_ROUNDS:
            break
        # The same sizing, the units that fell short made slower by how far they fell short:
        # the cut moves a little (measuring the new parts again would chase their shapes).
        # No margin on endurance now: each round's plan is checked for real.
        sized = strained(sized, over)
        again = share_searches(prepared, problem, tables, result.schedule, new_uuid, sized,
                               margin=1.0)
        if again is None:
            break
        shared = again
    if best is not None:
        best = _reseated(best, prepared, units, problem, tables, result, strategy, objective,
                         time_limit, new_uuid, sized)
    if best is None or best.result.schedule.key(objective) >= result.schedule.key(objective):
        log.info("sharing searches did not improve the plan: kept the unshared one")
        return None
    return best.shared, best.problem, best.result


@dataclass(frozen=True)
class _Planned:
    """A tree with shared searches, its problem and tables, and the strategy's plan of it."""

    shared: SharedTree
    problem: Problem
    tables: CostTables
    result: StrategyResult

    def better_than(self, other: _Planned, objective: Objective) -> bool:
        return self.result.schedule.key(objective) < other.result.schedule.key(objective)


def _plan_shared(shared: SharedTree, units: Sequence[UnitState], like: CostTables,
                 strategy: str, objective: Objective, time_limit: float) -> _Planned:
    tables = _tables_of(shared, units, like)
    problem = build_problem(shared.tree, units, tables)
    return _Planned(shared, problem, tables, STRATEGIES[strategy](problem, objective, time_limit))


def _reseated(
    best: _Planned, prepared: TstNode, units: Sequence[UnitState], problem: Problem,
    tables: CostTables, result: StrategyResult, strategy: str, objective: Objective,
    time_limit: float, new_uuid: Callable[[], str], sized: Fits,
) -> _Planned:
    """``best``, or a better plan with the parts sized again for what ``best`` has the units do
    before each search (``share_plan.seen_in``). The parts were sized for the other tasks
    allocated as in the unshared plan (``result``); planned with the parts, those tasks can go
    to other units: a unit given one of them first flies its part late, and the whole search
    ends late (a 6-unit coast area in a mixed tree ended 1.46 x its bound, one unit's part
    starting 2,000 s after the others'). Tried only when that would end a search sooner by
    ``RESEAT_GAIN`` (``share_plan.lateness``)."""
    seen = seen_in(best.shared, best.problem, best.tables, best.result.schedule)
    late = lateness(best.shared, seen, best.problem, best.result.schedule, problem, tables, sized)
    if late < RESEAT_GAIN:
        return best
    again = share_searches(prepared, problem, tables, result.schedule, new_uuid, sized, seen=seen)
    if again is None:
        return best
    planned = _plan_shared(again, units, tables, strategy, objective, time_limit)
    if planned.better_than(best, objective):
        log.debug("parts sized again for what the plan has the units do first (%.2f x late)",
                  late)
        return planned
    return best


def _tables_of(shared: SharedTree, units: Sequence[UnitState], like: CostTables) -> CostTables:
    """Cost tables for the leaves of ``shared.tree`` in the frame of ``like``, each part costed
    for its own unit alone (``cost_tables(only=...)``: no other unit may take it, and sweeping
    every part at each of the fleet's widths cost most of a round, issue 21)."""
    leaves = [node for _, node in flatten_tree(shared.tree)[1]]
    index = {node.node_uuid: t for t, node in enumerate(leaves)}
    names = {unit.name: u for u, unit in enumerate(units)}
    only = {index[part.node_uuid]: names[part.unit] for search in shared.searches
            for part in search.parts if part.node_uuid in index and part.unit in names}
    return cost_tables(list(units), leaves, frame=like.frame, exclude_busy=like.exclude_busy,
                       only=only)


def make_plan(
    problem: Problem,
    schedule: Schedule,
    prepared: TstNode,
    *,
    strategy: str,
    objective: Objective | str,
    solve_time: float,
    bound: float | None = None,
    engine_unit: str = "op0",
    new_uuid: Callable[[], str] | None = None,
    notes: list[str] | None = None,
    fallback: str | None = None,
    source: TstNode | None = None,
    shared: SharedTree | None = None,
) -> Plan:
    """Turn a schedule (planned on the precedence graph) into a Plan: the tree to send
    (``sent_tree.choose_tree``) and its simulated times; assignments sorted by start, then unit.

    ``prepared`` is the tree planned (with the parts of ``shared`` searches, if any); ``source``
    the caller's (default ``prepared``).
    """
    placements = _placements(problem, schedule)
    sent = choose_tree(problem, schedule, prepared, placements, engine_unit, new_uuid)
    precedence_makespan = schedule.makespan
    schedule = sent.schedule
    assignments: list[Assignment] = []
    unassigned: list[Unassigned] = []
    for t, task in enumerate(problem.tasks):
        u = int(schedule.assign[t])
        if u < 0:
            unassigned.append(Unassigned(task.uuid, task.name, unassigned_reason(problem, t)))
            continue
        unit = problem.unit_names[u]
        assignments.append(
            Assignment(
                node_uuid=task.uuid,
                name=task.name,
                execunit="/" + unit,
                start=float(schedule.start[t]),
                end=float(schedule.end[t]),
                travel_time=float(schedule.travel_time[t]),
                work_time=float(schedule.work_time[t]),
                distance=float(schedule.distance[t]),
            )
        )
    order = {a.node_uuid: i for i, a in enumerate(assignments)}
    assignments.sort(key=lambda a: (a.start, a.execunit, order[a.node_uuid]))
    by_uuid = {a.node_uuid: a for a in assignments}
    routes: dict[str, list[Assignment]] = {}
    for u, route in enumerate(schedule.orders):
        if route:
            routes[problem.unit_names[u]] = [by_uuid[problem.tasks[t].uuid] for t in route]
    goal = Objective(objective)
    match goal:
        case Objective.MAKESPAN:
            primary = schedule.makespan
        case Objective.TOTAL:
            primary = schedule.total_time
    gap = None
    if bound is not None:
        bound = min(bound, primary)
        gap = (primary - bound) / primary if primary > 0 else 0.0
    return Plan(
        strategy=strategy,
        objective=goal.value,
        feasible=not unassigned and schedule.valid,
        makespan=schedule.makespan,
        total_time=schedule.total_time,
        total_distance=schedule.total_distance,
        solve_time=solve_time,
        bound=bound,
        gap=gap,
        assignments=assignments,
        unassigned=unassigned,
        tst=sent.tree,
        routes=routes,
        notes=[*(notes or []), sent.note, *_share_notes(shared)],
        source=prepared if source is None else source,
        precedence_makespan=precedence_makespan,
        fallback=fallback,
        lower_bound=makespan_lower_bound(problem),
        shared=_shared_summary(shared, problem, schedule),
        planned=None if shared is None else prepared,
    )


def _shared_summary(shared: SharedTree | None, problem: Problem, schedule: Schedule
                    ) -> list[SharedSearch]:
    """The plan's account of each shared search: parts with their units, areas, sweeps and
    times in the schedule of the tree sent."""
    if shared is None:
        return []
    index = {task.uuid: t for t, task in enumerate(problem.tasks)}
    out = []
    for search in shared.searches:
        parts = []
        for part in search.parts:
            t = index[part.node_uuid]
            u = int(schedule.assign[t])
            sweep = float(problem.work_distance[u, t]) if u >= 0 else math.nan
            parts.append(SharedPart(part.node_uuid, problem.tasks[t].name, part.unit,
                                    part.area_m2, sweep, float(schedule.start[t]),
                                    float(schedule.end[t])))
        out.append(SharedSearch(search.node_uuid, search.name, search.area_m2, search.bound,
                                tuple(parts)))
    return out


def _share_notes(shared: SharedTree | None) -> list[str]:
    if shared is None:
        return []
    return [f"{s.name} {s.node_uuid} ({s.area_m2 / 1e6:.3g} km2) shared among "
            + ", ".join(f"{p.unit} ({p.area_m2 / s.area_m2:.0%})" for p in s.parts)
            for s in shared.searches]


def _placements(problem: Problem, schedule: Schedule) -> dict[str, Placement]:
    """Each assigned task's unit and rank in the unit's order (for the old wrap rule)."""
    rank = {t: k for order in schedule.orders for k, t in enumerate(order)}
    return {task.uuid: Placement(problem.unit_names[int(schedule.assign[t])], rank.get(t, 0),
                                 task.vehicle)
            for t, task in enumerate(problem.tasks) if schedule.assign[t] >= 0}
