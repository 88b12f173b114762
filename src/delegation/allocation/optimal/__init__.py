"""The ``optimal`` strategy: OR-Tools, warm-started from the auction, under a time limit.

Which solver (DESIGN 4):
- the **routing solver** for larger trees where every task is activated at mission start (a
  ``conc`` of tasks: an mTSP with per-unit speeds, capabilities, aliases, homes and battery);
  guided local search from the auction's routes; it proves no bound;
- **CP-SAT** where the tree orders tasks across units (``seq``) or has conc children that are
  subtrees, and for small flat trees (it proves optimality there, so the plan carries a ``bound``):
  per-unit circuits over optional arcs, activation times from the tree, makespan and battery as
  linear constraints. Conc children that share a unit run one after another as whole subtrees, in
  the order ``serialise`` derives (DESIGN 3.4); for concs with at most ``CP_EXACT_CHILDREN``
  children holding tasks the model encodes exactly that (which children share a unit, the total
  order of each component, the tie rule), for larger ones a relaxation (each unit's consecutive
  subtrees one after another), so the bound stays a lower bound and the solution is re-evaluated.

Solver costs are integers (ticks); durations are rounded down so that CP-SAT's bound stays a proven
lower bound. Whatever the solver returns is re-evaluated with the schedule simulator, and the
auction's schedule is kept (and said so in a note and a log line) when the solver found nothing
better: ``optimal`` is never worse than ``auction``.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from delegation.allocation.auction import assign_passive, auction
from delegation.allocation.problem import Problem
from delegation.allocation.routes import xy_distances
from delegation.allocation.schedule import Schedule, better, evaluate
from delegation.allocation.serialise import conc_paths, serialisation

log = logging.getLogger(__name__)

#: Flat trees with at most this many vehicle tasks go to CP-SAT (which proves optimality).
CP_MAX_FLAT_TASKS = 12
#: Above this many circuit arcs, CP-SAT considers only each task's cheapest units (no bound then).
CP_EXACT_ARCS = 6_000
#: ... and is not tried when even the pruned circuits would have more arcs than this.
CP_MAX_ARCS = 40_000
#: Routing is not tried when its transit matrices would hold more entries than this.
ROUTING_MAX_ENTRIES = 30_000_000
#: Concs with at most this many children holding tasks get the exact subtree-serialisation model.
CP_EXACT_CHILDREN = 8
#: Ticks per horizon: integer resolution of solver times.
TICKS = 1_000_000
#: Routing runs for makespan: (weight of the longest route against the total, share of the time).
ROUTING_MAKESPAN_PHASES: tuple[tuple[int, float], ...] = ((10, 0.5), (100, 0.5))


@dataclass
class OptimalResult:
    """The chosen schedule, a proven lower bound on the objective (s) if any, and what happened."""

    schedule: Schedule
    bound: float | None = None
    notes: list[str] = field(default_factory=list)
    solver: str = ""


def optimise(
    problem: Problem,
    objective: str = "makespan",
    time_limit: float = 5.0,
    *,
    use_all_units: bool = False,
) -> OptimalResult:
    """Plan with OR-Tools within ``time_limit`` seconds; never worse than the auction.

    ``use_all_units`` (benchmarks only: the published mTSP min-sum values require it) makes every
    unit take at least one task; the auction's plan then counts only if it does so too.
    """
    began = time.perf_counter()
    base = auction(problem, objective)
    tasks = [t for t in range(problem.n_tasks) if problem.tasks[t].vehicle and base.assign[t] >= 0]
    result = OptimalResult(base)
    if not tasks:
        result.notes.append("no vehicle task to optimise; the auction's plan is optimal")
        log.info("optimal: %s", result.notes[-1])
        return result
    flat = problem.plain  # routing models a unit's own route only: exact for plain trees
    mask = _candidates(problem, tasks, base)
    arcs = sum(int(mask[u, tasks].sum()) ** 2 for u in range(problem.n_units))
    remaining = max(0.05, time_limit - (time.perf_counter() - began))
    candidate: Schedule | None = None
    bound: float | None = None
    if (not flat or len(tasks) <= CP_MAX_FLAT_TASKS) and arcs <= CP_MAX_ARCS:
        result.solver = "cp-sat"
        candidate, bound, note = _cpsat(
            problem, objective, base, tasks, remaining, mask, use_all_units=use_all_units
        )
    elif flat:
        result.solver = "routing"
        candidate, note = _routing(
            problem, objective, base, tasks, remaining, use_all_units=use_all_units
        )
    else:
        note = (
            f"CP-SAT not run: the model would have {arcs} arcs (limit {CP_MAX_ARCS}); "
            "keeping the auction's plan"
        )
    result.notes.append(note)
    base_counts = not use_all_units or all(base.orders)
    if candidate is not None and candidate.valid and (
        better(candidate, base, objective) or not base_counts
    ):
        result.schedule = candidate
    elif candidate is not None:
        result.notes.append(
            f"{result.solver} found no better plan than the auction's; keeping the auction's plan"
        )
    result.bound = bound
    for text in result.notes:
        log.info("optimal: %s", text)
    return result


# --------------------------------------------------------------------------- shared helpers


def _finish(problem: Problem, orders: list[list[int]], base: Schedule) -> Schedule:
    """Evaluate vehicle routes, with non-vehicle tasks re-given to units afterwards."""
    assign = np.full(problem.n_tasks, -1, dtype=int)
    for u, order in enumerate(orders):
        assign[order] = u
    assign_passive(problem, assign)
    return evaluate(problem, assign, orders)


def _points(
    problem: Problem, u: int, tasks: list[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start/end points of ``tasks`` for unit ``u``; in-place tasks sit at the unit's position."""
    start, end, travels = problem.points_for(u, np.asarray(tasks, dtype=int))
    start[~travels] = problem.unit_xy[u]
    end[~travels] = problem.unit_xy[u]
    return start, end, travels


