"""Checks every plan must pass, computed from the plan itself (not from the strategy's state).

Used by the tests on every scenario and strategy, and cheap enough to run in the service. Times
are recomputed from the cost tables and the plan's own routes, so a strategy that got its
bookkeeping wrong is caught here; and by running the instantiated tree itself (its seq/conc
structure as the engine runs it), so that a plan's times are what executing its tree does.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from delegation.allocation.plan import Assignment, Plan
from delegation.tst import ExecUnitKind, TstNode, classify_execunit, is_vehicle_task, leaves, walk

if TYPE_CHECKING:
    from delegation.costs import CostTables
    from delegation.fleet import UnitState

TOL = 1e-6


def _close(a: float, b: float) -> bool:
    return abs(a - b) <= TOL * max(1.0, abs(a), abs(b))


def _unsafe_pairs(tst: TstNode, assigned: dict[str, Assignment]) -> list[str]:
    """Vehicle tasks of one unit that the instantiated tree could run at the same time.

    Two tasks of one unit are safe when their lowest common ancestor is a ``seq``.
    """
    ancestry: dict[str, list[tuple[str, str]]] = {}
    paths: dict[str, str] = {}
    for path, node in walk(tst):
        if not node.is_control and node.node_uuid in assigned:
            paths[node.node_uuid] = path
    nodes = dict(walk(tst))
    for uid, path in paths.items():
        parts = path.split("/")
        ancestry[uid] = [("/".join(parts[: k + 1]), nodes["/".join(parts[: k + 1])].name)
                         for k in range(len(parts) - 1)]
    per_unit: dict[str, list[str]] = {}
    for uid in ancestry:
        a = assigned[uid]
        if is_vehicle_task(a.name):
            per_unit.setdefault(a.execunit, []).append(uid)
    out = []
    for unit, uids in per_unit.items():
        for i, x in enumerate(uids):
            for y in uids[i + 1 :]:
                common = [p for p, q in zip(ancestry[x], ancestry[y], strict=False) if p == q]
                if common and common[-1][1] != "seq":
                    out.append(f"the instantiated tree can run {x} and {y} on {unit} at once")
    return out


@dataclass
class _Subject:
    """What the checks look at: the plan, the caller's tree and units, and what derives from
    them (computed once, when a check first asks)."""

    plan: Plan
    tree: TstNode
    units: Sequence[UnitState]

    @cached_property
    def planned(self) -> TstNode:
        """The caller's tree as planned: with each shared search's parts (DESIGN 3.11)."""
        return self.plan.planned if self.plan.planned is not None else self.tree

    @cached_property
    def inst_leaves(self) -> list[TstNode]:
        return leaves(self.plan.tst)

    @cached_property
    def assigned(self) -> dict[str, Assignment]:
        return {a.node_uuid: a for a in self.plan.assignments}

    @cached_property
    def per_unit(self) -> dict[str, list[Assignment]]:
        """Each unit's vehicle-task assignments, by start."""
        out: dict[str, list[Assignment]] = {}
        for a in self.plan.assignments:
            if is_vehicle_task(a.name):
                out.setdefault(a.execunit.strip("/"), []).append(a)
        for items in out.values():
            items.sort(key=lambda a: (a.start, a.end))
        return out

    @cached_property
    def routes(self) -> dict[str, list[Assignment]]:
        """Each unit's route from the plan; its assignments by start where the route does not
        list exactly its vehicle tasks."""
        out: dict[str, list[Assignment]] = {}
        for name, items in self.per_unit.items():
            route = self.listed(name)
            out[name] = route if _same_tasks(route, items) else items
        return out

    def listed(self, name: str) -> list[Assignment]:
        """The plan's route of unit ``name``: its vehicle tasks' assignments."""
        return [self.assigned[a.node_uuid] for a in self.plan.routes.get(name, [])
                if a.node_uuid in self.assigned and is_vehicle_task(a.name)]

    @cached_property
    def tables(self) -> CostTables:
        from delegation.costs import cost_tables

        return cost_tables(list(self.units), self.inst_leaves)


def _same_tasks(route: list[Assignment], items: list[Assignment]) -> bool:
    return sorted(a.node_uuid for a in route) == sorted(a.node_uuid for a in items)


def check_invariants(plan: Plan, tree: TstNode, units: Sequence[UnitState]) -> list[str]:
    """Every broken invariant as a sentence; ``[]`` when the plan is sound."""
    subject = _Subject(plan, tree, units)
    return [text for check in CHECKS for text in check(subject)]


