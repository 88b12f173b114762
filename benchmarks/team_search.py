"""Searching as a team (DESIGN 3.11): sweeps, sharing, bounds, solve time.

    python benchmarks/team_search.py                 # everything below
    python benchmarks/team_search.py --only sweeps   # (or team, mixed, endurance, speed)

The polygons are generated here, deterministically (fixed seeds): coastline-like radial polygons
with bays, and L, U, comb, crescent and star shapes, each scaled to 0.2-4 km2 (the published
multi-robot coverage benchmark's polygons cannot be downloaded here). For each polygon and sweep
width it prints the coverage path length over ``A / w`` (the area divided by the sweep width: no
turns, no overlap), once with the lanes along the minimum rectangle's long axis (the old rule) and
once along the direction ``delegation.coverage.sweep_direction`` chooses, then the geometric mean
and the worst of each; and the path the units fly (``flown_sweep``: turns pulled inside,
transitions round notches) over ``A / w`` with the share of the area its footprint covers (a
path made shorter by leaving corners unseen is not better).

``team``: each polygon searched (``execunit: "*"``) by a heterogeneous fleet of 3-6 units (drones
of different speeds, 37 m lanes; a boat, 9 m lanes), placed 0.5-2.5 km from the area (seeded):
the makespan of ``auction`` over the 3.11 lower bound (geometric mean and worst), the same with
``--no-split`` (one unit) and with ``nearest``, the share of the area the parts cover (union) and
how much they overlap, and the solve time. ``mixed``: the search inside a tree with other tasks
(seq and conc around it): the search's end over its bound. ``endurance``: drones whose endurance
is too short for the area alone (``--endurance``: 45, 40 and 36 % of one unit's need): feasible?
Each case prints its slack (``endurance_slack``: the fleet's endurance less each unit's own flight
to the area, over what the area's sweep needs); the issue's target applies from 1.1. And the
CPU time of the shared plan (cutting to fit tight endurance sweeps many candidate parts).
``speed``: ``auction`` on 10 units and 20 tasks with two large searches (wall time).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import random
import time

import numpy as np
import shapely
from shapely.geometry import Polygon

from delegation.allocation import plan_mission
from delegation.allocation.planner import flatten_tree
from delegation.allocation.problem import build_problem
from delegation.allocation.share_plan import Before, Busy, search_bound
from delegation.allocation.sharing import region_of
from delegation.bench.team_search import concave_polygons, fleet, geo_at, unit_at
from delegation.bench.team_search import search_node as _search
from delegation.costs import cost_tables, search_polygons_xy, sweep_width, task_path
from delegation.coverage import (
    coverage_length,
    flown_sweep,
    footprint,
    path_length,
    sweep_axes,
    sweep_direction,
)
from delegation.fleet import UnitState
from delegation.geo import LocalFrame
from delegation.tst import TstNode, make_node, with_defaults, with_uuids

#: Sweep widths (m): a drone at 40 m with a 60 degree camera, and a boat at 10 m.
WIDTHS = (37.0, 9.2)


def _geo_mean(xs: list[float]) -> float:
    return math.exp(sum(math.log(x) for x in xs) / len(xs))


def sweep_overhead(widths: tuple[float, ...]) -> None:
    """Print path / (A / w) per polygon and width, old rule and chosen direction, and the path
    the units fly (``flown_sweep``: turns inside, transitions round notches) with the share of
    the area its footprint covers: a shorter path is only better if it still covers."""
    old_all: list[float] = []
    new_all: list[float] = []
    covers: list[float] = []
    print(f"{'polygon':<20} {'w m':>5} {'A/w m':>9} {'old':>6} {'chosen':>7} {'choose s':>9} "
          f"{'flown':>6} {'cover %':>8}")
    for name, poly in concave_polygons().items():
        area = Polygon(poly).area
        for w in widths:
            ideal = area / w
            old = coverage_length(poly, w, along=sweep_axes(poly)[0]) / ideal
            t0 = time.perf_counter()
            along = sweep_direction(poly, w)
            took = time.perf_counter() - t0
            new = coverage_length(poly, w, along=along) / ideal
            flown, cover = _flown(poly, w)
            old_all.append(old)
            new_all.append(new)
            covers.append(cover)
            print(f"{name:<20} {w:5.1f} {ideal:9.0f} {old:6.3f} {new:7.3f} {took:9.3f} "
                  f"{flown / ideal:6.3f} {100.0 * cover:8.2f}")
    print(f"sweep overhead path/(A/w): long-axis rule geo-mean {_geo_mean(old_all):.3f} "
          f"worst {max(old_all):.3f}; chosen direction geo-mean {_geo_mean(new_all):.3f} "
          f"worst {max(new_all):.3f} ({len(new_all)} sweeps); flown footprint covers "
          f"{100.0 * min(covers):.2f} % of the area at worst")


def _flown(poly: np.ndarray, width: float) -> tuple[float, float]:
    """(length of the path the units fly over the polygon, share of the polygon its footprint
    covers: ``coverage.footprint``, ``width`` wide and as long)."""
    path = flown_sweep([poly], width)
    area = Polygon(poly)
    seen = shapely.intersection(footprint(path, width), area).area
    return path_length(path), float(seen / area.area)


def _bound(tree: TstNode, units: list[UnitState], uuid: str) -> float:
    """The 3.11 bound of the search ``uuid`` with every unit free at the start."""
    prepared = with_defaults(with_uuids(tree))
    tables = cost_tables(units, [node for _, node in flatten_tree(prepared)[1]])
    problem = build_problem(prepared, units, tables)
    t = next(t for t, task in enumerate(problem.tasks) if task.uuid == uuid)
    return search_bound(problem, tables, None, t)


def _tree_bound(plan, tree: TstNode, units: list[UnitState], uuid: str  # type: ignore[no-untyped-def]
                ) -> float:
    """The 3.11 bound of the search ``uuid`` with each unit busy only with what the tree puts
    before the search (as ``plan`` allocates it), every other unit free from when the search may
    start: a true lower bound of the search's end (the tasks beside it in a ``conc`` may be
    flown after it), looser than the plan's (``SharedSearch.bound``: units busy as the unshared
    plan had them, tasks beside the search included)."""
    prepared = with_defaults(tree)
    tables = cost_tables(units, [node for _, node in flatten_tree(prepared)[1]])
    problem = build_problem(prepared, units, tables)
    t = next(t for t, task in enumerate(problem.tasks) if task.uuid == uuid)
    names = [u.name for u in units]
    done = {a.node_uuid: a for a in plan.assignments}
    act, busy = 0.0, {}
    for k, task in enumerate(problem.tasks):
        a = done.get(task.uuid)
        if not problem.before[k, t] or a is None:
            continue
        u = names.index(a.execunit.strip("/"))
        end = tables.end_for(u, k)
        act = max(act, a.end)
        if a.end >= busy.get(u, Busy(-1.0)).free:
            busy[u] = Busy(a.end, a.travel_time + a.work_time,
                           None if end is None else (float(end[0]), float(end[1])))
    return search_bound(problem, tables, None, t, Before(act, busy))


def _parts_cover(plan, tree: TstNode) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """(union of the parts / area, overlap / area) of the plan's one shared search."""
    if not plan.shared:
        return 1.0, 0.0
    frame = LocalFrame(57.76, 16.68)
    area = region_of(search_polygons_xy(tree, frame))
    leaves = {n.node_uuid: n for _, n in flatten_tree(plan.planned)[1]}
    parts = [region_of(search_polygons_xy(leaves[p.node_uuid], frame))
             for p in plan.shared[0].parts]
    union = shapely.union_all(parts)
    inside = float(shapely.intersection(union, area).area)
    return inside / area.area, (sum(p.area for p in parts) - union.area) / area.area


