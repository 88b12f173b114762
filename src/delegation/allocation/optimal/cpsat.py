"""The CP-SAT model: per-unit circuits over optional arcs, activation times from the tree.

For trees that order tasks across units (``seq``) or whose conc children are subtrees, and for
small flat trees (it proves optimality there, so the plan carries a ``bound``). Makespan and
battery are linear constraints; conc children that share a unit run one after another as whole
subtrees (``cpsat_subtrees``). The model is built in the OR-Tools samples' order, one method per
constraint family: data, variables, assignment, aliases, tree timing, unit circuits (with subtree
runs and endurance, per unit), the serialised-subtrees sub-model, hints, the solve, the routes.

Solver costs are integers (ticks); durations are rounded down so that the bound stays a proven
lower bound (battery use is rounded up, so that a plan the model accepts fits).
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from delegation.allocation.optimal.cpsat_subtrees import (
    CP_EXACT_CHILDREN,
    SubtreeInputs,
    WrapVars,
    hint_subtrees,
    split_at,
    subtree_model,
    tasks_under,
)
from delegation.allocation.optimal.shared import TICKS, exact_model, finish, points
from delegation.allocation.problem import Problem
from delegation.allocation.routes import xy_distances
from delegation.allocation.schedule import Schedule, better
from delegation.allocation.serialise import conc_paths
from delegation.allocation.strategies import Objective

if TYPE_CHECKING:
    from ortools.sat.python import cp_model

#: Above this many circuit arcs, CP-SAT considers only each task's cheapest units (no bound then).
CP_EXACT_ARCS = 6_000

#: (found schedule or None, proven lower bound (s) or None, what happened)
CpSatResult = tuple[Schedule | None, float | None, str]


def solve_cpsat(
    problem: Problem,
    objective: Objective,
    base: Schedule,
    tasks: list[int],
    limit: float,
    mask: np.ndarray,
    *,
    use_all_units: bool = False,
) -> CpSatResult:
    """Build the model for ``tasks`` (each on the units ``mask`` allows), warm-started from
    ``base``, and solve it within ``limit`` seconds."""
    began = time.perf_counter()
    m = _CpSatModel(problem, objective, base, tasks, mask, use_all_units)
    m.task_times()
    m.assignment()
    m.aliases()
    m.passive_work()
    m.tree_timing()
    m.unit_circuits()
    if m.wrapping:
        m.serialised_subtrees()
    m.hint()
    return m.solve(deadline=began + limit)


def candidates(problem: Problem, tasks: list[int], base: Schedule) -> np.ndarray:
    """Which units CP-SAT considers per task: all allowed ones while the model stays small,
    else the cheapest few (from where the units are, plus the auction's choice)."""
    allowed = problem.allowed.copy()
    arcs = sum(int(allowed[u, tasks].sum()) ** 2 for u in range(problem.n_units))
    if arcs <= CP_EXACT_ARCS or not tasks:
        return allowed
    idx = np.asarray(tasks, dtype=int)
    keep = max(2, int(math.sqrt(CP_EXACT_ARCS * problem.n_units) / len(tasks)))
    with np.errstate(invalid="ignore"):
        start = np.where(problem.travels[idx, None], problem.unit_points()[0][:, idx], 0.0)
        gap = problem.unit_xy[:, None, :] - start  # (U, C, 2): each unit's own start
        travel = np.hypot(gap[..., 0], gap[..., 1]) / problem.speed[:, idx]
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


@dataclass(frozen=True)
class _UnitCosts:
    """One unit's durations (s) in the model; circuit node ``k + 1`` is ``tasks[k]``."""

    tasks: list[int]  # the vehicle tasks the unit may take
    first: np.ndarray  # (k,) from the unit's position: travel + work
    between: np.ndarray  # (k, k) from the end of task i: travel to task j + its work
    home: np.ndarray  # (k,) from the end of each task to the unit's home (0 without one)


def _unit_costs(problem: Problem, tasks: list[int], mask: np.ndarray) -> dict[int, _UnitCosts]:
    """Per unit with candidate tasks, its durations."""
    out: dict[int, _UnitCosts] = {}
    for u in range(problem.n_units):
        mine = [t for t in tasks if mask[u, t]]
        if not mine:
            continue
        start, end, travels = points(problem, u, mine)
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
        out[u] = _UnitCosts(mine, first, between, home)
    return out


class _CpSatModel:
    """The CP-SAT model of one problem; each method adds one family of constraints."""

    def __init__(
        self, problem: Problem, objective: Objective, base: Schedule, tasks: list[int],
        mask: np.ndarray, use_all_units: bool,
    ) -> None:
        from ortools.sat.python import cp_model

        self.problem, self.objective, self.base, self.tasks = problem, objective, base, tasks
        self.mask, self.use_all_units = mask, use_all_units
        self.vehicle_set = set(tasks)
        self.passive = [
            t for t in range(problem.n_tasks)
            if not problem.tasks[t].vehicle and problem.allowed[:, t].any()
        ]
        self.pruned = bool((mask != problem.allowed).any())
        self.exact = exact_model(problem, tasks) and not self.pruned
        # Data: durations (s) per unit and arc, then one horizon and one tick size for all.
        self.costs = _unit_costs(problem, tasks, mask)
        self.passive_dur = {
            t: float(problem.work_time[problem.allowed[:, t], t].max()) for t in self.passive
        }
        self.scale, self.horizon = self._ticks()
        # Whole-subtree wrapping is the old instantiation rule's; on the precedence graph (what
        # plans mean, docs/protocol.md §8) a unit's order and the tree's order are all there is.
        self.wrapping = problem.wrap_subtrees
        self.paths = ([dict(path) for path in conc_paths(problem, every_conc=False)]
                      if self.wrapping else [{} for _ in problem.tasks])
        self.model = cp_model.CpModel()
        self.begin: list[cp_model.IntVar] = []
        self.finish: list[cp_model.IntVar] = []
        self.makespan: cp_model.IntVar | None = None
        self.x: dict[tuple[int, int], cp_model.IntVar] = {}  # (task, unit): the unit takes it
        self.act: list[cp_model.IntVar] = []  # per tree node: when it is activated
        self.done: list[cp_model.IntVar] = []  # per tree node: when it ends
        self.arc_lits: dict[tuple[int, int, int], cp_model.IntVar] = {}  # (unit, from, to); -1
        self.total_terms: list[tuple[cp_model.IntVar, int]] = []  # (arc, its ticks)
        self.chained: dict[int, list[tuple[int, int, Any]]] = {}  # conc -> (child, next, arc)
        self.wrap_vars = WrapVars()
        self.relaxed = 0

    def _ticks(self) -> tuple[float, int]:
        """Ticks per second and the horizon in ticks: the auction's makespan (makespan), or
        every task after every other at the worst arc (total)."""
        worst = 0.0
        for c in self.costs.values():
            worst = max(worst, float(max(c.first.max(), c.between.max(initial=0.0)))
                        + float(c.home.max()))
        match self.objective:
            case Objective.MAKESPAN:
                horizon_s = self.base.makespan * (1 + 1e-6) + 1e-6
            case Objective.TOTAL:
                horizon_s = (worst * (len(self.tasks) + 1) + sum(self.passive_dur.values())
                             + 1.0)
        scale = TICKS / max(horizon_s, 1e-9)
        return scale, math.ceil(horizon_s * scale) + len(self.tasks) + 2

    def _down(self, seconds: float | np.floating[Any]) -> int:
        return math.floor(float(seconds) * self.scale)

    def _up(self, seconds: float | np.floating[Any]) -> int:
        return math.ceil(float(seconds) * self.scale)

    def _span(self) -> cp_model.IntVar:
        assert self.makespan is not None, "task_times() first"
        return self.makespan

    # ----------------------------------------------------------------------- constraints

    def task_times(self) -> None:
        """Every task ends after it begins, and by the makespan."""
        model, horizon, n_tasks = self.model, self.horizon, self.problem.n_tasks
        self.begin = [model.new_int_var(0, horizon, f"S{t}") for t in range(n_tasks)]
        self.finish = [model.new_int_var(0, horizon, f"E{t}") for t in range(n_tasks)]
        self.makespan = model.new_int_var(0, horizon, "makespan")
        for t in range(n_tasks):
            model.add(self.finish[t] >= self.begin[t])
            model.add(self.makespan >= self.finish[t])

    def assignment(self) -> None:
        """Each task goes to exactly one unit that may take it."""
        for t in [*self.tasks, *self.passive]:
            lits = []
            for u in np.nonzero(self.problem.allowed[:, t])[0].tolist():
                if t in self.vehicle_set and (u not in self.costs or not self.mask[u, t]):
                    continue
                self.x[t, u] = self.model.new_bool_var(f"x{t}_{u}")
                lits.append(self.x[t, u])
            self.model.add_exactly_one(lits)

    def aliases(self) -> None:
        """Tasks with the same alias go to the same unit."""
        x, n_units = self.x, self.problem.n_units
        for group in self.problem.alias_groups:
            members = [t for t in group if any((t, u) in x for u in range(n_units))]
            for a, b in itertools.pairwise(members):
                for u in range(n_units):
                    la, lb = x.get((a, u)), x.get((b, u))
                    if la is not None and lb is not None:
                        self.model.add(la == lb)
                    elif la is not None:
                        self.model.add(la == 0)
                    elif lb is not None:
                        self.model.add(lb == 0)

    def passive_work(self) -> None:
        """Non-vehicle tasks take their work time where the tree activates them."""
        for t in self.passive:
            self.model.add(self.finish[t] >= self.begin[t] + self._up(self.passive_dur[t]))

    def tree_timing(self) -> None:
        """The tree activates tasks: seq children one after another, conc children together."""
        model, s, horizon = self.model, self.problem.structure, self.horizon
        self.act = [model.new_int_var(0, horizon, f"A{n}") for n in range(s.size)]
        self.done = [
            self.finish[s.task_of_node[n]] if s.task_of_node[n] >= 0
            else model.new_int_var(0, horizon, f"F{n}")
            for n in range(s.size)
        ]
        act, done = self.act, self.done
        model.add(act[0] == 0)
        for n in range(s.size):
            kids = s.children[n]
            t = s.task_of_node[n]
            if t >= 0:
                model.add(self.begin[t] >= act[n])
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

    def unit_circuits(self) -> None:
        """Per unit: its circuit, its tasks under a node in one run, its endurance."""
        under_node = tasks_under(self.problem, self.vehicle_set)
        for u, c in self.costs.items():
            used, use_terms = self._circuit(u, c)
            if self.wrapping:
                self._subtree_runs(u, c.tasks, under_node)
            if self.use_all_units:
                self.model.add(used == 1)
            self._endurance(u, use_terms)

    def _circuit(self, u: int, c: _UnitCosts) -> tuple[Any, list[tuple[Any, int]]]:
        """The unit runs its vehicle tasks one after another: a circuit through its depot (node
        0), over the arcs that keep the tree's order. Returns whether the unit is used and its
        battery use per arc (ticks)."""
        model, x = self.model, self.x
        arcs: list[tuple[int, int, Any]] = []
        use_terms: list[tuple[Any, int]] = []
        used = model.new_bool_var(f"used{u}")
        arcs.append((0, 0, used.Not()))
        for j, t in enumerate(c.tasks, start=1):
            arcs.append((j, j, x[t, u].Not()))
            lit = model.new_bool_var(f"a{u}_0_{t}")
            arcs.append((0, j, lit))
            self.arc_lits[u, -1, t] = lit
            model.add(self.finish[t] >= self.begin[t] + self._down(c.first[j - 1]))\
                .only_enforce_if(lit)
            self.total_terms.append((lit, self._down(c.first[j - 1])))
            use_terms.append((lit, self._up(c.first[j - 1])))
            back = model.new_bool_var(f"a{u}_{t}_0")
            arcs.append((j, 0, back))
            self.arc_lits[u, t, -1] = back
            if self.problem.has_home[u]:
                model.add(self._span() >= self.finish[t] + self._down(c.home[j - 1]))\
                    .only_enforce_if(back)
                self.total_terms.append((back, self._down(c.home[j - 1])))
                use_terms.append((back, self._up(c.home[j - 1])))
            for i, r in enumerate(c.tasks, start=1):
                if i == j or self.problem.before[t, r]:  # r -> t would break the tree's order
                    continue
                lit = self._arc(u, c, i, j)
                arcs.append((i, j, lit))
                use_terms.append((lit, self._up(c.between[i - 1, j - 1])))
        model.add_circuit(arcs)
        for t in c.tasks:
            model.add_implication(x[t, u], used)
        return used, use_terms

    def _arc(self, u: int, c: _UnitCosts, i: int, j: int) -> Any:
        """Unit ``u`` goes from its task at node i (r) straight to node j (t): t begins when r
        has ended and takes the arc's time; if r and t are under different children P, Q of a
        conc with subtree children, the unit runs P whole, then Q."""
        model, r, t = self.model, c.tasks[i - 1], c.tasks[j - 1]
        lit = model.new_bool_var(f"a{u}_{r}_{t}")
        self.arc_lits[u, r, t] = lit
        model.add(self.begin[t] >= self.finish[r]).only_enforce_if(lit)
        model.add(self.finish[t] >= self.begin[t] + self._down(c.between[i - 1, j - 1]))\
            .only_enforce_if(lit)
        split = split_at(self.paths, r, t)
        if split is not None:
            n, kp, kq = split
            kids = self.problem.structure.children[n]
            model.add(self.act[kids[kq]] >= self.done[kids[kp]]).only_enforce_if(lit)
            self.chained.setdefault(n, []).append((kp, kq, lit))
        self.total_terms.append((lit, self._down(c.between[i - 1, j - 1])))
        return lit

    def _subtree_runs(self, u: int, mine: list[int], under_node: dict[int, set[int]]) -> None:
        """A unit's tasks under any node are one run of its route (else the subtree they are in
        could not run whole): at most one arc enters the node's tasks."""
        mine_set = set(mine)
        for inside in under_node.values():
            held = [t for t in inside if t in mine_set]
            if len(held) < 2 or len(held) == len(mine):
                continue
            outside = [-1] + [r for r in mine if r not in inside]
            entering = [self.arc_lits[u, r, t] for t in held for r in outside
                        if (u, r, t) in self.arc_lits]
            self.model.add(sum(entering) <= 1)

    def _endurance(self, u: int, use_terms: list[tuple[Any, int]]) -> None:
        """A unit's travel + work (+ way home) fits in its remaining endurance."""
        endurance = self.problem.endurance[u]
        if math.isfinite(endurance):
            self.model.add(
                sum(lit * c for lit, c in use_terms) <= math.floor(endurance * self.scale)
            )

    def serialised_subtrees(self) -> None:
        """Conc children that share a unit run one after another as whole subtrees."""
        inputs = SubtreeInputs(
            self.problem, self.paths, self.x, self.act, self.done, self.chained,
            list(self.costs), self.vehicle_set,
        )
        self.wrap_vars, self.relaxed = subtree_model(self.model, inputs)

    def hint(self) -> None:
        """Warm start: the auction's assignment, routes and times (rounded down, as the
        durations); arcs not on its routes are hinted off."""
        model, base, horizon, s = self.model, self.base, self.horizon, self.problem.structure
        if base.valid and base.node_act is not None and base.node_fin is not None:
            for t in range(self.problem.n_tasks):
                if np.isfinite(base.start[t]):
                    model.add_hint(self.begin[t], min(horizon, self._down(base.start[t])))
                    model.add_hint(self.finish[t], min(horizon, self._down(base.end[t])))
            for n in range(s.size):
                model.add_hint(self.act[n], min(horizon, self._down(base.node_act[n])))
                if s.task_of_node[n] < 0:
                    model.add_hint(self.done[n], min(horizon, self._down(base.node_fin[n])))
            model.add_hint(self._span(), min(horizon, self._down(base.makespan)))
        for (t, u), lit in self.x.items():
            model.add_hint(lit, int(base.assign[t] == u))
        hinted = set()
        for u, order in enumerate(base.orders):
            chain = [-1, *[t for t in order if t in self.vehicle_set], -1]
            if len(chain) > 2:
                for a, b in itertools.pairwise(chain):
                    if (u, a, b) in self.arc_lits:
                        model.add_hint(self.arc_lits[u, a, b], 1)
                        hinted.add((u, a, b))
        for key, lit in self.arc_lits.items():
            if key not in hinted:
                model.add_hint(lit, 0)
        if base.valid and self.wrapping:
            hint_subtrees(model, self.problem, base, self.wrap_vars)

    # ----------------------------------------------------------------------- solve

    def solve(self, deadline: float) -> CpSatResult:
        """Solve for the objective by ``deadline`` (``time.perf_counter()``); the routes found,
        re-evaluated with the schedule simulator, a bound if the model is exact, and a note."""
        from ortools.sat.python import cp_model

        solver = cp_model.CpSolver()
        solver.parameters.num_workers = 2
        solver.parameters.random_seed = 1
        # Level 2 (the default) spends ~0.5 s on symmetry search even for tiny models (measured).
        solver.parameters.symmetry_level = 1
        match self.objective:
            case Objective.MAKESPAN:
                result = self._solve_makespan(solver, deadline)
            case Objective.TOTAL:
                result = self._solve_total(solver, deadline)
        found, bound, note = result
        if found is None:
            return result
        if self.relaxed:
            note += (f" (subtrees sharing a unit under {self.relaxed} conc(s) with more than "
                     f"{CP_EXACT_CHILDREN} children relaxed: the solver's plan re-evaluated)")
        if self.pruned:
            note += " (each task among its cheapest units only: no bound)"
        elif not self.exact:
            note += " (in-place vehicle tasks modelled approximately: no bound)"
        return found, bound, note

    def _total(self) -> Any:
        return sum(lit * c for lit, c in self.total_terms)

    def _solve_makespan(self, solver: cp_model.CpSolver, deadline: float) -> CpSatResult:
        """The smallest makespan, then at that makespan the smallest total time."""
        from ortools.sat.python import cp_model

        model, makespan = self.model, self._span()
        model.minimize(makespan)
        solver.parameters.max_time_in_seconds = _remaining(deadline) * 0.7
        status = solver.solve(model)
        if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            return None, None, f"CP-SAT found no solution ({solver.status_name(status)})"
        best = int(solver.objective_value)
        bound = solver.best_objective_bound / self.scale if self.exact else None
        phase1 = solver.status_name(status).lower()
        found = finish(self.problem, self.read_routes(solver))
        s = self.problem.structure
        control_done = [d for n, d in enumerate(self.done) if s.task_of_node[n] < 0]
        everything: list[Any] = [
            *self.x.values(), *self.arc_lits.values(), *self.begin, *self.finish, *self.act,
            makespan, *control_done, *self.wrap_vars.all(),
        ]
        _hint_from(model, solver, everything)
        model.add(makespan <= best)
        model.minimize(self._total())
        solver.parameters.max_time_in_seconds = _remaining(deadline)
        status = solver.solve(model)
        if status in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            second = finish(self.problem, self.read_routes(solver))
            if second.valid and not better(found, second, self.objective):
                found = second
            note = (f"CP-SAT: makespan {phase1}, then total time "
                    f"{solver.status_name(status).lower()} at that makespan")
        else:
            note = (f"CP-SAT: makespan {phase1}; no total-time improvement in time "
                    f"({solver.status_name(status)})")
        return found, bound, note

    def _solve_total(self, solver: cp_model.CpSolver, deadline: float) -> CpSatResult:
        """The smallest total time."""
        from ortools.sat.python import cp_model

        self.model.minimize(self._total())
        solver.parameters.max_time_in_seconds = _remaining(deadline)
        status = solver.solve(self.model)
        if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            return None, None, f"CP-SAT found no solution ({solver.status_name(status)})"
        bound = None
        if self.exact:
            # Non-vehicle tasks add their work wherever they go: at least the smallest.
            problem = self.problem
            constant = sum(
                float(problem.work_time[problem.allowed[:, t], t].min()) for t in self.passive
            )
            bound = solver.best_objective_bound / self.scale + constant
        note = f"CP-SAT: total time {solver.status_name(status).lower()}"
        return finish(self.problem, self.read_routes(solver)), bound, note

    def read_routes(self, solver: cp_model.CpSolver) -> list[list[int]]:
        """Each unit's route: follow its arcs from the depot in the last solution."""
        orders: list[list[int]] = []
        for u in range(self.problem.n_units):
            route: list[int] = []
            if u in self.costs:
                succ = {a: b for (v, a, b), lit in self.arc_lits.items()
                        if v == u and solver.value(lit)}
                at = succ.get(-1, -1)
                while at != -1 and len(route) <= len(self.costs[u].tasks):
                    route.append(at)
                    at = succ.get(at, -1)
            orders.append(route)
        return orders


def _remaining(deadline: float) -> float:
    return max(0.05, deadline - time.perf_counter())


def _hint_from(model: cp_model.CpModel, solver: cp_model.CpSolver, lits: list[Any]) -> None:
    """Replace the hints by the solver's last solution (the second phase starts from it)."""
    model.clear_hints()  # type: ignore[no-untyped-call, unused-ignore]  # untyped in 9.15
    for lit in lits:
        model.add_hint(lit, solver.value(lit))
