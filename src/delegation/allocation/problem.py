"""The allocation problem: which tasks, which units may take them, what it costs, what must wait.

Built once from (tree, fleet snapshot, cost tables) and shared by every strategy and by the schedule
evaluator, so that all of them mean the same thing (docs/plan.md §2). Tasks are the tree's leaves in
tree order; ``allowed[u, t]`` already folds in capability, fixed units (``/dji0``) and aliases
(every unit of an alias group must be able to take every task of the group).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from delegation.tst import ExecUnitKind, TstNode, classify_execunit, is_vehicle_task, walk, where

if TYPE_CHECKING:
    from delegation.fleet import UnitState


class TablesLike(Protocol):
    """What the problem needs from ``delegation.costs.CostTables`` (see CONTRACTS.md): kept as a
    Protocol so tests can hand-make tables; read-only, so the frozen ``CostTables`` satisfies it."""

    @property
    def unit_xy(self) -> np.ndarray: ...
    @property
    def home_xy(self) -> np.ndarray: ...
    @property
    def start_xy(self) -> np.ndarray: ...
    @property
    def end_xy(self) -> np.ndarray: ...
    @property
    def speed(self) -> np.ndarray: ...
    @property
    def work_time(self) -> np.ndarray: ...
    @property
    def work_distance(self) -> np.ndarray: ...
    @property
    def travels(self) -> np.ndarray: ...
    @property
    def capable(self) -> np.ndarray: ...
    @property
    def endurance(self) -> np.ndarray: ...

    def reason(self, u: int, t: int) -> str | None: ...


@dataclass(frozen=True, slots=True)
class TaskRef:
    """One task (leaf) of the tree, as the planner sees it."""

    index: int
    path: str
    node: TstNode
    vehicle: bool
    kind: ExecUnitKind
    ref: str  # the fixed unit's name or the alias; "" when free

    @property
    def name(self) -> str:
        return self.node.name

    @property
    def uuid(self) -> str:
        return self.node.node_uuid or ""

    @property
    def label(self) -> str:
        return where(self.path, self.node)


@dataclass(frozen=True, slots=True)
class Structure:
    """The tree's control structure, flattened: what activates what (seq/conc)."""

    kinds: tuple[str, ...]  # per tree node: "seq", "conc" or "task"
    children: tuple[tuple[int, ...], ...]
    task_of_node: tuple[int, ...]  # task index, or -1 for control nodes
    node_of_task: tuple[int, ...]
    paths: tuple[str, ...] = ()  # per tree node, ``root/children[2]`` (for messages)

    @property
    def size(self) -> int:
        return len(self.kinds)

    def path(self, n: int) -> str:
        return self.paths[n] if n < len(self.paths) else f"node {n}"


def flatten_tree(root: TstNode) -> tuple[Structure, list[tuple[str, TstNode]]]:
    """The structure of ``root`` (node 0) and its leaves (path, node) in tree order."""
    kinds: list[str] = []
    paths: list[str] = []
    children: list[list[int]] = []
    task_of_node: list[int] = []
    node_of_task: list[int] = []
    leaves: list[tuple[str, TstNode]] = []
    index_of: dict[str, int] = {}
    for path, node in walk(root):
        i = len(kinds)
        index_of[path] = i
        paths.append(path)
        parent = path.rsplit("/", 1)[0] if "/" in path else None
        if parent is not None:
            children[index_of[parent]].append(i)
        children.append([])
        if node.is_control:
            kinds.append(node.name)
            task_of_node.append(-1)
        else:
            kinds.append("task")
            task_of_node.append(len(node_of_task))
            node_of_task.append(i)
            leaves.append((path, node))
    structure = Structure(
        tuple(kinds), tuple(tuple(c) for c in children), tuple(task_of_node), tuple(node_of_task),
        tuple(paths),
    )
    return structure, leaves


