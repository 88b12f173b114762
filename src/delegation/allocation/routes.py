"""Vectorised insertion costs into one unit's route (shared by the auction and the optimiser).

A route is the ordered list of a unit's vehicle tasks. Inserting task ``t`` at position ``p`` adds
the travel from where the unit is before ``p`` to ``t``'s start, ``t``'s work, and the travel from
``t``'s end to whatever comes next (the next travelling task, the way home, or nothing), minus the
travel it replaces. Tasks done in place (``travels`` False) leave the unit where it was.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

from delegation.allocation.problem import Problem
from delegation.allocation.schedule import static_for

#: Most positions x candidates an insertion table is priced for in plain Python: below it
#: numpy's ~20 calls cost more than the arithmetic (measured on the general auction's tables:
#: Python ~13 us + 0.5 us an entry, numpy ~55 us at any size up to 100 entries; the 10 x
#: 20 mixed trees' tables are mostly below it); above it numpy (1,000-task trees).
SMALL_TABLE = 64


def route_points(
    problem: Problem, u: int, route: Sequence[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For positions 0..L: where the unit is before p, where it goes next, and at what speed.

    Returns ``prev_xy`` (L+1,2), ``next_xy`` (L+1,2) and ``next_speed`` (L+1,); ``next_speed`` is
    inf where nothing follows (open route), so the travel to "next" costs nothing there.
    """
    prev, nxt, speeds = _route_lists(problem, u, route)
    n = len(route)
    prev_xy = np.array(prev, dtype=float).reshape(n + 1, 2)
    next_xy = np.array(nxt, dtype=float).reshape(n + 1, 2)
    next_speed = np.array(speeds, dtype=float).reshape(n + 1)
    return prev_xy, next_xy, next_speed


def _route_lists(
    problem: Problem, u: int, route: Sequence[int]
) -> tuple[list[list[float]], list[list[float]], list[float]]:
    """`route_points` as lists: plain Python over the route (a few to a few dozen tasks), one
    conversion at the end where arrays are wanted (numpy's per-row assignments cost more than
    the arithmetic)."""
    n = len(route)
    static = static_for(problem)
    if True in static.to_home:  # (go-home: its points are the unit's home, ``points_for``)
        start, end, travels = problem.points_for(u, np.asarray(route, dtype=int))
        start_l, end_l, travels_l = start.tolist(), end.tolist(), travels.tolist()
    else:  # the problem's lists, as the simulation reads them: no numpy call per route
        sx, sy, ex, ey = static.sx[u], static.sy[u], static.ex[u], static.ey[u]
        start_l = [[sx[t], sy[t]] for t in route]
        end_l = [[ex[t], ey[t]] for t in route]
        travels_l = [static.travels[t] for t in route]
    prev: list[list[float]] = [[static.ux[u], static.uy[u]]]
    for k in range(n):
        prev.append(end_l[k] if travels_l[k] else prev[k])
    here, speed = ([0.0, 0.0], math.inf)
    if static.has_home[u]:
        here, speed = [static.home_x[u], static.home_y[u]], static.home_speed[u]
    nxt: list[list[float]] = [here] * (n + 1)
    speeds = [speed] * (n + 1)
    unit_speed = static.speed[u]
    for k in range(n - 1, -1, -1):
        if travels_l[k]:
            here, speed = start_l[k], unit_speed[route[k]]
        nxt[k], speeds[k] = here, speed
    return prev, nxt, speeds


