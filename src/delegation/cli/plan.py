"""``delegation plan SCENARIO``: plan a scenario's mission offline and print the plan.

``--format json`` prints exactly the plan of DESIGN 3.5 and nothing else on stdout; ``table``
(the default) renders a summary, the assignments and the unassigned tasks with rich.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

from delegation.allocation import OBJECTIVES, STRATEGIES

if TYPE_CHECKING:
    from delegation.allocation import Plan

#: The planner's names (``delegation.allocation``), for argparse ``choices``; ``cli.runtime``
#: imports these two.
STRATEGY_CHOICES: tuple[str, ...] = tuple(STRATEGIES)
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
    parser.add_argument("scenario", metavar="SCENARIO", help="scenario file (YAML or JSON)")
    parser.add_argument("--strategy", default="auction", choices=STRATEGY_CHOICES,
                        help="allocation strategy (default: auction)")
    parser.add_argument("--objective", default="makespan", choices=OBJECTIVE_CHOICES,
                        help="what to minimise (default: makespan, ties broken by total time)")
    parser.add_argument("--time-limit", type=float, default=5.0, metavar="S",
                        help="solver time limit in seconds for optimal (default: 5)")
    parser.add_argument("--engine-unit", default="op0", metavar="NAME",
                        help="the TST engine that runs control nodes (default: op0)")
    parser.add_argument("--format", default="table", choices=("table", "json"),
                        help="output format (default: table)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from delegation.allocation import plan_mission
    from delegation.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    plan = plan_mission(
        scenario.tree(),
        scenario.units(),
        strategy=args.strategy,
        objective=args.objective,
        time_limit=args.time_limit,
        engine_unit=args.engine_unit,
    )
    if args.format == "json":
        sys.stdout.write(json.dumps(plan.to_json(), indent=2) + "\n")
    else:
        render_table(plan, scenario.name)
    return 0


def _fmt(value: float | None, unit: str = "") -> str:
    return "-" if value is None else f"{value:,.1f}{unit}"


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
        console.print(f"[dim]{note}[/dim]")

    table = Table(title="assignments")
    for name, justify in (("unit", "left"), ("task", "left"), ("node-uuid", "left"),
                          ("start s", "right"), ("end s", "right"), ("travel s", "right"),
                          ("work s", "right"), ("distance m", "right")):
        table.add_column(name, justify=justify)  # type: ignore[arg-type]
    for a in sorted(plan.assignments, key=lambda a: (a.execunit, a.start)):
        table.add_row(a.execunit, a.name, a.node_uuid, _fmt(a.start), _fmt(a.end),
                      _fmt(a.travel_time), _fmt(a.work_time), _fmt(a.distance))
    console.print(table)
    if plan.unassigned:
        missing = Table(title="unassigned")
        missing.add_column("task")
        missing.add_column("node-uuid")
        missing.add_column("reason")
        for u in plan.unassigned:
            missing.add_row(u.name, u.node_uuid, u.reason)
        console.print(missing)
