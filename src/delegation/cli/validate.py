"""``delegation validate FILE...``: check a TST or any WARA-PS command/message.

Prints ``OK`` and what the file holds, or one line per problem (file, node or message, field,
what is wrong); exit 0 when every file is valid, 1 otherwise.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "validate",
        help="check a TST or a command (start-tst, start-task, delegate, ...) from a file",
        description=(
            "Check a Task Specification Tree, or any WARA-PS command or message, read from FILE "
            "('-' for standard input). A command carrying a tree (start-tst, delegate, get-bids) "
            "has its tree checked against the task catalogue too. Exit 0 when valid, 1 otherwise."
        ),
    )
    parser.add_argument("files", nargs="+", metavar="FILE",
                        help="JSON or YAML file, a scenario file, or - for stdin (JSON)")
    parser.set_defaults(func=run)


def _read(name: str) -> bytes:
    if name == "-":
        return sys.stdin.buffer.read()
    with open(name, "rb") as handle:
        return handle.read()


def _as_json(name: str, payload: bytes) -> bytes:
    """YAML files (``.yaml``/``.yml``) as JSON, as ``submit`` and ``plan`` read them; anything
    else as it is."""
    import json

    import yaml

    from delegation.safe_yaml import load_yaml

    if not name.lower().endswith((".yaml", ".yml")):
        return payload
    try:
        return json.dumps(load_yaml(payload)).encode("utf-8")
    except (yaml.YAMLError, TypeError, ValueError, RecursionError):
        return payload  # check_bytes names the problem


def _scenario_summary(name: str, payload: bytes) -> str | None:
    """``OK: scenario ...`` or the problems, for a scenario file (fleet + mission); None for
    anything else."""
    import json

    import yaml

    from delegation.errors import InputError
    from delegation.safe_yaml import load_yaml
    from delegation.scenario import scenario_from_dict

    try:
        data = (json.loads(payload) if name.lower().endswith(".json")
                else load_yaml(payload))
    except (ValueError, RecursionError, yaml.YAMLError):
        return None  # check_bytes says what is wrong
    if not (isinstance(data, dict) and "agents" in data and "mission" in data):
        return None
    try:
        scenario = scenario_from_dict(data, name)
    except InputError as exc:
        return str(exc)
    tasks = sum(1 for _ in _tasks(scenario.tree()))
    return f"OK: scenario {scenario.name}, {len(scenario.agents)} agents, {tasks} tasks"


def _tasks(tree: Any) -> Any:
    from delegation.tst.node import walk

    return (n for _, n in walk(tree) if not n.is_control)


def _option_problems(message: Any) -> list[Any]:
    """A ``delegate``'s strategy, objective and time limit, by the rule a default service applies
    (`service.jobs.plan_options`): the message codec cannot know which strategies are installed,
    so a name that is neither built in nor installed passed as OK and failed only when sent."""
    from delegation.errors import InputError, InputProblem
    from delegation.messages.delegation_api import Delegate
    from delegation.service.config import ServiceConfig
    from delegation.service.jobs import PlanOptions, plan_options

    if not isinstance(message, Delegate):
        return []
    config = ServiceConfig()
    defaults = PlanOptions(config.strategy, config.objective, config.time_limit)
    try:
        plan_options(message.strategy, message.objective, message.time_limit,
                     defaults=defaults, max_time_limit=config.max_time_limit)
    except InputError as exc:
        return [InputProblem(message.command, p.field, p.message) for p in exc.problems]
    return []


def run(args: argparse.Namespace) -> int:
    from delegation.messages.check import check_bytes

    failed = False
    for name in args.files:
        label = "<stdin>" if name == "-" else name
        try:
            payload = _read(name)
        except OSError as exc:
            print(f"{label}: cannot read: {exc.strerror or exc}")
            failed = True
            continue
        scenario = _scenario_summary(name, payload)
        if scenario is not None:
            ok = scenario.startswith("OK")
            failed |= not ok
            print(f"{label}: {scenario}" if ok else scenario)  # problems name the file already
            continue
        result = check_bytes(_as_json(name, payload), source="")
        if result.ok:
            result.problems.extend(_option_problems(result.message))
        if result.ok:
            print(f"{label}: OK: {result.summary}")
            continue
        failed = True
        for problem in result.problems:
            print(f"{label}: {problem}" if problem.where else f"{label}: {problem.message}")
    return 1 if failed else 0