def _swept(plan, tree: TstNode, units: list[UnitState]  # type: ignore[no-untyped-def]
           ) -> tuple[float, float]:
    """(area some unit's camera footprint covers along its flown path / area, area swept by two
    units' paths / area; ``coverage.footprint``, as the simulated units count what they saw):
    what the paths the simulator flies (``costs.task_path``) cover, each part with its unit's own
    width; the single-unit path for an unshared plan."""
    frame = LocalFrame(57.76, 16.68)
    area = region_of(search_polygons_xy(tree, frame))
    by_name = {u.name: u for u in units}
    leaves = {n.node_uuid: n for _, n in flatten_tree(plan.planned or plan.tst)[1]}
    bands = []
    for a in plan.assignments:
        unit = by_name[a.execunit.strip("/")]
        node = leaves.get(a.node_uuid) or tree
        points = task_path(node, unit, frame)
        xy = frame.points_xy(points)
        g = node.params.get("target-size", 2.0)
        w = sweep_width(unit, float(g))
        bands.append(footprint(xy, w))
    union = shapely.union_all(bands)
    covered = float(shapely.intersection(union, area).area) / area.area
    twice = (sum(float(shapely.intersection(b, area).area) for b in bands)
             - float(shapely.intersection(union, area).area)) / area.area
    return covered, twice


