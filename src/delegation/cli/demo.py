"""``delegation demo``: broker, simulated fleet, engine and service in one process; a scenario's
mission flown end to end, with live progress, a summary, a map and a Gantt chart."""

from __future__ import annotations

import argparse
import json
import math
import threading
import time
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from delegation.cli.connect import add_broker_args, broker_settings
from delegation.cli.following import Watch, run_mission
from delegation.cli.inputs import find_scenario
from delegation.cli.options import UsageError
from delegation.cli.plan import OBJECTIVE_CHOICES, STRATEGY_CHOICES
from delegation.cli.ui import add_http_args
from delegation.errors import InputError, InputProblem
from delegation.tst import without_node_uuids

if TYPE_CHECKING:
    from rich.console import Console

    from delegation.fleet import UnitState
    from delegation.render.progress import MissionProgress
    from delegation.runtime.client import ServiceClient
    from delegation.scenario import Scenario


DEFAULT_SCENARIO = "demo.yaml"
#: Wall seconds the demo aims to take for the planned mission when ``--speedup`` is not given.
DEMO_TARGET_WALL_S = 15.0
#: Status ticks per wall second for the whole simulated fleet of the demo (a tick is 9 messages,
#: each delivered to the service, the engine and the demo's client). At 10 Hz per unit, 20 units
#: published 1800 messages/s, past what the embedded broker carries (~5k msg/s with that
#: fan-out): every command queued behind them and a 20 x 100 mission flew 8.5 % late.
DEMO_FLEET_TICKS_PER_S = 40.0


def demo_rates(agents: list[tuple[str, float | None]], speedup: float) -> dict[str, float]:
    """Each unit's status rate in the demo: often enough for a smooth flown track at this speedup
    (<= 10 Hz), within the fleet's budget, never below the rate its scenario gives."""
    cap = min(10.0, DEMO_FLEET_TICKS_PER_S / max(1, len(agents)))
    return {name: max(rate or 1.0, min(cap, speedup / 2.0)) for name, rate in agents}


def register(subparsers: Any) -> None:
    demo = subparsers.add_parser(
        "demo",
        help="broker + simulated fleet + engine + service; run a scenario's mission end to end",
        description="Starts an embedded broker (unless --broker/WARAPS_BROKER names one), a "
        "simulated fleet and the reference engine from a scenario, and the delegation service; "
        "submits the scenario's mission, shows live progress, prints a summary and writes a map. "
        "Exit 0 when the mission succeeded.",
    )
    demo.add_argument(
        "--scenario",
        default=DEFAULT_SCENARIO,
        help=f"scenario file or name under scenarios/ (default {DEFAULT_SCENARIO})",
    )
    demo.add_argument("--strategy", default="auction", choices=STRATEGY_CHOICES)
    demo.add_argument("--objective", default="makespan", choices=OBJECTIVE_CHOICES)
    demo.add_argument("--time-limit", type=float, default=2.0, help="planner time limit (s)")
    demo.add_argument(
        "--speedup",
        type=float,
        default=None,
        help="simulation time factor (default: fit the plan into ~15 s)",
    )
    demo.add_argument("--out", default="demo-out", help="directory for map.png and plan.json")
    demo.add_argument(
        "--no-profiles", action="store_true",
        help="the service starts without the fleet's profile (type default speeds) and learns "
        "the speeds while it flies (with --missions 2, the second plan matches the flight)",
    )
    demo.add_argument(
        "--missions", type=_positive_int, default=1,
        help="run the scenario's mission this many times, one after the other (fresh node "
        "uuids), and print plan vs flown for each",
    )
    demo.add_argument(
        "--timeout",
        type=float,
        default=50.0,
        help="give up after this many wall seconds of execution",
    )
    demo.add_argument(
        "--federated", action="store_true",
        help="split the fleet in two partners (each half of the area, by where the units are): "
        "the second half runs under its own delegation service delegator-b with its own engine; "
        "the mission goes to delegator0, which asks delegator-b for offers (docs/protocol.md §15)",
    )
    demo.add_argument(
        "--bid-window", type=float, default=1.0, metavar="SECONDS",
        help="with --federated: how long delegator0 waits for delegator-b's offers (default 1; "
        "the round ends as soon as they are in)",
    )
    demo.add_argument(
        "--hold", action="store_true",
        help="with --http: keep the system and the page up after the missions until Ctrl-C",
    )
    add_http_args(demo, default=None)
    add_broker_args(demo)
    demo.set_defaults(func=_demo)


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return value


