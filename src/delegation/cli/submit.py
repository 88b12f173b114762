"""``delegation submit``: send a mission to a running service and follow it to the end."""

from __future__ import annotations

import argparse
import json
from typing import Any

from delegation.cli.connect import add_broker_args, add_service_args, service_client
from delegation.cli.following import add_watch_args, run_mission, watch_from
from delegation.cli.inputs import read_mission
from delegation.cli.options import positive_float
from delegation.cli.plan import OBJECTIVE_CHOICES, STRATEGY_CHOICES


def register(subparsers: Any) -> None:
    submit = subparsers.add_parser(
        "submit", help="send a mission to a running service and follow it to the end"
    )
    submit.add_argument(
        "mission", help="a TST (JSON/YAML), a scenario file, or a start-tst/delegate command file"
    )
    add_service_args(submit)
    submit.add_argument("--strategy", default=None, choices=STRATEGY_CHOICES)
    submit.add_argument("--objective", default=None, choices=OBJECTIVE_CHOICES)
    submit.add_argument("--time-limit", type=positive_float, default=None,
                        help="planner time limit (s; default: the service's)")
    add_watch_args(submit)
    submit.add_argument("--json", action="store_true",
                        help="progress on stderr; the mission (query-mission) as JSON on stdout")
    add_broker_args(submit)
    submit.set_defaults(func=_submit)


def _submit(args: argparse.Namespace) -> int:
    from rich.console import Console

    from delegation.tst.validate import parse_and_validate

    tree = read_mission(args.mission)
    parse_and_validate(tree)  # a bad tree is answered here, before any broker is needed
    command: dict[str, Any] = {"tst": tree}
    for key, value in (
        ("strategy", args.strategy),
        ("objective", args.objective),
        ("time-limit", args.time_limit),
    ):
        if value is not None:
            command[key] = value
    with service_client(args) as client:
        progress = run_mission(
            client,
            command,
            Console(stderr=bool(args.json)),  # with --json, stdout holds the JSON alone
            watch_from(args),
        )
        if args.json and progress is not None:
            print(json.dumps(client.query_mission(progress.root_uuid), indent=2))
    return 0 if progress is not None and progress.succeeded else 1


# --------------------------------------------------------------------------- agents
