"""``delegation demo``, ``serve``, ``submit`` and ``agents``: the service and its users on MQTT.

Thin: parse arguments, start or reach the pieces (broker, simulated fleet, engine, service), call
the client, render with rich. Broker settings come from ``WARAPS_*`` like the WARA-PS example
agents, with matching flags.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import threading
import time
from contextlib import ExitStack, suppress
from pathlib import Path
from typing import TYPE_CHECKING, Any

from delegation.cli.options import (
    Stopped,
    UsageError,
    env_flag,
    env_port,
    port_number,
    positive_float,
)
from delegation.cli.plan import OBJECTIVE_CHOICES, STRATEGY_CHOICES
from delegation.cli.ui import add_http_args
from delegation.errors import DelegationError, InputError, InputProblem
from delegation.topics import AGENT_TYPES, ROLES
from delegation.tst import without_node_uuids

if TYPE_CHECKING:
    from rich.console import Console

    from delegation.render.progress import MissionProgress
    from delegation.runtime.client import ServiceClient
    from delegation.runtime.settings import BrokerSettings

log = logging.getLogger(__name__)

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


# --------------------------------------------------------------------------- arguments


def add_broker_args(parser: argparse.ArgumentParser) -> None:
    """``--broker/--port/--tls/--ca-file/--cert-file/--key-file/--username/--password-file``,
    defaulting to ``WARAPS_*``; a password never has to be given on the command line."""
    g = parser.add_argument_group("broker (defaults from WARAPS_* environment variables)")
    g.add_argument(
        "--broker", default=None, metavar="HOST",
        help="MQTT broker host [WARAPS_BROKER, else 127.0.0.1]",
    )
    g.add_argument("--port", default=None, type=port_number,
                   help="broker port [WARAPS_PORT, 1883 or 8883 with TLS]")
    g.add_argument(
        "--tls", action="store_true", default=None, help="connect with TLS [WARAPS_TLS_CONNECTION]"
    )
    g.add_argument(
        "--ca-file",
        default=None,
        metavar="PEM",
        help="CA to verify the broker with (implies --tls) [WARAPS_CA_FILE]",
    )
    g.add_argument(
        "--cert-file",
        default=None,
        metavar="PEM",
        help="client certificate (implies --tls) [WARAPS_CERT_FILE]",
    )
    g.add_argument(
        "--key-file", default=None, metavar="PEM", help="client certificate's key [WARAPS_KEY_FILE]"
    )
    g.add_argument("--username", default=None, help="[WARAPS_USERNAME]")
    g.add_argument(
        "--password-file",
        default=None,
        metavar="FILE",
        help="file whose first line is the password [WARAPS_PASSWORD_FILE; or the "
        "password itself in WARAPS_PASSWORD]",
    )
    g.add_argument("--password", default=None, help=argparse.SUPPRESS)  # visible in ps: avoid
    g.add_argument("--prefix", default="waraps", help="first topic level (default: waraps)")


def broker_settings(args: argparse.Namespace) -> BrokerSettings | None:
    """Flags over environment; None when neither names a broker host (``demo`` then starts its
    own). Bad ``WARAPS_*`` values are a `UsageError` naming the variable."""
    host = args.broker or (os.environ.get("WARAPS_BROKER") or "").strip()
    if not host:
        return None
    return client_settings(args)


def client_settings(args: argparse.Namespace) -> BrokerSettings:
    """The one rule for every command that joins a broker: ``--broker``, else ``WARAPS_BROKER``,
    else 127.0.0.1 (like ``mosquitto_sub``); port, TLS (CA file, client certificate and key) and
    login (the password from a file, never needed on the command line) from flags over
    ``WARAPS_*``."""
    from delegation.runtime.settings import BrokerSettings, read_password_file

    env = os.environ
    host = args.broker or (env.get("WARAPS_BROKER") or "").strip() or "127.0.0.1"
    tls = args.tls if args.tls is not None else bool(env_flag(env, "WARAPS_TLS_CONNECTION"))
    port = args.port or env_port(env) or None
    username = args.username if args.username is not None else env.get("WARAPS_USERNAME", "")
    if getattr(args, "password_file", None):
        password = read_password_file(args.password_file)
    elif getattr(args, "password", None) is not None:
        password = args.password
    elif env.get("WARAPS_PASSWORD"):
        password = env["WARAPS_PASSWORD"]
    elif env.get("WARAPS_PASSWORD_FILE"):
        password = read_password_file(env["WARAPS_PASSWORD_FILE"])
    else:
        password = ""

    def pick(flag: str, variable: str) -> str | None:
        value = getattr(args, flag, None)
        return str(value) if value else (env.get(variable) or None)

    return BrokerSettings.from_values(
        host=host,
        port=port,
        tls=bool(tls),
        username=username,
        password=password,
        ca_certs=pick("ca_file", "WARAPS_CA_FILE"),
        certfile=pick("cert_file", "WARAPS_CERT_FILE"),
        keyfile=pick("key_file", "WARAPS_KEY_FILE"),
    )


def register(subparsers: Any) -> None:
    _register_demo(subparsers)
    _register_serve(subparsers)
    _register_submit(subparsers)
    _register_agents(subparsers)


def _register_demo(subparsers: Any) -> None:
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
        "--hold", action="store_true",
        help="with --http: keep the system and the page up after the missions until Ctrl-C",
    )
    add_http_args(demo, default=None)
    add_broker_args(demo)
    demo.set_defaults(func=_demo)


def _register_serve(subparsers: Any) -> None:
    serve = subparsers.add_parser("serve", help="run the delegation service on a broker")
    _service_args(serve)
    serve.add_argument(
        "--state",
        default=None,
        metavar="PATH|DSN",
        help="where missions and answers survive a restart: an SQLite file (default "
        "$XDG_STATE_HOME/delegation/NAME.sqlite, ~/.local/state when unset; ':memory:' keeps "
        "nothing) or postgresql://... (shared: one instance active, the others stand by)",
    )
    serve.add_argument(
        "--retention",
        type=float,
        default=600.0,
        metavar="SECONDS",
        help="ended missions leave memory after this long (they stay in the store; default 600)",
    )
    serve.add_argument(
        "--operator",
        action="append",
        default=[],
        metavar="NAME",
        help="may query, cancel and signal every mission (repeatable)",
    )
    serve.add_argument(
        "--max-speed",
        type=float,
        default=100.0,
        metavar="M/S",
        help="the highest explicit speed a task may ask for (default 100)",
    )
    add_http_args(serve, default=None)
    add_broker_args(serve)
    serve.set_defaults(func=_serve)


def _register_submit(subparsers: Any) -> None:
    submit = subparsers.add_parser(
        "submit", help="send a mission to a running service and follow it to the end"
    )
    submit.add_argument(
        "mission", help="a TST (JSON/YAML), a scenario file, or a start-tst/delegate command file"
    )
    submit.add_argument("--service", default="delegator0", help="the service's unit name")
    submit.add_argument(
        "--wait",
        type=float,
        default=10.0,
        help="seconds to wait for the service's heartbeat (default 10)",
    )
    submit.add_argument("--strategy", default=None, choices=STRATEGY_CHOICES)
    submit.add_argument("--objective", default=None, choices=OBJECTIVE_CHOICES)
    submit.add_argument("--time-limit", type=positive_float, default=None,
                        help="planner time limit (s; default: the service's)")
    submit.add_argument(
        "--speedup",
        type=positive_float,
        default=1.0,
        help="the fleet's time factor, to show actual times in mission seconds",
    )
    submit.add_argument(
        "--timeout",
        type=positive_float,
        default=3600.0,
        help="stop following after this many seconds (exit 1)",
    )
    submit.add_argument(
        "--enough",
        action="store_true",
        help="send $enough to open-ended tasks (look-at-*) once all others ended",
    )
    submit.add_argument("--json", action="store_true",
                        help="progress on stderr; the mission (query-mission) as JSON on stdout")
    add_broker_args(submit)
    submit.set_defaults(func=_submit)


def _register_agents(subparsers: Any) -> None:
    agents = subparsers.add_parser("agents", help="list the live units a broker shows")
    agents.add_argument(
        "--wait", type=float, default=3.0, help="seconds to listen for heartbeats (default 3)"
    )
    agents.add_argument("--format", choices=("table", "json"), default="table")
    agents.add_argument("--json", dest="format", action="store_const", const="json",
                        help="same as --format json")
    add_broker_args(agents)
    agents.set_defaults(func=_agents)


def _fraction(text: str) -> float:
    """A number in 0..1 (argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text} is not in 0..1")
    return value


