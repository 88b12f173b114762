"""Sequential single-item auction.

Each round every capable unit bids, for every unassigned task, the marginal cost of inserting it at
the best place in its own route (for the chosen objective: makespan with ties broken by total time,
or total time); the lowest bid wins, ties go to the lower unit, then the lower task index.

When every task is activated at mission start and no conc child holds more than one task (a
``conc`` of tasks, the common case and the one that must scale to 200 units x 1000 tasks;
``Problem.plain``), a unit's bids depend only on its own route: bids live in a (units x tasks)
array and after each round only the winner's row is recomputed, with numpy over all candidate
positions at once. Otherwise (``seq`` orders tasks across units, or conc children are subtrees that
run one after another where they share a unit), bids are the same route insertions restricted to
positions that keep the tree's order and every subtree's tasks in one run per unit, but a task's
marginal makespan depends on the other units' timing: the auctioneer ranks the bids by an estimate
and simulates the best few exactly (see ``_general_auction``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

import numpy as np

from delegation.allocation.problem import Problem
from delegation.allocation.routes import home_legs, insertion_costs, keeps_subtrees_whole
from delegation.allocation.schedule import EPS, IssueKind, Schedule, evaluate
from delegation.allocation.serialise import Serialisation, conc_paths

log = logging.getLogger(__name__)

#: Route positions the general auction simulates for one bid before giving the bid up.
POSITION_TRIES = 3
#: Scale of "one unit's share of the work" in the general auction's estimates (see there).
SHARE_FACTOR = 2.0


def assign_passive(problem: Problem, assign: np.ndarray) -> None:
    """Give every unassigned non-vehicle task (``look-at-*``) a unit, in place.

    They neither travel nor occupy the unit, so any allowed unit will do: the alias's unit where
    one is bound, else the first allowed unit holding the fewest such tasks.
    """
    vehicle = problem.vehicle
    alias_of = problem.alias_of()
    load = np.zeros(problem.n_units, dtype=int)
    for t in range(problem.n_tasks):
        if vehicle[t] or assign[t] >= 0:
            continue
        allowed = problem.allowed[:, t].copy()
        g = alias_of[t]
        if g >= 0:
            bound = {int(assign[m]) for m in problem.alias_groups[g] if assign[m] >= 0}
            if bound:
                mask = np.zeros_like(allowed)
                mask[next(iter(bound))] = True
                allowed &= mask
        if not allowed.any():
            continue
        choices = np.nonzero(allowed)[0]
        u = int(choices[np.argmin(load[choices])])
        assign[t] = u
        load[u] += 1


def unassigned_reason(problem: Problem, t: int) -> str:
    """Why task ``t`` is left out of a plan."""
    if problem.reasons[t]:
        return str(problem.reasons[t])
    return "no capable unit has enough endurance left to add it to its route"


def auction(problem: Problem, objective: str = "makespan") -> Schedule:
    """Plan with the sequential auction; see the module docstring."""
    if problem.plain:
        assign, orders = _flat_auction(problem, objective)
    else:
        assign, orders = _general_auction(problem, objective)
    assign_passive(problem, assign)
    return evaluate(problem, assign, orders)


def _flat_auction(problem: Problem, objective: str) -> tuple[np.ndarray, list[list[int]]]:
    n_units, n_tasks = problem.n_units, problem.n_tasks
    assign = np.full(n_tasks, -1, dtype=int)
    routes: list[list[int]] = [[] for _ in range(n_units)]
    vehicle = problem.vehicle
    open_tasks = vehicle & problem.allowed.any(axis=0)
    if n_units == 0 or not open_tasks.any():
        return assign, routes
    base = home_legs(problem)
    used = np.zeros(n_units)  # travel + work incl. way home; 0 while idle (flat: also finish time)
    delta = np.full((n_units, n_tasks), np.inf)
    pos = np.zeros((n_units, n_tasks), dtype=int)
    alias_of = problem.alias_of()
    allowed = problem.allowed & open_tasks[None, :]

    def recompute(u: int) -> None:
        delta[u] = np.inf
        cand = np.nonzero(allowed[u])[0]
        if cand.size == 0:
            return
        costs = insertion_costs(problem, u, routes[u], cand)
        best = np.argmin(costs, axis=0)
        add = costs[best, np.arange(cand.size)]
        now = used[u] if routes[u] else base[u]
        ok = now + add <= problem.endurance[u] * (1 + EPS) + EPS
        delta[u, cand] = np.where(ok, add, np.inf)
        pos[u, cand] = best

    for u in range(n_units):
        recompute(u)
    makespan = 0.0
    for _ in range(int(open_tasks.sum())):
        current = np.where([bool(r) for r in routes], used, base)[:, None]
        if objective == "total":
            primary = delta
            secondary = current + delta
        else:
            primary = np.maximum(current + delta, makespan)
            secondary = delta
        best = primary.min()
        if not np.isfinite(best):
            break
        flat_index = int(np.argmin(np.where(primary <= best, secondary, np.inf)))
        u, t = divmod(flat_index, n_tasks)
        routes[u].insert(int(pos[u, t]), t)
        used[u] = (used[u] if len(routes[u]) > 1 else base[u]) + delta[u, t]
        makespan = max(makespan, used[u])
        assign[t] = u
        allowed[:, t] = False
        delta[:, t] = np.inf
        _bind_alias(problem, alias_of, allowed, delta, u, t)
        recompute(u)
    return assign, routes


def _general_auction(problem: Problem, objective: str) -> tuple[np.ndarray, list[list[int]]]:
    """Auction for trees with ``seq`` between tasks.

    A task takes part once every task that must precede it has a unit ("ready"); it may go at any
    place in a route after the tasks that start before it can be activated, which keeps routes and
    tree free of cycles (nobody waits for someone who waits for them), and that keeps the unit's
    tasks under every node of the tree in one run (``keeps_subtrees_whole``). Bids are each unit's
    added travel + work time (kept per unit and route position, recomputed only for the winner); a
    unit's marginal makespan also depends on waiting, so the auctioneer ranks bids by an estimate
    (``max(unit finish, activation) + added time``, or, where the task's subtree and the unit's
    are in different wrapped components, both components' lengths one after the other: taking
    it joins them into one seq) and simulates the best few exactly. For makespan, bids that do
    not raise the makespan are ranked by that estimate (the exact simulations then break ties by
    total time). A simulation that cannot run (units that would order two subtrees both ways
    round) moves the bid to the unit's next-best position, up to ``POSITION_TRIES`` of them.
    """
    n_units, n_tasks = problem.n_units, problem.n_tasks
    assign = np.full(n_tasks, -1, dtype=int)
    routes: list[list[int]] = [[] for _ in range(n_units)]
    vehicle = problem.vehicle
    allowed = problem.allowed & vehicle[None, :]
    alias_of = problem.alias_of()
    before = problem.before
    node_of = np.asarray(problem.structure.node_of_task, dtype=int)
    has_pred: np.ndarray = np.asarray(before.any(axis=0))
    open_task = allowed.any(axis=0)
    pending = (before & open_task[:, None]).sum(axis=0)
    base = home_legs(problem)
    costs: list[np.ndarray] = [np.zeros((1, n_tasks)) for _ in range(n_units)]
    delta = np.full((n_units, n_tasks), np.inf)
    pos = np.zeros((n_units, n_tasks), dtype=int)
    low = np.zeros((n_units, n_tasks), dtype=int)  # first position a waiting task may take
    shortlist = int(np.clip(300 // max(n_tasks, 1), 1, 8))

    def recompute(u: int) -> None:
        table = np.full((len(routes[u]) + 1, n_tasks), np.inf)
        cand = np.nonzero(allowed[u])[0]
        if cand.size:
            whole = keeps_subtrees_whole(problem, routes[u], cand)
            table[:, cand] = np.where(whole, insertion_costs(problem, u, routes[u], cand), np.inf)
        costs[u] = table
        free = ~has_pred
        pos[u, free] = np.argmin(table[:, free], axis=0)
        delta[u, free] = table[pos[u, free], np.nonzero(free)[0]]

    def close(t: int) -> None:
        """``t`` is settled (assigned or given up): its successors wait for one task less."""
        open_task[t] = False
        allowed[:, t] = False
        delta[:, t] = np.inf
        pending[before[t]] -= 1

    paths = [dict(path) for path in conc_paths(problem, every_conc=False)]

    def keeps_order(u: int, t: int, p: int, places: dict[int, tuple[int, int]]) -> bool:
        """Whether ``t`` at position ``p`` of ``u``'s route keeps the order of every wrapped
        component it joins (a sufficient test: the simulation has the last word)."""
        route = routes[u]
        a = paths[route[p - 1]] if p > 0 else {}
        b = paths[route[p]] if p < len(route) else {}
        for n, x in paths[t].items():
            left, right = a.get(n), b.get(n)
            if x in (left, right):
                continue
            kids = problem.structure.children[n]
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

    # Per conc whose children are subtrees: which child each task is under (-1: not under it),
    # a child of each unit there (all of a unit's children are in one wrapped component), and how
    # many tasks each child has on units.
    s = problem.structure
    child_at: dict[int, np.ndarray] = {}
    for t, path in enumerate(paths):
        for n, k in path.items():
            child_at.setdefault(n, np.full(n_tasks, -1, dtype=int))[t] = k
    unit_child = {n: np.full(n_units, -1, dtype=int) for n in child_at}
    child_count = {n: np.zeros(len(s.children[n]), dtype=int) for n in child_at}

    def joined_estimate(cols: np.ndarray, bid: np.ndarray, state: Schedule) -> np.ndarray:
        """(U, C) when the wrapped component that unit u and task t's subtree would share
        ends: both components' lengths one after the other, plus the bid (a unit that takes a
        task under a subtree already on other units joins their subtrees to its own)."""
        out = np.zeros_like(bid)
        if not child_at or state.node_act is None or state.node_fin is None:
            return out
        spans: list[float] = []
        comp_of_node: dict[int, int] = {}
        for w, (_, wrapped) in enumerate(state.serialised.wraps if state.serialised else []):
            spans.append(float(state.node_fin[wrapped[-1]] - state.node_act[wrapped[0]]))
            for kid in wrapped:
                comp_of_node[kid] = w
        for n, at in child_at.items():
            xs = at[cols]
            under = xs >= 0
            if not under.any():
                continue
            kids = np.asarray(s.children[n], dtype=int)
            child_comp = np.array([comp_of_node.get(int(k), -1) for k in kids], dtype=int)
            single = np.nonzero((child_count[n] > 0) & (child_comp < 0))[0]
            span = np.concatenate([
                np.asarray(spans, dtype=float),
                state.node_fin[kids[single]] - state.node_act[kids[single]],
                [0.0],
            ])
            child_comp[single] = len(spans) + np.arange(single.size)
            mine = np.where(unit_child[n] >= 0, child_comp[unit_child[n]], -1)
            theirs = np.where(under, child_comp[np.maximum(xs, 0)], -1)
            other = (mine[:, None] >= 0) & (mine[:, None] != theirs[None, :])
            length = np.where(other, span[mine][:, None], 0.0) + span[theirs][None, :]
            # Units in one component work one after another from then on: a component of k
            # units will take about k units' shares of the work.
            size = np.bincount(mine[mine >= 0], minlength=span.size + 1).astype(float)
            size[-1] = 0.0
            joined = np.where(other, size[mine][:, None], 0.0) + size[theirs][None, :]
            joined = np.maximum(joined, 1.0)
            joined += np.where(mine < 0, 1.0, 0.0)[:, None] * (theirs >= 0)[None, :]
            length = np.maximum(length, np.where(joined > 1, joined * share, 0.0))
            out = np.where(under[None, :], np.maximum(out, state.node_act[n] + length + bid), out)
        return out

    # One unit's share of the work (s), roughly: each task from its nearest capable unit.
    with np.errstate(invalid="ignore", divide="ignore"):
        start_xy = np.where(problem.travels[:, None], problem.start_xy, np.nan)
        leg = np.hypot(*(problem.unit_xy[:, None, :] - start_xy[None, :, :]).transpose(2, 0, 1))
        first = np.where(allowed, np.nan_to_num(leg / problem.speed) + problem.work_time, np.inf)
    cheapest = first.min(axis=0) if n_units else np.zeros(n_tasks)
    share = SHARE_FACTOR * float(cheapest[np.isfinite(cheapest)].sum()) / max(n_units, 1)

    for u in range(n_units):
        recompute(u)
    current = evaluate(problem, assign, routes)
    rejected = np.zeros((n_units, n_tasks), dtype=bool)
    seen_act = np.full(n_tasks, np.nan)  # activation when a waiting task's bids were made
    seen_start = np.full(n_tasks, np.nan)
    dirty = np.ones(n_units, dtype=bool)  # units whose waiting bids must all be remade
    while open_task.any():
        ready = open_task & (pending <= 0)
        act = current.node_act[node_of] if current.node_act is not None else np.zeros(n_tasks)
        waiting = ready & has_pred
        if waiting.any():
            # Tasks with predecessors go after what starts before they can be activated. Their
            # bids change only where the unit's route or start times changed, or the task's
            # activation did (or it is new).
            fresh = waiting & ~(act == seen_act)
            moved = ~(current.start == seen_start) & (assign >= 0)
            dirty[np.unique(assign[moved])] = True
            seen_act[waiting] = act[waiting]
            seen_start = current.start.copy()
            units = range(n_units) if fresh.any() else np.nonzero(dirty)[0].tolist()
            for u in units:
                cols = np.nonzero((waiting if dirty[u] else fresh) & allowed[u])[0]
                if cols.size == 0:
                    continue
                starts = current.start[routes[u]] if routes[u] else np.zeros(0)
                lo = np.searchsorted(starts, act[cols] - 1e-9, side="left")
                p = np.arange(len(routes[u]) + 1)[:, None]
                table = np.where(p >= lo[None, :], costs[u][:, cols], np.inf)
                low[u, cols] = lo
                pos[u, cols] = np.argmin(table, axis=0)
                delta[u, cols] = table[pos[u, cols], np.arange(cols.size)]
            dirty[:] = False
        # Only ready tasks bid: work on their columns.
        cols = np.nonzero(ready)[0]
        if cols.size == 0:
            break
        finish = np.where([bool(r) for r in routes], current.unit_finish, base)[:, None]
        bid = np.where(rejected[:, cols], np.inf, delta[:, cols])
        estimate = np.maximum(finish, act[None, cols]) + bid
        if objective == "makespan":  # for total it would only break ties between bids
            estimate = np.maximum(estimate, joined_estimate(cols, bid, current))
        if objective == "total":
            primary, secondary = bid, estimate
        else:
            primary = np.where(np.isfinite(bid), np.maximum(estimate, current.makespan), np.inf)
            secondary = estimate
        flat_primary = primary.ravel()
        finite = np.flatnonzero(np.isfinite(flat_primary))
        if finite.size == 0:
            for t in cols.tolist():  # nobody can take them: their successors go on without
                close(t)
            continue
        flat_secondary = secondary.ravel()
        places = _places(current.serialised)
        chosen: tuple[tuple[float, ...], int, int, int, Schedule] | None = None
        for rank, flat_index in enumerate(
            _ranked(finite, flat_primary, flat_secondary, 4 * shortlist)
        ):
            if rank >= shortlist and chosen is not None:
                break
            u, j = divmod(flat_index, cols.size)
            t = int(cols[j])
            column = np.array(costs[u][:, t], dtype=float)
            column[: int(low[u, t]) if bool(has_pred[t]) else 0] = np.inf
            tries = [int(pos[u, t])] + [
                int(q) for q in np.argsort(column, kind="stable")
                if np.isfinite(column[q]) and q != pos[u, t]
            ]
            tries = [q for q in tries if keeps_order(u, t, q, places)][:POSITION_TRIES]
            found: tuple[int, Schedule] | None = None
            for spot in tries:
                trial_routes = [list(r) for r in routes]
                trial_routes[u].insert(spot, t)
                assign[t] = u
                trial = evaluate(problem, assign, trial_routes)
                assign[t] = -1
                if trial.valid:
                    found = (spot, trial)
                    break
                if any(issue.kind is IssueKind.ENDURANCE for issue in trial.issues):
                    break  # other positions add more travel: they do not fit either
            if found is None:
                rejected[u, t] = True
                continue
            spot, trial = found
            key = (*trial.key(objective), float(u), float(t))
            if chosen is None or key < chosen[0]:
                chosen = (key, u, t, spot, trial)
        if chosen is None:
            continue
        _, u, t, spot, trial = chosen
        routes[u].insert(spot, t)
        assign[t] = u
        for n, k in paths[t].items():
            unit_child[n][u] = k
            child_count[n][k] += 1
        current = trial
        close(t)
        rejected[:] = False
        _bind_alias(problem, alias_of, allowed, delta, u, t)
        recompute(u)
        dirty[u] = True
    return assign, routes


def _bind_alias(
    problem: Problem, alias_of: np.ndarray, allowed: np.ndarray, delta: np.ndarray, u: int, t: int
) -> None:
    """Task ``t`` went to unit ``u``: the rest of its alias group may go to ``u`` only."""
    g = alias_of[t]
    if g < 0:
        return
    members = problem.alias_groups[g]
    others = np.ones(problem.n_units, dtype=bool)
    others[u] = False
    allowed[np.ix_(others, members)] = False
    delta[np.ix_(others, members)] = np.inf


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
