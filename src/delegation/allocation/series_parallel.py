"""Series-parallel instantiation (docs/protocol.md §8): the tree whose order holds the plan.

The execution a plan means is its precedence graph: the tree's order (a ``seq``'s children one
after another) plus each unit's order of its own tasks. A TST can only say series-parallel orders,
and that graph is generally not one, so the tree sent must order some tasks the graph leaves free:
this module builds a series-parallel order containing every edge of the graph, adding little
waiting.

Method (recursive decomposition of the graph's transitive closure, tasks in the order they start
in the precedence-graph schedule):
- tasks that nothing relates fall apart into components: a ``conc`` of them;
- else, cut points where every task before precedes every task after: a ``seq`` of the pieces;
- else (not series-parallel here) a forced cut: of the prefixes of the start order, the one whose
  estimated delay is least (when the prefix ends + the longest tail after the cut), in a ``seq``.

Control nodes of the caller whose set of tasks and kind survive keep their uuid and fields; new
ones get new uuids and the engine's unit. Caller control nodes without tasks are dropped (they
change no time).
"""

from __future__ import annotations

import itertools
import uuid as uuid_module
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from delegation.allocation.problem import Problem
from delegation.tst import ExecUnitKind, TstNode, classify_execunit, leaves, make_node, walk

if TYPE_CHECKING:
    from delegation.allocation.schedule import Schedule


@dataclass
class PrecedenceGraph:
    """The plan's precedence graph over tasks: ``reach[a, b]`` when a must end before b starts
    (transitive), a topological order, and per task its duration and tail (itself + the longest
    chain after it, ways home included)."""

    reach: np.ndarray
    order: list[int]
    tail: np.ndarray
    end: np.ndarray
    duration: np.ndarray  # per task: travel + work (0 where unassigned)
    home: np.ndarray  # per task: the way home after it (its unit's last task), else 0


def precedence_graph(
    problem: Problem,
    orders: Sequence[Sequence[int]],
    start: np.ndarray,
    end: np.ndarray,
    home_time: np.ndarray | None = None,
) -> PrecedenceGraph:
    """The graph of the tree's order plus the units' ``orders``, with the times of a schedule on
    it (``start``/``end`` per task, NaN where unassigned)."""
    s, n_tasks = problem.structure, problem.n_tasks
    succ: list[list[int]] = [[] for _ in range(n_tasks)]
    for order in orders:
        for a, b in itertools.pairwise(order):
            succ[a].append(b)
    # The tree's order through one barrier node per pair of consecutive seq children.
    tasks_under = _tasks_under(problem)
    n_nodes = n_tasks
    for n in range(s.size):
        if s.kinds[n] != "seq":
            continue
        holding = [c for c in s.children[n] if tasks_under[c]]
        for a, b in itertools.pairwise(holding):
            barrier = n_nodes
            n_nodes += 1
            succ.append(list(tasks_under[b]))
            for t in tasks_under[a]:
                succ[t].append(barrier)
    durations = np.zeros(n_nodes)
    got = _finite(np.asarray(end, dtype=float) - np.asarray(start, dtype=float))
    durations[:n_tasks] = got
    home = np.zeros(n_nodes)
    if home_time is not None:
        for u, order in enumerate(orders):
            if order:
                home[order[-1]] = float(home_time[u])
    key = np.zeros(n_nodes)
    act = _finite(np.asarray(start, dtype=float))
    key[:n_tasks] = act
    topo = _topological(succ, key)
    reach = np.zeros((n_nodes, n_tasks), dtype=bool)
    tail = np.zeros(n_nodes)
    for v in reversed(topo):
        longest = home[v]
        for w in succ[v]:
            reach[v] |= reach[w]
            if w < n_tasks:
                reach[v, w] = True
            longest = max(longest, tail[w])
        tail[v] = durations[v] + longest
    order = [v for v in topo if v < n_tasks]
    return PrecedenceGraph(reach[:n_tasks], order, tail[:n_tasks],
                           _finite(np.asarray(end, dtype=float)), durations[:n_tasks],
                           home[:n_tasks])


_LARGEST = float(np.finfo(float).max)


def _finite(values: np.ndarray) -> np.ndarray:
    """``np.nan_to_num(values)`` (NaN -> 0, infinities -> the largest floats) without the type
    lookups that make it cost more than the graph on small trees."""
    return np.clip(np.where(np.isnan(values), 0.0, values), -_LARGEST, _LARGEST)


