"""The routing model: an mTSP with per-unit speeds, capabilities, aliases, homes and battery.

For trees where every task is activated at mission start (``Problem.plain``): a unit's route is
then all that decides its times. Nodes ``0..n-1`` are the vehicle tasks, then one start and one
end node per unit. Guided local search from the auction's routes; it proves no bound.
"""

from __future__ import annotations

import itertools
import logging
import math
import os
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from delegation.allocation.optimal.minmax import MinMaxModel, minmax_search
from delegation.allocation.optimal.parallel import HELPER_MAX_ENTRIES, HelperSearch
from delegation.allocation.optimal.shared import TICKS, finish, points
from delegation.allocation.problem import Problem
from delegation.allocation.routes import xy_distances
from delegation.allocation.schedule import Schedule, better
from delegation.allocation.strategies import Objective

#: Routing is not tried when its transit matrices would hold more entries than this.
ROUTING_MAX_ENTRIES = 30_000_000
#: Makespan: the share of the time limit the routing solver gets before ``minmax`` takes over
#: (measured: its guided local search ends a few per cent above ``minmax``'s results).
MINMAX_ROUTING_SHARE = 0.25
#: Total (min-sum): the same; its guided local search is strong there (berlin52: +0.03 % at 10 s
#: idle) but slow under load (+1.6 % with a core busy), so ``minmax`` (min-sum mode) follows it
#: and runs from sweeps on the second core.
TOTAL_ROUTING_SHARE = 0.6
#: Makespan: the searches stop at this share of the time limit (the rest: evaluating, answers).
MINMAX_END = 0.96
#: Makespan: from this time limit (s) on, a second process runs ``minmax`` from sweeps.
PORTFOLIO_MIN_SECONDS = 2.0
#: Makespan: the helper process stops searching at this share of the time limit (a little before
#: this process: it still has to send its routes, and on a loaded machine it runs slower).
HELPER_END = 0.92
#: ... less this many seconds (its start-up and answer take about that on a loaded machine).
HELPER_SLACK = 0.1
#: Makespan: the helper's answer is waited for until this share of the time limit at most.
HELPER_WAIT_END = 1.04
log = logging.getLogger(__name__)

#: Routing runs for makespan: (weight of the longest route against the total, share of the time).
ROUTING_MAKESPAN_PHASES: tuple[tuple[int, float], ...] = ((10, 0.5), (100, 0.5))


@dataclass(frozen=True)
class _Setup:
    """What every routing run of one problem shares: the tasks, the units' transit matrices."""

    problem: Problem
    objective: Objective
    tasks: list[int]  # vehicle tasks: node k is task tasks[k]
    classes: dict[bytes, list[int]]  # units with the same costs share one transit matrix
    matrices: dict[bytes, list[list[int]]]  # per class: ticks from node i to node j
    scale: float  # ticks per second
    use_all_units: bool


@dataclass(frozen=True)
class _Phase:
    """One guided-local-search run: the weight of the longest route, seconds, where to start."""

    span_weight: int
    limit: float
    start_orders: list[list[int]]


def solve_routing(
    problem: Problem,
    objective: Objective,
    base: Schedule,
    tasks: list[int],
    limit: float,
    *,
    use_all_units: bool = False,
) -> tuple[Schedule | None, str]:
    """The best routes the routing solver, then ``minmax`` (on both cores) find within
    ``limit`` seconds (None: none better than ``base``), and a note of what it did."""
    setup = _setup(problem, objective, base, tasks, use_all_units)
    if isinstance(setup, str):
        return None, setup
    began = time.perf_counter()
    pos = {t: k for k, t in enumerate(tasks)}
    model = minmax_model(setup)
    helper = None
    if (
        limit >= PORTFOLIO_MIN_SECONDS and (os.cpu_count() or 1) >= 2
        and len(setup.classes) * (len(tasks) + 2 * problem.n_units) ** 2 <= HELPER_MAX_ENTRIES
    ):
        start = [[pos[t] for t in order if t in pos] for order in base.orders]
        helper = HelperSearch.start(model, start, limit * HELPER_END - HELPER_SLACK, seed=1)
    search = _Best(problem, objective, base, use_all_units)
    # Makespan: a short run that weighs the longest route lightly (the total guides the search
    # to good tours), then one that weighs it heavily, from the best so far. Measured on berlin52
    # (3 units, 10 s): 3072 vs 3154 for one heavy run alone.
    match objective:
        case Objective.MAKESPAN:
            phases = ROUTING_MAKESPAN_PHASES
        case Objective.TOTAL:
            phases = ((0, 1.0),)
    share = MINMAX_ROUTING_SHARE if objective is Objective.MAKESPAN else TOTAL_ROUTING_SHARE
    routing_limit = limit * share
    for k, (weight, share) in enumerate(phases):
        left = routing_limit - (time.perf_counter() - began)
        budget = left if k == len(phases) - 1 else routing_limit * share
        orders, note = _routing_phase(setup, _Phase(weight, max(0.05, budget), search.orders))
        search.notes.append(note)
        if orders is not None:
            search.offer(orders)
    _minmax_phase(search, model, tasks, pos, began + limit * MINMAX_END, helper,
                  began + limit * HELPER_WAIT_END)
    if search.best is base:
        return None, "; ".join(search.notes)
    return search.best, "; ".join(search.notes)