def _exact_model(problem: Problem, tasks: list[int]) -> bool:
    """Arc costs are exact only when every vehicle task ends at a known point."""
    idx = np.asarray(tasks, dtype=int)
    home = problem.home_task()[idx]
    if home.any() and not problem.has_home.all():
        return False
    return bool(problem.travels[idx].all())


# --------------------------------------------------------------------------- routing


def _routing(
    problem: Problem,
    objective: str,
    base: Schedule,
    tasks: list[int],
    limit: float,
    *,
    use_all_units: bool = False,
) -> tuple[Schedule | None, str]:

    # Data: nodes 0..n-1 are tasks, then one start and one end node per unit.
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
            ]
        )
        classes.setdefault(key, []).append(u)
    if len(classes) * size * size > ROUTING_MAX_ENTRIES:
        return None, f"routing not run: {len(classes)} x {size}^2 matrix entries is too many"
    scale = TICKS / max(base.total_time, 1e-6)
    matrices = {key: _routing_matrix(problem, members[0], idx, scale)
                for key, members in classes.items()}
    began = time.perf_counter()
    best = base
    best_orders = [list(o) for o in base.orders]
    notes = []
    # Makespan: a short run that weighs the longest route lightly (the total guides the search
    # to good tours), then one that weighs it heavily, from the best so far. Measured on berlin52
    # (3 units, 10 s): 3072 vs 3154 for one heavy run alone.
    phases = ROUTING_MAKESPAN_PHASES if objective == "makespan" else ((0, 1.0),)
    for k, (weight, share) in enumerate(phases):
        left = limit - (time.perf_counter() - began)
        budget = left if k == len(phases) - 1 else limit * share
        orders, note = _routing_phase(
            problem, objective, tasks, classes, matrices, scale, weight, max(0.05, budget),
            best_orders, use_all_units,
        )
        notes.append(note)
        if orders is None:
            continue
        found = _finish(problem, orders, base)
        counts = not use_all_units or all(best.orders)
        if found.valid and (better(found, best, objective) or not counts):
            best, best_orders = found, orders
    if best is base:
        return None, "; ".join(notes)
    return best, "; ".join(notes)


