"""Checks every plan must pass, computed from the plan itself (not from the strategy's state).

Used by the tests on every scenario and strategy, and cheap enough to run in the service. Times
are recomputed from the cost tables and the plan's own routes, so a strategy that got its
bookkeeping wrong is caught here; and by running the instantiated tree itself (its seq/conc
structure as the engine runs it), so that a plan's times are what executing its tree does.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from delegation.allocation.plan import Assignment, Plan
from delegation.tst import ExecUnitKind, TstNode, classify_execunit, is_vehicle_task, leaves, walk

if TYPE_CHECKING:
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


def check_invariants(plan: Plan, tree: TstNode, units: Sequence[UnitState]) -> list[str]:
    """Every broken invariant as a sentence; ``[]`` when the plan is sound."""
    from delegation.costs import cost_tables

    out: list[str] = []
    by_name = {u.name: u for u in units}
    inst_leaves = leaves(plan.tst)
    leaf_by_uuid = {leaf.node_uuid: leaf for leaf in inst_leaves}

    # The instantiated tree keeps the caller's tasks and uuids.
    original = leaves(tree)
    if len(original) != len(inst_leaves):
        out.append(f"tree has {len(original)} tasks but the plan's tree {len(inst_leaves)}")
    inst_uuids = {n.node_uuid for _, n in walk(plan.tst)}
    for _, node in walk(tree):
        if node.node_uuid and node.node_uuid not in inst_uuids:
            out.append(f"node-uuid {node.node_uuid} of the caller is missing from the plan's tree")

    # Every task is assigned or unassigned with a reason, exactly once.
    assigned = {a.node_uuid: a for a in plan.assignments}
    if len(assigned) != len(plan.assignments):
        out.append("a task is assigned twice")
    missing = {u.node_uuid for u in plan.unassigned}
    for gone in plan.unassigned:
        if not gone.reason:
            out.append(f"unassigned task {gone.node_uuid} has no reason")
        if gone.node_uuid in assigned:
            out.append(f"task {gone.node_uuid} is both assigned and unassigned")
    for leaf in inst_leaves:
        if leaf.node_uuid not in assigned and leaf.node_uuid not in missing:
            out.append(f"task {leaf.node_uuid} ({leaf.name}) is neither assigned nor unassigned")
    if plan.feasible != (not plan.unassigned):
        out.append("feasible does not match the unassigned list")

    # Each assignment: a live unit that offers the task, the one the tree names.
    for a in plan.assignments:
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
    for _, node in walk(tree):
        if node.is_control or not node.node_uuid or node.node_uuid not in assigned:
            continue
        kind, ref = classify_execunit(node.execunit)
        if kind is ExecUnitKind.FIXED and assigned[node.node_uuid].execunit != "/" + ref:
            out.append(f"{node.node_uuid} is fixed to /{ref} but planned on "
                       f"{assigned[node.node_uuid].execunit}")
    aliases: dict[str, set[str]] = {}
    for orig in original:
        kind, ref = classify_execunit(orig.execunit)
        hit = assigned.get(orig.node_uuid or "")
        if kind is ExecUnitKind.ALIAS and hit is not None:
            aliases.setdefault(ref, set()).add(hit.execunit)
    for alias, chosen in aliases.items():
        if len(chosen) > 1:
            out.append(f"alias {alias!r} is split over {', '.join(sorted(chosen))}")
    for path, node in walk(plan.tst):
        unit_text = node.execunit if isinstance(node.execunit, str) else ""
        if node.is_control and not unit_text.startswith("/"):
            out.append(f"control node {path} has no unit")

    # No unit runs two vehicle tasks at once.
    per_unit: dict[str, list[Assignment]] = {}
    for a in plan.assignments:
        if is_vehicle_task(a.name):
            per_unit.setdefault(a.execunit.strip("/"), []).append(a)
    for name, items in per_unit.items():
        items.sort(key=lambda a: (a.start, a.end))
        for p, q in itertools.pairwise(items):
            if q.start < p.end - TOL * max(1.0, p.end):
                out.append(f"{name} runs {p.node_uuid} and {q.node_uuid} at the same time")

    # The plan's source is the caller's tree (same shape, names, uuids); its seq order holds.
    source = plan.source if plan.source is not None else plan.tst
    if plan.source is not None:
        mine = list(walk(tree))
        theirs = list(walk(plan.source))
        if len(mine) != len(theirs):
            out.append("the plan's source tree does not have the caller's shape")
        for (path, ours), (_, kept) in zip(mine, theirs, strict=False):
            if ours.name != kept.name or len(ours.children) != len(kept.children):
                out.append(f"{path}: the plan's source tree differs from the caller's")
                break
            if ours.node_uuid and ours.node_uuid != kept.node_uuid:
                out.append(f"{path}: node-uuid {ours.node_uuid} was not kept")
    out.extend(_unsafe_pairs(plan.tst, assigned))
    for path, node in walk(source):
        if node.name != "seq":
            continue
        ended = -math.inf
        for k, child in enumerate(node.children):
            items = [assigned[x.node_uuid] for x in leaves(child) if x.node_uuid in assigned]
            if items and min(a.start for a in items) < ended - TOL * max(1.0, ended):
                out.append(f"{path}/children[{k}] starts before its predecessor ended")
            if items:
                ended = max(ended, max(a.end for a in items))

    # Each unit's route (its order; the plan's assignments in it) holds exactly its vehicle tasks.
    routes: dict[str, list[Assignment]] = {}
    for name, items in per_unit.items():
        route = [assigned[a.node_uuid] for a in plan.routes.get(name, [])
                 if a.node_uuid in assigned and is_vehicle_task(a.name)]
        if sorted(a.node_uuid for a in route) != sorted(a.node_uuid for a in items):
            out.append(f"the route of {name} does not list exactly its vehicle tasks")
            route = items
        routes[name] = route

    # Times agree with distances and speeds; battery holds; totals add up.
    if inst_leaves and units:
        unit_list = list(units)
        tables = cost_tables(unit_list, inst_leaves)
        index = {x.node_uuid: t for t, x in enumerate(inst_leaves)}
        total_time = sum(a.travel_time + a.work_time for a in plan.assignments)
        total_distance = sum(a.distance for a in plan.assignments)
        latest = max((a.end for a in plan.assignments), default=0.0)
        unit_index = {x.name: i for i, x in enumerate(unit_list)}
        duration: dict[str, float] = {}  # travel + work per task, from the tables and the route
        for a in plan.assignments:
            u = unit_index.get(a.execunit.strip("/"))
            t = index.get(a.node_uuid)
            if u is not None and t is not None and not is_vehicle_task(a.name):
                duration[a.node_uuid] = float(tables.work_time[u, t])
        for name, items in routes.items():
            u = unit_index[name]
            here = tables.unit_xy[u]
            spent = 0.0
            for a in items:
                t = index[a.node_uuid]
                start, end = tables.start_for(u, t), tables.end_for(u, t)
                d = 0.0 if start is None else float(np.hypot(*(start - here)))
                speed = float(tables.speed[u, t])
                duration[a.node_uuid] = d / speed + float(tables.work_time[u, t])
                if not _close(a.travel_time, d / speed):
                    out.append(f"{a.node_uuid}: travel time {a.travel_time:.3f} s does not match "
                               f"{d:.1f} m at {speed} m/s")
                if not _close(a.work_time, float(tables.work_time[u, t])):
                    out.append(f"{a.node_uuid}: work time {a.work_time:.3f} s is not the task's "
                               f"{float(tables.work_time[u, t]):.3f} s")
                if not _close(a.distance, d + float(tables.work_distance[u, t])):
                    out.append(f"{a.node_uuid}: distance {a.distance:.1f} m does not match")
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
        out.extend(_run_the_tree(plan.tst, assigned, routes, duration))
    return out


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