def _tasks_kept(x: _Subject) -> list[str]:
    """The instantiated tree keeps the caller's tasks and their uuids (control nodes may be
    regrouped, docs/protocol.md §8)."""
    out = []
    original = leaves(x.planned)
    if len(original) != len(x.inst_leaves):
        out.append(f"tree has {len(original)} tasks but the plan's tree {len(x.inst_leaves)}")
    inst_uuids = {n.node_uuid for _, n in walk(x.plan.tst)}
    for node in original:
        if node.node_uuid and node.node_uuid not in inst_uuids:
            out.append(f"node-uuid {node.node_uuid} of the caller is missing from the plan's tree")
    return out


def _each_task_once(x: _Subject) -> list[str]:
    """Every task is assigned or unassigned with a reason, exactly once."""
    out = []
    plan, assigned = x.plan, x.assigned
    if len(assigned) != len(plan.assignments):
        out.append("a task is assigned twice")
    missing = {u.node_uuid for u in plan.unassigned}
    for gone in plan.unassigned:
        if not gone.reason:
            out.append(f"unassigned task {gone.node_uuid} has no reason")
        if gone.node_uuid in assigned:
            out.append(f"task {gone.node_uuid} is both assigned and unassigned")
    for leaf in x.inst_leaves:
        if leaf.node_uuid not in assigned and leaf.node_uuid not in missing:
            out.append(f"task {leaf.node_uuid} ({leaf.name}) is neither assigned nor unassigned")
    if plan.feasible != (not plan.unassigned):
        out.append("feasible does not match the unassigned list")
    return out


def _units_valid(x: _Subject) -> list[str]:
    """Each assignment: a live unit that offers the task, the one the tree names; fixed units
    and aliases hold; every control node has a unit."""
    out = []
    by_name = {u.name: u for u in x.units}
    leaf_by_uuid = {leaf.node_uuid: leaf for leaf in x.inst_leaves}
    for a in x.plan.assignments:
        found = leaf_by_uuid.get(a.node_uuid)
        unit = by_name.get(a.execunit.strip("/"))
        if found is None:
            out.append(f"assignment {a.node_uuid} is not a task of the plan's tree")
            continue
        if unit is None:
            out.append(f"{a.node_uuid} is assigned to unknown unit {a.execunit}")
            continue
        if not unit.alive:
            out.append(f"{a.node_uuid} is assigned to {a.execunit}, which is not alive")
        if found.name not in unit.tasks:
            out.append(f"{a.node_uuid} ({found.name}) is assigned to {a.execunit}, which lacks it")
        if found.execunit != a.execunit:
            out.append(f"{a.node_uuid}: tree says {found.execunit!r}, plan says {a.execunit!r}")
        if not _close(a.end, a.start + a.travel_time + a.work_time):
            out.append(f"{a.node_uuid}: end is not start + travel + work")
    return out + _fixed_and_aliases(x)


def _fixed_and_aliases(x: _Subject) -> list[str]:
    out = []
    assigned = x.assigned
    for _, node in walk(x.planned):
        if node.is_control or not node.node_uuid or node.node_uuid not in assigned:
            continue
        kind, ref = classify_execunit(node.execunit)
        if kind is ExecUnitKind.FIXED and assigned[node.node_uuid].execunit != "/" + ref:
            out.append(f"{node.node_uuid} is fixed to /{ref} but planned on "
                       f"{assigned[node.node_uuid].execunit}")
    aliases: dict[str, set[str]] = {}
    for orig in leaves(x.planned):
        kind, ref = classify_execunit(orig.execunit)
        hit = assigned.get(orig.node_uuid or "")
        if kind is ExecUnitKind.ALIAS and hit is not None:
            aliases.setdefault(ref, set()).add(hit.execunit)
    for alias, chosen in aliases.items():
        if len(chosen) > 1:
            out.append(f"alias {alias!r} is split over {', '.join(sorted(chosen))}")
    for path, node in walk(x.plan.tst):
        unit_text = node.execunit if isinstance(node.execunit, str) else ""
        if node.is_control and not unit_text.startswith("/"):
            out.append(f"control node {path} has no unit")
    return out