def _tasks_under(problem: Problem) -> list[list[int]]:
    s = problem.structure
    under: list[list[int]] = [[] for _ in range(s.size)]
    for n in range(s.size - 1, -1, -1):  # children have higher indices (pre-order)
        t = s.task_of_node[n]
        under[n] = [t] if t >= 0 else [x for c in s.children[n] for x in under[c]]
    return under


def _topological(succ: list[list[int]], key: np.ndarray) -> list[int]:
    """Kahn's order, the earliest ``key`` first among the free nodes (then the lowest id)."""
    import heapq

    indeg = [0] * len(succ)
    for out in succ:
        for w in out:
            indeg[w] += 1
    heap = [(float(key[v]), v) for v in range(len(succ)) if indeg[v] == 0]
    heapq.heapify(heap)
    order: list[int] = []
    while heap:
        _, v = heapq.heappop(heap)
        order.append(v)
        for w in succ[v]:
            indeg[w] -= 1
            if indeg[w] == 0:
                heapq.heappush(heap, (float(key[w]), w))
    if len(order) != len(succ):
        raise ValueError("the tree's order and the units' orders form a cycle")
    return order


@dataclass
class SpNode:
    """A node of the series-parallel order: ``task`` (one task), ``seq`` or ``conc``."""

    kind: str
    tasks: np.ndarray  # task indices under it, in topological order
    children: list[SpNode] = field(default_factory=list)


#: Decompositions with forced cuts drawn at random tried after the deterministic ones, when
#: those lose time against the precedence graph (measured: on generated mixed 20x100 trees 40
#: restarts take ~0.2 s and cut the loss by about a third; 16 are a compromise with latency).
#: Large trees get fewer (``RESTART_TASKS`` / tasks, at least 2): one decomposition of a
#: 1000-task tree takes ~70 ms.
RESTARTS = 16
RESTART_TASKS = 3000


