"""``delegation plan SCENARIO``: plan a scenario's mission offline and print the plan.

``--format json`` prints exactly the plan of docs/plan.md §1 and nothing else on stdout; ``table``
(the default) renders a summary, the assignments, each shared search's parts (DESIGN 3.11) and
the unassigned tasks with rich.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

from delegation.allocation import OBJECTIVES, STRATEGIES
from delegation.allocation.strategies import resolve_strategy
from delegation.cli.options import add_format_args
from delegation.errors import DelegationError

if TYPE_CHECKING:
    from rich.table import Table

    from delegation.allocation import Plan
    from delegation.allocation.plan import SharedSearch



class StrategyChoices:
    """argparse ``choices`` for ``--strategy``: the registry's names (listed in help), and any
    ``package.module:function`` spec, imported and registered when argparse checks it; a spec
    that cannot be used is refused with its reason (docs/strategies.md)."""

    def __iter__(self) -> Iterator[str]:
        return iter(list(STRATEGIES))

    def __len__(self) -> int:
        return len(STRATEGIES)

    def __contains__(self, value: object) -> bool:
        if not isinstance(value, str):
            return False
        if value in STRATEGIES or ":" not in value:
            return value in STRATEGIES
        try:
            resolve_strategy(value)
        except DelegationError as exc:
            raise argparse.ArgumentError(None, str(exc)) from None
        return True


#: The planner's names (``delegation.allocation``), for argparse ``choices``; ``cli.demo``,
#: ``cli.serve`` and ``cli.submit`` import these two, so ``plan``, ``serve``, ``submit`` and
#: ``demo`` accept the same strategies.
STRATEGY_CHOICES = StrategyChoices()
OBJECTIVE_CHOICES: tuple[str, ...] = tuple(o.value for o in OBJECTIVES)


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "plan",
        help="plan a scenario's mission offline (who does what, when)",
        description=(
            "Allocate the scenario's fleet to its mission with a strategy and print the plan: "
            "assignments with times and distances, unassigned tasks with reasons, and the fully "
            "instantiated tree (json)."
        ),
    )
    parser.add_argument("scenario", metavar="SCENARIO",
                        help="scenario file (YAML or JSON) or name under scenarios/; with --fleet "
                        "or --broker: a mission (TST, scenario or start-tst file)")
    parser.add_argument("--fleet", metavar="FILE", default=None,
                        help="plan for this fleet instead: a scenario file (its agents)")
    parser.add_argument("--live", action="store_true",
                        help="plan for the live fleet of a running service (list-agents, with "
                        "the speeds it learnt); broker from --broker/WARAPS_BROKER")
    parser.add_argument("--service", default="delegator0",
                        help="the service asked for the live fleet (default delegator0)")
    parser.add_argument("--strategy", default="auction", choices=STRATEGY_CHOICES,
                        metavar="STRATEGY",
                        help="allocation strategy: " + ", ".join(STRATEGY_CHOICES)
                        + " or package.module:function (default: auction)")
    parser.add_argument("--objective", default="makespan", choices=OBJECTIVE_CHOICES,
                        help="what to minimise (default: makespan, ties broken by total time)")
    parser.add_argument("--time-limit", type=float, default=5.0, metavar="S",
                        help="solver time limit in seconds for optimal (default: 5)")
    parser.add_argument("--no-split", dest="split", action="store_false",
                        help="never share a search among units (auction and optimal share a "
                        "search whose unit is free when that ends sooner)")
    parser.add_argument("--engine-unit", default="op0", metavar="NAME",
                        help="the TST engine that runs control nodes (default: op0)")
    add_format_args(parser)
    from delegation.cli.connect import add_broker_args

    add_broker_args(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Plan and print; exit 1 when the plan is infeasible (the plan is still printed)."""
    from delegation.allocation import plan_mission
    from delegation.cli.fleetfile import mission_and_fleet
    from delegation.learning import input_warnings

    name, tree, units, notes = mission_and_fleet(args)
    plan = plan_mission(
        tree,
        units,
        strategy=args.strategy,
        objective=args.objective,
        time_limit=args.time_limit,
        engine_unit=args.engine_unit,
        split=args.split,
    )
    plan.notes.extend([*input_warnings(tree, units), *notes])
    if args.format == "json":
        sys.stdout.write(json.dumps({**plan.to_json(), "notes": plan.notes}, indent=2) + "\n")
    else:
        render_table(plan, name)
    return 0 if plan.feasible else 1


