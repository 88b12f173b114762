"""A bounded local search after the auction: move runs of tasks off the unit that ends last.

The sequential auction awards one task at a time, cheapest marginal cost first, so a long task
(a ``move-path``) bid late lands on a unit that already holds short ones, and nothing moves it
back: the same tasks can be planned worse alone than inside a larger mission where other units
happened to take the short ones first (issue 25: 441 s alone vs 314 s inside both fleets' plan).
Here a run of one to ``SEGMENT`` consecutive tasks of the critical unit (the one whose finish is
the objective's worst: for makespan the last to end; for total time any unit) is moved to the
place in another unit's route that the route arithmetic says is best (after the tasks the tree
runs before it), or one of its tasks is swapped with another unit's; a move is kept only if the
simulation (``schedule.evaluate``) is strictly better on the mission's objective, and for trees
that are not plain the result only if the tree the plan would send is better too. Moves are
ranked by that arithmetic and at most ``EVALUATIONS`` simulations run, so the auction stays
fast (about 2-3 ms of CPU on latency.py's 10 x 20 mixed trees); trees above ``MAX_TASKS``
vehicle tasks keep the auction's plan.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from delegation.allocation.problem import Problem
from delegation.allocation.routes import route_points
from delegation.allocation.schedule import Schedule, better_key, evaluate, static_for
from delegation.allocation.series_parallel import schedule_decomposition, sp_times
from delegation.allocation.strategies import Objective
from delegation.coverage import pick_way

#: Longest run of consecutive tasks moved as one (a ``seq`` of a few tasks moves whole).
SEGMENT = 3
#: Simulations the search may run per plan (each about 0.1 ms on a 10-task mission).
EVALUATIONS = 40
#: Best-estimated moves simulated per round before the search gives up.
TRIES_PER_ROUND = 4
#: Schedules the search found whose sent trees are checked against the auction's.
GUARDED = 3
#: Vehicle tasks above which the search is skipped (the auction must scale to 1000 tasks).
MAX_TASKS = 120

#: ``routes.route_points`` of one route: where the unit is before each position, where it goes
#: next, and at what speed.
_Points = tuple[np.ndarray, np.ndarray, np.ndarray]
#: A candidate: (estimated key, tie-break, the move).
_Move = tuple[tuple[float, float], int, "_Relocation | _Swap"]


def improve(problem: Problem, objective: Objective, schedule: Schedule) -> Schedule:
    """``schedule`` or a strictly better one reached by moving or swapping tasks; see the
    module docstring. Invalid schedules (endurance, unassigned tasks) are returned as they are."""
    if not schedule.valid or problem.n_units < 2:
        return schedule
    movable = _movable(problem, schedule)
    if not movable.any() or int(movable.sum()) > MAX_TASKS:
        return schedule
    search = _Search(problem, objective, schedule, movable)
    return search.run()


def _movable(problem: Problem, schedule: Schedule) -> np.ndarray:
    """Vehicle tasks with a unit, no alias (an alias group must stay on one unit) and not
    ``go-home`` (its points are the unit's own)."""
    alias = problem.alias_of()
    movable = problem.vehicle & (schedule.assign >= 0) & (alias < 0)
    return np.asarray(movable & ~problem.home_task()) if problem.n_tasks else movable


def route_time(problem: Problem, u: int, route: Sequence[int]) -> float:
    """Unit ``u``'s travel + work time for ``route`` and the way home (0 when empty); each
    search flown the way that costs least from where the unit is (as ``schedule.evaluate``)."""
    if not route:
        return 0.0
    idx = np.asarray(route, dtype=int)
    start, end, travels = problem.points_for(u, idx)
    # Plain floats (one conversion per array): numpy scalars cost more than the arithmetic.
    start_l, end_l, travels_l = start.tolist(), end.tolist(), travels.tolist()
    speeds, works = problem.speed[u, idx].tolist(), problem.work_time[u, idx].tolist()
    hx, hy = problem.unit_xy[u].tolist()
    ways = static_for(problem).ways[u]
    total = 0.0
    for k in range(len(route)):
        way = ways.get(route[k]) if travels_l[k] else None
        if way is not None:  # a sweep: flown as the schedule flies it from here
            sx, sy, ex, ey, _, work = way[pick_way(way, (hx, hy))]
            total += math.hypot(sx - hx, sy - hy) / speeds[k] + work
            hx, hy = ex, ey
            continue
        if travels_l[k]:
            sx, sy = start_l[k]
            total += math.hypot(sx - hx, sy - hy) / speeds[k]
            hx, hy = end_l[k]
        total += works[k]
    if problem.has_home[u]:
        gx, gy = problem.home_xy[u].tolist()
        total += math.hypot(gx - hx, gy - hy) / float(problem.home_speed[u])
    return total


class _Search:
    """The current best schedule, its key, and the simulations left."""

    def __init__(self, problem: Problem, objective: Objective, schedule: Schedule,
                 movable: np.ndarray) -> None:
        self.problem, self.objective, self.movable = problem, objective, movable
        self.best, self.best_key = schedule, schedule.key(objective)
        self.left = EVALUATIONS
        self.plain = problem.plain
        self._times: dict[tuple[int, tuple[int, ...]], float] = {}
        self._points: dict[tuple[int, tuple[int, ...]], _Points] = {}

    def route_time(self, v: int, route: Sequence[int]) -> float:
        """``route_time``, remembered per (unit, route): moves meet the same routes again."""
        key = (v, tuple(route))
        found = self._times.get(key)
        if found is None:
            found = self._times[key] = route_time(self.problem, v, route)
        return found

    def route_points(self, v: int, route: Sequence[int]) -> _Points:
        """``routes.route_points``, remembered per (unit, route): a kept move changes two
        routes, and each round prices moves against every route."""
        key = (v, tuple(route))
        found = self._points.get(key)
        if found is None:
            found = self._points[key] = route_points(self.problem, v, route)
        return found

    def run(self) -> Schedule:
        start = self.best
        kept = [start]
        while self.left > 0 and self._round():
            kept.append(self.best)
        if self.plain or len(kept) == 1:
            return self.best
        # The search compared precedence graphs; the plan sends the better of the best
        # series-parallel tree and the old wrap rule's. Keep the latest of the last
        # ``GUARDED`` schedules that is better on that measure too (a tree is never shorter
        # than its graph: the auction's own tree is only built where that cannot decide).
        floor = start.key(self.objective)  # the start's tree is never better than its graph
        start_key: tuple[float, float, float] | None = None
        for schedule in reversed(kept[1:][-GUARDED:]):
            key = self._sent_key(schedule)
            if better_key(key, floor):
                return schedule
            start_key = start_key or self._sent_key(start)
            if better_key(key, start_key):
                return schedule
        return start

    def _sent_key(self, schedule: Schedule) -> tuple[float, float, float]:
        """``_key`` with the tree the plan would send: the best series-parallel decomposition
        or the old rule's wrapped tree, whichever is shorter (``sent_tree.choose_tree``)."""
        problem = self.problem
        graph, tree = schedule_decomposition(problem, schedule)
        sent, _, _ = sp_times(tree, graph)
        wrapped = evaluate(problem, schedule.assign, schedule.orders, wrapped=True)
        if wrapped.valid:
            sent = min(sent, wrapped.makespan)
        key = schedule.key(self.objective)
        if self.objective is Objective.MAKESPAN:
            return (key[0], sent, key[2])
        return (key[0], key[1], sent)

    def _round(self) -> bool:
        """Simulate the best-estimated moves that keep subtrees whole; True when one was kept."""
        now = self.best_key[1:]
        moves = sorted((m for m in self._moves() if better_key(m[0], now)),
                       key=lambda m: (m[0], m[1]))
        tries = 0
        for _, _, move in moves:
            if self.left <= 0 or tries >= TRIES_PER_ROUND:
                return False
            change = move.routes(self.best.orders)
            if not all(self._whole(route) for route in change.values()):
                continue
            tries += 1
            self.left -= 1
            orders = [list(o) for o in self.best.orders]
            assign = self.best.assign.copy()
            for v, route in change.items():
                orders[v] = route
                assign[route] = v
            trial = evaluate(self.problem, assign, orders)
            key = trial.key(self.objective)
            if trial.valid and better_key(key, self.best_key):
                self.best, self.best_key = trial, key
                return True
        return False

    def _moves(self) -> Iterator[_Move]:
        """Moves off the critical unit (total time: off every unit), with their estimated
        (objective, other measure): each changed unit's finish moves by its route's change."""
        best, problem = self.best, self.problem
        self.times = [self.route_time(v, r) for v, r in enumerate(best.orders)]
        self.finish = np.asarray(best.unit_finish, dtype=float)
        node_of = np.asarray(problem.structure.node_of_task, dtype=int)
        self.act = best.node_act[node_of] if best.node_act is not None \
            else np.zeros(problem.n_tasks)
        makespan_first = self.objective is Objective.MAKESPAN
        sources = [int(np.argmax(self.finish))] if makespan_first else range(problem.n_units)
        top = sorted(((float(f), v) for v, f in enumerate(self.finish)), reverse=True)[:3]
        serial = 0
        for s in sources:
            for added, move in self._changes(s):
                # The latest end of the units the move leaves alone (moves change two units).
                rest = next((f for f, v in top if v not in added), 0.0)
                latest = max(rest, *(self.finish[v] + a for v, a in added.items()))
                total = float(best.total_time) + sum(added.values())
                est = (float(latest), total) if makespan_first else (total, float(latest))
                serial += 1
                yield est, serial, move

    def _hopeless(self, added: np.ndarray, gain: float | np.ndarray, ends: np.ndarray
                  ) -> np.ndarray:
        """Which takers cannot take ``added`` more time (freeing ``gain`` elsewhere) and
        improve: for makespan they would end (now ``ends``) no earlier than the plan does now,
        for total the added time outweighs the gain."""
        if self.objective is Objective.MAKESPAN:
            return np.asarray(ends + added >= self.best.makespan)
        return np.asarray(added >= gain)

    def _changes(self, s: int) -> Iterator[tuple[dict[int, float], _Relocation | _Swap]]:
        """Moves of a run of ``s``'s tasks to the cheapest place in another unit's route, then
        swaps of one of them with another unit's task: (added time per unit, new routes)."""
        orders = self.best.orders
        route = orders[s]
        flat = _FlatRoutes(self.problem, orders, self.route_points)
        for i in range(len(route)):
            for k in range(1, SEGMENT + 1):
                seg = route[i:i + k]
                if len(seg) < k or not self.movable[seg].all() or (k > 1 and not self._bundle(seg)):
                    break
                rest = route[:i] + route[i + k:]
                gain = self.times[s] - self.route_time(s, rest)
                cost, place = flat.insertion(seg)
                # A run the tree activates late makes its new unit wait for it.
                cost = np.maximum(self.finish, self.act[seg[0]]) + cost - self.finish
                takers = self.problem.allowed[:, seg].all(axis=1)
                takers &= ~self._hopeless(cost, gain, self.finish)
                takers[s] = False
                for v in np.flatnonzero(takers).tolist():
                    yield ({s: -gain, v: float(cost[v])},
                           _Relocation(s, rest, v, int(place[v]), seg))
        yield from self._swaps(s, flat)

    def _bundle(self, seg: list[int]) -> bool:
        """Whether the run ``seg`` lies under one node below the root (a ``seq`` or subtree
        child moved whole); runs across the root's children are not tried (too many)."""
        r = np.asarray(seg, dtype=int)
        return bool((self.problem.lca_depth(r[:1], r[1:]) >= 2).all())

    def _swaps(self, s: int, flat: _FlatRoutes
               ) -> Iterator[tuple[dict[int, float], _Relocation | _Swap]]:
        """Swaps of each of ``s``'s tasks with one task of another unit (both travelling), in
        route order; priced for all of ``s``'s tasks at once (rows), not task by task."""
        problem, route = self.problem, self.best.orders[s]
        rows = [i for i, t in enumerate(route) if self.movable[t] and problem.travels[t]]
        if not rows:
            return
        ts = np.asarray([route[i] for i in rows], dtype=int)
        mine, theirs = flat.swap_costs(s, np.asarray(rows, dtype=int), ts)  # (rows, F)
        ok = (flat.owner_at != s) & self.movable[flat.task_at] & problem.travels[flat.task_at]
        ok = ok & problem.allowed[flat.owner_at[None, :], ts[:, None]] \
            & problem.allowed[s, flat.task_at]
        ok &= ~self._hopeless(theirs, -mine, self.finish[flat.owner_at])
        for r, i in enumerate(rows):
            for f in np.flatnonzero(ok[r]).tolist():
                v = int(flat.owner_at[f])
                yield ({s: float(mine[r, f]), v: float(theirs[r, f])},
                       _Swap(s, i, v, int(flat.k_at[f])))

    def _whole(self, route: list[int]) -> bool:
        """Whether the unit's tasks under every node of the tree are one run of ``route`` (as
        ``routes.keeps_subtrees_whole`` keeps them; plain trees: always): for each task, the
        depth of its lowest common ancestor with the tasks after it never rises."""
        if self.plain or len(route) < 3:
            return True
        r = np.asarray(route, dtype=int)
        depth = self.problem.lca_depth(r[:, None], r[None, :])
        n = r.size
        i, j = np.ogrid[:n, : n - 1]
        rises = (depth[:, 1:] > depth[:, :-1]) & (j > i)
        return not bool(rises.any())


@dataclass(frozen=True)
class _Relocation:
    """The run ``seg`` off unit ``s`` (leaving ``rest``) to position ``p`` of unit ``v``."""

    s: int
    rest: list[int]
    v: int
    p: int
    seg: list[int]

    def routes(self, orders: Sequence[Sequence[int]]) -> dict[int, list[int]]:
        there = list(orders[self.v])
        return {self.s: self.rest, self.v: there[:self.p] + self.seg + there[self.p:]}


@dataclass(frozen=True)
class _Swap:
    """Task ``i`` of unit ``s`` for task ``j`` of unit ``v``."""

    s: int
    i: int
    v: int
    j: int

    def routes(self, orders: Sequence[Sequence[int]]) -> dict[int, list[int]]:
        here, there = list(orders[self.s]), list(orders[self.v])
        here[self.i], there[self.j] = there[self.j], here[self.i]
        return {self.s: here, self.v: there}


class _FlatRoutes:
    """Every unit's route points (``routes.route_points``) end to end, to price inserting a run
    of tasks at every position of every route with one numpy pass."""

    def __init__(self, problem: Problem, orders: Sequence[Sequence[int]],
                 points: Callable[[int, Sequence[int]], _Points]) -> None:
        self.problem = problem
        parts = [points(v, r) for v, r in enumerate(orders)]
        self.prev = np.concatenate([p[0] for p in parts])
        self.next = np.concatenate([p[1] for p in parts])
        speed = np.concatenate([p[2] for p in parts])
        self.has_next = np.isfinite(speed)
        self.speed = np.where(self.has_next, speed, 1.0)
        sizes = np.array([len(r) + 1 for r in orders])
        self.owner = np.repeat(np.arange(len(orders)), sizes)
        self.offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        self.old = np.where(self.has_next,
                            np.hypot(*(self.next - self.prev).T) / self.speed, 0.0)
        # Per task on a route (flat position f): its unit, its place k and the task.
        self.task_at = np.array([t for r in orders for t in r], dtype=int)
        self.k_at = np.array([k for r in orders for k in range(len(r))], dtype=int)
        self.owner_at = np.repeat(np.arange(len(orders)), sizes - 1)
        self.ordered = bool(problem.before.any())
        self.at = self.offsets[self.owner_at] + self.k_at  # the point before the task
        if self.ordered:  # the tree's order between the routes' tasks and any task
            self.preceding = problem.before[self.task_at]  # (F, T): route task before t
            self.following = problem.before[:, self.task_at].T  # (F, T): t before route task
            self.ends = np.diff(np.append(self.offsets, self.owner.size)) - 1
            self.place = np.arange(self.owner.size) - self.offsets[self.owner]

    def _in_place(self, f: np.ndarray, units: np.ndarray | int, t: np.ndarray) -> np.ndarray:
        """Travel + work time of travelling task(s) ``t`` on ``units`` put between the points
        before and after route position(s) ``f`` (broadcast)."""
        p = self.problem
        gap = self.prev[f] - p.start_at(units, t)
        into = np.hypot(gap[..., 0], gap[..., 1]) / p.speed[units, t]
        gap = self.next[f + 1] - p.end_at(units, t)
        out = np.where(self.has_next[f + 1],
                       np.hypot(gap[..., 0], gap[..., 1]) / self.speed[f + 1], 0.0)
        return np.asarray(into + p.work_time[units, t] + out)

    def swap_costs(self, s: int, rows: np.ndarray, ts: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """For each of unit ``s``'s tasks ``ts`` (at its route places ``rows``) and every task
        w on a route, (rows, F): the time ``s`` adds with w in place of that task, and w's unit
        adds with that task in place of w (travelling tasks only)."""
        f = self.at
        fi = (self.offsets[s] + rows)[:, None]
        mine = self._in_place(np.broadcast_to(fi, (rows.size, f.size)), s, self.task_at[None, :]) \
            - self._in_place(fi, s, ts[:, None])
        own = self._in_place(f, self.owner_at, self.task_at)  # each task in its own place
        theirs = self._in_place(f[None, :], self.owner_at[None, :], ts[:, None]) - own
        return mine, theirs

    def insertion(self, seg: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Per unit: the least added travel + work time of the run ``seg`` in its route
        (``routes.insertion_costs`` for a run) at a position after the tasks the tree runs
        before it and before those it runs after it (inf: none), and that position."""
        p, idx = self.problem, np.asarray(seg, dtype=int)
        extra = p.work_time[:, idx].sum(axis=1)  # (U,)
        moving = idx[p.travels[idx]]
        if moving.size == 0:
            cost = np.zeros(self.owner.size)
        else:
            first, last = int(moving[0]), int(moving[-1])
            for a, b in itertools.pairwise(moving.tolist()):
                every = np.arange(p.n_units)
                gap = p.start_at(every, b) - p.end_at(every, a)  # (U, 2): each unit's own
                extra = extra + np.hypot(gap[:, 0], gap[:, 1]) / p.speed[:, b]
            into = np.hypot(*(self.prev - p.start_at(self.owner, first)).T) \
                / p.speed[self.owner, first]
            out = np.where(self.has_next,
                           np.hypot(*(self.next - p.end_at(self.owner, last)).T) / self.speed,
                           0.0)
            cost = into + out - self.old
        if self.ordered:
            cost = np.where(self._in_order(idx), cost, np.inf)
        best = np.minimum.reduceat(cost, self.offsets)
        at = np.flatnonzero(cost == best[self.owner])
        place = np.zeros(p.n_units, dtype=int)
        # The first best position of each unit (``at`` is sorted: reverse so the first wins).
        place[self.owner[at[::-1]]] = at[::-1] - self.offsets[self.owner[at[::-1]]]
        return best + extra, place

    def _in_order(self, seg: np.ndarray) -> np.ndarray:
        """(positions,) where the run ``seg`` keeps the tree's order with the route's tasks."""
        pred = self.preceding[:, seg].any(axis=1)
        succ = self.following[:, seg].any(axis=1)
        low = np.zeros(self.offsets.size, dtype=int)
        np.maximum.at(low, self.owner_at[pred], self.k_at[pred] + 1)
        high = self.ends.copy()
        np.minimum.at(high, self.owner_at[succ], self.k_at[succ])
        place = self.place
        return np.asarray((place >= low[self.owner]) & (place <= high[self.owner]))
