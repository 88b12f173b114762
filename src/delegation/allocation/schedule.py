"""Schedule evaluation: given who does what in which order, when does everything happen.

The one place that turns (assignment, per-unit order) into times, so that every strategy, the
invariants and the tests agree (docs/plan.md §3): a task is executed when the tree activates it
(seq: after its predecessor ended; conc: with its siblings) and its unit is free; travel starts
then, from where the unit is at that time. Non-vehicle tasks (``look-at-*``) do not occupy the unit
and do not travel. A unit with a ``home`` flies back after its last task; that counts for makespan
and totals.

By default the graph simulated is the plan's precedence graph (the tree's order plus the units'
orders, docs/protocol.md §8), what the strategies plan for; the plan's own times come from
simulating the tree actually sent on its own structure (``sent_tree``). ``wrapped=True`` simulates
the old rule's tree (children of a conc that share a unit wrapped whole in a seq, ``serialise``).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from delegation.allocation.problem import Problem, Structure
from delegation.allocation.serialise import Serialisation, serialisation
from delegation.allocation.strategies import Objective
from delegation.coverage import pick_way

#: Relative slack when comparing times against endurance (float noise, not a real margin).
EPS = 1e-9


class IssueKind(StrEnum):
    """Why an allocation cannot run as planned."""

    ORDER = "order"  # a unit's order lists a task wrongly, or an assigned task is in none
    SERIALISATION = "serialisation"  # subtrees sharing units cannot run one after another
    DEADLOCK = "deadlock"  # the tree's order and the units' orders wait for each other
    ENDURANCE = "endurance"  # a unit would run out of battery


@dataclass(frozen=True)
class ScheduleIssue:
    """One reason a schedule is not valid: its kind, and a sentence for people."""

    kind: IssueKind
    text: str

    def __str__(self) -> str:
        return self.text


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
    issues: list[ScheduleIssue] = field(default_factory=list)  # empty: the schedule can run
    node_act: np.ndarray | None = None  # (tree nodes,) when each node was activated
    node_fin: np.ndarray | None = None  # (tree nodes,) when each node finished
    #: The wrappers that change times (concs whose children holding tasks are subtrees).
    serialised: Serialisation | None = None
    #: (T, 2) where each vehicle task leaves its unit (east, north m; a search: the end of the
    #: way it was flown, which depends on where the unit came from); NaN where not reached.
    end_xy: np.ndarray | None = None

    @property
    def valid(self) -> bool:
        return not self.issues

    @property
    def n_unassigned(self) -> int:
        # (count_nonzero: a direct C call; ``sum`` goes through numpy's Python wrappers, and
        # the auction asks for every bid it simulates)
        return int(np.count_nonzero(self.assign < 0))

    def key(self, objective: Objective | str) -> tuple[float, float, float]:
        """Sort key: fewer unassigned tasks first, then the objective, then the other measure."""
        match Objective(objective):
            case Objective.MAKESPAN:
                return (float(self.n_unassigned), self.makespan, self.total_time)
            case Objective.TOTAL:
                return (float(self.n_unassigned), self.total_time, self.makespan)


@dataclass(frozen=True)
class _Template:
    """The tree's part of the activation graph, and which task each event finishes."""

    succ: list[list[int]]
    indeg: list[int]
    task_of_event: list[int]  # per event: the task whose fin(n) it is, else -1
    node_of_task: list[int]


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
    task_of_event = [-1] * (2 * s.size)
    for n, t in enumerate(s.task_of_node):
        task_of_event[2 * n + 1] = t
    return _Template(succ, indeg, task_of_event, list(s.node_of_task))


def template_for(problem: Problem) -> _Template:
    tpl: _Template | None = problem.cache.get("template")
    if tpl is None:
        tpl = problem.cache["template"] = _template(problem)
    return tpl


