"""Schedule evaluation: given who does what in which order, when does everything happen.

The one place that turns (assignment, per-unit order) into times, so that every strategy, the
invariants and the tests agree (DESIGN 3.6): a task is executed when the tree activates it (seq:
after its predecessor ended; conc: with its siblings) and its unit is free; travel starts then, from
where the unit is at that time. Non-vehicle tasks (``look-at-*``) do not occupy the unit and do not
travel. A unit with a ``home`` flies back after its last task; that counts for makespan and totals.

The tree simulated is the tree as it will run (``serialise``): children of a conc that share a
unit run one after another as whole subtrees, in the order ``instantiate`` gives them, so the times
are those of executing the instantiated tree.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from delegation.allocation.problem import Problem
from delegation.allocation.serialise import Serialisation, serialisation

#: Relative slack when comparing times against endurance (float noise, not a real margin).
EPS = 1e-9


@dataclass
class Schedule:
    """Times (s from mission start) and distances (m) of one allocation; NaN for unassigned."""

    assign: np.ndarray  # (T,) unit index or -1
    orders: list[list[int]]  # per unit, its vehicle tasks in execution order
    start: np.ndarray  # (T,) travel starts
    end: np.ndarray
    travel_time: np.ndarray
    work_time: np.ndarray
    distance: np.ndarray  # travel + work distance
    unit_finish: np.ndarray  # (U,) end of last task, incl. the way home; 0 when idle
    unit_used: np.ndarray  # (U,) travel + work of vehicle tasks + way home (battery use)
    home_time: np.ndarray  # (U,)
    home_distance: np.ndarray  # (U,)
    makespan: float
    total_time: float
    total_distance: float
    problems: list[str] = field(default_factory=list)  # deadlock, battery, serialisation
    node_act: np.ndarray | None = None  # (tree nodes,) when each node was activated
    node_fin: np.ndarray | None = None  # (tree nodes,) when each node finished
    #: The wrappers that change times (concs whose children holding tasks are subtrees).
    serialised: Serialisation | None = None

    @property
    def valid(self) -> bool:
        return not self.problems

    @property
    def n_unassigned(self) -> int:
        return int((self.assign < 0).sum())

    def key(self, objective: str) -> tuple[float, float, float]:
        """Sort key: fewer unassigned tasks first, then the objective, then the other measure."""
        if objective == "total":
            return (float(self.n_unassigned), self.total_time, self.makespan)
        return (float(self.n_unassigned), self.makespan, self.total_time)


@dataclass(frozen=True)
class _Template:
    succ: list[list[int]]
    indeg: list[int]


def _template(problem: Problem) -> _Template:
    """The static part of the activation graph: ids act(n) = 2n, fin(n) = 2n + 1."""
    s = problem.structure
    succ: list[list[int]] = [[] for _ in range(2 * s.size)]
    for n in range(s.size):
        act, fin = 2 * n, 2 * n + 1
        succ[act].append(fin)
        kids = s.children[n]
        if s.kinds[n] == "seq":
            if kids:
                succ[act].append(2 * kids[0])
                for a, b in itertools.pairwise(kids):
                    succ[2 * a + 1].append(2 * b)
                succ[2 * kids[-1] + 1].append(fin)
        else:
            for c in kids:
                succ[act].append(2 * c)
                succ[2 * c + 1].append(fin)
    indeg = [0] * (2 * s.size)
    for out in succ:
        for v in out:
            indeg[v] += 1
    return _Template(succ, indeg)


def template_for(problem: Problem) -> _Template:
    tpl: _Template | None = problem.cache.get("template")
    if tpl is None:
        tpl = problem.cache["template"] = _template(problem)
    return tpl


def _static_for(problem: Problem) -> dict[str, list[Any]]:
    """The problem's per-task and per-unit numbers as plain lists (the simulation loop is
    Python), made once per problem."""
    static: dict[str, list[Any]] | None = problem.cache.get("static")
    if static is None:
        static = problem.cache["static"] = {
            "vehicle": [t.vehicle for t in problem.tasks],
            "ux": problem.unit_xy[:, 0].tolist(), "uy": problem.unit_xy[:, 1].tolist(),
            "sx": problem.start_xy[:, 0].tolist(), "sy": problem.start_xy[:, 1].tolist(),
            "ex": problem.end_xy[:, 0].tolist(), "ey": problem.end_xy[:, 1].tolist(),
            "travels": problem.travels.tolist(), "to_home": problem.home_task().tolist(),
            "has_home": problem.has_home.tolist(),
            "home_x": problem.home_xy[:, 0].tolist(), "home_y": problem.home_xy[:, 1].tolist(),
        }
    return static


def evaluate(
    problem: Problem, assign: Sequence[int] | np.ndarray, orders: Sequence[Sequence[int]]
) -> Schedule:
    """Simulate the tree with this allocation (earliest start everywhere) and measure it.

    A cycle between the tree's order and the units' orders (unit A waits for B which waits for A)
    is reported in ``problems`` ("deadlock"), as is a unit that would run out of battery.
    """
    n_tasks, n_units = problem.n_tasks, problem.n_units
    assign_arr = np.asarray(assign, dtype=int).reshape(n_tasks)
    s = problem.structure
    tpl = template_for(problem)
    problems: list[str] = []

    prev = [-1] * n_tasks
    seen = [False] * n_tasks
    static = _static_for(problem)
    vehicle = static["vehicle"]
    clean: list[list[int]] = []
    for u, order in enumerate(orders):
        p = -1
        kept: list[int] = []
        for t in order:
            if assign_arr[t] != u or not vehicle[t] or seen[t]:
                problems.append(f"order of unit {problem.unit_names[u]} lists task {t} wrongly")
                continue
            seen[t] = True
            prev[t] = p
            p = t
            kept.append(t)
        clean.append(kept)
    for t in range(n_tasks):
        if assign_arr[t] >= 0 and vehicle[t] and not seen[t]:
            problems.append(f"task {t} is assigned but in no unit's order")

    succ = tpl.succ
    indeg = list(tpl.indeg)
    extra: dict[int, int] = {}  # a unit's previous task ends -> its next task may begin
    node_of = s.node_of_task
    for t in range(n_tasks):
        if prev[t] >= 0:
            src = 2 * node_of[prev[t]] + 1
            extra[src] = 2 * node_of[t] + 1
            indeg[2 * node_of[t] + 1] += 1
    # Whole subtrees sharing a unit run one after another: fin(X) -> act(next X).
    wrapped = serialisation(problem, clean, every_conc=False)
    problems.extend(wrapped.problems)
    chained: dict[int, int] = {}
    for _, kids in wrapped.wraps:
        for a, b in itertools.pairwise(kids):
            chained[2 * a + 1] = 2 * b
            indeg[2 * b] += 1

    ux, uy, sx, sy = static["ux"], static["uy"], static["sx"], static["sy"]
    ex, ey, travels, to_home = static["ex"], static["ey"], static["travels"], static["to_home"]
    has_home = static["has_home"]
    # Per task, the numbers of its unit (0 where unassigned): plain floats for the loop below.
    safe = np.where(assign_arr >= 0, assign_arr, 0)
    cols = np.arange(n_tasks)
    if n_units:
        speed_t = problem.speed[safe, cols].tolist()
        work_tt = problem.work_time[safe, cols].tolist()
        work_dt = problem.work_distance[safe, cols].tolist()
    else:
        speed_t = work_tt = work_dt = [0.0] * n_tasks
    home_x, home_y = static["home_x"], static["home_y"]
    assigned_to = assign_arr.tolist()

    nan = math.nan
    start_l = [nan] * n_tasks
    end_l = [nan] * n_tasks
    travel_l = [nan] * n_tasks
    work_l = [nan] * n_tasks
    dist_l = [nan] * n_tasks
    pos_x = [0.0] * n_tasks
    pos_y = [0.0] * n_tasks

    value = [0.0] * (2 * s.size)
    after = [-1] * (2 * s.size)  # the extra successors: a unit's next task, the next subtree
    for i, j in extra.items():
        after[i] = j
    wrap_next = [-1] * (2 * s.size)
    for i, j in chained.items():
        wrap_next[i] = j
    task_of_node = s.task_of_node
    stack = [i for i in range(2 * s.size) if indeg[i] == 0]
    done = 0
    while stack:
        i = stack.pop()
        done += 1
        if i & 1:
            t = task_of_node[i >> 1]
            if t >= 0:
                begin = value[i]
                u = assigned_to[t]
                if u < 0:
                    end_t = begin
                elif not vehicle[t]:
                    w = work_tt[t]
                    start_l[t], travel_l[t], work_l[t] = begin, 0.0, w
                    dist_l[t] = 0.0
                    end_t = begin + w
                    end_l[t] = end_t
                else:
                    p = prev[t]
                    px, py = (pos_x[p], pos_y[p]) if p >= 0 else (ux[u], uy[u])
                    if to_home[t] and has_home[u]:
                        hx, hy = home_x[u], home_y[u]
                        d = math.hypot(hx - px, hy - py)
                        tt = d / speed_t[t]
                        pos_x[t], pos_y[t] = hx, hy
                    elif travels[t] and not to_home[t]:
                        d = math.hypot(sx[t] - px, sy[t] - py)
                        tt = d / speed_t[t]
                        pos_x[t], pos_y[t] = ex[t], ey[t]
                    else:
                        d, tt = 0.0, 0.0
                        pos_x[t], pos_y[t] = px, py
                    w = work_tt[t]
                    start_l[t], travel_l[t], work_l[t] = begin, tt, w
                    dist_l[t] = d + work_dt[t]
                    end_t = begin + tt + w
                    end_l[t] = end_t
                value[i] = end_t
            v = value[i]
            for j in (after[i], wrap_next[i]):
                if j >= 0:
                    if v > value[j]:
                        value[j] = v
                    indeg[j] -= 1
                    if indeg[j] == 0:
                        stack.append(j)
        v = value[i]
        for j in succ[i]:
            if v > value[j]:
                value[j] = v
            indeg[j] -= 1
            if indeg[j] == 0:
                stack.append(j)
    start = np.array(start_l, dtype=float)
    end = np.array(end_l, dtype=float)
    travel_time = np.array(travel_l, dtype=float)
    work_time = np.array(work_l, dtype=float)
    distance = np.array(dist_l, dtype=float)
    if done < 2 * s.size and not wrapped.problems:
        problems.append("deadlock: the units' orders and the tree's order wait for each other")
    elif done < 2 * s.size:
        problems.append("deadlock: the serialised subtrees and the units' orders wait for each "
                        "other")

    # Per unit: travel + work of its vehicle tasks, the way home, when it is done (plain
    # Python: cheaper than numpy at the sizes the auction simulates hundreds of times).
    unit_finish_l = [0.0] * n_units
    unit_used_l = [0.0] * n_units
    home_time_l = [0.0] * n_units
    home_dist_l = [0.0] * n_units
    makespan = 0.0
    total_time = 0.0
    total_distance = 0.0
    for t in range(n_tasks):
        e = end_l[t]
        if e != e:  # NaN: unassigned or never reached
            continue
        tt, w = travel_l[t], work_l[t]
        total_time += tt + w
        total_distance += dist_l[t]
        makespan = max(makespan, e)
        if vehicle[t]:
            unit_used_l[assigned_to[t]] += tt + w
    home_speed = problem.home_speed.tolist()
    endurance = problem.endurance.tolist()
    for u, order in enumerate(orders):
        if not order:
            continue
        last = order[-1]
        if has_home[u]:
            d = math.hypot(home_x[u] - pos_x[last], home_y[u] - pos_y[last])
            home_dist_l[u] = d
            home_time_l[u] = d / home_speed[u]
        unit_finish_l[u] = end_l[last] + home_time_l[u]
        unit_used_l[u] += home_time_l[u]
        total_time += home_time_l[u]
        total_distance += home_dist_l[u]
        makespan = max(makespan, unit_finish_l[u])
        if unit_used_l[u] > endurance[u] * (1 + EPS) + EPS:
            problems.append(
                f"unit {problem.unit_names[u]} needs {unit_used_l[u]:.0f} s but has "
                f"{endurance[u]:.0f} s of endurance left"
            )
    unit_finish = np.array(unit_finish_l, dtype=float)
    unit_used = np.array(unit_used_l, dtype=float)
    home_time = np.array(home_time_l, dtype=float)
    home_distance = np.array(home_dist_l, dtype=float)
    return Schedule(
        assign=assign_arr.copy(),
        orders=[list(o) for o in orders],
        start=start,
        end=end,
        travel_time=travel_time,
        work_time=work_time,
        distance=distance,
        unit_finish=unit_finish,
        unit_used=unit_used,
        home_time=home_time,
        home_distance=home_distance,
        makespan=makespan,
        total_time=total_time,
        total_distance=total_distance,
        problems=problems,
        node_act=np.array(value[0::2]),
        node_fin=np.array(value[1::2]),
        serialised=wrapped,
    )


def better(a: Schedule, b: Schedule, objective: str, rel: float = 1e-9) -> bool:
    """True when ``a`` is strictly better than ``b`` (beyond float noise)."""
    ka, kb = a.key(objective), b.key(objective)
    for x, y in zip(ka, kb, strict=True):
        if x < y - rel * max(1.0, abs(y)):
            return True
        if x > y + rel * max(1.0, abs(y)):
            return False
    return False
