"""CP-SAT sub-model: conc children that share a unit run one after another as whole subtrees.

One total order per component of children that share units, as ``serialise`` derives it
(docs/protocol.md §8). Exact for concs with at most ``CP_EXACT_CHILDREN`` children holding tasks:

- ``has``: a unit has a task under a child;
- ``share``: two children have a unit in common;
- ``together``: same component (closed under sharing);
- ``prec``: a total order on each component, transitive, consistent with every unit's route;
- the tie rule: a child j runs before an earlier one i (in the tree) only if i waits for j (they
  share a unit) or for a child that shares a unit with i, runs before i and after j. So the order is
  the topological order that takes the child first in the tree among those free to go.

Extra ``together`` pairs only add constraints, so they never beat the true model. Larger concs are
relaxed (the main model keeps each unit's consecutive subtrees one after another).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from delegation.allocation.problem import Problem
from delegation.allocation.schedule import Schedule
from delegation.allocation.serialise import serialisation

if TYPE_CHECKING:
    from ortools.sat.python import cp_model

#: Concs with at most this many children holding tasks get the exact subtree-serialisation model.
CP_EXACT_CHILDREN = 8

Key = tuple[int, int, int]


@dataclass
class WrapVars:
    """The serialisation model's variables, per conc: ``prec[n, i, j]`` child i runs before j."""

    has: dict[Key, Any] = field(default_factory=dict)  # (conc, child, unit)
    share: dict[Key, Any] = field(default_factory=dict)  # (conc, i, j), i < j
    prec: dict[Key, Any] = field(default_factory=dict)  # (conc, i, j)
    together: dict[Key, Any] = field(default_factory=dict)  # (conc, i, j), i < j

    def all(self) -> list[Any]:
        return [*self.has.values(), *self.share.values(), *self.prec.values(),
                *self.together.values()]


@dataclass(frozen=True)
class SubtreeInputs:
    """What the sub-model reads from the main CP-SAT model."""

    problem: Problem
    paths: list[dict[int, int]]  # per task: conc node -> which of its children holds the task
    x: dict[tuple[int, int], Any]  # (task, unit) -> the task goes to the unit
    act: list[Any]  # per tree node: when it is activated
    done: list[Any]  # per tree node: when it ends
    chained: dict[int, list[tuple[int, int, Any]]]  # conc -> (child, next child, route arc)
    units: list[int]  # units that may take vehicle tasks in the model
    tasks: set[int]  # the vehicle tasks of the model


def split_at(paths: list[dict[int, int]], r: int, t: int) -> tuple[int, int, int] | None:
    """(conc, child of r, child of t) where r and t are under different children of a conc
    whose children are subtrees (their lowest common ancestor), else None."""
    mine = paths[r]
    for n, kq in paths[t].items():
        kp = mine.get(n)
        if kp is not None and kp != kq:
            return n, kp, kq
    return None


def tasks_under(problem: Problem, tasks: set[int]) -> dict[int, set[int]]:
    """Control nodes (not the root) holding two or more of ``tasks``, with those tasks."""
    s = problem.structure
    under: list[set[int]] = [set() for _ in range(s.size)]
    for n in range(s.size - 1, -1, -1):
        t = s.task_of_node[n]
        if t >= 0:
            if t in tasks:
                under[n] = {t}
        else:
            under[n] = set().union(*(under[c] for c in s.children[n])) if s.children[n] else set()
    return {n: under[n] for n in range(1, s.size)
            if s.task_of_node[n] < 0 and len(under[n]) >= 2}


def subtree_model(model: cp_model.CpModel, inputs: SubtreeInputs) -> tuple[WrapVars, int]:
    """Add the sub-model; returns its variables and how many concs were relaxed."""
    wv = WrapVars()
    relaxed = 0
    children_of: dict[int, dict[int, list[int]]] = {}
    for t in inputs.tasks:
        for n, k in inputs.paths[t].items():
            children_of.setdefault(n, {}).setdefault(k, []).append(t)
    for n, held in sorted(children_of.items()):
        if len(held) < 2:
            continue
        if len(held) > CP_EXACT_CHILDREN:
            relaxed += 1
            continue
        _exact_conc(model, inputs, wv, n, held)
    return wv, relaxed


def _exact_conc(
    model: cp_model.CpModel, inputs: SubtreeInputs, wv: WrapVars, n: int,
    held: dict[int, list[int]],
) -> None:
    """The exact model of conc ``n`` whose children ``held`` (child -> its tasks) hold tasks."""
    ks = sorted(held)
    _has_vars(model, inputs, wv, n, held)
    for i, j in itertools.combinations(ks, 2):
        _pair_vars(model, inputs, wv, n, i, j)
    _transitive(model, wv, n, ks)
    # A unit's route from a task under child p to one under q runs p before q.
    for kp, kq, lit in inputs.chained.get(n, []):
        model.add_implication(lit, wv.prec[n, kp, kq])
    _tie_rule(model, wv, n, ks)