class _Best:
    """The best schedule so far among the routes offered (the routing solver's, ``minmax``'s)."""

    def __init__(
        self, problem: Problem, objective: Objective, base: Schedule, use_all_units: bool
    ) -> None:
        self.problem, self.objective, self.use_all_units = problem, objective, use_all_units
        self.best = base
        self.orders = [list(o) for o in base.orders]
        self.notes: list[str] = []

    def offer(self, orders: list[list[int]]) -> bool:
        """Keep ``orders`` (task indices per unit) if they are valid and better (with
        ``use_all_units``, routes using every unit beat any that do not)."""
        found = finish(self.problem, orders)
        counts = not self.use_all_units or all(self.best.orders)
        found_counts = not self.use_all_units or all(found.orders)
        if not found.valid or (counts and not found_counts):
            return False
        if better(found, self.best, self.objective) or (found_counts and not counts):
            self.best, self.orders = found, orders
            return True
        return False


def _minmax_phase(
    search: _Best, model: MinMaxModel, tasks: list[int], pos: dict[int, int], deadline: float,
    helper: HelperSearch | None, wait_until: float,
) -> None:
    """``minmax`` from the best routes so far until ``deadline``; then the helper's routes."""
    start = [[pos[t] for t in order if t in pos] for order in search.orders]
    mine = minmax_search(model, start, deadline, seed=0)
    kept = search.offer([[tasks[k] for k in route] for route in mine.routes])
    label = "min-sum" if model.total else "min-max"
    search.notes.append(
        f"{label} local search from the best routes ({mine.rounds} perturbations, "
        f"{mine.restarts} restarts"
        + (", improved them)" if kept else ", no better)")
    )
    if helper is None:
        return
    theirs = helper.result(wait_until - time.perf_counter())
    if isinstance(theirs, str):
        search.notes.append(f"{label} search on the second core: {theirs}")
        log.warning("optimal: %s search on the second core: %s", label, theirs)
        return
    kept = search.offer([[tasks[k] for k in route] for route in theirs.routes])
    search.notes.append(
        f"{label} search on the second core from sweeps ({theirs.rounds} "
        f"perturbations, {theirs.restarts} restarts"
        + (", best of all)" if kept else ", not better)")
    )


def _setup(
    problem: Problem, objective: Objective, base: Schedule, tasks: list[int], use_all_units: bool
) -> _Setup | str:
    """The units' classes and transit matrices, or why the model would be too large."""
    n, n_units = len(tasks), problem.n_units
    size = n + 2 * n_units
    idx = np.asarray(tasks, dtype=int)
    classes: dict[bytes, list[int]] = {}
    for u in range(n_units):
        key = b"".join(
            [
                problem.speed[u, idx].tobytes(),
                problem.work_time[u, idx].tobytes(),
                np.float64(problem.home_speed[u]).tobytes(),
                problem.home_xy[u].tobytes() if problem.home_task()[idx].any() else b"",
                problem.unit_xy[u].tobytes() if not problem.travels[idx].all() else b"",
                *([] if problem.unit_start_xy is None or problem.unit_end_xy is None else
                  [problem.unit_start_xy[u, idx].tobytes(), problem.unit_end_xy[u, idx].tobytes()]),
            ]
        )
        classes.setdefault(key, []).append(u)
    if len(classes) * size * size > ROUTING_MAX_ENTRIES:
        return f"routing not run: {len(classes)} x {size}^2 matrix entries is too many"
    scale = TICKS / max(base.total_time, 1e-6)
    matrices = {key: _routing_matrix(problem, members[0], idx, scale)
                for key, members in classes.items()}
    return _Setup(problem, objective, tasks, classes, matrices, scale, use_all_units)


