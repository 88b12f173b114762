"""Speed of ``plan_mission`` with the auction on mixed trees (prints the figures of issue 9 item 6).

1. The service's case: 10 units x 20-task mixed trees (a conc of a 10-task seq and 10 single
   tasks: move-tos, move-paths, search-areas), the same units and trees ``benchmarks/latency.py``
   plans (its generator, its seed), called directly (no broker). Per mission the wall time of
   ``plan_mission`` and its stages (``plan_mission(stages=...)``): validation (options, tree,
   plausibility), problem (uuids, defaults, cost tables), strategy (the auction), sent-tree (the
   series-parallel / old-rule tree, its simulation, the plan). Target: p50 <= 20 ms. The CPU time
   of the process over the call is printed too: on a shared machine it moves less than the wall
   time (other processes' load shows in the wall time only).
2. ``--large``: 200 units x 1000 move-tos in a mixed tree (``benchmarks/planning.py``'s
   generator, seed 7), makespan and total. Target: under 10 s.

Also printed: the mean makespan of the plans, so a change that speeds the auction up by planning
worse shows here too (``benchmarks/instantiation.py`` is the quality check proper).

    .venv/bin/python benchmarks/auction_speed.py [--missions 50] [--large [--repeats N]]
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
import time

# Sibling benchmark scripts (the script's directory is on sys.path): the same generators.
from latency import make_tree, make_units, pct
from planning import random_fleet

from delegation.allocation import plan_mission
from delegation.tst import parse_tree

STAGES = ("validation", "problem", "strategy", "sent-tree")


def line(name: str, values_ms: list[float]) -> str:
    return (f"{name:<26} p50={pct(values_ms, 50):7.2f} ms  p90={pct(values_ms, 90):7.2f} ms  "
            f"mean={statistics.fmean(values_ms):7.2f} ms  max={max(values_ms):7.2f} ms")


def small(missions: int, units_n: int, tasks: int, seed: int, objective: str) -> float:
    """The 10 x 20 figures; returns the p50 (ms)."""
    rng = random.Random(seed)
    units = make_units(units_n, rng)
    warm = [parse_tree(make_tree(tasks, rng)) for _ in range(3)]
    trees = [parse_tree(make_tree(tasks, rng, "mixed")) for _ in range(missions)]
    for tree in warm:  # imports, first-use caches
        plan_mission(tree, units, strategy="auction", objective=objective)
    total: list[float] = []
    cpu: list[float] = []
    stages: dict[str, list[float]] = {k: [] for k in STAGES}
    makespans: list[float] = []
    infeasible = 0
    for tree in trees:
        parts: dict[str, float] = {}
        began, began_cpu = time.perf_counter(), time.process_time()
        plan = plan_mission(tree, units, strategy="auction", objective=objective, stages=parts)
        total.append((time.perf_counter() - began) * 1000)
        cpu.append((time.process_time() - began_cpu) * 1000)
        for k in STAGES:
            stages[k].append(parts[k] * 1000)
        makespans.append(plan.makespan)
        infeasible += not plan.feasible
    print(f"plan_mission, auction, {objective}: {units_n} units x {tasks}-task mixed trees "
          f"(latency.py's), {missions} missions, seed {seed}")
    print(line("plan_mission", total))
    print(line("  (its CPU time)", cpu))
    for k in STAGES:
        print(line(f"  {k}", stages[k]))
    print(f"mean makespan {statistics.fmean(makespans):.1f} s, infeasible plans {infeasible}")
    p50 = pct(total, 50)
    print("target p50 <= 20 ms:", "met" if p50 <= 20 else "NOT met")
    return p50


def large(repeats: int) -> None:
    tree, units = random_fleet(200, 1000, seed=7, shape="mixed")
    print("plan_mission, auction: 200 units x 1000 move-tos, mixed tree (planning.py's, seed 7)")
    for objective in ("makespan", "total"):
        times = []
        for _ in range(repeats):
            parts: dict[str, float] = {}
            began = time.perf_counter()
            plan = plan_mission(tree, units, strategy="auction", objective=objective, stages=parts)
            times.append(time.perf_counter() - began)
        split = ", ".join(f"{k} {parts[k]:.2f} s" for k in STAGES)
        print(f"  {objective:<9} median {statistics.median(times):6.2f} s  max {max(times):6.2f} s"
              f"  (last: {split}; makespan {plan.makespan:.0f} s, total {plan.total_time:.0f} s,"
              f" feasible {plan.feasible})")
    print("target under 10 s:", "met" if max(times) < 10 else "NOT met")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--missions", type=int, default=50)
    parser.add_argument("--units", type=int, default=10)
    parser.add_argument("--tasks", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--objective", choices=("makespan", "total"), default="makespan")
    parser.add_argument("--large", action="store_true",
                        help="also 200 units x 1000 tasks (slow: about a minute)")
    parser.add_argument("--repeats", type=int, default=1, help="runs per objective of --large")
    args = parser.parse_args(argv)
    with open("/proc/loadavg") as f:
        print("load average:", f.read().strip())
    small(args.missions, args.units, args.tasks, args.seed, args.objective)
    if args.large:
        large(args.repeats)
    with open("/proc/loadavg") as f:
        print("load average:", f.read().strip())
    return 0


if __name__ == "__main__":
    sys.exit(main())