def _service_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--name", default="delegator0", help="the service's unit name")
    p.add_argument("--engine", default="op0", help="the TST engine's unit name")
    p.add_argument(
        "--strategy",
        default="auction",
        choices=STRATEGY_CHOICES,
        help="default strategy for start-tst",
    )
    p.add_argument("--objective", default="makespan", choices=OBJECTIVE_CHOICES)
    p.add_argument("--time-limit", type=float, default=2.0)
    p.add_argument("--agent-type", default="ground", choices=AGENT_TYPES,
                   help="agent-type in the heartbeat topic (default ground)")
    p.add_argument("--role", default="simulation", choices=ROLES,
                   help="role level of the topic (default simulation)")
    p.add_argument(
        "--profiles",
        default=None,
        metavar="FILE",
        help="what heartbeats do not tell (speeds, endurance, home, camera): a "
        "scenario file (its agents) or a YAML/JSON object keyed by unit name or "
        "agent type",
    )
    p.add_argument("--min-battery", type=_fraction, default=0.2, metavar="FRACTION",
                   help="units with a battery below this (0..1) are not planned for")
    p.add_argument("--commitments", default="wait", choices=("wait", "exclude", "share"),
                   help="a unit busy in another mission: planned from when and where it is free "
                   "(wait), left out (exclude), or ignored (share)")