def _no_overlap(x: _Subject) -> list[str]:
    """No unit runs two vehicle tasks at once."""
    out = []
    for name, items in x.per_unit.items():
        for p, q in itertools.pairwise(items):
            if q.start < p.end - TOL * max(1.0, p.end):
                out.append(f"{name} runs {p.node_uuid} and {q.node_uuid} at the same time")
    return out


def _source_kept(x: _Subject) -> list[str]:
    """The plan's source is the caller's tree (same shape, names, uuids)."""
    out: list[str] = []
    if x.plan.source is None:
        return out
    mine = list(walk(x.tree))
    theirs = list(walk(x.plan.source))
    if len(mine) != len(theirs):
        out.append("the plan's source tree does not have the caller's shape")
    for (path, ours), (_, kept) in zip(mine, theirs, strict=False):
        if ours.name != kept.name or len(ours.children) != len(kept.children):
            out.append(f"{path}: the plan's source tree differs from the caller's")
            break
        if ours.node_uuid and ours.node_uuid != kept.node_uuid:
            out.append(f"{path}: node-uuid {ours.node_uuid} was not kept")
    return out


def _planned_source(x: _Subject) -> TstNode:
    """The tree the plan's order refers to: the planned tree (shared searches' parts), else the
    plan's source, else the tree sent."""
    for tree in (x.plan.planned, x.plan.source):
        if tree is not None:
            return tree
    return x.plan.tst


def _seq_order(x: _Subject) -> list[str]:
    """The instantiated tree never runs two tasks of a unit at once; the source's seq order
    holds in the plan's times."""
    out = _unsafe_pairs(x.plan.tst, x.assigned)
    source = _planned_source(x)
    for path, node in walk(source):
        if node.name != "seq":
            continue
        ended = -math.inf
        for k, child in enumerate(node.children):
            items = [x.assigned[n.node_uuid] for n in leaves(child) if n.node_uuid in x.assigned]
            if items and min(a.start for a in items) < ended - TOL * max(1.0, ended):
                out.append(f"{path}/children[{k}] starts before its predecessor ended")
            if items:
                ended = max(ended, max(a.end for a in items))
    return out


def _precedences_kept(x: _Subject) -> list[str]:
    """The sent tree's order contains every precedence of the plan: the caller's seq order and
    each unit's route."""
    from delegation.allocation.sent_tree import missing_precedences

    source = _planned_source(x)
    routes = {name: [a.node_uuid for a in items] for name, items in x.routes.items()}
    return missing_precedences(source, x.plan.tst, routes)


def _routes_exact(x: _Subject) -> list[str]:
    """Each unit's route (its order; the plan's assignments in it) holds exactly its vehicle
    tasks."""
    return [f"the route of {name} does not list exactly its vehicle tasks"
            for name, items in x.per_unit.items() if not _same_tasks(x.listed(name), items)]


def _times_and_totals(x: _Subject) -> list[str]:
    """Times agree with distances and speeds; battery holds; totals add up."""
    out: list[str] = []
    if not (x.inst_leaves and x.units):
        return out
    plan, unit_list, tables = x.plan, list(x.units), x.tables
    index = {n.node_uuid: t for t, n in enumerate(x.inst_leaves)}
    total_time = sum(a.travel_time + a.work_time for a in plan.assignments)
    total_distance = sum(a.distance for a in plan.assignments)
    latest = max((a.end for a in plan.assignments), default=0.0)
    unit_index = {u.name: i for i, u in enumerate(unit_list)}
    for name, items in x.routes.items():
        u = unit_index[name]
        here = tables.unit_xy[u]
        spent = 0.0
        for a in items:
            t = index[a.node_uuid]
            out.extend(_leg_matches(a, tables, u, t, here))
            end = tables.way_for(u, t, here)[1]
            here = here if end is None else end
            spent += a.travel_time + a.work_time
        if unit_list[u].home is not None:
            back = float(np.hypot(*(tables.home_xy[u] - here)))
            leg = back / float(unit_list[u].speeds["standard"])
            spent += leg
            total_time += leg
            total_distance += back
            latest = max(latest, items[-1].end + leg)
        remaining = unit_list[u].remaining_endurance
        if remaining is not None and spent > remaining * (1 + TOL) + TOL:
            out.append(f"{name} needs {spent:.0f} s but has {remaining:.0f} s of endurance")
    if not _close(plan.total_time, total_time):
        out.append(f"total-time {plan.total_time:.3f} is not the sum {total_time:.3f}")
    if not _close(plan.total_distance, total_distance):
        out.append(f"total-distance {plan.total_distance:.1f} is not the sum "
                   f"{total_distance:.1f}")
    if not _close(plan.makespan, latest):
        out.append(f"makespan {plan.makespan:.3f} is not the last end {latest:.3f}")
    return out