def team(seeds: int) -> None:
    """Makespan / bound per polygon and fleet: shared (auction), one unit, nearest."""
    rows: dict[str, list[float]] = {"auction": [], "no-split": [], "nearest": []}
    covers, overlaps, solves, swept, twice = [], [], [], [], []
    print(f"{'polygon':<20} {'units':>5} {'bound s':>8} {'auction':>8} {'no-split':>8} "
          f"{'nearest':>8} {'parts':>5} {'cover':>7} {'overlap':>7} {'solve s':>7} {'cpu s':>7}")
    for k, (name, poly) in enumerate(concave_polygons().items()):
        for seed in range(seeds):
            units = fleet(10 * k + seed, poly)
            tree = with_uuids(_search(poly))
            cpu = time.process_time()
            shared = plan_mission(tree, units, strategy="auction")
            cpu = time.process_time() - cpu
            alone = plan_mission(tree, units, strategy="auction", split=False)
            near = plan_mission(tree, units, strategy="nearest")
            bound = _bound(tree, units, tree.node_uuid or "")
            cover, overlap = _parts_cover(shared, tree)
            for key, plan in (("auction", shared), ("no-split", alone), ("nearest", near)):
                rows[key].append(plan.makespan / bound)
            covers.append(cover)
            overlaps.append(overlap)
            flown = _swept(shared, tree, units)
            swept.append(flown[0])
            twice.append(flown[1])
            solves.append(cpu)
            parts = len(shared.shared[0].parts) if shared.shared else 1
            print(f"{name:<20} {len(units):5d} {bound:8.0f} {rows['auction'][-1]:8.3f} "
                  f"{rows['no-split'][-1]:8.3f} {rows['nearest'][-1]:8.3f} {parts:5d} "
                  f"{cover:7.2%} {overlap:7.2%} {shared.solve_time:7.3f} {cpu:7.3f}")
    for key, ratios in rows.items():
        print(f"makespan / bound, {key}: geo-mean {_geo_mean(ratios):.3f}, worst {max(ratios):.3f}")
    gains = [a / b for a, b in zip(rows["auction"], rows["no-split"], strict=True)]
    print(f"sharing vs one unit (auction / no-split makespan): geo-mean {_geo_mean(gains):.3f}")
    print(f"parts: union covers >= {min(covers):.3%} of the area, overlap <= {max(overlaps):.3%}; "
          f"auction CPU time (first plan of each area, caches cold) median "
          f"{sorted(solves)[len(solves) // 2]:.3f} s, max {max(solves):.3f} s")
    print(f"flown paths (camera footprint): cover >= {min(swept):.2%} of the area (geo-mean "
          f"{_geo_mean(swept):.2%}), swept twice <= {max(twice):.2%}")


