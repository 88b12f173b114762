"""Mission commands over MQTT: ``missions``, ``status``, ``cancel``, ``follow``, ``signal``,
``bids``, and ``completion`` for the shell.

Each talks to a running service through `delegation.runtime.client.ServiceClient` and its
Delegation API (list-missions, query-mission, cancel-mission, get-bids; signals on the TST face
as ``signal-tst-tree``). A mission id may be any unique prefix of its root-uuid (resolved with
list-missions); an unknown or ambiguous one is one line and exit 1. ``--json`` prints the
service's answer as JSON and nothing else on stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import TYPE_CHECKING, Any

from delegation.cli.connect import add_broker_args, add_service_args, service_client
from delegation.cli.following import add_watch_args, follow, still_running_hint, watch_from
from delegation.cli.options import positive_float

if TYPE_CHECKING:
    from rich.console import Console

    from delegation.render.progress import MissionProgress

#: What ``delegation signal`` may send to a whole mission (``cancel`` is ``$abort``).
SIGNALS: tuple[str, ...] = ("$enough", "$pause", "$continue")
MISSION_STATUSES: tuple[str, ...] = (
    "planned", "started", "running", "succeeded", "failed", "aborted", "active", "ended",
)


def register(subparsers: Any) -> None:
    p = _command(subparsers, "missions", "list the service's missions (newest last)")
    p.add_argument("--status", choices=MISSION_STATUSES,
                   help="only missions with this status (active: not ended; ended: any final)")
    p.set_defaults(func=_missions)

    p = _command(subparsers, "status", "one mission: its tree with each node's status, "
                 "plan vs actual times")
    p.add_argument("mission_id", metavar="ID", help="mission id or a unique prefix of it")
    p.add_argument("--speedup", type=positive_float, default=1.0,
                   help="the fleet's time factor, to show actual times in mission seconds")
    p.set_defaults(func=_status)

    p = _command(subparsers, "cancel", "abort a mission (answered once the engine confirmed)")
    p.add_argument("mission_id", metavar="ID", help="mission id or a unique prefix of it")
    p.set_defaults(func=_cancel)

    p = _command(subparsers, "follow", "re-attach to a mission and show its live progress")
    p.add_argument("mission_id", metavar="ID", help="mission id or a unique prefix of it")
    add_watch_args(p)
    p.set_defaults(func=_follow)

    p = _command(subparsers, "signal", "send $enough, $pause or $continue to a whole mission")
    p.add_argument("mission_id", metavar="ID", help="mission id or a unique prefix of it")
    p.add_argument("signal", choices=SIGNALS, help="quote it in the shell: '$enough'")
    p.set_defaults(func=_signal)

    p = _command(subparsers, "bids", "every task x live unit estimate for a mission file")
    p.add_argument("mission", help="a TST (JSON/YAML), a scenario file or a start-tst file")
    p.set_defaults(func=_bids)

    comp = subparsers.add_parser(
        "completion", help="print a shell completion script (bash, zsh or tcsh)",
        description="Print a completion script: "
        "'delegation completion bash > /etc/bash_completion.d/delegation' or "
        "'source <(delegation completion bash)'.",
    )
    comp.add_argument("shell", choices=("bash", "zsh", "tcsh"))
    comp.set_defaults(func=_completion)


def _command(subparsers: Any, name: str, text: str) -> argparse.ArgumentParser:
    p: argparse.ArgumentParser = subparsers.add_parser(name, help=text, description=text + ".")
    add_service_args(p)
    p.add_argument("--json", action="store_true", help="print JSON (nothing else on stdout)")
    add_broker_args(p)
    return p


def _print_json(data: Any) -> None:
    sys.stdout.write(json.dumps(data, indent=2) + "\n")


def _console() -> Console:
    from rich.console import Console

    return Console()


def _clock(epoch: Any) -> str:
    return time.strftime("%H:%M:%S", time.localtime(epoch)) if isinstance(epoch, int | float) \
        else "-"


# --------------------------------------------------------------------------- missions


def _missions(args: argparse.Namespace) -> int:
    from rich.table import Table

    with service_client(args) as client:
        rows = client.list_missions()
    if args.status == "active":
        rows = [r for r in rows if r.get("status") not in ("succeeded", "failed", "aborted")]
    elif args.status == "ended":
        rows = [r for r in rows if r.get("status") in ("succeeded", "failed", "aborted")]
    elif args.status:
        rows = [r for r in rows if r.get("status") == args.status]
    if args.json:
        _print_json(rows)
        return 0
    table = Table(title=f"missions of {args.service}", title_justify="left",
                  caption="ID: the first 8 characters; any unique prefix works")
    for col in ("ID", "name", "status", "created", "ended", "reason"):
        table.add_column(col, no_wrap=col != "reason", overflow="fold")
    for r in rows:
        table.add_row(str(r.get("root-uuid", ""))[:8], str(r.get("name", "")),
                      str(r.get("status", "")), _clock(r.get("created")), _clock(r.get("ended")),
                      str(r.get("fail-reason") or ""))
    _console().print(table)
    if not rows:
        print("no missions" + (f" with status {args.status}" if args.status else ""))
    return 0


# --------------------------------------------------------------------------- status


def _status(args: argparse.Namespace) -> int:
    with service_client(args) as client:
        mission = client.query_mission(client.resolve_mission(args.mission_id))
    if args.json:
        _print_json(mission)
        return 0
    console = _console()
    console.print(mission_tree_table(mission, args.speedup))
    for note in mission.get("notes") or []:
        console.print(f"note: {note}", markup=False, highlight=False)  # wrapped at 80 columns
    return 0


def mission_tree_table(mission: dict[str, Any], speedup: float = 1.0) -> Any:
    """The mission's tree, a line per node: unit, status, plan and actual start-end (mission
    seconds; actual = wall seconds since the mission started x ``speedup``)."""
    from rich.table import Table

    plan = {a.get("node-uuid"): a for a in mission.get("assignments", [])}
    reason = f": {mission['fail-reason']}" if mission.get("fail-reason") else ""
    makespan = mission.get("makespan")
    title = (f"mission {mission.get('root-uuid')} {mission.get('name', '')} "
             f"[{mission.get('status')}{reason}]")
    caption = (f"{mission.get('strategy')} plan, makespan "
               f"{float(makespan or 0):.0f} s; times in mission seconds")
    table = Table(title=title, title_justify="left", caption=caption)
    table.add_column("node", overflow="fold")
    table.add_column("unit", no_wrap=True)
    table.add_column("status", no_wrap=True)
    table.add_column("plan", justify="right", no_wrap=True)
    table.add_column("actual", justify="right", no_wrap=True)
    for node in mission.get("nodes", []):
        depth = str(node.get("path", "")).count("/")
        a = plan.get(node.get("node-uuid"))
        planned = f"{a['start']:.0f}-{a['end']:.0f}" if a else ""
        started, ended = node.get("started"), node.get("ended")
        actual = "" if started is None else (
            f"{started * speedup:.0f}-" + ("" if ended is None else f"{ended * speedup:.0f}"))
        table.add_row("  " * depth + str(node.get("name", "")), str(node.get("execunit") or ""),
                      str(node.get("status", "")), planned, actual)
    return table


# --------------------------------------------------------------------------- cancel, signal


def _cancel(args: argparse.Namespace) -> int:
    with service_client(args) as client:
        root = client.resolve_mission(args.mission_id)
        client.cancel_mission(root)
    if args.json:
        _print_json({"root-uuid": root, "response": "ok"})
    else:
        print(f"mission {root} cancelled")
    return 0


def _signal(args: argparse.Namespace) -> int:
    with service_client(args) as client:
        root = client.resolve_mission(args.mission_id)
        client.signal_mission(root, args.signal)
    if args.json:
        _print_json({"root-uuid": root, "signal": args.signal, "response": "ok"})
    else:
        print(f"{args.signal} sent to mission {root}")
    return 0


# --------------------------------------------------------------------------- follow


def _follow(args: argparse.Namespace) -> int:
    from rich.console import Console

    from delegation.cli.options import Stopped

    console = Console(stderr=bool(args.json))  # with --json, stdout holds the JSON alone
    with service_client(args) as client:
        root = client.resolve_mission(args.mission_id)
        mission = client.query_mission(root)
        progress = resume_progress(mission, args.speedup)
        if not progress.done:
            try:
                follow(client, progress.plan, watch_from(args), console, progress=progress)
            except (KeyboardInterrupt, Stopped):
                console.print()
                still_running_hint(console, root, progress.status)
                raise
        final = client.query_mission(root) if args.json else None
    console.print(progress.summary_table())
    console.print(f"mission {root} {progress.status}"
                  + (f": {progress.fail_reason}" if progress.fail_reason else ""), soft_wrap=True)
    if not progress.done:
        console.print(f"gave up following after {args.timeout:g} s")
        still_running_hint(console, root, progress.status)
    if args.json:
        _print_json(final)
    if not progress.done:
        return 1
    return 0 if progress.succeeded else 1


def resume_progress(mission: dict[str, Any], speedup: float) -> MissionProgress:
    """A `MissionProgress` seeded with what ``query-mission`` says has happened so far."""
    from delegation.render.progress import MissionProgress

    plan = {"tst": mission["tst"], "assignments": mission.get("assignments", []),
            "makespan": mission.get("makespan"), "strategy": mission.get("strategy")}
    progress = MissionProgress(plan, speedup=speedup)
    started = mission.get("started")
    if isinstance(started, int | float):
        progress.started_at = float(started)
    now = time.time()
    for node in mission.get("nodes", []):
        started, ended = node.get("started"), node.get("ended")
        progress.resume(str(node.get("node-uuid")), str(node.get("status", "not-active")),
                        None if started is None else float(started) * speedup,
                        None if ended is None else float(ended) * speedup, now)
    progress.status = str(mission.get("status", "planned"))
    progress.fail_reason = str(mission.get("fail-reason") or "")
    ended = mission.get("ended")
    if isinstance(ended, int | float):
        progress.ended_at = float(ended)
    return progress


# --------------------------------------------------------------------------- bids


def _bids(args: argparse.Namespace) -> int:
    from delegation.cli.inputs import read_mission
    from delegation.tst.node import walk, with_uuids
    from delegation.tst.validate import parse_and_validate

    tree = with_uuids(parse_and_validate(read_mission(args.mission)))
    with service_client(args) as client:
        bids = client.get_bids(tree.to_dict())
    if args.json:
        _print_json(bids)
        return 0
    order = [n.node_uuid for _, n in walk(tree) if not n.is_control]
    paths = {n.node_uuid: p for p, n in walk(tree)}
    _console().print(bids_table(bids, order, paths))
    return 0


def bids_table(bids: list[dict[str, Any]], order: list[str | None],
               paths: dict[str | None, str]) -> Any:
    """Task x unit: estimated seconds (travel + work) or ``-`` (with the reasons below)."""
    from rich.table import Table

    units = sorted({str(b.get("unit")) for b in bids})
    cells: dict[tuple[str, str], str] = {}
    names: dict[str, str] = {}
    reasons: list[str] = []
    for b in bids:
        node, unit = str(b.get("node-uuid")), str(b.get("unit"))
        names[node] = str(b.get("name", ""))
        if b.get("reason"):
            cells[(node, unit)] = "-"
            reasons.append(f"{unit}: {b['reason']}")
        else:
            total = float(b.get("travel-time") or 0) + float(b.get("work-time") or 0)
            cells[(node, unit)] = f"{total:.0f}" + ("+" if b.get("open-ended") else "")
    table = Table(title="bids: estimated seconds (travel + work) per task and unit",
                  title_justify="left",
                  caption="+ open-ended (runs until $enough); - cannot (reasons below)")
    table.add_column("task", overflow="fold")
    for u in units:
        table.add_column(u, justify="right", no_wrap=True)
    for node in [n for n in order if n in names]:
        assert node is not None
        table.add_row(f"{names[node]} {paths.get(node, '')}",
                      *(cells.get((node, u), "") for u in units))
    from rich.console import Group
    from rich.text import Text

    return Group(table, *(Text(r) for r in dict.fromkeys(reasons)))


# --------------------------------------------------------------------------- completion


def _completion(args: argparse.Namespace) -> int:
    import shtab

    from delegation.cli import build_parser

    sys.stdout.write(shtab.complete(build_parser(), shell=args.shell))
    return 0