def _routing_phase(
    problem: Problem,
    objective: str,
    tasks: list[int],
    classes: dict[bytes, list[int]],
    matrices: dict[bytes, list[list[int]]],
    scale: float,
    span_weight: int,
    limit: float,
    start_orders: list[list[int]],
    use_all_units: bool,
) -> tuple[list[list[int]] | None, str]:
    """One guided-local-search run of the routing model from ``start_orders``."""
    from ortools.constraint_solver import pywrapcp, routing_enums_pb2

    n, n_units = len(tasks), problem.n_units
    size = n + 2 * n_units
    starts = list(range(n, n + n_units))
    ends = list(range(n + n_units, size))
    manager = pywrapcp.RoutingIndexManager(size, n_units, starts, ends)
    routing = pywrapcp.RoutingModel(manager)
    evaluators = [0] * n_units
    for key, members in classes.items():
        evaluator = routing.RegisterTransitMatrix(matrices[key])
        for v in members:
            evaluators[v] = evaluator

    # Each unit's route time (travel + work + way home) is bounded by its remaining endurance.
    capacity = [
        int(min(problem.endurance[u] * scale, 2**52)) if math.isfinite(problem.endurance[u])
        else 2**52
        for u in range(n_units)
    ]
    routing.AddDimensionWithVehicleTransitAndCapacity(evaluators, 0, capacity, True, "time")
    time_dim = routing.GetDimensionOrDie("time")
    for u in range(n_units):
        routing.SetArcCostEvaluatorOfVehicle(evaluators[u], u)
    if objective == "makespan":
        # The longest route dominates; the total breaks ties.
        time_dim.SetGlobalSpanCostCoefficient(span_weight)

    # Each task goes to one unit that may take it; dropping one costs more than any plan.
    penalty = int((max(span_weight, 1) + 1) * TICKS * 10)
    for k, t in enumerate(tasks):
        index = manager.NodeToIndex(k)
        allowed = np.nonzero(problem.allowed[:, t])[0].tolist()
        if len(allowed) < n_units:
            _allow_vehicles(routing, index, allowed, n_units)
        routing.AddDisjunction([index], penalty)
    # Tasks with the same alias go to the same unit.
    pos = {t: k for k, t in enumerate(tasks)}
    solver = routing.solver()
    for group in problem.alias_groups:
        members = [pos[t] for t in group if t in pos]
        for a, b in itertools.pairwise(members):
            solver.Add(
                routing.VehicleVar(manager.NodeToIndex(a))
                == routing.VehicleVar(manager.NodeToIndex(b))
            )
    if use_all_units:
        # Every unit takes at least one task.
        for u in range(n_units):
            solver.Add(routing.ActiveVehicleVar(u) == 1)

    # Solve from the given routes with guided local search.
    params = pywrapcp.DefaultRoutingSearchParameters()
    params.first_solution_strategy = routing_enums_pb2.FirstSolutionStrategy.PATH_CHEAPEST_ARC
    params.local_search_metaheuristic = (
        routing_enums_pb2.LocalSearchMetaheuristic.GUIDED_LOCAL_SEARCH
    )
    params.time_limit.FromMilliseconds(max(50, int(limit * 1000)))
    routing.CloseModelWithParameters(params)
    initial_routes = [[pos[t] for t in order if t in pos] for order in start_orders]
    initial = routing.ReadAssignmentFromRoutes(initial_routes, True)
    label = f"routing solver ({objective}" + (
        f", span weight {span_weight}" if objective == "makespan" else "") + f", {limit:.1f} s"
    if initial is None:
        solution = routing.SolveWithParameters(params)
        note = label + ", start routes rejected: searched from scratch)"
    else:
        solution = routing.SolveFromAssignmentWithParameters(initial, params)
        note = label + ", guided local search from the best routes so far)"
    if solution is None:
        return None, label + ": no solution)"
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
    start, end, travels = _points(problem, u, idx.tolist())
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
    ticks = np.rint(matrix * scale).astype(np.int64)
    return ticks.tolist()


# --------------------------------------------------------------------------- CP-SAT