def _routing_phase(setup: _Setup, phase: _Phase) -> tuple[list[list[int]] | None, str]:
    """One guided-local-search run of the routing model from ``phase.start_orders``."""
    from ortools.constraint_solver import pywrapcp

    tasks, n_units = setup.tasks, setup.problem.n_units
    size = len(tasks) + 2 * n_units
    starts = list(range(len(tasks), len(tasks) + n_units))
    ends = list(range(len(tasks) + n_units, size))
    manager = pywrapcp.RoutingIndexManager(size, n_units, starts, ends)
    routing = pywrapcp.RoutingModel(manager)
    _costs_and_battery(setup, routing, phase.span_weight)
    _tasks_and_units(setup, manager, routing, phase.span_weight)
    pos = {t: k for k, t in enumerate(tasks)}
    label = f"routing solver ({setup.objective}" + (
        f", span weight {phase.span_weight}" if setup.objective is Objective.MAKESPAN else ""
    ) + f", {phase.limit:.1f} s"
    solution, note = _search(routing, phase, pos, label)
    if solution is None:
        return None, note
    orders: list[list[int]] = []
    for u in range(n_units):
        order: list[int] = []
        index = routing.Start(u)
        while True:
            index = solution.Value(routing.NextVar(index))
            if routing.IsEnd(index):
                break
            order.append(tasks[manager.IndexToNode(index)])
        orders.append(order)
    return orders, note


def _costs_and_battery(setup: _Setup, routing: Any, span_weight: int) -> None:
    """Arc costs per unit; each unit's route time (travel + work + way home) is bounded by its
    remaining endurance; for makespan, the longest route dominates and the total breaks ties."""
    n_units = setup.problem.n_units
    evaluators = [0] * n_units
    for key, members in setup.classes.items():
        evaluator = routing.RegisterTransitMatrix(setup.matrices[key])
        for v in members:
            evaluators[v] = evaluator
    capacity = _capacities(setup)
    routing.AddDimensionWithVehicleTransitAndCapacity(evaluators, 0, capacity, True, "time")
    time_dim = routing.GetDimensionOrDie("time")
    for u in range(n_units):
        routing.SetArcCostEvaluatorOfVehicle(evaluators[u], u)
    if setup.objective is Objective.MAKESPAN:
        time_dim.SetGlobalSpanCostCoefficient(span_weight)


def _capacities(setup: _Setup) -> list[int]:
    """Per unit, its remaining endurance in ticks (the route's time may not exceed it)."""
    endurance = setup.problem.endurance
    return [int(min(e * setup.scale, 2**52)) if math.isfinite(e) else 2**52 for e in endurance]


def minmax_model(setup: _Setup) -> MinMaxModel:
    """The routing model's matrices, capacities, capabilities and aliases for ``minmax``."""
    problem, n, n_units = setup.problem, len(setup.tasks), setup.problem.n_units
    matrices: list[np.ndarray] = [np.zeros(0)] * n_units
    for key, members in setup.classes.items():
        matrix = np.asarray(setup.matrices[key], dtype=float)
        for u in members:
            matrices[u] = matrix
    idx = np.asarray(setup.tasks, dtype=int)
    pinned = np.zeros(n, dtype=bool)
    pos = {t: k for k, t in enumerate(setup.tasks)}
    for group in problem.alias_groups:
        pinned[[pos[t] for t in group if t in pos]] = True
    return MinMaxModel(
        matrices=matrices,
        starts=list(range(n, n + n_units)),
        ends=list(range(n + n_units, n + 2 * n_units)),
        capacity=np.asarray(_capacities(setup), dtype=float),
        allowed=np.asarray(problem.allowed[:, idx], dtype=bool),
        pinned=pinned,
        angle=_angles(problem, idx),
        total=setup.objective is Objective.TOTAL,
        every_unit=setup.use_all_units,
    )


def _angles(problem: Problem, idx: np.ndarray) -> np.ndarray:
    """Each task's angle around the units' mean start (for ``minmax``'s sweep starts); tasks
    done in place (no point) get the angle of their rank, which is as good as any."""
    centre = problem.unit_xy.mean(axis=0)
    xy = problem.start_xy[idx]
    angle = np.arctan2(xy[:, 1] - centre[1], xy[:, 0] - centre[0])
    spread = np.linspace(-np.pi, np.pi, idx.size, endpoint=False)
    return np.where(np.isnan(angle), spread, angle)