def _move(x: float, y: float) -> TstNode:
    return make_node("move-to", execunit="*",
                     params={"waypoint": geo_at(x, y), "speed": "standard"})


def _path(rng: random.Random, reach: float) -> TstNode:
    pts = [geo_at(rng.uniform(-reach, reach), rng.uniform(-reach, reach)) for _ in range(3)]
    return make_node("move-path", execunit="*", params={"waypoints": pts, "speed": "standard"})


def mixed(seeds: int) -> None:
    """The search inside seq(move-to, conc(search, move-path, move-to), move-to): its end over
    its bound (units busy first as in the unshared plan, the bound from when each could be
    there: the plan's), and over the looser tree bound (``_tree_bound``: units busy only with
    what the tree puts before the search)."""
    ratios, loose = [], []
    print(f"{'polygon':<20} {'units':>5} {'search end':>10} {'bound s':>8} {'ratio':>6} "
          f"{'makespan':>9} {'tree bnd':>8} {'ratio':>6}")
    for k, (name, poly) in enumerate(concave_polygons().items()):
        for seed in range(seeds):
            rng = random.Random(100 + 10 * k + seed)
            units = fleet(10 * k + seed, poly)
            reach = float(np.hypot(*(poly - poly.mean(axis=0)).T).max()) + 1000.0
            tree = make_node("seq", children=[
                _move(rng.uniform(-reach, reach), rng.uniform(-reach, reach)),
                make_node("conc", children=[_search(poly), _path(rng, reach),
                                            _move(rng.uniform(-reach, reach), -reach)]),
                _move(rng.uniform(-reach, reach), reach)])
            tree = with_uuids(tree)
            plan = plan_mission(tree, units, strategy="auction")
            if not plan.shared:
                print(f"{name:<20} {len(units):5d} not shared")
                continue
            s = plan.shared[0]
            ratios.append(s.end / s.bound)
            floor = _tree_bound(plan, tree, units, s.node_uuid)
            loose.append(s.end / floor)
            print(f"{name:<20} {len(units):5d} {s.end:10.0f} {s.bound:8.0f} {ratios[-1]:6.3f} "
                  f"{plan.makespan:9.0f} {floor:8.0f} {loose[-1]:6.3f}")
    print(f"search end / its bound with other tasks: geo-mean {_geo_mean(ratios):.3f}, worst "
          f"{max(ratios):.3f} ({len(ratios)} trees); / the tree bound: geo-mean "
          f"{_geo_mean(loose):.3f}, worst {max(loose):.3f}")


def endurance_slack(tree: TstNode, units: list[UnitState]) -> float:
    """What the fleet's endurance allows over what the area needs: ``sum_i max(0, E_i - d_i /
    v_i) v_i w_i / (A o)``, each unit's endurance less its flight to the area's nearest point
    (and home again, where it has one), swept at its rate, over the area at the sweep overhead
    ``o`` of the whole area (path / (A / w), the narrowest width's). The target applies from
    1.1 (10 % slack): the flight there is each unit's own, so it is not the total endurance
    over one unit's need."""
    prepared = with_defaults(with_uuids(tree))
    tables = cost_tables(units, [node for _, node in flatten_tree(prepared)[1]])
    region = region_of(search_polygons_xy(prepared, tables.frame))
    polygon = search_polygons_xy(prepared, tables.frame)[0]
    swept = 0.0
    width_ref = float(np.nanmin(tables.width[:, 0]))
    overhead = coverage_length(polygon, width_ref) / (region.area / width_ref)
    for u, _unit in enumerate(units):
        v, w = float(tables.speed[u, 0]), float(tables.width[u, 0])
        there = float(region.distance(shapely.Point(tables.unit_xy[u]))) / v
        back = 0.0
        if not np.isnan(tables.home_xy[u]).any():
            back = float(region.distance(shapely.Point(tables.home_xy[u]))) / v
        swept += max(0.0, float(tables.endurance[u]) - there - back) * v * w
    return swept / (region.area * overhead)