@dataclass(frozen=True)
class Static:
    """The problem's per-task and per-unit numbers as plain lists (the simulation loop is
    Python: list indexing is several times cheaper than numpy scalars), made once per problem."""

    vehicle: list[bool]  # per task
    sx: list[list[float]]  # per unit, per task: start and end point (its own sweep's)
    sy: list[list[float]]
    ex: list[list[float]]
    ey: list[list[float]]
    travels: list[bool]
    to_home: list[bool]
    ux: list[float]  # per unit: where it is, its home, how fast it flies home, its battery
    uy: list[float]
    has_home: list[bool]
    home_x: list[float]
    home_y: list[float]
    home_speed: list[float]
    endurance: list[float]
    ready: list[float]  # per unit: when it is free of earlier commitments (s)
    speed: list[list[float]]  # per unit, per task: m/s, work time (s), work distance (m)
    work_time: list[list[float]]
    work_distance: list[list[float]]
    #: per unit: search task -> the ways it may fly it, rows (start x, y, end x, y, m, s)
    #: (``Problem.sweep_ways``; ``coverage.pick_way`` chooses from where the unit is)
    ways: list[dict[int, list[list[float]]]]


def static_for(problem: Problem) -> Static:
    static: Static | None = problem.cache.get("static")
    if static is None:
        starts, ends = problem.unit_points()
        static = problem.cache["static"] = Static(
            vehicle=[t.vehicle for t in problem.tasks],
            sx=_per_unit(problem, starts[..., 0]), sy=_per_unit(problem, starts[..., 1]),
            ex=_per_unit(problem, ends[..., 0]), ey=_per_unit(problem, ends[..., 1]),
            travels=problem.travels.tolist(), to_home=problem.home_task().tolist(),
            ux=problem.unit_xy[:, 0].tolist(), uy=problem.unit_xy[:, 1].tolist(),
            has_home=problem.has_home.tolist(),
            home_x=problem.home_xy[:, 0].tolist(), home_y=problem.home_xy[:, 1].tolist(),
            home_speed=problem.home_speed.tolist(), endurance=problem.endurance.tolist(),
            ready=(problem.ready.tolist() if problem.ready is not None
                   else [0.0] * problem.n_units),
            speed=problem.speed.tolist(), work_time=problem.work_time.tolist(),
            work_distance=problem.work_distance.tolist(),
            ways=_ways_per_unit(problem),
        )
    return static


def _ways_per_unit(problem: Problem) -> list[dict[int, list[list[float]]]]:
    """``_Static.ways``: per unit, each search's ways it can fly (rows without NaN)."""
    out: list[dict[int, list[list[float]]]] = [{} for _ in range(problem.n_units)]
    for t, table in problem.sweep_ways.items():
        for u, rows in enumerate(table.tolist()):
            mine = [row for row in rows if row[4] == row[4]]  # (NaN: none)
            if mine:
                out[u][t] = mine
    return out


def _per_unit(problem: Problem, table: np.ndarray) -> list[list[float]]:
    """(U, T) ``table`` as lists: one row shared by every unit where points are uniform."""
    if problem.unit_start_xy is None and problem.n_units:
        return [table[0].tolist()] * problem.n_units
    return list(table.tolist())


def restructured(problem: Problem, structure: Structure) -> Problem:
    """``problem`` with another tree over the same tasks (the tree sent): the per-task and
    per-unit numbers are shared, what depends on the tree is made anew."""
    cache = {"static": problem.cache["static"]} if "static" in problem.cache else {}
    return dataclasses.replace(problem, structure=structure, cache=cache, _before=None)