# --------------------------------------------------------------------------- scenarios


def find_scenario(name: str) -> Path:
    """A scenario by path, or by name under the project's ``scenarios/`` directory.

    Looked up: the path as given; ``scenarios/<name>`` under the working directory and its
    parents; the source checkout this package runs from; ``DELEGATION_SCENARIOS``.
    """
    given = Path(name)
    if given.is_file():
        return given
    names = [given.name] if given.suffix else [f"{given.name}.yaml", f"{given.name}.json"]
    dirs: list[Path] = []
    if os.environ.get("DELEGATION_SCENARIOS"):
        dirs.append(Path(os.environ["DELEGATION_SCENARIOS"]))
    cwd = Path.cwd()
    dirs += [d / "scenarios" for d in (cwd, *cwd.parents)]
    here = Path(__file__).resolve()
    dirs += [d / "scenarios" for d in here.parents]
    dirs.append(here.parents[1] / "scenarios")  # shipped as package data, if ever
    for d in dirs:
        for n in names:
            if (d / n).is_file():
                return d / n
    raise InputError(
        InputProblem(
            name,
            "",
            "no such scenario file (looked in ./scenarios and the project's scenarios/ directory)",
        )
    )


# --------------------------------------------------------------------------- following


def follow(
    client: ServiceClient,
    plan: dict[str, Any],
    *,
    speedup: float,
    console: Console,
    timeout: float,
    tracks: dict[str, list[Any]] | None = None,
    enough: bool = False,
    progress: MissionProgress | None = None,
) -> MissionProgress:
    """Show a mission's progress until it ends or ``timeout`` wall seconds pass: a live table on
    a terminal, else one plain line per change (logs, CI, ``tee``).

    With ``enough``, open-ended tasks (look-at-*) that hold the mission up (nothing else
    running) get ``$enough``, as an operator would send it, so that the mission can finish.
    ``progress`` continues a mission already under way (``delegation follow``).
    """
    from rich.live import Live

    from delegation.render.progress import MissionProgress, status_lines

    if progress is None:
        progress = MissionProgress(plan, speedup=speedup)
    deadline = time.monotonic() + timeout
    if not console.is_terminal:
        shown: dict[str, str] = {}

        def lines() -> None:
            for line in status_lines(progress, shown):
                console.print(line, soft_wrap=True, highlight=False)

        lines()
        _pump(client, progress, deadline, lines, tracks=tracks, enough=enough)
        return progress
    with Live(
        progress.table(), console=console, refresh_per_second=6, transient=False, auto_refresh=True
    ) as live:
        _pump(client, progress, deadline, lambda: live.update(progress.table()),
              tracks=tracks, enough=enough)
        live.update(progress.table())
    return progress


def _pump(
    client: ServiceClient,
    progress: MissionProgress,
    deadline: float,
    refresh: Any,
    *,
    tracks: dict[str, list[Any]] | None,
    enough: bool,
) -> None:
    """Feed the client's events to ``progress`` until the mission ends or the deadline."""
    import queue

    root = progress.root_uuid
    while not progress.done and time.monotonic() < deadline:
        if enough:
            _send_enough(client, progress, time.time())
        try:
            ev = client.events.get(timeout=0.25)
        except queue.Empty:
            continue
        if ev.kind == "position":
            if tracks is not None:
                tracks.setdefault(ev.unit, []).append(ev.data)
            continue
        data = ev.data
        if ev.kind == "mission" and data.get("root-uuid") == root:
            progress.on_mission(str(data.get("status")), str(data.get("fail-reason", "")), ev.at)
        elif ev.kind == "tst-feedback" and isinstance(data.get("node-uuid"), str):
            progress.on_node(data["node-uuid"], str(data.get("status")), ev.at)
        refresh()