def _candidates(problem: Problem, tasks: list[int], base: Schedule) -> np.ndarray:
    """Which units CP-SAT considers per task: all allowed ones while the model stays small,
    else the cheapest few (from where the units are, plus the auction's choice)."""
    allowed = problem.allowed.copy()
    arcs = sum(int(allowed[u, tasks].sum()) ** 2 for u in range(problem.n_units))
    if arcs <= CP_EXACT_ARCS or not tasks:
        return allowed
    idx = np.asarray(tasks, dtype=int)
    keep = max(2, int(math.sqrt(CP_EXACT_ARCS * problem.n_units) / len(tasks)))
    with np.errstate(invalid="ignore"):
        start = np.where(problem.travels[idx, None], problem.start_xy[idx], 0.0)
        travel = xy_distances(problem.unit_xy, start) / problem.speed[:, idx]
        reach = travel + problem.work_time[:, idx]
    reach = np.where(allowed[:, idx], reach, np.inf)
    reach = np.nan_to_num(reach, nan=np.inf)
    cheapest = np.argsort(reach, axis=0, kind="stable")[:keep]  # (keep, C)
    mask = np.zeros_like(allowed)
    mask[:, ~problem.vehicle] = allowed[:, ~problem.vehicle]
    mask[cheapest, idx[None, :]] = True
    mask[base.assign[idx], idx] = True
    mask &= allowed
    alias_of = problem.alias_of()
    for g, members in enumerate(problem.alias_groups):
        joint = mask[:, members].any(axis=1) & allowed[:, members[0]]
        mask[:, [t for t in members if alias_of[t] == g]] = joint[:, None]
    return mask



