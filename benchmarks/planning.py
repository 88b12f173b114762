"""Planning quality and speed: prints the figures quoted in the issue notes.

    .venv/bin/python benchmarks/planning.py            # everything (about 2 minutes)
    .venv/bin/python benchmarks/planning.py --quick    # 2 s solver limit, fewer repeats

1. Reference instance: TSPLIB berlin52 as a 3- and a 5-unit mTSP with every unit starting and
   ending at the depot (/work/shared/benchmarks/README.md), 1 m/s so that seconds = metres.
   ``optimal`` (10 s) is compared with the best published values (LKH-3): objective ``total``
   against min-sum (total tour length), objective ``makespan`` against min-max (longest tour).
   The published min-sum values require every unit to make a tour; a delegation plan may leave a
   unit at home, so min-sum is reported both ways (``idle allowed`` is the product's own answer;
   ``all units used`` is comparable with the table). ``auction`` and ``nearest`` are printed too.
2. Speed: ``auction`` end to end (``plan_mission``: cost tables, problem, auction, plan and the
   instantiated tree) on 20 units x 100 tasks and 200 units x 1000 tasks, with the move-tos under
   one ``conc`` (flat) and in a ``mixed`` tree (a conc of single tasks and short seqs, some holding
   a small conc, like ``delegation bench``'s generator), where seq order crosses units.
3. The same mixed trees, 20 x 100: nearest, auction, optimal (5 s) side by side.
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from delegation.allocation import plan_mission
from delegation.allocation.auction import auction
from delegation.allocation.nearest import nearest
from delegation.allocation.optimal import optimise
from delegation.allocation.problem import build_problem
from delegation.allocation.schedule import Schedule
from delegation.bench.best_known import BEST_KNOWN
from delegation.fleet import UnitState, make_unit
from delegation.geo import LocalFrame
from delegation.scenario import berlin52_scenario
from delegation.tst import TstNode, parse_tree, with_defaults, with_uuids

BERLIN = Path(__file__).resolve().parent / "data" / "berlin52.tsp"  # TSPLIB, bundled
#: Best published values (LKH-3, integer-rounded distances), from the instance's README.
PUBLISHED = {m: {"min-sum": v["total"], "min-max": v["makespan"]}
             for (name, m), v in BEST_KNOWN.items() if name == "berlin52"}


def route_lengths(s: Schedule) -> list[float]:
    """Metres per unit: its tasks' travel and work plus the way home."""
    return [float(np.nansum(s.distance[o])) + float(s.home_distance[u]) if o else 0.0
            for u, o in enumerate(s.orders)]


def reference(time_limit: float) -> None:
    print("== berlin52 as an mTSP (depot = node 1, homes at the depot, 1 m/s) ==")
    print(f"{'units':>5} {'strategy':<26} {'objective':<9} {'total m':>9} {'longest m':>10} "
          f"{'published':>10} {'vs pub.':>8} {'time s':>7}")
    for n_units in (3, 5):
        scenario = berlin52_scenario(BERLIN, n_units)
        tree = with_defaults(with_uuids(scenario.tree()))
        units = scenario.units()
        for objective in ("total", "makespan"):
            pub_key = "min-sum" if objective == "total" else "min-max"
            published = PUBLISHED[n_units][pub_key]
            runs: list[tuple[str, Schedule, float]] = []
            for name in ("nearest", "auction", "optimal", "optimal, all units used"):
                if name == "optimal, all units used" and objective != "total":
                    continue
                began = time.perf_counter()
                problem = build_problem(tree, units)
                if name == "nearest":
                    s = nearest(problem, objective)
                elif name == "auction":
                    s = auction(problem, objective)
                else:
                    s = optimise(problem, objective, time_limit,
                                 use_all_units=name.endswith("used")).schedule
                runs.append((name, s, time.perf_counter() - began))
            for name, s, took in runs:
                lengths = route_lengths(s)
                value = sum(lengths) if objective == "total" else max(lengths)
                label = name + (" (idle allowed)" if name == "optimal" and objective == "total"
                                else "")
                print(f"{n_units:>5} {label:<26} {objective:<9} {sum(lengths):>9.1f} "
                      f"{max(lengths):>10.1f} {published:>10.0f} "
                      f"{100 * (value / published - 1):>+7.2f}% {took:>7.2f}")
    print("(vs pub.: total m against min-sum for objective total, longest m against min-max "
          "for objective makespan; real-valued distances, the table's are rounded)")