def xy_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,M) distances between rows of a (N,2) and b (M,2); NaN rows give NaN.

    ``geo.pairwise_xy_distances`` gives the same (to 1e-13 m) but via ``hypot`` over an (N,M,2)
    difference, 3-4x slower: too slow for the auction's per-round insertion costs.
    """
    dx = a[:, 0][:, None] - b[:, 0][None, :]
    dy = a[:, 1][:, None] - b[:, 1][None, :]
    return np.asarray(np.sqrt(dx * dx + dy * dy))


def insertion_costs(
    problem: Problem, u: int, route: Sequence[int], cand: np.ndarray
) -> np.ndarray:
    """(L+1, C) added travel + work time of inserting each candidate task at each position."""
    cand = np.asarray(cand, dtype=int)
    if (len(route) + 1) * cand.size <= SMALL_TABLE:
        rows = _insertion_rows(problem, u, route, cand)
        if rows is not None:
            return np.array(rows, dtype=float).reshape(len(route) + 1, cand.size)
    prev_xy, next_xy, next_speed = route_points(problem, u, route)
    speed = problem.speed[u, cand]
    work = problem.work_time[u, cand]
    start, end, travels = problem.points_for(u, cand)
    has_next = np.isfinite(next_speed)
    safe_speed = np.where(has_next, next_speed, 1.0)
    into = xy_distances(prev_xy, start) / speed[None, :]
    out = np.where(has_next[:, None], xy_distances(next_xy, end) / safe_speed[:, None], 0.0)
    old = np.where(has_next, np.hypot(*(next_xy - prev_xy).T) / safe_speed, 0.0)
    cost = into + out - old[:, None]
    cost = np.where(travels[None, :], cost, 0.0) + work[None, :]
    return np.asarray(cost)


def whole_insertion_costs(
    problem: Problem, u: int, route: Sequence[int], cand: np.ndarray
) -> np.ndarray:
    """(L+1, C) ``insertion_costs`` where ``keeps_subtrees_whole`` allows the position, else
    inf: the general auction's table of a unit (one pass in plain Python when small)."""
    cand = np.asarray(cand, dtype=int)
    if (len(route) + 1) * cand.size <= SMALL_TABLE:
        whole = _whole_rows(problem, route, cand.tolist())
        rows = _insertion_rows(problem, u, route, cand) if whole is not None else None
        if rows is not None and whole is not None:
            inf = math.inf
            return np.array(
                [[c if w else inf for c, w in zip(row, ok, strict=True)]
                 for row, ok in zip(rows, whole, strict=True)], dtype=float,
            ).reshape(len(route) + 1, cand.size)
    return np.where(keeps_subtrees_whole(problem, route, cand),
                    insertion_costs(problem, u, route, cand), np.inf)


def _insertion_rows(
    problem: Problem, u: int, route: Sequence[int], cand: np.ndarray
) -> list[list[float]] | None:
    """``insertion_costs`` in plain Python from the problem's lists (``schedule.static_for``):
    the same operations on the same floats, element by element (IEEE arithmetic and ``sqrt``
    round the same; the leg replaced is numpy's ``hypot`` as before). None where that would
    differ or cost more: ``go-home`` tasks (their points are the unit's home) or a speed of 0
    (numpy's inf, Python's ZeroDivisionError)."""
    static = static_for(problem)
    if True in static.to_home:
        return None
    speed_u, work_u, travels = static.speed[u], static.work_time[u], static.travels
    sx, sy, ex, ey = static.sx[u], static.sy[u], static.ex[u], static.ey[u]
    # Where the unit is before each position, where it goes next and how fast.
    prev, nxt, ns = _route_lists(problem, u, route)
    px, py = [p[0] for p in prev], [p[1] for p in prev]
    nx, ny = [q[0] for q in nxt], [q[1] for q in nxt]
    cols = cand.tolist()
    if 0.0 in ns or any(speed_u[t] == 0.0 for t in cols):
        return None
    olds = np.hypot([b - a for a, b in zip(px, nx, strict=True)],
                    [b - a for a, b in zip(py, ny, strict=True)]).tolist()
    rows: list[list[float]] = []
    for x, y, x2, y2, s, hyp in zip(px, py, nx, ny, ns, olds, strict=True):
        has_next = math.isfinite(s)
        old = hyp / s if has_next else 0.0
        row: list[float] = []
        for t in cols:
            if not travels[t]:
                row.append(0.0 + work_u[t])
                continue
            dx, dy = x - sx[t], y - sy[t]
            into = math.sqrt(dx * dx + dy * dy) / speed_u[t]
            if has_next:
                dx, dy = x2 - ex[t], y2 - ey[t]
                out = math.sqrt(dx * dx + dy * dy) / s
            else:
                out = 0.0
            row.append(into + out - old + work_u[t])
        rows.append(row)
    return rows