def _cpsat(
    problem: Problem,
    objective: str,
    base: Schedule,
    tasks: list[int],
    limit: float,
    mask: np.ndarray,
    *,
    use_all_units: bool = False,
) -> tuple[Schedule | None, float | None, str]:
    from ortools.sat.python import cp_model

    began = time.perf_counter()
    n_units = problem.n_units
    s = problem.structure
    vehicle_set = set(tasks)
    passive = [
        t for t in range(problem.n_tasks)
        if not problem.tasks[t].vehicle and problem.allowed[:, t].any()
    ]
    pruned = bool((mask != problem.allowed).any())
    exact = _exact_model(problem, tasks) and not pruned
    before = problem.before

    # Data: durations (s) per unit and arc, then one horizon and one tick size for all.
    dur: dict[int, tuple[list[int], np.ndarray, np.ndarray, np.ndarray]] = {}
    worst = 0.0
    for u in range(n_units):
        mine = [t for t in tasks if mask[u, t]]
        if not mine:
            continue
        start, end, travels = _points(problem, u, mine)
        speed = problem.speed[u, mine]
        work = problem.work_time[u, mine]
        first = np.hypot(*(start - problem.unit_xy[u]).T) / speed
        between = xy_distances(end, start) / speed[None, :]
        first[~travels] = 0.0
        between[:, ~travels] = 0.0
        first += work
        between += work[None, :]
        if problem.has_home[u]:
            home = np.hypot(*(end - problem.home_xy[u]).T) / problem.home_speed[u]
        else:
            home = np.zeros(len(mine))
        dur[u] = (mine, first, between, home)
        worst = max(worst, float(max(first.max(), between.max(initial=0.0))) + float(home.max()))
    passive_dur = {
        t: float(problem.work_time[problem.allowed[:, t], t].max()) for t in passive
    }
    if objective == "makespan":
        horizon_s = base.makespan * (1 + 1e-6) + 1e-6
    else:
        horizon_s = worst * (len(tasks) + 1) + sum(passive_dur.values()) + 1.0
    scale = TICKS / max(horizon_s, 1e-9)
    horizon = math.ceil(horizon_s * scale) + len(tasks) + 2

    def down(x: float | np.floating) -> int:
        return math.floor(float(x) * scale)

    def up(x: float | np.floating) -> int:
        return math.ceil(float(x) * scale)

    model = cp_model.CpModel()
    n_tasks = problem.n_tasks
    begin = [model.new_int_var(0, horizon, f"S{t}") for t in range(n_tasks)]
    finish = [model.new_int_var(0, horizon, f"E{t}") for t in range(n_tasks)]
    makespan = model.new_int_var(0, horizon, "makespan")
    for t in range(n_tasks):
        model.add(finish[t] >= begin[t])
        model.add(makespan >= finish[t])

    # Each task goes to exactly one unit that may take it.
    x: dict[tuple[int, int], cp_model.IntVar] = {}
    for t in [*tasks, *passive]:
        lits = []
        for u in np.nonzero(problem.allowed[:, t])[0].tolist():
            if t in vehicle_set and (u not in dur or not mask[u, t]):
                continue
            x[t, u] = model.new_bool_var(f"x{t}_{u}")
            lits.append(x[t, u])
        model.add_exactly_one(lits)
    # Tasks with the same alias go to the same unit.
    for group in problem.alias_groups:
        members = [t for t in group if any((t, u) in x for u in range(n_units))]
        for a, b in itertools.pairwise(members):
            for u in range(n_units):
                la, lb = x.get((a, u)), x.get((b, u))
                if la is not None and lb is not None:
                    model.add(la == lb)
                elif la is not None:
                    model.add(la == 0)
                elif lb is not None:
                    model.add(lb == 0)
    # Non-vehicle tasks take their work time where the tree activates them.
    for t in passive:
        model.add(finish[t] >= begin[t] + up(passive_dur[t]))

    # The tree activates tasks: seq children one after another, conc children together.
    act = [model.new_int_var(0, horizon, f"A{n}") for n in range(s.size)]
    done = [
        finish[s.task_of_node[n]] if s.task_of_node[n] >= 0
        else model.new_int_var(0, horizon, f"F{n}")
        for n in range(s.size)
    ]
    model.add(act[0] == 0)
    for n in range(s.size):
        kids = s.children[n]
        t = s.task_of_node[n]
        if t >= 0:
            model.add(begin[t] >= act[n])
            continue
        model.add(done[n] >= act[n])
        if s.kinds[n] == "seq":
            previous = act[n]
            for c in kids:
                model.add(act[c] >= previous)
                previous = done[c]
            model.add(done[n] >= previous)
        else:
            for c in kids:
                model.add(act[c] >= act[n])
                model.add(done[n] >= done[c])

    # Each unit runs its vehicle tasks one after another: a circuit through its depot.
    paths = [dict(path) for path in conc_paths(problem, every_conc=False)]
    under_node = _tasks_under(problem, vehicle_set)
    chained: dict[int, list[tuple[int, int, Any]]] = {}  # conc -> (child, next child, arc)
    total_terms: list[tuple[cp_model.IntVar, int]] = []
    arc_lits: dict[tuple[int, int, int], cp_model.IntVar] = {}
    for u, (mine, first, between, home) in dur.items():
        arcs: list[tuple[int, int, Any]] = []
        use_terms: list[tuple[cp_model.IntVar, int]] = []
        used = model.new_bool_var(f"used{u}")
        arcs.append((0, 0, used.Not()))
        for j, t in enumerate(mine, start=1):
            arcs.append((j, j, x[t, u].Not()))
            lit = model.new_bool_var(f"a{u}_0_{t}")
            arcs.append((0, j, lit))
            arc_lits[u, -1, t] = lit
            model.add(finish[t] >= begin[t] + down(first[j - 1])).only_enforce_if(lit)
            total_terms.append((lit, down(first[j - 1])))
            use_terms.append((lit, up(first[j - 1])))
            back = model.new_bool_var(f"a{u}_{t}_0")
            arcs.append((j, 0, back))
            arc_lits[u, t, -1] = back
            if problem.has_home[u]:
                model.add(makespan >= finish[t] + down(home[j - 1])).only_enforce_if(back)
                total_terms.append((back, down(home[j - 1])))
                use_terms.append((back, up(home[j - 1])))
            for i, r in enumerate(mine, start=1):
                if i == j or before[t, r]:  # r -> t would break the tree's order
                    continue
                lit = model.new_bool_var(f"a{u}_{r}_{t}")
                arcs.append((i, j, lit))
                arc_lits[u, r, t] = lit
                model.add(begin[t] >= finish[r]).only_enforce_if(lit)
                model.add(finish[t] >= begin[t] + down(between[i - 1, j - 1])).only_enforce_if(lit)
                split = _split_at(paths, r, t)
                if split is not None:
                    # r and t are under different children P, Q of a conc with subtree children:
                    # the unit runs P whole, then Q.
                    n, kp, kq = split
                    kids = s.children[n]
                    model.add(act[kids[kq]] >= done[kids[kp]]).only_enforce_if(lit)
                    chained.setdefault(n, []).append((kp, kq, lit))
                total_terms.append((lit, down(between[i - 1, j - 1])))
                use_terms.append((lit, up(between[i - 1, j - 1])))
        model.add_circuit(arcs)
        for t in mine:
            model.add_implication(x[t, u], used)
        # A unit's tasks under any node are one run of its route (else the subtree they are in
        # could not run whole): at most one arc enters the node's tasks.
        mine_set = set(mine)
        for inside in under_node.values():
            held = [t for t in inside if t in mine_set]
            if len(held) < 2 or len(held) == len(mine):
                continue
            outside = [-1] + [r for r in mine if r not in inside]
            entering = [arc_lits[u, r, t] for t in held for r in outside if (u, r, t) in arc_lits]
            model.add(sum(entering) <= 1)
        if use_all_units:
            model.add(used == 1)
        # A unit's travel + work (+ way home) fits in its remaining endurance.
        if math.isfinite(problem.endurance[u]):
            model.add(
                sum(lit * c for lit, c in use_terms)
                <= math.floor(problem.endurance[u] * scale)
            )
    total = sum(lit * c for lit, c in total_terms)
    wrap_vars, relaxed = _serialisation_model(
        model, problem, paths, x, act, done, chained, dur, vehicle_set
    )

    # Warm start: the auction's assignment, routes and times (rounded down, as the durations).
    if base.valid and base.node_act is not None and base.node_fin is not None:
        for t in range(n_tasks):
            if np.isfinite(base.start[t]):
                model.add_hint(begin[t], min(horizon, down(base.start[t])))
                model.add_hint(finish[t], min(horizon, down(base.end[t])))
        for n in range(s.size):
            model.add_hint(act[n], min(horizon, down(base.node_act[n])))
            if s.task_of_node[n] < 0:
                model.add_hint(done[n], min(horizon, down(base.node_fin[n])))
        model.add_hint(makespan, min(horizon, down(base.makespan)))
    for (t, u), lit in x.items():
        model.add_hint(lit, int(base.assign[t] == u))
    hinted = set()
    for u, order in enumerate(base.orders):
        chain = [-1, *[t for t in order if t in vehicle_set], -1]
        if len(chain) > 2:
            for a, b in itertools.pairwise(chain):
                if (u, a, b) in arc_lits:
                    model.add_hint(arc_lits[u, a, b], 1)
                    hinted.add((u, a, b))
    for key, lit in arc_lits.items():
        if key not in hinted:
            model.add_hint(lit, 0)
    if base.valid:
        _hint_serialisation(model, problem, base, wrap_vars)

    solver = cp_model.CpSolver()
    solver.parameters.num_workers = 2
    solver.parameters.random_seed = 1
    # Level 2 (the default) spends ~0.5 s on symmetry search even for tiny models (measured).
    solver.parameters.symmetry_level = 1
    bound: float | None = None

    def remaining() -> float:
        return max(0.05, limit - (time.perf_counter() - began))

    def read_orders() -> list[list[int]]:
        """Each unit's route: follow its arcs from the depot in the last solution."""
        orders: list[list[int]] = []
        for u in range(n_units):
            route: list[int] = []
            if u in dur:
                succ = {a: b for (v, a, b), lit in arc_lits.items()
                        if v == u and solver.value(lit)}
                at = succ.get(-1, -1)
                while at != -1 and len(route) <= len(dur[u][0]):
                    route.append(at)
                    at = succ.get(at, -1)
            orders.append(route)
        return orders

    if objective == "makespan":
        model.minimize(makespan)
        solver.parameters.max_time_in_seconds = remaining() * 0.7
        status = solver.solve(model)
        if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            return None, None, f"CP-SAT found no solution ({solver.status_name(status)})"
        best = int(solver.objective_value)
        if exact:
            bound = solver.best_objective_bound / scale
        phase1 = solver.status_name(status).lower()
        found = _finish(problem, read_orders(), base)
        control_done = [d for n, d in enumerate(done) if s.task_of_node[n] < 0]
        everything: list[object] = [
            *x.values(), *arc_lits.values(), *begin, *finish, *act, makespan, *control_done,
            *wrap_vars.all(),
        ]
        _hint_from(model, solver, everything)
        # Second phase: the best makespan found, with the smallest total time.
        model.add(makespan <= best)
        model.minimize(total)
        solver.parameters.max_time_in_seconds = remaining()
        status = solver.solve(model)
        if status in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            second = _finish(problem, read_orders(), base)
            if second.valid and not better(found, second, objective):
                found = second
            note = (f"CP-SAT: makespan {phase1}, then total time "
                    f"{solver.status_name(status).lower()} at that makespan")
        else:
            note = (f"CP-SAT: makespan {phase1}; no total-time improvement in time "
                    f"({solver.status_name(status)})")
    else:
        model.minimize(total)
        solver.parameters.max_time_in_seconds = remaining()
        status = solver.solve(model)
        if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            return None, None, f"CP-SAT found no solution ({solver.status_name(status)})"
        if exact:
            # Non-vehicle tasks add their work wherever they go: at least the smallest.
            constant = sum(
                float(problem.work_time[problem.allowed[:, t], t].min()) for t in passive
            )
            bound = solver.best_objective_bound / scale + constant
        note = f"CP-SAT: total time {solver.status_name(status).lower()}"
        found = _finish(problem, read_orders(), base)
    if relaxed:
        note += (f" (subtrees sharing a unit under {relaxed} conc(s) with more than "
                 f"{CP_EXACT_CHILDREN} children relaxed: the solver's plan re-evaluated)")
    if pruned:
        note += " (each task among its cheapest units only: no bound)"
    elif not exact:
        note += " (in-place vehicle tasks modelled approximately: no bound)"
    return found, bound, note