def still_running_hint(console: Console, root: str, status: str = "running") -> None:
    """What an operator needs once a command stops following a mission that goes on."""
    console.print(
        f"mission {root} is still {status}; re-attach: delegation follow {root[:8]}; "
        f"cancel: delegation cancel {root[:8]}; end open-ended tasks: "
        f"delegation signal {root[:8]} '$enough'",
        soft_wrap=True,
    )


def _send_enough(client: ServiceClient, progress: MissionProgress, now: float) -> None:
    for node_uuid in progress.due_for_enough(now):
        progress.enough_sent.add(node_uuid)
        answer = client.request(
            {"command": "signal-tst-node", "node-uuid": node_uuid, "signal": "$enough"},
            api="tst",
            timeout=10.0,
        )
        if answer.get("response") != "ok":
            log.warning("$enough to %s: %s", node_uuid, answer.get("fail-reason"))


def run_mission(
    client: ServiceClient,
    command: dict[str, Any],
    console: Console,
    *,
    speedup: float,
    timeout: float,
    tracks: dict[str, list[Any]] | None = None,
    enough: bool = False,
    hint: bool = True,
) -> MissionProgress | None:
    """Send a ``delegate`` with ``start``, follow the mission live and print the summary; None
    (after saying why) when it was not started. With ``hint``, stopping early says how to
    re-attach to or cancel the mission, which goes on."""
    answer = client.request({**command, "command": "delegate", "start": True}, timeout=120.0)
    if answer.get("response") != "started":
        console.print(f"[red]not started[/]: {answer.get('fail-reason')}")
        return None
    started = time.monotonic()
    root = str(answer["plan"]["tst"].get("common_params", {}).get("node-uuid", ""))
    try:  # from here on a stop leaves a running mission behind: always say how to go on
        console.print(f"mission {root} started", soft_wrap=True)
        for note in answer["plan"].get("notes") or []:  # default speeds, suspicious input
            console.print(f"note: {note}", soft_wrap=True, highlight=False)
        progress = follow(
            client,
            answer["plan"],
            speedup=speedup,
            console=console,
            timeout=timeout,
            tracks=tracks,
            enough=enough,
        )
    except (KeyboardInterrupt, Stopped):
        console.print()
        if hint:
            still_running_hint(console, root)
        raise
    _print_summary(console, progress, time.monotonic() - started)
    if not progress.done:
        console.print(f"[red]gave up following after {timeout:g} s[/]")
        if hint:
            still_running_hint(console, root, progress.status)
    return progress


def _print_summary(console: Console, progress: MissionProgress, wall: float) -> None:
    console.print()
    console.print(progress.summary_table())
    plan = progress.plan
    status = progress.status
    style = "green" if progress.succeeded else "red"
    elapsed = progress.elapsed
    console.print(
        f"mission [{style}]{status}[/]"
        + (f": {progress.fail_reason}" if progress.fail_reason else "")
        + f"  plan makespan {float(plan.get('makespan') or 0):.0f} s"
        + (f", actual {elapsed:.0f} s" if elapsed is not None and progress.done else "")
        + f" (mission seconds; {wall:.1f} s wall at speedup {progress.speedup:g})"
    )