def _print_plan_vs_flown(console: Console, flown: list[MissionProgress]) -> None:
    """Per mission: the plan's makespan against the flown one (the service learns speeds from
    the flight, so with a wrong profile the first is off and the next close)."""
    console.print("plan vs flown, per mission (mission seconds):")
    for number, progress in enumerate(flown, start=1):
        plan = float(progress.plan.get("makespan") or 0.0)
        actual = progress.elapsed
        if actual is None or not plan:
            console.print(f"  mission {number}: plan {plan:.0f} s, flown -")
            continue
        console.print(f"  mission {number}: plan {plan:.0f} s, flown {actual:.0f} s "
                      f"({(plan - actual) / actual * 100.0:+.1f} % plan vs flown)")


def _demo(args: argparse.Namespace) -> int:
    from rich.console import Console

    from delegation.scenario import load_scenario

    console = Console()
    t0 = time.monotonic()
    if args.http:
        from delegation.cli.ui import page_options

        page_options(args)  # usage errors before anything starts
    elif args.hold:
        raise UsageError("--hold needs --http HOST:PORT")
    scenario = load_scenario(find_scenario(args.scenario))
    units = scenario.units()
    speedup = _speedup(args, scenario, units)
    console.print(f"[bold]{scenario.name}[/]: {len(units)} units, speedup {speedup:g}")

    with ExitStack() as stack:
        client, page_url = _start(stack, args, scenario, units, speedup, console)
        tracks: dict[str, list[Any]] = {u.name: [u.position] for u in units}
        flown = _fly(client, args, scenario, speedup, console, tracks)
        if flown is None:
            return 1
        if len(flown) > 1:
            _print_plan_vs_flown(console, flown)
        progress = flown[-1]
        shown = _write_results(Path(args.out), scenario.name, progress, units, tracks)
        console.print(f"{shown}   ({time.monotonic() - t0:.1f} s wall in all)")
        if page_url is not None and args.hold:
            console.print(f"still serving the page on {page_url}; Ctrl-C stops", soft_wrap=True)
            threading.Event().wait()
        return 0 if progress.succeeded else 1


def _speedup(args: argparse.Namespace, scenario: Scenario, units: list[UnitState]) -> float:
    """``--speedup``, else one that fits the planned mission into ~``DEMO_TARGET_WALL_S``."""
    from delegation.allocation import plan_mission

    speedup = args.speedup
    if speedup is None:
        # The auction's makespan (fast) is a good enough estimate to pick the speedup.
        offline = plan_mission(scenario.tree(), units, strategy="auction", objective=args.objective)
        speedup = max(1.0, round(float(offline.makespan or 0.0) / DEMO_TARGET_WALL_S, 1))
    if speedup <= 0:
        raise InputError(InputProblem("--speedup", "", "must be greater than 0"))
    return float(speedup)


def _start(
    stack: ExitStack,
    args: argparse.Namespace,
    scenario: Scenario,
    units: list[UnitState],
    speedup: float,
    console: Console,
) -> tuple[ServiceClient, str | None]:
    """Broker, fleet, engine and service (and the page with ``--http``) on ``stack``; the
    demo's client and the page's address."""
    from delegation.local import LocalSystem
    from delegation.runtime.client import ServiceClient
    from delegation.service import ServiceConfig

    rates = demo_rates([(a.name, a.rate) for a in scenario.agents], speedup)
    config = ServiceConfig(
        prefix=args.prefix,
        strategy=args.strategy,
        objective=args.objective,
        time_limit=args.time_limit,
        profiles=None if args.no_profiles else scenario.profiles(),
    )
    ours, theirs = split_partners(units) if args.federated else (units, [])
    if theirs:
        config = replace(config, fleet=frozenset(u.name for u in ours),
                         bid_window=args.bid_window, federate=args.bid_window > 0)
    system = LocalSystem(
        ours, settings=broker_settings(args), config=config, speedup=speedup, rates=rates
    )
    stack.enter_context(system)
    settings = system.settings
    assert settings is not None
    if system.broker is not None:
        console.print(f"embedded broker on {settings.describe()}")
    if theirs:
        _start_partner(stack, system, theirs, speedup, rates, console)
    page_url = None
    if args.http:
        from delegation.cli.ui import start_page

        server = start_page(stack, args, settings, prefix=config.prefix, service=config.name,
                            time_scale=speedup)
        page_url = server.url
        console.print(f"operator page on {page_url}", soft_wrap=True)
    client = ServiceClient(
        settings, prefix=config.prefix, service=config.name, track_positions=True,
        sender=args.sender,
    ).start()
    stack.callback(client.stop)
    return client, page_url