def evaluate(
    problem: Problem, assign: Sequence[int] | np.ndarray, orders: Sequence[Sequence[int]],
    *, wrapped: bool | None = None,
) -> Schedule:
    """Simulate the tree with this allocation (earliest start everywhere) and measure it.

    By default the precedence graph (the tree's order plus each unit's order, docs/protocol.md §8):
    what every strategy plans for; the tree sent is built from it (``series_parallel``) and
    simulated on its own structure. ``wrapped`` adds the old rule's whole-subtree wrappers
    (``serialise``): the times of the tree ``instantiate`` builds (default: the problem's
    ``wrap_subtrees``).

    A cycle between the tree's order and the units' orders (unit A waits for B which waits for A)
    is reported in ``issues`` (``DEADLOCK``), as is a unit that would run out of battery
    (``ENDURANCE``).
    """
    assign_arr = np.asarray(assign, dtype=int).reshape(problem.n_tasks)
    assigned_to = assign_arr.tolist()
    static = static_for(problem)
    prev, clean, issues = _clean_orders(problem, assigned_to, orders, static)
    wrap = problem.wrap_subtrees if wrapped is None else wrapped
    graph = _activation_graph(problem, prev, clean, wrap)
    issues.extend(ScheduleIssue(IssueKind.SERIALISATION, text) for text in graph.wrapped.problems)
    run = _simulate(problem, assigned_to, prev, graph, static)
    if run.done < len(run.value):
        issues.append(ScheduleIssue(IssueKind.DEADLOCK, (
            "deadlock: the units' orders and the tree's order wait for each other"
            if not graph.wrapped.problems else
            "deadlock: the serialised subtrees and the units' orders wait for each other"
        )))
    totals = _unit_totals(problem, assigned_to, orders, run, static)
    issues.extend(totals.issues)
    # One conversion per shape (rows are views): cheaper than eleven small arrays.
    per_task = np.array([run.start, run.end, run.travel, run.work, run.dist], dtype=float)
    per_task = per_task.reshape(5, problem.n_tasks)
    per_unit = np.array([totals.unit_finish, totals.unit_used, totals.home_time,
                         totals.home_dist], dtype=float).reshape(4, problem.n_units)
    events = np.array(run.value, dtype=float)
    return Schedule(
        assign=assign_arr.copy(),
        orders=[list(o) for o in orders],
        start=per_task[0],
        end=per_task[1],
        travel_time=per_task[2],
        work_time=per_task[3],
        distance=per_task[4],
        unit_finish=per_unit[0],
        unit_used=per_unit[1],
        home_time=per_unit[2],
        home_distance=per_unit[3],
        makespan=totals.makespan,
        total_time=totals.total_time,
        total_distance=totals.total_distance,
        issues=issues,
        node_act=events[0::2],
        node_fin=events[1::2],
        serialised=graph.wrapped,
        end_xy=np.where(np.isnan(per_task[1])[:, None], np.nan,
                        np.column_stack([run.pos_x, run.pos_y]).reshape(problem.n_tasks, 2)),
    )


def _clean_orders(
    problem: Problem, assign: list[int], orders: Sequence[Sequence[int]], static: Static
) -> tuple[list[int], list[list[int]], list[ScheduleIssue]]:
    """Each task's predecessor on its unit (-1: first), the orders without the tasks they list
    wrongly, and the wrongly listed or missing tasks."""
    n_tasks, vehicle = problem.n_tasks, static.vehicle
    issues: list[ScheduleIssue] = []
    prev = [-1] * n_tasks
    seen = [False] * n_tasks
    clean: list[list[int]] = []
    for u, order in enumerate(orders):
        p = -1
        kept: list[int] = []
        for t in order:
            if assign[t] != u or not vehicle[t] or seen[t]:
                issues.append(ScheduleIssue(
                    IssueKind.ORDER, f"order of unit {problem.unit_names[u]} lists task {t} wrongly"
                ))
                continue
            seen[t] = True
            prev[t] = p
            p = t
            kept.append(t)
        clean.append(kept)
    for t in range(n_tasks):
        if assign[t] >= 0 and vehicle[t] and not seen[t]:
            issues.append(ScheduleIssue(IssueKind.ORDER,
                                        f"task {t} is assigned but in no unit's order"))
    return prev, clean, issues


@dataclass
class _Graph:
    """The activation graph of one allocation: the tree's (``template_for``) plus, per event, at
    most one successor from a unit's order and one from the serialised subtrees."""

    indeg: list[int]
    after: list[int]  # a unit's previous task ends -> its next task may begin (-1: none)
    wrap_next: list[int]  # fin(X) -> act(next X) of whole subtrees sharing a unit (-1: none)
    wrapped: Serialisation


