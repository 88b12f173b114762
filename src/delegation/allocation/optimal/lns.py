"""Large neighbourhood search (ruin and recreate) over the precedence-graph schedule.

For trees of any shape and size, where CP-SAT is too large or proves nothing in time: start from a
schedule (the auction's or the solver's), repeatedly remove a few vehicle tasks (at random, a task
and its neighbours, or a stretch of the route of the unit that ends last) and put them back one by
one where the schedule simulator (``schedule.evaluate``, the precedence graph every strategy plans
for) says they cost least, among the few places per unit that add the least detour. A new
schedule is judged by the makespan of the series-parallel tree it would be sent as
(``series_parallel.tree_makespan``): the precedence graph's own makespan rewards interleavings no
tree can carry (measured: -39 % on the graph, -9 % on the tree sent, 20x100 mixed, 5 s). It is
accepted when at most a shrinking threshold worse than the current one (0.5 % at first, 0 at the
deadline); the best is kept. Tasks of an alias group and non-vehicle tasks stay
where they are. Anytime: it stops at ``deadline`` (one reinsertion late at most).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from delegation.allocation.problem import Problem
from delegation.allocation.schedule import Schedule, better, better_key, evaluate
from delegation.allocation.series_parallel import tree_makespan
from delegation.allocation.strategies import Objective

#: Places per task evaluated with the simulator (the ones adding the least detour). Measured
#: (lns alone, 8 s, 20x100 and 50x300 mixed, two sites, seeds 0-1, geometric mean of the tree's
#: makespan over the auction's): 2: 0.75, 3: 0.72 (three runs), 4: 0.73, 6: 0.75 (two runs);
#: fewer places mean more iterations, and the search stalls in local optima sooner than it runs
#: out of iterations.
CANDIDATES = 3
#: Threshold acceptance: at the start, a schedule this much worse (relative) is accepted.
START_THRESHOLD = 0.005
#: Tasks one ruin removes at most (at least 2, at most a quarter of the movable tasks). Measured
#: as for ``CANDIDATES``: 4: 0.72, 6: 0.70, 8: 0.73, 12: 0.72, 25: 0.79 (no trend beyond noise
#: below 12; larger ruins are worse).
RUIN_MAX = 12


@dataclass
class LnsResult:
    """The best schedule found, how many iterations ran, and how many improved the best."""

    schedule: Schedule
    iterations: int
    improvements: int
    objective: Objective
    base_value: float  # the objective as judged (makespan: of the tree sent), before and after
    value: float


@dataclass(frozen=True)
class _Geometry:
    """Per unit and task: where the task starts and ends for that unit, whether it travels."""

    start: np.ndarray  # (U, T, 2)
    end: np.ndarray
    travels: np.ndarray  # (U, T)


def _geometry(problem: Problem) -> _Geometry:
    every = np.arange(problem.n_tasks)
    starts, ends, travels = [], [], []
    for u in range(problem.n_units):
        s, e, tr = problem.points_for(u, every)
        starts.append(s)
        ends.append(e)
        travels.append(tr)
    return _Geometry(np.array(starts), np.array(ends), np.array(travels))


class _Search:
    """The state of one search: the current schedule, the best, the random source."""

    def __init__(self, problem: Problem, objective: Objective, base: Schedule, seed: int) -> None:
        self.problem, self.objective = problem, objective
        self.rng = np.random.default_rng(seed)
        self.geo = _geometry(problem)
        alias = problem.alias_of()
        self.movable = [t for t in range(problem.n_tasks)
                        if problem.tasks[t].vehicle and alias[t] < 0 and base.assign[t] >= 0]
        self.current = base
        self.best = base
        self.current_key = self.best_key = self._key(base)

    def _key(self, schedule: Schedule) -> tuple[float, float, float]:
        return tree_key(self.problem, self.objective, schedule)

    def iterate(self, threshold: float, deadline: float = float("inf")) -> bool:
        """One ruin and recreate; True when it improved the best. Given up (False) when
        ``deadline`` passes while reinserting (on large trees one takes up to a second)."""
        assign = self.current.assign.copy()
        orders = [list(o) for o in self.current.orders]
        removed = self._ruin(assign, orders)
        if not removed:
            return False
        self.rng.shuffle(removed)
        for t in removed:
            if time.perf_counter() >= deadline or not self._insert(t, assign, orders):
                return False
        trial = evaluate(self.problem, assign, orders)
        if not trial.valid:
            return False
        key = self._key(trial)
        if _within(key, self.current_key, threshold):
            self.current, self.current_key = trial, key
        if better_key(key, self.best_key):
            self.best, self.best_key = trial, key
            return True
        return False

    def _ruin(self, assign: np.ndarray, orders: list[list[int]]) -> list[int]:
        n = len(self.movable)
        if n < 2:
            return []
        k = int(self.rng.integers(2, max(3, min(RUIN_MAX, n // 4) + 1)))
        kind = self.rng.integers(3)
        if kind == 0:
            chosen = list(self.rng.choice(self.movable, size=min(k, n), replace=False))
        elif kind == 1:
            seed = int(self.rng.choice(self.movable))
            points = self.problem.start_xy[self.movable]
            here = self.problem.start_xy[seed]
            dist = np.nan_to_num(np.hypot(*(points - here).T), nan=np.inf)
            chosen = [self.movable[i] for i in np.argsort(dist)[:k]]
        else:
            finish = self.current.unit_finish
            u = int(np.argmax(finish))
            route = [t for t in orders[u] if t in set(self.movable)]
            if not route:
                return []
            first = int(self.rng.integers(len(route)))
            chosen = route[first:first + k]
        chosen = [int(t) for t in chosen]
        gone = set(chosen)
        for u, order in enumerate(orders):
            orders[u] = [t for t in order if t not in gone]
        assign[chosen] = -1
        return chosen

    def _insert(self, t: int, assign: np.ndarray, orders: list[list[int]]) -> bool:
        """Put task ``t`` where the simulator says it costs least among the cheap places."""
        places = self._places(t, orders)
        best: Schedule | None = None
        best_place: tuple[int, int] | None = None
        for u, pos in places:
            orders[u].insert(pos, t)
            assign[t] = u
            trial = evaluate(self.problem, assign, orders)
            orders[u].pop(pos)
            if trial.valid and (best is None or better(trial, best, self.objective)):
                best, best_place = trial, (u, pos)
        if best_place is None:
            assign[t] = -1
            return False
        u, pos = best_place
        orders[u].insert(pos, t)
        assign[t] = u
        return True

    def _places(self, t: int, orders: list[list[int]]) -> list[tuple[int, int]]:
        """The ``CANDIDATES`` (unit, position) pairs adding the least detour time (for makespan:
        plus the unit's current finish)."""
        p, geo = self.problem, self.geo
        scored: list[tuple[float, int, int]] = []
        for u in (int(x) for x in np.nonzero(p.allowed[:, t])[0]):
            route = orders[u]
            speed = float(p.speed[u, t])
            work = float(p.work_time[u, t])
            ends = [p.unit_xy[u]] + [geo.end[u, r] if geo.travels[u, r] else None for r in route]
            base = float(self.current.unit_finish[u]) if self.objective is Objective.MAKESPAN \
                else 0.0
            here = p.unit_xy[u]
            for pos in range(len(route) + 1):
                if ends[pos] is not None:
                    here = ends[pos]
                detour = work
                if geo.travels[u, t]:
                    detour += float(np.hypot(*(geo.start[u, t] - here))) / speed
                    if pos < len(route) and geo.travels[u, route[pos]]:
                        nxt = geo.start[u, route[pos]]
                        detour += (float(np.hypot(*(nxt - geo.end[u, t])))
                                   - float(np.hypot(*(nxt - here)))) / speed
                scored.append((base + detour, u, pos))
        scored.sort()
        return [(u, pos) for _, u, pos in scored[:CANDIDATES]]


def tree_key(
    problem: Problem, objective: Objective, schedule: Schedule
) -> tuple[float, float, float]:
    """The objective's key, with the makespan of the tree the schedule would be sent as (the
    precedence graph's makespan alone rewards orders no tree can carry)."""
    key = schedule.key(objective)
    sent = tree_makespan(problem, schedule.orders, schedule.start, schedule.end,
                         schedule.home_time, schedule.makespan)
    if objective is Objective.MAKESPAN:
        return (key[0], sent, key[2])
    return (key[0], key[1], sent)


def _within(ka: tuple[float, ...], kb: tuple[float, ...], threshold: float) -> bool:
    """Key ``ka`` is at most ``threshold`` (relative) worse than ``kb`` on the objective."""
    if ka[0] != kb[0]:
        return ka[0] < kb[0]
    return ka[1] <= kb[1] * (1.0 + threshold) + 1e-9


def lns(
    problem: Problem, objective: Objective | str, base: Schedule, deadline: float, seed: int = 0
) -> LnsResult:
    """Improve ``base`` (a valid schedule) until ``deadline`` (``time.perf_counter()``)."""
    objective = Objective(objective)
    search = _Search(problem, objective, base, seed)
    began = time.perf_counter()
    span = max(1e-6, deadline - began)
    iterations = improvements = 0
    while True:
        now = time.perf_counter()
        if now >= deadline:
            break
        threshold = START_THRESHOLD * max(0.0, 1.0 - (now - began) / span)
        improvements += search.iterate(threshold, deadline)
        iterations += 1
    first = search._key(base)[1]
    return LnsResult(search.best, iterations, improvements, objective, first,
                     search.best_key[1])


def lns_note(result: LnsResult) -> str:
    """What the search did, for the plan's notes."""
    before, after = result.base_value, result.value
    change = (after - before) / before * 100 if before > 0 else 0.0
    return (f"large neighbourhood search: {result.iterations} iterations, "
            f"{result.improvements} improvements, {result.objective.value} {before:.1f} -> "
            f"{after:.1f} "
            f"({change:+.1f} %)")
