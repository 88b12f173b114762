"""Min-max (and min-sum) quality of ``optimal`` on mTSP instances, idle and under load.

    .venv/bin/python benchmarks/minmax.py                 # 10 s per run, idle then loaded
    .venv/bin/python benchmarks/minmax.py --no-load --instances berlin52 --units 3

Instances (``benchmarks/data``): TSPLIB berlin52, the only TSPLIB file we have (no PyPI package
ships TSPLIB data and nothing else can be downloaded here), and three generated Euclidean instances
(``gen_instances`` below writes them; deterministic). Every unit starts and ends at node 1, 1 m/s,
so seconds = metres (``delegation.scenario.berlin52_scenario``).

Reference values: berlin52's are the best published (LKH-3, integer-rounded distances). The
generated instances have no published values: theirs are the best longest route any of our runs
found (``optimal`` at 60 s, and every run of this script so far), so a gap against them is a lower
estimate of the true gap. "Under load" runs the same while a second process burns one of the two
cores. Min-sum (objective ``total``, every unit used) is checked on berlin52 against the published
values.
"""

from __future__ import annotations

import argparse
import random
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from delegation.allocation.optimal import optimise
from delegation.allocation.optimal.parallel import use_second_core
from delegation.allocation.problem import build_problem
from delegation.allocation.schedule import Schedule
from delegation.runtime.second_core import launch
from delegation.scenario import berlin52_scenario
from delegation.tst import with_defaults, with_uuids

DATA = Path(__file__).resolve().parent / "data"
#: Min-max reference (m): per instance, per number of units. See the module docstring.
MIN_MAX = {
    "berlin52": {3: 3070.0, 5: 2440.0},  # published (LKH-3)
    "uni60": {3: 2440.2, 5: 1697.8},  # best found here (60 s runs; uni60/3 by the sweep restarts)
    "clu80": {3: 1422.2, 5: 1231.4},
    "uni100": {3: 3374.1, 5: 2749.0},
}
#: Min-sum, published (LKH-3), every unit making a tour.
MIN_SUM = {"berlin52": {3: 7735.0, 5: 8124.0}}


def gen_instances() -> None:
    """Write the generated instances (deterministic: fixed seeds, integer coordinates)."""
    def write(name: str, pts: list[tuple[float, float]], comment: str) -> None:
        lines = [f"NAME: {name}", "TYPE: TSP", f"COMMENT: {comment}", f"DIMENSION: {len(pts)}",
                 "EDGE_WEIGHT_TYPE: EUC_2D", "NODE_COORD_SECTION"]
        lines += [f"{i + 1} {x:.1f} {y:.1f}" for i, (x, y) in enumerate(pts)] + ["EOF"]
        (DATA / f"{name}.tsp").write_text("\n".join(lines) + "\n")

    def uniform(n: int, seed: int, depot: tuple[float, float]) -> list[tuple[float, float]]:
        rng = random.Random(seed)
        return [depot] + [(float(rng.randint(0, 1000)), float(rng.randint(0, 1000)))
                          for _ in range(n - 1)]

    def clustered(n: int, seed: int, k: int) -> list[tuple[float, float]]:
        rng = random.Random(seed)
        centres = [(rng.uniform(100, 900), rng.uniform(100, 900)) for _ in range(k)]
        pts: list[tuple[float, float]] = []
        while len(pts) < n - 1:
            cx, cy = rng.choice(centres)
            x, y = rng.gauss(cx, 60), rng.gauss(cy, 60)
            if 0 <= x <= 1000 and 0 <= y <= 1000:
                pts.append((float(round(x)), float(round(y))))
        return [(500.0, 500.0), *pts]

    write("uni60", uniform(60, 60, (500.0, 500.0)),
          "generated: 59 points uniform on [0,1000]^2 (random.Random(60)), depot (500,500)")
    write("clu80", clustered(80, 80, 6),
          "generated: 79 points in 6 Gaussian clusters (sigma 60, random.Random(80)), "
          "depot (500,500)")
    write("uni100", uniform(100, 100, (0.0, 0.0)),
          "generated: 99 points uniform on [0,1000]^2 (random.Random(100)), depot at the "
          "corner (0,0)")


def route_lengths(s: Schedule) -> list[float]:
    """Metres per unit: its tasks' travel and work plus the way home."""
    return [float(np.nansum(s.distance[o])) + float(s.home_distance[u]) if o else 0.0
            for u, o in enumerate(s.orders)]


def run(name: str, units: int, objective: str, limit: float) -> tuple[float, float]:
    """(the objective's value in m, seconds taken) of ``optimal`` on one instance."""
    scenario = berlin52_scenario(DATA / f"{name}.tsp", units)
    problem = build_problem(with_defaults(with_uuids(scenario.tree())), scenario.units())
    began = time.perf_counter()
    result = optimise(problem, objective, limit, use_all_units=objective == "total")
    took = time.perf_counter() - began
    lengths = route_lengths(result.schedule)
    return (max(lengths) if objective == "makespan" else sum(lengths)), took


def table(instances: list[str], units: list[int], limit: float, label: str) -> list[float]:
    """Print one line per instance and unit count; return the min-max gaps (%)."""
    gaps, sum_gaps = [], []
    print(f"== {label}: optimal, {limit:g} s ==")
    print(f"{'instance':<9} {'units':>5} {'objective':<9} {'found m':>9} {'reference':>10} "
          f"{'gap':>7} {'time s':>7}")
    for name in instances:
        for m in units:
            cases = [("makespan", MIN_MAX[name][m])]
            if name in MIN_SUM:
                cases.append(("total", MIN_SUM[name][m]))
            for objective, ref in cases:
                value, took = run(name, m, objective, limit)
                gap = 100 * (value / ref - 1)
                (gaps if objective == "makespan" else sum_gaps).append(gap)
                print(f"{name:<9} {m:>5} {objective:<9} {value:>9.1f} {ref:>10.1f} "
                      f"{gap:>+6.2f}% {took:>7.2f}", flush=True)
    print(f"min-max: worst gap {max(gaps):+.2f}%, mean {sum(gaps) / len(gaps):+.2f}%")
    if sum_gaps:
        print(f"min-sum: worst gap {max(sum_gaps):+.2f}%")
    return gaps


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--time-limit", type=float, default=10.0)
    parser.add_argument("--instances", default=",".join(MIN_MAX))
    parser.add_argument("--units", default="3,5")
    parser.add_argument("--no-load", action="store_true", help="skip the run under load")
    parser.add_argument("--generate", action="store_true", help="rewrite the generated files")
    parser.add_argument("--one-core", action="store_true", help="no helper process")
    args = parser.parse_args(argv)
    if not args.one_core:
        use_second_core(launch)  # as a composition root does: the planner's second core
    if args.generate:
        gen_instances()
    instances = args.instances.split(",")
    units = [int(m) for m in args.units.split(",")]
    table(instances, units, args.time_limit, "idle")
    if args.no_load:
        return 0
    burner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        table(instances, units, args.time_limit, "under load (a second process burns a core)")
    finally:
        burner.kill()
        burner.wait(5)
    return 0


if __name__ == "__main__":
    sys.exit(main())