def precedence(structure: Structure, n_tasks: int) -> np.ndarray:
    """``before[a, b]``: task a must end before task b is activated (a in an earlier seq child)."""
    before = np.zeros((n_tasks, n_tasks), dtype=bool)
    tasks_under: list[list[int]] = [[] for _ in range(structure.size)]
    for n in range(structure.size - 1, -1, -1):  # children have higher indices (pre-order)
        t = structure.task_of_node[n]
        if t >= 0:
            tasks_under[n] = [t]
        else:
            tasks_under[n] = [x for c in structure.children[n] for x in tasks_under[c]]
    for n in range(structure.size):
        if structure.kinds[n] != "seq":
            continue
        # One block per seq: a before b where a's child comes before b's (a block per child
        # pair cost a numpy call each).
        under = tasks_under[n]
        if not under:
            continue
        rank = np.array([k for k, c in enumerate(structure.children[n])
                         for _ in tasks_under[c]], dtype=int)
        block = np.ix_(under, under)
        before[block] |= rank[:, None] < rank[None, :]
    return before


#: Largest task count for which ``Problem.lca_depth`` keeps a (T, T) table (8 bytes a pair).
LCA_TABLE_TASKS = 1500


@dataclass
class Problem:
    """Everything a strategy needs: tasks, units, costs (s, m), who may take what, the tree."""

    tasks: list[TaskRef]
    unit_names: list[str]
    unit_xy: np.ndarray  # (U,2)
    home_xy: np.ndarray  # (U,2), NaN rows: no home
    start_xy: np.ndarray  # (T,2), NaN rows for tasks done in place
    end_xy: np.ndarray  # (T,2)
    speed: np.ndarray  # (U,T) m/s
    work_time: np.ndarray  # (U,T) s
    work_distance: np.ndarray  # (U,T) m
    travels: np.ndarray  # (T,) bool (go-home: True; see ``points_for``)
    home_speed: np.ndarray  # (U,) m/s for the way home
    endurance: np.ndarray  # (U,) s, inf where unknown
    allowed: np.ndarray  # (U,T) bool
    reasons: list[str | None]  # per task: why no unit may take it
    alias_groups: list[list[int]]
    structure: Structure
    to_home: np.ndarray | None = None  # (T,) bool: go-home (start and end are the unit's home)
    ready: np.ndarray | None = None  # (U,) s until each unit is free (None: all free now)
    #: Plan for the old instantiation rule (``schedule.evaluate`` wraps conc children sharing a
    #: unit whole in a seq) instead of the precedence graph: for benchmarks comparing the two.
    wrap_subtrees: bool = False
    #: (U,T,2) where each unit starts and ends each task when that differs between units (a
    #: search: each unit sweeps at its own width, DESIGN 3.11); None when every unit's points are
    #: ``start_xy``/``end_xy`` (those stay the reference points of heuristics).
    unit_start_xy: np.ndarray | None = None
    unit_end_xy: np.ndarray | None = None
    #: Search task -> (U, K, 6) the ways each unit may fly its sweep (``CostTables.
    #: sweep_ways``): the schedule flies the one that costs least from where the unit is.
    sweep_ways: dict[int, np.ndarray] = field(default_factory=dict)
    _before: np.ndarray | None = field(default=None, repr=False)
    cache: dict[str, Any] = field(default_factory=dict, repr=False)  # derived data, per problem

    @property
    def n_units(self) -> int:
        return len(self.unit_names)

    @property
    def n_tasks(self) -> int:
        return len(self.tasks)

    @property
    def vehicle(self) -> np.ndarray:
        return np.array([t.vehicle for t in self.tasks], dtype=bool)

    @property
    def has_home(self) -> np.ndarray:
        return ~np.isnan(self.home_xy[:, 0]) if self.n_units else np.zeros(0, dtype=bool)

    @property
    def before(self) -> np.ndarray:
        """(T,T) precedence matrix, computed on first use."""
        if self._before is None:
            self._before = precedence(self.structure, self.n_tasks)
        return self._before

    @property
    def flat(self) -> bool:
        """True when every task is activated at mission start (no seq between tasks)."""
        counts = self._task_counts()
        for n, kind in enumerate(self.structure.kinds):
            if kind == "seq" and sum(1 for c in self.structure.children[n] if counts[c]) > 1:
                return False
        return True

    @property
    def plain(self) -> bool:
        """True when the tree is a conc of tasks in effect: flat, and no child of a conc holds more
        than one task. Then a unit's order alone says when its tasks run (no whole subtrees to
        serialise, see ``serialise``), so routing on a unit's own route is exact."""
        value = self.cache.get("plain")
        if value is None:
            counts = self._task_counts()
            s = self.structure
            value = self.flat
            for n, kind in enumerate(s.kinds):
                holding = [c for c in s.children[n] if counts[c]]
                if kind != "task" and len(holding) > 1 and any(counts[c] > 1 for c in holding):
                    value = False
                    break
            self.cache["plain"] = value
        return bool(value)

    def ancestry(self) -> np.ndarray:
        """(T, D) tree nodes from the root down to each task (the task's own node last), padded
        with -1: two tasks' lowest common ancestor is where their rows stop agreeing."""
        value = self.cache.get("ancestry")
        if value is None:
            s = self.structure
            parent = [-1] * s.size
            for n in range(s.size):
                for c in s.children[n]:
                    parent[c] = n
            chains = []
            for n in s.node_of_task:
                chain = [n]
                while parent[chain[-1]] >= 0:
                    chain.append(parent[chain[-1]])
                chains.append(chain[::-1])
            depth = max((len(c) for c in chains), default=1)
            value = np.full((len(chains), depth), -1, dtype=np.int64)
            for t, chain in enumerate(chains):
                value[t, : len(chain)] = chain
            self.cache["ancestry"] = value
        return np.asarray(value)

    def lca_depth(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Depth (root = 1) of the lowest common ancestor of tasks ``a`` and ``b`` (broadcast);
        for ``a == b`` the task's own depth + 1.

        Up to ``LCA_TABLE_TASKS`` tasks a (T, T) table made on first use answers (the auction
        asks after every award); above, the ancestry rows are compared each time.
        """
        table = self._lca_table()
        if table is not None:
            return np.asarray(table[np.asarray(a, dtype=int), np.asarray(b, dtype=int)])
        anc = self.ancestry()
        same = anc[np.asarray(a, dtype=int)] == anc[np.asarray(b, dtype=int)]
        return np.asarray(np.cumprod(same, axis=-1).sum(axis=-1))

    def lca_rows(self) -> list[list[int]] | None:
        """The ``lca_depth`` table as lists (None above ``LCA_TABLE_TASKS`` tasks): for the
        auction's plain-Python passes over small tables (``routes``), made once."""
        rows = self.cache.get("lca-rows")
        if rows is None:
            table = self._lca_table()
            if table is None:
                return None
            rows = self.cache["lca-rows"] = table.tolist()
        return rows  # type: ignore[no-any-return]

    def _lca_table(self) -> np.ndarray | None:
        """(T, T) ``lca_depth`` of every pair (None above ``LCA_TABLE_TASKS`` tasks): the rows'
        agreeing prefix, counted one depth level at a time (T x T booleans, not T x T x D)."""
        if self.n_tasks > LCA_TABLE_TASKS:
            return None
        value = self.cache.get("lca")
        if value is None:
            anc = self.ancestry()
            agree = np.ones((self.n_tasks, self.n_tasks), dtype=bool)
            value = np.zeros((self.n_tasks, self.n_tasks), dtype=np.int64)
            for d in range(anc.shape[1]):
                agree &= anc[:, d][:, None] == anc[:, d][None, :]
                value += agree
            self.cache["lca"] = value
        return np.asarray(value)

    def _task_counts(self) -> list[int]:
        s = self.structure
        counts = [0] * s.size
        for n in range(s.size - 1, -1, -1):
            counts[n] = 1 if s.task_of_node[n] >= 0 else sum(counts[c] for c in s.children[n])
        return counts

    def home_task(self) -> np.ndarray:
        return self.to_home if self.to_home is not None else np.zeros(self.n_tasks, dtype=bool)

    def points_for(
        self, u: int, cand: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Start (C,2), end (C,2) and travels (C,) of tasks ``cand`` when unit ``u`` does them.

        ``go-home`` starts and ends at the unit's home (in place when it has none); rows of tasks
        done in place are 0 (never used: they do not travel).
        """
        cand = np.asarray(cand, dtype=int).reshape(-1)
        if self.unit_start_xy is not None and self.unit_end_xy is not None:
            start, end = self.unit_start_xy[u, cand], self.unit_end_xy[u, cand]
        else:
            start = self.start_xy[cand]  # (indexing by an array copies)
            end = self.end_xy[cand]
        travels = self.travels[cand]
        if self._any_home_task():
            home = self.home_task()[cand]
            if home.any():
                if self.has_home[u]:
                    start[home] = self.home_xy[u]
                    end[home] = self.home_xy[u]
                    travels[home] = True
                else:
                    travels[home] = False
        if not travels.all():
            start[~travels] = 0.0
            end[~travels] = 0.0
        return start, end, travels

    def start_at(self, units: np.ndarray | int, tasks: np.ndarray | int) -> np.ndarray:
        """(..., 2) where ``units`` start ``tasks`` (broadcast), go-home and in-place aside:
        the per-unit points where they differ, else the task's."""
        if self.unit_start_xy is None:
            return np.asarray(self.start_xy[np.broadcast_arrays(units, tasks)[1]])
        return np.asarray(self.unit_start_xy[units, tasks])

    def end_at(self, units: np.ndarray | int, tasks: np.ndarray | int) -> np.ndarray:
        """(..., 2) where ``units`` end ``tasks`` (broadcast), as ``start_at``."""
        if self.unit_end_xy is None:
            return np.asarray(self.end_xy[np.broadcast_arrays(units, tasks)[1]])
        return np.asarray(self.unit_end_xy[units, tasks])

    def unit_points(self) -> tuple[np.ndarray, np.ndarray]:
        """(U,T,2) start and end of every task for every unit (``start_at``/``end_at``)."""
        if self.unit_start_xy is not None and self.unit_end_xy is not None:
            return self.unit_start_xy, self.unit_end_xy
        shape = (self.n_units, self.n_tasks, 2)
        return (np.broadcast_to(self.start_xy[None], shape),
                np.broadcast_to(self.end_xy[None], shape))

    def _any_home_task(self) -> bool:
        value = self.cache.get("any-home-task")
        if value is None:
            value = self.cache["any-home-task"] = bool(self.home_task().any())
        return bool(value)

    def alias_of(self) -> np.ndarray:
        """(T,) index of each task's alias group, -1 when none."""
        out = np.full(self.n_tasks, -1, dtype=int)
        for g, members in enumerate(self.alias_groups):
            out[members] = g
        return out


def _summarise(reasons: dict[str, list[str]]) -> str:
    """``dji0, dji1: does not offer search-area; usv0: is not alive ...`` (names shortened)."""
    parts = []
    for text, names in reasons.items():
        shown = ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")
        parts.append(f"{shown}: {text}")
    return "; ".join(parts)


def build_problem(
    tree: TstNode, units: Sequence[UnitState], tables: TablesLike | None = None
) -> Problem:
    """The problem for ``tree`` (leaves in tree order, uuids as given) and ``units``.

    ``tables`` are built with ``delegation.costs.cost_tables`` unless given.
    """
    structure, leaves = flatten_tree(tree)
    if tables is None:
        from delegation.costs import cost_tables

        tables = cost_tables(list(units), [node for _, node in leaves])
    names = [u.name for u in units]
    home_speed = np.array([float(u.speeds.get("standard", 1.0)) for u in units], dtype=float)
    problem = problem_from_arrays(
        structure,
        leaves,
        names,
        tables=tables,
        home_speed=home_speed,
    )
    if any(u.available_at > 0.0 for u in units):
        problem.ready = np.array([max(0.0, u.available_at) for u in units], dtype=float)
    return problem


def problem_from_arrays(
    structure: Structure,
    leaves: list[tuple[str, TstNode]],
    unit_names: list[str],
    *,
    tables: TablesLike,
    home_speed: np.ndarray,
) -> Problem:
    """Assemble a problem from the flattened tree and cost tables (tests use hand-made tables)."""
    n_units, n_tasks = len(unit_names), len(leaves)
    capable = np.asarray(tables.capable, dtype=bool).reshape(n_units, n_tasks)
    allowed = capable.copy()
    reasons: list[str | None] = [None] * n_tasks
    tasks: list[TaskRef] = []
    groups: dict[str, list[int]] = {}
    unit_index = {name: i for i, name in enumerate(unit_names)}
    why: list[dict[str, list[str]]] = [{} for _ in range(n_tasks)]
    for t, (path, node) in enumerate(leaves):
        try:
            kind, ref = classify_execunit(node.execunit)
        except TypeError:
            kind, ref = ExecUnitKind.FREE, ""
        tasks.append(TaskRef(t, path, node, is_vehicle_task(node.name), kind, ref))
        if kind is ExecUnitKind.FIXED:
            u = unit_index.get(ref)
            mask = np.zeros(n_units, dtype=bool)
            if u is None:
                reasons[t] = f"fixed unit /{ref} is not known to the fleet"
            else:
                mask[u] = True
            allowed[:, t] &= mask
        elif kind is ExecUnitKind.ALIAS:
            groups.setdefault(ref, []).append(t)
    for t in range(n_tasks):
        if reasons[t] is None and not allowed[:, t].any():
            for u in range(n_units):
                if tasks[t].kind is ExecUnitKind.FIXED and unit_names[u] != tasks[t].ref:
                    continue
                text = tables.reason(u, t) or "cannot take it"
                text = text.removeprefix(unit_names[u] + " ")  # the name is listed separately
                why[t].setdefault(text, []).append(unit_names[u])
            reasons[t] = (
                _summarise(why[t]) if why[t] else "no live unit in the fleet"
            )
    unit_start, unit_end = _unit_points(tables, n_units, n_tasks)
    alias_groups = list(groups.values())
    for alias, members in groups.items():
        joint = np.asarray(allowed[:, members].all(axis=1), dtype=bool)
        if not joint.any():
            for t in members:
                if reasons[t] is None:
                    reasons[t] = f"no single unit can take every task of alias {alias!r}"
        allowed[:, members] = joint[:, None]
    return Problem(
        tasks=tasks,
        unit_names=list(unit_names),
        unit_xy=np.asarray(tables.unit_xy, dtype=float).reshape(n_units, 2),
        home_xy=np.asarray(tables.home_xy, dtype=float).reshape(n_units, 2),
        start_xy=np.asarray(tables.start_xy, dtype=float).reshape(n_tasks, 2),
        end_xy=np.asarray(tables.end_xy, dtype=float).reshape(n_tasks, 2),
        speed=np.asarray(tables.speed, dtype=float).reshape(n_units, n_tasks),
        work_time=np.asarray(tables.work_time, dtype=float).reshape(n_units, n_tasks),
        work_distance=np.asarray(tables.work_distance, dtype=float).reshape(n_units, n_tasks),
        travels=_travels(tables, n_tasks),
        home_speed=np.asarray(home_speed, dtype=float).reshape(n_units),
        endurance=np.asarray(tables.endurance, dtype=float).reshape(n_units),
        allowed=allowed,
        reasons=reasons,
        alias_groups=alias_groups,
        structure=structure,
        to_home=_to_home(tables, n_tasks),
        unit_start_xy=unit_start,
        unit_end_xy=unit_end,
        sweep_ways=dict(getattr(tables, "sweep_ways", None) or {}),
    )


def _unit_points(tables: Any, n_units: int, n_tasks: int
                 ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``unit_start_xy``/``unit_end_xy`` from tables that have them and where some unit's
    points differ from the task's (else nothing: the fast uniform paths stay)."""
    start = getattr(tables, "unit_start_xy", None)
    end = getattr(tables, "unit_end_xy", None)
    if start is None or end is None or not n_units or not n_tasks:
        return None, None
    start = np.asarray(start, dtype=float).reshape(n_units, n_tasks, 2)
    end = np.asarray(end, dtype=float).reshape(n_units, n_tasks, 2)
    ref_s = np.asarray(tables.start_xy, dtype=float).reshape(1, n_tasks, 2)
    ref_e = np.asarray(tables.end_xy, dtype=float).reshape(1, n_tasks, 2)
    same = np.allclose(start, ref_s, equal_nan=True) and np.allclose(end, ref_e, equal_nan=True)
    return (None, None) if same else (start, end)


def _to_home(tables: Any, n_tasks: int) -> np.ndarray:
    value = getattr(tables, "to_home", None)
    if value is None:
        return np.zeros(n_tasks, dtype=bool)
    return np.asarray(value, dtype=bool).reshape(n_tasks)


def _travels(tables: Any, n_tasks: int) -> np.ndarray:
    travels = np.asarray(tables.travels, dtype=bool).reshape(n_tasks).copy()
    start = np.asarray(tables.start_xy, dtype=float).reshape(n_tasks, 2)
    end = np.asarray(tables.end_xy, dtype=float).reshape(n_tasks, 2)
    fixed = np.isfinite(start).all(axis=1) & np.isfinite(end).all(axis=1)
    travels &= fixed | _to_home(tables, n_tasks)
    return travels