# --------------------------------------------------------------------------- demo


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

    from delegation.allocation import plan_mission
    from delegation.local import LocalSystem
    from delegation.render.mapplot import render_map
    from delegation.runtime.client import ServiceClient
    from delegation.scenario import load_scenario
    from delegation.service import ServiceConfig

    console = Console()
    t0 = time.monotonic()
    if args.http:
        from delegation.cli.ui import page_options

        page_options(args)  # usage errors before anything starts
    elif args.hold:
        raise UsageError("--hold needs --http HOST:PORT")
    scenario = load_scenario(find_scenario(args.scenario))
    units = scenario.units()
    speedup = args.speedup
    if speedup is None:
        # The auction's makespan (fast) is a good enough estimate to pick the speedup.
        offline = plan_mission(scenario.tree(), units, strategy="auction", objective=args.objective)
        speedup = max(1.0, round(float(offline.makespan or 0.0) / DEMO_TARGET_WALL_S, 1))
    if speedup <= 0:
        raise InputError(InputProblem("--speedup", "", "must be greater than 0"))
    console.print(f"[bold]{scenario.name}[/]: {len(units)} units, speedup {speedup:g}")

    with ExitStack() as stack:
        rates = demo_rates([(a.name, a.rate) for a in scenario.agents], speedup)
        config = ServiceConfig(
            prefix=args.prefix,
            strategy=args.strategy,
            objective=args.objective,
            time_limit=args.time_limit,
            profiles=None if args.no_profiles else scenario.profiles(),
        )
        system = LocalSystem(
            units, settings=broker_settings(args), config=config, speedup=speedup, rates=rates
        )
        stack.enter_context(system)
        settings = system.settings
        assert settings is not None
        if system.broker is not None:
            console.print(f"embedded broker on {settings.describe()}")
        if args.http:
            from delegation.cli.ui import start_page

            server = start_page(stack, args, settings, prefix=config.prefix, service=config.name,
                                time_scale=speedup)
            console.print(f"operator page on {server.url}", soft_wrap=True)
        client = ServiceClient(
            settings, prefix=config.prefix, service=config.name, track_positions=True,
            sender=args.sender,
        ).start()
        stack.callback(client.stop)

        tracks: dict[str, list[Any]] = {u.name: [u.position] for u in units}
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
                speedup=speedup,
                timeout=args.timeout,
                tracks=tracks,
                enough=True,
                hint=False,  # the demo stops the whole system: nothing goes on to re-attach to
            )
            if progress is None:
                return 1
            flown.append(progress)
            if not progress.succeeded:
                break
        if len(flown) > 1:
            _print_plan_vs_flown(console, flown)
        progress = flown[-1]
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        plan = progress.plan
        (out / "plan.json").write_text(json.dumps(plan, indent=2, sort_keys=True))
        path = render_map(
            plan,
            units,
            tracks,
            out / "map.png",
            title=f"{scenario.name}: {plan.get('strategy')} plan, "
            f"makespan {float(plan.get('makespan') or 0):.0f} s",
        )
        from delegation.render.gantt import flown_bars, render_gantt

        gantt = render_gantt(
            plan,
            out / "gantt.png",
            title=f"{scenario.name}: planned vs flown (mission seconds)",
            flown=flown_bars(progress.rows.values(), progress.elapsed),
        )
        console.print(
            f"map: {path}   gantt: {gantt}   plan: {out / 'plan.json'}   "
            f"({time.monotonic() - t0:.1f} s wall in all)"
        )
        if args.http and args.hold:
            console.print(f"still serving the page on {server.url}; Ctrl-C stops", soft_wrap=True)
            threading.Event().wait()
        return 0 if progress.succeeded else 1


# --------------------------------------------------------------------------- serve


def _serve(args: argparse.Namespace) -> int:
    from delegation.service import ServiceConfig
    from delegation.service.active import run_active
    from delegation.service.store import default_state_path, open_store

    settings = client_settings(args)
    config = ServiceConfig(
        name=args.name,
        prefix=args.prefix,
        engine=args.engine,
        strategy=args.strategy,
        objective=args.objective,
        time_limit=args.time_limit,
        agent_type=args.agent_type,
        role=args.role,
        profiles=_read_profiles(args.profiles) if args.profiles else None,
        min_battery=args.min_battery,
        commitments=args.commitments,
        operators=frozenset(args.operator),
        max_speed=args.max_speed,
    )
    if args.http:
        from delegation.cli.ui import page_options

        page_options(args)  # usage errors before the store is opened
    store = open_store(args.state or str(default_state_path(config.name)))
    page = ExitStack()
    if args.http:
        from delegation.cli.ui import start_page

        try:
            server = start_page(page, args, settings, prefix=config.prefix, service=config.name)
        except BaseException:
            page.close()
            store.close()
            raise
        print(f"operator page on {server.url}", flush=True)
    print(
        f"{config.name} serving on {settings.describe()} at {config.base_topic} "
        f"(engine {config.engine}, state {store.where}); Ctrl-C stops",
        flush=True,
    )
    try:
        # Serves until SIGINT/SIGTERM (`cli.options.Stopped` is raised in the wait), or exits 1
        # when the lock on a shared store is lost.
        code = run_active(settings, config, store, threading.Event(), retention=args.retention,
                          announce=lambda text: print(text, flush=True))
    finally:
        page.close()
        store.close()
        print(f"{config.name} stopped", flush=True)
    return code


