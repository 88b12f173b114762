"""What ``delegation plan`` plans: a scenario, or a mission file with a fleet from a file
(``--fleet``) or from a running service (``--live`` / ``--broker``: its list-agents, with the
speeds it learnt)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from delegation.errors import InputError, InputProblem
from delegation.fleet import UnitState
from delegation.tst.node import TstNode


def mission_and_fleet(args: argparse.Namespace) -> tuple[str, TstNode, list[UnitState], list[str]]:
    """(title, tree, units, notes about the fleet) for the plan command's arguments."""
    from delegation.cli.inputs import find_scenario, read_mission
    from delegation.scenario import load_scenario, read_document
    from delegation.tst.validate import parse_and_validate

    live = bool(args.live or args.broker)
    if not live and not args.fleet:
        path = find_scenario(args.scenario)
        data = read_document(path)
        if isinstance(data, dict) and "agents" not in data and "name" in data:
            raise InputError(InputProblem(
                args.scenario, "", "this is a mission (a TST), not a scenario: give a fleet with "
                "--fleet SCENARIO or plan for the live fleet with --live/--broker HOST"))
        scenario = load_scenario(path)
        return scenario.name, scenario.tree(), scenario.units(), []
    tree = parse_and_validate(read_mission(str(args.scenario)))
    if args.fleet:
        return f"{Path(args.scenario).name} on {args.fleet}", tree, fleet_from_file(args.fleet), []
    units, notes = live_fleet(args)
    return f"{Path(args.scenario).name} on the live fleet", tree, units, notes


def fleet_from_file(path: str) -> list[UnitState]:
    """The agents of a scenario file (or of a file holding only ``agents:``)."""
    from pydantic import ValidationError

    from delegation.cli.inputs import find_scenario
    from delegation.scenario import AgentSpec, read_document

    data = read_document(find_scenario(path))
    agents = data.get("agents") if isinstance(data, dict) else data
    if not isinstance(agents, list) or not agents:
        raise InputError(InputProblem(
            path, "agents", "a fleet file needs a non-empty 'agents' list"))
    units = []
    for i, raw in enumerate(agents):
        try:
            units.append(AgentSpec.model_validate(raw).unit())
        except ValidationError as exc:
            err = exc.errors()[0]
            field = ".".join(str(x) for x in err["loc"])
            raise InputError(InputProblem(path, f"agents[{i}].{field}", err["msg"])) from None
    return units


def live_fleet(args: argparse.Namespace) -> tuple[list[UnitState], list[str]]:
    """The units a running service would plan for, from its ``list-agents``."""
    from delegation.cli.connect import client_settings
    from delegation.fleet import make_unit
    from delegation.geo import GeoPoint
    from delegation.runtime.client import ServiceClient

    with ServiceClient(client_settings(args), prefix=args.prefix, service=args.service) as client:
        rows = client.list_agents()
    if not rows:
        raise InputError(InputProblem(args.service, "list-agents", "no live units to plan for"))
    units, notes = [], []
    for row in rows:
        pos = row.get("position")
        if not isinstance(pos, dict):
            continue
        units.append(make_unit(str(row["name"]), str(row.get("type") or "air"),
                               GeoPoint.model_validate(pos), list(row.get("tasks-available", [])),
                               speeds=_speeds(row), battery=row.get("battery")))
        if row.get("speeds-source") == "default":
            notes.append(f"unit /{row['name']}: speeds are the {row.get('type')} defaults "
                         "(the service has no profile and learnt nothing yet)")
    return units, notes


def _speeds(row: dict[str, Any]) -> dict[str, float] | None:
    speeds = row.get("speeds")
    return {k: float(v) for k, v in speeds.items()} if isinstance(speeds, dict) else None