def _activation_graph(
    problem: Problem, prev: list[int], clean: list[list[int]], wrapped: bool
) -> _Graph:
    """Events act(n) = 2n, fin(n) = 2n + 1 of every tree node, and what waits for what."""
    size = 2 * problem.structure.size
    template = template_for(problem)
    indeg = list(template.indeg)
    after = [-1] * size
    node_of = template.node_of_task
    for t, p in enumerate(prev):
        if p >= 0:
            j = 2 * node_of[t] + 1
            after[2 * node_of[p] + 1] = j
            indeg[j] += 1
    # Whole subtrees sharing a unit run one after another: fin(X) -> act(next X).
    wrap_next = [-1] * size
    if not wrapped:
        return _Graph(indeg, after, wrap_next, Serialisation())
    wraps = serialisation(problem, clean, every_conc=False)
    for _, kids in wraps.wraps:
        for a, b in itertools.pairwise(kids):
            wrap_next[2 * a + 1] = 2 * b
            indeg[2 * b] += 1
    return _Graph(indeg, after, wrap_next, wraps)


@dataclass
class _Run:
    """Per task (NaN: unassigned or never reached): times, distances, where it leaves the unit;
    per event its time, and how many events ran (fewer than all: a deadlock)."""

    start: list[float]
    end: list[float]
    travel: list[float]
    work: list[float]
    dist: list[float]
    pos_x: list[float]
    pos_y: list[float]
    value: list[float]
    done: int


def _simulate(
    problem: Problem, assigned_to: list[int], prev: list[int], graph: _Graph, static: Static
) -> _Run:
    """Run the events in topological order, earliest times everywhere: a task's event fin(n)
    is reached when the tree activated it and its unit is free; travel starts then, from where
    the unit is."""
    n_tasks, n_events = problem.n_tasks, 2 * problem.structure.size
    vehicle, ux, uy, sx, sy = static.vehicle, static.ux, static.uy, static.sx, static.sy
    ex, ey, travels, to_home = static.ex, static.ey, static.travels, static.to_home
    has_home, home_x, home_y = static.has_home, static.home_x, static.home_y
    speed_rows, work_rows, workd_rows = static.speed, static.work_time, static.work_distance
    ways_of = static.ways
    template = template_for(problem)
    ready, task_of_event = static.ready, template.task_of_event
    nan = math.nan
    hypot = math.hypot
    run = _Run([nan] * n_tasks, [nan] * n_tasks, [nan] * n_tasks, [nan] * n_tasks,
               [nan] * n_tasks, [0.0] * n_tasks, [0.0] * n_tasks, [0.0] * n_events, 0)
    start_l, end_l, travel_l, work_l, dist_l = run.start, run.end, run.travel, run.work, run.dist
    pos_x, pos_y, value = run.pos_x, run.pos_y, run.value
    succ, indeg, after, wrap_next = template.succ, graph.indeg, graph.after, graph.wrap_next
    stack = [i for i in range(n_events) if indeg[i] == 0]
    done = 0
    while stack:
        i = stack.pop()
        done += 1
        v = value[i]
        if i & 1:
            t = task_of_event[i]
            if t >= 0:
                u = assigned_to[t]
                if u < 0:
                    pass  # unassigned: ends when it begins
                elif not vehicle[t]:
                    w = work_rows[u][t]
                    start_l[t], travel_l[t], work_l[t] = v, 0.0, w
                    dist_l[t] = 0.0
                    v += w
                    end_l[t] = v
                else:
                    p = prev[t]
                    if p < 0:  # its first task: not before the unit is free
                        px, py = ux[u], uy[u]
                        if ready[u] > v:
                            v = ready[u]
                    else:
                        px, py = pos_x[p], pos_y[p]
                    if to_home[t] and has_home[u]:
                        hx, hy = home_x[u], home_y[u]
                        d = hypot(hx - px, hy - py)
                        tt = d / speed_rows[u][t]
                        pos_x[t], pos_y[t] = hx, hy
                        w, wd = work_rows[u][t], workd_rows[u][t]
                    elif travels[t] and not to_home[t]:
                        ways = ways_of[u].get(t)
                        if ways is not None:  # a sweep: the way that costs least from here
                            way = ways[pick_way(ways, (px, py))]
                            d = hypot(way[0] - px, way[1] - py)
                            pos_x[t], pos_y[t] = way[2], way[3]
                            w, wd = way[5], way[4]
                        else:
                            d = hypot(sx[u][t] - px, sy[u][t] - py)
                            pos_x[t], pos_y[t] = ex[u][t], ey[u][t]
                            w, wd = work_rows[u][t], workd_rows[u][t]
                        tt = d / speed_rows[u][t]
                    else:
                        d, tt = 0.0, 0.0
                        pos_x[t], pos_y[t] = px, py
                        w, wd = work_rows[u][t], workd_rows[u][t]
                    start_l[t], travel_l[t], work_l[t] = v, tt, w
                    dist_l[t] = d + wd
                    v = v + tt + w
                    end_l[t] = v
                value[i] = v
            j = after[i]
            if j >= 0:
                if v > value[j]:
                    value[j] = v
                indeg[j] -= 1
                if indeg[j] == 0:
                    stack.append(j)
            j = wrap_next[i]
            if j >= 0:
                if v > value[j]:
                    value[j] = v
                indeg[j] -= 1
                if indeg[j] == 0:
                    stack.append(j)
        for j in succ[i]:
            if v > value[j]:
                value[j] = v
            indeg[j] -= 1
            if indeg[j] == 0:
                stack.append(j)
    run.done = done
    return run


