"""``delegation serve``: the delegation service on a broker, its state in a store, optionally
with the operator page."""

from __future__ import annotations

import argparse
import threading
from collections.abc import Callable
from contextlib import ExitStack
from typing import TYPE_CHECKING, Any

from delegation.cli.connect import add_broker_args, client_settings
from delegation.cli.inputs import read_profiles
from delegation.cli.options import UsageError, fraction, positive_float
from delegation.cli.plan import OBJECTIVE_CHOICES, STRATEGY_CHOICES
from delegation.cli.ui import add_http_args
from delegation.topics import AGENT_TYPES, ROLES

if TYPE_CHECKING:
    from delegation.service.jobs import Job, JobResult


def register(subparsers: Any) -> None:
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
        "--store-bound",
        type=positive_float,
        default=60.0,
        metavar="SECONDS",
        help="a state store that keeps failing this long (disk full, database gone) makes this "
        "instance leave the broker, release its lock and exit 1, so a standby or a restart takes "
        "over; until then what is not stored waits and is retried (default 60)",
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
        type=positive_float,
        default=100.0,
        metavar="M/S",
        help="the highest explicit speed a task may ask for (default 100)",
    )
    add_http_args(serve, default=None)
    add_broker_args(serve)
    serve.set_defaults(func=_serve)


def _queue_size(value: str) -> int:
    """An argparse ``type`` for ``--planner-queue``: a whole number >= 1."""
    try:
        number = int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{value!r} is not a whole number") from None
    if number < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return number


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
    p.add_argument("--time-limit", type=positive_float, default=2.0, metavar="S",
                   help="default planner time limit (s, at most 60; default 2)")
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
    p.add_argument("--min-battery", type=fraction, default=0.2, metavar="FRACTION",
                   help="units with a battery below this (0..1) are not planned for")
    p.add_argument("--planner", default="process", choices=("process", "thread"),
                   help="plan in a child process beside the service, on another core (process, "
                   "the default: a plan never competes with answering for Python's lock, and a "
                   "crashed or hung plan is ended without the service), or on a thread of the "
                   "service's own process (thread)")
    p.add_argument("--planner-queue", type=_queue_size, default=1000, metavar="N", help="plans "
                   "waiting or being made past which a command that plans is refused (busy)")
    p.add_argument("--listen-round", type=float, default=1.2, metavar="SECONDS",
                   help="after starting, hold commands that plan until this long has been "
                   "listened (one round of the fleet's heartbeats) and the engine is heard, at "
                   "most 3 s (0: as soon as the engine is heard)")
    p.add_argument("--fleet", action="append", default=[], metavar="UNIT",
                   help="a unit this service manages (repeatable; default: every unit no other "
                   "delegator says it manages); said in its delegation_info")
    p.add_argument("--bid-window", type=float, default=1.0, metavar="SECONDS",
                   help="how long to wait for other delegators' offers before planning "
                   "(default 1; 0 plans with the own fleet only)")
    p.add_argument("--partner", action="append", default=[], metavar="NAME",
                   help="another delegator (or its TST engine) whose offer requests and "
                   "subtrees this service accepts (repeatable)")
    p.add_argument("--commitments", default="wait", choices=("wait", "exclude", "share"),
                   help="a unit busy in another mission: planned from when and where it is free "
                   "(wait), left out (exclude), or ignored (share)")


def _planner(kind: str) -> Callable[[Job], JobResult]:
    """The planner `serve` runs its jobs with (`--planner`)."""
    if kind == "thread":
        from delegation.service.jobs import run_job

        return run_job
    from delegation.service.planner_process import PlannerProcess

    return PlannerProcess()


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
        profiles=read_profiles(args.profiles) if args.profiles else None,
        min_battery=args.min_battery,
        commitments=args.commitments,
        operators=frozenset(args.operator),
        max_speed=args.max_speed,
        fleet=frozenset(args.fleet),
        bid_window=args.bid_window,
        federate=args.bid_window > 0,
        partners=frozenset(args.partner),
        planner_queue=args.planner_queue,
        listen_round=args.listen_round,
    )
    if config.time_limit > config.max_time_limit:
        raise UsageError(f"--time-limit: {config.time_limit:g} s is above the service's maximum "
                         f"of {config.max_time_limit:g} s")
    if args.http:
        from delegation.cli.ui import page_options

        page_options(args)  # usage errors before the store is opened
    resources = ExitStack()
    # First, while this process runs one thread and has opened nothing: a planner process is
    # then forked, not spawned (`PlannerProcess`), and inherits no lock, socket or database.
    planner = _planner(args.planner)
    close = getattr(planner, "close", None)
    if close is not None:
        resources.callback(close)
    try:
        store = open_store(args.state or str(default_state_path(config.name)))
    except BaseException:
        resources.close()
        raise
    if args.http:
        from delegation.cli.ui import start_page

        try:
            server = start_page(resources, args, settings, prefix=config.prefix,
                                service=config.name)
        except BaseException:
            resources.close()
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
        # when it gives up: the lock on a shared store lost, or the store failing too long.
        code = run_active(settings, config, store, threading.Event(), retention=args.retention,
                          store_bound=args.store_bound,
                          announce=lambda text: print(text, flush=True),
                          planner=planner)
    finally:
        resources.close()
        store.close()
        print(f"{config.name} stopped", flush=True)
    return code