def _tasks_and_units(setup: _Setup, manager: Any, routing: Any, span_weight: int) -> None:
    """Each task goes to one unit that may take it (dropping one costs more than any plan);
    tasks with the same alias go to the same unit; with ``use_all_units`` every unit takes one."""
    problem, tasks, n_units = setup.problem, setup.tasks, setup.problem.n_units
    penalty = int((max(span_weight, 1) + 1) * TICKS * 10)
    for k, t in enumerate(tasks):
        index = manager.NodeToIndex(k)
        allowed = np.nonzero(problem.allowed[:, t])[0].tolist()
        if len(allowed) < n_units:
            _allow_vehicles(routing, index, allowed, n_units)
        routing.AddDisjunction([index], penalty)
    pos = {t: k for k, t in enumerate(tasks)}
    solver = routing.solver()
    for group in problem.alias_groups:
        members = [pos[t] for t in group if t in pos]
        for a, b in itertools.pairwise(members):
            solver.Add(
                routing.VehicleVar(manager.NodeToIndex(a))
                == routing.VehicleVar(manager.NodeToIndex(b))
            )
    if setup.use_all_units:
        for u in range(n_units):
            solver.Add(routing.ActiveVehicleVar(u) == 1)


def _search(
    routing: Any, phase: _Phase, pos: dict[int, int], label: str
) -> tuple[Any | None, str]:
    """Guided local search from the phase's routes (from scratch if the model rejects them)."""
    from ortools.constraint_solver import pywrapcp, routing_enums_pb2

    params = pywrapcp.DefaultRoutingSearchParameters()
    params.first_solution_strategy = routing_enums_pb2.FirstSolutionStrategy.PATH_CHEAPEST_ARC
    params.local_search_metaheuristic = (
        routing_enums_pb2.LocalSearchMetaheuristic.GUIDED_LOCAL_SEARCH
    )
    params.time_limit.FromMilliseconds(max(50, int(phase.limit * 1000)))
    routing.CloseModelWithParameters(params)
    initial_routes = [[pos[t] for t in order if t in pos] for order in phase.start_orders]
    initial = routing.ReadAssignmentFromRoutes(initial_routes, True)
    if initial is None:
        solution = routing.SolveWithParameters(params)
        note = label + ", start routes rejected: searched from scratch)"
    else:
        solution = routing.SolveFromAssignmentWithParameters(initial, params)
        note = label + ", guided local search from the best routes so far)"
    if solution is None:
        return None, label + ": no solution)"
    return solution, note


def _allow_vehicles(routing: Any, index: int, allowed: list[int], n_units: int) -> None:
    """Only the units ``allowed`` may visit ``index``.

    ``RoutingModel.SetAllowedVehiclesForIndex`` takes an ``absl::Span<const int>``, which the
    Python binding of OR-Tools 9.15 cannot build from any Python value (``TypeError``); there the
    unit variable of the node loses the other units instead (same constraint, found by
    propagation rather than by the routing filters).
    """
    try:
        routing.SetAllowedVehiclesForIndex(allowed, index)
    except TypeError:
        kept = set(allowed)
        barred = [u for u in range(n_units) if u not in kept]
        routing.VehicleVar(index).RemoveValues(barred)


def _routing_matrix(problem: Problem, u: int, idx: np.ndarray, scale: float) -> list[list[int]]:
    """Ticks from node i to node j for unit u: travel to j's start + j's work (+ way home)."""
    n, n_units = idx.size, problem.n_units
    size = n + 2 * n_units
    start, end, travels = points(problem, u, idx.tolist())
    origin = np.vstack([end, problem.unit_xy, np.zeros((n_units, 2))])  # where a node leaves from
    speed = problem.speed[u, idx]
    into = xy_distances(origin, start) / speed[None, :]
    into[:, ~travels] = 0.0
    into += problem.work_time[u, idx][None, :]
    matrix = np.zeros((size, size))
    matrix[:, :n] = into
    has_home = problem.has_home
    home = np.where(has_home[:, None], problem.home_xy, 0.0)
    back = xy_distances(origin, home) / np.where(has_home, problem.home_speed, 1.0)[None, :]
    matrix[:, n + n_units :] = np.where(has_home[None, :], back, 0.0)
    np.fill_diagonal(matrix, 0.0)
    ticks: list[list[int]] = np.rint(matrix * scale).astype(np.int64).tolist()
    return ticks