def endurance(seeds: int, share: float = 0.45) -> None:
    """Drones whose endurance is ``share`` (45 %) of what the best of them needs for the area
    alone, four of them (1.8 x one unit's need in total; but each unit flies there on its own):
    is the plan feasible, and within endurance? The slack (``endurance_slack``) says whether
    the issue's target applies (from 1.1)."""
    feasible, total, due, met = 0, 0, 0, 0
    cpus: list[float] = []
    margins: list[float] = []
    for k, (name, poly) in enumerate(concave_polygons().items()):
        for seed in range(seeds):
            probe = [u for u in fleet(10 * k + seed, poly) if u.agent_type == "air"]
            tree = with_uuids(_search(poly))
            alone = plan_mission(tree, probe, strategy="auction", split=False)
            need = min(a.end for a in alone.assignments)
            limit = share * need
            units = [dataclasses.replace(u, endurance=limit) for u in fleet(10 * k + seed, poly)
                     if u.agent_type == "air"]
            units = (units * 2)[:4] if len(units) < 4 else units[:4]
            units = [dataclasses.replace(u, name=f"dji{i}") for i, u in enumerate(units)]
            cpu = time.process_time()
            plan = plan_mission(tree, units, strategy="auction")
            cpus.append(time.process_time() - cpu)
            one = plan_mission(tree, units, strategy="auction", split=False)
            slack = endurance_slack(tree, units)
            total += 1
            used = max((sum(a.travel_time + a.work_time for a in r) / limit
                        for r in plan.routes.values()), default=0.0)
            ok = plan.feasible and bool(plan.routes) and used <= 1 + 1e-9
            feasible += ok
            due += slack >= 1.1
            met += ok and slack >= 1.1
            if ok and slack >= 1.1:
                margins.append(1.0 - used)
            verdict = "feasible" if ok else "INFEASIBLE"
            print(f"{name:<20} endurance {limit:7.0f} s x 4, slack {slack:5.2f}: shared "
                  f"{verdict} ({len(plan.assignments)} parts, makespan {plan.makespan:.0f} s, "
                  f"most used {used:6.1%}, CPU {cpus[-1]:.2f} s); one unit "
                  f"{'feasible' if one.feasible else 'infeasible'}")
    print(f"endurance at {share:.0%} of one unit's need: {feasible} of {total} areas needing "
          f"{1 / share:.1f}+ units' endurance planned feasibly; {met} of the {due} whose fleet "
          f"has 10 % slack (slack >= 1.1); auction CPU time median "
          f"{sorted(cpus)[len(cpus) // 2]:.2f} s, max {max(cpus):.2f} s")
    if margins:
        print(f"  margin (1 - the most any unit uses of its endurance) where slack >= 1.1: "
              f"least {min(margins):.2%}, median {sorted(margins)[len(margins) // 2]:.2%}")


