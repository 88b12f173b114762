"""The auction for trees with ``seq`` between tasks or conc children that are subtrees.

A task takes part once every task that must precede it has a unit ("ready"); it may go at any place
in a route after the tasks that start before it can be activated, which keeps routes and tree free
of cycles (nobody waits for someone who waits for them), and that keeps the unit's tasks under
every node of the tree in one run (``keeps_subtrees_whole``). Bids are each unit's added travel +
work time (kept per unit and route position, recomputed only for the winner); a unit's marginal
makespan also depends on waiting, so the auctioneer ranks bids by an estimate (``max(unit finish,
activation) + added time``, or, where the task's subtree and the unit's are in different wrapped
components, both components' lengths one after the other: taking it joins them into one seq) and
simulates the best few exactly. For makespan, bids that do not raise the makespan are ranked by that
estimate (the exact simulations then break ties by total time). A simulation that cannot run (units
that would order two subtrees both ways round) moves the bid to the unit's next-best position, up
to ``POSITION_TRIES`` of them.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import numpy as np

from delegation.allocation.auction.flat import bind_alias
from delegation.allocation.auction.stacked import StackedTables
from delegation.allocation.problem import Problem
from delegation.allocation.routes import (
    first_insertion_costs,
    home_legs,
    whole_insertion_costs,
)
from delegation.allocation.schedule import IssueKind, Schedule, evaluate
from delegation.allocation.serialise import Serialisation, conc_paths
from delegation.allocation.strategies import Objective

#: Route positions the general auction simulates for one bid before giving the bid up.
POSITION_TRIES = 3
#: Scale of "one unit's share of the work" in the general auction's estimates (see there).
SHARE_FACTOR = 2.0

#: A bid the auctioneer simulated: (sort key, unit, task, route position, the simulation).
_Chosen = tuple[tuple[float, ...], int, int, int, Schedule]


def general_auction(
    problem: Problem, objective: Objective
) -> tuple[np.ndarray, list[list[int]]]:
    """Assignment and per-unit routes of the vehicle tasks; see the module docstring."""
    return _GeneralAuction(problem, objective).run()


class _GeneralAuction:
    """The auction's state: bids per (unit, task), the routes so far and their simulation."""

    def __init__(self, problem: Problem, objective: Objective) -> None:
        n_units, n_tasks = problem.n_units, problem.n_tasks
        self.problem, self.objective = problem, objective
        self.n_units, self.n_tasks = n_units, n_tasks
        self.assign = np.full(n_tasks, -1, dtype=int)
        self.routes: list[list[int]] = [[] for _ in range(n_units)]
        self.has_route = np.zeros(n_units, dtype=bool)
        self.allowed = problem.allowed & problem.vehicle[None, :]
        self.alias_of = problem.alias_of()
        self.before = problem.before
        self.node_of = np.asarray(problem.structure.node_of_task, dtype=int)
        self.has_pred: np.ndarray = np.asarray(self.before.any(axis=0))
        self.free = ~self.has_pred
        self.open_task = self.allowed.any(axis=0)
        self.pending = (self.before & self.open_task[:, None]).sum(axis=0)  # unsettled preds
        self.base = home_legs(problem)
        self.ready = problem.ready.tolist() if problem.ready is not None else [0.0] * n_units
        # Per unit: added time per (route position, task); the best position and its cost.
        self.costs: list[np.ndarray] = [np.zeros((1, n_tasks)) for _ in range(n_units)]
        self.suffix_min: list[np.ndarray] = [np.zeros((1, n_tasks)) for _ in range(n_units)]
        self.suffix_arg: list[np.ndarray] = [np.zeros((1, n_tasks), dtype=int)
                                             for _ in range(n_units)]
        self.stacked = StackedTables(n_units, n_tasks) \
            if StackedTables.fits(n_units, n_tasks) else None
        self.delta = np.full((n_units, n_tasks), np.inf)
        self.pos = np.zeros((n_units, n_tasks), dtype=int)
        self.low = np.zeros((n_units, n_tasks), dtype=int)  # first position a waiting task may take
        self.shortlist = int(np.clip(300 // max(n_tasks, 1), 1, 8))
        self.paths = [dict(path) for path in conc_paths(problem, every_conc=False)]
        # Per conc whose children are subtrees: which child each task is under (-1: not under
        # it), a child of each unit there (all of a unit's children are in one wrapped
        # component), and how many tasks each child has on units.
        self.child_at: dict[int, np.ndarray] = {}
        for t, path in enumerate(self.paths):
            for n, k in path.items():
                self.child_at.setdefault(n, np.full(n_tasks, -1, dtype=int))[t] = k
        s = problem.structure
        self.unit_child = {n: np.full(n_units, -1, dtype=int) for n in self.child_at}
        self.kids = {n: np.asarray(s.children[n], dtype=int) for n in self.child_at}
        self.child_count = {n: np.zeros(len(s.children[n]), dtype=int) for n in self.child_at}
        self.share = self._share()
        self.rejected = np.zeros((n_units, n_tasks), dtype=bool)  # simulated and failed
        self.seen_act = np.full(n_tasks, np.nan)  # activation when a waiting task's bids were made
        self.seen_start = np.full(n_tasks, np.nan)
        self.dirty = np.ones(n_units, dtype=bool)  # units whose waiting bids must all be remade
        self.current = evaluate(problem, self.assign, self.routes)
        self.node_of_list: list[int] = self.node_of.tolist()
        self._times_of: Schedule | None = None
        self._times_lists: tuple[list[float], list[float], list[float] | None, list[float]] = \
            ([], [], None, [])

    def _share(self) -> float:
        """One unit's share of the work (s), roughly: each task from its nearest capable unit."""
        problem = self.problem
        with np.errstate(invalid="ignore", divide="ignore"):
            start_xy = np.where(problem.travels[None, :, None], problem.unit_points()[0], np.nan)
            leg = np.hypot(
                *(problem.unit_xy[:, None, :] - start_xy).transpose(2, 0, 1)
            )
            first = np.where(
                self.allowed, np.nan_to_num(leg / problem.speed) + problem.work_time, np.inf
            )
        cheapest = first.min(axis=0) if self.n_units else np.zeros(self.n_tasks)
        return SHARE_FACTOR * float(cheapest[np.isfinite(cheapest)].sum()) / max(self.n_units, 1)

    def run(self) -> tuple[np.ndarray, list[list[int]]]:
        """Rounds until every task is settled: the ready tasks bid, the best simulated bid wins."""
        if not self._first_tables():
            for u in range(self.n_units):
                self.recompute(u)
        while self.open_task.any():
            ready = self.open_task & (self.pending <= 0)
            current = self.current
            act = current.node_act[self.node_of] if current.node_act is not None \
                else np.zeros(self.n_tasks)
            waiting = ready & self.has_pred
            if waiting.any():
                self._rebid_waiting(waiting, act)
            # Only ready tasks bid: work on their columns.
            cols = np.nonzero(ready)[0]
            if cols.size == 0:
                break
            primary, secondary = self._ranking(cols, act)
            finite = np.flatnonzero(np.isfinite(primary))
            if finite.size == 0:
                for t in cols.tolist():  # nobody can take them: their successors go on without
                    self.close(t)
                continue
            chosen = self._choose(cols, finite, primary, secondary)
            if chosen is not None:
                self._award(chosen)
        return self.assign, self.routes

    # ----------------------------------------------------------------------- bids

    def recompute(self, u: int) -> None:
        """Unit ``u``'s added time for every task at every position of its route, and its
        suffix minima (the cheapest position from p on, for the waiting tasks' bids); the best
        position of the tasks without predecessors."""
        table = np.full((len(self.routes[u]) + 1, self.n_tasks), np.inf)
        cand = np.nonzero(self.allowed[u])[0]
        if cand.size:
            table[:, cand] = whole_insertion_costs(self.problem, u, self.routes[u], cand)
        self.costs[u] = table
        low, arg = _suffix_minima(table)
        self._set_tables(u, low, arg)
        free = self.free
        self.pos[u, free] = arg[0, free]
        self.delta[u, free] = low[0, free]

    def _first_tables(self) -> bool:
        """``recompute`` for every unit at once while routes are empty
        (``routes.first_insertion_costs``); False where task points depend on the unit
        (``go-home``): then unit by unit."""
        cost = first_insertion_costs(self.problem)
        if cost is None:
            return False
        table = np.where(self.allowed, cost, np.inf)
        first = np.zeros((1, self.n_tasks), dtype=int)
        for u in range(self.n_units):
            self.costs[u] = table[u][None, :]
            self._set_tables(u, self.costs[u], first)
        self.pos[:, self.free] = 0
        self.delta[:, self.free] = table[:, self.free]
        return True

    def _set_tables(self, u: int, low: np.ndarray, arg: np.ndarray) -> None:
        self.suffix_min[u], self.suffix_arg[u] = low, arg
        if self.stacked is not None and not self.stacked.set(u, low, arg):
            self.stacked = None  # too big to keep stacked: unit by unit from now on

    def _rebid_waiting(self, waiting: np.ndarray, act: np.ndarray) -> None:
        """Tasks with predecessors go after what starts before they can be activated. Their
        bids change only where the unit's route or start times changed, or the task's
        activation did (or it is new)."""
        current, assign, dirty = self.current, self.assign, self.dirty
        fresh = waiting & ~(act == self.seen_act)
        moved = ~(current.start == self.seen_start) & (assign >= 0)
        dirty[assign[moved]] = True
        self.seen_act[waiting] = act[waiting]
        self.seen_start = current.start.copy()
        earliest = act - 1e-9
        if self.stacked is not None:
            # Dirty units rebid every waiting task, the others the fresh ones.
            us, cs = np.nonzero(np.where(dirty[:, None], waiting, fresh) & self.allowed)
            if us.size:
                lo, best, arg = self.stacked.lookup(us, cs, earliest, current.start)
                self.low[us, cs] = lo
                self.pos[us, cs] = np.where(best < np.inf, arg, 0)
                self.delta[us, cs] = best
            dirty[:] = False
            return
        units = range(self.n_units) if fresh.any() else np.flatnonzero(dirty).tolist()
        for u in units:
            cols = np.flatnonzero((waiting if dirty[u] else fresh) & self.allowed[u])
            if cols.size == 0:
                continue
            route = self.routes[u]
            lo = np.searchsorted(current.start[route], earliest[cols], side="left") if route \
                else np.zeros(cols.size, dtype=int)
            best = self.suffix_min[u][lo, cols]
            self.low[u, cols] = lo
            # (np.argmin's answer where no position is left: the first)
            self.pos[u, cols] = np.where(best < np.inf, self.suffix_arg[u][lo, cols], 0)
            self.delta[u, cols] = best
        dirty[:] = False

    def _ranking(self, cols: np.ndarray, act: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The bids of the ready tasks ``cols``, flattened (unit, column): the primary and the
        secondary ranking key (inf: no bid)."""
        current = self.current
        finish = np.where(self.has_route, current.unit_finish, self.base)[:, None]
        bid = np.where(self.rejected[:, cols], np.inf, self.delta[:, cols])
        estimate = np.maximum(finish, act[None, cols]) + bid
        match self.objective:
            case Objective.MAKESPAN:
                # (for total the joined estimate would only break ties between bids)
                estimate = np.maximum(estimate, self.joined_estimate(cols, bid, current))
                primary = np.where(
                    np.isfinite(bid), np.maximum(estimate, current.makespan), np.inf
                )
                secondary = estimate
            case Objective.TOTAL:
                primary, secondary = bid, estimate
        return primary.ravel(), secondary.ravel()

    def joined_estimate(self, cols: np.ndarray, bid: np.ndarray, state: Schedule) -> np.ndarray:
        """(U, C) when the wrapped component that unit u and task t's subtree would share
        ends: both components' lengths one after the other, plus the bid (a unit that takes a
        task under a subtree already on other units joins their subtrees to its own)."""
        out = np.zeros_like(bid)
        if not self.child_at or state.node_act is None or state.node_fin is None:
            return out
        spans: list[float] = []
        comp_of_node: dict[int, int] = {}
        for w, (_, wrapped) in enumerate(state.serialised.wraps if state.serialised else []):
            spans.append(float(state.node_fin[wrapped[-1]] - state.node_act[wrapped[0]]))
            for kid in wrapped:
                comp_of_node[kid] = w
        for n, at in self.child_at.items():
            xs = at[cols]
            under = xs >= 0
            if not under.any():
                continue
            length = self._joined_length(n, xs, under, spans, comp_of_node, state)
            out = np.where(under[None, :], np.maximum(out, state.node_act[n] + length + bid), out)
        return out

    def _joined_length(
        self, n: int, xs: np.ndarray, under: np.ndarray, spans: list[float],
        comp_of_node: dict[int, int], state: Schedule,
    ) -> np.ndarray:
        """(U, C) under conc ``n``: the length of the component unit u and the child ``xs``
        of task column c would share."""
        assert state.node_act is not None and state.node_fin is not None
        kids = self.kids[n]
        child_comp = np.array([comp_of_node.get(k, -1) for k in kids.tolist()], dtype=int) \
            if comp_of_node else np.full(kids.size, -1, dtype=int)
        single = np.nonzero((self.child_count[n] > 0) & (child_comp < 0))[0]
        span = np.concatenate([
            np.asarray(spans, dtype=float),
            state.node_fin[kids[single]] - state.node_act[kids[single]],
            [0.0],
        ])
        child_comp[single] = len(spans) + np.arange(single.size)
        unit_child = self.unit_child[n]
        mine = np.where(unit_child >= 0, child_comp[unit_child], -1)
        theirs = np.where(under, child_comp[np.maximum(xs, 0)], -1)
        other = (mine[:, None] >= 0) & (mine[:, None] != theirs[None, :])
        length = np.where(other, span[mine][:, None], 0.0) + span[theirs][None, :]
        # Units in one component work one after another from then on: a component of k
        # units will take about k units' shares of the work.
        size = np.bincount(mine[mine >= 0], minlength=span.size + 1).astype(float)
        size[-1] = 0.0
        joined = np.where(other, size[mine][:, None], 0.0) + size[theirs][None, :]
        joined = np.maximum(joined, 1.0)
        joined += (mine < 0)[:, None] & (theirs >= 0)[None, :]
        result: np.ndarray = np.maximum(length, np.where(joined > 1, joined * self.share, 0.0))
        return result

    # ----------------------------------------------------------------------- the award

    def _choose(
        self, cols: np.ndarray, finite: np.ndarray, primary: np.ndarray, secondary: np.ndarray
    ) -> _Chosen | None:
        """Simulate the best-ranked bids (a shortlist) and keep the best schedule.

        The shortlist is simulated cheapest lower bound first, and a bid whose lower bound on
        the objective is already worse than the best simulation is not simulated: the winner is
        the same as simulating them all (keys are unique: they end in unit and task). With the
        unit's finish as the bound (``_finish_bound``) that is about one simulation per round
        (measured on 10 x 20 mixed trees: 21 per mission instead of 67). Past the shortlist,
        bids are simulated in rank order until one runs.
        """
        places = _places(self.current.serialised)
        ranked = _ranked(finite, primary, secondary, 4 * self.shortlist)
        shortlist = [divmod(int(i), int(cols.size))
                     for i in itertools.islice(ranked, self.shortlist)]
        bounds = self._bounds(shortlist, cols)
        chosen: _Chosen | None = None
        for k in np.argsort(bounds, kind="stable").tolist():
            if chosen is not None and bounds[k] > _slack(chosen[0][1]):
                break  # sorted: no later bid can win either
            u, j = shortlist[k]
            chosen = self._try_bid(chosen, u, j, cols, places)
        for flat_index in ranked:
            if chosen is not None:
                break
            u, j = divmod(int(flat_index), int(cols.size))
            chosen = self._try_bid(chosen, u, j, cols, places)
        return chosen

    def _bounds(self, bids: list[tuple[int, int]], cols: np.ndarray) -> np.ndarray:
        """A lower bound on the objective after each bid (unit, column): the unit's finish
        (``_finish_bound``) for makespan, the total time with the task at its cheapest position
        for total."""
        if not bids:
            return np.zeros(0)
        match self.objective:
            case Objective.MAKESPAN:
                times = self._times()
                return np.array([self._finish_bound(u, int(cols[j]), times) for u, j in bids])
            case Objective.TOTAL:
                ts = cols[np.array([j for _, j in bids], dtype=int)]
                us = np.array([u for u, _ in bids], dtype=int)
                return np.asarray(self.current.total_time + self.delta[us, ts])

    def _times(self) -> tuple[list[float], list[float], list[float] | None, list[float]]:
        """The current schedule's task ends, travel + work per task, node activations and
        units' use as lists (``_finish_bound`` reads them element by element, several bids a
        round: numpy scalars cost more), made once per schedule."""
        current = self.current
        if self._times_of is not current:
            self._times_of = current
            self._times_lists = (
                current.end.tolist(), (current.travel_time + current.work_time).tolist(),
                current.node_act.tolist() if current.node_act is not None else None,
                current.unit_used.tolist())
        return self._times_lists

    def _finish_bound(
        self, u: int, t: int,
        times: tuple[list[float], list[float], list[float] | None, list[float]],
    ) -> float:
        """A lower bound on when unit ``u`` finishes with ``t`` at any position it may take.

        Nothing before the position moves (those tasks wait for nothing ``t`` waits for: its
        tree successors have no unit yet), so ``t`` starts no earlier than its activation and
        the end of the task before it; then the unit does ``t`` and the rest of its route one
        after another: their travel and work, ``costs`` more than they took before.
        ``times``: ``_times()``.
        """
        route = self.routes[u]
        end, busy, node_act, used = times
        column = self.costs[u][:, t].tolist()
        low = int(self.low[u, t]) if self.has_pred[t] else 0
        act = node_act[self.node_of_list[t]] if node_act is not None else 0.0
        before = self.ready[u]
        rest = used[u] if route else float(self.base[u])
        best = np.inf
        for q, added in enumerate(column):
            if q > 0:
                k = route[q - 1]
                before = end[k]
                rest -= busy[k]
            if q >= low and added < np.inf:
                best = min(best, max(act, before) + added + rest)
        return best

    def _try_bid(
        self, chosen: _Chosen | None, u: int, j: int, cols: np.ndarray,
        places: dict[int, tuple[int, int]],
    ) -> _Chosen | None:
        """Simulate unit ``u``'s bid for column ``j``; the better of it and ``chosen``."""
        t = int(cols[j])
        found = self._simulate_bid(u, t, places)
        if found is None:
            self.rejected[u, t] = True
            return chosen
        spot, trial = found
        key = (*trial.key(self.objective), float(u), float(t))
        if chosen is None or key < chosen[0]:
            return (key, u, t, spot, trial)
        return chosen

    def _simulate_bid(
        self, u: int, t: int, places: dict[int, tuple[int, int]]
    ) -> tuple[int, Schedule] | None:
        """The first of the unit's best positions for ``t`` whose simulation runs, and that."""
        for spot in itertools.islice(self._positions(u, t, places), POSITION_TRIES):
            trial_routes = [list(r) for r in self.routes]
            trial_routes[u].insert(spot, t)
            self.assign[t] = u
            trial = evaluate(self.problem, self.assign, trial_routes)
            self.assign[t] = -1
            if trial.valid:
                return spot, trial
            if any(issue.kind is IssueKind.ENDURANCE for issue in trial.issues):
                break  # other positions add more travel: they do not fit either
        return None

    def _positions(self, u: int, t: int, places: dict[int, tuple[int, int]]) -> Iterator[int]:
        """Unit ``u``'s positions for ``t`` that keep the tree's order, best first (the rest
        are only sorted when the best one fails: it rarely does)."""
        best = int(self.pos[u, t])
        if self.keeps_order(u, t, best, places):
            yield best
        column = np.array(self.costs[u][:, t], dtype=float)
        column[: int(self.low[u, t]) if bool(self.has_pred[t]) else 0] = np.inf
        for q in np.argsort(column, kind="stable").tolist():
            if np.isfinite(column[q]) and q != best and self.keeps_order(u, t, q, places):
                yield q

    def keeps_order(self, u: int, t: int, p: int, places: dict[int, tuple[int, int]]) -> bool:
        """Whether ``t`` at position ``p`` of ``u``'s route keeps the order of every wrapped
        component it joins (a sufficient test: the simulation has the last word)."""
        route, paths = self.routes[u], self.paths
        a = paths[route[p - 1]] if p > 0 else {}
        b = paths[route[p]] if p < len(route) else {}
        for n, x in paths[t].items():
            left, right = a.get(n), b.get(n)
            if x in (left, right):
                continue
            kids = self.problem.structure.children[n]
            near = left if left is not None else right
            mine = places.get(kids[near]) if near is not None else None
            ours = places.get(kids[x])
            if mine is None or ours is None or mine[0] != ours[0]:
                continue  # joins another component (or none): no way round
            if left is not None and places[kids[left]][1] > ours[1]:
                return False
            if right is not None and places[kids[right]][1] < ours[1]:
                return False
        return True

    def _award(self, chosen: _Chosen) -> None:
        """The winning bid: the task joins the unit's route; the bids change."""
        _, u, t, spot, trial = chosen
        self.routes[u].insert(spot, t)
        if self.stacked is not None:
            self.stacked.insert(u, spot, t)
        self.has_route[u] = True
        self.assign[t] = u
        for n, k in self.paths[t].items():
            self.unit_child[n][u] = k
            self.child_count[n][k] += 1
        self.current = trial
        self.close(t)
        self.rejected[:] = False
        bind_alias(self.problem, self.alias_of, self.allowed, self.delta, u, t)
        self.recompute(u)
        self.dirty[u] = True

    def close(self, t: int) -> None:
        """``t`` is settled (assigned or given up): its successors wait for one task less."""
        self.open_task[t] = False
        self.allowed[:, t] = False
        self.delta[:, t] = np.inf
        self.pending[self.before[t]] -= 1


def _suffix_minima(table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row p of ``table`` (positions x tasks): the minimum over rows p.. and the first row
    holding it (``np.argmin`` of the rows from p on, offset by p)."""
    low = np.minimum.accumulate(table[::-1], axis=0)[::-1]
    # Row p holds its suffix's minimum when it is no more than the minimum from p + 1 on (the
    # last row always); the answer for p is the first such row from p on: a reversed running
    # minimum of those rows' indices (one pass, not a numpy call per row).
    rows = np.arange(table.shape[0])[:, None]
    holds = np.ones(table.shape, dtype=bool)
    holds[:-1] = table[:-1] <= low[1:]
    marked = np.where(holds, rows, table.shape[0])
    arg = np.minimum.accumulate(marked[::-1], axis=0)[::-1]
    return low, np.ascontiguousarray(arg)


def _slack(value: float) -> float:
    """``value`` plus float noise: bounds above it are surely worse."""
    return value + 1e-7 * max(1.0, abs(value))


def _places(serialised: Serialisation | None) -> dict[int, tuple[int, int]]:
    """Tree node of each wrapped child -> (its wrapper, its place in the wrapper)."""
    out: dict[int, tuple[int, int]] = {}
    for w, (_, kids) in enumerate(serialised.wraps if serialised is not None else []):
        for i, child in enumerate(kids):
            out[child] = (w, i)
    return out


def _ranked(
    index: np.ndarray, primary: np.ndarray, secondary: np.ndarray, k: int
) -> Iterator[int]:
    """``index`` by (primary, secondary, index), sorting only as far as the caller reads."""
    done = np.zeros(0, dtype=index.dtype)
    while True:
        pool = _smallest(index, primary, secondary, k)
        if done.size:
            pool = pool[~np.isin(pool, done)]
        order = np.lexsort((pool, secondary[pool], primary[pool]))
        yield from pool[order].tolist()
        if k >= index.size:
            return
        done = np.concatenate([done, pool])
        k *= 8


def _smallest(index: np.ndarray, primary: np.ndarray, secondary: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` entries of ``index`` smallest by (primary, secondary), in no particular order."""
    if index.size <= k:
        return index
    values = primary[index]
    kth = np.partition(values, k - 1)[k - 1]
    below = index[values < kth]
    ties = index[values == kth]
    need = k - below.size
    if ties.size > need:
        ties = ties[np.argpartition(secondary[ties], need - 1)[:need]]
    return np.concatenate([below, ties])