def random_fleet(
    n_units: int, n_tasks: int, seed: int, shape: str = "flat"
) -> tuple[TstNode, list[UnitState]]:
    """Units and move-tos spread over a 10 km square near Motala, under one conc (``flat``) or
    in a ``mixed`` tree."""
    rng = random.Random(seed)
    frame = LocalFrame(58.54, 15.04)

    def point() -> tuple[float, float]:
        return rng.uniform(-5000.0, 5000.0), rng.uniform(-5000.0, 5000.0)

    units = [make_unit(f"u{i}", "air", frame.geopoint(*point()), ["move-to"])
             for i in range(n_units)]
    speeds = ("slow", "standard", "fast")
    children = [{"name": "move-to", "params": {"speed": speeds[rng.randrange(3)],
                                               "waypoint": frame.geopoint(*point()).to_wire()}}
                for _ in range(n_tasks)]
    if shape == "mixed":
        children = _mixed(children, rng)
    return parse_tree({"name": "conc", "children": children}), units


def _mixed(leaves: list[dict[str, Any]], rng: random.Random) -> list[dict[str, Any]]:
    """Half single tasks, half seqs of 2-4 (some ending in a small conc)."""
    out: list[dict[str, Any]] = []
    i = 0
    while i < len(leaves):
        roll = rng.random()
        if roll < 0.5:
            out.append(leaves[i])
            i += 1
            continue
        group = leaves[i : i + rng.randint(2, 4)]
        i += len(group)
        if len(group) >= 3 and roll > 0.85:
            group = [group[0], {"name": "conc", "children": group[1:]}]
        out.append({"name": "seq", "children": group} if len(group) > 1 else group[0])
    return out


def speed(repeats: int) -> None:
    print("\n== auction speed, end to end (plan_mission), move-tos ==")
    print(f"{'units x tasks':>14} {'tree':<6} {'objective':<9} {'median s':>9} {'max s':>7} "
          f"{'target s':>9}")
    for n_units, n_tasks, target in ((20, 100, 0.2), (200, 1000, 10.0)):
        for shape in ("flat", "mixed"):
            tree, units = random_fleet(n_units, n_tasks, seed=7, shape=shape)
            for objective in ("makespan", "total"):
                times = []
                for _ in range(repeats if n_tasks <= 100 else max(1, repeats // 3)):
                    plan = plan_mission(tree, units, strategy="auction", objective=objective)
                    times.append(plan.solve_time)
                    assert plan.feasible
                print(f"{n_units:>5} x {n_tasks:<6} {shape:<6} {objective:<9} "
                      f"{statistics.median(times):>9.3f} {max(times):>7.3f} {target:>9.1f}")


def mixed_quality(time_limit: float) -> None:
    print(f"\n== mixed trees, 20 units x 100 move-tos (optimal: {time_limit:g} s) ==")
    print(f"{'seed':>4} {'objective':<9} {'nearest':>9} {'auction':>9} {'optimal':>9} "
          f"{'opt/auc':>8}")
    for seed in (1, 2, 3):
        tree, units = random_fleet(20, 100, seed=seed, shape="mixed")
        for objective in ("makespan", "total"):
            values = []
            for strategy in ("nearest", "auction", "optimal"):
                plan = plan_mission(tree, units, strategy=strategy, objective=objective,
                                    time_limit=time_limit)
                values.append(plan.makespan if objective == "makespan" else plan.total_time)
            print(f"{seed:>4} {objective:<9} {values[0]:>9.0f} {values[1]:>9.0f} "
                  f"{values[2]:>9.0f} {values[2] / values[1]:>8.3f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 s solver limit, fewer repeats")
    args = parser.parse_args(argv)
    if not BERLIN.exists():
        print(f"missing {BERLIN}", file=sys.stderr)
        return 1
    reference(2.0 if args.quick else 10.0)
    speed(3 if args.quick else 9)
    mixed_quality(2.0 if args.quick else 5.0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