def endurance_floor(seeds: int, steps: int = 7) -> None:
    """The least endurance each area is planned feasibly with (four drones, as ``endurance``),
    found by bisection, as a share of a reference that no sweep path enters: the area over the
    fastest drone's sweep rate (``A / (w v)``, no turns, no flight there). A lower floor is
    endurance the plan no longer needs; it compares versions of the planner whose one-unit
    need (``endurance``'s reference) differs."""
    floors: list[float] = []
    for k, (name, poly) in enumerate(concave_polygons().items()):
        for seed in range(seeds):
            air = [u for u in fleet(10 * k + seed, poly) if u.agent_type == "air"]
            air = (air * 2)[:4] if len(air) < 4 else air[:4]
            air = [dataclasses.replace(u, name=f"dji{i}") for i, u in enumerate(air)]
            tree = with_uuids(_search(poly))
            rate = max(u.speeds["standard"] * sweep_width(u, 2.0) for u in air)
            reference = Polygon(poly).area / rate

            def fits(share: float, air: list[UnitState] = air, reference: float = reference,
                     tree: TstNode = tree) -> bool:
                limit = share * reference
                units = [dataclasses.replace(u, endurance=limit) for u in air]
                plan = plan_mission(tree, units, strategy="auction")
                return plan.feasible and bool(plan.routes) and all(
                    sum(a.travel_time + a.work_time for a in r) <= limit * (1 + 1e-9)
                    for r in plan.routes.values())

            lo, hi = 0.2, 0.8
            if not fits(hi):
                print(f"{name:<20} seed {seed}: not feasible at {hi:.0%}")
                continue
            for _ in range(steps):
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if fits(mid) else (mid, hi)
            floors.append(hi)
            print(f"{name:<20} seed {seed}: feasible from {hi:6.1%} of A / (w v) per drone")
    print(f"least endurance planned feasibly (share of A / (w v), bisection within "
          f"{0.6 / 2 ** steps:.2%}): geo-mean {_geo_mean(floors):.3f}, worst {max(floors):.3f} "
          f"({len(floors)} cases)")


def speed(repeats: int = 3) -> None:
    """``auction`` on 10 units and 20 tasks with two large searches: wall and CPU time."""
    polys = concave_polygons()
    rng = random.Random(7)
    a, b = polys["coast1-2km2"], polys["star-4km2"] + np.array([4000.0, 0.0])
    units = [unit_at(f"dji{i}", "air", rng.uniform(-3e3, 6e3), rng.uniform(-3e3, 3e3))
             for i in range(8)]
    units += [unit_at(f"usv{i}", "surface", rng.uniform(-3e3, 6e3), -3500.0) for i in range(2)]
    others = [_move(rng.uniform(-3e3, 6e3), rng.uniform(-3e3, 3e3)) for _ in range(12)]
    others += [_path(rng, 3000.0) for _ in range(6)]
    for run in range(repeats):
        tree = make_node("conc", children=[
            make_node("seq", children=[others[0], _search(a), others[1]]),
            _search(b), *others[2:]])
        wall, cpu = time.perf_counter(), time.process_time()
        plan = plan_mission(tree, units, strategy="auction")
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        print(f"auction, 10 units, 20 tasks, two searches (run {run + 1}, "
              f"{'caches cold' if run == 0 else 'same areas again'}): {wall:.3f} s wall, "
              f"{cpu:.3f} s CPU; {len(plan.shared)} shared, feasible {plan.feasible}, makespan "
              f"{plan.makespan:.0f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--widths", type=float, nargs="+", default=list(WIDTHS))
    parser.add_argument("--only", choices=("sweeps", "team", "mixed", "endurance", "speed",
                                           "floor"),
                        default=None, help="one family (floor: the least endurance planned "
                        "feasibly, by bisection; not in the default run)")
    parser.add_argument("--seeds", type=int, default=2, help="fleets per polygon (default 2)")
    parser.add_argument("--endurance", type=float, nargs="+", default=[0.45, 0.40, 0.36],
                        help="each drone's endurance as a share of one unit's need for the area "
                        "(default 0.45 0.40 0.36)")
    args = parser.parse_args()
    if args.only in (None, "sweeps"):
        sweep_overhead(tuple(args.widths))
    if args.only in (None, "team"):
        team(args.seeds)
    if args.only in (None, "mixed"):
        mixed(args.seeds)
    if args.only in (None, "endurance"):
        for share in args.endurance:
            endurance(args.seeds, share)
    if args.only in (None, "speed"):
        speed()
    if args.only == "floor":
        endurance_floor(args.seeds)


if __name__ == "__main__":
    main()