def first_insertion_costs(problem: Problem) -> np.ndarray | None:
    """(U, T) ``insertion_costs`` of every task into every unit's empty route, for all units at
    once (the same arithmetic, over units x tasks, each unit's own search ends): the auctions'
    first bids. None with ``go-home`` (its points are the unit's home) or no units: then unit
    by unit."""
    if not problem.n_units or (problem.to_home is not None and bool(problem.to_home.any())):
        return None
    start, end = problem.unit_points()  # (U, T, 2): searches start where each unit's sweep does
    travels = problem.travels
    prev = problem.unit_xy
    # The way home comes next, at home speed (else nothing), as ``route_points`` says.
    has_next = problem.has_home & np.isfinite(problem.home_speed)
    after = np.where(problem.has_home[:, None], problem.home_xy, 0.0)
    speed = np.where(has_next, problem.home_speed, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        dx, dy = prev[:, 0][:, None] - start[..., 0], prev[:, 1][:, None] - start[..., 1]
        into = np.sqrt(dx * dx + dy * dy) / problem.speed
        dx, dy = after[:, 0][:, None] - end[..., 0], after[:, 1][:, None] - end[..., 1]
        out = np.where(has_next[:, None], np.sqrt(dx * dx + dy * dy) / speed[:, None], 0.0)
        old = np.where(has_next, np.hypot(after[:, 0] - prev[:, 0], after[:, 1] - prev[:, 1])
                       / speed, 0.0)
        cost = into + out - old[:, None]
        return np.asarray(np.where(travels[None, :], cost, 0.0) + problem.work_time)


def home_legs(problem: Problem) -> np.ndarray:
    """(U,) seconds from each unit to its home (0 without one): a route's cost before any task."""
    legs = np.zeros(problem.n_units)
    h = problem.has_home
    legs[h] = np.hypot(*(problem.home_xy[h] - problem.unit_xy[h]).T) / problem.home_speed[h]
    return legs


def keeps_subtrees_whole(problem: Problem, route: Sequence[int], cand: np.ndarray) -> np.ndarray:
    """(L+1, C): may candidate task ``cand[c]`` go at position ``p`` of ``route``?

    A unit's tasks under any node of the tree must stay one run in its route: where a conc's
    children share a unit they run one after another as whole subtrees (``serialise``), and a
    seq runs its children in order. So ``t`` may go between ``a`` and ``b`` only if every node
    holding both also holds ``t``, and next to the unit's other tasks in the deepest node that
    holds ``t`` and any of them.
    """
    cand = np.asarray(cand, dtype=int)
    n = len(route)
    if n == 0:
        return np.ones((1, cand.size), dtype=bool)
    r = np.asarray(route, dtype=int)
    d = problem.lca_depth(cand[:, None], r[None, :])  # (C, L)
    deepest = d.max(axis=1)
    # (C, L+1): the deeper LCA with the task before position p and the one after it
    near = np.full((cand.size, n + 1), -1, dtype=d.dtype)
    near[:, :n] = d
    near[:, 1:] = np.maximum(near[:, 1:], d)
    pair = np.full(n + 1, -1)
    if n > 1:
        pair[1:n] = problem.lca_depth(r[:-1], r[1:])
    ok = (near == deepest[:, None]) & (pair[None, :] <= near)
    return np.asarray(ok.T)


def _whole_rows(problem: Problem, route: Sequence[int], cand: list[int]) -> list[list[bool]] | None:
    """``keeps_subtrees_whole`` in plain Python, (L+1) rows of C (None without the LCA table:
    large trees)."""
    lca = problem.lca_rows()
    if lca is None:
        return None
    n = len(route)
    if n == 0:
        return [[True] * len(cand)]
    pair = [-1] + [lca[a][b] for a, b in itertools.pairwise(route)] + [-1]
    depths = [[lca[t][r] for r in route] for t in cand]
    deepest = [max(d) for d in depths]
    rows: list[list[bool]] = []
    for p in range(n + 1):
        row: list[bool] = []
        for d, top in zip(depths, deepest, strict=True):
            near = d[0] if p == 0 else d[p - 1] if p == n else max(d[p], d[p - 1])
            row.append(near == top and pair[p] <= near)
        rows.append(row)
    return rows