def _leg_matches(
    a: Assignment, tables: CostTables, u: int, t: int, here: np.ndarray
) -> list[str]:
    """Task ``t`` of unit ``u``, which comes from ``here``: its travel, work and distance (a
    search's as flown the way that costs least from there, ``CostTables.way_for``)."""
    out = []
    start, _, work, work_m = tables.way_for(u, t, here)
    d = 0.0 if start is None else float(np.hypot(*(start - here)))
    speed = float(tables.speed[u, t])
    if not _close(a.travel_time, d / speed):
        out.append(f"{a.node_uuid}: travel time {a.travel_time:.3f} s does not match "
                   f"{d:.1f} m at {speed} m/s")
    if not _close(a.work_time, work):
        out.append(f"{a.node_uuid}: work time {a.work_time:.3f} s is not the task's "
                   f"{work:.3f} s")
    if not _close(a.distance, d + work_m):
        out.append(f"{a.node_uuid}: distance {a.distance:.1f} m does not match")
    return out


def _tree_runs(x: _Subject) -> list[str]:
    """Running the instantiated tree gives the plan's times."""
    if not (x.inst_leaves and x.units):
        return []
    return _run_the_tree(x.plan.tst, x.assigned, x.routes, _durations(x))


def _durations(x: _Subject) -> dict[str, float]:
    """Travel + work per task, from the cost tables and the routes."""
    tables = x.tables
    index = {n.node_uuid: t for t, n in enumerate(x.inst_leaves)}
    unit_index = {u.name: i for i, u in enumerate(x.units)}
    duration: dict[str, float] = {}
    for a in x.plan.assignments:
        u = unit_index.get(a.execunit.strip("/"))
        t = index.get(a.node_uuid)
        if u is not None and t is not None and not is_vehicle_task(a.name):
            duration[a.node_uuid] = float(tables.work_time[u, t])
    for name, items in x.routes.items():
        u = unit_index[name]
        here = tables.unit_xy[u]
        for a in items:
            t = index[a.node_uuid]
            start, end, work, _ = tables.way_for(u, t, here)
            d = 0.0 if start is None else float(np.hypot(*(start - here)))
            duration[a.node_uuid] = d / float(tables.speed[u, t]) + work
            here = here if end is None else end
    return duration


#: Every check, in the order its sentences are reported.
#: How far the union of a shared search's parts may be from its area (DESIGN 3.11: 0.5 %).
COVER_TOL = 0.005


def _shared_searches(x: _Subject) -> list[str]:
    """Each shared search's parts lie inside its area and cover it (union within 0.5 %, overlap
    within 0.5 %), each part on the unit it was cut for (DESIGN 3.11)."""
    if not x.plan.shared or x.plan.source is None:
        return []
    from delegation.allocation.sharing import region_of
    from delegation.costs import search_polygons_xy
    from delegation.geo import GeoPoint, LocalFrame

    originals = {n.node_uuid: n for _, n in walk(x.plan.source)}
    parts = {n.node_uuid: n for n in leaves(x.planned)}
    out: list[str] = []
    for search in x.plan.shared:
        node = originals.get(search.node_uuid)
        if node is None:
            out.append(f"shared search {search.node_uuid} is not in the caller's tree")
            continue
        pts = [GeoPoint.model_validate(p) for p in _geopoints(node.params)]
        frame = LocalFrame.around(pts)
        area = region_of(search_polygons_xy(node, frame))
        pieces = []
        for part in search.parts:
            leaf = parts.get(part.node_uuid)
            if leaf is None:
                out.append(f"part {part.node_uuid} of {search.node_uuid} is not in the plan")
                continue
            pieces.append(region_of(search_polygons_xy(leaf, frame)))
            got = x.assigned.get(part.node_uuid)
            if got is not None and got.execunit != "/" + part.unit:
                out.append(f"part {part.node_uuid} was cut for {part.unit}, runs on {got.execunit}")
        if not pieces:
            continue
        import shapely

        union = shapely.union_all(pieces)
        outside = float(shapely.difference(union, area).area)
        uncovered = float(shapely.difference(area, union).area)
        overlap = sum(float(p.area) for p in pieces) - float(union.area)
        for what, value in (("outside", outside), ("uncovered", uncovered), ("overlap", overlap)):
            if value > COVER_TOL * float(area.area):
                out.append(f"shared search {search.node_uuid}: {value:.0f} m2 {what} "
                           f"({value / float(area.area):.2%} of its area)")
    return out