def _has_vars(
    model: cp_model.CpModel, inputs: SubtreeInputs, wv: WrapVars, n: int,
    held: dict[int, list[int]],
) -> None:
    """``has[n, k, u]``: unit u has a task under child k."""
    for k in sorted(held):
        for u in inputs.units:
            lits = [inputs.x[t, u] for t in held[k] if (t, u) in inputs.x]
            if lits:
                var = model.new_bool_var(f"has{n}_{k}_{u}")
                model.add_max_equality(var, lits)
                wv.has[n, k, u] = var


def _pair_vars(
    model: cp_model.CpModel, inputs: SubtreeInputs, wv: WrapVars, n: int, i: int, j: int
) -> None:
    """Children i < j: ``share`` (a unit in common) puts them ``together``; together, exactly
    one runs before the other, and the later one starts when the earlier one has ended."""
    act, done, kids = inputs.act, inputs.done, inputs.problem.structure.children[n]
    both = []
    for u in inputs.units:
        a, b = wv.has.get((n, i, u)), wv.has.get((n, j, u))
        if a is None or b is None:
            continue
        lit = model.new_bool_var(f"both{n}_{i}_{j}_{u}")
        model.add_implication(lit, a)
        model.add_implication(lit, b)
        model.add_bool_or([a.Not(), b.Not(), lit])
        both.append(lit)
    if both:
        share = model.new_bool_var(f"share{n}_{i}_{j}")
        model.add_max_equality(share, both)
        wv.share[n, i, j] = share
    together = model.new_bool_var(f"together{n}_{i}_{j}")
    wv.together[n, i, j] = together
    wv.prec[n, i, j] = model.new_bool_var(f"prec{n}_{i}_{j}")
    wv.prec[n, j, i] = model.new_bool_var(f"prec{n}_{j}_{i}")
    model.add(wv.prec[n, i, j] + wv.prec[n, j, i] == together)
    if both:
        model.add_implication(wv.share[n, i, j], together)
    model.add(act[kids[j]] >= done[kids[i]]).only_enforce_if(wv.prec[n, i, j])
    model.add(act[kids[i]] >= done[kids[j]]).only_enforce_if(wv.prec[n, j, i])


def _transitive(model: cp_model.CpModel, wv: WrapVars, n: int, ks: list[int]) -> None:
    """``prec`` and ``together`` are transitive."""

    def tog(i: int, j: int) -> Any:
        return wv.together[n, min(i, j), max(i, j)]

    for i, j, m in itertools.permutations(ks, 3):
        model.add_bool_or([wv.prec[n, i, m].Not(), wv.prec[n, m, j].Not(), wv.prec[n, i, j]])
        if i < j:
            model.add_bool_or([tog(i, m).Not(), tog(m, j).Not(), tog(i, j)])


def _tie_rule(model: cp_model.CpModel, wv: WrapVars, n: int, ks: list[int]) -> None:
    """j (later in the tree) runs before i only if i waits for j or for a child p that shares a
    unit with i and runs after j."""
    for i, j in itertools.combinations(ks, 2):
        direct = wv.share.get((n, i, j))
        blockers = [direct] if direct is not None else []
        for p in ks:
            share = wv.share.get((n, min(p, i), max(p, i))) if p not in (i, j) else None
            if share is None:
                continue
            z = model.new_bool_var(f"block{n}_{p}_{i}_{j}")
            model.add_implication(z, share)
            model.add_implication(z, wv.prec[n, p, i])
            model.add_implication(z, wv.prec[n, j, p])
            blockers.append(z)
        model.add_bool_or([wv.prec[n, j, i].Not(), *blockers])


def hint_subtrees(model: cp_model.CpModel, problem: Problem, base: Schedule, wv: WrapVars) -> None:
    """Hint the serialisation variables from the auction's schedule."""
    s = problem.structure
    order = serialisation(problem, base.orders, every_conc=False)
    place: dict[tuple[int, int], tuple[int, int]] = {}
    for w, (n, kids) in enumerate(order.wraps):
        position = {child: k for k, child in enumerate(s.children[n])}
        for rank, child in enumerate(kids):
            place[n, position[child]] = (w, rank)
    for (n, i, j), lit in wv.prec.items():
        a, b = place.get((n, i)), place.get((n, j))
        model.add_hint(lit, int(a is not None and b is not None and a[0] == b[0] and a[1] < b[1]))
    for (n, i, j), lit in wv.together.items():
        a, b = place.get((n, i)), place.get((n, j))
        model.add_hint(lit, int(a is not None and b is not None and a[0] == b[0]))
