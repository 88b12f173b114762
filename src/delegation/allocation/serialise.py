"""The old wrap rule (docs/protocol.md §8): children of a ``conc`` that share a unit, serialised.

A unit runs one vehicle task at a time, so where an allocation gives one unit tasks under several
children of a ``conc``, the instantiated tree wraps those children (whole subtrees, grouped into
connected components of "shares a unit") in a new ``seq``. The wrapped children run in the order
derived from the units' orders alone (never from times, so that the schedule evaluator and
``instantiate`` agree exactly): the topological order of "some unit does its tasks under X before
those under Y", where among the children free to go next the one first in the tree goes first.

Two allocations cannot run as whole subtrees, and are invalid: a unit that leaves a child and later
comes back to it, and units that disagree (X before Y on one, Y before X on another).
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from delegation.allocation.problem import Problem


@dataclass
class Serialisation:
    """The ``seq`` wrappers an allocation adds to the tree, and why it cannot run (if so)."""

    #: (conc node, its children in the order the new seq runs them), one per wrapped component.
    wraps: list[tuple[int, list[int]]] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)


def order_children(
    runs: Sequence[tuple[str, Sequence[int]]],
    label: Callable[[int], str] = lambda i: f"children[{i}]",
) -> tuple[list[list[int]], list[str]]:
    """Components of one conc's children that share a unit, each in the order the units imply.

    ``runs``: per unit (its name), the child position of each of its vehicle tasks under this conc,
    in the unit's order. Returns the components with two or more children (ordered; listed by
    their first child) and the problems that make the allocation invalid (then the order given
    for a component is a deterministic fallback, not a runnable one).
    """
    succ: dict[int, set[int]] = {}
    indeg: dict[int, int] = {}
    parent: dict[int, int] = {}
    problems: list[str] = []

    def find(i: int) -> int:
        root = i
        while parent[root] != root:
            root = parent[root]
        while parent[i] != root:
            parent[i], i = root, parent[i]
        return root

    for name, children in runs:
        left: set[int] = set()
        current = -1
        for c in children:
            if c == current:
                continue
            parent.setdefault(c, c)
            if current >= 0:
                if c in left:
                    problems.append(
                        f"{name} would come back to {label(c)} after leaving it: its tasks there "
                        "cannot run as one subtree"
                    )
                left.add(current)
                out = succ.setdefault(current, set())
                if c not in out:
                    out.add(c)
                    indeg[c] = indeg.get(c, 0) + 1
                parent[find(c)] = find(current)
            current = c
    members: dict[int, list[int]] = {}
    for c in sorted(parent):
        members.setdefault(find(c), []).append(c)
    groups: list[list[int]] = []
    for component in members.values():
        if len(component) < 2:
            continue
        order: list[int] = []
        remaining = set(component)
        heap = [c for c in component if indeg.get(c, 0) == 0]
        heapq.heapify(heap)
        while remaining:
            if not heap:
                stuck = sorted(remaining)
                problems.append(
                    "the units disagree on the order of " + ", ".join(label(c) for c in stuck)
                    + " (one runs a child before another, a second unit the other way round)"
                )
                heapq.heappush(heap, stuck[0])
            c = heapq.heappop(heap)
            if c not in remaining:
                continue
            remaining.remove(c)
            order.append(c)
            for d in sorted(succ.get(c, ())):
                indeg[d] -= 1
                if indeg[d] == 0 and d in remaining:
                    heapq.heappush(heap, d)
        groups.append(order)
    groups.sort(key=lambda g: min(g))
    return groups, problems


def conc_paths(problem: Problem, every_conc: bool) -> list[list[tuple[int, int]]]:
    """Per task, the concs above it that may need wrapping, with the child (position) it is under.

    Without ``every_conc``, only concs where some child holding a task holds several: where every
    such child is one task, the wrap runs a unit's tasks in its order, which the evaluator already
    does (a unit waits for its previous task), so those concs change no time.
    """
    key = "conc_paths_all" if every_conc else "conc_paths"
    value: list[list[tuple[int, int]]] | None = problem.cache.get(key)
    if value is not None:
        return value
    s = problem.structure
    counts = [0] * s.size
    for n in range(s.size - 1, -1, -1):
        counts[n] = 1 if s.task_of_node[n] >= 0 else sum(counts[c] for c in s.children[n])
    wanted = [False] * s.size
    for n, kind in enumerate(s.kinds):
        if kind == "task" or kind == "seq":
            continue
        holding = [c for c in s.children[n] if counts[c]]
        wanted[n] = len(holding) > 1 and (every_conc or any(counts[c] > 1 for c in holding))
    paths: list[list[tuple[int, int]]] = [[] for _ in range(s.size)]
    for n in range(s.size):  # parents come before children (pre-order)
        for k, c in enumerate(s.children[n]):
            paths[c] = paths[n] + [(n, k)] if wanted[n] else paths[n]
    value = [paths[node] for node in s.node_of_task]
    problem.cache[key] = value
    return value


def _labeller(path: str) -> Callable[[int], str]:
    return lambda i: f"{path}/children[{i}]"


def serialisation(
    problem: Problem, orders: Sequence[Sequence[int]], *, every_conc: bool = True
) -> Serialisation:
    """The wrappers that the units' ``orders`` (vehicle tasks, in execution order) add.

    ``every_conc`` False leaves out concs whose wrappers change no time (see ``conc_paths``):
    what the evaluator needs.
    """
    paths = conc_paths(problem, every_conc)
    runs: dict[int, dict[int, list[int]]] = {}
    for u, order in enumerate(orders):
        for t in order:
            for n, k in paths[t]:
                runs.setdefault(n, {}).setdefault(u, []).append(k)
    out = Serialisation()
    s = problem.structure
    names = problem.unit_names
    for n in sorted(runs):
        groups, problems = order_children(
            [(names[u], children) for u, children in runs[n].items()], _labeller(s.path(n))
        )
        out.problems.extend(problems)
        kids = s.children[n]
        out.wraps.extend((n, [kids[i] for i in group]) for group in groups)
    return out