def _read_profiles(path: str) -> dict[str, dict[str, Any]]:
    """Fleet profiles from a scenario file (its agents) or a plain object of profiles."""
    from delegation.scenario import load_scenario

    data = _read_object(path)
    if "agents" in data:
        return load_scenario(path).profiles()
    bad = [k for k, v in data.items() if not isinstance(v, dict)]
    if bad:
        raise InputError(
            InputProblem(path, bad[0], "a profile must be an object (speeds, endurance, home, ...)")
        )
    return data


# --------------------------------------------------------------------------- submit


def _read_object(path: str) -> dict[str, Any]:
    """A JSON or YAML file holding an object."""
    from delegation.scenario import read_document

    data = read_document(path)
    if not isinstance(data, dict):
        raise InputError(InputProblem(path, "", "must hold a JSON/YAML object"))
    return data


def _read_mission(path: str) -> dict[str, Any]:
    """A mission file: a TST, a scenario (its ``mission``) or a start-tst/delegate command."""
    data: Any = _read_object(path)
    if "mission" in data and "agents" in data:
        data = data["mission"]
    elif "tst" in data and "command" in data:
        data = data["tst"]
    if not isinstance(data, dict) or "name" not in data:
        raise InputError(
            InputProblem(
                path,
                "",
                "no TST found (expected a tree, a scenario or a start-tst/delegate command)",
            )
        )
    return data


def _submit(args: argparse.Namespace) -> int:
    from rich.console import Console

    from delegation.runtime.client import ServiceClient
    from delegation.tst.validate import parse_and_validate

    tree = _read_mission(args.mission)
    parse_and_validate(tree)  # a bad tree is answered here, before any broker is needed
    command: dict[str, Any] = {"tst": tree}
    for key, value in (
        ("strategy", args.strategy),
        ("objective", args.objective),
        ("time-limit", args.time_limit),
    ):
        if value is not None:
            command[key] = value
    settings = client_settings(args)
    with ServiceClient(
        settings, prefix=args.prefix, service=args.service, service_timeout=args.wait
    ) as client:
        progress = run_mission(
            client,
            command,
            Console(stderr=bool(args.json)),  # with --json, stdout holds the JSON alone
            speedup=args.speedup,
            timeout=args.timeout,
            enough=args.enough,
        )
        if args.json and progress is not None:
            print(json.dumps(client.query_mission(progress.root_uuid), indent=2))
    return 0 if progress is not None and progress.succeeded else 1


# --------------------------------------------------------------------------- agents


def _agents(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from delegation.fleet import FleetRegistry
    from delegation.messages import decode
    from delegation.runtime.mqtt import MqttClient

    settings = client_settings(args)
    registry = FleetRegistry()
    lock = threading.Lock()

    def sink(msg: Any) -> None:
        try:
            message = decode(msg.topic, msg.payload)
        except DelegationError:
            return
        with lock, suppress(DelegationError):
            registry.observe(msg.topic, message, time.time())

    client = MqttClient(settings, sink=sink)
    for rest in (
        "heartbeat",
        "direct_execution_info",
        "sensor_info",
        "sensor/position",
        "sensor/battery_state",
    ):
        client.subscribe(f"{args.prefix}/unit/+/+/+/{rest}")
    client.connect(timeout=max(args.wait, 1.0))  # --wait bounds the connect too
    try:
        threading.Event().wait(args.wait)
    finally:
        client.disconnect()
    with lock:
        rows = registry.agents(time.time(), alive_only=True)
    if args.format == "json":
        print(json.dumps(rows, indent=2))
        return 0
    table = Table(title=f"live units on {settings.describe()} under {args.prefix}/")
    for col in ("name", "type", "state", "position", "seen", "tasks-available"):
        table.add_column(col, no_wrap=col in ("name", "seen"), overflow="fold")
    now = time.time()
    for r in rows:
        pos = r["position"]
        seen = r.get("last-seen")
        levels = r.get("levels", [])
        state = str(r.get("state", "")) if "direct execution" in levels else ", ".join(levels)
        table.add_row(
            r["name"],
            str(r.get("type") or "?"),
            state,
            f"{pos['latitude']:.5f},{pos['longitude']:.5f}" if pos else "-",
            f"{now - seen:.0f}s ago" if isinstance(seen, int | float) else "-",
            ", ".join(r.get("tasks-available", [])) or "-",
        )
    Console().print(table)
    if not rows:
        print(f"no live units seen within {args.wait:g} s")
    return 0