#: The demo's partner service with ``--federated``, and its engine.
PARTNER, PARTNER_ENGINE = "delegator-b", "op-b"


def split_partners(units: list[UnitState]) -> tuple[list[UnitState], list[UnitState]]:
    """Two halves of the fleet by where the units are (along the axis they spread most on):
    ours, and the partner's. A fleet of one is not split."""
    if len(units) < 2:
        return units, []
    lats = [u.position.latitude for u in units]
    lons = [u.position.longitude for u in units]
    # Degrees of longitude are shorter by cos(latitude); good enough to pick the axis.
    scale = math.cos(math.radians(sum(lats) / len(lats)))
    by_lon = (max(lons) - min(lons)) * scale > max(lats) - min(lats)
    ordered = sorted(units, key=lambda u: (u.position.longitude if by_lon
                                           else u.position.latitude, u.name))
    half = len(ordered) // 2
    return ordered[:half], ordered[half:]


def _start_partner(stack: ExitStack, system: Any, units: list[UnitState], speedup: float,
                   rates: dict[str, float], console: Console) -> None:
    """delegator-b with its engine and its half of the fleet, on the same broker; waits until
    delegator0 knows what it can do."""
    from delegation.local import LocalSystem

    ours = system.config
    config = replace(ours, name=PARTNER, engine=PARTNER_ENGINE,
                     fleet=frozenset(u.name for u in units),
                     partners=frozenset({ours.name, ours.engine}))
    partner = LocalSystem(units, settings=system.settings, config=config, speedup=speedup,
                          rates={u.name: rates[u.name] for u in units})
    stack.enter_context(partner)
    mine = sorted(ours.fleet)
    console.print(f"federated: {ours.name} manages {', '.join(mine)}; {PARTNER} (engine "
                  f"{PARTNER_ENGINE}) manages {', '.join(u.name for u in units)}")
    service = system.service
    known = service.wait_until(
        lambda core: any(d.name == PARTNER and d.tasks
                         for d in core.fleet.delegators(time.monotonic())), 15.0)
    if not known:
        raise InputError(InputProblem("--federated", "", f"{ours.name} did not hear {PARTNER}'s "
                                      "delegation_info within 15 s"))


def _fly(
    client: ServiceClient,
    args: argparse.Namespace,
    scenario: Scenario,
    speedup: float,
    console: Console,
    tracks: dict[str, list[Any]],
) -> list[MissionProgress] | None:
    """The scenario's mission ``--missions`` times (fresh node uuids after the first), until
    one fails; None when one was not started."""
    command = {
        "tst": scenario.mission,
        "strategy": args.strategy,
        "objective": args.objective,
        "time-limit": args.time_limit,
    }
    flown: list[MissionProgress] = []
    for number in range(args.missions):
        tree = scenario.mission if number == 0 else without_node_uuids(scenario.mission)
        progress = run_mission(
            client,
            {**command, "tst": tree},
            console,
            Watch(speedup, args.timeout, tracks=tracks, enough=True),
            hint=False,  # the demo stops the whole system: nothing goes on to re-attach to
        )
        if progress is None:
            return None
        flown.append(progress)
        if not progress.succeeded:
            break
    return flown


def _write_results(
    out: Path,
    name: str,
    progress: MissionProgress,
    units: list[UnitState],
    tracks: dict[str, list[Any]],
) -> str:
    """plan.json, map.png and gantt.png of the last mission under ``out``; where they went."""
    from delegation.render.gantt import flown_bars, render_gantt
    from delegation.render.mapplot import render_map

    out.mkdir(parents=True, exist_ok=True)
    plan = progress.plan
    (out / "plan.json").write_text(json.dumps(plan, indent=2, sort_keys=True))
    path = render_map(
        plan,
        units,
        tracks,
        out / "map.png",
        title=f"{name}: {plan.get('strategy')} plan, "
        f"makespan {float(plan.get('makespan') or 0):.0f} s",
    )
    gantt = render_gantt(
        plan,
        out / "gantt.png",
        title=f"{name}: planned vs flown (mission seconds)",
        flown=flown_bars(progress.rows.values(), progress.elapsed),
    )
    return f"map: {path}   gantt: {gantt}   plan: {out / 'plan.json'}"