@dataclass
class _Totals:
    """Per unit: when it is done, its battery use, its way home; the plan's measures."""

    unit_finish: list[float]
    unit_used: list[float]
    home_time: list[float]
    home_dist: list[float]
    makespan: float = 0.0
    total_time: float = 0.0
    total_distance: float = 0.0
    issues: list[ScheduleIssue] = field(default_factory=list)


def _unit_totals(
    problem: Problem, assigned_to: list[int], orders: Sequence[Sequence[int]], run: _Run,
    static: Static,
) -> _Totals:
    """Per unit: travel + work of its vehicle tasks, the way home, when it is done, whether its
    battery holds (plain Python: cheaper than numpy at the sizes the auction simulates hundreds
    of times)."""
    n_units, vehicle = problem.n_units, static.vehicle
    out = _Totals([0.0] * n_units, [0.0] * n_units, [0.0] * n_units, [0.0] * n_units)
    unit_finish_l, unit_used_l = out.unit_finish, out.unit_used
    home_time_l, home_dist_l = out.home_time, out.home_dist
    makespan = total_time = total_distance = 0.0
    end_l, travel_l, work_l, dist_l = run.end, run.travel, run.work, run.dist
    for t in range(problem.n_tasks):
        e = end_l[t]
        if e != e:  # NaN: unassigned or never reached
            continue
        tw = travel_l[t] + work_l[t]
        total_time += tw
        total_distance += dist_l[t]
        if e > makespan:
            makespan = e
        if vehicle[t]:
            unit_used_l[assigned_to[t]] += tw
    has_home, home_x, home_y = static.has_home, static.home_x, static.home_y
    home_speed, endurance = static.home_speed, static.endurance
    for u, order in enumerate(orders):
        if not order:
            continue
        last = order[-1]
        if has_home[u]:
            d = math.hypot(home_x[u] - run.pos_x[last], home_y[u] - run.pos_y[last])
            home_dist_l[u] = d
            home_time_l[u] = d / home_speed[u]
        unit_finish_l[u] = end_l[last] + home_time_l[u]
        unit_used_l[u] += home_time_l[u]
        total_time += home_time_l[u]
        total_distance += home_dist_l[u]
        if unit_finish_l[u] > makespan:
            makespan = unit_finish_l[u]
        if unit_used_l[u] > endurance[u] * (1 + EPS) + EPS:
            out.issues.append(ScheduleIssue(IssueKind.ENDURANCE, (
                f"unit {problem.unit_names[u]} needs {unit_used_l[u]:.0f} s but has "
                f"{endurance[u]:.0f} s of endurance left"
            )))
    out.makespan, out.total_time, out.total_distance = makespan, total_time, total_distance
    return out


def better(a: Schedule, b: Schedule, objective: Objective | str, rel: float = 1e-9) -> bool:
    """True when ``a`` is strictly better than ``b`` (beyond float noise)."""
    return better_key(a.key(objective), b.key(objective), rel)


def better_key(ka: tuple[float, ...], kb: tuple[float, ...], rel: float = 1e-9) -> bool:
    """Key ``ka`` strictly better than ``kb``, compared in order, beyond float noise."""
    for x, y in zip(ka, kb, strict=True):
        if x < y - rel * max(1.0, abs(y)):
            return True
        if x > y + rel * max(1.0, abs(y)):
            return False
    return False