def _fmt(value: float | None, unit: str = "") -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:,.1f}{unit}"


def _shared_table(search: SharedSearch) -> Table:
    """One shared search (DESIGN 3.11): a row per part, the bound and the gap in the title."""
    from rich.table import Table

    gap = "-" if search.gap is None else f"{100 * search.gap:.1f} %"
    table = Table(title=f"{search.name} {search.node_uuid} shared: {search.area_m2 / 1e6:.3f} km2, "
                        f"ends {_fmt(search.end, ' s')}, bound {_fmt(search.bound, ' s')}, "
                        f"gap {gap}")
    for name in ("unit", "part", "area m2", "sweep m", "start s", "end s"):
        table.add_column(name, justify="left" if name in ("unit", "part") else "right")
    for p in search.parts:
        table.add_row("/" + p.unit, p.name, f"{p.area_m2:,.0f}", _fmt(p.sweep_m), _fmt(p.start),
                      _fmt(p.end))
    return table


def render_table(plan: Plan, title: str) -> None:
    """The plan as rich tables on stdout."""
    from rich.console import Console
    from rich.table import Table

    console = Console()
    summary = Table(title=f"{title}: {plan.strategy_label} / {plan.objective}", show_header=False)
    summary.add_column("what")
    summary.add_column("value", justify="right")
    summary.add_row("feasible", "yes" if plan.feasible else "no")
    summary.add_row("makespan", _fmt(plan.makespan, " s"))
    summary.add_row("precedence makespan", _fmt(plan.precedence_makespan, " s"))
    summary.add_row("instantiation loss", _fmt(plan.instantiation_loss, " s"))
    summary.add_row("total time", _fmt(plan.total_time, " s"))
    summary.add_row("total distance", _fmt(plan.total_distance, " m"))
    summary.add_row("solve time", f"{plan.solve_time:.3f} s")
    summary.add_row("bound", _fmt(plan.bound, " s"))
    summary.add_row("gap", "-" if plan.gap is None else f"{100 * plan.gap:.2f} %")
    console.print(summary)
    for note in plan.notes:
        console.print(f"note: {note}", style="dim", highlight=False)

    # At 80 columns (a default terminal, a pipe) the node-uuid and the split of the time into
    # travel and work make the table unreadable: they are in --format json.
    wide = console.width >= 110
    columns = [("unit", "left"), ("task", "left"), *([("node-uuid", "left")] if wide else []),
               ("start s", "right"), ("end s", "right"),
               *([("travel s", "right"), ("work s", "right")] if wide else []),
               ("distance m", "right")]
    table = Table(title="assignments")
    for name, justify in columns:
        table.add_column(name, justify=justify, no_wrap=name != "task")  # type: ignore[arg-type]
    for a in sorted(plan.assignments, key=lambda a: (a.execunit, a.start)):
        cells = [a.execunit, a.name, *([a.node_uuid] if wide else []), _fmt(a.start),
                 _fmt(a.end), *([_fmt(a.travel_time), _fmt(a.work_time)] if wide else []),
                 _fmt(a.distance)]
        table.add_row(*cells)
    console.print(table)
    for search in plan.shared:
        console.print(_shared_table(search))
    if plan.unassigned:
        missing = Table(title="unassigned")
        missing.add_column("task")
        missing.add_column("node-uuid")
        missing.add_column("reason")
        for u in plan.unassigned:
            missing.add_row(u.name, u.node_uuid, u.reason)
        console.print(missing)
