"""optimal vs the auction on generated mixed (conc-of-seq) trees (issue 9, item 2): the figures.

Per scenario (seed 0, three sites): the auction planned and sent under the old wrap rule
(``Problem.wrap_subtrees``), the auction today, and ``optimal`` at the given time limit, each the
makespan of the tree sent; then the geometric mean of optimal / old auction.

    .venv/bin/python benchmarks/optimal_mixed.py [--one-core] [TIME_LIMIT] [SIZES] [SITES]
    .venv/bin/python benchmarks/optimal_mixed.py 10 10x30,20x100,50x300 granso,motala,linkoping

The search runs on both cores (a second process searches with another seed, as a composition root
wires it: ``use_second_core(launch)``); ``--one-core`` leaves the second core out.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time

from delegation.allocation import check_invariants, plan_mission
from delegation.allocation.auction import auction
from delegation.allocation.optimal.parallel import use_second_core
from delegation.allocation.problem import build_problem
from delegation.bench.generate import generate_scenario
from delegation.runtime.second_core import launch
from delegation.scenario import scenario_from_dict
from delegation.tst import with_defaults, with_uuids


def main(argv: list[str]) -> int:
    if "--one-core" in argv:
        argv = [a for a in argv if a != "--one-core"]
    else:
        use_second_core(launch)
    limit = float(argv[0]) if argv else 10.0
    sizes = [tuple(int(x) for x in s.split("x"))
             for s in (argv[1] if len(argv) > 1 else "10x30,20x100,50x300").split(",")]
    sites = (argv[2] if len(argv) > 2 else "granso,motala,linkoping").split(",")
    ratios, to_auction = [], []
    print(f"{'scenario':<18} {'old auction s':>13} {'auction s':>10} {'optimal s':>10} "
          f"{'opt/old':>8} {'opt/auction':>11} {'wall s':>7} {'invariants':>10}")
    for units, tasks in sizes:
        for site in sites:
            data = generate_scenario(units=units, tasks=tasks, site=site, seed=0,
                                     structure="mixed")
            scenario = scenario_from_dict(data)
            tree, fleet = scenario.tree(), scenario.units()
            problem = build_problem(with_defaults(with_uuids(tree)), fleet)
            old = auction(dataclasses.replace(problem, wrap_subtrees=True, cache={}),
                          "makespan").makespan
            now = plan_mission(tree, fleet, strategy="auction")
            began = time.perf_counter()
            best = plan_mission(tree, fleet, strategy="optimal", time_limit=limit)
            wall = time.perf_counter() - began
            ok = "ok" if not check_invariants(best, tree, fleet) else "BROKEN"
            ratios.append(best.makespan / old)
            to_auction.append(best.makespan / now.makespan)
            print(f"{f'{units}x{tasks} {site}':<18} {old:13.0f} {now.makespan:10.0f} "
                  f"{best.makespan:10.0f} {ratios[-1]:8.2f} {to_auction[-1]:11.2f} {wall:7.1f} "
                  f"{ok:>10}")
    for label, values in (("optimal / old-rule auction", ratios),
                          ("optimal / auction today", to_auction)):
        geo = math.exp(sum(math.log(x) for x in values) / len(values))
        print(f"{label}: geometric mean {geo:.2f}, range {min(values):.2f}-{max(values):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
