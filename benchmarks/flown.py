"""Shared searches flown by the simulated fleet, against the plan (issue 21: "flown within 5 %").

    python benchmarks/flown.py                 # every polygon of the team-search family, 1 fleet
    python benchmarks/flown.py --seeds 2 --dt 0.5

Each polygon of ``delegation.bench.team_search`` (concave, 0.2-4 km2) is searched (``execunit:
"*"``) by a 3-6 unit fleet, planned with ``auction``; every part is then flown in process by a
`SimVehicle` (``delegation.sim.flown``: the same vehicles ``delegation sim`` runs, stepped ``dt``
simulated seconds at a time, no broker). Per part: planned time (travel + work), flown time, their
ratio, and the metres of the work's track farther than 1 m and than ``w/2`` outside the part. Per
case: the flown makespan over the planned one, the area the flown footprints cover (``w`` wide,
square ends and corners) and how much of it two parts' footprints see. Then the worst and the
geometric means.
"""

from __future__ import annotations

import argparse
import math
import time

import shapely

from delegation.allocation import plan_mission
from delegation.allocation.sharing import region_of
from delegation.bench.team_search import FRAME, concave_polygons, fleet, search_node
from delegation.costs import search_polygons_xy, sweep_width
from delegation.sim.flown import fly_plan, footprint, outside, swept
from delegation.tst import with_uuids


def _geo_mean(xs: list[float]) -> float:
    return math.exp(sum(math.log(x) for x in xs) / len(xs))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1, help="fleets per polygon (default 1)")
    parser.add_argument("--dt", type=float, default=1.0, help="simulated seconds per step")
    parser.add_argument("--only", default=None, help="polygons whose name contains this")
    args = parser.parse_args()
    ratios, makespans, covers, overlaps, out_share = [], [], [], [], []
    print(f"{'case':<22} {'unit':<5} {'w m':>5} {'planned s':>9} {'flown s':>8} {'ratio':>6} "
          f"{'out>1m':>7} {'out>w/2':>7}")
    started = time.perf_counter()
    for k, (name, poly) in enumerate(concave_polygons().items()):
        if args.only and args.only not in name:
            continue
        for seed in range(args.seeds):
            units = fleet(10 * k + seed, poly)
            tree = with_uuids(search_node(poly))
            plan = plan_mission(tree, units, strategy="auction")
            flown = fly_plan(plan, units, FRAME, dt=args.dt)
            by_name = {u.name: u for u in units}
            prints, case = [], f"{name}/{seed}"
            for f in flown:
                unit = by_name[f.unit]
                w = sweep_width(unit, 2.0)
                node = next(n for n in _leaves(plan) if n.node_uuid == f.node_uuid)
                part = region_of(search_polygons_xy(node, FRAME))
                length = shapely.LineString(f.track_xy).length if len(f.track_xy) > 1 else 0.0
                far, near = outside(f.track_xy, part, w / 2.0), outside(f.track_xy, part, 1.0)
                out_share.append(near / length if length else 0.0)
                ratios.append(f.ratio)
                prints.append(footprint(f.track_xy, w))
                print(f"{case:<22} {f.unit:<5} {w:5.1f} {f.planned_s:9.0f} {f.flown_s:8.0f} "
                      f"{f.ratio:6.3f} {near / max(length, 1e-9):7.2%} "
                      f"{far / max(length, 1e-9):7.2%}"
                      + ("" if f.state == "finished" else f" {f.state}"))
            area = region_of(search_polygons_xy(tree, FRAME))
            cover, twice = swept(area, prints)
            span = max(f.flown_s for f in flown) / plan.makespan
            covers.append(cover)
            overlaps.append(twice)
            makespans.append(span)
            print(f"{case:<22} parts {len(flown)}: flown makespan / planned {span:.3f}, footprints "
                  f"cover {cover:.2%}, seen twice {twice:.2%}")
    worst = max(ratios, key=lambda r: abs(r - 1.0))
    print(f"per part flown / planned: geo-mean {_geo_mean(ratios):.4f}, farthest from 1 "
          f"{worst:.4f} ({len(ratios)} parts); makespan flown / planned: geo-mean "
          f"{_geo_mean(makespans):.4f}, range {min(makespans):.4f}-{max(makespans):.4f}")
    print(f"flown footprints: cover >= {min(covers):.2%} (geo-mean {_geo_mean(covers):.2%}); "
          f"seen by two parts <= {max(overlaps):.2%} (geo-mean {_geo_mean(overlaps):.3%}); "
          f"work track farther than 1 m outside its part <= {max(out_share):.2%} of its length")
    print(f"({len(covers)} cases, dt {args.dt:g} s, {time.perf_counter() - started:.0f} s wall)")


def _leaves(plan):  # type: ignore[no-untyped-def]
    from delegation.tst import leaves

    return leaves(plan.planned or plan.tst)


if __name__ == "__main__":
    main()