def _geopoints(params: dict[str, object]) -> list[object]:
    """Every GeoPoint value of a search's parameters (its area(s) or centre)."""
    if "area" in params and isinstance(params["area"], list):
        return list(params["area"])
    if "areas" in params and isinstance(params["areas"], list):
        return [p for area in params["areas"] if isinstance(area, list) for p in area]
    centre = params.get("geopoint")
    return [centre[0] if isinstance(centre, list) else centre]


CHECKS: list[Callable[[_Subject], list[str]]] = [
    _tasks_kept,
    _each_task_once,
    _units_valid,
    _no_overlap,
    _source_kept,
    _seq_order,
    _precedences_kept,
    _routes_exact,
    _times_and_totals,
    _tree_runs,
    _shared_searches,
]


def _run_the_tree(
    tst: TstNode,
    assigned: dict[str, Assignment],
    routes: dict[str, list[Assignment]],
    duration: dict[str, float],
) -> list[str]:
    """Run the instantiated tree as the engine does and compare with the plan's times.

    ``seq`` activates a child when the previous one has ended, ``conc`` all children at once; a
    task starts when it is activated and its unit has ended the task before it on its route;
    it takes its ``duration`` (travel + work, from the cost tables); an unassigned task ends at
    once. Earliest times everywhere, as the engine starts what is activated.
    """
    nodes = list(walk(tst))
    at = {path: i for i, (path, _) in enumerate(nodes)}
    succ: list[list[int]] = [[] for _ in range(2 * len(nodes))]  # act(i) = 2i, fin(i) = 2i + 1
    for i, (path, node) in enumerate(nodes):
        kids = [at[f"{path}/children[{k}]"] for k in range(len(node.children))]
        succ[2 * i].append(2 * i + 1)
        if node.name == "seq" and kids:
            succ[2 * i].append(2 * kids[0])
            for a, b in itertools.pairwise(kids):
                succ[2 * a + 1].append(2 * b)
            succ[2 * kids[-1] + 1].append(2 * i + 1)
        else:
            for k in kids:
                succ[2 * i].append(2 * k)
                succ[2 * k + 1].append(2 * i + 1)
    leaf_of = {node.node_uuid: i for i, (_, node) in enumerate(nodes) if not node.is_control}
    start_node: dict[int, str] = {}  # the fin node of a task: where its time is computed
    after: list[list[int]] = [[] for _ in range(2 * len(nodes))]
    for route in routes.values():
        for p, q in itertools.pairwise(route):
            if p.node_uuid in leaf_of and q.node_uuid in leaf_of:
                after[2 * leaf_of[p.node_uuid] + 1].append(2 * leaf_of[q.node_uuid] + 1)
    for uid, i in leaf_of.items():
        if uid in assigned:
            start_node[2 * i + 1] = uid
    indeg = [0] * len(succ)
    for i in range(len(succ)):
        for j in (*succ[i], *after[i]):
            indeg[j] += 1
    value = [0.0] * len(succ)
    began: dict[str, float] = {}
    stack = [i for i, d in enumerate(indeg) if d == 0]
    done = 0
    while stack:
        i = stack.pop()
        done += 1
        uid = start_node.get(i)
        if uid is not None:
            began[uid] = value[i]
            value[i] += duration.get(uid, 0.0)
        for j in (*succ[i], *after[i]):
            value[j] = max(value[j], value[i])
            indeg[j] -= 1
            if indeg[j] == 0:
                stack.append(j)
    if done < len(succ):
        return ["the instantiated tree cannot run the routes: they wait for each other"]
    out = []
    for uid, item in assigned.items():
        if uid not in began:
            continue
        end = value[2 * leaf_of[uid] + 1]
        if not (_close(item.start, began[uid]) and _close(item.end, end)):
            out.append(
                f"{uid} ({item.name} on {item.execunit}): the instantiated tree runs it at "
                f"{began[uid]:.1f}-{end:.1f} s, the plan says {item.start:.1f}-{item.end:.1f} s"
            )
    return out
