"""Series-parallel instantiation vs the old wrap rule (docs/protocol.md §8): prints the figures.

On generated mixed (conc-of-seq) scenarios, the auction's plan as sent today (planned on the
precedence graph, sent as the series-parallel tree or the old rule's tree, whichever simulates
shorter) against the auction planned and sent under the old rule alone (conc children sharing a
unit wrapped whole in a seq: ``Problem.wrap_subtrees``). Per scenario: both makespans (each the
simulation of the tree sent), the precedence graph's own makespan, the crude lower bound
(``allocation.bounds``), and the ratio new / old; then the geometric mean and range of the ratio.

    .venv/bin/python benchmarks/instantiation.py [--sizes 10x30,20x100] [--seeds 0,1,2]
        [--sites granso,linkoping,motala]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time

from delegation.allocation.auction import auction
from delegation.allocation.planner import make_plan
from delegation.allocation.problem import build_problem
from delegation.bench.generate import SITES, generate_scenario
from delegation.scenario import scenario_from_dict
from delegation.tst import with_defaults, with_uuids


def run(units: int, tasks: int, site: str, seed: int) -> dict[str, float]:
    """One scenario: the old rule's makespan, the new plan's, its precedence graph's, a bound."""
    data = generate_scenario(units=units, tasks=tasks, site=site, seed=seed, structure="mixed")
    scenario = scenario_from_dict(data)
    prepared = with_defaults(with_uuids(scenario.tree()))
    problem = build_problem(prepared, scenario.units())
    began = time.perf_counter()
    plan = make_plan(problem, auction(problem, "makespan"), prepared, strategy="auction",
                     objective="makespan", solve_time=0.0)
    took = time.perf_counter() - began
    old = auction(dataclasses.replace(problem, wrap_subtrees=True, cache={}), "makespan")
    return {"old": old.makespan, "new": plan.makespan,
            "precedence": plan.precedence_makespan or math.nan,
            "bound": plan.lower_bound or math.nan, "seconds": took,
            "series-parallel": float("series-parallel tree" in plan.notes[-1].split(",")[0])}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="10x30,20x100")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--sites", default=",".join(SITES))
    args = parser.parse_args(argv)
    sizes = [tuple(int(x) for x in s.split("x")) for s in args.sizes.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    sites = args.sites.split(",")
    print(f"{'scenario':<28} {'old s':>8} {'new s':>8} {'prec. s':>8} {'bound s':>8} "
          f"{'new/old':>8} {'tree':>6} {'plan s':>7}")
    ratios, graph_ratios, losses = [], [], []
    for units, tasks in sizes:
        for site in sites:
            for seed in seeds:
                r = run(units, tasks, site, seed)
                ratio = r["new"] / r["old"]
                ratios.append(ratio)
                graph_ratios.append(r["precedence"] / r["old"])
                losses.append(r["new"] / r["precedence"])
                tree = "sp" if r["series-parallel"] else "wrap"
                print(f"{f'{units}x{tasks} {site} seed {seed}':<28} {r['old']:8.0f} "
                      f"{r['new']:8.0f} {r['precedence']:8.0f} {r['bound']:8.0f} {ratio:8.2f} "
                      f"{tree:>6} {r['seconds']:7.2f}")
    for label, values in (("new/old makespan (the tree sent)", ratios),
                          ("precedence graph/old makespan", graph_ratios),
                          ("new/precedence graph (instantiation loss)", losses)):
        geo = math.exp(sum(math.log(x) for x in values) / len(values))
        print(f"{label}: geometric mean {geo:.2f}, range {min(values):.2f}-{max(values):.2f} "
              f"over {len(values)} scenarios")
    return 0


if __name__ == "__main__":
    sys.exit(main())