def _hint_from(model: object, solver: object, lits: list[object]) -> None:
    """Replace the hints by the solver's last solution (the second phase starts from it)."""
    model.clear_hints()  # type: ignore[attr-defined]
    for lit in lits:
        model.add_hint(lit, solver.value(lit))  # type: ignore[attr-defined]


# --------------------------------------------------------------------------- CP-SAT: subtrees


@dataclass
class _WrapVars:
    """The serialisation model's variables, per conc: ``prec[n][i, j]`` child i runs before j."""

    has: dict[tuple[int, int, int], Any] = field(default_factory=dict)  # (conc, child, unit)
    share: dict[tuple[int, int, int], Any] = field(default_factory=dict)  # (conc, i, j), i < j
    prec: dict[tuple[int, int, int], Any] = field(default_factory=dict)  # (conc, i, j)
    together: dict[tuple[int, int, int], Any] = field(default_factory=dict)  # (conc, i, j), i < j

    def all(self) -> list[Any]:
        return [*self.has.values(), *self.share.values(), *self.prec.values(),
                *self.together.values()]


def _split_at(paths: list[dict[int, int]], r: int, t: int) -> tuple[int, int, int] | None:
    """(conc, child of r, child of t) where r and t are under different children of a conc
    whose children are subtrees (their lowest common ancestor), else None."""
    mine = paths[r]
    for n, kq in paths[t].items():
        kp = mine.get(n)
        if kp is not None and kp != kq:
            return n, kp, kq
    return None


