"""``delegation engine`` and ``delegation sim``: the reference TST engine and a simulated fleet.

Both run until interrupted (or for ``--duration`` seconds) on the broker named by the flags or the
``WARAPS_*`` environment, like the WARA-PS example agents.
"""

from __future__ import annotations

import argparse
import logging
import threading
from typing import Any

from delegation.cli.connect import add_broker_args, client_settings
from delegation.cli.inputs import find_scenario
from delegation.cli.options import add_duration_arg
from delegation.errors import InputError, InputProblem
from delegation.topics import AGENT_TYPES, ROLES

log = logging.getLogger(__name__)


def register(subparsers: Any) -> None:
    engine = subparsers.add_parser(
        "engine",
        help="run the reference TST engine (op0)",
        description="Executes fully instantiated TSTs sent to <prefix>/unit/<type>/<role>/<name>"
        "/tst/command by sending start-task to the units (seed section 14).",
    )
    engine.add_argument("--name", default="op0", help="the engine's unit name (default op0)")
    engine.add_argument("--agent-type", default="ground", choices=AGENT_TYPES,
                        help="agent-type in its topics (default ground)")
    engine.add_argument("--role", default="simulation", choices=ROLES,
                        help="role level of its topics (default simulation)")
    add_duration_arg(engine)
    add_broker_args(engine)
    engine.set_defaults(func=_engine)

    sim = subparsers.add_parser(
        "sim",
        help="run a simulated fleet: one unit per scenario agent",
        description="Simulated units speaking the Heartbeat, Sensor and Direct Execution APIs, "
        "one per agent of the scenario, at the agents' positions, speeds and tasks.",
    )
    sim.add_argument("scenario", help="scenario file (YAML/JSON) or name under scenarios/")
    sim.add_argument(
        "--speedup", type=float, default=1.0, help="simulated seconds per wall second (default 1)"
    )
    sim.add_argument("--role", default="simulation", choices=ROLES,
                     help="role level of the units' topics (default simulation)")
    sim.add_argument(
        "--example-agent",
        action="store_true",
        help="behave like the public WARA-PS example agent (message shapes and quirks)",
    )
    add_duration_arg(sim)
    add_broker_args(sim)
    sim.set_defaults(func=_sim)


def _settings(args: argparse.Namespace) -> Any:
    """The broker by the one rule of every command (``cli.connect.client_settings``)."""
    return client_settings(args)


def _wait(duration: float | None) -> None:
    """Block until ``duration`` passes, or SIGINT/SIGTERM (`cli.options.Stopped`, which the
    caller's ``finally`` turns into a clean stop and ``main`` into exit 130/0)."""
    threading.Event().wait(duration)


def _engine(args: argparse.Namespace) -> int:
    from delegation.engine import TstEngine

    settings = _settings(args)
    engine = TstEngine(
        settings, args.name, prefix=args.prefix, agent_type=args.agent_type, role=args.role
    )
    engine.start()
    print(f"TST engine {args.name} on {settings.describe()}: {engine.base}/tst/command")
    try:
        _wait(args.duration)
    finally:
        engine.stop()
    return 0


def _sim(args: argparse.Namespace) -> int:
    from delegation.scenario import load_scenario
    from delegation.sim import SimFleet, agent_rates

    if args.speedup <= 0:
        raise InputError(InputProblem("--speedup", "", f"must be positive, not {args.speedup}"))
    settings = _settings(args)
    scenario = load_scenario(find_scenario(args.scenario))
    fleet = SimFleet(
        settings,
        scenario.units(),
        rates=agent_rates(scenario),
        prefix=args.prefix,
        role=args.role,
        speedup=args.speedup,
        example_agent=args.example_agent,
    )
    fleet.start()
    print(
        f"{len(fleet)} simulated units from {scenario.name} on {settings.describe()} "
        f"(speed-up {args.speedup:g}): {', '.join(u.base for u in fleet)}"
    )
    try:
        _wait(args.duration)
    finally:
        fleet.stop()
    return 0
