"""What the sweeps cost in a plan: ``plan_mission`` over ``benchmarks/latency.py``'s 20-task
mixed trees (its generators and seed), this thread's CPU ms per plan, and the same for only the
sweeps those plans ask for (``coverage.flown_ways`` of each search area at each unit's width,
remembered results forgotten first). For instruction counts run it under callgrind twice, with
``--plans 0`` and ``--plans N``: the difference over N is the instructions of a plan (the imports
and the warm-up plan are the same in both).

    PYTHONPATH=src .venv/bin/python benchmarks/sweep_speed.py [--plans 100] [--repeat 5]
    PYTHONPATH=src valgrind --tool=callgrind --trace-children=yes --callgrind-out-file=/dev/null \
        .venv/bin/python benchmarks/sweep_speed.py --plans 20 --repeat 0   # (and --plans 0)
"""

from __future__ import annotations

import argparse
import random
import statistics
import time
from typing import Any

from latency import make_tree, make_units

from delegation import coverage, lanes, ways_inside
from delegation.allocation import plan_mission
from delegation.costs import search_polygons_xy, sweep_width, task_geometry
from delegation.geo import LocalFrame
from delegation.tst import parse_tree


def _forget() -> None:
    """Forget every remembered sweep, frame and direction (each plan's areas are new to it)."""
    for module in (coverage, lanes, ways_inside):
        for value in vars(module).values():
            if hasattr(value, "cache_clear"):
                value.cache_clear()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--plans", type=int, default=100)
    parser.add_argument("--repeat", type=int, default=5,
                        help="times the sweeps alone are run (0: plans only)")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    units = make_units(10, random.Random(args.seed))
    warm = parse_tree(make_tree(20, rng, "mixed"))
    trees = [parse_tree(make_tree(20, rng, "mixed")) for _ in range(args.plans)]
    plan_mission(warm, units, strategy="auction")
    cpu: list[float] = []
    for tree in trees:
        c0 = time.thread_time()
        plan_mission(tree, units, strategy="auction")
        cpu.append((time.thread_time() - c0) * 1000)
    if not trees:
        return 0
    print(f"plan_mission (mixed, auction)  n={len(cpu)}  CPU p50={statistics.median(cpu):.2f} ms"
          f"  mean={statistics.fmean(cpu):.2f} ms", flush=True)
    if args.repeat < 1:
        return 0
    sweeps = _sweeps_of(trees, units)
    per_plan: list[float] = []
    for _ in range(args.repeat):
        _forget()
        c0 = time.thread_time()
        for polygons, width in sweeps:
            coverage.flown_ways(polygons, width)
        per_plan.append((time.thread_time() - c0) * 1000 / len(trees))
    print(f"flown_ways alone  {len(sweeps)} sweeps ({len(sweeps) / len(trees):.1f} a plan)  "
          f"CPU per plan min={min(per_plan):.2f} ms  median={statistics.median(per_plan):.2f} ms")
    return 0


def _sweeps_of(trees: list[Any], units: list[Any]) -> list[tuple[list[Any], float]]:
    """(polygons, width) of every search in the trees at each distinct width of the units."""
    from latency import ORIGIN

    frame = LocalFrame(ORIGIN.latitude, ORIGIN.longitude)
    out = []
    for tree in trees:
        for node in _leaves(tree):
            polygons = search_polygons_xy(node, frame)
            if polygons:
                size = task_geometry(node).target_size
                out += [(polygons, w) for w in sorted({sweep_width(u, size) for u in units})]
    return out


def _leaves(node: Any) -> list[Any]:
    return [node] if not node.children else [x for c in node.children for x in _leaves(c)]


if __name__ == "__main__":
    raise SystemExit(main())