def _tasks_under(problem: Problem, tasks: set[int]) -> dict[int, set[int]]:
    """Control nodes (not the root) holding two or more of ``tasks``, with those tasks."""
    s = problem.structure
    under: list[set[int]] = [set() for _ in range(s.size)]
    for n in range(s.size - 1, -1, -1):
        t = s.task_of_node[n]
        if t >= 0:
            if t in tasks:
                under[n] = {t}
        else:
            under[n] = set().union(*(under[c] for c in s.children[n])) if s.children[n] else set()
    return {n: under[n] for n in range(1, s.size)
            if s.task_of_node[n] < 0 and len(under[n]) >= 2}


def _serialisation_model(
    model: Any,
    problem: Problem,
    paths: list[dict[int, int]],
    x: dict[tuple[int, int], Any],
    act: list[Any],
    done: list[Any],
    chained: dict[int, list[tuple[int, int, Any]]],
    dur: dict[int, Any],
    vehicle_set: set[int],
) -> tuple[_WrapVars, int]:
    """Children of a conc that share a unit: one total order per component, as ``serialise``.

    Exact for concs with at most ``CP_EXACT_CHILDREN`` children holding tasks: ``has`` (a unit
    has a task under a child), ``share`` (two children have a unit in common), ``together``
    (same component: closed under sharing), ``prec`` (a total order on each component,
    transitive, consistent with every unit's route) and the tie rule: a child j runs before an
    earlier one i (in the tree) only if i waits for j (they share a unit) or for a child that
    shares a unit with i, runs before i and after j. So the order is the topological order that
    takes the child first in the tree among those free to go. Extra ``together`` pairs only add
    constraints, so they never beat the true model. Returns the variables and how many concs
    were relaxed.
    """
    wv = _WrapVars()
    s = problem.structure
    relaxed = 0
    children_of: dict[int, dict[int, list[int]]] = {}
    for t in vehicle_set:
        for n, k in paths[t].items():
            children_of.setdefault(n, {}).setdefault(k, []).append(t)
    for n, held in sorted(children_of.items()):
        ks = sorted(held)
        if len(ks) < 2:
            continue
        if len(ks) > CP_EXACT_CHILDREN:
            relaxed += 1
            continue
        kids = s.children[n]
        for k in ks:
            for u in dur:
                lits = [x[t, u] for t in held[k] if (t, u) in x]
                if lits:
                    var = model.new_bool_var(f"has{n}_{k}_{u}")
                    model.add_max_equality(var, lits)
                    wv.has[n, k, u] = var
        for i, j in itertools.combinations(ks, 2):
            both = []
            for u in dur:
                a, b = wv.has.get((n, i, u)), wv.has.get((n, j, u))
                if a is None or b is None:
                    continue
                lit = model.new_bool_var(f"both{n}_{i}_{j}_{u}")
                model.add_implication(lit, a)
                model.add_implication(lit, b)
                model.add_bool_or([a.Not(), b.Not(), lit])
                both.append(lit)
            if both:
                share = model.new_bool_var(f"share{n}_{i}_{j}")
                model.add_max_equality(share, both)
                wv.share[n, i, j] = share
            together = model.new_bool_var(f"together{n}_{i}_{j}")
            wv.together[n, i, j] = together
            wv.prec[n, i, j] = model.new_bool_var(f"prec{n}_{i}_{j}")
            wv.prec[n, j, i] = model.new_bool_var(f"prec{n}_{j}_{i}")
            model.add(wv.prec[n, i, j] + wv.prec[n, j, i] == together)
            if both:
                model.add_implication(wv.share[n, i, j], together)
            model.add(act[kids[j]] >= done[kids[i]]).only_enforce_if(wv.prec[n, i, j])
            model.add(act[kids[i]] >= done[kids[j]]).only_enforce_if(wv.prec[n, j, i])

        def tog(i: int, j: int, n: int = n) -> Any:
            return wv.together[n, min(i, j), max(i, j)]

        for i, j, m in itertools.permutations(ks, 3):
            model.add_bool_or([wv.prec[n, i, m].Not(), wv.prec[n, m, j].Not(), wv.prec[n, i, j]])
            if i < j:
                model.add_bool_or([tog(i, m).Not(), tog(m, j).Not(), tog(i, j)])
        for kp, kq, lit in chained.get(n, []):
            model.add_implication(lit, wv.prec[n, kp, kq])
        # The tie rule: j (later in the tree) before i only if i waits for j or for a child p
        # that shares a unit with it and runs after j.
        for i, j in itertools.combinations(ks, 2):
            direct = wv.share.get((n, i, j))
            blockers = [direct] if direct is not None else []
            for p in ks:
                share = wv.share.get((n, min(p, i), max(p, i))) if p not in (i, j) else None
                if share is None:
                    continue
                z = model.new_bool_var(f"block{n}_{p}_{i}_{j}")
                model.add_implication(z, share)
                model.add_implication(z, wv.prec[n, p, i])
                model.add_implication(z, wv.prec[n, j, p])
                blockers.append(z)
            model.add_bool_or([wv.prec[n, j, i].Not(), *blockers])
    return wv, relaxed


def _hint_serialisation(model: Any, problem: Problem, base: Schedule, wv: _WrapVars) -> None:
    """Hint the serialisation variables from the auction's schedule."""
    s = problem.structure
    order = serialisation(problem, base.orders, every_conc=False)
    place: dict[tuple[int, int], tuple[int, int]] = {}
    for w, (n, kids) in enumerate(order.wraps):
        position = {child: k for k, child in enumerate(s.children[n])}
        for rank, child in enumerate(kids):
            place[n, position[child]] = (w, rank)
    for (n, i, j), lit in wv.prec.items():
        a, b = place.get((n, i)), place.get((n, j))
        model.add_hint(lit, int(a is not None and b is not None and a[0] == b[0] and a[1] < b[1]))
    for (n, i, j), lit in wv.together.items():
        a, b = place.get((n, i)), place.get((n, j))
        model.add_hint(lit, int(a is not None and b is not None and a[0] == b[0]))