def best_decomposition(
    graph: PrecedenceGraph, makespan: float, rounds: int = 3, restarts: int | None = None
) -> SpNode:
    """The shortest of a few decompositions: the first from the precedence graph's times, each
    next from the times of the tree before it (forced cuts then see the waiting that earlier
    cuts added); then, while the best still loses against the graph's ``makespan``, restarts
    with random near-best forced cuts (seeded: the same plan gives the same tree)."""
    best = decompose(graph)
    best_span, _, _ = sp_times(best, graph)
    current = best
    for _ in range(rounds - 1):
        if best_span <= makespan * (1 + 1e-9):
            break
        _, start, end = sp_times(current, graph)
        rank = np.empty(len(graph.order), dtype=int)
        rank[np.asarray(graph.order, dtype=int)] = np.arange(len(graph.order))
        order = sorted(graph.order, key=lambda t: (start[t], rank[t]))
        again = PrecedenceGraph(graph.reach, order, graph.tail, end, graph.duration, graph.home)
        current = decompose(again)
        span, _, _ = sp_times(current, graph)
        if span < best_span - 1e-9 * max(1.0, best_span):
            best, best_span = current, span
    if restarts is None:
        restarts = min(RESTARTS, max(2, RESTART_TASKS // max(1, len(graph.order))))
    rng: np.random.Generator | None = None  # made on first use: it costs more than a cut
    for _ in range(restarts):
        if best_span <= makespan * (1 + 1e-9):
            break
        rng = rng or np.random.default_rng(0)
        current = decompose(graph, rng)
        span, _, _ = sp_times(current, graph)
        if span < best_span - 1e-9 * max(1.0, best_span):
            best, best_span = current, span
    return best


#: Decompositions remembered per problem (``schedule_decomposition``).
_REMEMBERED = 4


def schedule_decomposition(problem: Problem, schedule: Schedule
                           ) -> tuple[PrecedenceGraph, SpNode]:
    """``precedence_graph`` and ``best_decomposition`` of ``schedule`` (a schedule of
    ``problem``), remembered on the problem for the last few schedules: the auction's search
    judges its result by the tree it would send (``improve``), and the plan then builds that
    tree from the same schedule (``sent_tree.choose_tree``): one decomposition, not two."""
    memo: dict[int, tuple[Schedule, PrecedenceGraph, SpNode]] = \
        problem.cache.setdefault("decompositions", {})
    found = memo.get(id(schedule))
    if found is not None and found[0] is schedule:
        return found[1], found[2]
    graph = precedence_graph(problem, schedule.orders, schedule.start, schedule.end,
                             schedule.home_time)
    tree = best_decomposition(graph, schedule.makespan)
    if len(memo) >= _REMEMBERED:
        memo.clear()
    memo[id(schedule)] = (schedule, graph, tree)  # (the schedule held: its id stays its own)
    return graph, tree


def tree_makespan(problem: Problem, orders: Sequence[Sequence[int]], start: np.ndarray,
                  end: np.ndarray, home_time: np.ndarray, graph_makespan: float) -> float:
    """The makespan of the series-parallel tree this schedule would be sent as (the first,
    deterministic decomposition only: cheap enough for a search to call per move)."""
    graph = precedence_graph(problem, orders, start, end, home_time)
    span, _, _ = sp_times(best_decomposition(graph, graph_makespan, rounds=1, restarts=0), graph)
    return span


def sp_times(root: SpNode, graph: PrecedenceGraph) -> tuple[float, np.ndarray, np.ndarray]:
    """Makespan, start and end per task of running ``root`` (earliest times; the durations are
    fixed because every unit's order is in the tree's)."""
    n = len(graph.duration)
    start, end = np.zeros(n), np.zeros(n)
    finish: dict[int, float] = {}  # how long each node runs, from its children's
    nodes = _preorder(root)
    for node in reversed(nodes):
        if node.kind == "task":
            finish[id(node)] = graph.duration[int(node.tasks[0])]
        elif node.kind == "conc":
            finish[id(node)] = max(finish[id(c)] for c in node.children)
        else:
            finish[id(node)] = sum(finish[id(c)] for c in node.children)
    begin = {id(root): 0.0}
    span = 0.0
    for node in nodes:  # parents first: a seq's children one after another
        b = begin[id(node)]
        if node.kind == "task":
            t = int(node.tasks[0])
            start[t], end[t] = b, b + graph.duration[t]
            span = max(span, end[t] + graph.home[t])
        elif node.kind == "conc":
            for c in node.children:
                begin[id(c)] = b
        else:
            for c in node.children:
                begin[id(c)] = b
                b += finish[id(c)]
    return span, start, end


def decompose(graph: PrecedenceGraph, rng: np.random.Generator | None = None) -> SpNode:
    """The series-parallel order (see the module doc) containing ``graph``'s every edge; with
    ``rng``, each forced cut is drawn among the near-best (restarts).

    Sets of tasks are Python integer bitsets over the tasks' places in ``graph.order`` (a node's
    tasks are always a subsequence of it): the relations within a node are bit operations on the
    rows of ``_rank_bits``, not a submatrix per node (measured: several times faster from 20
    tasks on, and far less memory traffic on 1000).
    """
    order = np.asarray(graph.order, dtype=int)
    down, up = _rank_bits(graph)
    root = SpNode("?", order)
    stack = [(root, (1 << len(order)) - 1, list(range(len(order))))]
    while stack:
        node, members, places = stack.pop()
        if len(places) == 1:
            node.kind = "task"
            continue
        parts = _components(members, down, up)
        if len(parts) > 1:
            node.kind = "conc"
            pieces = [(part, _places(part)) for part in parts]
        else:
            node.kind = "seq"
            cuts = _clean_cuts(members, places, down)
            if not cuts:
                cuts = [_forced_cut(graph, node.tasks, rng)]
            pieces = []
            for lo, hi in itertools.pairwise([0, *cuts, len(places)]):
                below = (1 << places[hi - 1] + 1) - 1
                pieces.append((members & below & ~((1 << places[lo]) - 1), places[lo:hi]))
        node.children = [SpNode("?", order[part_places]) for _, part_places in pieces]
        stack.extend((child, part, part_places)
                     for child, (part, part_places) in zip(node.children, pieces, strict=True))
    _splice(root)
    return root


def _rank_bits(graph: PrecedenceGraph) -> tuple[list[int], list[int]]:
    """Per place i of ``graph.order``: the places its task reaches (bit j: it ends before the
    task at place j starts), and the places that reach it."""
    order = np.asarray(graph.order, dtype=int)
    ranked = graph.reach[np.ix_(order, order)]

    def rows(matrix: np.ndarray) -> list[int]:
        packed = np.packbits(matrix, axis=1, bitorder="little")
        return [int.from_bytes(r.tobytes(), "little") for r in packed]

    return rows(ranked), rows(ranked.T)


def _places(bits: int) -> list[int]:
    """The set bits of ``bits``, ascending."""
    out: list[int] = []
    while bits:
        low = bits & -bits
        out.append(low.bit_length() - 1)
        bits ^= low
    return out


def _components(members: int, down: list[int], up: list[int]) -> list[int]:
    """Connected components of "one reaches the other" among ``members`` (bitsets, by their
    lowest place)."""
    out: list[int] = []
    unseen = members
    while unseen:
        comp = frontier = unseen & -unseen
        while frontier:
            reached = 0
            while frontier:
                bit = frontier & -frontier
                i = bit.bit_length() - 1
                reached |= down[i] | up[i]
                frontier ^= bit
            frontier = reached & members & ~comp
            comp |= frontier
        unseen &= ~comp
        out.append(comp)
    return out


def _clean_cuts(members: int, places: list[int], down: list[int]) -> list[int]:
    """Positions k of ``places`` (ascending, a topological order) where every task before k
    reaches every task from k: no task reaches back, so a cut is clean when the last member
    some earlier task does not reach lies before k."""
    cuts: list[int] = []
    furthest = -1
    for k, p in enumerate(places):
        if k and furthest < p:
            cuts.append(k)
        unrelated = members & ~down[p] & ~((2 << p) - 1)  # later members p does not reach
        furthest = max(furthest, unrelated.bit_length() - 1 if unrelated else p)
    return cuts


def _forced_cut(
    graph: PrecedenceGraph, tasks: np.ndarray, rng: np.random.Generator | None = None
) -> int:
    """The prefix to run before the rest whose estimated makespan (the prefix's last end + the
    longest tail after the cut) is least; ties go to the most even split. With ``rng``: one of
    the cuts within a random 0-20 % of the least, at random."""
    ends = np.maximum.accumulate(graph.end[tasks])
    tails = np.maximum.accumulate(graph.tail[tasks][::-1])[::-1]
    n = len(tasks)
    ks = np.arange(1, n)
    cost = ends[ks - 1] + tails[ks]
    best = cost.min()
    if rng is not None:
        near = ks[cost <= best * (1.0 + rng.uniform(0.0, 0.2)) + 1e-9]
        return int(rng.choice(near))
    ties = ks[cost <= best + 1e-9 * max(1.0, abs(best))]
    return int(ties[np.argmin(np.abs(ties - n / 2))])


def _splice(root: SpNode) -> None:
    """A ``seq`` directly under a ``seq`` is spliced into it (forced cuts nest them)."""
    for node in reversed(_preorder(root)):  # children before parents
        if node.kind == "seq":
            node.children = [g for c in node.children
                             for g in (c.children if c.kind == "seq" else [c])]


def _preorder(root: SpNode) -> list[SpNode]:
    out: list[SpNode] = []
    stack = [root]
    while stack:
        node = stack.pop()
        out.append(node)
        stack.extend(node.children)
    return out


def build_tree(
    root: SpNode,
    source: TstNode,
    filled_leaves: Mapping[str, TstNode],
    task_uuids: Sequence[str],
    engine_unit: str = "op0",
    new_uuid: Callable[[], str] | None = None,
) -> TstNode:
    """The TST of ``root``: the leaves ``filled_leaves[uuid]``; a caller's control node reused
    (uuid, fields) where one of its kind has the same tasks, and caller nodes with the same
    tasks but the other kind wrapped around it."""
    make = new_uuid or (lambda: str(uuid_module.uuid4()))
    engine = "/" + engine_unit.strip("/")
    callers: dict[frozenset[str], list[TstNode]] = {}
    for _, given in walk(source):  # parents first: outermost first
        if given.is_control:
            uids = frozenset(leaf.node_uuid or "" for leaf in leaves(given))
            if uids:
                callers.setdefault(uids, []).append(given)

    def control(node: TstNode, children: list[TstNode]) -> TstNode:
        try:
            kind, _ = classify_execunit(node.execunit)
        except TypeError:
            kind = ExecUnitKind.FREE
        node = node.with_children(tuple(children))
        return node if kind is ExecUnitKind.FIXED else node.with_common_values(
            {"execunit": engine})

    built: dict[int, TstNode] = {}
    for node in reversed(_preorder(root)):  # children before parents
        uids = frozenset(task_uuids[int(t)] for t in node.tasks)
        same = callers.get(uids, [])
        mine = next((c for c in same if c.name == node.kind), None)
        if node.kind == "task":
            tree = filled_leaves[task_uuids[int(node.tasks[0])]]
        else:
            kids = [built.pop(id(c)) for c in node.children]
            tree = (control(mine, kids) if mine is not None
                    else make_node(node.kind, kids, execunit=engine, node_uuid=make()))
        for outer in reversed([c for c in same if c is not mine]):
            tree = control(outer, [tree])
        built[id(node)] = tree
    return built[id(root)]
